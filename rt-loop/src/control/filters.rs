//! The discrete filters of docs/physics.md, "The loop step", exactly as the thesis code runs them (forward Euler
//! with the measured period `dt`): the pseudo-derivative and the DOB/RFOB low-pass observers.
//! All are plain structs of f64: updating them allocates nothing and locks nothing.
//!
//! A bad step (issue 14): forward Euler multiplies the innovation by `g dt`; after a stall of
//! several milliseconds `g dt` is far above 1 (300 rad/s x 15 ms = 4.5), the update overshoots
//! by several times the innovation, the force estimate spikes and the current slams into its
//! clamp. So every update uses forward Euler only while `g dt <= EULER_MAX_GDT` (every normal
//! step: the thesis's numbers are unchanged bit for bit), and beyond it the exact
//! discretisation of the first-order lag, `1 - exp(-g dt)`, which never exceeds 1: after a
//! long stall the filter settles onto its input (re-initialises from the measured state)
//! instead of overshooting it.

use crate::params::LoopParams;

/// Largest `g dt` updated with forward Euler (beyond: exact discretisation). At the default
/// 10 kHz the largest gain (300 rad/s) gives 0.03; a step must last 8 periods to cross this.
pub const EULER_MAX_GDT: f64 = 0.25;

/// The fraction of the innovation one update of a first-order lag with gain `g` applies over
/// `dt`: forward Euler `g dt` for normal steps, `1 - exp(-g dt)` (< 1) for long ones.
#[inline]
pub fn lag_fraction(g: f64, dt: f64) -> f64 {
    let gdt = g * dt;
    if gdt <= EULER_MAX_GDT {
        gdt
    } else {
        -(-gdt).exp_m1()
    }
}

/// Pseudo-derivative `y = g s / (s + g) u`: `integ += y * dt; y = g * (u - integ)`.
#[derive(Clone, Debug)]
pub struct PseudoDerivative {
    pub gain: f64,
    integ: f64,
    out: f64,
    started: bool,
}

impl PseudoDerivative {
    pub fn new(gain: f64) -> Self {
        PseudoDerivative {
            gain,
            integ: 0.0,
            out: 0.0,
            started: false,
        }
    }

    /// Feeds one sample. The integrator starts at the first sample (not at 0), so a run that
    /// starts away from x = 0 (a replayed or imported series) does not begin with a spike.
    #[inline]
    pub fn update(&mut self, input: f64, dt: f64) -> f64 {
        if !self.started {
            self.started = true;
            self.integ = input;
        }
        // integ += out dt == integ += g dt (u_prev - integ): a first-order lag on the input
        if self.gain * dt <= EULER_MAX_GDT {
            self.integ += self.out * dt;
        } else if self.gain > 0.0 {
            self.integ += self.out / self.gain * lag_fraction(self.gain, dt);
        }
        self.out = self.gain * (input - self.integ);
        self.out
    }

    pub fn output(&self) -> f64 {
        self.out
    }
}

/// Velocity and acceleration from position, the two cascaded pseudo-derivatives of the loop.
/// The loop and the offline feature import share this one implementation.
#[derive(Clone, Debug)]
pub struct Kinematics {
    vel: PseudoDerivative,
    acc: PseudoDerivative,
}

impl Kinematics {
    pub fn new(g_v: f64, g_a: f64) -> Self {
        Kinematics {
            vel: PseudoDerivative::new(g_v),
            acc: PseudoDerivative::new(g_a),
        }
    }

    /// Returns (velocity, acceleration) for position `x` after a period `dt`.
    #[inline]
    pub fn update(&mut self, x: f64, dt: f64) -> (f64, f64) {
        let v = self.vel.update(x, dt);
        let a = self.acc.update(v, dt);
        (v, a)
    }
}

/// Disturbance observer: `lp += g (K_fn I + M_n g v - F_model - lp) dt; F_hat = lp - M_n g v`.
/// With `F_model = 0` it is the DOB (F_dis_hat); with the friction/internal-force model
/// subtracted it is the RFOB (F_ext_hat, the force response F_res).
#[derive(Clone, Debug)]
pub struct ForceObserver {
    pub gain: f64,
    m_n: f64,
    k_fn: f64,
    lp: f64,
    est: f64,
}

impl ForceObserver {
    pub fn new(gain: f64, m_n: f64, k_fn: f64) -> Self {
        ForceObserver {
            gain,
            m_n,
            k_fn,
            lp: 0.0,
            est: 0.0,
        }
    }

    /// `current` is the current that was applied during the last period.
    #[inline]
    pub fn update(&mut self, current: f64, v: f64, model_force: f64, dt: f64) -> f64 {
        let mgv = self.m_n * self.gain * v;
        let input = self.k_fn * current + mgv - model_force;
        if self.gain * dt <= EULER_MAX_GDT {
            self.lp += self.gain * (input - self.lp) * dt;
        } else {
            self.lp += (input - self.lp) * lag_fraction(self.gain, dt);
        }
        self.est = self.lp - mgv;
        self.est
    }

    pub fn estimate(&self) -> f64 {
        self.est
    }
}

/// The loop's state estimator: position, velocity, acceleration, DOB and RFOB.
#[derive(Clone, Debug)]
pub struct Estimator {
    pub kin: Kinematics,
    pub dob: ForceObserver,
    pub rfob: ForceObserver,
    friction_model: f64,
    friction: crate::control::friction::Friction,
    /// Whether the identified friction model is subtracted this step (the rig sets it: while
    /// the probe pushes against an object; see rig.rs).
    pub friction_active: bool,
}

/// One step's estimates.
#[derive(Clone, Copy, Debug, Default)]
pub struct Estimate {
    pub x: f64,
    pub v: f64,
    pub a: f64,
    pub f_dis: f64,
    pub f_ext: f64,
}

impl Estimator {
    pub fn new(p: &LoopParams) -> Self {
        Estimator {
            kin: Kinematics::new(p.g_v, p.g_a),
            dob: ForceObserver::new(p.g_dis, p.m_n, p.k_fn),
            rfob: ForceObserver::new(p.g_rec, p.m_n, p.k_fn),
            friction_model: p.friction_model,
            friction: p.friction,
            friction_active: true,
        }
    }

    /// `prev_current`: the current applied during the period that just ended.
    #[inline]
    pub fn update(&mut self, x: f64, dt: f64, prev_current: f64) -> Estimate {
        let (v, a) = self.kin.update(x, dt);
        let f_dis = self.dob.update(prev_current, v, 0.0, dt);
        // Coulomb model: sign(0) = 0, so a resting probe gets no friction compensation.
        let coulomb = if v > 0.0 {
            self.friction_model
        } else if v < 0.0 {
            -self.friction_model
        } else {
            0.0
        };
        // plus the identified Coulomb/Stribeck/viscous model (crate::control::friction), 0 by default
        let fric = if self.friction_active {
            coulomb + self.friction.force(v)
        } else {
            coulomb
        };
        let f_ext = self.rfob.update(prev_current, v, fric, dt);
        Estimate {
            x,
            v,
            a,
            f_dis,
            f_ext,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A ramp x = r t through the pseudo-derivative: the exact response of the discrete
    /// recursion converges to r (the continuous one is r (1 - e^{-g t})). Checked against the
    /// analytic continuous solution within the discretisation error.
    #[test]
    fn pseudo_derivative_ramp_matches_analytic_first_order_response() {
        let g = 30.0;
        let dt = 1e-4;
        let r = 0.01; // m/s
        let mut f = PseudoDerivative::new(g);
        f.update(0.0, 0.0);
        let mut worst: f64 = 0.0;
        for k in 1..=20_000 {
            let t = k as f64 * dt;
            let y = f.update(r * t, dt);
            let analytic = r * (1.0 - (-g * t).exp());
            worst = worst.max((y - analytic).abs());
        }
        // forward Euler error is O(g dt) relative: 30 * 1e-4 = 0.3 %, so 1 % of r is ample but
        // a wrong gain (e.g. 20 or 40) or a missing dt would be far outside it.
        assert!(worst < 0.01 * r, "worst deviation {worst}");
        assert!((f.output() - r).abs() < 1e-9);
    }

    /// A step in position gives the impulse-like response y = g * step * e^{-g t}.
    #[test]
    fn pseudo_derivative_step_decays_exponentially() {
        let g = 100.0;
        let dt = 1e-4;
        let mut f = PseudoDerivative::new(g);
        f.update(0.0, dt);
        let y0 = f.update(1.0, dt);
        assert!((y0 - g).abs() < 1e-9);
        for k in 1..500 {
            let y = f.update(1.0, dt);
            let t = k as f64 * dt;
            let analytic = g * (-g * t).exp();
            assert!((y - analytic).abs() < 0.01 * g, "k {k}: {y} vs {analytic}");
        }
    }

    /// A 20 ms stall (g dt = 6 for the DOB) moves each filter at most onto its input: no
    /// overshoot, where forward Euler would have overshot by five times the innovation.
    #[test]
    fn a_long_step_never_overshoots() {
        let mut obs = ForceObserver::new(300.0, 0.643, 24.0);
        for _ in 0..1000 {
            obs.update(0.1, 0.0, 0.0, 1e-4);
        }
        let before = obs.estimate();
        let after = obs.update(0.3, 0.0, 0.0, 0.02);
        assert!((before - 2.4).abs() < 1e-6, "{before}");
        assert!(after > before && after <= 0.3 * 24.0 + 1e-9, "{after}");
        let mut d = PseudoDerivative::new(100.0);
        for k in 0..1000 {
            d.update(1e-3 * k as f64 * 1e-4, 1e-4); // 1 mm/s
        }
        let v = d.update(1e-3 * 999e-4 + 1e-5, 0.02);
        assert!(v.is_finite() && v.abs() < 2.0 * 1e-3 * 100.0, "{v}");
        assert!(
            lag_fraction(300.0, 1e-4) == 300.0 * 1e-4,
            "normal steps are forward Euler"
        );
        assert!(lag_fraction(300.0, 0.01) < 1.0 && lag_fraction(300.0, 1.0) <= 1.0);
    }

    /// With a constant external force F on a free mass that the DOB knows exactly, the
    /// estimate approaches the true disturbance as 1 - e^{-g t} (first-order observer).
    #[test]
    fn dob_step_response_matches_first_order_lag() {
        let p = LoopParams::default();
        let dt = 1e-5; // fine step so the forward-Euler plant is close to continuous
        let (m, kf) = (p.m_n, p.k_fn);
        let current = 0.2; // A
        let f_dist = 2.0; // N opposing the motor: M a = K_f I - F
        let mut obs = ForceObserver::new(p.g_dis, m, kf);
        let (mut v, mut t) = (0.0, 0.0);
        let mut worst: f64 = 0.0;
        for _ in 0..20_000 {
            let a = (kf * current - f_dist) / m;
            v += a * dt;
            t += dt;
            let est = obs.update(current, v, 0.0, dt);
            let analytic = f_dist * (1.0 - (-p.g_dis * t).exp());
            worst = worst.max((est - analytic).abs());
        }
        assert!(worst < 0.01 * f_dist, "worst {worst}");
        // O(g dt) discretisation offset: M_n g a dt = 0.01 N here
        assert!((obs.estimate() - f_dist).abs() < 0.02);
    }

    /// The RFOB subtracts its friction model: with the model equal to the true Coulomb force,
    /// the estimate converges to the external force alone.
    #[test]
    fn rfob_removes_modelled_friction() {
        let p = LoopParams {
            friction_model: 0.8,
            ..LoopParams::default()
        };
        let dt = 1e-5;
        let mut est = Estimator::new(&p);
        let current = 0.3;
        let f_ext = 3.0;
        let (mut x, mut v) = (0.0, 0.0);
        let mut last = Estimate::default();
        for _ in 0..40_000 {
            let fric = if v > 0.0 { 0.8 } else { 0.0 };
            let a = (p.k_fn * current - f_ext - fric) / p.m_n;
            v += a * dt;
            x += v * dt;
            last = est.update(x, dt, current);
        }
        // DOB sees external + friction, RFOB the external force only (v > 0 by now).
        assert!((last.f_dis - 3.8).abs() < 0.05, "dob {}", last.f_dis);
        assert!((last.f_ext - 3.0).abs() < 0.05, "rfob {}", last.f_ext);
    }
}
