//! `BlendStep` (train's `blend`, models/blend.py): the weighted mean of two stateful models'
//! forces, each stepping its own state, in one node.
//!
//! Why one node: ONNX Runtime charges each node its dispatch (docs/infer-server.md), so the
//! members' two nodes with the slices, the sum and the concatenations around them cost about
//! eleven dispatches; one node costs one, and the arithmetic of two members is a few hundred
//! flops. The two members are the existing kernels (`StructuredStep`, `LawFreeStep`), so a
//! blend steps exactly as its members step alone.
//!
//! Attributes: `a_op`, `b_op` (STRING: `StructuredStep` or `LawFreeStep`), `weights` (FLOATS
//! [w_a, w_b], non-negative, not both 0), and each member's own attributes with its prefix,
//! `a.` or `b.` (`a.dt_s`, `b.readout`, ...). The state is the members' one after the other:
//! `h` = [h_a, h_b], `c` = [c_a, c_b], H = H_a + H_b.

use crate::attrs::{AttrError, Attrs, Reader};
use crate::lawfree::LawFreeParams;
use crate::math::Madd;
use crate::stateful::{StatefulStep, StepModel};
use crate::structured::StructuredParams;

/// The operator's name in the domain.
pub const OP: &str = "BlendStep";

/// The blend operator.
pub type BlendStep = StatefulStep<BlendParams>;

/// A member: one of the stateful models a blend may hold.
#[derive(Debug, Clone, PartialEq)]
pub enum Member {
    Structured(StructuredParams),
    LawFree(LawFreeParams),
}

/// A member's attributes: the node's, read under the member's prefix. Allocates the prefixed
/// name, which is fine: attributes are read once, when the kernel is created.
struct Prefixed<'a, A: ?Sized> {
    attrs: &'a A,
    prefix: &'static str,
}

impl<A: Attrs + ?Sized> Attrs for Prefixed<'_, A> {
    fn float(&self, name: &str) -> Option<f32> {
        self.attrs.float(&format!("{}{name}", self.prefix))
    }
    fn floats(&self, name: &str) -> Option<Vec<f32>> {
        self.attrs.floats(&format!("{}{name}", self.prefix))
    }
    fn ints(&self, name: &str) -> Option<Vec<i64>> {
        self.attrs.ints(&format!("{}{name}", self.prefix))
    }
    fn string(&self, name: &str) -> Option<String> {
        self.attrs.string(&format!("{}{name}", self.prefix))
    }
}

impl Member {
    /// The member named by the STRING attribute `op_attr`, from the attributes under `prefix`.
    fn from_attrs<A: Attrs + ?Sized>(
        attrs: &A,
        op_attr: &'static str,
        prefix: &'static str,
    ) -> Result<Self, AttrError> {
        let inner = Prefixed { attrs, prefix };
        let op = attrs.string(op_attr);
        if op.as_deref() == Some(StructuredParams::OP) {
            Ok(Self::Structured(StructuredParams::from_attrs(&inner)?))
        } else if op.as_deref() == Some(LawFreeParams::OP) {
            Ok(Self::LawFree(LawFreeParams::from_attrs(&inner)?))
        } else {
            Err(AttrError::Missing {
                op: OP,
                name: op_attr,
                kind: "string naming StructuredStep or LawFreeStep",
            })
        }
    }

    fn state_size(&self) -> usize {
        match self {
            Self::Structured(p) => p.state_size(),
            Self::LawFree(p) => p.state_size(),
        }
    }

    #[inline]
    fn step<M: Madd>(
        &mut self,
        features: &[f32],
        h_in: &[f32],
        c_in: &[f32],
        h_out: &mut [f32],
        c_out: &mut [f32],
    ) -> f32 {
        match self {
            Self::Structured(p) => p.step::<M>(features, h_in, c_in, h_out, c_out),
            Self::LawFree(p) => p.step::<M>(features, h_in, c_in, h_out, c_out),
        }
    }
}

/// Both members and their weights, parsed once from the node's attributes.
#[derive(Debug, Clone, PartialEq)]
pub struct BlendParams {
    a: Member,
    b: Member,
    weights: (f64, f64),
}

impl StepModel for BlendParams {
    const OP: &'static str = OP;
    // both members read x and v (LawFreeStep's least)
    const MIN_FEATURES: usize = 2;

    fn from_attrs<A: Attrs + ?Sized>(attrs: &A) -> Result<Self, AttrError> {
        let r = Reader { op: OP, attrs };
        let w = r.list("weights")?;
        if w.len() != 2 {
            return Err(AttrError::Invalid {
                op: OP,
                name: "weights",
                value: w.len() as f64,
                reason: "not 2 values (one weight per member)",
            });
        }
        for &v in &w {
            if !(v.is_finite() && v >= 0.0) {
                return Err(AttrError::Invalid {
                    op: OP,
                    name: "weights",
                    value: v,
                    reason: "not a finite non-negative weight",
                });
            }
        }
        if w[0] + w[1] <= 0.0 {
            return Err(AttrError::Invalid {
                op: OP,
                name: "weights",
                value: 0.0,
                reason: "their sum: a blend of nothing",
            });
        }
        Ok(Self {
            a: Member::from_attrs(attrs, "a_op", "a.")?,
            b: Member::from_attrs(attrs, "b_op", "b.")?,
            weights: (w[0], w[1]),
        })
    }

    fn state_size(&self) -> usize {
        self.a.state_size() + self.b.state_size()
    }

    /// Each member steps its own part of the state; no allocation (the slices are views).
    #[inline]
    fn step<M: Madd>(
        &mut self,
        features: &[f32],
        h_in: &[f32],
        c_in: &[f32],
        h_out: &mut [f32],
        c_out: &mut [f32],
    ) -> f32 {
        let ha = self.a.state_size();
        let (ha_in, hb_in) = h_in.split_at(ha);
        let (ca_in, cb_in) = c_in.split_at(ha);
        let (ha_out, hb_out) = h_out.split_at_mut(ha);
        let (ca_out, cb_out) = c_out.split_at_mut(ha);
        let fa = self.a.step::<M>(features, ha_in, ca_in, ha_out, ca_out);
        let fb = self.b.step::<M>(features, hb_in, cb_in, hb_out, cb_out);
        (self.weights.0 * f64::from(fa) + self.weights.1 * f64::from(fb)) as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::attrs::tests::Map;
    use crate::math::Split;

    /// A small structured member (one plateau, one branch, one Dahl state, at 1 kHz) and a
    /// small law-free one (one filter, one play), the attributes as their tests write them.
    const STRUCTURED: &[(&str, &[f32])] = &[
        ("dt_s", &[1e-3]),
        ("yield_m", &[0.01]),
        ("a_yield", &[2.0]),
        ("taus_s", &[0.5]),
        ("branch_gains", &[0.3]),
        ("hysteresis_m", &[0.002]),
        ("hysteresis_gains", &[0.1]),
        ("set_max_m", &[0.0]),
    ];
    const LAWFREE: &[(&str, &[f32])] = &[
        ("depth_scale_m", &[0.01]),
        ("speed_scale_mps", &[0.1]),
        ("filter_decay", &[0.9]),
        ("filter_gain", &[0.1]),
        ("play_widths", &[0.1]),
        (
            "readout",
            &[2.0, 0.5, 1.0, 3.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        ),
    ];

    fn member(attrs: &[(&str, &[f32])]) -> Map {
        Map::of(
            &attrs
                .iter()
                .map(|(k, v)| (leak(k), v.to_vec()))
                .collect::<Vec<_>>(),
        )
    }

    fn leak(s: &str) -> &'static str {
        Box::leak(s.to_string().into_boxed_str())
    }

    /// The blend's attributes: `a` structured, `b` law-free, with `weights`.
    fn blend(weights: Vec<f32>) -> Map {
        let mut m = Map::of(&[("weights", weights)])
            .with_str("a_op", "StructuredStep")
            .with_str("b_op", "LawFreeStep");
        for (prefix, attrs) in [("a.", STRUCTURED), ("b.", LAWFREE)] {
            for (k, v) in attrs.iter() {
                m = m.with(leak(&format!("{prefix}{k}")), v.to_vec());
            }
        }
        m
    }

    /// Steps a model from the zero state along a press in and out of contact; the forces.
    fn run<P: StepModel>(p: &mut P) -> Vec<f32> {
        let h = p.state_size();
        let (mut hs, mut cs) = (vec![0.0f32; h], vec![0.0f32; h]);
        let (mut ho, mut co) = (vec![0.0f32; h], vec![0.0f32; h]);
        (0..400)
            .map(|n| {
                let t = n as f32 * 1e-3;
                let x = 0.012 * (t * 9.0).sin() - 0.002;
                let v = 0.012 * 9.0 * (t * 9.0).cos();
                let f = p.step::<Split>(&[x, v], &hs, &cs, &mut ho, &mut co);
                std::mem::swap(&mut hs, &mut ho);
                std::mem::swap(&mut cs, &mut co);
                f
            })
            .collect()
    }

    #[test]
    fn a_blend_steps_as_the_weighted_mean_of_its_members_stepped_alone() {
        let mut a = StructuredParams::from_attrs(&member(STRUCTURED)).unwrap();
        let mut b = LawFreeParams::from_attrs(&member(LAWFREE)).unwrap();
        let mut p = BlendParams::from_attrs(&blend(vec![0.25, 0.75])).unwrap();
        assert_eq!(p.state_size(), a.state_size() + b.state_size());
        let (fa, fb, fp) = (run(&mut a), run(&mut b), run(&mut p));
        assert!(fa.iter().any(|&f| f > 0.1) && fb.iter().any(|&f| f > 0.1));
        for (n, ((&fa, &fb), &fp)) in fa.iter().zip(&fb).zip(&fp).enumerate() {
            let want = 0.25 * f64::from(fa) + 0.75 * f64::from(fb);
            assert!(
                (f64::from(fp) - want).abs() < 1e-6,
                "step {n}: {fp} vs {want}"
            );
        }
    }

    #[test]
    fn bad_attributes_are_refused_with_their_name() {
        let e = |m: Map| BlendParams::from_attrs(&m).unwrap_err().to_string();
        assert!(e(blend(vec![0.5])).contains("`weights`"));
        assert!(e(blend(vec![0.5, -0.5])).contains("non-negative"));
        assert!(e(blend(vec![0.0, 0.0])).contains("blend of nothing"));
        assert!(e(blend(vec![0.5, 0.5]).with_str("b_op", "DenseStep")).contains("`b_op`"));
        // a member's own attribute missing: its kernel's error, read under its prefix
        let mut m = blend(vec![0.5, 0.5]);
        m.0.remove("a.dt_s");
        assert!(e(m).contains("StructuredStep: attribute `dt_s`"));
    }
}
