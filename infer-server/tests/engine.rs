//! StepEngine against hand-computed values, and every way validation must refuse a model.

mod common;

use std::path::Path;

use infer_server::model::contract::FEATURE_NAMES;
use infer_server::{FeatureSchema, ModelError, ModelKind, SessionConfig, StepEngine, StepError};

fn load(path: &Path, schema: &FeatureSchema) -> Result<StepEngine, ModelError> {
    StepEngine::load(common::runtime(), path, schema, &SessionConfig::default())
}

/// A schema-ordered vector (the nine standard features) with the given values set.
fn standard_vector(values: &[(&str, f64)]) -> Vec<f64> {
    let mut v = vec![0.0; 9];
    for (name, value) in values {
        let i = FEATURE_NAMES.iter().position(|n| n == name).unwrap();
        v[i] = *value;
    }
    v
}

fn close(a: f32, b: f64, tol: f64) -> bool {
    ((a as f64) - b).abs() <= tol * (1.0 + b.abs())
}

#[test]
fn linear_model_matches_hand_computation_through_the_schema_map() {
    let path = model_or_skip!("linear");
    let schema = FeatureSchema::standard();
    let mut engine = load(&path, &schema).expect("linear model is valid");
    let info = engine.info();
    assert_eq!(info.kind, ModelKind::Stateless);
    assert_eq!(info.features, ["velocity", "position_x"]);
    assert_eq!(info.input_map, [1, 0]);
    assert_eq!(info.units, "N");
    assert_eq!(info.provenance["seed"], 0);
    // force = 2 velocity - 3 position_x + 0.5
    for (x, v) in [
        (0.0, 0.0),
        (0.2, 0.7),
        (-1.5, 3.25),
        (0.004, -0.02),
        (1e3, 1e-3),
    ] {
        let input = standard_vector(&[("position_x", x), ("velocity", v), ("cycle_no", 7.0)]);
        let got = engine.step(&input).unwrap();
        let want = 2.0 * v - 3.0 * x + 0.5;
        assert!(
            close(got, want, 1e-6),
            "x={x} v={v}: got {got}, want {want}"
        );
    }
}

#[test]
fn any_schema_order_and_subset_works() {
    let path = model_or_skip!("linear");
    // A producer offering only three features, in its own order.
    let schema = FeatureSchema::parse("velocity,area_fx,position_x").unwrap();
    let mut engine = load(&path, &schema).unwrap();
    assert_eq!(engine.info().input_map, [0, 2]);
    let got = engine.step(&[0.7f32, 99.0, 0.2]).unwrap();
    assert!(close(got, 2.0 * 0.7 - 3.0 * 0.2 + 0.5, 1e-6), "{got}");
    // A non-finite feature the model uses is refused; one it does not use is ignored.
    assert_eq!(
        engine.step(&[f32::NAN, 99.0, 0.2]).unwrap_err(),
        StepError::NonFiniteFeature { schema_index: 0 }
    );
    assert_eq!(
        engine.step(&[0.7f64, 99.0, 1e300]).unwrap_err(),
        StepError::NonFiniteFeature { schema_index: 2 },
        "beyond f32's range counts as infinite"
    );
    assert!(engine.step(&[0.7f32, f32::INFINITY, 0.2]).is_ok());
    // A vector shorter than the schema is refused without touching the model.
    assert_eq!(
        engine.step(&[0.7f32, 99.0]).unwrap_err(),
        StepError::SchemaLength {
            expected: 3,
            got: 2
        }
    );
}

/// The tree fixture's function, written out independently of the ONNX graph.
fn tree_reference(position_x: f32, f_previous_x: f32) -> f32 {
    let t0 = if position_x <= 0.5 {
        1.0
    } else if f_previous_x <= 2.0 {
        2.0
    } else {
        3.0
    };
    let t1 = if f_previous_x <= -1.0 { 10.0 } else { 20.0 };
    t0 + t1 + 0.25
}

#[test]
fn tree_ensemble_takes_the_hand_computed_branches() {
    let path = model_or_skip!("tree");
    let mut engine = load(&path, &FeatureSchema::standard()).unwrap();
    assert_eq!(engine.info().input_map, [0, 3]);
    // Includes the thresholds themselves (<= goes left) and values just past them.
    let xs = [-1.0f32, 0.0, 0.5, 0.500_001, 0.75, 10.0];
    let fs = [-5.0f32, -1.0, -0.999_99, 0.0, 2.0, 2.000_001, 100.0];
    let mut distinct = std::collections::BTreeSet::new();
    for &x in &xs {
        for &f in &fs {
            let input = standard_vector(&[("position_x", x as f64), ("f_previous_x", f as f64)]);
            let got = engine.step(&input).unwrap();
            let want = tree_reference(x, f);
            assert_eq!(got, want, "position_x={x} f_previous_x={f}");
            distinct.insert((want * 4.0) as i32);
        }
    }
    // Every reachable leaf combination was hit: {1,2,3} x {10,20} except 3 + 10, which needs
    // f_previous_x > 2 and <= -1 at once.
    assert_eq!(distinct.len(), 5);
}

/// ONNX LSTM (gate order i, o, f, c; sigmoid/tanh/tanh), stepped one sample at a time, with
/// the fixture's weight formulas (tests/fixtures/make_models.py `lstm_weights`).
struct ReferenceLstm {
    w: Vec<Vec<f64>>, // [4H][I]
    r: Vec<Vec<f64>>, // [4H][H]
    b: Vec<f64>,      // [8H]
    w_out: [f64; 3],
    b_out: f64,
    h: Vec<f64>,
    c: Vec<f64>,
}

const H: usize = 3;
const I: usize = 2;

impl ReferenceLstm {
    fn new() -> Self {
        // float32 weights, as the fixture stores them
        let f = |v: f64| v as f32 as f64;
        let w = (0..4 * H)
            .map(|r| {
                (0..I)
                    .map(|c| f(0.1 * (((r * I + c) % 7) as f64 - 3.0)))
                    .collect()
            })
            .collect();
        let rr = (0..4 * H)
            .map(|r| {
                (0..H)
                    .map(|c| f(0.05 * (((r * H + c) % 5) as f64 - 2.0)))
                    .collect()
            })
            .collect();
        let b = (0..8 * H)
            .map(|k| f(0.01 * ((k % 9) as f64 - 4.0)))
            .collect();
        Self {
            w,
            r: rr,
            b,
            w_out: [0.5, -1.0, 2.0],
            b_out: f(0.1),
            h: vec![0.0; H],
            c: vec![0.0; H],
        }
    }

    fn step(&mut self, x: [f64; I]) -> f64 {
        let sig = |v: f64| 1.0 / (1.0 + (-v).exp());
        let gate = |g: usize, k: usize, this: &Self| {
            let row = g * H + k;
            let mut acc = this.b[row] + this.b[4 * H + row];
            for (j, xj) in x.iter().enumerate() {
                acc += this.w[row][j] * xj;
            }
            for j in 0..H {
                acc += this.r[row][j] * this.h[j];
            }
            acc
        };
        let mut h = vec![0.0; H];
        let mut c = vec![0.0; H];
        for k in 0..H {
            let i = sig(gate(0, k, self));
            let o = sig(gate(1, k, self));
            let fg = sig(gate(2, k, self));
            let cand = gate(3, k, self).tanh();
            c[k] = fg * self.c[k] + i * cand;
            h[k] = o * c[k].tanh();
        }
        self.h = h;
        self.c = c;
        (0..H).map(|k| self.w_out[k] * self.h[k]).sum::<f64>() + self.b_out
    }
}

fn lstm_input(t: usize) -> (f64, f64) {
    // (f_previous_x, position_x): a slow ramp and an oscillation, so the state matters.
    let f = ((t as f64) * 0.37).sin() * 2.0;
    let x = (t as f64) * 0.05 - 1.0;
    (f, x)
}

#[test]
fn lstm_carries_state_between_steps_and_resets() {
    let path = model_or_skip!("lstm");
    let schema = FeatureSchema::standard();
    let mut engine = load(&path, &schema).unwrap();
    let info = engine.info();
    assert_eq!(info.kind, ModelKind::Stateful);
    assert_eq!(info.features, ["f_previous_x", "position_x"]);
    assert_eq!(info.state_shape.as_deref(), Some(&[1i64, 1, 3][..]));
    assert!(
        engine.hidden_state().iter().all(|&v| v == 0.0),
        "warm-up leaves the state reset"
    );

    let mut reference = ReferenceLstm::new();
    let mut first = Vec::new();
    for t in 0..60 {
        let (f, x) = lstm_input(t);
        let input = standard_vector(&[("f_previous_x", f), ("position_x", x)]);
        let got = engine.step(&input).unwrap();
        let want = reference.step([f, x]);
        assert!(close(got, want, 1e-5), "step {t}: got {got}, want {want}");
        for (k, (&g, &w)) in engine.hidden_state().iter().zip(&reference.h).enumerate() {
            assert!(close(g, w, 1e-5), "step {t} h[{k}]: got {g}, want {w}");
        }
        first.push(got);
    }
    // The same input twice in a row gives different outputs: the state is carried.
    let input = standard_vector(&[("f_previous_x", 1.0), ("position_x", 0.5)]);
    let a = engine.step(&input).unwrap();
    let b = engine.step(&input).unwrap();
    assert_ne!(a, b);

    // After reset the sequence replays exactly.
    engine.reset();
    assert!(engine.hidden_state().iter().all(|&v| v == 0.0));
    for (t, &want) in first.iter().enumerate().take(10) {
        let (f, x) = lstm_input(t);
        let input = standard_vector(&[("f_previous_x", f), ("position_x", x)]);
        assert_eq!(engine.step(&input).unwrap(), want, "replay step {t}");
    }
}

fn refused(name: &str, schema: &FeatureSchema) -> Option<ModelError> {
    let dir = common::fixtures()?;
    match load(&dir.join(format!("{name}.onnx")), schema) {
        Ok(_) => panic!("{name}.onnx was accepted"),
        Err(e) => {
            eprintln!("{name}: {e}");
            Some(e)
        }
    }
}

#[test]
fn broken_models_are_refused_with_the_right_error() {
    let std_schema = FeatureSchema::standard();
    let Some(e) = refused("corrupt", &std_schema) else {
        return;
    };
    assert!(matches!(e, ModelError::Corrupt { .. }), "{e:?}");
    assert!(e.to_string().contains("not a valid ONNX model"));

    let e = refused("truncated", &std_schema).unwrap();
    assert!(matches!(e, ModelError::Corrupt { .. }), "{e:?}");

    let e = refused("wrong_input", &std_schema).unwrap();
    match &e {
        ModelError::WrongInputs {
            kind,
            expected,
            found,
        } => {
            assert_eq!(*kind, ModelKind::Stateless);
            assert_eq!(expected, &["features"]);
            assert_eq!(found, &["x"]);
        }
        other => panic!("{other:?}"),
    }

    let no_deformation = FeatureSchema::parse("position_x,velocity,acceleration").unwrap();
    let e = refused("needs_deformation", &no_deformation).unwrap();
    assert_eq!(
        e,
        ModelError::MissingFeature {
            name: "deformation".into(),
            schema: no_deformation.names().to_vec()
        }
    );
    // ... and the same file is fine where the schema has the feature.
    load(
        &common::fixtures().unwrap().join("needs_deformation.onnx"),
        &std_schema,
    )
    .expect("valid against the standard schema");

    let e = refused("unknown_feature", &std_schema).unwrap();
    assert!(
        matches!(&e, ModelError::MissingFeature { name, .. } if name == "temperature"),
        "{e:?}"
    );
    assert!(e.to_string().contains("not one of the nine features"));

    let e = refused("shape_mismatch", &std_schema).unwrap();
    assert!(
        matches!(&e, ModelError::BadShape { name, .. } if name == "features"),
        "{e:?}"
    );

    let e = refused("nan_output", &std_schema).unwrap();
    match &e {
        ModelError::NonFinite { output, value, .. } => {
            assert_eq!(output, "force");
            assert!(value.is_nan());
        }
        other => panic!("{other:?}"),
    }

    let e = refused("no_kind", &std_schema).unwrap();
    assert_eq!(
        e,
        ModelError::MissingMetadata {
            key: "haptics.kind".into()
        }
    );

    let e = refused("bad_provenance", &std_schema).unwrap();
    assert!(
        matches!(&e, ModelError::BadMetadata { key, .. } if key == "haptics.provenance"),
        "{e:?}"
    );

    let e = refused("stateful_without_state", &std_schema).unwrap();
    assert!(
        matches!(&e, ModelError::WrongInputs { kind: ModelKind::Stateful, found, .. } if found == &["features"]),
        "{e:?}"
    );

    let e = refused("lstm_no_c_in", &std_schema).unwrap();
    assert!(
        matches!(&e, ModelError::WrongInputs { found, .. } if found == &["features", "h_in"]),
        "{e:?}"
    );

    let e = load(Path::new("/nonexistent/model.onnx"), &std_schema).unwrap_err();
    assert!(matches!(e, ModelError::Unreadable { .. }), "{e:?}");
}

#[test]
fn io_binding_path_gives_identical_results() {
    let Some(dir) = common::fixtures() else {
        return;
    };
    let schema = FeatureSchema::standard();
    let bound = SessionConfig {
        io_binding: true,
        ..SessionConfig::default()
    };
    let run = SessionConfig {
        io_binding: false,
        ..SessionConfig::default()
    };
    for name in ["linear", "tree", "lstm"] {
        let path = dir.join(format!("{name}.onnx"));
        let mut plain = StepEngine::load(common::runtime(), &path, &schema, &run).unwrap();
        let mut binding = StepEngine::load(common::runtime(), &path, &schema, &bound).unwrap();
        let mut reference = ReferenceLstm::new();
        for t in 0..100 {
            let (f, x) = lstm_input(t);
            let input =
                standard_vector(&[("f_previous_x", f), ("position_x", x), ("velocity", f * x)]);
            let a = plain.step(&input).unwrap();
            let b = binding.step(&input).unwrap();
            assert_eq!(a, b, "{name} step {t}");
            if name == "lstm" {
                let want = reference.step([f, x]);
                assert!(close(b, want, 1e-5), "{name} step {t}: {b} vs {want}");
            }
        }
    }
}

#[test]
fn warm_up_is_timed_into_the_cost() {
    let Some(dir) = common::fixtures() else {
        return;
    };
    let schema = FeatureSchema::standard();
    for name in ["linear", "lstm"] {
        let engine = load(&dir.join(format!("{name}.onnx")), &schema).unwrap();
        let cost = &engine.info().cost;
        // the fixtures were exported without `haptics.cost`
        assert!(cost["export"].is_null(), "{name}: {cost}");
        let p50 = cost["warmup"]["p50_us"].as_f64().unwrap();
        let max = cost["warmup"]["max_us"].as_f64().unwrap();
        assert!(p50 > 0.0 && p50 <= max, "{name}: {cost}");
        assert_eq!(cost["warmup"]["deadline_us"], 50.0);
        // a fixture steps in microseconds: nothing to warn about unless the machine stalls
        // for the whole warm-up (the warning itself: the wording is in engine.rs)
        if p50 < 50.0 {
            assert!(engine.cost_warning().is_none(), "{name}: {cost}");
        }
    }
}

/// `haptics.reference` (docs/model-contract.md): the engine steps a model's reference rows
/// from the zero state when it loads it, and refuses the model where a force is further than
/// the tolerance from what its export computed.
#[test]
fn reference_steps_are_checked_at_load() {
    let schema = FeatureSchema::standard();
    // The linear model's own forces: it loads and serves as the plain one does.
    let mut engine = load(&model_or_skip!("linear_reference"), &schema).expect("agrees");
    let input = standard_vector(&[("position_x", 0.2), ("velocity", 0.7)]);
    let got = engine.step(&input).unwrap();
    assert!(close(got, 2.0 * 0.7 - 3.0 * 0.2 + 0.5, 1e-6), "{got}");
    // The LSTM's forces as ONNX Runtime computed them stepping it from the zero state: the
    // engine carries its state between the twelve steps as that stepping did (a state not
    // carried, or not swapped, gives other forces from the second step on), and the check
    // leaves the state at zero for the loop.
    let engine = load(&model_or_skip!("lstm_reference"), &schema).expect("agrees");
    assert!(engine.hidden_state().iter().all(|&v| v == 0.0));
    // One force 10 mN off: refused, naming the step, both forces and the tolerance.
    let err = load(&model_or_skip!("linear_reference_wrong"), &schema).unwrap_err();
    assert_eq!(err.code(), "reference_mismatch", "{err}");
    match &err {
        ModelError::ReferenceMismatch {
            step,
            steps,
            expected,
            got,
            tolerance,
            input,
        } => {
            assert_eq!((*step, *steps), (5, 8));
            assert!((expected - got - 0.01).abs() < 1e-5, "{expected} {got}");
            assert_eq!(*tolerance, 1e-4);
            assert_eq!(input.len(), 2);
        }
        other => panic!("{other:?}"),
    }
    assert!(err.to_string().contains("haptics_build"), "{err}");
    // A row of the wrong width: the entry is refused as metadata, its size named, not its text.
    let err = load(&model_or_skip!("linear_reference_bad"), &schema).unwrap_err();
    assert_eq!(err.code(), "bad_metadata", "{err}");
    let msg = err.to_string();
    assert!(
        msg.contains("row 3 has 3 values; the graph has 2 features"),
        "{msg}"
    );
    assert!(
        msg.contains("bytes>") && !msg.contains("tolerance_n\""),
        "{msg}"
    );
}
