//! The model contract (docs/model-contract.md): what an `.onnx` file must
//! say about itself and look like to be served.

use std::fmt;

/// Metadata key: comma-separated feature names in the model's input order.
pub const META_FEATURES: &str = "haptics.features";
/// Metadata key: `stateless` or `stateful`.
pub const META_KIND: &str = "haptics.kind";
/// Metadata key: the unit of the output force (the loop renders newtons).
pub const META_UNITS: &str = "haptics.units";
/// Metadata key: JSON object describing how the model was trained.
pub const META_PROVENANCE: &str = "haptics.provenance";

/// Metadata key (stateful models): the hidden size H, as a decimal integer.
pub const META_STATE_SIZE: &str = "haptics.state_size";
/// Metadata key (optional): what "previous" means for the previous-force features (`step`).
pub const META_PREVIOUS_FORCE: &str = "haptics.previous_force";
/// Metadata key (optional, stateful models whose state steps in time): the period, in seconds,
/// the state expects between two calls, i.e. one step of the loop it was exported for (its
/// decays are exp(-step / tau)). A model served by a loop of another rate relaxes at the wrong
/// speed, so infer-server refuses to activate it beside such a loop.
pub const META_STEP_S: &str = "haptics.step_s";

/// Metadata key (optional): the filters its training recordings' velocity and acceleration
/// features were computed with, JSON `{"g_v": rad/s, "g_a": rad/s}` (`haptics-train export`
/// writes it when the recordings agree). A model fitted on other filters than the loop's sees
/// a velocity or an acceleration that means something else: infer-server names it when it
/// activates the model (a warning, not a refusal: nothing else can serve it).
pub const META_FEATURE_GAINS: &str = "haptics.feature_gains";

/// Metadata key (optional): reference steps, JSON `{"inputs": [[f32; n]; K], "force": [f32; K],
/// "tolerance_n": N, "source": text}` (`haptics-train export` writes it, train/'s
/// reference.py): K rows in the model's input order, stepped from the zero state, and the force
/// the exporter's ONNX Runtime computed for each. infer-server steps them when it loads the
/// model and refuses it when a force differs by more than the tolerance: a server whose
/// ONNX Runtime or fused operators read the graph otherwise (a build older than the exporter's
/// ignores attributes it does not know) would render another object. The format, its limits
/// (at most `MAX_REFERENCE_STEPS` steps, a tolerance of at most `MAX_REFERENCE_TOLERANCE_N`)
/// and the comparison are ort-host's (`reference.rs`), which rt-loop's ONNX objects share.
pub use haptics_ort_host::reference::{
    MAX_REFERENCE_STEPS, MAX_REFERENCE_TOLERANCE_N, META_REFERENCE,
};

/// How far a model's feature gains may be from the loop's (a fraction of them).
pub const GAIN_TOLERANCE: f64 = 0.01;

/// Why a model whose features were computed with `model_gains` (g_v, g_a) sees other features
/// in a loop whose filters are `loop_gains`, or `None` when they agree where its `features` use
/// them (or either is unknown).
pub fn gains_mismatch(
    model_gains: Option<(f64, f64)>,
    features: &[String],
    loop_gains: (f64, f64),
) -> Option<String> {
    let (mv, ma) = model_gains?;
    let (lv, la) = loop_gains;
    let uses = |what: &str, suffix: &str| {
        features
            .iter()
            .any(|f| f.contains(what) || f.ends_with(suffix))
    };
    let off = |m: f64, l: f64| l.is_finite() && l > 0.0 && ((m / l) - 1.0).abs() > GAIN_TOLERANCE;
    let mut parts = Vec::new();
    if uses("velocity", "_v") && off(mv, lv) {
        parts.push(format!(
            "velocity at g_v {mv:.1} rad/s (the loop's {lv:.1})"
        ));
    }
    if uses("acceleration", "_a") && off(ma, la) {
        parts.push(format!(
            "acceleration at g_a {ma:.1} rad/s (the loop's {la:.1})"
        ));
    }
    (!parts.is_empty()).then(|| {
        format!(
            "its training features were computed with other filters ({META_FEATURE_GAINS}): {}; \
             served here it sees a feature that means something else than the one it \
             learned (import its recordings with the loop's --g-v/--g-a, or run the loop \
             with its gains)",
            parts.join(", ")
        )
    })
}

/// How far a model's `haptics.step_s` may be from the loop's period (a fraction of it).
pub const STEP_TOLERANCE: f64 = 0.01;

/// Why a model whose state steps at `step_s` cannot be served by a loop of `loop_rate_hz`, or
/// `None` when it can (or either is unknown: no step declared, no loop status yet).
pub fn step_mismatch(step_s: Option<f64>, loop_rate_hz: f64) -> Option<String> {
    let step = step_s?;
    if !(loop_rate_hz.is_finite() && loop_rate_hz > 0.0) {
        return None;
    }
    let ratio = step * loop_rate_hz;
    ((ratio - 1.0).abs() > STEP_TOLERANCE).then(|| {
        format!(
            "its state steps every {:.6} s ({META_STEP_S}, {:.0} Hz) but the loop runs at {:.0} Hz: \
             served there it would relax {ratio:.3}x as fast as the object it learned; export it \
             again from recordings of this loop's rate (haptics-train export serves at the \
             recording loop's rate)",
            step,
            1.0 / step,
            loop_rate_hz,
        )
    })
}

/// Input and output names fixed by the contract.
pub const INPUT_FEATURES: &str = "features";
pub const INPUT_H: &str = "h_in";
pub const INPUT_C: &str = "c_in";
pub const OUTPUT_FORCE: &str = "force";
pub const OUTPUT_H: &str = "h_out";
pub const OUTPUT_C: &str = "c_out";

/// Largest rank of a tensor the server allocates for a model (`h_in`/`c_in`, `h_out`/`c_out`).
pub const MAX_TENSOR_RANK: usize = 8;
/// Largest single dimension of such a tensor.
pub const MAX_TENSOR_DIM: i64 = 1 << 16;
/// Most elements of one such tensor: 4 MiB of float32. An LSTM of the thesis's size has a few
/// hundred; this cap refuses a crafted declaration before anything is allocated for it.
pub const MAX_TENSOR_ELEMENTS: usize = 1 << 20;

/// The element count of a concrete (all dimensions >= 0) shape, with checked arithmetic, or why
/// the shape is refused: a rank, a dimension or a count over the caps above, or a negative
/// dimension. Called before any buffer of that shape is allocated.
pub fn checked_elements(shape: &[i64]) -> Result<usize, String> {
    if shape.len() > MAX_TENSOR_RANK {
        return Err(format!(
            "shape {shape:?} has rank {}, over the limit of {MAX_TENSOR_RANK}",
            shape.len()
        ));
    }
    let mut count: usize = 1;
    for &d in shape {
        if !(0..=MAX_TENSOR_DIM).contains(&d) {
            return Err(format!(
                "shape {shape:?} has a dimension {d}, outside 0..={MAX_TENSOR_DIM}"
            ));
        }
        count = count
            .checked_mul(d as usize)
            .filter(|&c| c <= MAX_TENSOR_ELEMENTS)
            .ok_or_else(|| {
                format!(
                    "shape {shape:?} has more than {MAX_TENSOR_ELEMENTS} elements (the limit \
                     for one tensor the server allocates)"
                )
            })?;
    }
    Ok(count)
}

/// The nine features of thesis Table 3.1, in that order (docs/recording-format.md). A model uses
/// any subset of these, in any order.
/// One list for the whole system: haptics-proto's.
pub const FEATURE_NAMES: [&str; 9] = haptics_proto::THESIS_FEATURES;

/// How the server steps a model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ModelKind {
    /// One feature vector in, one force out; no memory between steps.
    Stateless,
    /// A recurrent model stepped one sample at a time; the server carries `h`/`c` between steps
    /// and resets them to zero when a new run starts.
    Stateful,
}

impl ModelKind {
    pub fn parse(s: &str) -> Option<Self> {
        match s.trim() {
            "stateless" => Some(Self::Stateless),
            "stateful" => Some(Self::Stateful),
            _ => None,
        }
    }

    pub fn as_str(self) -> &'static str {
        match self {
            Self::Stateless => "stateless",
            Self::Stateful => "stateful",
        }
    }
}

impl fmt::Display for ModelKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The features a producer (the shared-memory segment, a recording) offers, in its slot order.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct FeatureSchema {
    names: Vec<String>,
}

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SchemaError {
    #[error("the feature schema is empty")]
    Empty,
    #[error("the feature schema names {0:?} twice")]
    Duplicate(String),
    #[error("the feature schema has an empty name (schema {0:?})")]
    EmptyName(String),
}

impl FeatureSchema {
    /// The nine features in the order of thesis Table 3.1.
    pub fn standard() -> Self {
        Self {
            names: FEATURE_NAMES.iter().map(|s| s.to_string()).collect(),
        }
    }

    pub fn new<I, S>(names: I) -> Result<Self, SchemaError>
    where
        I: IntoIterator<Item = S>,
        S: Into<String>,
    {
        let names: Vec<String> = names.into_iter().map(Into::into).collect();
        if names.is_empty() {
            return Err(SchemaError::Empty);
        }
        for (i, n) in names.iter().enumerate() {
            if n.is_empty() {
                return Err(SchemaError::EmptyName(names.join(",")));
            }
            if names[..i].contains(n) {
                return Err(SchemaError::Duplicate(n.clone()));
            }
        }
        Ok(Self { names })
    }

    /// Parses `a,b,c` (spaces around names are ignored).
    pub fn parse(list: &str) -> Result<Self, SchemaError> {
        if list.trim().is_empty() {
            return Err(SchemaError::Empty);
        }
        Self::new(list.split(',').map(|s| s.trim().to_string()))
    }

    pub fn names(&self) -> &[String] {
        &self.names
    }

    pub fn len(&self) -> usize {
        self.names.len()
    }

    pub fn is_empty(&self) -> bool {
        self.names.is_empty()
    }

    pub fn index_of(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn other_feature_gains_are_named_only_where_the_model_uses_them() {
        let loop_gains = (30.0, 100.0);
        let xv = names(&["position_x", "velocity"]);
        let why = gains_mismatch(Some((10.0, 10.0)), &xv, loop_gains).expect("velocity differs");
        assert!(
            why.contains("velocity at g_v 10") && !why.contains("acceleration"),
            "{why}"
        );
        // a model of x and v only: its acceleration filter does not matter
        assert_eq!(gains_mismatch(Some((30.0, 10.0)), &xv, loop_gains), None);
        let six = names(&["position_x", "velocity", "acceleration", "f_previous_a"]);
        assert!(gains_mismatch(Some((30.0, 10.0)), &six, loop_gains).is_some());
        // within 1 %, unknown on either side, or a model that uses neither: nothing to say
        assert_eq!(gains_mismatch(Some((30.2, 100.5)), &six, loop_gains), None);
        assert_eq!(gains_mismatch(None, &six, loop_gains), None);
        assert_eq!(gains_mismatch(Some((10.0, 10.0)), &six, (0.0, 0.0)), None);
        assert_eq!(
            gains_mismatch(Some((10.0, 10.0)), &names(&["position_x"]), loop_gains),
            None
        );
    }

    #[test]
    fn a_step_is_checked_against_the_loop_rate_only_when_both_are_known() {
        assert_eq!(step_mismatch(None, 10_000.0), None);
        assert_eq!(step_mismatch(Some(1e-4), 0.0), None, "no loop status yet");
        assert_eq!(step_mismatch(Some(1e-4), f64::NAN), None);
        assert_eq!(step_mismatch(Some(1e-4), 10_000.0), None);
        assert_eq!(step_mismatch(Some(1.005e-4), 10_000.0), None, "within 1 %");
        let why = step_mismatch(Some(2e-4), 10_000.0).expect("2x the period");
        assert!(why.contains("5000 Hz") && why.contains("10000 Hz") && why.contains("2.000x"));
        let why = step_mismatch(Some(0.02), 10_000.0).expect("a 50 Hz import's step");
        assert!(why.contains("200.000x"), "{why}");
        assert!(step_mismatch(Some(1e-4), 5_000.0)
            .unwrap()
            .contains("0.500x"));
    }

    #[test]
    fn schema_parsing_refuses_duplicates_and_blanks() {
        assert_eq!(FeatureSchema::parse("").unwrap_err(), SchemaError::Empty);
        assert_eq!(
            FeatureSchema::parse("position_x, velocity,position_x").unwrap_err(),
            SchemaError::Duplicate("position_x".into())
        );
        assert!(matches!(
            FeatureSchema::parse("a,,b").unwrap_err(),
            SchemaError::EmptyName(_)
        ));
        let s = FeatureSchema::parse(" velocity , position_x").unwrap();
        assert_eq!(s.names(), ["velocity", "position_x"]);
        assert_eq!(s.index_of("position_x"), Some(1));
        assert_eq!(s.index_of("cycle_no"), None);
    }

    #[test]
    fn standard_schema_is_table_3_1_order() {
        let s = FeatureSchema::standard();
        assert_eq!(s.len(), 9);
        assert_eq!(s.names()[0], "position_x");
        assert_eq!(s.names()[8], "area_fx");
    }

    #[test]
    fn element_counts_are_checked_before_allocation() {
        assert_eq!(checked_elements(&[]), Ok(1));
        assert_eq!(checked_elements(&[1, 1, 64]), Ok(64));
        assert_eq!(checked_elements(&[2, 0, 5]), Ok(0));
        assert_eq!(checked_elements(&[1024, 1024]), Ok(MAX_TENSOR_ELEMENTS));
        for bad in [
            vec![1, 1, 1 << 31],
            vec![1 << 32, 1 << 32, 1 << 32],
            vec![i64::MAX, i64::MAX],
            vec![1025, 1024],
            vec![-1, 4],
            vec![1; 9],
        ] {
            assert!(checked_elements(&bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn kind_round_trips() {
        for k in [ModelKind::Stateless, ModelKind::Stateful] {
            assert_eq!(ModelKind::parse(k.as_str()), Some(k));
        }
        assert_eq!(ModelKind::parse("recurrent"), None);
    }
}
