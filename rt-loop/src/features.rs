//! The nine features of docs/features.md (thesis Table 3.1), computed the same way online (one
//! call pair per loop step, no allocation) and offline (over a recording or an imported series,
//! by the very same code).
//!
//! Per step t: `begin(x, v, a)` gives the feature vector from the current kinematics and the
//! force committed at t-1; `commit(x, F)` then hands it the step's force (F_res, or the model's
//! own prediction in reproduction), which drives the ratios of the next step and the cycle
//! segmentation.
//!
//! Rules:
//! - `f_previous_*` = F(t-1) / divisor; on a divisor exactly 0 the ratio keeps its previous
//!   value (thesis code); before the first committed force all three are 0.
//! - Cycle segmentation uses the force with hysteresis thresholds: a cycle becomes "loaded"
//!   when F rises above `contact_on_n` and ends on the step F falls below `contact_off_n`. At
//!   that step the cycle's F-x loop area (trapezoid integral of F dx since the previous cycle
//!   end: positive for a dissipative loop) and its permanent deformation (x at the release
//!   crossing: where the object stops pushing back) become the `area_fx` / `deformation`
//!   features, and `cycle_no` counts up. Cycle 1 has deformation 0 and area 0.

use crate::invalid::InvalidSetting;
use serde::{Deserialize, Serialize};

/// The feature names in the order of thesis Table 3.1 (and of [`Features::as_array`]).
/// One list for the whole system: haptics-proto's.
pub const FEATURE_NAMES: [&str; 9] = haptics_proto::THESIS_FEATURES;

/// The names the loop publishes to a served model (the shared-memory segment's schema, in
/// [`Features::as_schema_array`] order): the nine of thesis Table 3.1, then `f_previous`
/// = F(t-1), the force committed the step before, in N. Not a recorded column: train/
/// derives it from a recording (`haptics_train.data.add_previous_force`). haptics-proto's.
pub const SCHEMA_NAMES: [&str; 10] = haptics_proto::SCHEMA_NAMES;

#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[repr(C)]
pub struct Features {
    pub position_x: f64,
    pub velocity: f64,
    pub acceleration: f64,
    pub f_previous_x: f64,
    pub f_previous_v: f64,
    pub f_previous_a: f64,
    pub cycle_no: u32,
    pub deformation: f64,
    pub area_fx: f64,
    /// F(t-1), N: the force committed the step before (0 before the first).
    pub f_previous: f64,
}

impl Features {
    /// The values of [`SCHEMA_NAMES`], in that order (what the shared-memory client sends).
    #[inline]
    pub fn as_schema_array(&self) -> [f64; 10] {
        let n = self.as_array();
        [
            n[0],
            n[1],
            n[2],
            n[3],
            n[4],
            n[5],
            n[6],
            n[7],
            n[8],
            self.f_previous,
        ]
    }

    /// The nine values as f64 in [`FEATURE_NAMES`] order (what a model client copies into its
    /// input slot).
    #[inline]
    pub fn as_array(&self) -> [f64; 9] {
        [
            self.position_x,
            self.velocity,
            self.acceleration,
            self.f_previous_x,
            self.f_previous_v,
            self.f_previous_a,
            self.cycle_no as f64,
            self.deformation,
            self.area_fx,
        ]
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FeatureParams {
    /// Force above which a cycle counts as loaded, N.
    pub contact_on_n: f64,
    /// Force below which a loaded cycle ends, N.
    pub contact_off_n: f64,
}

impl Default for FeatureParams {
    fn default() -> Self {
        FeatureParams {
            contact_on_n: 0.5,
            contact_off_n: 0.25,
        }
    }
}

impl FeatureParams {
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        if !(self.contact_off_n.is_finite()
            && self.contact_on_n.is_finite()
            && self.contact_off_n < self.contact_on_n)
        {
            return Err("features.contact_off_n must be below features.contact_on_n".into());
        }
        Ok(())
    }
}

/// Fraction of the force range below which contact cannot be told from rest: thresholds are
/// at least this far above zero (the loop's 0.25 / 0.5 N are 2.5 / 5 % of the bench's ~10 N).
pub const CONTACT_OFF_RANGE_FRACTION: f64 = 0.025;
/// Contact ends this many noise standard deviations above zero (at the least).
pub const CONTACT_OFF_NOISE_SIGMAS: f64 = 3.0;

/// The force's noise floor, N: a robust standard deviation (1.4826 x the median absolute
/// deviation) of the second differences, divided by sqrt(6) (the second difference of white
/// noise has variance 6 sigma^2; a smooth signal's second differences are small). Non-finite
/// samples are skipped; fewer than 3 samples give 0.
pub fn force_noise_floor(force: &[f64]) -> f64 {
    let mut d2: Vec<f64> = force
        .windows(3)
        .map(|w| w[2] - 2.0 * w[1] + w[0])
        .filter(|v| v.is_finite())
        .collect();
    if d2.is_empty() {
        return 0.0;
    }
    let med = median(&mut d2);
    let mut dev: Vec<f64> = d2.iter().map(|v| (v - med).abs()).collect();
    1.4826 * median(&mut dev) / 6f64.sqrt()
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

impl FeatureParams {
    /// Contact thresholds from a series' own force (offline import): contact ends at
    /// max(3 sigma, 2.5 % of the force's 1-99 percentile range) and starts at twice that, so
    /// the noise at rest never counts as contact and the hysteresis is as wide as the loop's.
    /// Returns the parameters and the noise floor sigma (N).
    pub fn from_force(force: &[f64]) -> (FeatureParams, f64) {
        let sigma = force_noise_floor(force);
        let mut f: Vec<f64> = force.iter().cloned().filter(|v| v.is_finite()).collect();
        let range = if f.is_empty() {
            0.0
        } else {
            f.sort_by(|a, b| a.total_cmp(b));
            let q = |p: f64| f[((f.len() - 1) as f64 * p).round() as usize];
            q(0.99) - q(0.01)
        };
        let off = (CONTACT_OFF_NOISE_SIGMAS * sigma).max(CONTACT_OFF_RANGE_FRACTION * range);
        let off = if off > 0.0 {
            off
        } else {
            FeatureParams::default().contact_off_n
        };
        (
            FeatureParams {
                contact_on_n: 2.0 * off,
                contact_off_n: off,
            },
            sigma,
        )
    }
}

#[derive(Clone, Debug)]
pub struct FeatureExtractor {
    p: FeatureParams,
    prev_force: f64,
    has_prev: bool,
    f_px: f64,
    f_pv: f64,
    f_pa: f64,
    cycle_no: u32,
    deformation: f64,
    area: f64,
    loaded: bool,
    area_acc: f64,
    seg_x: f64,
    seg_f: f64,
}

impl FeatureExtractor {
    pub fn new(p: FeatureParams) -> Self {
        FeatureExtractor {
            p,
            prev_force: 0.0,
            has_prev: false,
            f_px: 0.0,
            f_pv: 0.0,
            f_pa: 0.0,
            cycle_no: 1,
            deformation: 0.0,
            area: 0.0,
            loaded: false,
            area_acc: 0.0,
            seg_x: 0.0,
            seg_f: 0.0,
        }
    }

    /// Features of this step from its kinematics and the force committed last step.
    #[inline]
    pub fn begin(&mut self, x: f64, v: f64, a: f64) -> Features {
        if self.has_prev {
            let f = self.prev_force;
            if x != 0.0 {
                self.f_px = f / x;
            }
            if v != 0.0 {
                self.f_pv = f / v;
            }
            if a != 0.0 {
                self.f_pa = f / a;
            }
        }
        Features {
            position_x: x,
            velocity: v,
            acceleration: a,
            f_previous_x: self.f_px,
            f_previous_v: self.f_pv,
            f_previous_a: self.f_pa,
            cycle_no: self.cycle_no,
            deformation: self.deformation,
            area_fx: self.area,
            f_previous: if self.has_prev { self.prev_force } else { 0.0 },
        }
    }

    /// Hands over this step's force (at position `x`).
    #[inline]
    pub fn commit(&mut self, x: f64, force: f64) {
        // A NaN force (e.g. an imported gap) must not poison the loop area for good.
        let f = if force.is_finite() { force } else { 0.0 };
        if self.has_prev {
            self.area_acc += 0.5 * (f + self.seg_f) * (x - self.seg_x);
        }
        if !self.loaded && f > self.p.contact_on_n {
            self.loaded = true;
        } else if self.loaded && f < self.p.contact_off_n {
            self.loaded = false;
            self.area = self.area_acc;
            self.deformation = x;
            self.area_acc = 0.0;
            self.cycle_no += 1;
        }
        self.seg_x = x;
        self.seg_f = f;
        self.prev_force = force;
        self.has_prev = true;
    }

    pub fn cycle_no(&self) -> u32 {
        self.cycle_no
    }
}

/// One row of offline kinematics and features.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct OfflineRow {
    pub velocity: f64,
    pub acceleration: f64,
    pub features: Features,
}

/// Offline computation over a whole series (position m, period s, force N), with the same
/// pseudo-derivative filters and feature code as the loop. `dt[0]` is ignored (the loop's
/// first step has no period).
pub fn compute_offline(
    x: &[f64],
    dt: &[f64],
    force: &[f64],
    g_v: f64,
    g_a: f64,
    p: &FeatureParams,
) -> Vec<OfflineRow> {
    let mut kin = crate::control::filters::Kinematics::new(g_v, g_a);
    let mut fx = FeatureExtractor::new(p.clone());
    let mut out = Vec::with_capacity(x.len());
    for i in 0..x.len() {
        let d = if i == 0 { 0.0 } else { dt[i] };
        let (v, a) = kin.update(x[i], d);
        let features = fx.begin(x[i], v, a);
        fx.commit(x[i], force[i]);
        out.push(OfflineRow {
            velocity: v,
            acceleration: a,
            features,
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ratios_hold_last_value_on_zero_divisors() {
        let mut fx = FeatureExtractor::new(FeatureParams::default());
        let f0 = fx.begin(0.0, 0.0, 0.0);
        assert_eq!(
            (f0.f_previous_x, f0.f_previous_v, f0.f_previous_a),
            (0.0, 0.0, 0.0)
        );
        fx.commit(0.0, 2.0);
        let f1 = fx.begin(0.01, 0.5, 4.0);
        assert_eq!(f1.f_previous_x, 2.0 / 0.01);
        assert_eq!(f1.f_previous_v, 2.0 / 0.5);
        assert_eq!(f1.f_previous_a, 2.0 / 4.0);
        fx.commit(0.01, 3.0);
        let f2 = fx.begin(0.0, 0.0, -2.0);
        assert_eq!(f2.f_previous_x, 200.0, "held");
        assert_eq!(f2.f_previous_v, 4.0, "held");
        assert_eq!(f2.f_previous_a, 3.0 / -2.0, "updated");
        assert_eq!(
            (f0.f_previous, f1.f_previous, f2.f_previous),
            (0.0, 2.0, 3.0)
        );
        assert_eq!(f2.as_schema_array()[9], 3.0);
        assert_eq!(f2.as_schema_array()[..9], f2.as_array());
        assert_eq!(SCHEMA_NAMES[..9], FEATURE_NAMES);
    }

    #[test]
    fn contact_thresholds_follow_the_noise_floor_and_the_range() {
        // a clean 1.2 N cycle: 2.5 % of the range
        let f: Vec<f64> = (0..1000)
            .map(|i| 1.2 * (std::f64::consts::PI * i as f64 / 999.0).sin())
            .collect();
        let (p, sigma) = FeatureParams::from_force(&f);
        assert!(sigma < 1e-4, "{sigma}");
        assert!((p.contact_off_n - 0.03).abs() < 1e-3, "{p:?}");
        assert_eq!(p.contact_on_n, 2.0 * p.contact_off_n);
        // the same with 0.02 N Gaussian noise (Box-Muller on a small LCG): 3 sigma dominates
        let mut state: u64 = 12345;
        let mut uniform = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        let noisy: Vec<f64> = f
            .iter()
            .map(|v| {
                let (u1, u2) = (uniform(), uniform());
                v + 0.02 * (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
            })
            .collect();
        let sigma = force_noise_floor(&noisy);
        assert!((sigma - 0.02).abs() < 0.003, "{sigma}");
        let (p, _) = FeatureParams::from_force(&noisy);
        assert!((p.contact_off_n - 3.0 * sigma).abs() < 1e-12, "{p:?}");
        assert!(p.validate().is_ok());
    }

    /// A synthetic loop: load along F = k x, unload along F = k (x - d) (a set d). The area
    /// is the exact parallelogram-ish region, the deformation is d, the cycle counts up.
    #[test]
    fn cycle_area_and_deformation_of_a_known_loop() {
        let mut fx = FeatureExtractor::new(FeatureParams::default());
        let (k, xm, d) = (500.0, 0.02, 0.004);
        let n = 10_000;
        let mut feed = |x: f64, f: f64| {
            let feats = fx.begin(x, 0.0, 0.0);
            fx.commit(x, f);
            feats
        };
        for i in 0..=n {
            let x = xm * i as f64 / n as f64;
            feed(x, k * x);
        }
        for i in 0..=n {
            let x = xm - (xm - d) * i as f64 / n as f64;
            feed(x, (k * (x - d)).max(0.0));
        }
        let after = feed(d, 0.0);
        assert_eq!(after.cycle_no, 2);
        // area = 1/2 k xm^2 - 1/2 k (xm - d)^2 (loading work minus returned work)
        // ... up to the release crossing at x = d + 0.25 / k, where the cycle closes
        let tail = 0.25 / k;
        let exact = 0.5 * k * xm * xm - 0.5 * k * (xm - d) * (xm - d) + 0.5 * k * tail * tail;
        assert!(
            (after.area_fx - exact).abs() < 1e-3 * exact,
            "{} vs {exact}",
            after.area_fx
        );
        // the cycle ends where F drops under 0.25 N: x = d + 0.25 / k
        assert!((after.deformation - (d + 0.25 / k)).abs() < 1e-5);
        assert!(after.area_fx > 0.0);
    }
}
