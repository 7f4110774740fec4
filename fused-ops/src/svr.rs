//! `ai.haptics:SvrStep`: train's RBF SVR (`svr`: sklearn_models.py `SVRModel`, a
//! StandardScaler and an `SVR`) as one node: f = b + sum_i a_i exp(-gamma |z - s_i|^2),
//! z = (x - mean) / scale.
//!
//! Contract (docs/model-contract.md, stateless): input `features` [N, n], output `force`
//! [N, 1], any N.
//!
//! Why: ONNX Runtime's `SVMRegressor` costs about 4 ns per support vector and call (docs/
//! infer-server.md), several microseconds for the thousand-odd support vectors an SVR keeps.
//! Here the support vectors are stored feature-major ([n][S]), so the squared distances to all
//! of them build up as one vectorised pass per feature, and the kernel values come from the
//! branch-free exp (math.rs), 8 lanes at a time under AVX2; the weighted sum accumulates in
//! float64 lanes (a float32 sum over thousands of terms would lose its last digits).
//!
//! Attributes (sklearn_models.py `svr_fused` writes them): `feature_mean`, `feature_scale`
//! [n]; `support_vectors` [S][n] (scaled space, row-major as scikit-learn keeps them);
//! `coefficients` [S] (the dual coefficients); `gamma`; `intercept`.

use crate::attrs::{AttrError, Attrs, Reader};
use crate::math::{self, Madd};
use crate::stateless::{RowModel, StatelessStep};

const OP: &str = "SvrStep";

/// Support vectors per accumulation lane group (f64 lanes: 4 per AVX2 register, two registers).
const LANES: usize = 8;

/// The fitted SVR, parsed once from the node's attributes.
#[derive(Debug, Clone, PartialEq)]
pub struct SvrParams {
    mean: Vec<f32>,
    inv_scale: Vec<f32>,
    /// support vectors, feature-major: [n][S]
    sv_t: Vec<f32>,
    coef: Vec<f32>,
    neg_gamma: f32,
    intercept: f64,
    /// scratch: the squared distances to each support vector
    dist: Vec<f32>,
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
        Ok(Self {
            mean: f32s(&mean),
            inv_scale: scale.iter().map(|&v| (1.0 / v) as f32).collect(),
            sv_t: math::transpose(&f32s(&sv), s, n),
            coef: f32s(&coef),
            neg_gamma: -gamma as f32,
            intercept: r.float("intercept")?,
            dist: vec![0.0; s],
        })
    }

    fn inputs(&self) -> usize {
        self.mean.len()
    }

    /// The force of one row. Allocates nothing.
    #[inline(always)]
    fn row<M: Madd>(&mut self, x: &[f32]) -> f32 {
        let s = self.coef.len();
        self.dist.fill(0.0);
        for ((col, &xj), (&mu, &inv)) in self
            .sv_t
            .chunks_exact(s)
            .zip(x)
            .zip(self.mean.iter().zip(&self.inv_scale))
        {
            let z = (xj - mu) * inv;
            for (d, &sv) in self.dist.iter_mut().zip(col) {
                let e = z - sv;
                *d = M::madd(e, e, *d);
            }
        }
        let mut acc = [0.0f64; LANES];
        let (dist, coef) = (&self.dist, &self.coef);
        let full = s - s % LANES;
        for (d8, c8) in dist[..full]
            .chunks_exact(LANES)
            .zip(coef[..full].chunks_exact(LANES))
        {
            for ((a, &d), &c) in acc.iter_mut().zip(d8).zip(c8) {
                *a += f64::from(c * math::exp(self.neg_gamma * d));
            }
        }
        let rest: f64 = dist[full..]
            .iter()
            .zip(&coef[full..])
            .map(|(&d, &c)| f64::from(c * math::exp(self.neg_gamma * d)))
            .sum();
        (self.intercept + acc.iter().sum::<f64>() + rest) as f32
    }
}

/// The operator ONNX Runtime registers (`ai.haptics:SvrStep`).
pub type SvrStep = StatelessStep<SvrParams>;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::attrs::tests::Map;

    /// n = 2, 11 support vectors (a lane group and a rest), gamma 0.5.
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
