//! The networks' input scaling (train's networks.py `InputScaler`): the ratio features
//! F(t-1)/x, /v, /a reach 1e7 and beyond near a zero divisor, so they are read as
//! asinh(clip(x / s)); the standardisation after it is folded into the first weights by the
//! exporter (or, for `lstm_slow`, applied by its kernel).

use crate::attrs::{AttrError, Attrs, Reader};

/// Attributes `soft_scale` [n] (s_j of the soft features, 0 for the features read as they
/// are) and `clip`.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct SoftScaler {
    /// 1 / s_j, 0 for the features read as they are
    inv: Vec<f32>,
    clip: f32,
}

impl SoftScaler {
    pub fn from_attrs<A: Attrs + ?Sized>(
        r: &Reader<'_, A>,
        n: usize,
        what: &'static str,
    ) -> Result<Self, AttrError> {
        let soft = r.list_of("soft_scale", n, what)?;
        for &s in &soft {
            r.check(
                "soft_scale",
                s,
                s >= 0.0,
                "negative (0: not a soft feature)",
            )?;
        }
        let clip = r.positive("clip")?;
        Ok(Self {
            inv: soft
                .iter()
                .map(|&s| if s > 0.0 { (1.0 / s) as f32 } else { 0.0 })
                .collect(),
            clip: clip as f32,
        })
    }

    /// A network's scaler: its width (the network's input) is `soft_scale`'s, at least 1.
    pub fn networks<A: Attrs + ?Sized>(r: &Reader<'_, A>) -> Result<Self, AttrError> {
        let n = r.list("soft_scale")?.len();
        r.check(
            "soft_scale",
            n as f64,
            n >= 1,
            "empty (one value per feature)",
        )?;
        Self::from_attrs(r, n, "the features")
    }

    /// The features it reads.
    pub fn len(&self) -> usize {
        self.inv.len()
    }

    /// `z` = the scaled `x` (both `len()` long).
    #[inline(always)]
    pub fn apply(&self, x: &[f32], z: &mut [f32]) {
        for ((z, &xj), &inv) in z.iter_mut().zip(x).zip(&self.inv) {
            *z = if inv > 0.0 {
                (xj * inv).clamp(-self.clip, self.clip).asinh()
            } else {
                xj
            };
        }
    }
}
