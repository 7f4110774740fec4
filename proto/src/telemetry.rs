//! The telemetry row: the full state of one loop step, loop to server (the overwriting
//! telemetry channel), and its word encoding.

use shm_ring::{layout_id, DecodeError, Message};

/// The full state of one loop step, loop to server, for live plots and statistics: the same
/// columns as a recording row (`docs/recording-format.md`), plus the run id.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[allow(missing_docs)]
pub struct TelemetryRow {
    pub run_id: u32,
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
}

impl TelemetryRow {
    const FLOATS: usize = 17;

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
        ]
    }
}

impl Message for TelemetryRow {
    const WORDS: usize = 4 + Self::FLOATS;
    const LAYOUT_ID: u64 = layout_id(
        "TelemetryRow v1: run_id u64, step u64, timestamp u32|counts i32, \
         analog_out_motor u16|phase u8<<16|fallback u8<<24|cycle_no u32<<32, time, dt, f_ref, \
         rtob_force, dob_force, position_x, velocity, acceleration, i_a_ref, i_motor, f_true, \
         f_pred, f_previous_x, f_previous_v, f_previous_a, deformation, area_fx (f64)",
    );

    fn encode(&self, out: &mut [u64]) {
        out[0] = self.run_id as u64;
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
        })
    }
}
