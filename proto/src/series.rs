//! The series the telemetry plots show (the web protocol's frame, gRPC `TelemetrySample`,
//! the page): one name per quantity, the recording's column name where the quantity is a
//! recorded column (`rtob_force`, not `F_res`). Appended, never reordered (a client reads the
//! series it knows by position, docs/web-protocol.md).

use crate::telemetry::TelemetryRow;

/// Series names, in frame order.
pub const SERIES: [&str; N_SERIES] = [
    "F_ref",
    "rtob_force",
    "F_pred",
    "position_x",
    "velocity",
    "acceleration",
    "F_true",
    "f_previous",
    "model_id",
    "F_object",
];
/// How many series a frame carries.
pub const N_SERIES: usize = 10;

/// Index of each series in a frame (and in `SERIES`).
pub const F_REF: usize = 0;
pub const RTOB_FORCE: usize = 1;
pub const F_PRED: usize = 2;
pub const POSITION_X: usize = 3;
pub const VELOCITY: usize = 4;
pub const ACCELERATION: usize = 5;
pub const F_TRUE: usize = 6;
pub const F_PREVIOUS: usize = 7;
pub const MODEL_ID: usize = 8;
/// The simulated object's own force (the recording's `F_object`); `F_TRUE` is the felt force
/// (with the simulated hand, the hand's).
pub const F_OBJECT: usize = 9;

/// One telemetry row's value of every series, in frame order (NaN: not known, e.g. F_pred
/// without a model, F_true on a real board).
pub fn values(row: &TelemetryRow) -> [f64; N_SERIES] {
    let mut v = [f64::NAN; N_SERIES];
    v[F_REF] = row.f_ref;
    v[RTOB_FORCE] = row.rtob_force;
    v[F_PRED] = row.f_pred;
    v[POSITION_X] = row.position_x;
    v[VELOCITY] = row.velocity;
    v[ACCELERATION] = row.acceleration;
    v[F_TRUE] = row.f_true;
    v[F_PREVIOUS] = row.f_previous;
    v[MODEL_ID] = f64::from(row.model_id);
    v[F_OBJECT] = row.f_object;
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_series_has_its_index_and_a_value() {
        let names = [
            (F_REF, "F_ref"),
            (RTOB_FORCE, "rtob_force"),
            (F_PRED, "F_pred"),
            (POSITION_X, "position_x"),
            (VELOCITY, "velocity"),
            (ACCELERATION, "acceleration"),
            (F_TRUE, "F_true"),
            (F_PREVIOUS, "f_previous"),
            (MODEL_ID, "model_id"),
            (F_OBJECT, "F_object"),
        ];
        for (i, name) in names {
            assert_eq!(SERIES[i], name);
        }
        let row = TelemetryRow {
            rtob_force: 2.0,
            f_previous: 1.5,
            model_id: 4,
            f_object: 0.5,
            ..TelemetryRow::default()
        };
        let v = values(&row);
        assert_eq!(v[F_OBJECT], 0.5);
        assert_eq!(v[RTOB_FORCE], 2.0);
        assert_eq!(v[F_PREVIOUS], 1.5);
        assert_eq!(v[MODEL_ID], 4.0);
        assert!(
            v.iter().all(|x| !x.is_nan()),
            "a default row has every series"
        );
    }
}
