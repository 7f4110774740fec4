//! `ai.haptics:PronyStep`: one control step of train's `prony` model
//! (train/src/haptics_train/models/prony.py): F = max(0, sum_j k_j x^j + sum_i w_i s_i),
//! s_i' = e_i s_i + tau_i (1 - e_i) v, e_i = exp(-dt / tau_i).
//!
//! Contract (docs/model-contract.md, stateful): inputs `features` [1, n] (x, v the first two),
//! `h_in`, `c_in` [1, 1, K]; outputs `force` [1, 1], `h_out`, `c_out` [1, 1, K]: `h` carries
//! the K branch states as the multi-node graph's (prony.py `prony_graph`).
//!
//! `c`, which the multi-node graph passes through unused, carries each branch's low part,
//! s_i - float32(s_i): the slowest branch (tau 30 s at 10 kHz: e = 0.9999967) moves by a few
//! millionths of itself per step, below float32's resolution of its state (the reason
//! structured.rs and lawfree.rs keep their slow states the same way). The decays and gains are
//! computed in f64 once, from the raw fitted values the attributes carry.

use crate::attrs::{AttrError, Attrs, Reader};
use crate::math::Madd;
use crate::stateful::{split, StatefulStep, StepModel};

const OP: &str = "PronyStep";

/// Everything one step needs, parsed once from the node's attributes.
#[derive(Debug, Clone, PartialEq)]
pub struct PronyParams {
    /// k_1..k_P of x^1..x^P
    spring: Vec<f64>,
    /// (decay e_i, gain tau_i (1 - e_i), weight w_i) per branch
    branches: Vec<(f64, f64, f64)>,
}

impl StepModel for PronyParams {
    const OP: &'static str = OP;
    const MIN_FEATURES: usize = 2;

    /// Reads and checks the attributes (names as prony.py `prony_fused` writes them).
    fn from_attrs<A: Attrs + ?Sized>(attrs: &A) -> Result<Self, AttrError> {
        let r = Reader { op: OP, attrs };
        let dt = r.positive("dt_s")?;
        let taus = r.positive_list("taus_s")?;
        let w = r.list("branch_weights")?;
        r.paired("branch_weights", &w, "taus_s", &taus)?;
        let spring = r.list("spring")?;
        Ok(Self {
            spring,
            branches: taus
                .iter()
                .zip(&w)
                .map(|(&tau, &w)| {
                    let one_minus_e = -(-dt / tau).exp_m1();
                    (1.0 - one_minus_e, tau * one_minus_e, w)
                })
                .collect(),
        })
    }

    fn state_size(&self) -> usize {
        self.branches.len()
    }

    /// Reads x, v (features[0..2]), the branches in `h_in` and their low parts in `c_in`.
    fn step<M: Madd>(
        &mut self,
        features: &[f32],
        h_in: &[f32],
        c_in: &[f32],
        h_out: &mut [f32],
        c_out: &mut [f32],
    ) -> f32 {
        let (x, v) = (f64::from(features[0]), f64::from(features[1]));
        // Horner: x (k_1 + x (k_2 + x k_3 ..))
        let mut f = x * self.spring.iter().rev().fold(0.0, |acc, &k| acc * x + k);
        for (k, &(e, gain, w)) in self.branches.iter().enumerate() {
            let s = e * (f64::from(h_in[k]) + f64::from(c_in[k])) + gain * v;
            (h_out[k], c_out[k]) = split(s);
            f += w * s;
        }
        f.max(0.0) as f32
    }
}

/// The operator ONNX Runtime registers (`ai.haptics:PronyStep`).
pub type PronyStep = StatefulStep<PronyParams>;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::attrs::tests::Map;

    /// dt 1 ms, spring 100 x + 2000 x^2, two branches tau 0.01 s (w 50) and 100 s (w 5).
    fn simple() -> Map {
        Map::of(&[
            ("dt_s", vec![1e-3]),
            ("taus_s", vec![0.01, 100.0]),
            ("branch_weights", vec![50.0, 5.0]),
            ("spring", vec![100.0, 2000.0]),
        ])
    }

    #[test]
    fn a_step_matches_the_model_written_out_by_hand() {
        let mut p = PronyParams::from_attrs(&simple()).unwrap();
        let (mut h, mut ho) = (vec![0.0f32; 2], vec![0.0f32; 2]);
        let (mut c, mut co) = (vec![0.0f32; 2], vec![0.0f32; 2]);
        let mut s = [0.0f64; 2];
        for n in 0..20_000 {
            let x = f64::from((0.01 * (n as f64 * 0.002).sin()) as f32);
            let v = f64::from((0.02 * (n as f64 * 0.002).cos()) as f32);
            let got = p.step::<crate::math::Split>(&[x as f32, v as f32], &h, &c, &mut ho, &mut co);
            std::mem::swap(&mut h, &mut ho);
            std::mem::swap(&mut c, &mut co);
            for (si, tau) in s.iter_mut().zip([0.01f64, 100.0]) {
                let e = (-1e-3 / tau).exp();
                *si = e * *si + tau * (1.0 - e) * v;
            }
            let want = (100.0 * x + 2000.0 * x * x + 50.0 * s[0] + 5.0 * s[1]).max(0.0);
            assert!(
                (f64::from(got) - want).abs() < 1e-5 * (1.0 + want),
                "step {n}: {got} vs {want}"
            );
        }
    }

    #[test]
    fn a_bad_attribute_is_a_clear_error_not_a_panic() {
        let cases = [
            (
                simple().with("branch_weights", vec![1.0]),
                "attribute `branch_weights` has 1 values, `taus_s` has 2: they pair up",
            ),
            (
                simple().with("taus_s", vec![0.01, -1.0]),
                "attribute `taus_s` = -1 is not positive",
            ),
            (
                simple().with("dt_s", vec![0.0]),
                "attribute `dt_s` = 0 is not positive",
            ),
            (
                simple().with("spring", vec![f32::INFINITY]),
                "attribute `spring` = inf is not finite",
            ),
        ];
        for (attrs, want) in cases {
            let err = PronyParams::from_attrs(&attrs).unwrap_err().to_string();
            assert_eq!(err, format!("PronyStep: {want}"));
        }
    }
}
