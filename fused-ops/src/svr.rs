//! `ai.haptics:SvrStep`: train's RBF SVR (`svr`: sklearn_models.py `SVRModel`, a
//! StandardScaler and an `SVR`) as one node: f = b + sum_i a_i exp(-gamma |z - s_i|^2),
//! z = (x - mean) / scale.
//!
//! Contract (docs/model-contract.md, stateless): input `features` [N, n], output `force`
//! [N, 1], any N.
//!
//! Why: ONNX Runtime's `SVMRegressor` costs about 4 ns per support vector and call (docs/
//! infer-server.md), several microseconds for the thousand-odd support vectors an SVR keeps.
//! Here the support vectors are stored in blocks of [`BLOCK`], each block feature-major
//! ([n][BLOCK]): one block's squared distances build up in registers (one vector per feature,
//! no scratch written and read back n times), its kernel values come from the branch-free exp
//! (math.rs), and its weighted terms join float64 lanes (a float32 sum over thousands of terms
//! would lose its last digits). The last block is padded with zero-weight vectors, whose terms
//! are exactly 0. A block is 16 vectors, two AVX2 registers (the kernel alone, svr_six's 1,674
//! vectors on the 2-core VM: 2.15 us a row at 16, 5.7 us at 8, 2.6 us at 32; 3.46 us before,
//! with the distances in scratch and the exps 4 lanes at a time).
//!
//! Attributes (sklearn_models.py `svr_fused` writes them): `feature_mean`, `feature_scale`
//! [n]; `support_vectors` [S][n] (scaled space, row-major as scikit-learn keeps them);
//! `coefficients` [S] (the dual coefficients); `gamma`; `intercept`.

use crate::attrs::{AttrError, Attrs, Reader};
use crate::math::{self, Madd};
use crate::stateless::{RowModel, StatelessStep};

const OP: &str = "SvrStep";

/// Support vectors per block (two AVX2 registers of float32; four of float64 lanes).
const BLOCK: usize = 16;

/// The fitted SVR, parsed once from the node's attributes.
#[derive(Debug, Clone, PartialEq)]
pub struct SvrParams {
    mean: Vec<f32>,
    inv_scale: Vec<f32>,
    /// support vectors in blocks, each feature-major: [S / BLOCK][n][BLOCK] (S padded)
    sv_blocks: Vec<f32>,
    /// the dual coefficients, [S] padded with zeros to whole blocks
    coef: Vec<f32>,
    /// S, the support vectors without the padding
    vectors: usize,
    neg_gamma: f32,
    intercept: f64,
    /// scratch: the row's scaled features
    z: Vec<f32>,
}

impl RowModel for SvrParams {
    const OP: &'static str = OP;

    /// Reads and checks the attributes.
    fn from_attrs<A: Attrs + ?Sized>(attrs: &A) -> Result<Self, AttrError> {
        let r = Reader { op: OP, attrs };
        let mean = r.list("feature_mean")?;
        let n = mean.len();
        r.check(
            "feature_mean",
            n as f64,
            n >= 1,
            "empty (one value per feature)",
        )?;
        let scale = r.list_of("feature_scale", n, "feature_mean (the features)")?;
        for &s in &scale {
            r.check("feature_scale", s, s > 0.0, "not positive")?;
        }
        let coef = r.list("coefficients")?;
        let s = coef.len();
        r.check(
            "coefficients",
            s as f64,
            s >= 1,
            "empty (one per support vector)",
        )?;
        let sv = r.list_of("support_vectors", s * n, "coefficients x the features")?;
        let gamma = r.positive("gamma")?;
        let f32s = |v: &[f64]| v.iter().map(|&x| x as f32).collect::<Vec<f32>>();
        let blocks = s.div_ceil(BLOCK);
        // Padding: a zero coefficient (its term is 0 whatever its distance) at the origin.
        let mut sv_blocks = vec![0.0f32; blocks * n * BLOCK];
        for (i, v) in sv.chunks_exact(n).enumerate() {
            let (b, k) = (i / BLOCK, i % BLOCK);
            for (j, &x) in v.iter().enumerate() {
                sv_blocks[(b * n + j) * BLOCK + k] = x as f32;
            }
        }
        let mut coef = f32s(&coef);
        coef.resize(blocks * BLOCK, 0.0);
        Ok(Self {
            mean: f32s(&mean),
            inv_scale: scale.iter().map(|&v| (1.0 / v) as f32).collect(),
            sv_blocks,
            coef,
            vectors: s,
            neg_gamma: -gamma as f32,
            intercept: r.float("intercept")?,
            z: vec![0.0; n],
        })
    }

    fn inputs(&self) -> usize {
        self.mean.len()
    }

    /// The force of one row. Allocates nothing.
    #[inline(always)]
    fn row<M: Madd>(&mut self, x: &[f32]) -> f32 {
        for ((z, &xj), (&mu, &inv)) in self
            .z
            .iter_mut()
            .zip(x)
            .zip(self.mean.iter().zip(&self.inv_scale))
        {
            *z = (xj - mu) * inv;
        }
        let n = self.z.len();
        let mut acc = [0.0f64; BLOCK];
        for (block, c) in self
            .sv_blocks
            .chunks_exact(n * BLOCK)
            .zip(self.coef.chunks_exact(BLOCK))
        {
            // The block's squared distances, in registers, feature by feature.
            let mut d = [0.0f32; BLOCK];
            for (col, &z) in block.chunks_exact(BLOCK).zip(&self.z) {
                for (d, &sv) in d.iter_mut().zip(col) {
                    let e = z - sv;
                    *d = M::madd(e, e, *d);
                }
            }
            // The kernel values in float32 lanes first, then the widening: written as one loop,
            // the compiler computes the exps 4 lanes at a time, to match the float64 registers.
            let mut t = [0.0f32; BLOCK];
            for ((t, &d), &c) in t.iter_mut().zip(&d).zip(c) {
                *t = c * math::exp(self.neg_gamma * d);
            }
            for (a, &t) in acc.iter_mut().zip(&t) {
                *a += f64::from(t);
            }
        }
        (self.intercept + acc.iter().sum::<f64>()) as f32
    }
}

impl SvrParams {
    /// One row's force, compiled for this CPU (AVX2 and FMA where it has them), as the kernel
    /// runs it (examples/svr_cost.rs times it).
    pub fn predict(&mut self, x: &[f32]) -> f32 {
        math::fast!(M => self.row::<M>(x))
    }

    /// The support vectors (without the padding).
    pub fn support_vectors(&self) -> usize {
        self.vectors
    }
}

/// The operator ONNX Runtime registers (`ai.haptics:SvrStep`).
pub type SvrStep = StatelessStep<SvrParams>;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::attrs::tests::Map;

    /// n = 2, 11 support vectors (less than a block: the padding), gamma 0.5.
    fn simple() -> Map {
        let s = 11;
        let sv: Vec<f32> = (0..2 * s)
            .map(|i| ((i * 7) % 9) as f32 * 0.25 - 1.0)
            .collect();
        let coef: Vec<f32> = (0..s).map(|i| (i as f32 - 5.0) * 0.3).collect();
        Map::of(&[
            ("feature_mean", vec![0.01, -0.5]),
            ("feature_scale", vec![0.02, 2.0]),
            ("support_vectors", sv),
            ("coefficients", coef),
            ("gamma", vec![0.5]),
            ("intercept", vec![1.25]),
        ])
    }

    #[test]
    fn a_row_matches_the_kernel_sum_written_out_by_hand() {
        let attrs = simple();
        let mut p = SvrParams::from_attrs(&attrs).unwrap();
        let (sv, coef) = (&attrs.0["support_vectors"], &attrs.0["coefficients"]);
        for (x0, x1) in [(0.0f32, 0.0f32), (0.03, -1.0), (-0.01, 2.5), (0.02, 0.3)] {
            let z = [(f64::from(x0) - 0.01) / 0.02, (f64::from(x1) + 0.5) / 2.0];
            let want: f64 = 1.25
                + (0..11)
                    .map(|i| {
                        let d: f64 = (0..2)
                            .map(|j| (z[j] - f64::from(sv[i * 2 + j])).powi(2))
                            .sum();
                        f64::from(coef[i]) * (-0.5 * d).exp()
                    })
                    .sum::<f64>();
            let got = math::fast!(M => p.row::<M>(&[x0, x1]));
            assert!(
                (f64::from(got) - want).abs() < 1e-5,
                "{x0}, {x1}: {got} vs {want}"
            );
        }
    }

    /// Several blocks and a padded rest (n = 3, 37 vectors: two blocks of 16 and 5), each
    /// vector's term visible in the sum: the layout puts every coordinate where the row reads it.
    #[test]
    fn every_block_and_the_padded_rest_count() {
        let (n, s) = (3usize, 37usize);
        let sv: Vec<f32> = (0..n * s)
            .map(|i| ((i * 11) % 13) as f32 * 0.2 - 1.2)
            .collect();
        let coef: Vec<f32> = (0..s).map(|i| ((i * 5) % 7) as f32 * 0.4 - 1.1).collect();
        let attrs = Map::of(&[
            ("feature_mean", vec![0.0, 1.0, -1.0]),
            ("feature_scale", vec![1.0, 0.5, 2.0]),
            ("support_vectors", sv.clone()),
            ("coefficients", coef.clone()),
            ("gamma", vec![0.7]),
            ("intercept", vec![-0.3]),
        ]);
        let mut p = SvrParams::from_attrs(&attrs).unwrap();
        assert_eq!(p.support_vectors(), s);
        for x in [[0.0f32, 1.0, -1.0], [0.4, 0.6, 1.5], [-1.0, 1.9, -3.0]] {
            let z = [
                f64::from(x[0]),
                (f64::from(x[1]) - 1.0) / 0.5,
                (f64::from(x[2]) + 1.0) / 2.0,
            ];
            let want: f64 = -0.3
                + (0..s)
                    .map(|i| {
                        let d: f64 = (0..n)
                            .map(|j| (z[j] - f64::from(sv[i * n + j])).powi(2))
                            .sum();
                        f64::from(coef[i]) * (-0.7 * d).exp()
                    })
                    .sum::<f64>();
            let got = math::fast!(M => p.row::<M>(&x));
            assert!(
                (f64::from(got) - want).abs() < 1e-5,
                "{x:?}: {got} vs {want}"
            );
        }
    }

    #[test]
    fn a_bad_attribute_is_a_clear_error_not_a_panic() {
        let cases = [
            (simple().with("support_vectors", vec![0.0; 21]), "attribute `support_vectors` has 21 values, `coefficients x the features` has 22: they pair up"),
            (simple().with("feature_scale", vec![0.02, 0.0]), "attribute `feature_scale` = 0 is not positive"),
            (simple().with("gamma", vec![-1.0]), "attribute `gamma` = -1 is not positive"),
            (simple().with("coefficients", vec![]), "attribute `coefficients` = 0 is empty (one per support vector)"),
        ];
        for (attrs, want) in cases {
            let err = SvrParams::from_attrs(&attrs).unwrap_err().to_string();
            assert_eq!(err, format!("SvrStep: {want}"));
        }
    }
}
