//! A poroelastic gel under a spherical indenter (`law = "poroelastic"`): the force relaxes as
//! the solvent flows out of the contact zone, and the relaxation time grows with the square of
//! the contact radius, so a deep press relaxes slower than a shallow one. No foam element has
//! a time constant that depends on the depth; train's `structured` has such branches among its
//! indentation elements, where validation chooses them (docs/laws.md, "Indentation shapes").
//!
//! Source: Y. Hu, X. Zhao, J. J. Vlassak, Z. Suo, "Using indentation to characterize the
//! poroelasticity of gels", Appl. Phys. Lett. 96:121904, 2010. For a spherical indenter of
//! radius R at depth e (contact radius a = sqrt(R e)):
//!
//! ```text
//! F_0(e)   = 16/3 G sqrt(R) e^(3/2)                   instantaneous (undrained, nu = 1/2)
//! F_inf(e) =  8/3 G sqrt(R) e^(3/2) / (1 - nu)        long-time (drained, nu = nu_drained)
//! F(t)     = F_inf + (F_0 - F_inf) g(D t / a^2)        after a step to e (their eqs. 3-5)
//! g(s)     = 0.491 exp(-0.908 sqrt(s)) + 0.509 exp(-1.679 s)    (their eq. 6, fitted to FEM)
//! ```
//!
//! F_0 / F_inf = 2 (1 - nu). For any motion, not only a step, the law is stepped as quasi-linear
//! poroelasticity: g is written as a sum of exponentials exp(-lambda_k s) (six terms fitted to
//! their eq. 6 within 0.003 over s in 1e-4..20), each a branch q_k driven by the change of
//! F_0 - F_inf and relaxing in the normalized time ds = D dt / a(t)^2, which runs slower the
//! larger the contact. Out of contact the gel re-swells (the branches are emptied). The
//! diffusivity of the repository's file is that of a very open network (a fluid-filled
//! sponge), so the relaxation falls within the seconds a bench recording spans; a hydrogel's
//! D (1e-10..1e-9 m^2/s) would put it at hours.

use super::Law;
use crate::invalid::{require_positive, InvalidSetting};
use serde::{Deserialize, Serialize};

/// The relaxation function of Hu et al. (2010) eq. 6 as exponentials in the normalized time s:
/// (lambda_k, weight_k), fitted by non-negative least squares to
/// 0.491 exp(-0.908 sqrt(s)) + 0.509 exp(-1.679 s) on s in [1e-4, 20] (max error 0.003).
const RELAXATION: [(f64, f64); 6] = [
    (0.1, 0.0779),
    (0.5, 0.1889),
    (1.679, 0.5837),
    (6.0, 0.0874),
    (30.0, 0.0264),
    (150.0, 0.0288),
];

/// The `poroelastic` law's table (`[poroelastic]` in the material file).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoroelasticParams {
    pub poroelastic: PoroelasticTable,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoroelasticTable {
    /// Shear modulus of the network G, Pa.
    pub shear_modulus_pa: f64,
    /// Drained Poisson's ratio nu (0 <= nu < 1/2).
    pub poisson_drained: f64,
    /// Radius of the spherical indenter R, m.
    pub indenter_radius_m: f64,
    /// Poroelastic diffusivity D, m^2/s.
    pub diffusivity_m2_per_s: f64,
}

impl PoroelasticParams {
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        let p = &self.poroelastic;
        require_positive(&[
            ("poroelastic.shear_modulus_pa", p.shear_modulus_pa),
            ("poroelastic.indenter_radius_m", p.indenter_radius_m),
            ("poroelastic.diffusivity_m2_per_s", p.diffusivity_m2_per_s),
        ])?;
        if !(p.poisson_drained.is_finite() && (0.0..0.5).contains(&p.poisson_drained)) {
            return Err(format!(
                "poroelastic.poisson_drained must be in [0, 0.5) (got {})",
                p.poisson_drained
            )
            .into());
        }
        Ok(())
    }
}

#[derive(Clone, Debug)]
pub struct Poroelastic {
    /// 16/3 G sqrt(R): F_0 = c0 e^1.5.
    c0: f64,
    /// F_inf = c_inf e^1.5.
    c_inf: f64,
    radius: f64,
    diffusivity: f64,
    h: f64,
    // state
    q: [f64; RELAXATION.len()],
    excess_prev: f64,
    force: f64,
}

impl Poroelastic {
    pub fn new(p: &PoroelasticParams) -> Self {
        let p = &p.poroelastic;
        let sr = p.indenter_radius_m.sqrt();
        Poroelastic {
            c0: 16.0 / 3.0 * p.shear_modulus_pa * sr,
            c_inf: 8.0 / 3.0 * p.shear_modulus_pa * sr / (1.0 - p.poisson_drained),
            radius: p.indenter_radius_m,
            diffusivity: p.diffusivity_m2_per_s,
            h: 1e-5,
            q: [0.0; RELAXATION.len()],
            excess_prev: 0.0,
            force: 0.0,
        }
    }

    /// The relaxation time a^2 / D at depth e, s.
    pub fn relaxation_time_s(&self, e: f64) -> f64 {
        self.radius * e.max(0.0) / self.diffusivity
    }
}

impl Law for Poroelastic {
    #[inline]
    fn prepare(&mut self, h: f64) {
        self.h = h;
    }

    #[inline]
    fn substep(&mut self, x: f64) -> f64 {
        let e = x;
        if e <= 0.0 {
            self.q = [0.0; RELAXATION.len()];
            self.excess_prev = 0.0;
            self.force = 0.0;
            return 0.0;
        }
        let e15 = e * e.sqrt();
        let drained = self.c_inf * e15;
        let excess = (self.c0 - self.c_inf) * e15;
        let d_excess = excess - self.excess_prev;
        self.excess_prev = excess;
        // normalized time of this sub-step: D h / a^2, a^2 = R e (slower for a larger contact)
        let ds = self.diffusivity * self.h / (self.radius * e);
        let mut relaxing = 0.0;
        for (q, (lambda, w)) in self.q.iter_mut().zip(RELAXATION) {
            *q = *q * (-lambda * ds).exp() + w * d_excess;
            relaxing += *q;
        }
        self.force = (drained + relaxing).max(0.0);
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

    fn gel() -> Poroelastic {
        match Material::repository("gel").law {
            LawParams::Poroelastic(p) => Poroelastic::new(&p),
            other => panic!("materials/gel.toml is {}", other.name()),
        }
    }

    /// Pressed quickly to a depth and held: the force starts near F_0, relaxes toward F_inf
    /// (ratio 2 (1 - nu)), follows Hu et al.'s g(D t / a^2) during the hold, and the time to
    /// relax half-way grows with the square of the contact radius: four times the depth, four
    /// times the time (a^2 = R e).
    #[test]
    fn relaxes_from_undrained_to_drained_slower_for_a_larger_contact() {
        let half_time = |depth: f64| {
            let mut g = gel();
            let h = 1e-5;
            g.prepare(h);
            let ramp = 2000; // 20 ms ramp: fast against a^2 / D
            for k in 1..=ramp {
                g.substep(depth * k as f64 / ramp as f64);
            }
            let f0 = g.force();
            let (fi, fz) = (g.c_inf * depth.powf(1.5), g.c0 * depth.powf(1.5));
            assert!(
                f0 > fi + 0.9 * (fz - fi),
                "close to undrained: {f0} vs {fz}"
            );
            let tau = g.relaxation_time_s(depth);
            let mut t = 0.5 * ramp as f64 * h; // the ramp's middle: when the step "happened"

            let mut half = None;
            while t < 3.0 * tau {
                let f = g.substep(depth);
                t += h;
                let s = g.diffusivity * t / (g.radius * depth);
                let expect = 0.491 * (-0.908 * s.sqrt()).exp() + 0.509 * (-1.679 * s).exp();
                let got = (f - fi) / (fz - fi);
                assert!((got - expect).abs() < 0.04, "t {t}: g {got} vs {expect}");
                if half.is_none() && got < 0.5 {
                    half = Some(t);
                }
            }
            (half.unwrap(), fz / fi)
        };
        let (t_shallow, ratio) = half_time(0.004);
        let (t_deep, _) = half_time(0.016);
        let nu = match Material::repository("gel").law {
            LawParams::Poroelastic(p) => p.poroelastic.poisson_drained,
            _ => unreachable!(),
        };
        assert!((ratio - 2.0 * (1.0 - nu)).abs() < 1e-9, "{ratio}");
        let r = t_deep / t_shallow;
        assert!(
            (r - 4.0).abs() < 0.3,
            "half-relaxation times {t_shallow} / {t_deep}: {r}"
        );
    }
}
