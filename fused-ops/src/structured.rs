//! `ai.haptics:StructuredStep`: one control step of train's `structured` model
//! (train/src/haptics_train/models/structured.py, `_parts`), the same arithmetic as its
//! hand-built graph (structured_graph.py) in one node.
//!
//! Contract (docs/model-contract.md, stateful): inputs `features` [1, n] (x is feature 0),
//! `h_in`, `c_in` [1, 1, H]; outputs `force` [1, 1], `h_out`, `c_out` [1, 1, H], with
//! H = K + M + 3: `h` carries [q_1..q_K Maxwell branches (those of fixed time, then the
//! depth-scaled ones, whose time grows with the compression), u_1..u_M Dahl states, set,
//! largest depth, previous e] as the multi-node graph's; `c` carries the equilibrium force at the
//! previous e in its first element, as the graph's, and then the low parts of the states that
//! integrate over millions of steps (below).
//!
//! Float-float state: a float32 state cannot hold the small steps of a slow integrator. The set
//! grows by dt / tau_grow (3e-4 at 10 kHz) of its distance to the target per step, so within
//! ulp(s) / 3e-4 of the target the float32 step rounds to nothing and the set stalls there
//! (measured: the multi-node graph and a float32-state kernel drift 2-3e-3 N from `predict`
//! over a 3-million-step recording). The previous e as well: a press held still moves e by the
//! set's growth alone, far below float32's resolution of e, so the rounding of a float32 e
//! turns the Dahl states' direction of motion into noise and they random-walk. `c` has
//! H = K + M + 3 elements of which the graph uses one, so it carries each such value's low part,
//! value - float32(value): `c` = [F_eq, F_eq low, set low, q_1 low..q_K low, previous e low
//! (when M >= 1: the Dahl states are its only reader), 0..]; a state written by the graph (low
//! parts 0) steps the same.
//!
//! The step is computed in f64 from the f32 state; the derived constants (decays
//! exp(-dt / tau), the poles' linear continuation, the set law's gains) are computed in f64 once
//! at kernel creation from the raw fitted values the attributes carry, where the multi-node
//! graph stores them rounded to f32 (a decay of 0.999999 for tau = 100 s at 10 kHz is 6 % off
//! in 1 - d as an f32).

use crate::attrs::{AttrError, Attrs, Reader};
use crate::math::Madd;
use crate::stateful::{split, StatefulStep, StepModel};

const OP: &str = "StructuredStep";

/// The compression-set law (present when the fitted largest set is above 0).
#[derive(Debug, Clone, PartialEq)]
struct SetLaw {
    /// target = c1 md^k
    c1: f64,
    k: f64,
    keep: f64,
    loaded_fraction: f64,
    /// growth and recovery gains per step, min(dt / tau, 1)
    kg: f64,
    kr: f64,
}

/// One pole of the equilibrium: a (u^-n - 1) + lin relu(e - 0.95 d), u = max(1 - e/d, 0.05).
#[derive(Debug, Clone, PartialEq)]
struct Pole {
    a: f64,
    inv_d: f64,
    neg_n: f64,
    /// -n when n is a whole number (the grid's 1, 2, 3): powi is several times cheaper than powf
    neg_n_int: Option<i32>,
    cap: f64,
    lin: f64,
}

/// Everything one step needs, parsed and derived once from the node's attributes.
#[derive(Debug, Clone, PartialEq)]
pub struct StructuredParams {
    /// (weight, 1 / yield length) per plateau tanh(e / y)
    plateaus: Vec<(f64, f64)>,
    poles: Vec<Pole>,
    /// (weight, 1 / D, exponent p) per indentation power (e / D)^p
    powers: Vec<(f64, f64, f64)>,
    /// (decay exp(-dt / tau), gain g) per Maxwell branch
    branches: Vec<(f64, f64)>,
    /// (-dt D / tau_k, gain g) per depth-scaled branch: its decay at compression e is
    /// exp(-dt D / tau_k / max(e, `depth_floor_m`)), and it is emptied out of contact
    depth_branches: Vec<(f64, f64)>,
    /// the compression under which a depth-scaled branch's time stops shrinking, m
    depth_floor_m: f64,
    /// (-1 / length, gain h on F_eq u, force hc of u alone) per Dahl hysteresis state
    hysteresis: Vec<(f64, f64, f64)>,
    set: Option<SetLaw>,
}

impl StepModel for StructuredParams {
    const OP: &'static str = OP;
    const MIN_FEATURES: usize = 1;

    /// Reads and checks the attributes (names as train's exporter writes them:
    /// structured_graph.py `structured_fused`).
    fn from_attrs<A: Attrs + ?Sized>(attrs: &A) -> Result<Self, AttrError> {
        let r = Reader { op: OP, attrs };
        let dt = r.positive("dt_s")?;

        let yield_m = r.positive_list("yield_m")?;
        let a_yield = r.list("a_yield")?;
        r.paired("a_yield", &a_yield, "yield_m", &yield_m)?;
        let plateaus = a_yield
            .iter()
            .zip(&yield_m)
            .map(|(&a, &y)| (a, 1.0 / y))
            .collect();

        let dens = r.positive_list("densification_m")?;
        let dexp = r.list("densification_exponent")?;
        let a_dens = r.list("a_densification")?;
        r.paired("densification_exponent", &dexp, "densification_m", &dens)?;
        r.paired("a_densification", &a_dens, "densification_m", &dens)?;
        let poles = dens
            .iter()
            .zip(&dexp)
            .zip(&a_dens)
            .map(|((&d, &n), &a)| Pole {
                a,
                inv_d: 1.0 / d,
                neg_n: -n,
                neg_n_int: (n.fract() == 0.0 && n.abs() <= 16.0).then_some(-n as i32),
                cap: 0.95 * d,
                lin: a * n / d * 20f64.powf(n + 1.0),
            })
            .collect();

        let taus = r.positive_list("taus_s")?;
        let gains = r.list("branch_gains")?;
        r.paired("branch_gains", &gains, "taus_s", &taus)?;
        let branches = taus
            .iter()
            .zip(&gains)
            .map(|(&t, &g)| ((-dt / t).exp(), g))
            .collect();

        // the indentation elements: absent on a model fitted without them
        let exps = r.list("power_exponents")?;
        let a_power = r.list("a_power")?;
        r.paired("a_power", &a_power, "power_exponents", &exps)?;
        let depth_taus = r.positive_list("depth_taus_s")?;
        let depth_gains = r.list("depth_gains")?;
        r.paired("depth_gains", &depth_gains, "depth_taus_s", &depth_taus)?;
        let (depth, floor) = if exps.is_empty() && depth_taus.is_empty() {
            (1.0, 0.0)
        } else {
            let floor = r.positive("depth_floor")?;
            (r.positive("depth_scale_m")?, floor)
        };
        let powers = a_power
            .iter()
            .zip(&exps)
            .map(|(&a, &p)| (a, 1.0 / depth, p))
            .collect();
        let depth_branches = depth_taus
            .iter()
            .zip(&depth_gains)
            .map(|(&t, &g)| (-dt * depth / t, g))
            .collect();

        let lengths = r.positive_list("hysteresis_m")?;
        let hg = r.list("hysteresis_gains")?;
        r.paired("hysteresis_gains", &hg, "hysteresis_m", &lengths)?;
        // a hysteresis of its own size (N): absent on a model fitted without one
        let mut hc = r.list("hysteresis_constant_n")?;
        if hc.is_empty() {
            hc = vec![0.0; lengths.len()];
        }
        r.paired("hysteresis_constant_n", &hc, "hysteresis_m", &lengths)?;
        let hysteresis = lengths
            .iter()
            .zip(&hg)
            .zip(&hc)
            .map(|((&l, &h), &c)| (-1.0 / l, h, c))
            .collect();

        let set_max = r.float("set_max_m")?;
        r.check("set_max_m", set_max, set_max >= 0.0, "negative")?;
        let set = if set_max > 0.0 {
            let k = r.positive("set_exponent")?;
            let keep = r.float("set_keep_fraction")?;
            r.check(
                "set_keep_fraction",
                keep,
                (0.0..=1.0).contains(&keep),
                "outside 0..1",
            )?;
            let lf = r.float("set_loaded_fraction")?;
            r.check(
                "set_loaded_fraction",
                lf,
                (0.0..=1.0).contains(&lf),
                "outside 0..1",
            )?;
            Some(SetLaw {
                c1: set_max / r.positive("set_reference_m")?.powf(k),
                k,
                keep,
                loaded_fraction: lf,
                kg: (dt / r.positive("set_tau_grow_s")?).min(1.0),
                kr: (dt / r.positive("set_tau_recover_s")?).min(1.0),
            })
        } else {
            None
        };
        Ok(Self {
            plateaus,
            poles,
            powers,
            branches,
            depth_branches,
            depth_floor_m: floor * depth,
            hysteresis,
            set,
        })
    }

    fn state_size(&self) -> usize {
        self.branches.len() + self.depth_branches.len() + self.hysteresis.len() + 3
    }

    /// Reads x (features[0]), `h_in`, `c_in`; writes the next state. Allocates nothing.
    fn step<M: Madd>(
        &mut self,
        features: &[f32],
        h_in: &[f32],
        c_in: &[f32],
        h_out: &mut [f32],
        c_out: &mut [f32],
    ) -> f32 {
        self.step_x(features[0], h_in, c_in, h_out, c_out)
    }
}

impl StructuredParams {
    /// F_eq at the compression `ec` >= 0.
    fn equilibrium(&self, ec: f64) -> f64 {
        let mut f = 0.0;
        for &(a, inv_y) in &self.plateaus {
            f += a * (ec * inv_y).tanh();
        }
        for p in &self.poles {
            let u = (1.0 - ec * p.inv_d).max(0.05);
            let pow = p.neg_n_int.map_or_else(|| u.powf(p.neg_n), |n| u.powi(n));
            f += p.a * (pow - 1.0) + p.lin * (ec - p.cap).max(0.0);
        }
        for &(a, inv_d, p) in &self.powers {
            f += a * (ec * inv_d).powf(p);
        }
        f
    }

    /// One step at x: reads `h_in`, `c_in`; writes the next state, returns the force.
    /// Allocates nothing. Slices have the lengths the contract gives (checked by the caller).
    pub fn step_x(
        &self,
        x: f32,
        h_in: &[f32],
        c_in: &[f32],
        h_out: &mut [f32],
        c_out: &mut [f32],
    ) -> f32 {
        // nk: every branch, of fixed time and depth-scaled (their states side by side)
        let nk = self.branches.len() + self.depth_branches.len();
        let nm = self.hysteresis.len();
        let x = f64::from(x);
        // c = [F_eq, F_eq low, set low, q low.., e low] (module doc: float-float state)
        let s = f64::from(h_in[nk + nm]) + f64::from(c_in[C_SET_LO]);
        let md = f64::from(h_in[nk + nm + 1]).max(x);
        let c_e_lo = C_Q_LO + nk; // < H when nm >= 1, the only case that reads it
        let e_prev =
            f64::from(h_in[nk + nm + 2]) + if nm > 0 { f64::from(c_in[c_e_lo]) } else { 0.0 };
        let s = match &self.set {
            None => s,
            Some(law) => {
                let target = law.c1 * if law.k == 1.0 { md } else { md.powf(law.k) };
                let loaded = x > (law.loaded_fraction * md).max(s);
                if loaded {
                    s + law.kg * (target - s).max(0.0)
                } else {
                    s - law.kr * (s - law.keep * target).max(0.0)
                }
            }
        };
        let e = x - s;
        let ec = e.max(0.0);
        let contact = if ec > 0.0 { 1.0 } else { 0.0 };
        let fe = self.equilibrium(ec);
        let dfeq = fe - (f64::from(c_in[C_FEQ]) + f64::from(c_in[C_FEQ_LO]));
        c_out.fill(0.0);

        let mut f = fe;
        for (i, &(decay, g)) in self.branches.iter().enumerate() {
            let q_prev = f64::from(h_in[i]) + f64::from(c_in[C_Q_LO + i]);
            let q = decay * q_prev + dfeq;
            (h_out[i], c_out[C_Q_LO + i]) = split(q);
            f += g * q;
        }
        if !self.depth_branches.is_empty() {
            // one division for every depth-scaled branch: exp(k / max(e, floor)), k = -dt D / tau
            let inv = 1.0 / ec.max(self.depth_floor_m);
            let first = self.branches.len();
            for (j, &(k, g)) in self.depth_branches.iter().enumerate() {
                let i = first + j;
                let r_prev = f64::from(h_in[i]) + f64::from(c_in[C_Q_LO + i]);
                // emptied out of contact (the multi-node graph's product with `contact`)
                let r = ((k * inv).exp() * r_prev + dfeq) * contact;
                (h_out[i], c_out[C_Q_LO + i]) = split(r);
                f += g * r;
            }
        }
        let de = ec - e_prev.max(0.0);
        let sg = if de > 0.0 {
            1.0
        } else if de < 0.0 {
            -1.0
        } else {
            0.0
        };
        for (m, &(neg_inv_l, h, hc)) in self.hysteresis.iter().enumerate() {
            let att = (de.abs() * neg_inv_l).exp();
            let u = (sg + att * (f64::from(h_in[nk + m]) - sg)) * contact;
            h_out[nk + m] = u as f32;
            f += (h * fe + hc) * u;
        }
        (h_out[nk + nm], c_out[C_SET_LO]) = split(s);
        h_out[nk + nm + 1] = md as f32;
        if nm > 0 {
            (h_out[nk + nm + 2], c_out[c_e_lo]) = split(e);
        } else {
            h_out[nk + nm + 2] = e as f32;
        }
        (c_out[C_FEQ], c_out[C_FEQ_LO]) = split(fe);
        (f.max(0.0) * contact) as f32
    }
}

/// Where `c` holds F_eq at the previous e (as the multi-node graph), its low part, the set's
/// low part and the branches' low parts (K of them), then the previous e's low part (with M >= 1
/// Dahl states: H = K + M + 3 >= K + 4 leaves room).
const C_FEQ: usize = 0;
const C_FEQ_LO: usize = 1;
const C_SET_LO: usize = 2;
const C_Q_LO: usize = 3;

/// The operator ONNX Runtime registers (`ai.haptics:StructuredStep`).
pub type StructuredStep = StatefulStep<StructuredParams>;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::attrs::tests::Map;

    /// One plateau 2 tanh(e / 10 mm), one branch (tau 0.5 s, gain 0.3), one Dahl state,
    /// no set, at 1 kHz.
    fn simple() -> Map {
        Map::of(&[
            ("dt_s", vec![1e-3]),
            ("yield_m", vec![0.01]),
            ("a_yield", vec![2.0]),
            ("taus_s", vec![0.5]),
            ("branch_gains", vec![0.3]),
            ("hysteresis_m", vec![0.002]),
            ("hysteresis_gains", vec![0.1]),
            ("set_max_m", vec![0.0]),
        ])
    }

    fn with(m: Map, name: &'static str, v: Vec<f32>) -> Map {
        m.with(name, v)
    }

    /// Steps `xs` from the zero state; the forces.
    fn run(p: &StructuredParams, xs: &[f32]) -> Vec<f32> {
        run_state(p, xs).0
    }

    /// Steps `xs` from the zero state; the forces and the last `h`, `c`.
    fn run_state(p: &StructuredParams, xs: &[f32]) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
        let h = p.state_size();
        let (mut hs, mut cs) = (vec![0.0f32; h], vec![0.0f32; h]);
        let (mut ho, mut co) = (vec![0.0f32; h], vec![0.0f32; h]);
        let forces = xs
            .iter()
            .map(|&x| {
                let f = p.step_x(x, &hs, &cs, &mut ho, &mut co);
                std::mem::swap(&mut hs, &mut ho);
                std::mem::swap(&mut cs, &mut co);
                f
            })
            .collect();
        (forces, hs, cs)
    }

    /// `simple()` with a set law of largest set `max_m` (reference 10 mm, linear), growing
    /// with `tau_grow`, at the step `dt`.
    fn with_set(dt: f32, max_m: f32, tau_grow: f32) -> StructuredParams {
        let law = [
            ("dt_s", vec![dt]),
            ("set_max_m", vec![max_m]),
            ("set_reference_m", vec![0.01]),
            ("set_exponent", vec![1.0]),
            ("set_tau_grow_s", vec![tau_grow]),
            ("set_tau_recover_s", vec![100.0]),
            ("set_loaded_fraction", vec![0.5]),
            ("set_keep_fraction", vec![0.8]),
        ];
        let mut m = simple();
        for (k, v) in law {
            m = with(m, k, v);
        }
        StructuredParams::from_attrs(&m).unwrap()
    }

    /// Checks the kernel's forces `got` along `xs` against `simple()`'s model written out by
    /// hand with the equilibrium `fe_of`: f = fe + 0.3 q + 0.1 fe u, 0 out of contact, plus
    /// `depth`'s branch (tau at D, D, gain) when given, its time tau max(e / D, 1e-3).
    fn check_by_hand(
        xs: &[f32],
        got: &[f32],
        fe_of: impl Fn(f64) -> f64,
        depth: Option<(f64, f64, f64)>,
    ) {
        let (d, mut q, mut r, mut u, mut fe_prev, mut e_prev) =
            ((-1e-3f64 / 0.5).exp(), 0.0, 0.0, 0.0, 0.0, 0.0f64);
        for (&x, &g) in xs.iter().zip(got) {
            let e = f64::from(x);
            let ec = e.max(0.0);
            let fe = fe_of(ec);
            q = d * q + fe - fe_prev;
            let mut relaxing = 0.3 * q;
            if let Some((tau, depth_m, gain)) = depth {
                let t = tau * (ec / depth_m).max(1e-3);
                r = if ec > 0.0 {
                    (-1e-3 / t).exp() * r + fe - fe_prev
                } else {
                    0.0
                };
                relaxing += gain * r;
            }
            fe_prev = fe;
            let de = ec - e_prev.max(0.0);
            e_prev = e;
            if ec <= 0.0 {
                u = 0.0;
            } else if de != 0.0 {
                let a = (-de.abs() / 0.002).exp();
                u = a * u + (1.0 - a) * de.signum();
            }
            let want = if ec > 0.0 {
                (fe + relaxing + 0.1 * fe * u).max(0.0)
            } else {
                0.0
            };
            assert!((f64::from(g) - want).abs() < 1e-5, "x {x}: {g} vs {want}");
        }
    }

    #[test]
    fn a_step_matches_the_model_written_out_by_hand() {
        let p = StructuredParams::from_attrs(&simple()).unwrap();
        assert_eq!(p.state_size(), 5);
        let xs: Vec<f32> = (0..400).map(|n| 0.004 * (n as f32 * 0.01).sin()).collect();
        let got = run(&p, &xs);
        // the same model, independently: f = fe + 0.3 q + 0.1 fe u, 0 out of contact
        check_by_hand(&xs, &got, |ec| 2.0 * (ec / 0.01).tanh(), None);
        assert!(got.iter().any(|&f| f > 0.5) && got.contains(&0.0));
    }

    /// `simple()` with the indentation elements: a Hertz power 1.5 (weight 3, D 20 mm) and one
    /// depth-scaled branch (tau 1 s at D, gain 0.4).
    fn indentation() -> Map {
        let mut m = simple();
        for (k, v) in [
            ("depth_scale_m", vec![0.02]),
            ("depth_floor", vec![1e-3]),
            ("power_exponents", vec![1.5]),
            ("a_power", vec![3.0]),
            ("depth_taus_s", vec![1.0]),
            ("depth_gains", vec![0.4]),
        ] {
            m = with(m, k, v);
        }
        m
    }

    #[test]
    fn a_depth_scaled_branch_relaxes_slower_the_deeper_and_empties_out_of_contact() {
        let p = StructuredParams::from_attrs(&indentation()).unwrap();
        assert_eq!(p.state_size(), 6); // q, r, u, set, largest depth, e
        let xs: Vec<f32> = (0..600).map(|n| 0.01 * (n as f32 * 0.012).sin()).collect();
        let got = run(&p, &xs);
        // the same model, independently: f = fe + 0.3 q + 0.4 r + 0.1 fe u
        let fe = |ec: f64| 2.0 * (ec / 0.01).tanh() + 3.0 * (ec / 0.02).powf(1.5);
        check_by_hand(&xs, &got, fe, Some((1.0, 0.02, 0.4)));
        // held after a step, the branch decays with the time of its depth: over 100 ms it
        // keeps exp(-0.1 / 0.8) = 0.88 of the step at 16 mm (tau 0.8 s), exp(-1) = 0.37 at 2 mm
        let held = |depth: f32| {
            let (_, hs, cs) = run_state(&p, &[vec![0.0; 1], vec![depth; 101]].concat());
            f64::from(hs[1]) + f64::from(cs[4])
        };
        let (fe16, fe2) = (
            2.0 * (1.6f64).tanh() + 3.0 * 0.8f64.powf(1.5),
            2.0 * (0.2f64).tanh() + 3.0 * 0.1f64.powf(1.5),
        );
        let (deep, shallow) = (held(0.016) / fe16, held(0.002) / fe2);
        assert!((deep - (-0.125f64).exp()).abs() < 1e-3, "{deep}");
        assert!((shallow - (-1.0f64).exp()).abs() < 1e-3, "{shallow}");
        // a model without the elements is the model before them
        let plain = StructuredParams::from_attrs(&simple()).unwrap();
        assert!(plain.powers.is_empty() && plain.depth_branches.is_empty());
    }

    #[test]
    fn the_set_law_moves_the_surface_only_when_present() {
        let p = with_set(1e-3, 0.002, 0.01);
        let plain = StructuredParams::from_attrs(&simple()).unwrap();
        let xs = vec![0.01f32; 200];
        let (set, no_set) = (run(&p, &xs), run(&plain, &xs));
        // held at 10 mm: the set grows toward 2 mm, so the compression and force fall below
        assert!(
            set[199] < no_set[199] - 0.1,
            "{} vs {}",
            set[199],
            no_set[199]
        );
    }

    #[test]
    fn a_slow_set_keeps_growing_where_a_float32_state_would_stall() {
        // 10 kHz, tau_grow 30 s: each step moves the set by 3.3e-6 of its distance to the
        // target, below float32's resolution within 0.4 % of it
        let p = with_set(1e-4, 0.003, 30.0);
        let (x, kg) = (0.01f32, f64::from(1e-4f32) / f64::from(30.0f32));
        let target = f64::from(0.003f32) / f64::from(0.01f32) * f64::from(x);
        let mut s_ref = 0.0f64;
        for _ in 0..1_000_000 {
            s_ref += kg * (target - s_ref);
        }
        let (_, hs, cs) = run_state(&p, &vec![x; 1_000_000]);
        let h = p.state_size();
        let s = f64::from(hs[h - 3]) + f64::from(cs[2]);
        assert!((s - s_ref).abs() < 1e-12, "set {s} vs float64 {s_ref}");
        assert!(
            (target - s_ref) > 1e-6,
            "still growing: the test exercises the slow tail"
        );
    }

    #[test]
    fn a_bad_attribute_is_a_clear_error_not_a_panic() {
        let cases = [
            (
                with(simple(), "taus_s", vec![-1.0]),
                "attribute `taus_s` = -1 is not positive",
            ),
            (
                with(simple(), "dt_s", vec![]),
                "attribute `dt_s` is missing or not a float",
            ),
            (
                with(simple(), "branch_gains", vec![0.3, 0.2]),
                "attribute `branch_gains` has 2 values, `taus_s` has 1: they pair up",
            ),
            (
                with(simple(), "a_yield", vec![f32::NAN]),
                "attribute `a_yield` = NaN is not finite",
            ),
            (
                with(simple(), "set_max_m", vec![0.001]),
                "attribute `set_exponent` is missing or not a float",
            ),
            (
                with(simple(), "set_max_m", vec![-0.001]),
                "attribute `set_max_m` = -0.0010000000474974513 is negative",
            ),
        ];
        for (attrs, want) in cases {
            let err = StructuredParams::from_attrs(&attrs)
                .unwrap_err()
                .to_string();
            assert_eq!(err, format!("StructuredStep: {want}"));
        }
    }

    #[test]
    fn absent_lists_are_empty_columns() {
        let mut m = simple();
        m.0.remove("yield_m");
        m.0.remove("a_yield");
        let m = with(
            with(
                with(m, "densification_m", vec![0.02]),
                "densification_exponent",
                vec![2.0],
            ),
            "a_densification",
            vec![0.5],
        );
        let p = StructuredParams::from_attrs(&m).unwrap();
        // past 0.95 d the pole continues linearly: finite, rising
        let f = run(&p, &[0.015, 0.0195, 0.025, 0.03]);
        assert!(
            f.iter().all(|v| v.is_finite()) && f.windows(2).all(|w| w[1] > w[0]),
            "{f:?}"
        );
    }

    /// A hysteresis of its own size adds hc u on top of the F_eq-scaled one: pressing (u
    /// rising to +1) the force is higher by hc u, releasing lower; absent, the kernel is the
    /// one before the attribute existed; a count that does not match is an error.
    #[test]
    fn a_constant_hysteresis_adds_its_own_force_in_contact_only() {
        let xs: Vec<f32> = (0..40)
            .map(|i| 0.001 * (if i < 20 { i } else { 40 - i }) as f32)
            .chain([-0.001, 0.002])
            .collect();
        let plain = StructuredParams::from_attrs(&simple()).unwrap();
        let with_hc =
            StructuredParams::from_attrs(&with(simple(), "hysteresis_constant_n", vec![0.5]))
                .unwrap();
        let zero =
            StructuredParams::from_attrs(&with(simple(), "hysteresis_constant_n", vec![0.0]))
                .unwrap();
        assert_eq!(plain, zero);
        let (a, b) = (run(&plain, &xs), run(&with_hc, &xs));
        // the Dahl state u of the one 2 mm length, written out: a 1 mm step moves it
        // 1 - exp(-0.5) of the way to the sign of the motion, and it is 0 out of contact
        let (mut u, mut e_prev) = (0.0f64, 0.0f64);
        for (i, &x) in xs.iter().enumerate() {
            let ec = f64::from(x).max(0.0);
            let de = ec - e_prev;
            let sg = de.signum() * f64::from(u8::from(de != 0.0));
            let contact = f64::from(u8::from(ec > 0.0));
            u = (sg + (-de.abs() / 0.002).exp() * (u - sg)) * contact;
            e_prev = ec; // the kernel's previous e, clamped at 0
            let want = (f64::from(a[i]) + 0.5 * u).max(0.0) * contact;
            // where the plain force is 0 the clamp may hide part of it: compare above 0
            if a[i] > 0.0 && want > 0.0 {
                assert!(
                    (f64::from(b[i]) - want).abs() < 1e-5,
                    "{i}: {} vs {want}",
                    b[i]
                );
            }
        }
        assert!(
            b[5] > a[5] && b[30] < a[30],
            "pressing {} {}, releasing {} {}",
            b[5],
            a[5],
            b[30],
            a[30]
        );
        assert_eq!(b[40], 0.0, "out of contact");
        let bad = with(simple(), "hysteresis_constant_n", vec![0.5, 0.5]);
        assert!(StructuredParams::from_attrs(&bad).is_err());
    }
}
