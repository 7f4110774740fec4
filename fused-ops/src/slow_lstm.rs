//! `ai.haptics:SlowLstmStep`: one control step of train's `lstm_slow`
//! (train/src/haptics_train/models/slow_lstm.py), the arithmetic of its multi-node graph
//! (`slow_lstm_graph`) in one node: the force from the last complete block's state and this
//! step's scaled features, and the LSTM cell stepped once per block of `block_steps` control
//! steps on the block's mean features.
//!
//! Contract (docs/model-contract.md, stateful): inputs `features` [1, f], `h_in`, `c_in`
//! [1, 1, H + f + 1]; outputs `force` [1, 1], `h_out`, `c_out` likewise: `h` carries [h (H),
//! the block's running sum of z (f), its step count (1)], `c` carries [c (H), zeros], as the
//! graph's.
//!
//! Attributes (slow_lstm.py `slow_lstm_fused` writes them): `soft_scale`, `clip` (scaler.rs),
//! `feature_scale` and `feature_offset` [f] (the standardisation, z = scaled x * scale +
//! offset; a z not finite or beyond 1e6 counts as 0); the cell's `input_weights`,
//! `recurrent_weights`, `biases` (lstm.rs); the head's `head_weights` [K][H + f] and
//! `head_biases` [K] (tanh), `out_weights` [K] and `out_bias` with the target scaling folded
//! in; `block_steps`.

use crate::attrs::{AttrError, Attrs, Reader};
use crate::lstm::LstmCell;
use crate::math::{self, Activation, Madd};
use crate::scaler::SoftScaler;
use crate::stateful::{StatefulStep, StepModel};

const OP: &str = "SlowLstmStep";

/// A scaled feature beyond this (or not finite) counts as 0 (slow_lstm.py `_Z_LIMIT`).
const Z_LIMIT: f32 = 1e6;

/// Everything one step needs, parsed once from the node's attributes.
#[derive(Debug, Clone, PartialEq)]
pub struct SlowLstmParams {
    scaler: SoftScaler,
    scale: Vec<f32>,
    offset: Vec<f32>,
    cell: LstmCell,
    /// the head's first layer transposed: [H + f][K]
    head_t: Vec<f32>,
    head_b: Vec<f32>,
    out_w: Vec<f32>,
    out_b: f32,
    block_steps: f32,
    /// scratch: [h, z] (H + f), the block's mean (f), the head's hidden layer (K)
    hz: Vec<f32>,
    mean: Vec<f32>,
    pre: Vec<f32>,
}

impl StepModel for SlowLstmParams {
    const OP: &'static str = OP;
    const MIN_FEATURES: usize = 1;

    fn from_attrs<A: Attrs + ?Sized>(attrs: &A) -> Result<Self, AttrError> {
        let r = Reader { op: OP, attrs };
        let scaler = SoftScaler::networks(&r)?;
        let f = scaler.len();
        let scale = r.list_of("feature_scale", f, "soft_scale (the features)")?;
        let offset = r.list_of("feature_offset", f, "soft_scale (the features)")?;
        let cell = LstmCell::from_attrs(&r, f)?;
        let hid = cell.hidden();
        let out_w = r.list("out_weights")?;
        let k = out_w.len();
        r.check("out_weights", k as f64, k >= 1, "empty (one per head unit)")?;
        let head = r.list_of(
            "head_weights",
            k * (hid + f),
            "out_weights x (H + features)",
        )?;
        let head_b = r.list_of("head_biases", k, "out_weights (the head's units)")?;
        let block = r.float("block_steps")?;
        r.check("block_steps", block, block >= 1.0, "below 1")?;
        let f32s = |v: &[f64]| v.iter().map(|&x| x as f32).collect::<Vec<f32>>();
        Ok(Self {
            scaler,
            scale: f32s(&scale),
            offset: f32s(&offset),
            head_t: math::columns(&f32s(&head), k, hid + f),
            head_b: f32s(&head_b),
            out_w: f32s(&out_w),
            out_b: r.float("out_bias")? as f32,
            block_steps: block as f32,
            hz: vec![0.0; hid + f],
            mean: vec![0.0; f],
            pre: vec![0.0; k],
            cell,
        })
    }

    fn state_size(&self) -> usize {
        self.cell.hidden() + self.scaler.len() + 1
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
        let hid = self.cell.hidden();
        let (h, z) = self.hz.split_at_mut(hid);
        h.copy_from_slice(&h_in[..hid]);
        self.scaler.apply(features, z);
        for ((z, &a), &b) in z.iter_mut().zip(&self.scale).zip(&self.offset) {
            let v = *z * a + b;
            *z = if v.abs() < Z_LIMIT { v } else { 0.0 };
        }
        math::affine::<M>(&self.head_t, &self.head_b, &self.hz, &mut self.pre);
        Activation::Tanh.apply(&mut self.pre);
        let dot: f32 = self.pre.iter().zip(&self.out_w).map(|(&p, &w)| p * w).sum();
        let force = dot + self.out_b;

        let f = self.scaler.len();
        let z = &self.hz[hid..];
        let cnt = h_in[hid + f] + 1.0;
        if cnt > self.block_steps - 0.5 {
            // a complete block: the cell steps on its mean, the next block starts empty
            for ((m, &acc), &z) in self.mean.iter_mut().zip(&h_in[hid..hid + f]).zip(z) {
                *m = (acc + z) / cnt;
            }
            self.cell
                .step::<M>(&self.mean, &h_in[..hid], &c_in[..hid], h_out, c_out);
            h_out[hid..].fill(0.0);
            c_out[hid..].copy_from_slice(&c_in[hid..]);
        } else {
            h_out[..hid].copy_from_slice(&h_in[..hid]);
            for ((o, &acc), &z) in h_out[hid..hid + f].iter_mut().zip(&h_in[hid..]).zip(z) {
                *o = acc + z;
            }
            h_out[hid + f] = cnt;
            c_out.copy_from_slice(c_in);
        }
        force
    }
}

/// The operator ONNX Runtime registers (`ai.haptics:SlowLstmStep`).
pub type SlowLstmStep = StatefulStep<SlowLstmParams>;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::attrs::tests::Map;

    /// f = 1, H = 1, K = 1, blocks of 3 steps; the cell's gates all from its bias (weights 0)
    /// except the input gate's input weight.
    fn simple() -> Map {
        Map::of(&[
            ("soft_scale", vec![0.0]),
            ("clip", vec![1e15]),
            ("feature_scale", vec![2.0]),
            ("feature_offset", vec![-1.0]),
            ("input_weights", vec![0.0, 0.0, 1.0, 0.0]),
            ("recurrent_weights", vec![0.0; 4]),
            ("biases", vec![20.0, -20.0, 0.0, 20.0]),
            ("head_weights", vec![1.0, 0.5]),
            ("head_biases", vec![0.0]),
            ("out_weights", vec![3.0]),
            ("out_bias", vec![0.25]),
            ("block_steps", vec![3.0]),
        ])
    }

    #[test]
    fn the_cell_steps_once_per_block_on_the_mean_of_its_features() {
        let mut p = SlowLstmParams::from_attrs(&simple()).unwrap();
        assert_eq!(p.state_size(), 3);
        let (mut h, mut c) = ([0.0f32; 3], [0.0f32; 3]);
        let xs = [0.5f32, 1.0, 2.0, 1e9, 0.75, 0.5];
        // i, o ~ 1, f ~ 0, g = tanh(mean z): after a block, c = tanh(mean), h = tanh(c)
        let zs: Vec<f32> = xs
            .iter()
            .map(|&x| {
                let z = 2.0 * x - 1.0;
                if z.abs() < 1e6 {
                    z
                } else {
                    0.0
                }
            })
            .collect();
        let mut hk = 0.0f64;
        for (n, &x) in xs.iter().enumerate() {
            let (mut ho, mut co) = ([0.0f32; 3], [0.0f32; 3]);
            let got = p.step::<math::Split>(&[x], &h, &c, &mut ho, &mut co);
            let want = 3.0 * (hk + 0.5 * f64::from(zs[n])).tanh() + 0.25;
            assert!(
                (f64::from(got) - want).abs() < 1e-4,
                "step {n}: {got} vs {want}"
            );
            (h, c) = (ho, co);
            if n % 3 == 2 {
                let mean = f64::from(zs[n - 2] + zs[n - 1] + zs[n]) / 3.0;
                hk = mean.tanh().tanh();
                assert!((f64::from(h[0]) - hk).abs() < 1e-4, "step {n}: h {}", h[0]);
                assert_eq!([h[1], h[2]], [0.0, 0.0]);
            } else {
                assert_eq!(h[2], (n % 3 + 1) as f32);
            }
        }
    }

    #[test]
    fn a_bad_attribute_is_a_clear_error_not_a_panic() {
        let cases = [
            (simple().with("block_steps", vec![0.5]), "attribute `block_steps` = 0.5 is below 1"),
            (simple().with("head_weights", vec![1.0]), "attribute `head_weights` has 1 values, `out_weights x (H + features)` has 2: they pair up"),
            (simple().with("feature_offset", vec![1.0, 2.0]), "attribute `feature_offset` has 2 values, `soft_scale (the features)` has 1: they pair up"),
            (simple().with("head_biases", vec![]), "attribute `head_biases` has 0 values, `out_weights (the head's units)` has 1: they pair up"),
        ];
        for (attrs, want) in cases {
            let err = SlowLstmParams::from_attrs(&attrs).unwrap_err().to_string();
            assert_eq!(err, format!("SlowLstmStep: {want}"));
        }
    }
}
