//! The passivity observer: the energy the rendered object has taken in from the hand, step by
//! step, and the forgetting of dissipated energy.
//!
//! Sign conventions (this loop's): x and v are positive INTO the object (the encoder counts up
//! as the probe is pressed in). The object's force F is in the RFOB's sign and the model's
//! (docs/model-contract.md): positive = the object pushes the probe back out, toward -x; the
//! loop commands F_cmd = -F (rig.rs). The power flowing from the hand into the object is
//! therefore p = F v (a press, v > 0, against a pushing object, F > 0, puts energy in), and the
//! object is passive when its energy E(t) = integral of F v dt, from rest, never goes below 0:
//! it never gives back more than it received.
//!
//! Discretisation: the force rendered at step k is held by the DAC until step k + 1, so the
//! work done on the object over that period is exactly F(k) (x(k+1) - x(k)) (Ryu, Kim and
//! Hannaford 2004, "Sampled- and continuous-time passivity and stability of virtual
//! environments"); the encoder's position is used rather than the filtered velocity so the
//! observer adds no filter lag and no integration error.
//!
//! Forgetting (the windowed-observer guard): a reserve of dissipated energy built up over a
//! long, mostly dissipative session would otherwise let the object return all of it at once
//! later without any damping. Stored energy must not be forgotten (a compressed spring gives
//! its energy back on release, legitimately), so only at a step where the object holds no force
//! (F = 0: nothing is stored in a force-displacement law) is the energy, then all dissipated,
//! cut to what the object received during the last `window_s` seconds.
//!
//! REAL-TIME PATH: fixed-size state, plain f64 arithmetic; no allocation, lock or syscall.

/// The window is kept as this many bins of received energy (a fixed array).
pub const BINS: usize = 32;

#[derive(Clone, Debug)]
pub struct EnergyObserver {
    /// E, J: the net energy into the object since the run began, less what was forgotten.
    energy: f64,
    /// Gross energy in (sum of the positive increments), J.
    received: f64,
    /// Gross energy out (sum of the negative increments, as a positive number), J.
    returned: f64,
    /// The part of E that the damper added (its F - F_object times the displacement), J.
    damper: f64,
    forgotten: f64,
    /// The lowest E of the run (without forgetting: received - returned), J.
    min_net: f64,
    bins: [f64; BINS],
    bin: usize,
    bin_elapsed: f64,
    bin_len: f64,
    window_sum: f64,
    x_prev: f64,
    f_prev: f64,
    f_object_prev: f64,
    started: bool,
}

impl EnergyObserver {
    pub fn new(window_s: f64) -> Self {
        EnergyObserver {
            energy: 0.0,
            received: 0.0,
            returned: 0.0,
            damper: 0.0,
            forgotten: 0.0,
            min_net: 0.0,
            bins: [0.0; BINS],
            bin: 0,
            bin_elapsed: 0.0,
            bin_len: window_s / BINS as f64,
            window_sum: 0.0,
            x_prev: 0.0,
            f_prev: 0.0,
            f_object_prev: 0.0,
            started: false,
        }
    }

    /// The period that just ended (`dt` long, the probe now at `x`): its work into the object.
    /// Returns E.
    #[inline]
    pub fn observe(&mut self, x: f64, dt: f64) -> f64 {
        if !self.started {
            return self.energy;
        }
        let dx = x - self.x_prev;
        let dw = self.f_prev * dx;
        self.energy += dw;
        self.damper += (self.f_prev - self.f_object_prev) * dx;
        if dw > 0.0 {
            self.received += dw;
            self.bins[self.bin] += dw;
            self.window_sum += dw;
        } else {
            self.returned -= dw;
        }
        let net = self.received - self.returned;
        if net < self.min_net {
            self.min_net = net;
        }
        self.bin_elapsed += dt;
        if self.bin_elapsed >= self.bin_len {
            self.bin_elapsed = 0.0;
            self.bin = (self.bin + 1) % BINS;
            self.bins[self.bin] = 0.0;
            // summed again at each turn: no drift from adding and subtracting
            self.window_sum = self.bins.iter().sum();
        }
        self.energy
    }

    /// The object holds no force this step: everything in E is dissipated energy; what is
    /// older than the window is forgotten (E cut to the energy received within the window).
    #[inline]
    pub fn forget_dissipated(&mut self) {
        if self.energy > self.window_sum {
            self.forgotten += self.energy - self.window_sum;
            self.energy = self.window_sum;
        }
    }

    /// The force rendered from this step on (`f`; the object's own was `f_object`) and where
    /// the probe is (`x`).
    #[inline]
    pub fn commit(&mut self, x: f64, f: f64, f_object: f64) {
        self.x_prev = x;
        self.f_prev = f;
        self.f_object_prev = f_object;
        self.started = true;
    }

    /// Where the probe was at the last committed step, m.
    pub fn last_x(&self) -> f64 {
        self.x_prev
    }
    pub fn energy(&self) -> f64 {
        self.energy
    }
    pub fn received(&self) -> f64 {
        self.received
    }
    pub fn returned(&self) -> f64 {
        self.returned
    }
    pub fn damper(&self) -> f64 {
        self.damper
    }
    pub fn forgotten(&self) -> f64 {
        self.forgotten
    }
    pub fn min_net(&self) -> f64 {
        self.min_net
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A spring pressed and released gives back what it received: E returns to 0; a held force
    /// over a displacement is exactly F dx.
    #[test]
    fn a_spring_cycle_nets_zero_and_work_is_force_times_displacement() {
        let mut o = EnergyObserver::new(1.0);
        let k = 1000.0;
        let dt = 1e-4;
        let n = 2000;
        let xs: Vec<f64> = (0..=2 * n)
            .map(|i| 0.01 * (std::f64::consts::PI * i as f64 / (2 * n) as f64).sin())
            .collect();
        for &x in &xs {
            o.observe(x, dt);
            o.commit(x, k * x, k * x);
        }
        // the ZOH lag makes the discrete spring dissipate a little (F(k) dx(k+1) < integral)
        let peak = 0.5 * k * 0.01f64.powi(2);
        assert!(o.energy().abs() < 0.01 * peak, "{} vs {peak}", o.energy());
        assert!((o.received() - peak).abs() < 0.01 * peak);
        let mut o = EnergyObserver::new(1.0);
        o.commit(0.0, 2.0, 2.0);
        assert_eq!(o.observe(0.003, dt), 2.0 * 0.003);
    }

    /// Dissipated energy is forgotten only when the object holds no force, and only beyond what
    /// it received within the window.
    #[test]
    fn forgetting_keeps_the_window_and_never_stored_energy() {
        let mut o = EnergyObserver::new(0.32); // bins of 10 ms
        let dt = 1e-3;
        // 1 J received at the start
        o.commit(0.0, 100.0, 100.0);
        o.observe(0.01, dt);
        o.commit(0.01, 0.0, 0.0);
        assert!((o.energy() - 1.0).abs() < 1e-12);
        // within the window: nothing forgotten
        o.forget_dissipated();
        assert!((o.energy() - 1.0).abs() < 1e-12);
        // 0.5 s later (beyond the window), unloaded: all forgotten
        for _ in 0..500 {
            o.observe(0.01, dt);
            o.commit(0.01, 0.0, 0.0);
        }
        o.forget_dissipated();
        assert_eq!(o.energy(), 0.0);
        assert!((o.forgotten() - 1.0).abs() < 1e-12);
        // a negative E (a debt) is never forgotten
        o.commit(0.01, 100.0, 100.0);
        o.observe(0.0, dt);
        o.forget_dissipated();
        assert!((o.energy() + 1.0).abs() < 1e-12);
        assert!(
            (o.min_net() - 0.0).abs() < 1e-12,
            "net = 1 - 1 = 0 J at the lowest"
        );
    }
}
