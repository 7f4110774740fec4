//! infer-server serves a model made of one fused operator (`ai.haptics:StructuredStep`,
//! `ai.haptics:ForestStep`, fused-ops/): the domain is registered on every session it opens.
//! The fixtures' models are recomputed here by hand (not with fused-ops' code), and a node with
//! a bad attribute is refused at load with the kernel's one-line error.

mod common;

use infer_server::{FeatureSchema, ModelKind, SessionConfig, StepEngine};

/// The fixture's model (make_models.py `write_structured_fused`), stepped in f64 from f32 x:
/// f = fe + 0.3 q + 0.1 fe u, fe = 2 tanh(e / 10 mm), 0 out of contact.
struct Reference {
    q: f64,
    u: f64,
    fe_prev: f64,
    e_prev: f64,
}

impl Reference {
    fn step(&mut self, x: f64) -> f64 {
        let ec = x.max(0.0);
        let fe = 2.0 * (ec / 0.01).tanh();
        self.q = (-1e-3f64 / 0.5).exp() * self.q + fe - self.fe_prev;
        self.fe_prev = fe;
        let de = ec - self.e_prev.max(0.0);
        self.e_prev = x;
        if ec <= 0.0 {
            self.u = 0.0;
        } else if de != 0.0 {
            let a = (-de.abs() / 0.002).exp();
            self.u = a * self.u + (1.0 - a) * de.signum();
        }
        if ec > 0.0 {
            (fe + 0.3 * self.q + 0.1 * fe * self.u).max(0.0)
        } else {
            0.0
        }
    }
}

#[test]
fn a_fused_structured_model_is_served_and_steps_as_written() {
    let path = model_or_skip!("structured_fused");
    let schema = FeatureSchema::standard();
    let mut engine =
        StepEngine::load(common::runtime(), &path, &schema, &SessionConfig::default()).unwrap();
    assert_eq!(engine.info().kind, ModelKind::Stateful);
    assert_eq!(
        engine.info().state_shape.as_deref(),
        Some(&[1i64, 1, 5][..])
    );
    let mut reference = Reference {
        q: 0.0,
        u: 0.0,
        fe_prev: 0.0,
        e_prev: 0.0,
    };
    let mut pushed = 0;
    for n in 0..600 {
        let x = f64::from((0.004 * (n as f64 * 0.013).sin()) as f32);
        let mut input = [0.0f64; 9];
        input[0] = x; // position_x
        let got = f64::from(engine.step(&input).unwrap());
        let want = reference.step(x);
        assert!(
            (got - want).abs() < 1e-5,
            "step {n} x {x}: got {got}, want {want}"
        );
        pushed += usize::from(got > 0.5);
    }
    assert!(
        pushed > 100,
        "the presses reach the plateau ({pushed} steps above 0.5 N)"
    );
}

#[test]
fn a_fused_node_with_a_bad_attribute_is_refused_in_one_line() {
    let path = model_or_skip!("structured_fused_bad_tau");
    let schema = FeatureSchema::standard();
    let Err(err) = StepEngine::load(common::runtime(), &path, &schema, &SessionConfig::default())
    else {
        panic!("a negative relaxation time is refused");
    };
    let text = err.to_string();
    assert!(
        text.contains("StructuredStep: attribute `taus_s` = -1 is not positive"),
        "{text}"
    );
}

/// The fixture's forest (make_models.py `write_forest_fused`): 20 equal trees
/// x <= 0.002 ? (v <= 0 ? 1 : 2) : 3, so the mean is that tree's leaf; x and v read as f32.
#[test]
fn a_fused_forest_is_served_and_answers_the_mean_of_its_leaves() {
    let path = model_or_skip!("forest_fused");
    let schema = FeatureSchema::standard();
    let mut engine =
        StepEngine::load(common::runtime(), &path, &schema, &SessionConfig::default()).unwrap();
    assert_eq!(engine.info().kind, ModelKind::Stateless);
    let mut seen = [0usize; 3];
    for n in 0..400 {
        let t = n as f64 * 0.05;
        let (x, v) = (0.003 * t.sin(), 0.01 * t.cos());
        let mut input = [0.0f64; 9];
        input[0] = x; // position_x
        input[1] = v; // velocity
        let (x32, v32) = (x as f32, v as f32);
        let want = if x32 <= 0.002 {
            if v32 <= 0.0 {
                1.0
            } else {
                2.0
            }
        } else {
            3.0
        };
        let got = engine.step(&input).unwrap();
        assert!(
            (got - want).abs() < 1e-6,
            "x {x}, v {v}: got {got}, want {want}"
        );
        seen[want as usize - 1] += 1;
    }
    assert!(
        seen.iter().all(|&s| s > 20),
        "every leaf is reached: {seen:?}"
    );
}
