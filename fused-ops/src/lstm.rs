//! `ai.haptics:LstmStep`: one control step of train's LSTM (`lstm`, `lstm_fb`: networks.py
//! `LSTMNet`), the arithmetic of its multi-node graph (network_graphs.py `lstm_graph`: the
//! soft features' asinh, ONNX's LSTM op, the head) in one node; and [`LstmCell`], the cell that
//! `lstm_slow` (slow_lstm.rs) steps once per block.
//!
//! Contract (docs/model-contract.md, stateful): inputs `features` [1, n], `h_in`, `c_in`
//! [1, 1, H]; outputs `force` [1, 1], `h_out`, `c_out` [1, 1, H]: the LSTM's h and c, as the
//! graph's.
//!
//! Attributes (network_graphs.py `lstm_fused` writes them): `soft_scale` [n] and `clip` (the
//! input scaling, scaler.rs); `input_weights` W_ih [4H][n] with the standardisation folded in,
//! `recurrent_weights` W_hh [4H][H], `biases` b_ih + b_hh [4H], all in torch's gate order
//! (i, f, g, o); `head_weights` [H] and `head_bias` with the target scaling folded in.
//!
//! The cell is two column-sum products (math.rs: an axpy of 4H per input and per state
//! element, vectorised, AVX2 where the CPU has it) and 5H exps, in float32 as torch's. The
//! recurrent one, three quarters of the step at H = 100, reads only the state: a serving thread
//! does it for the next step after sending this one's answer (ahead.rs).

use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use crate::ahead::{self, Ahead, Slot};
use crate::attrs::{AttrError, Attrs, Reader};
use crate::math::{self, Madd};
use crate::scaler::SoftScaler;
use crate::stateful::{StatefulStep, StepModel};

const OP: &str = "LstmStep";

/// One LSTM cell (torch's equations): gates = W_ih x + W_hh h + b; c' = f c + i g;
/// h' = o tanh(c').
///
/// The recurrent product W_hh h is the step's cost (160 KB of weights at H = 100) and reads
/// only the state, so a serving thread does it for the next step after answering this one
/// (ahead.rs). Whether or not it was done ahead, the gates are summed in one order,
/// (b + W_ih x) + (W_hh h), each product from zero: the same bits either way.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct LstmCell {
    hidden: usize,
    /// W_ih transposed: [n][4H]
    w_ih_t: Vec<f32>,
    recurrent: Arc<Recurrent>,
    b: Vec<f32>,
    /// scratch: the 4H gates of a step
    gates: Vec<f32>,
    /// scratch: W_hh h, when the work ahead is in someone else's hands
    product: Vec<f32>,
}

/// W_hh and the product done ahead for the last state this cell wrote. A cell's clone shares
/// it (the slot is claimed, never waited for, and checked bit for bit: sharing costs only hits).
pub(crate) struct Recurrent {
    /// W_hh transposed: [H][4H]
    w_hh_t: Vec<f32>,
    ahead: Slot<Cached>,
}

/// A state h and, once the work ahead has run ([`ahead::DONE`]), W_hh h.
struct Cached {
    h: Vec<f32>,
    product: Vec<f32>,
}

impl Recurrent {
    fn new(w_hh_t: Vec<f32>, hidden: usize) -> Self {
        let cached = Cached {
            h: vec![0.0; hidden],
            product: vec![0.0; 4 * hidden],
        };
        Self {
            w_hh_t,
            ahead: Slot::new(cached),
        }
    }

    /// `out = W_hh h`, summed from zero (the one order both paths use).
    #[inline(always)]
    fn product<M: Madd>(&self, h: &[f32], out: &mut [f32]) {
        out.fill(0.0);
        math::add_product::<M>(&self.w_hh_t, h, out);
    }
}

impl Ahead for Recurrent {
    /// W_hh h for the h the last step wrote, if that step is still the last.
    fn run_ahead(&self) {
        if let Some(mut c) = self.ahead.claim_queued() {
            let Cached { h, product } = &mut *c;
            math::fast!(M => self.product::<M>(h, product));
            c.release(ahead::DONE);
        }
    }

    fn queued(&self) -> &AtomicBool {
        self.ahead.queued()
    }
}

impl PartialEq for Recurrent {
    fn eq(&self, other: &Self) -> bool {
        self.w_hh_t == other.w_hh_t
    }
}

impl std::fmt::Debug for Recurrent {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recurrent")
            .field("w_hh_t", &self.w_hh_t.len())
            .finish_non_exhaustive()
    }
}

/// Whether two states are the same bits (the product done ahead is for exactly this one).
#[inline(always)]
fn same_bits(a: &[f32], b: &[f32]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
}

impl LstmCell {
    /// Reads `biases` (its length, 4H, sets H), `input_weights` ([4H][n_in]) and
    /// `recurrent_weights` ([4H][H]).
    pub fn from_attrs<A: Attrs + ?Sized>(
        r: &Reader<'_, A>,
        n_in: usize,
    ) -> Result<Self, AttrError> {
        let b = r.list("biases")?;
        if b.is_empty() || b.len() % 4 != 0 {
            return Err(AttrError::Invalid {
                op: r.op,
                name: "biases",
                value: b.len() as f64,
                reason: "not a length of 4 H (the gates i, f, g, o), H >= 1",
            });
        }
        let hidden = b.len() / 4;
        let g = 4 * hidden;
        let w_ih = r.list_of("input_weights", g * n_in, "4 H x the features")?;
        let w_hh = r.list_of("recurrent_weights", g * hidden, "4 H x H")?;
        let f32s = |v: &[f64]| v.iter().map(|&x| x as f32).collect::<Vec<f32>>();
        Ok(Self {
            hidden,
            w_ih_t: math::columns(&f32s(&w_ih), g, n_in),
            recurrent: Arc::new(Recurrent::new(
                math::columns(&f32s(&w_hh), g, hidden),
                hidden,
            )),
            b: f32s(&b),
            gates: vec![0.0; g],
            product: vec![0.0; g],
        })
    }

    pub fn hidden(&self) -> usize {
        self.hidden
    }

    /// One step from input `x`, state (`h_in`, `c_in`) to (`h_out`, `c_out`), each H long.
    /// Allocates nothing, takes no lock (the work ahead is claimed or left, never waited for).
    #[inline(always)]
    pub fn step<M: Madd>(
        &mut self,
        x: &[f32],
        h_in: &[f32],
        c_in: &[f32],
        h_out: &mut [f32],
        c_out: &mut [f32],
    ) {
        let h = self.hidden;
        math::affine::<M>(&self.w_ih_t, &self.b, x, &mut self.gates);
        let rec = &self.recurrent;
        let mut claim = rec.ahead.claim();
        let product = match claim.as_mut() {
            Some(c) => {
                let done = c.was() == ahead::DONE;
                let Cached {
                    h: done_for,
                    product,
                } = &mut **c;
                if !(done && same_bits(done_for, h_in)) {
                    rec.product::<M>(h_in, product);
                }
                &*product
            }
            None => {
                rec.product::<M>(h_in, &mut self.product);
                &self.product
            }
        };
        for (g, &p) in self.gates.iter_mut().zip(product) {
            *g += p;
        }
        let (ifg, o) = self.gates.split_at_mut(3 * h);
        let (i_f, g) = ifg.split_at_mut(2 * h);
        math::Activation::Sigmoid.apply(i_f);
        math::Activation::Tanh.apply(g);
        math::Activation::Sigmoid.apply(o);
        let (i, f) = i_f.split_at(h);
        for ((((c2, &c), &i), &f), &g) in c_out[..h].iter_mut().zip(c_in).zip(i).zip(f).zip(&*g) {
            *c2 = f * c + i * g;
        }
        for ((h2, &c2), &o) in h_out[..h].iter_mut().zip(&c_out[..h]).zip(&*o) {
            *h2 = o * math::tanh(c2);
        }
        if let Some(mut c) = claim {
            // The next step's product reads this h: leave it for the serving thread.
            c.h.copy_from_slice(&h_out[..h]);
            let next = if ahead::queue(rec) {
                ahead::QUEUED
            } else {
                ahead::EMPTY
            };
            c.release(next);
        }
    }
}

/// Everything one step needs, parsed once from the node's attributes.
#[derive(Debug, Clone, PartialEq)]
pub struct LstmParams {
    scaler: SoftScaler,
    cell: LstmCell,
    head: Vec<f32>,
    head_bias: f32,
    /// scratch: the scaled features
    z: Vec<f32>,
}

impl StepModel for LstmParams {
    const OP: &'static str = OP;
    const MIN_FEATURES: usize = 1;

    fn from_attrs<A: Attrs + ?Sized>(attrs: &A) -> Result<Self, AttrError> {
        let r = Reader { op: OP, attrs };
        let scaler = SoftScaler::networks(&r)?;
        let n = scaler.len();
        let cell = LstmCell::from_attrs(&r, n)?;
        let head = r.list_of("head_weights", cell.hidden(), "H")?;
        Ok(Self {
            scaler,
            head: head.iter().map(|&x| x as f32).collect(),
            head_bias: r.float("head_bias")? as f32,
            cell,
            z: vec![0.0; n],
        })
    }

    fn state_size(&self) -> usize {
        self.cell.hidden()
    }

    fn features(&self) -> Option<usize> {
        Some(self.scaler.len())
    }

    #[inline(always)]
    fn step<M: Madd>(
        &mut self,
        features: &[f32],
        h_in: &[f32],
        c_in: &[f32],
        h_out: &mut [f32],
        c_out: &mut [f32],
    ) -> f32 {
        self.scaler.apply(features, &mut self.z);
        self.cell.step::<M>(&self.z, h_in, c_in, h_out, c_out);
        let dot: f32 = h_out.iter().zip(&self.head).map(|(&h, &w)| h * w).sum();
        dot + self.head_bias
    }
}

/// The operator ONNX Runtime registers (`ai.haptics:LstmStep`).
pub type LstmStep = StatefulStep<LstmParams>;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::attrs::tests::Map;

    /// n = 2 (the second soft, s = 0.5), H = 2, weights a fixed pattern.
    fn simple() -> Map {
        let w = |n: usize, k: f32| (0..n).map(|i| ((i * 7) % 5) as f32 * k - 0.3).collect();
        Map::of(&[
            ("soft_scale", vec![0.0, 0.5]),
            ("clip", vec![1e15]),
            ("input_weights", w(16, 0.2)),
            ("recurrent_weights", w(16, 0.15)),
            ("biases", w(8, 0.1)),
            ("head_weights", vec![1.5, -2.0]),
            ("head_bias", vec![0.25]),
        ])
    }

    #[test]
    fn a_step_matches_the_cell_written_out_by_hand() {
        let attrs = simple();
        let mut p = LstmParams::from_attrs(&attrs).unwrap();
        let (wi, wh, b) = (
            &attrs.0["input_weights"],
            &attrs.0["recurrent_weights"],
            &attrs.0["biases"],
        );
        let sig = |x: f64| 1.0 / (1.0 + (-x).exp());
        let (mut h, mut c) = ([0.0f32; 2], [0.0f32; 2]);
        let (mut rh, mut rc) = ([0.0f64; 2], [0.0f64; 2]);
        for n in 0..200 {
            let x = [(n as f32 * 0.1).sin(), 30.0 * (n as f32 * 0.07).cos()];
            let (mut ho, mut co) = ([0.0f32; 2], [0.0f32; 2]);
            let got = math::fast!(M => p.step::<M>(&x, &h, &c, &mut ho, &mut co));
            (h, c) = (ho, co);
            let z = [f64::from(x[0]), (f64::from(x[1]) / 0.5).asinh()];
            let gate = |k: usize| {
                f64::from(b[k])
                    + (0..2).map(|j| f64::from(wi[k * 2 + j]) * z[j]).sum::<f64>()
                    + (0..2)
                        .map(|j| f64::from(wh[k * 2 + j]) * rh[j])
                        .sum::<f64>()
            };
            let g: Vec<f64> = (0..8).map(gate).collect();
            for j in 0..2 {
                rc[j] = sig(g[2 + j]) * rc[j] + sig(g[j]) * g[4 + j].tanh();
            }
            for j in 0..2 {
                rh[j] = sig(g[6 + j]) * rc[j].tanh();
            }
            let want = 1.5 * rh[0] - 2.0 * rh[1] + 0.25;
            assert!(
                (f64::from(got) - want).abs() < 2e-5,
                "step {n}: {got} vs {want}"
            );
        }
    }

    /// n = 3, H = 70 (4H = 280: four full blocks of the product and a narrower rest).
    fn wide() -> Map {
        let w = |n: usize, k: f32| {
            (0..n)
                .map(|i| (((i * 37) % 101) as f32 / 101.0 - 0.5) * k)
                .collect()
        };
        Map::of(&[
            ("soft_scale", vec![0.0, 0.5, 0.0]),
            ("clip", vec![1e15]),
            ("input_weights", w(280 * 3, 1.0)),
            ("recurrent_weights", w(280 * 70, 0.4)),
            ("biases", w(280, 0.2)),
            ("head_weights", w(70, 1.0)),
            ("head_bias", vec![0.1]),
        ])
    }

    /// Steps `wide()` 300 times, fed back as infer-server feeds it, with a reset to zero at
    /// step 100 and a state that is not the last one written at step 200; `ahead`: on a
    /// thread that serves ahead, `run_ahead` after every step. Returns the forces' bits and
    /// how many steps found the product done for their state.
    fn stepped(ahead: bool) -> (Vec<u32>, usize) {
        std::thread::spawn(move || {
            if ahead {
                crate::ahead::serve_ahead_on_this_thread();
            }
            let mut p = LstmParams::from_attrs(&wide()).unwrap();
            let (mut h, mut c) = (vec![0.0f32; 70], vec![0.0f32; 70]);
            let (mut ho, mut co) = (vec![0.0f32; 70], vec![0.0f32; 70]);
            let (mut forces, mut hits) = (Vec::new(), 0);
            for n in 0..300 {
                if n == 100 {
                    h.fill(0.0);
                    c.fill(0.0);
                }
                if n == 200 {
                    h[3] += 1e-3;
                }
                let x = [(n as f32 * 0.1).sin(), 3.0 * (n as f32 * 0.07).cos(), 0.5];
                let rec = &p.cell.recurrent;
                if let Some(cl) = rec.ahead.claim() {
                    let was = cl.was();
                    if was == ahead::DONE && same_bits(&cl.h, &h) {
                        hits += 1;
                    }
                    cl.release(was);
                }
                let f = math::fast!(M => p.step::<M>(&x, &h, &c, &mut ho, &mut co));
                forces.push(f.to_bits());
                std::mem::swap(&mut h, &mut ho);
                std::mem::swap(&mut c, &mut co);
                crate::ahead::run_ahead();
            }
            (forces, hits)
        })
        .join()
        .unwrap()
    }

    #[test]
    fn the_product_done_ahead_is_used_and_changes_no_bit() {
        let (plain, no_hits) = stepped(false);
        let (ahead, hits) = stepped(true);
        assert_eq!(
            no_hits, 0,
            "a thread that does not serve ahead does all the work"
        );
        // every step but the first, the reset's and the altered state's
        assert_eq!(hits, 297);
        let differ = plain.iter().zip(&ahead).filter(|(a, b)| a != b).count();
        assert_eq!(differ, 0, "{differ} of 300 forces differ");
    }

    #[test]
    fn a_bad_attribute_is_a_clear_error_not_a_panic() {
        let cases = [
            (simple().with("biases", vec![0.0; 7]), "attribute `biases` = 7 is not a length of 4 H (the gates i, f, g, o), H >= 1"),
            (simple().with("input_weights", vec![0.0; 15]), "attribute `input_weights` has 15 values, `4 H x the features` has 16: they pair up"),
            (simple().with("recurrent_weights", vec![0.0; 8]), "attribute `recurrent_weights` has 8 values, `4 H x H` has 16: they pair up"),
            (simple().with("head_weights", vec![1.0]), "attribute `head_weights` has 1 values, `H` has 2: they pair up"),
            (simple().with("clip", vec![-1.0]), "attribute `clip` = -1 is not positive"),
        ];
        for (attrs, want) in cases {
            let err = LstmParams::from_attrs(&attrs).unwrap_err().to_string();
            assert_eq!(err, format!("LstmStep: {want}"));
        }
    }
}
