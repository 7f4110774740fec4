//! `ai.haptics:SpringDamperStep`: train's spring-dampers (`sd_const`, `sd_poly1`, `sd_poly2`:
//! spring_damper.py `SpringDamper`) as one node: F = x k(x) + v b(x), with k and b polynomials
//! in x of the same order (0-2), features (position_x, velocity).
//!
//! Contract (docs/model-contract.md, stateless): input `features` [N, 2], output `force`
//! [N, 1], any N.
//!
//! Why: the graph is five nodes (the powers of x, one MatMul for [k(x), b(x)], the dot with
//! [x, v]) for a dozen flops; ONNX Runtime's per-node dispatch made `sd_poly2`, the baseline of
//! record and the fallback's shape, 1.9-2.2x the identity graph (docs/infer-server.md). Horner's
//! rule in float64 here: one dispatch.
//!
//! Attributes (spring_damper.py `spring_damper_fused` writes them): `k`, `b` (the polynomial
//! coefficients, lowest power first, the same count: 1 to 3).

use crate::attrs::{AttrError, Attrs, Reader};
use crate::math::Madd;
use crate::stateless::{RowModel, StatelessStep};

const OP: &str = "SpringDamperStep";

/// The highest order the fits use (sd_poly2).
const MAX_TERMS: usize = 3;

/// The fitted coefficients, parsed once from the node's attributes.
#[derive(Debug, Clone, PartialEq)]
pub struct SpringDamperParams {
    k: Vec<f64>,
    b: Vec<f64>,
}

/// p(x) by Horner's rule, coefficients lowest power first.
#[inline(always)]
fn poly(c: &[f64], x: f64) -> f64 {
    c.iter().rev().fold(0.0, |acc, &ci| acc * x + ci)
}

impl RowModel for SpringDamperParams {
    const OP: &'static str = OP;

    fn from_attrs<A: Attrs + ?Sized>(attrs: &A) -> Result<Self, AttrError> {
        let r = Reader { op: OP, attrs };
        let k = r.list("k")?;
        r.check(
            "k",
            k.len() as f64,
            (1..=MAX_TERMS).contains(&k.len()),
            "not 1 to 3 coefficients (orders 0-2)",
        )?;
        let b = r.list_of("b", k.len(), "k (the same order)")?;
        Ok(Self { k, b })
    }

    fn inputs(&self) -> usize {
        2
    }

    /// The force of one row. Allocates nothing.
    #[inline(always)]
    fn row<M: Madd>(&mut self, x: &[f32]) -> f32 {
        let (p, v) = (f64::from(x[0]), f64::from(x[1]));
        (p * poly(&self.k, p) + v * poly(&self.b, p)) as f32
    }
}

/// The operator ONNX Runtime registers (`ai.haptics:SpringDamperStep`).
pub type SpringDamperStep = StatelessStep<SpringDamperParams>;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::attrs::tests::Map;
    use crate::math::Split;

    fn sd_poly2() -> Map {
        Map::of(&[
            ("k", vec![120.0, -800.0, 40000.0]),
            ("b", vec![3.0, 10.0, -50.0]),
        ])
    }

    #[test]
    fn a_row_is_the_spring_damper_written_out() {
        let mut p = SpringDamperParams::from_attrs(&sd_poly2()).unwrap();
        for (x, v) in [(0.0f32, 0.0f32), (0.01, 0.05), (0.03, -0.2), (-0.002, 0.1)] {
            let (xf, vf) = (f64::from(x), f64::from(v));
            let want = xf * (120.0 - 800.0 * xf + 40000.0 * xf * xf)
                + vf * (3.0 + 10.0 * xf - 50.0 * xf * xf);
            let got = f64::from(p.row::<Split>(&[x, v]));
            assert!(
                (got - want).abs() <= 1e-6 * want.abs().max(1.0),
                "{x} {v}: {got} vs {want}"
            );
        }
        let mut c =
            SpringDamperParams::from_attrs(&Map::of(&[("k", vec![200.0]), ("b", vec![4.0])]))
                .unwrap();
        assert_eq!(
            c.row::<Split>(&[0.01, 0.5]),
            (0.01f64 * 200.0 + 0.5 * 4.0) as f32
        );
    }

    #[test]
    fn a_bad_attribute_is_a_clear_error_not_a_panic() {
        let cases = [
            (
                sd_poly2().with("b", vec![1.0, 2.0]),
                "attribute `b` has 2 values, `k (the same order)` has 3: they pair up",
            ),
            (
                sd_poly2().with("k", vec![]),
                "attribute `k` = 0 is not 1 to 3 coefficients (orders 0-2)",
            ),
            (
                sd_poly2().with("k", vec![1.0, 2.0, 3.0, 4.0]),
                "attribute `k` = 4 is not 1 to 3 coefficients (orders 0-2)",
            ),
        ];
        for (attrs, want) in cases {
            let err = SpringDamperParams::from_attrs(&attrs)
                .unwrap_err()
                .to_string();
            assert_eq!(err, format!("SpringDamperStep: {want}"));
        }
    }
}
