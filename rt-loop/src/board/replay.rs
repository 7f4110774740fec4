//! The replay board: feeds a recording's encoder counts and timestamps back through the loop,
//! so a recording can be reprocessed offline with other observer settings. The DAC words the
//! loop writes are ignored (the recorded motion already happened); the recorded F_true and
//! F_object are passed through (NaN when the recording has no such column: older recordings
//! have no F_object).

use super::{Board, BoardError, BoardStop, Snapshot};
use crate::invalid::InvalidSeries;

pub struct ReplayBoard {
    counts: Vec<i32>,
    timestamps: Vec<u32>,
    f_true: Vec<f64>,
    f_object: Vec<f64>,
    next: usize,
    current: usize,
}

impl ReplayBoard {
    pub fn new(
        counts: Vec<i32>,
        timestamps: Vec<u32>,
        f_true: Vec<f64>,
    ) -> Result<Self, InvalidSeries> {
        if counts.len() != timestamps.len() || (!f_true.is_empty() && f_true.len() != counts.len())
        {
            return Err("replay columns have different lengths".into());
        }
        if counts.is_empty() {
            return Err("replay recording has no rows".into());
        }
        Ok(ReplayBoard {
            counts,
            timestamps,
            f_true,
            f_object: Vec::new(),
            next: 0,
            current: 0,
        })
    }

    /// Passes the recording's `F_object` through as well (empty: none, NaN on every step).
    pub fn with_object_force(mut self, f_object: Vec<f64>) -> Result<Self, InvalidSeries> {
        if !f_object.is_empty() && f_object.len() != self.counts.len() {
            return Err("replay columns have different lengths".into());
        }
        self.f_object = f_object;
        Ok(self)
    }

    /// Loads `counts`, `timestamp` and (if present) `F_true` and `F_object` from a recording.
    pub fn from_recording(path: &std::path::Path) -> anyhow::Result<Self> {
        let cols = crate::record::read::read_columns(path, &["counts", "timestamp"])?;
        let optional = |name: &str| {
            crate::record::read::read_columns(path, &[name])
                .map(|mut c| c.remove(0))
                .unwrap_or_default()
        };
        let (f_true, f_object) = (optional("F_true"), optional("F_object"));
        let counts = integers(&cols[0], "counts", i32::MIN as f64, i32::MAX as f64)
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?
            .into_iter()
            .map(|c| c as i32)
            .collect();
        let ts = integers(&cols[1], "timestamp", 0.0, u32::MAX as f64)
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?
            .into_iter()
            .map(|t| t as u32)
            .collect();
        ReplayBoard::new(counts, ts, f_true)
            .and_then(|b| b.with_object_force(f_object))
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
    }

    pub fn len(&self) -> usize {
        self.counts.len()
    }

    pub fn is_empty(&self) -> bool {
        self.counts.is_empty()
    }
}

/// The column's values when every one is a whole number within `lo..=hi`; otherwise the first
/// offending row (1-based data row). A cast would turn NaN into 0 and clip the rest silently.
fn integers(col: &[f64], name: &str, lo: f64, hi: f64) -> Result<Vec<f64>, String> {
    match col
        .iter()
        .position(|v| !(v.is_finite() && v.fract() == 0.0 && *v >= lo && *v <= hi))
    {
        Some(i) => Err(format!(
            "row {}: {name} = {} is not a whole number within {lo}..{hi}",
            i + 1,
            col[i]
        )),
        None => Ok(col.to_vec()),
    }
}

/// The replayed motion already happened: configuring, arming, writing and kicking change
/// nothing, and cannot fail.
impl Board for ReplayBoard {
    fn configure(&mut self) -> Result<(), BoardError> {
        Ok(())
    }
    fn activate(&mut self, _watchdog_us: u32) -> Result<(), BoardError> {
        Ok(())
    }
    fn read(&mut self) -> Result<Snapshot, BoardStop> {
        if self.next >= self.counts.len() {
            return Err(BoardStop::EndOfData);
        }
        self.current = self.next;
        self.next += 1;
        Ok(Snapshot {
            counts: self.counts[self.current],
            timestamp_us: self.timestamps[self.current],
        })
    }
    fn write(&mut self, _word: u16) -> Result<(), BoardStop> {
        Ok(())
    }
    fn kick(&mut self) -> Result<(), BoardStop> {
        Ok(())
    }
    fn deactivate(&mut self) {}
    fn on_error(&mut self, _reason: &'static str) {}
    fn shutdown(&mut self) {}
    fn true_force(&self) -> f64 {
        self.f_true.get(self.current).copied().unwrap_or(f64::NAN)
    }
    fn object_force(&self) -> f64 {
        self.f_object.get(self.current).copied().unwrap_or(f64::NAN)
    }
    fn name(&self) -> &'static str {
        "replay"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn non_finite_or_fractional_values_are_refused_with_their_row() {
        let e = integers(&[1.0, 2.0, f64::NAN], "counts", -10.0, 10.0).unwrap_err();
        assert!(e.contains("row 3") && e.contains("counts"), "{e}");
        let e = integers(&[1.0, 2.5], "timestamp", 0.0, 10.0).unwrap_err();
        assert!(e.contains("row 2"), "{e}");
        let e = integers(&[1.0, 1e12], "timestamp", 0.0, u32::MAX as f64).unwrap_err();
        assert!(e.contains("row 2"), "{e}");
        assert_eq!(
            integers(&[-3.0, 4.0], "counts", -10.0, 10.0).unwrap(),
            vec![-3.0, 4.0]
        );
    }
}
