//! The model contract's checks on plain data: the `haptics.*` metadata entries and the declared
//! input and output names and shapes, as the model module (`mod.rs`) reads them from a model
//! through ONNX Runtime. Kept apart from `mod.rs` (which re-exports everything here) so that they
//! run without ONNX Runtime: the `model_contract` fuzz target (`fuzz/`) compiles this file and
//! `contract.rs` as they are and feeds them arbitrary metadata and shapes. So this file names its
//! sibling as `super::contract`, which is the crate root's `contract` there and `model::contract`
//! here.

use std::path::PathBuf;

use super::contract::{
    checked_elements, FeatureSchema, ModelKind, FEATURE_NAMES, INPUT_C, INPUT_FEATURES, INPUT_H,
    META_FEATURES, META_FEATURE_GAINS, META_KIND, META_PREVIOUS_FORCE, META_PROVENANCE,
    META_REFERENCE, META_STATE_SIZE, META_STEP_S, META_UNITS, OUTPUT_C, OUTPUT_FORCE, OUTPUT_H,
};

fn unknown_hint(name: &str) -> String {
    if FEATURE_NAMES.contains(&name) {
        String::new()
    } else {
        format!(
            "; {name:?} is not one of the nine features of docs/recording-format.md ({})",
            FEATURE_NAMES.join(", ")
        )
    }
}

/// Why a model is refused. Each message says what is wrong and, where it can, what was found.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ModelError {
    #[error("cannot read model file {path}: {reason}")]
    Unreadable { path: PathBuf, reason: String },
    #[error("{path} is not a valid ONNX model (ONNX Runtime refused it: {reason})")]
    Corrupt { path: PathBuf, reason: String },
    #[error("the model's metadata has no `{key}` entry (the contract, docs/model-contract.md, needs haptics.features, haptics.kind, haptics.units, haptics.provenance, and haptics.state_size for stateful models)")]
    MissingMetadata { key: String },
    #[error("metadata `{key}` = {value:?} is invalid: {reason}")]
    BadMetadata {
        key: String,
        value: String,
        reason: String,
    },
    #[error("the model wants feature {name:?}, which the segment's schema does not provide (schema: {}){}", schema.join(", "), unknown_hint(name))]
    MissingFeature { name: String, schema: Vec<String> },
    #[error("a {kind} model must have inputs [{}], this one has [{}]", expected.join(", "), found.join(", "))]
    WrongInputs {
        kind: ModelKind,
        expected: Vec<String>,
        found: Vec<String>,
    },
    #[error("a {kind} model must have outputs [{}], this one has [{}]", expected.join(", "), found.join(", "))]
    WrongOutputs {
        kind: ModelKind,
        expected: Vec<String>,
        found: Vec<String>,
    },
    #[error("{name}: {detail}")]
    BadShape { name: String, detail: String },
    #[error("warm-up run produced a non-finite {output} ({value}) for input {input:?}")]
    NonFinite {
        output: String,
        value: f32,
        input: Vec<f32>,
    },
    #[error("reference step {step} of {steps} (input {input:?}) computes {got} N on this server, where the model's export computed {expected} N (tolerance {tolerance} N): this server's ONNX Runtime or fused operators read the model otherwise than its exporter's did (a build older than the exporter's ignores the attributes it does not know; rebuild: `source scripts/env.sh && haptics_build`), or the graph was changed after its export (export it again: `haptics-train export`)")]
    ReferenceMismatch {
        step: usize,
        steps: usize,
        input: Vec<f32>,
        expected: f32,
        got: f32,
        tolerance: f32,
    },
    #[error("ONNX Runtime failed to run the model: {reason}")]
    RunFailed { reason: String },
    #[error("could not configure the ONNX Runtime session: {reason}")]
    Session { reason: String },
    #[error("loading and warming up the model took longer than the limit of {limit_s} s; it was stopped (a model this slow could not keep up with the loop)")]
    TimedOut { limit_s: f64 },
    #[error("{running} model loads that ran out of time are still running (each finishes its current run first); try again in a moment")]
    Busy { running: usize },
}

impl ModelError {
    /// A stable machine-readable code (used by `validate --json` and the control plane).
    pub fn code(&self) -> &'static str {
        match self {
            Self::Unreadable { .. } => "unreadable",
            Self::Corrupt { .. } => "corrupt",
            Self::MissingMetadata { .. } => "missing_metadata",
            Self::BadMetadata { .. } => "bad_metadata",
            Self::MissingFeature { .. } => "missing_feature",
            Self::WrongInputs { .. } => "wrong_inputs",
            Self::WrongOutputs { .. } => "wrong_outputs",
            Self::BadShape { .. } => "bad_shape",
            Self::NonFinite { .. } => "non_finite_output",
            Self::ReferenceMismatch { .. } => "reference_mismatch",
            Self::RunFailed { .. } => "run_failed",
            Self::Session { .. } => "session_failed",
            Self::TimedOut { .. } => "timed_out",
            Self::Busy { .. } => "busy",
        }
    }
}

/// The parsed `haptics.*` metadata.
#[derive(Debug, Clone, PartialEq)]
pub struct Metadata {
    pub features: Vec<String>,
    pub kind: ModelKind,
    pub units: String,
    pub provenance: serde_json::Value,
    /// `haptics.state_size`: H, required for stateful models.
    pub state_size: Option<usize>,
    /// `haptics.previous_force`, when a feature uses the previous force (informational).
    pub previous_force: Option<String>,
    /// `haptics.step_s`: the period the state steps at, s (checked against the loop's rate
    /// when the model is activated).
    pub step_s: Option<f64>,
    /// `haptics.feature_gains`: (g_v, g_a) of its training features, rad/s (compared with the
    /// loop's when the model is activated).
    pub feature_gains: Option<(f64, f64)>,
    /// `haptics.reference`: steps the engine checks itself against when it loads the model.
    pub reference: Option<Reference>,
}

/// A model's reference steps (`haptics.reference`), checked when parsed (ort-host's
/// `reference.rs`: the format both processes read).
pub use haptics_ort_host::reference::Reference;

/// Parses `haptics.reference` for a model of `n` features. The error's value is the entry's
/// size, not its text (kilobytes of numbers).
pub fn parse_reference(raw: &str, n: usize) -> Result<Reference, ModelError> {
    haptics_ort_host::reference::parse(raw, n).map_err(|reason| ModelError::BadMetadata {
        key: META_REFERENCE.to_string(),
        value: format!("<{} bytes>", raw.len()),
        reason,
    })
}

/// Checks the `haptics.*` metadata entries; `custom(key)` is the model's entry for `key`.
pub fn parse_metadata(custom: impl Fn(&str) -> Option<String>) -> Result<Metadata, ModelError> {
    let get = |key: &str| {
        custom(key).ok_or_else(|| ModelError::MissingMetadata {
            key: key.to_string(),
        })
    };
    let features_raw = get(META_FEATURES)?;
    let kind_raw = get(META_KIND)?;
    let units = get(META_UNITS)?;
    let provenance_raw = get(META_PROVENANCE)?;

    let bad = |key: &str, value: &str, reason: String| ModelError::BadMetadata {
        key: key.to_string(),
        value: value.to_string(),
        reason,
    };
    let features: Vec<String> = features_raw
        .split(',')
        .map(|s| s.trim().to_string())
        .collect();
    if features.iter().any(String::is_empty) {
        return Err(bad(
            META_FEATURES,
            &features_raw,
            "empty feature name (expected comma-separated names, e.g. position_x,velocity)".into(),
        ));
    }
    for (i, f) in features.iter().enumerate() {
        if features[..i].contains(f) {
            return Err(bad(
                META_FEATURES,
                &features_raw,
                format!("{f:?} is listed twice"),
            ));
        }
    }
    let kind = ModelKind::parse(&kind_raw).ok_or_else(|| {
        bad(
            META_KIND,
            &kind_raw,
            "must be `stateless` or `stateful`".into(),
        )
    })?;
    if units.trim().is_empty() {
        return Err(bad(
            META_UNITS,
            &units,
            "empty (the force unit, e.g. N)".into(),
        ));
    }
    let provenance: serde_json::Value = serde_json::from_str(&provenance_raw)
        .map_err(|e| bad(META_PROVENANCE, &provenance_raw, format!("not JSON: {e}")))?;
    if !provenance.is_object() {
        return Err(bad(
            META_PROVENANCE,
            &provenance_raw,
            "must be a JSON object".into(),
        ));
    }
    let state_size = match (kind, custom(META_STATE_SIZE)) {
        (ModelKind::Stateful, None) => {
            return Err(ModelError::MissingMetadata {
                key: META_STATE_SIZE.to_string(),
            })
        }
        (_, None) => None,
        (_, Some(raw)) => Some(
            raw.trim()
                .parse::<usize>()
                .ok()
                .filter(|&h| h > 0)
                .ok_or_else(|| bad(META_STATE_SIZE, &raw, "must be a positive integer".into()))?,
        ),
    };
    let step_s = match custom(META_STEP_S) {
        None => None,
        Some(raw) => Some(
            raw.trim()
                .parse::<f64>()
                .ok()
                .filter(|s| s.is_finite() && *s > 0.0 && *s < 1.0)
                .ok_or_else(|| {
                    bad(
                        META_STEP_S,
                        &raw,
                        "must be the state's step in seconds, a number in (0, 1)".into(),
                    )
                })?,
        ),
    };
    let feature_gains =
        match custom(META_FEATURE_GAINS) {
            None => None,
            Some(raw) => {
                let v: Option<serde_json::Value> = serde_json::from_str(&raw).ok();
                let gain = |k: &str| {
                    v.as_ref()
                        .and_then(|v| v.get(k))
                        .and_then(serde_json::Value::as_f64)
                        .filter(|g| g.is_finite() && *g > 0.0)
                };
                match (gain("g_v"), gain("g_a")) {
                    (Some(g_v), Some(g_a)) => Some((g_v, g_a)),
                    _ => return Err(bad(
                        META_FEATURE_GAINS,
                        &raw,
                        "must be a JSON object {\"g_v\": rad/s, \"g_a\": rad/s} of positive gains"
                            .into(),
                    )),
                }
            }
        };
    let reference = match custom(META_REFERENCE) {
        None => None,
        Some(raw) => Some(parse_reference(&raw, features.len())?),
    };
    Ok(Metadata {
        features,
        kind,
        units,
        provenance,
        state_size,
        previous_force: custom(META_PREVIOUS_FORCE),
        step_s,
        feature_gains,
        reference,
    })
}

/// Maps each model feature to its index in `schema`, refusing the first one missing.
pub fn map_features(features: &[String], schema: &FeatureSchema) -> Result<Vec<usize>, ModelError> {
    features
        .iter()
        .map(|f| {
            schema
                .index_of(f)
                .ok_or_else(|| ModelError::MissingFeature {
                    name: f.clone(),
                    schema: schema.names().to_vec(),
                })
        })
        .collect()
}

/// The concrete shapes the engine will allocate, derived from the declared signature.
#[derive(Debug, Clone, PartialEq)]
pub struct Signature {
    pub features_shape: Vec<i64>,
    pub state_shape: Option<Vec<i64>>,
    /// Declared shape of `force` (dimensions may be -1 = dynamic).
    pub force_declared: Vec<i64>,
}

/// A declared input or output: its name, and its shape or why it is not a float32 tensor.
pub type Declared = (String, Result<Vec<i64>, ModelError>);

/// Checks the declared input/output names and shapes against the contract for the metadata's
/// `kind` and feature count.
pub fn check_declared(
    inputs: &[Declared],
    outputs: &[Declared],
    meta: &Metadata,
) -> Result<Signature, ModelError> {
    let kind = meta.kind;
    let n = meta.features.len();
    let input_names: Vec<String> = inputs.iter().map(|(name, _)| name.clone()).collect();
    let output_names: Vec<String> = outputs.iter().map(|(name, _)| name.clone()).collect();
    let (want_in, want_out): (&[&str], &[&str]) = match kind {
        ModelKind::Stateless => (&[INPUT_FEATURES], &[OUTPUT_FORCE]),
        ModelKind::Stateful => (
            &[INPUT_FEATURES, INPUT_H, INPUT_C],
            &[OUTPUT_FORCE, OUTPUT_H, OUTPUT_C],
        ),
    };
    let same_set = |have: &[String], want: &[&str]| {
        have.len() == want.len() && want.iter().all(|w| have.iter().any(|h| h == w))
    };
    if !same_set(&input_names, want_in) {
        return Err(ModelError::WrongInputs {
            kind,
            expected: want_in.iter().map(|s| s.to_string()).collect(),
            found: input_names,
        });
    }
    if !same_set(&output_names, want_out) {
        return Err(ModelError::WrongOutputs {
            kind,
            expected: want_out.iter().map(|s| s.to_string()).collect(),
            found: output_names,
        });
    }
    let declared = |list: &[Declared], name: &str| {
        list.iter()
            .find(|(have, _)| have == name)
            .map(|(_, shape)| shape.clone())
            .expect("checked above")
    };
    let input = |name: &str| declared(inputs, name);
    let output = |name: &str| declared(outputs, name);

    // features: [N, n] for stateless (we feed N = 1); [1, n] or [1, 1, n] for stateful.
    let declared = input(INPUT_FEATURES)?;
    let shape_err = |detail: String| ModelError::BadShape {
        name: INPUT_FEATURES.to_string(),
        detail,
    };
    let rank_ok = match kind {
        ModelKind::Stateless => declared.len() == 2,
        ModelKind::Stateful => declared.len() == 2 || declared.len() == 3,
    };
    if !rank_ok {
        return Err(shape_err(format!(
            "declared shape {declared:?}; the contract wants {}",
            match kind {
                ModelKind::Stateless => "[N, n]",
                ModelKind::Stateful => "[1, n] or [1, 1, n]",
            }
        )));
    }
    let last = *declared.last().expect("rank checked");
    if last >= 0 && last as usize != n {
        return Err(shape_err(format!(
            "declared shape {declared:?} takes {last} features, but haptics.features names {n}"
        )));
    }
    if declared[..declared.len() - 1].iter().any(|&d| d > 1) {
        return Err(shape_err(format!(
            "declared shape {declared:?}: leading dimensions must be 1 or dynamic (one sample per step)"
        )));
    }
    let mut features_shape = vec![1; declared.len()];
    *features_shape.last_mut().expect("rank checked") = n as i64;

    let force_declared = output(OUTPUT_FORCE)?;
    if force_declared.iter().any(|&d| d > 1) {
        return Err(ModelError::BadShape {
            name: OUTPUT_FORCE.to_string(),
            detail: format!(
                "declared shape {force_declared:?}: one force per sample expected ([N, 1])"
            ),
        });
    }

    let state_shape = match kind {
        ModelKind::Stateless => None,
        ModelKind::Stateful => {
            let h = input(INPUT_H)?;
            let c = input(INPUT_C)?;
            let ho = output(OUTPUT_H)?;
            let co = output(OUTPUT_C)?;
            let hidden = h.last().copied().unwrap_or(-1);
            if h.is_empty() || hidden <= 0 {
                return Err(ModelError::BadShape {
                    name: INPUT_H.to_string(),
                    detail: format!(
                        "declared shape {h:?}: the hidden size (last dimension) must be fixed"
                    ),
                });
            }
            // Leading dimensions (layers, batch) must be fixed or dynamic-batch (taken as 1).
            let concrete: Vec<i64> = h.iter().map(|&d| if d < 0 { 1 } else { d }).collect();
            let compatible = |other: &[i64]| {
                other.len() == h.len()
                    && other.iter().zip(&concrete).all(|(&o, &w)| o < 0 || o == w)
            };
            for (name, s) in [(INPUT_C, &c), (OUTPUT_H, &ho), (OUTPUT_C, &co)] {
                if !compatible(s) {
                    return Err(ModelError::BadShape {
                        name: name.to_string(),
                        detail: format!("declared shape {s:?} differs from h_in's {h:?}"),
                    });
                }
            }
            checked_elements(&concrete).map_err(|detail| ModelError::BadShape {
                name: INPUT_H.to_string(),
                detail,
            })?;
            if let Some(size) = meta.state_size {
                if i64::try_from(size).ok() != Some(hidden) {
                    return Err(ModelError::BadMetadata {
                        key: META_STATE_SIZE.to_string(),
                        value: size.to_string(),
                        reason: format!("h_in's hidden size is {hidden}"),
                    });
                }
            }
            Some(concrete)
        }
    };
    Ok(Signature {
        features_shape,
        state_shape,
        force_declared,
    })
}

#[cfg(test)]
mod tests {
    use super::super::contract::MAX_REFERENCE_STEPS;
    use super::*;

    fn meta_with(step: Option<&str>) -> Result<Metadata, ModelError> {
        meta_with_gains(step, None)
    }

    fn meta_with_gains(step: Option<&str>, gains: Option<&str>) -> Result<Metadata, ModelError> {
        parse_with(
            "stateful",
            &[(META_STEP_S, step), (META_FEATURE_GAINS, gains)],
        )
    }

    /// The metadata of a model of `kind` over (position_x, velocity), with `extra` entries
    /// (None: the entry is absent).
    fn parse_with(kind: &str, extra: &[(&str, Option<&str>)]) -> Result<Metadata, ModelError> {
        parse_metadata(|k| {
            if let Some((_, v)) = extra.iter().find(|(key, _)| *key == k) {
                return v.map(str::to_string);
            }
            match k {
                META_FEATURES => Some("position_x,velocity".into()),
                META_KIND => Some(kind.into()),
                META_UNITS => Some("N".into()),
                META_PROVENANCE => Some("{}".into()),
                META_STATE_SIZE => Some("4".into()),
                _ => None,
            }
        })
    }

    #[test]
    fn reference_steps_are_optional_and_checked_before_anything_steps_them() {
        let ok = r#"{"inputs": [[0.001, 0.01], [0.002, -0.5]], "force": [0.25, 0.5],
                     "tolerance_n": 1e-4, "source": "test"}"#;
        let r = parse_reference(ok, 2).unwrap();
        assert_eq!(r.inputs, [[0.001, 0.01], [0.002, -0.5]]);
        assert_eq!((r.force.len(), r.tolerance_n), (2, 1e-4));
        // the whole metadata: absent, or parsed for the model's feature count
        let with = |raw: Option<&str>| parse_with("stateless", &[(META_REFERENCE, raw)]);
        assert_eq!(with(None).unwrap().reference, None);
        assert_eq!(with(Some(ok)).unwrap().reference, Some(r));
        let doc = |inputs: &str, force: &str, tolerance: &str| {
            format!(r#"{{"inputs": {inputs}, "force": {force}, "tolerance_n": {tolerance}}}"#)
        };
        let many = format!(
            r#"{{"inputs": {rows}, "force": {forces}, "tolerance_n": 1e-4}}"#,
            rows = serde_json::json!(vec![[0.0, 0.0]; MAX_REFERENCE_STEPS + 1]),
            forces = serde_json::json!(vec![0.0; MAX_REFERENCE_STEPS + 1]),
        );
        for (bad, says) in [
            ("", "not a JSON object"),
            ("[1, 2]", "not a JSON object"),
            (r#"{"inputs": [[0, 0]], "force": [0]}"#, "not a JSON object"),
            (&doc("[]", "[]", "1e-4"), "0 forces"),
            (&doc("[[0, 0]]", "[0, 1]", "1e-4"), "1 input rows for 2"),
            (&doc("[[0, 0, 0]]", "[0]", "1e-4"), "row 0 has 3 values"),
            // past f32's range: read as infinite, or refused by the JSON reader itself,
            // depending on serde_json's features in the build (JSON has no NaN or infinity)
            (
                &doc("[[0, 1e39]]", "[0]", "1e-4"),
                "not finite|out of range",
            ),
            (&doc("[[0, 0]]", "[0]", "0"), "tolerance_n 0"),
            (&doc("[[0, 0]]", "[0]", "0.5"), "tolerance_n 0.5"),
            (&many, "257 forces"),
        ] {
            let e = with(Some(bad)).unwrap_err();
            match &e {
                ModelError::BadMetadata { key, value, reason } => {
                    assert_eq!(key, META_REFERENCE, "{bad:?}");
                    assert_eq!(
                        value,
                        &format!("<{} bytes>", bad.len()),
                        "the size, not the text"
                    );
                    assert!(
                        says.split('|').any(|s| reason.contains(s)),
                        "{bad:?}: {reason}"
                    );
                }
                other => panic!("{bad:?}: {other}"),
            }
        }
    }

    #[test]
    fn the_step_is_optional_and_must_be_a_period_in_seconds() {
        assert_eq!(meta_with(None).unwrap().step_s, None);
        assert_eq!(meta_with(Some("0.0001")).unwrap().step_s, Some(1e-4));
        assert_eq!(meta_with(Some(" 2e-4 ")).unwrap().step_s, Some(2e-4));
        for bad in ["0", "-1e-4", "NaN", "inf", "1.5", "10 kHz", ""] {
            let e = meta_with(Some(bad)).unwrap_err();
            assert!(
                matches!(&e, ModelError::BadMetadata { key, .. } if key == META_STEP_S),
                "{bad:?}: {e}"
            );
        }
    }

    #[test]
    fn the_feature_gains_are_optional_and_must_be_two_positive_gains() {
        assert_eq!(meta_with(None).unwrap().feature_gains, None);
        let m = meta_with_gains(None, Some(r#"{"g_v": 10.0, "g_a": 10}"#)).unwrap();
        assert_eq!(m.feature_gains, Some((10.0, 10.0)));
        for bad in [
            "",
            "10",
            r#"{"g_v": 10}"#,
            r#"{"g_v": -1, "g_a": 1}"#,
            r#"{"g_v": "x", "g_a": 1}"#,
        ] {
            let e = meta_with_gains(None, Some(bad)).unwrap_err();
            assert!(
                matches!(&e, ModelError::BadMetadata { key, .. } if key == META_FEATURE_GAINS),
                "{bad:?}: {e}"
            );
        }
    }
}
