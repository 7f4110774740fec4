//! `ai.haptics:LawFreeStep`: one control step of train's `lawfree` model
//! (train/src/haptics_train/models/lawfree.py, `predict_served`), the arithmetic of its
//! hand-built graph (lawfree_graph.py) in one node.
//!
//! Contract (docs/model-contract.md, stateful): inputs `features` [1, n] (x, v the first two),
//! `h_in`, `c_in` [1, 1, H]; outputs `force` [1, 1], `h_out`, `c_out` [1, 1, H], with H = K + P
//! (+ 1): `h` carries [s_1..s_K filters, p_1..p_P plays (, u_max)] (the multi-node graph's
//! layout; u_max, the deepest compression so far, only with the irreversible memory,
//! `damage_frac`). The filters' coefficients arrive as the float32 values `predict` uses, the
//! rest is computed in f64.
//!
//! `c`, which the multi-node graph passes through unused, carries the filters' low parts,
//! s_k - float32(s_k) (then zeros): a slow filter (tau = 100 s at 10 kHz: a = 0.999999) moves by
//! a millionth of its input per step, below float32's resolution of its state, so a float32
//! state drifts from `predict` (measured: 7-10e-3 N over a 3-million-step recording).
//!
//! The readout may add a small network (attributes `net_w1`, `net_b1`, `net_w2`, `net_b2`,
//! `net_w3`, `net_b3`; all absent in models exported before it: the linear readout alone):
//! g = b3 + w3 . tanh(b2 + W2 tanh(b1 + W1 [q, w])), two tanh layers of H units over the
//! readout's inputs q and w = min(u, 1), added to the force before the contact's clamp. Why: a
//! readout linear in its weights cannot follow a memory whose relaxation depends on the force
//! it carries (an Eyring/sinh dashpot relaxes faster the harder it is pushed); train keeps the
//! network only where validation prefers it, and exports it (standardisation folded into W1,
//! b1) from lawfree_graph.py `lawfree_fused`. The memories step exactly as without it.

use crate::attrs::{AttrError, Attrs, Reader};
use crate::math::Madd;
use crate::stateful::{split, StatefulStep, StepModel};

const OP: &str = "LawFreeStep";

/// At most this many saturating depth functions in the readout (train exports 2): their values
/// are computed once per step into a fixed array, so a step allocates nothing.
pub const MAX_DEPTH_SCALES: usize = 8;

/// At most this many hidden units per layer of the readout's network: a step holds its layers
/// in fixed arrays, so it allocates nothing.
pub const MAX_NET_HIDDEN: usize = 64;
/// At most this many network inputs (n + 1: q and w), held in a fixed array likewise.
pub const MAX_NET_INPUTS: usize = 64;

/// The readout's network g(q, w) (module doc): weights stored by columns (one input's weights
/// to every unit, contiguous), so a layer is a sum of scaled columns, an axpy over its units
/// that the compiler vectorises (a row-by-row dot product is a reduction it may not reorder);
/// each unit still adds its inputs in order, as the row-major product would.
#[derive(Debug, Clone, PartialEq)]
struct Net {
    /// W1's columns: `w1_t[i * H + j]` = W1[j, i], i over [q_1..q_n, w]
    w1_t: Vec<f64>,
    b1: Vec<f64>,
    /// W2's columns: `w2_t[i * H + j]` = W2[j, i]
    w2_t: Vec<f64>,
    b2: Vec<f64>,
    w3: Vec<f64>,
    b3: f64,
}

impl Net {
    /// The six `net_*` attributes for a readout of `n` inputs: all absent (`None`) or all
    /// present, H = `net_b1`'s length, each shape checked.
    fn from_attrs<A: Attrs + ?Sized>(
        r: &Reader<'_, A>,
        n: usize,
    ) -> Result<Option<Self>, AttrError> {
        const NAMES: [&str; 6] = ["net_w1", "net_b1", "net_w2", "net_b2", "net_w3", "net_b3"];
        // ONNX cannot write an empty FLOATS, so empty = absent (`list` reads absent as empty)
        let [w1, b1, w2, b2, w3, b3] = NAMES.map(|name| r.list(name));
        let [w1, b1, w2, b2, w3, b3] = [w1?, b1?, w2?, b2?, w3?, b3?];
        let lists = [&w1, &b1, &w2, &b2, &w3, &b3];
        if lists.iter().all(|v| v.is_empty()) {
            return Ok(None);
        }
        if let Some(i) = lists.iter().position(|v| v.is_empty()) {
            return Err(AttrError::Missing {
                op: OP,
                name: NAMES[i],
                kind: "list of floats (the six net_* attributes come together)",
            });
        }
        let h = b1.len();
        if h > MAX_NET_HIDDEN {
            return Err(r.invalid("net_b1", h as f64, "more hidden units than the kernel's 64"));
        }
        if n + 1 > MAX_NET_INPUTS {
            return Err(r.invalid(
                "net_w1",
                (n + 1) as f64,
                "more network inputs (readout inputs + 1) than the kernel's 64",
            ));
        }
        let length = |name, v: &Vec<f64>, other, expected| {
            if v.len() == expected {
                return Ok(());
            }
            Err(AttrError::Length {
                op: OP,
                name,
                got: v.len(),
                other,
                expected,
            })
        };
        length(
            "net_w1",
            &w1,
            "net_b1 x (2 + filter_decay + play_widths (+ 1 + damage_frac) + 1)",
            h * (n + 1),
        )?;
        length("net_w2", &w2, "net_b1 x net_b1", h * h)?;
        length("net_b2", &b2, "net_b1", h)?;
        length("net_w3", &w3, "net_b1", h)?;
        length("net_b3", &b3, "one bias", 1)?;
        let columns = |w: &[f64], cols: usize| -> Vec<f64> {
            (0..cols * h).map(|k| w[(k % h) * cols + k / h]).collect()
        };
        Ok(Some(Self {
            w1_t: columns(&w1, n + 1),
            b1,
            w2_t: columns(&w2, h),
            b2,
            w3,
            b3: b3[0],
        }))
    }

    /// g at the inputs `x` = [q_1..q_n, w]. Allocates nothing.
    #[inline]
    fn eval(&self, x: &[f64]) -> f64 {
        let h = self.b1.len();
        let (mut h1, mut h2) = ([0.0f64; MAX_NET_HIDDEN], [0.0f64; MAX_NET_HIDDEN]);
        let (h1, h2) = (&mut h1[..h], &mut h2[..h]);
        layer(&self.w1_t, &self.b1, x, h1);
        layer(&self.w2_t, &self.b2, h1, h2);
        self.b3
            + self
                .w3
                .iter()
                .zip(h2.iter())
                .map(|(a, b)| a * b)
                .sum::<f64>()
    }
}

/// `y = tanh(b + W x)`, W by columns (each `y.len()` long).
#[inline(always)]
fn layer(w_t: &[f64], b: &[f64], x: &[f64], y: &mut [f64]) {
    y.copy_from_slice(b);
    for (col, &xi) in w_t.chunks_exact(y.len()).zip(x) {
        for (a, &w) in y.iter_mut().zip(col) {
            *a += w * xi;
        }
    }
    y.iter_mut().for_each(|a| *a = a.tanh());
}

/// Everything one step needs, parsed once from the node's attributes.
#[derive(Debug, Clone, PartialEq)]
pub struct LawFreeParams {
    inv_depth: f64,
    inv_speed: f64,
    /// (a_k, b_k): s' = a s + b u
    filters: Vec<(f64, f64)>,
    /// half-widths r (in units of u)
    plays: Vec<f64>,
    /// the readout's weights per input q_j: (w1, w2, w3) of 1, w, w^2, q = [u, v/V, u - s..,
    /// u - p..]
    readout: Vec<[f64; 3]>,
    /// -1/a_s of the saturating depth functions 1 - exp(-w/a_s) (`readout_depth_scales`;
    /// absent in models exported before them: none)
    neg_inv_scales: Vec<f64>,
    /// their weights, input by input: `sat[j * S + s]`
    sat: Vec<f64>,
    /// the irreversible memory's scales c (`damage_frac`; empty: none): inputs d = u - u_max
    /// and c (1 - exp(d / c)) after the plays'
    damage: Vec<f64>,
    /// the readout's network over [q, w], added to the linear readout (`net_*`; absent in
    /// models exported before it, or where train's validation kept the linear readout: none)
    net: Option<Net>,
}

impl StepModel for LawFreeParams {
    const OP: &'static str = OP;
    const MIN_FEATURES: usize = 2;

    /// Reads and checks the attributes (names as lawfree_graph.py `lawfree_fused` writes them).
    fn from_attrs<A: Attrs + ?Sized>(attrs: &A) -> Result<Self, AttrError> {
        let r = Reader { op: OP, attrs };
        let depth = r.positive("depth_scale_m")?;
        let speed = r.positive("speed_scale_mps")?;
        let a = r.list("filter_decay")?;
        for &x in &a {
            r.check("filter_decay", x, (0.0..=1.0).contains(&x), "outside 0..1")?;
        }
        let b = r.list("filter_gain")?;
        r.paired("filter_gain", &b, "filter_decay", &a)?;
        let plays = r.positive_list("play_widths")?;
        let scales = r.positive_list("readout_depth_scales")?;
        if scales.len() > MAX_DEPTH_SCALES {
            return Err(r.invalid(
                "readout_depth_scales",
                scales.len() as f64,
                "more values than the kernel's 8",
            ));
        }
        let damage = r.positive_list("damage_frac")?;
        let w = r.list("readout")?;
        let n_damage = if damage.is_empty() {
            0
        } else {
            1 + damage.len()
        };
        let n = 2 + a.len() + plays.len() + n_damage;
        let blocks = 3 + scales.len();
        if w.len() != blocks * n {
            return Err(AttrError::Length {
                op: OP,
                name: "readout",
                got: w.len(),
                other: "(3 + readout_depth_scales) x (2 + filter_decay + play_widths (+ 1 + damage_frac))",
                expected: blocks * n,
            });
        }
        let net = Net::from_attrs(&r, n)?;
        let ns = scales.len();
        Ok(Self {
            inv_depth: 1.0 / depth,
            inv_speed: 1.0 / speed,
            filters: a.into_iter().zip(b).collect(),
            plays,
            readout: (0..n).map(|j| [w[j], w[n + j], w[2 * n + j]]).collect(),
            neg_inv_scales: scales.iter().map(|a| -1.0 / a).collect(),
            sat: (0..n * ns).map(|i| w[(3 + i % ns) * n + i / ns]).collect(),
            damage,
            net,
        })
    }

    fn state_size(&self) -> usize {
        self.filters.len() + self.plays.len() + usize::from(!self.damage.is_empty())
    }

    /// Reads x, v (features[0..2]), `h_in` and the filters' low parts in `c_in`.
    fn step<M: Madd>(
        &mut self,
        features: &[f32],
        h_in: &[f32],
        c_in: &[f32],
        h_out: &mut [f32],
        c_out: &mut [f32],
    ) -> f32 {
        self.step_xv(features[0], features[1], h_in, c_in, h_out, c_out)
    }
}

impl LawFreeParams {
    /// One step from (x, v) and `h_in`; writes `h_out`, returns the force. Allocates nothing.
    /// (`#[inline]`: compiled into the operator's step, for AVX2 where the CPU has it.)
    #[inline]
    pub fn step_xv(
        &self,
        x: f32,
        v: f32,
        h_in: &[f32],
        c_in: &[f32],
        h_out: &mut [f32],
        c_out: &mut [f32],
    ) -> f32 {
        let nk = self.filters.len();
        let x = f64::from(x);
        let contact = x > 0.0;
        let u = x.max(0.0) * self.inv_depth;
        let vn = if contact {
            f64::from(v) * self.inv_speed
        } else {
            0.0
        };
        let w = u.min(1.0);
        let ns = self.neg_inv_scales.len();
        let mut phi = [0.0f64; MAX_DEPTH_SCALES];
        for (p, k) in phi.iter_mut().zip(&self.neg_inv_scales) {
            *p = 1.0 - (w * k).exp();
        }
        // the network's inputs, recorded as the readout computes them: q_j at j, then w
        let with_net = self.net.is_some();
        let mut q_net = [0.0f64; MAX_NET_INPUTS];
        let mut term = |q: f64, j: usize| {
            if with_net {
                q_net[j] = q; // j < n < MAX_NET_INPUTS (from_attrs)
            }
            let c = &self.readout[j];
            let sat: f64 = self.sat[j * ns..(j + 1) * ns]
                .iter()
                .zip(&phi)
                .map(|(e, p)| e * p)
                .sum();
            q * (c[0] + w * (c[1] + w * c[2]) + sat)
        };
        let mut f = term(u, 0) + term(vn, 1);
        c_out.fill(0.0);
        for (k, &(a, b)) in self.filters.iter().enumerate() {
            let s = a * (f64::from(h_in[k]) + f64::from(c_in[k])) + b * u;
            (h_out[k], c_out[k]) = split(s);
            f += term(u - s, 2 + k);
        }
        for (j, &r) in self.plays.iter().enumerate() {
            let p = f64::from(h_in[nk + j]).max(u - r).min(u + r);
            h_out[nk + j] = p as f32;
            f += term(u - p, 2 + nk + j);
        }
        if !self.damage.is_empty() {
            // the irreversible memory: u_max never decreases, so d = u - u_max <= 0
            let at = nk + self.plays.len();
            let m = f64::from(h_in[at]).max(u);
            h_out[at] = m as f32;
            let d = u - m;
            f += term(d, 2 + at);
            for (i, &c) in self.damage.iter().enumerate() {
                f += term(c * (1.0 - (d / c).exp()), 3 + at + i);
            }
        }
        if !contact {
            return 0.0; // the network is not evaluated out of contact: its value would be clamped
        }
        if let Some(net) = &self.net {
            let n = self.readout.len();
            q_net[n] = w;
            f += net.eval(&q_net[..=n]);
        }
        f.max(0.0) as f32
    }
}

/// The operator ONNX Runtime registers (`ai.haptics:LawFreeStep`).
pub type LawFreeStep = StatefulStep<LawFreeParams>;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::attrs::tests::Map;

    /// One filter (a 0.9, b 0.1), one play (r 0.1), depth 10 mm, speed 0.1 m/s; readout
    /// q = [u, v/V, u - s, u - p] with weights w1 = [2, 0.5, 1, 3], w2 = [1, 0, 0, 0], w3 = 0.
    fn simple() -> Map {
        Map::of(&[
            ("depth_scale_m", vec![0.01]),
            ("speed_scale_mps", vec![0.1]),
            ("filter_decay", vec![0.9]),
            ("filter_gain", vec![0.1]),
            ("play_widths", vec![0.1]),
            (
                "readout",
                vec![2.0, 0.5, 1.0, 3.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            ),
        ])
    }

    /// Steps `p` along a sine of `amplitude` (m; 300 steps, above and below the surface) and
    /// checks each force against `want(u, v/V, s, p)`, the model written out by hand with the
    /// filter (a 0.9, b 0.1) and the play (r 0.1) of `simple()` stepped beside it.
    fn check_by_hand(p: &LawFreeParams, amplitude: f64, want: impl Fn(f64, f64, f64, f64) -> f64) {
        let (mut h, mut ho) = (vec![0.0f32; 2], vec![0.0f32; 2]);
        let (mut c, mut co) = (vec![0.0f32; 2], vec![0.0f32; 2]);
        let (mut s, mut pl) = (0.0f64, 0.0f64);
        for n in 0..300 {
            let x = amplitude * (n as f64 * 0.03).sin();
            let v = amplitude * 0.03 * 1000.0 * (n as f64 * 0.03).cos();
            let got = p.step_xv(x as f32, v as f32, &h, &c, &mut ho, &mut co);
            std::mem::swap(&mut h, &mut ho);
            std::mem::swap(&mut c, &mut co);
            let u = (x as f32 as f64).max(0.0) / 0.01;
            s = 0.9 * s + 0.1 * u;
            pl = pl.max(u - 0.1).min(u + 0.1);
            let want = if x as f32 > 0.0 {
                want(u, f64::from(v as f32) / 0.1, s, pl).max(0.0)
            } else {
                0.0
            };
            assert!(
                (f64::from(got) - want).abs() < 1e-4 * (1.0 + want),
                "step {n}: {got} vs {want}"
            );
        }
    }

    #[test]
    fn a_step_matches_the_model_written_out_by_hand() {
        let p = LawFreeParams::from_attrs(&simple()).unwrap();
        check_by_hand(&p, 0.008, |u, vn, s, pl| {
            2.0 * u + u.min(1.0) * u + 0.5 * vn + (u - s) + 3.0 * (u - pl)
        });
    }

    /// The saturating depth functions: the same model with `readout_depth_scales` [0.5, 0.2]
    /// and weights on them for u (3, 4) and for the play (-1, 2), past the deepest press too
    /// (u up to 1.2: w = min(u, 1)).
    #[test]
    fn saturating_depth_terms_match_the_model_written_out_by_hand() {
        let mut w = vec![2.0, 0.5, 1.0, 3.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        // block 4 (1 - exp(-w/0.5)) then block 5 (1 - exp(-w/0.2)), one weight per input
        w.extend([3.0, 0.0, 0.0, -1.0, 4.0, 0.0, 0.0, 2.0]);
        let attrs = simple()
            .with("readout_depth_scales", vec![0.5, 0.2])
            .with("readout", w);
        let p = LawFreeParams::from_attrs(&attrs).unwrap();
        check_by_hand(&p, 0.012, |u, vn, s, pl| {
            let wu = u.min(1.0);
            let (e1, e2) = (1.0 - (-wu / 0.5).exp(), 1.0 - (-wu / 0.2).exp());
            u * (2.0 + wu + 3.0 * e1 + 4.0 * e2)
                + 0.5 * vn
                + (u - s)
                + (u - pl) * (3.0 - e1 + 2.0 * e2)
        });
    }

    /// The irreversible memory: `simple()` with `damage_frac` [0.05], so two more inputs d =
    /// u - u_max and 0.05 (1 - exp(d / 0.05)) with weights 1.5 and -4 (times 1), d also times w
    /// (2),
    /// one more state (u_max). The sine's presses grow, then shrink: d is 0 on the first
    /// loadings and negative after the deepest.
    #[test]
    fn the_irreversible_memory_matches_the_model_written_out_by_hand() {
        let n = 6;
        let mut w = vec![0.0; 3 * n];
        w[..n].copy_from_slice(&[2.0, 0.5, 1.0, 3.0, 1.5, -4.0]);
        w[n] = 1.0;
        w[n + 4] = 2.0;
        let attrs = simple().with("damage_frac", vec![0.05]).with("readout", w);
        let p = LawFreeParams::from_attrs(&attrs).unwrap();
        assert_eq!(p.state_size(), 3);
        let (mut h, mut ho) = (vec![0.0f32; 3], vec![0.0f32; 3]);
        let (mut c, mut co) = (vec![0.0f32; 3], vec![0.0f32; 3]);
        let (mut s, mut pl, mut top) = (0.0f64, 0.0f64, 0.0f64);
        let mut backed_off = 0;
        for k in 0..400 {
            let envelope = if k < 200 {
                k as f64 / 200.0
            } else {
                2.0 - k as f64 / 200.0
            };
            let x = (0.008 * envelope * (k as f64 * 0.05).sin()) as f32;
            let got = p.step_xv(x, 0.0, &h, &c, &mut ho, &mut co);
            std::mem::swap(&mut h, &mut ho);
            std::mem::swap(&mut c, &mut co);
            let u = f64::from(x).max(0.0) / 0.01;
            s = 0.9 * s + 0.1 * u;
            pl = pl.max(u - 0.1).min(u + 0.1);
            top = top.max(u);
            let d = u - top;
            backed_off += usize::from(d < -0.05);
            let want = if x > 0.0 {
                (2.0 * u + u.min(1.0) * u + (u - s) + 3.0 * (u - pl) + d * (1.5 + 2.0 * u.min(1.0))
                    - 4.0 * 0.05 * (1.0 - (d / 0.05).exp()))
                .max(0.0)
            } else {
                0.0
            };
            assert!(
                (f64::from(got) - want).abs() < 1e-4 * (1.0 + want),
                "step {k}: {got} vs {want}"
            );
            assert!(
                (f64::from(h[2]) - top).abs() < 1e-6,
                "step {k}: u_max {} vs {top}",
                h[2]
            );
        }
        assert!(
            backed_off > 50,
            "the programme backs off the deepest press: {backed_off}"
        );
    }

    const NET: [&str; 6] = ["net_w1", "net_b1", "net_w2", "net_b2", "net_w3", "net_b3"];

    /// A network of `h` units over `inputs` inputs: fixed, varied weights of either sign (none
    /// zero where it matters: W1's last column, w's, is 0.3, 0.6, ..), as the attributes hold them.
    fn net(h: usize, inputs: usize) -> [Vec<f32>; 6] {
        let v = |len: usize, seed: usize, scale: f32| -> Vec<f32> {
            (0..len)
                .map(|i| (((i * 37 + seed) % 23) as f32 - 11.0) * scale)
                .collect()
        };
        let mut w1 = v(h * inputs, 5, 0.05);
        for j in 0..h {
            w1[j * inputs + inputs - 1] = 0.3 + 0.3 * j as f32;
        }
        [
            w1,
            v(h, 3, 0.04),
            v(h * h, 7, 0.1),
            v(h, 1, 0.03),
            v(h, 9, 0.2),
            vec![0.7],
        ]
    }

    fn with_net(mut attrs: Map, net: &[Vec<f32>; 6]) -> Map {
        for (name, v) in NET.into_iter().zip(net) {
            attrs = attrs.with(name, v.clone());
        }
        attrs
    }

    /// g(x) written out from the attributes (row-major), x = [q_1..q_n, w].
    fn net_by_hand(net: &[Vec<f32>; 6], x: &[f64]) -> f64 {
        let [w1, b1, w2, b2, w3, b3] = net
            .each_ref()
            .map(|v| -> Vec<f64> { v.iter().map(|&a| f64::from(a)).collect() });
        let h = b1.len();
        let h1: Vec<f64> = (0..h)
            .map(|j| {
                (b1[j]
                    + (0..x.len())
                        .map(|i| w1[j * x.len() + i] * x[i])
                        .sum::<f64>())
                .tanh()
            })
            .collect();
        let h2: Vec<f64> = (0..h)
            .map(|j| (b2[j] + (0..h).map(|i| w2[j * h + i] * h1[i]).sum::<f64>()).tanh())
            .collect();
        b3[0] + (0..h).map(|j| w3[j] * h2[j]).sum::<f64>()
    }

    /// `simple()` with a network of 3 units over [u, v/V, u - s, u - p, w]: the force is the
    /// linear readout plus g, past the deepest press too (u up to 1.2: w = min(u, 1) != u).
    #[test]
    fn a_readout_network_matches_the_model_written_out_by_hand() {
        let nw = net(3, 5);
        let p = LawFreeParams::from_attrs(&with_net(simple(), &nw)).unwrap();
        check_by_hand(&p, 0.012, |u, vn, s, pl| {
            let g = net_by_hand(&nw, &[u, vn, u - s, u - pl, u.min(1.0)]);
            2.0 * u + u.min(1.0) * u + 0.5 * vn + (u - s) + 3.0 * (u - pl) + g
        });
    }

    /// The network alone (every linear weight 0), 5 units: the force is max(g, 0) in contact.
    #[test]
    fn a_readout_network_alone_matches_the_model_written_out_by_hand() {
        let nw = net(5, 5);
        let attrs = with_net(simple().with("readout", vec![0.0; 12]), &nw);
        let p = LawFreeParams::from_attrs(&attrs).unwrap();
        check_by_hand(&p, 0.012, |u, vn, s, pl| {
            net_by_hand(&nw, &[u, vn, u - s, u - pl, u.min(1.0)])
        });
    }

    /// The network changes the force only: the memories (h, and the filters' low parts in c)
    /// step bit for bit as without it, out of contact too.
    #[test]
    fn a_readout_network_leaves_the_state_as_it_was() {
        let plain = LawFreeParams::from_attrs(&simple()).unwrap();
        let netted = LawFreeParams::from_attrs(&with_net(simple(), &net(4, 5))).unwrap();
        let mut states = [
            [vec![0.0f32; 2], vec![0.0f32; 2]],
            [vec![0.0f32; 2], vec![0.0f32; 2]],
        ];
        let mut differ = 0;
        for k in 0..300 {
            let x = 0.012 * (k as f64 * 0.03).sin();
            let v = 0.36 * (k as f64 * 0.03).cos();
            let mut forces = [0.0f32; 2];
            for (i, p) in [&plain, &netted].into_iter().enumerate() {
                let [h, c] = &mut states[i];
                let (mut ho, mut co) = (vec![0.0f32; 2], vec![0.0f32; 2]);
                forces[i] = p.step_xv(x as f32, v as f32, h, c, &mut ho, &mut co);
                (*h, *c) = (ho, co);
            }
            assert_eq!(states[0], states[1], "step {k}");
            differ += usize::from(forces[0] != forces[1]);
        }
        assert!(
            differ > 100,
            "the network changes the force: {differ} steps"
        );
    }

    #[test]
    fn a_bad_readout_network_is_a_clear_error_not_a_panic() {
        let nw = net(3, 5);
        let mut no_b2 = with_net(simple(), &nw);
        no_b2.0.remove("net_b2");
        let mut wide = nw.clone();
        wide[1] = vec![0.1; 65];
        let cases = [
            (no_b2, "attribute `net_b2` is missing or not a list of floats (the six net_* attributes come together)".to_string()),
            (with_net(simple(), &nw).with("net_w1", vec![0.1; 12]), "attribute `net_w1` has 12 values, `net_b1 x (2 + filter_decay + play_widths (+ 1 + damage_frac) + 1)` has 15: they pair up".into()),
            (with_net(simple(), &nw).with("net_w2", vec![0.1; 6]), "attribute `net_w2` has 6 values, `net_b1 x net_b1` has 9: they pair up".into()),
            (with_net(simple(), &nw).with("net_b3", vec![0.1, 0.2]), "attribute `net_b3` has 2 values, `one bias` has 1: they pair up".into()),
            (with_net(simple(), &nw).with("net_w3", vec![0.1, f32::NAN, 0.2]), "attribute `net_w3` = NaN is not finite".into()),
            (with_net(simple(), &wide), "attribute `net_b1` = 65 is more hidden units than the kernel's 64".into()),
            // 2 + 1 + 61 = 64 readout inputs, 65 with w
            (with_net(simple(), &nw).with("play_widths", vec![0.1; 61]).with("readout", vec![0.0; 3 * 64]), "attribute `net_w1` = 65 is more network inputs (readout inputs + 1) than the kernel's 64".into()),
        ];
        for (attrs, want) in cases {
            let err = LawFreeParams::from_attrs(&attrs).unwrap_err().to_string();
            assert_eq!(err, format!("LawFreeStep: {want}"));
        }
        // at the limits: 64 units, 63 readout inputs
        let at_limit = with_net(simple(), &net(64, 5))
            .with("play_widths", vec![0.1; 60])
            .with("readout", vec![0.0; 3 * 63])
            .with("net_w1", vec![0.1; 64 * 64]);
        assert!(LawFreeParams::from_attrs(&at_limit).is_ok());
    }

    #[test]
    fn a_bad_attribute_is_a_clear_error_not_a_panic() {
        let cases = [
            (simple().with("readout", vec![1.0; 11]), "attribute `readout` has 11 values, `(3 + readout_depth_scales) x (2 + filter_decay + play_widths (+ 1 + damage_frac))` has 12: they pair up"),
            (simple().with("readout_depth_scales", vec![0.5]), "attribute `readout` has 12 values, `(3 + readout_depth_scales) x (2 + filter_decay + play_widths (+ 1 + damage_frac))` has 16: they pair up"),
            (simple().with("readout_depth_scales", vec![-0.5]), "attribute `readout_depth_scales` = -0.5 is not positive"),
            (simple().with("damage_frac", vec![0.1]), "attribute `readout` has 12 values, `(3 + readout_depth_scales) x (2 + filter_decay + play_widths (+ 1 + damage_frac))` has 18: they pair up"),
            (simple().with("damage_frac", vec![0.0]), "attribute `damage_frac` = 0 is not positive"),
            (simple().with("filter_decay", vec![1.5]), "attribute `filter_decay` = 1.5 is outside 0..1"),
            (simple().with("depth_scale_m", vec![0.0]), "attribute `depth_scale_m` = 0 is not positive"),
        ];
        for (attrs, want) in cases {
            let err = LawFreeParams::from_attrs(&attrs).unwrap_err().to_string();
            assert_eq!(err, format!("LawFreeStep: {want}"));
        }
    }
}
