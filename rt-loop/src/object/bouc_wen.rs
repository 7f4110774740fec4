//! A Bouc-Wen hysteretic material (`law = "bouc_wen"`): a rate-independent hysteresis loop
//! whose shape no foam element has, on a stiffening elastic spring, with a little viscosity.
//!
//! Sources: R. Bouc, "Forced vibration of mechanical systems with hysteresis", Proc. 4th Conf.
//! on Nonlinear Oscillation, Prague, 1967; Y.-K. Wen, "Method for random vibration of
//! hysteretic systems", J. Eng. Mech. Div. ASCE 102(2):249-263, 1976; the survey M. Ismail,
//! F. Ikhouane, J. Rodellar, "The hysteresis Bouc-Wen model, a survey", Arch. Comput. Methods
//! Eng. 16:161-188, 2009 (the form and the bound of z below are its eqs. (1)-(2) and section
//! 3.1). Used for rubber bearings, elastomer pads and magnetorheological dampers.
//!
//! With the compression e = x (the surface at x = 0) and its rate:
//!
//! ```text
//! dz = de (A - |z|^n (beta sgn(z de) + gamma))          the hysteretic displacement, |z| <= z_max
//! F  = max(0, alpha k e + k3 e^3 + (1 - alpha) k z + c de/dt)    in contact (e > 0), else 0
//! ```
//!
//! z_max = (A / (beta + gamma))^(1/n). Out of contact the material springs back: z = 0.
//! Integrated at the bench's sub-step (the increment de is a few micrometres, far below
//! z_max). All state is inline: stepping allocates nothing.

use super::Law;
use crate::invalid::{require_non_negative, require_positive, InvalidSetting};
use serde::{Deserialize, Serialize};

/// The `bouc_wen` law's table (`[bouc_wen]` in the material file).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoucWenParams {
    pub bouc_wen: BoucWenTable,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoucWenTable {
    /// Elastic stiffness k, N/m.
    pub stiffness_n_per_m: f64,
    /// Cubic stiffening k3, N/m^3 (the pad stiffens as it is squeezed).
    pub cubic_n_per_m3: f64,
    /// Share of the stiffness that is elastic (alpha in [0, 1]); the rest is hysteretic.
    pub alpha: f64,
    /// A (dimensionless), beta and gamma (1/m^n): the loop's shape.
    pub a: f64,
    pub beta: f64,
    pub gamma: f64,
    /// n >= 1: the sharpness of the transition from loading to yielding.
    pub n: f64,
    /// Viscous damping c, N s/m.
    pub damping_ns_per_m: f64,
}

impl BoucWenParams {
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        let b = &self.bouc_wen;
        require_positive(&[
            ("bouc_wen.stiffness_n_per_m", b.stiffness_n_per_m),
            ("bouc_wen.a", b.a),
        ])?;
        require_non_negative(&[
            ("bouc_wen.cubic_n_per_m3", b.cubic_n_per_m3),
            ("bouc_wen.damping_ns_per_m", b.damping_ns_per_m),
        ])?;
        if !(b.alpha.is_finite() && (0.0..=1.0).contains(&b.alpha)) {
            return Err(format!("bouc_wen.alpha must be in [0, 1] (got {})", b.alpha).into());
        }
        if !(b.n.is_finite() && b.n >= 1.0 && b.n <= 10.0) {
            return Err(format!("bouc_wen.n must be in [1, 10] (got {})", b.n).into());
        }
        // beta + gamma > 0 and beta >= |gamma| keep z bounded (Ismail et al. 2009, 3.1)
        if !(b.beta.is_finite() && b.gamma.is_finite() && b.beta + b.gamma > 0.0)
            || b.beta < b.gamma.abs()
        {
            return Err(format!(
                "bouc_wen: beta + gamma must be > 0 and beta >= |gamma| (got beta {}, gamma {})",
                b.beta, b.gamma
            )
            .into());
        }
        Ok(())
    }
}

#[derive(Clone, Debug)]
pub struct BoucWen {
    p: BoucWenTable,
    h: f64,
    z_max: f64,
    // state
    z: f64,
    e_prev: f64,
    force: f64,
}

impl BoucWen {
    pub fn new(p: &BoucWenParams) -> Self {
        let b = p.bouc_wen.clone();
        let z_max = (b.a / (b.beta + b.gamma)).powf(1.0 / b.n);
        BoucWen {
            p: b,
            h: 1e-5,
            z_max,
            z: 0.0,
            e_prev: 0.0,
            force: 0.0,
        }
    }

    /// The hysteretic displacement z, m.
    pub fn z(&self) -> f64 {
        self.z
    }

    /// Its bound (A / (beta + gamma))^(1/n), m.
    pub fn z_max(&self) -> f64 {
        self.z_max
    }
}

impl Law for BoucWen {
    #[inline]
    fn prepare(&mut self, h: f64) {
        self.h = h;
    }

    #[inline]
    fn substep(&mut self, x: f64) -> f64 {
        let e = x;
        if e <= 0.0 {
            self.z = 0.0;
            self.e_prev = 0.0;
            self.force = 0.0;
            return 0.0;
        }
        let p = &self.p;
        let de = e - self.e_prev;
        let az = self.z.abs();
        let zn = if p.n == 1.0 { az } else { az.powf(p.n) };
        let s = if self.z * de >= 0.0 { 1.0 } else { -1.0 };
        let dz = de * (p.a - zn * (p.beta * s + p.gamma));
        self.z = (self.z + dz).clamp(-self.z_max, self.z_max);
        self.e_prev = e;
        let rate = de / self.h;
        let f = p.alpha * p.stiffness_n_per_m * e
            + p.cubic_n_per_m3 * e * e * e
            + (1.0 - p.alpha) * p.stiffness_n_per_m * self.z
            + p.damping_ns_per_m * rate;
        self.force = f.max(0.0);
        self.force
    }

    #[inline]
    fn force(&self) -> f64 {
        self.force
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::object::material::{LawParams, Material};

    fn bw() -> BoucWen {
        match Material::repository("bouc-wen").law {
            LawParams::BoucWen(p) => BoucWen::new(&p),
            other => panic!("materials/bouc-wen.toml is {}", other.name()),
        }
    }

    /// A slow and a fast cycle at the same depth: the loop is there (loading above unloading
    /// at mid-depth by about twice the hysteretic force), its width does not depend on the
    /// rate but for the small viscous term (rate independence: the mark of Bouc-Wen), z stays
    /// within its bound, and a reload after separation starts from z = 0.
    #[test]
    fn hysteresis_loop_is_rate_independent_and_bounded() {
        let cycle = |rate: f64| {
            let mut o = bw();
            let h = 1e-5;
            o.prepare(h);
            let depth = 0.015;
            let n = (depth / rate / h) as usize;
            let (mut up, mut down) = (0.0, 0.0);
            for k in 0..=n {
                let f = o.substep(rate * h * k as f64);
                assert!(o.z().abs() <= o.z_max() + 1e-15);
                if k == n / 2 {
                    up = f;
                }
            }
            for k in 0..=n {
                let f = o.substep(depth - rate * h * k as f64);
                if k == n / 2 {
                    down = f;
                }
            }
            (up, down, o)
        };
        let (up_s, down_s, _) = cycle(0.002);
        let (up_f, down_f, mut o) = cycle(0.02);
        let fresh = bw();
        let p = &fresh.p;
        let hyst = (1.0 - p.alpha) * p.stiffness_n_per_m * fresh.z_max();
        assert!(
            up_s - down_s > 1.5 * hyst,
            "loop {up_s} vs {down_s} ({hyst})"
        );
        // the width differs between the rates only by the viscous term 2 c (v_fast - v_slow)
        let visc = 2.0 * p.damping_ns_per_m * (0.02 - 0.002);
        let widths = ((up_f - down_f) - (up_s - down_s)).abs();
        assert!(widths < visc + 0.05, "{widths} vs {visc}");
        assert_eq!(o.substep(-0.001), 0.0);
        assert_eq!(o.z(), 0.0, "separation resets z");
    }
}
