//! The telemetry row: the full state of one loop step. ONE type for the recorder (rt-loop's
//! `record::Row` is this type: its recorded columns are [`RECORDING_COLUMNS`]), the telemetry
//! ring (loop to server, overwriting) and the server's plots; and its word encoding.

use shm_ring::{layout_id, DecodeError, Message};

/// The recording's columns in file order (docs/recording-format.md): the fields of a
/// [`TelemetryRow`] but `run_id`, `model_id` and `f_previous`, which only telemetry carries.
pub const RECORDING_COLUMNS: [&str; 25] = [
    "step",
    "timestamp",
    "time",
    "dt",
    "F_ref",
    "rtob_force",
    "dob_force",
    "counts",
    "position_x",
    "velocity",
    "acceleration",
    "I_a_ref",
    "I_motor",
    "analog_out_motor",
    "phase",
    "F_true",
    "F_pred",
    "fallback",
    "cycle_no",
    "f_previous_x",
    "f_previous_v",
    "f_previous_a",
    "deformation",
    "area_fx",
    "F_object",
];

/// The full state of one loop step: a recording row (`docs/recording-format.md`, columns
/// [`RECORDING_COLUMNS`]) plus what live telemetry adds: the run id, the served model that drew
/// the step, and F(t-1). A plain `Copy` struct: pushing it through a ring copies bytes.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[allow(missing_docs)]
pub struct TelemetryRow {
    /// The run this step belongs to (telemetry only; 0 in the recorder).
    pub run_id: u32,
    /// The served model whose answer the step rendered or held (`ForceMsg.model_id`, the
    /// server's registry id); 0 when none did (other experiments, the fallback, a built-in
    /// model). Telemetry only.
    pub model_id: u32,
    /// F(t-1), N: the force committed the step before, as the features give it to a model
    /// (the schema's `f_previous`). Telemetry only.
    pub f_previous: f64,
    pub step: u64,
    pub timestamp: u32,
    pub time: f64,
    pub dt: f64,
    pub f_ref: f64,
    pub rtob_force: f64,
    pub dob_force: f64,
    pub counts: i32,
    pub position_x: f64,
    pub velocity: f64,
    pub acceleration: f64,
    pub i_a_ref: f64,
    pub i_motor: f64,
    pub analog_out_motor: u16,
    pub phase: u8,
    pub f_true: f64,
    pub f_pred: f64,
    pub fallback: bool,
    pub cycle_no: u32,
    pub f_previous_x: f64,
    pub f_previous_v: f64,
    pub f_previous_a: f64,
    pub deformation: f64,
    pub area_fx: f64,
    /// The simulated object's own force on the probe, N (NaN where the bench has no object
    /// of its own: a real board, reproduction's virtual object, imported data). `f_true` is
    /// the felt force: with the simulated hand, the hand's force, which also carries the
    /// bench's friction and the motor's mass; an object-only model is compared with this one.
    pub f_object: f64,
}

impl TelemetryRow {
    const FLOATS: usize = 19;

    fn floats(&self) -> [f64; Self::FLOATS] {
        [
            self.time,
            self.dt,
            self.f_ref,
            self.rtob_force,
            self.dob_force,
            self.position_x,
            self.velocity,
            self.acceleration,
            self.i_a_ref,
            self.i_motor,
            self.f_true,
            self.f_pred,
            self.f_previous_x,
            self.f_previous_v,
            self.f_previous_a,
            self.deformation,
            self.area_fx,
            self.f_previous,
            self.f_object,
        ]
    }
}

impl Message for TelemetryRow {
    const WORDS: usize = 4 + Self::FLOATS;
    const LAYOUT_ID: u64 = layout_id(
        "TelemetryRow v3: run_id u32|model_id u32<<32, step u64, timestamp u32|counts i32, \
         analog_out_motor u16|phase u8<<16|fallback u8<<24|cycle_no u32<<32, time, dt, f_ref, \
         rtob_force, dob_force, position_x, velocity, acceleration, i_a_ref, i_motor, f_true, \
         f_pred, f_previous_x, f_previous_v, f_previous_a, deformation, area_fx, f_previous, f_object (f64)",
    );

    fn encode(&self, out: &mut [u64]) {
        out[0] = self.run_id as u64 | (self.model_id as u64) << 32;
        out[1] = self.step;
        out[2] = self.timestamp as u64 | (self.counts as u32 as u64) << 32;
        out[3] = self.analog_out_motor as u64
            | (self.phase as u64) << 16
            | (self.fallback as u64) << 24
            | (self.cycle_no as u64) << 32;
        for (word, value) in out[4..4 + Self::FLOATS].iter_mut().zip(self.floats()) {
            *word = value.to_bits();
        }
    }

    fn decode(w: &[u64]) -> Result<Self, DecodeError> {
        let fallback = (w[3] >> 24) & 0xff;
        if fallback > 1 {
            return Err(DecodeError::InvalidField {
                field: "TelemetryRow.fallback",
                value: fallback,
            });
        }
        let f = |i: usize| f64::from_bits(w[4 + i]);
        Ok(TelemetryRow {
            run_id: w[0] as u32,
            model_id: (w[0] >> 32) as u32,
            step: w[1],
            timestamp: w[2] as u32,
            counts: (w[2] >> 32) as u32 as i32,
            analog_out_motor: w[3] as u16,
            phase: (w[3] >> 16) as u8,
            fallback: fallback == 1,
            cycle_no: (w[3] >> 32) as u32,
            time: f(0),
            dt: f(1),
            f_ref: f(2),
            rtob_force: f(3),
            dob_force: f(4),
            position_x: f(5),
            velocity: f(6),
            acceleration: f(7),
            i_a_ref: f(8),
            i_motor: f(9),
            f_true: f(10),
            f_pred: f(11),
            f_previous_x: f(12),
            f_previous_v: f(13),
            f_previous_a: f(14),
            deformation: f(15),
            area_fx: f(16),
            f_previous: f(17),
            f_object: f(18),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_row_round_trips_through_its_words() {
        let row = TelemetryRow {
            run_id: 7,
            model_id: u32::MAX,
            f_previous: -2.5,
            step: 11,
            timestamp: 12,
            counts: -13,
            analog_out_motor: 40_000,
            phase: 5,
            fallback: true,
            cycle_no: 3,
            rtob_force: 1.25,
            area_fx: 0.5,
            f_object: 0.75,
            ..TelemetryRow::default()
        };
        let mut words = [0u64; TelemetryRow::WORDS];
        row.encode(&mut words);
        assert_eq!(TelemetryRow::decode(&words), Ok(row));
    }
}
