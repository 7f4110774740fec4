//! `ai.haptics:DenseStep`: train's dense network (`dnn`, `dnn_fb`: networks.py `DenseNet`) as
//! one node, the arithmetic of its multi-node graph (network_graphs.py `dense_graph`: the soft
//! features' asinh, a Gemm and an activation per layer, the scalers folded into the weights).
//!
//! Contract (docs/model-contract.md, stateless): input `features` [N, n], output `force`
//! [N, 1], any N (the export's parity check runs a whole recording in one call, infer-server
//! one row). The feedback network (`dnn_fb`) is the same operator: its state, the previous
//! force, reaches it as a feature the loop computes.
//!
//! Attributes (network_graphs.py `dense_fused` writes them): `widths` INTS [n, h_1, .., 1];
//! `weights` FLOATS, each layer's W [out][in] row-major, one after the other; `biases` FLOATS;
//! `activations` STRING, one name per layer (identity|relu|sigmoid|tanh|silu), comma
//! separated; `soft_scale` FLOATS [n], s_j of the features read as asinh(clip(x_j / s_j)) and 0
//! for the features read as they are; `clip`; `out_scale`, `out_offset` (force = offset + scale
//! y, 1 and 0 when folded into the last layer).
//!
//! The weights are float32, as the graph's; the kernel keeps each W transposed, so that a
//! layer is a sum of scaled columns (math.rs: vectorised, AVX2 where the CPU has it).

use crate::attrs::{AttrError, Attrs, Reader};
use crate::math::{self, Activation, Madd};
use crate::scaler::SoftScaler;
use crate::stateless::{RowModel, StatelessStep};

const OP: &str = "DenseStep";

#[derive(Debug, Clone, PartialEq)]
struct Layer {
    /// W transposed: [in][out]
    w_t: Vec<f32>,
    b: Vec<f32>,
    act: Activation,
}

/// The network, parsed once from the node's attributes.
#[derive(Debug, Clone, PartialEq)]
pub struct DenseParams {
    scaler: SoftScaler,
    layers: Vec<Layer>,
    out_scale: f32,
    out_offset: f32,
    /// scratch: two rows of the widest layer
    scratch: [Vec<f32>; 2],
}

impl DenseParams {
    /// Reads and checks the attributes.
    fn read<A: Attrs + ?Sized>(attrs: &A) -> Result<Self, AttrError> {
        let r = Reader { op: OP, attrs };
        let widths = r.sizes("widths")?;
        if widths.len() < 2 || widths[widths.len() - 1] != 1 {
            return Err(AttrError::Invalid {
                op: OP,
                name: "widths",
                value: widths.last().copied().unwrap_or(0) as f64,
                reason: "the last of widths, not 1: they must be [inputs, hidden.., 1]",
            });
        }
        let n_layers = widths.len() - 1;
        let n_weights = widths.windows(2).map(|p| p[0] * p[1]).sum();
        let n_biases = widths[1..].iter().sum();
        let w = r.list_of("weights", n_weights, "the sum of widths[i] x widths[i+1]")?;
        let b = r.list_of("biases", n_biases, "the sum of widths[1..]")?;
        let names = r.names("activations")?;
        if names.len() != n_layers {
            return Err(AttrError::Length {
                op: OP,
                name: "activations",
                got: names.len(),
                other: "widths - 1 (the layers)",
                expected: n_layers,
            });
        }
        let scaler = SoftScaler::from_attrs(&r, widths[0], "widths[0] (the features)")?;
        let mut layers = Vec::with_capacity(n_layers);
        let (mut wo, mut bo) = (0, 0);
        for (l, name) in names.iter().enumerate() {
            let (inp, out) = (widths[l], widths[l + 1]);
            let act = Activation::parse(name).ok_or(AttrError::Invalid {
                op: OP,
                name: "activations",
                value: l as f64,
                reason: "the index of a name other than identity|relu|sigmoid|tanh|silu",
            })?;
            let wl: Vec<f32> = w[wo..wo + inp * out].iter().map(|&v| v as f32).collect();
            layers.push(Layer {
                w_t: math::columns(&wl, out, inp),
                b: b[bo..bo + out].iter().map(|&v| v as f32).collect(),
                act,
            });
            wo += inp * out;
            bo += out;
        }
        Ok(Self {
            scaler,
            layers,
            out_scale: r.float("out_scale")? as f32,
            out_offset: r.float("out_offset")? as f32,
            scratch: {
                let widest = widths.iter().copied().max().unwrap_or(1);
                [vec![0.0; widest], vec![0.0; widest]]
            },
        })
    }
}

impl RowModel for DenseParams {
    const OP: &'static str = OP;

    fn from_attrs<A: Attrs + ?Sized>(attrs: &A) -> Result<Self, AttrError> {
        Self::read(attrs)
    }

    fn inputs(&self) -> usize {
        self.scaler.len()
    }

    /// The force of one row of features. Allocates nothing (two scratch rows of the widest
    /// layer, made at creation).
    #[inline(always)]
    fn row<M: Madd>(&mut self, x: &[f32]) -> f32 {
        let [a, b] = &mut self.scratch;
        let (mut cur, mut next) = (a, b);
        let mut width = self.scaler.len();
        self.scaler.apply(x, &mut cur[..width]);
        for layer in &self.layers {
            let out = layer.b.len();
            let y = &mut next[..out];
            math::affine::<M>(&layer.w_t, &layer.b, &cur[..width], y);
            layer.act.apply(y);
            std::mem::swap(&mut cur, &mut next);
            width = out;
        }
        cur[0] * self.out_scale + self.out_offset
    }
}

/// The operator ONNX Runtime registers (`ai.haptics:DenseStep`).
pub type DenseStep = StatelessStep<DenseParams>;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::attrs::tests::Map;

    /// features [x, r] (r soft, s = 2), one hidden layer of 2 (tanh), a linear output:
    /// W1 = [[1, 0.5], [-1, 2]], b1 = [0.1, -0.2], W2 = [[3, -1]], b2 = [0.5]; force = 2 y + 1.
    fn simple() -> Map {
        Map::of(&[
            ("widths", vec![2.0, 2.0, 1.0]),
            ("weights", vec![1.0, 0.5, -1.0, 2.0, 3.0, -1.0]),
            ("biases", vec![0.1, -0.2, 0.5]),
            ("soft_scale", vec![0.0, 2.0]),
            ("clip", vec![1e15]),
            ("out_scale", vec![2.0]),
            ("out_offset", vec![1.0]),
        ])
        .with_str("activations", "tanh,identity")
    }

    #[test]
    fn a_row_matches_the_network_written_out_by_hand() {
        let mut p = DenseParams::from_attrs(&simple()).unwrap();
        for (x, r) in [(0.3f64, -5.0f64), (0.0, 0.0), (-1.0, 1e6), (2.0, 0.01)] {
            let z = [x, (r / 2.0).asinh()];
            let h1 = (z[0] + 0.5 * z[1] + 0.1).tanh();
            let h2 = (-z[0] + 2.0 * z[1] - 0.2).tanh();
            let want = 2.0 * (3.0 * h1 - h2 + 0.5) + 1.0;
            let got = p.row::<math::Split>(&[x as f32, r as f32]);
            assert!(
                (f64::from(got) - want).abs() < 1e-5,
                "{x}, {r}: {got} vs {want}"
            );
            let fast = math::fast!(M => p.row::<M>(&[x as f32, r as f32]));
            assert!(
                (f64::from(fast) - want).abs() < 1e-5,
                "{x}, {r}: {fast} vs {want}"
            );
        }
    }

    #[test]
    fn a_bad_attribute_is_a_clear_error_not_a_panic() {
        let cases = [
            (simple().with("weights", vec![1.0; 5]), "attribute `weights` has 5 values, `the sum of widths[i] x widths[i+1]` has 6: they pair up"),
            (simple().with("widths", vec![2.0, 2.0, 2.0]), "attribute `widths` = 2 is the last of widths, not 1: they must be [inputs, hidden.., 1]"),
            (simple().with("widths", vec![2.0, 0.0, 1.0]), "attribute `widths` = 0 is not a size (>= 1)"),
            (simple().with_str("activations", "tanh"), "attribute `activations` has 1 values, `widths - 1 (the layers)` has 2: they pair up"),
            (simple().with_str("activations", "tanh,gelu"), "attribute `activations` = 1 is the index of a name other than identity|relu|sigmoid|tanh|silu"),
            (simple().with("soft_scale", vec![0.0, -1.0]), "attribute `soft_scale` = -1 is negative (0: not a soft feature)"),
            (simple().with("clip", vec![f32::NAN]), "attribute `clip` = NaN is not finite"),
        ];
        for (attrs, want) in cases {
            let err = DenseParams::from_attrs(&attrs).unwrap_err().to_string();
            assert_eq!(err, format!("DenseStep: {want}"));
        }
    }
}
