//! The oracle model (issue 11, item 2): the simulated object's own physics as a [`ForceModel`].
//!
//! A separate [`Object`] of the same material (whatever its law), driven by the loop's measured
//! position, predicts
//! the force; reproduction renders it through the same force loop as any served model
//! (observers, force controller, friction, motor). Its felt-force error is therefore the
//! rendering floor: what no learned model can beat, since a perfect model of the object is
//! exactly this one.
//!
//! REAL-TIME PATH: [`OracleModel::predict`] steps the inline sponge state: no allocation, no
//! lock, no I/O. `begin_run` (off the real-time path) restores a fresh sponge.

use super::material::Material;
use super::{Law, Object};
use crate::features::Features;
use crate::serving::model::ForceModel;

/// Sub-steps per control period: the simulated bench integrates its sponge at 10 us sub-steps
/// at 10 kHz; the oracle interpolates the measured position over the same number.
const SUBSTEPS: usize = 10;

pub struct OracleModel {
    fresh: Object,
    sponge: Object,
    period_s: f64,
    x_prev: f64,
    scale: f64,
}

impl OracleModel {
    /// `rate_hz`: the loop's nominal rate (the model is told positions, not times; the
    /// realtime clock's period jitter is a few microseconds of 100). `scale`: the sponge's
    /// force in the loop's units, K_fn / K_f,true on the simulated bench. A learned model
    /// learns its target in those units (the RFOB measures K_fn times current), so the
    /// force-constant error cancels between recording and rendering; the oracle is given the
    /// same conversion, or it would carry a 3 % error no learned model has.
    pub fn new(material: &Material, rate_hz: f64, scale: f64) -> Self {
        let fresh = Object::new(material);
        OracleModel {
            sponge: fresh.clone(),
            fresh,
            period_s: 1.0 / rate_hz,
            x_prev: 0.0,
            scale,
        }
    }
}

impl ForceModel for OracleModel {
    fn name(&self) -> &str {
        "oracle"
    }

    fn begin_run(&mut self) {
        // Off the real-time path: a fresh sponge for every run, as the bench's own.
        self.sponge = self.fresh.clone();
        self.x_prev = 0.0;
    }

    #[inline]
    fn predict(&mut self, _step: u64, f: &Features) -> Option<f64> {
        let x = f.position_x;
        if !x.is_finite() {
            return None;
        }
        let h = self.period_s / SUBSTEPS as f64;
        self.sponge.prepare(h);
        for k in 1..=SUBSTEPS {
            let xi = self.x_prev + (x - self.x_prev) * (k as f64 / SUBSTEPS as f64);
            self.sponge.substep(xi);
        }
        self.sponge.slow_update(x, self.period_s);
        self.x_prev = x;
        if self.sponge.fault().is_some() {
            // an ONNX object whose graph answered NaN or failed: no prediction (the ladder
            // renders its fallback), never a made-up 0
            return None;
        }
        Some(self.scale * self.sponge.force())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::object::foam::Sponge;

    fn material() -> Material {
        Material::repository_sponge()
    }

    /// Driven along a press, the oracle gives the force of a sponge driven the same way at the
    /// bench's own sub-step, out of contact 0, and a new run starts from a fresh sponge.
    #[test]
    fn oracle_follows_the_sponge_and_restarts_fresh() {
        let m = material();
        let mut o = OracleModel::new(&m, 10_000.0, 1.0);
        let mut s = Sponge::new(m.foam().unwrap());
        o.begin_run();
        let mut feats = Features::default();
        let mut worst: f64 = 0.0;
        let mut peak: f64 = 0.0;
        let mut x_prev = 0.0;
        for k in 0..20_000 {
            let t = k as f64 * 1e-4;
            let x = 0.025 * (std::f64::consts::PI * t / 2.0).sin().max(0.0) - 0.002;
            feats.position_x = x;
            let f = o.predict(k, &feats).unwrap();
            s.prepare(1e-5);
            for i in 1..=10 {
                s.substep(x_prev + (x - x_prev) * i as f64 / 10.0);
            }
            s.slow_update(x, 1e-4);
            x_prev = x;
            worst = worst.max((f - s.force()).abs());
            peak = peak.max(f);
            if x <= 0.0 {
                assert_eq!(f, 0.0);
            }
        }
        assert!(worst < 1e-12, "{worst}");
        assert!(peak > 5.0, "a 23 mm press pushes back: {peak}");
        o.begin_run();
        feats.position_x = 0.01;
        let first = o.predict(0, &feats).unwrap();
        let mut fresh = OracleModel::new(&m, 10_000.0, 2.0);
        assert_eq!(2.0 * first, fresh.predict(0, &feats).unwrap());
        feats.position_x = f64::NAN;
        assert_eq!(o.predict(1, &feats), None);
    }
}
