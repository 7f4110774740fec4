//! The foam law (`law = "foam"`), the simulated sponge (docs/physics.md, "The simulated sponge bench"): nonlinear foam
//! stiffness (plateau, then densification), generalized Maxwell viscoelastic branches, a
//! rate-independent Dahl hysteresis element, a permanent set that grows with the largest
//! compression seen and slowly partly recovers, and unilateral contact (it pushes, never
//! pulls). All state is inline (fixed arrays), so stepping it allocates nothing.
//!
//! Sources of its parts: the tanh plateau and densification of flexible cellular foams (Gibson
//! & Ashby, Cellular Solids, 2nd ed. 1997, ch. 5), quasi-linear viscoelasticity with a Prony
//! series (Fung, Biomechanics, 1993, ch. 7), the Dahl friction/hysteresis element (Dahl 1968),
//! compression set of flexible polyurethane foam (ASTM D3574, test D).

use super::material::{Foam, MAX_BRANCHES};
use super::Law;

#[derive(Clone, Debug)]
pub struct Sponge {
    m: Foam,
    n_branches: usize,
    gains: [f64; MAX_BRANCHES],
    taus: [f64; MAX_BRANCHES],
    decay: [f64; MAX_BRANCHES],
    decay_h: f64,
    // state
    q: [f64; MAX_BRANCHES],
    hyst: f64,
    set: f64,
    e_prev: f64,
    feq_prev: f64,
    max_depth: f64,
    force: f64,
}

impl Sponge {
    pub fn new(m: &Foam) -> Self {
        let mut gains = [0.0; MAX_BRANCHES];
        let mut taus = [1.0; MAX_BRANCHES];
        for (i, b) in m.maxwell.iter().take(MAX_BRANCHES).enumerate() {
            gains[i] = b.gain;
            taus[i] = b.tau_s;
        }
        Sponge {
            m: m.clone(),
            n_branches: m.maxwell.len().min(MAX_BRANCHES),
            gains,
            taus,
            decay: [1.0; MAX_BRANCHES],
            decay_h: -1.0,
            q: [0.0; MAX_BRANCHES],
            hyst: 0.0,
            set: 0.0,
            e_prev: 0.0,
            feq_prev: 0.0,
            max_depth: 0.0,
            force: 0.0,
        }
    }

    /// Equilibrium (fully relaxed, hysteresis-free) force at compression `e` (m).
    pub fn f_eq(&self, e: f64) -> f64 {
        self.eq_and_tangent(e).0
    }

    /// Tangent stiffness dF_eq/de (N/m).
    pub fn k_eq(&self, e: f64) -> f64 {
        self.eq_and_tangent(e).1
    }

    /// F_eq(e) and its slope together, sharing the transcendental calls (one tanh, one
    /// power): this is the sub-step's hot spot.
    #[inline]
    pub fn eq_and_tangent(&self, e: f64) -> (f64, f64) {
        if e <= 0.0 {
            let q = &self.m.equilibrium;
            return (
                0.0,
                q.plateau_n / q.yield_m + q.densification_n * q.exponent / q.densification_m,
            );
        }
        let q = &self.m.equilibrium;
        // Past 95 % of the densification strain the law continues linearly with its tangent:
        // the pole at e = densification_m is never reached.
        let e_cap = 0.95 * q.densification_m;
        let ec = e.min(e_cap);
        let th = (ec / q.yield_m).tanh();
        let u = 1.0 - ec / q.densification_m;
        let p = if q.exponent == 2.0 {
            1.0 / (u * u)
        } else {
            u.powf(-q.exponent)
        };
        let f = q.plateau_n * th + q.densification_n * (p - 1.0);
        let k = q.plateau_n / q.yield_m * (1.0 - th * th)
            + q.densification_n * q.exponent / q.densification_m * p / u;
        if e > e_cap {
            (f + k * (e - e_cap), k)
        } else {
            (f, k)
        }
    }

    /// Prepares the per-substep relaxation factors for a substep of `h` seconds (cached: the
    /// exponentials are only recomputed when the substep length changes).
    #[inline]
    pub fn prepare(&mut self, h: f64) {
        if h != self.decay_h {
            for i in 0..self.n_branches {
                self.decay[i] = (-h / self.taus[i]).exp();
            }
            self.decay_h = h;
        }
    }

    /// Advances the sponge to probe position `x` (m, positive into the sponge) over one
    /// substep prepared with [`Sponge::prepare`]; returns the contact force (N, >= 0) with
    /// which the sponge pushes the probe back.
    #[inline]
    pub fn substep(&mut self, x: f64) -> f64 {
        let e = x - self.set;
        if e <= 0.0 {
            // Out of contact: the foam expands freely, its branch forces relax.
            for i in 0..self.n_branches {
                self.q[i] *= self.decay[i];
            }
            self.hyst = 0.0;
            self.e_prev = 0.0;
            self.force = 0.0;
            return 0.0;
        }
        let e0 = self.e_prev.max(0.0);
        let (feq1, k1) = self.eq_and_tangent(e);
        // F_eq at the previous compression is cached from the previous sub-step
        let df = feq1
            - if self.e_prev > 0.0 {
                self.feq_prev
            } else {
                0.0
            };
        let mut branches = 0.0;
        for i in 0..self.n_branches {
            self.q[i] = self.q[i] * self.decay[i] + self.gains[i] * df;
            branches += self.q[i];
        }
        let hmax = self.m.hysteresis.fraction * feq1;
        let de = e - e0;
        if hmax > 0.0 && de != 0.0 {
            let sig = self.m.hysteresis.stiffness_ratio * k1;
            let s = de.signum();
            self.hyst += sig * de * (1.0 - s * self.hyst / hmax);
        }
        self.hyst = self.hyst.clamp(-hmax, hmax);
        self.e_prev = e;
        self.feq_prev = feq1;
        // Unilateral contact: the sponge never pulls on the probe.
        self.force = (feq1 + self.hyst + branches).max(0.0);
        self.force
    }

    /// The slow part, once per control period of `dt` seconds: the permanent set grows toward
    /// its target while the sponge is heavily compressed and recovers partly otherwise.
    pub fn slow_update(&mut self, x: f64, dt: f64) {
        let ps = &self.m.permanent_set;
        if x > self.max_depth {
            self.max_depth = x;
        }
        let target = ps.max_m * (self.max_depth / ps.reference_m).powf(ps.exponent);
        let loaded = x > ps.loaded_fraction * self.max_depth && x - self.set > 0.0;
        if loaded && self.set < target {
            self.set += (target - self.set) * (dt / ps.tau_grow_s).min(1.0);
        } else if !loaded {
            let floor = ps.keep_fraction * target;
            if self.set > floor {
                self.set -= (self.set - floor) * (dt / ps.tau_recover_s).min(1.0);
            }
        }
    }

    pub fn force(&self) -> f64 {
        self.force
    }

    /// Current permanent deformation (m): where the unloaded surface now sits.
    pub fn permanent_set(&self) -> f64 {
        self.set
    }

    pub fn max_depth(&self) -> f64 {
        self.max_depth
    }
}

impl Law for Sponge {
    #[inline]
    fn prepare(&mut self, h: f64) {
        Sponge::prepare(self, h)
    }
    #[inline]
    fn substep(&mut self, x: f64) -> f64 {
        Sponge::substep(self, x)
    }
    #[inline]
    fn slow_update(&mut self, x: f64, dt: f64) {
        Sponge::slow_update(self, x, dt)
    }
    #[inline]
    fn force(&self) -> f64 {
        self.force
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::object::material::Material;

    fn sponge() -> Sponge {
        Sponge::new(Material::repository_sponge().foam().unwrap())
    }

    #[test]
    fn tangent_is_the_derivative_of_the_law() {
        let s = sponge();
        for i in 1..40 {
            let e = i as f64 * 1e-3;
            let h = 1e-7;
            let num = (s.f_eq(e + h) - s.f_eq(e - h)) / (2.0 * h);
            assert!(
                (num - s.k_eq(e)).abs() < 1e-4 * num.abs().max(1.0),
                "e {e}: {num} vs {}",
                s.k_eq(e)
            );
        }
    }

    #[test]
    fn foam_law_has_plateau_then_densification_and_reaches_14n_within_30mm() {
        let s = sponge();
        let k_start = s.k_eq(0.0);
        let k_plateau = s.k_eq(0.012);
        let k_dense = s.k_eq(0.028);
        assert!(k_plateau < 0.5 * k_start, "plateau softer than the start");
        assert!(k_dense > 4.0 * k_plateau, "densification stiffens");
        let e14 = (1..4000)
            .map(|i| i as f64 * 1e-5)
            .find(|&e| s.f_eq(e) >= 14.0)
            .unwrap();
        assert!(e14 <= 0.030 && e14 > 0.015, "14 N at {e14} m");
        // monotone
        let mut prev = 0.0;
        for i in 1..5000 {
            let f = s.f_eq(i as f64 * 1e-5);
            assert!(f > prev);
            prev = f;
        }
    }

    /// Drive the sponge position directly: loading force exceeds unloading force at the same
    /// depth (hysteresis), a faster stroke is stiffer (viscoelasticity), it never pulls, and a
    /// set remains.
    #[test]
    fn hysteresis_rate_dependence_unilateral_and_set() {
        let stroke = |rate: f64| {
            let mut s = sponge();
            let h = 1e-4;
            s.prepare(h);
            let depth = 0.025;
            let n = (depth / rate / h) as usize;
            let mut up = 0.0;
            let mut down = 0.0;
            let mut min_force = f64::INFINITY;
            for k in 0..=n {
                let x = rate * h * k as f64;
                let f = s.substep(x);
                s.slow_update(x, h);
                if k == n / 2 {
                    up = f;
                }
            }
            for k in 0..=n {
                let x = depth - rate * h * k as f64;
                let f = s.substep(x);
                s.slow_update(x, h);
                min_force = min_force.min(f);
                if k == n / 2 {
                    down = f;
                }
            }
            (up, down, min_force, s.permanent_set())
        };
        let (up_slow, down_slow, min_slow, set_slow) = stroke(0.002);
        let (up_fast, _, _, _) = stroke(0.02);
        assert!(
            up_slow > down_slow + 0.2,
            "hysteresis: {up_slow} vs {down_slow}"
        );
        assert!(
            up_fast > up_slow * 1.05,
            "rate dependence: {up_fast} vs {up_slow}"
        );
        assert!(min_slow >= 0.0, "unilateral");
        assert!(set_slow > 1e-4, "permanent set {set_slow}");
    }
}
