//! The inference thread over a real shared-memory segment: this test plays rt-loop (it creates
//! the segment and sends features), the library's inference thread answers.

mod common;

use std::time::Duration;

use haptics_proto::{FeatureMsg, LoopSide, Segment, MAX_FEATURES};
use infer_server::serving::inference_thread::{force_flags, InferenceConfig, InferenceThread};
use infer_server::{FeatureSchema, SessionConfig, StepEngine};
use shm_ring::{Config, SegmentName, WaitStrategy};

const TIMEOUT: Duration = Duration::from_secs(10);

fn segment_name(tag: &str) -> SegmentName {
    SegmentName::new(&format!("/infer-server-test-{tag}-{}", std::process::id())).unwrap()
}

fn features(seq: u64, run_id: u32, flags: u32, values: &[f64]) -> FeatureMsg {
    let mut v = [0.0; MAX_FEATURES];
    v[..values.len()].copy_from_slice(values);
    FeatureMsg {
        seq,
        timestamp_ns: seq * 1000,
        run_id,
        flags,
        len: values.len() as u8,
        values: v,
    }
}

/// The standard segment layout with the loop's own feature schema `names`.
fn config_for(names: &[&str]) -> Config {
    Config {
        feature_names: names.iter().map(|s| s.to_string()).collect(),
        ..haptics_proto::layout::config()
    }
}

/// Waits until the thread has attached: features sent before that are skipped at attach (they
/// would be requests to a previous server), as a real loop knows from `peer_alive`.
fn wait_attached(thread: &InferenceThread) {
    let end = std::time::Instant::now() + TIMEOUT;
    while thread.segment_schema().is_none() {
        assert!(
            std::time::Instant::now() < end,
            "the inference thread did not attach"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Sends one step and waits for its answer, as a lockstep loop does.
fn round_trip(lp: &mut LoopSide, msg: FeatureMsg) -> haptics_proto::ForceMsg {
    lp.features_tx
        .try_send(msg)
        .expect("features ring has room");
    let answer = lp.forces_rx.recv_timeout(TIMEOUT).expect("an answer");
    assert_eq!(
        answer.seq, msg.seq,
        "answers come in order, tagged with their step"
    );
    answer
}

#[test]
fn serves_every_step_in_order_swaps_models_and_resets_state() {
    let Some(dir) = common::fixtures() else {
        return;
    };
    let rt = common::runtime();
    // A loop whose schema is not the standard order: the model must be fed through the map.
    let schema_names = ["velocity", "f_previous_x", "position_x"];
    let schema = FeatureSchema::new(schema_names).unwrap();
    let name = segment_name("swap");
    let config = config_for(&schema_names);
    let (mut lp, mut activator, thread) = common::parked_inference_thread(&name, &config);
    wait_attached(&thread);

    // Before any model: every step is still answered, with NaN and NO_MODEL.
    let a = round_trip(
        &mut lp,
        features(1, 1, FeatureMsg::RUN_START, &[0.1, 0.2, 0.3]),
    );
    assert!(a.force.is_nan());
    assert_eq!(a.flags, force_flags::NO_MODEL);
    assert_eq!(thread.segment_schema().as_ref(), Some(&schema));

    // Linear model: force = 2 velocity - 3 position_x + 0.5.
    let load = |n: &str| {
        StepEngine::load(
            rt,
            &dir.join(format!("{n}.onnx")),
            &schema,
            &SessionConfig::default(),
        )
        .unwrap()
    };
    let g1 = activator.offer(load("linear"));
    assert!(activator.wait_active(g1, TIMEOUT));
    let mut seq = 2;
    for i in 0..500 {
        let (v, f, x) = (i as f64 * 0.01, 1.0, -(i as f64) * 0.003);
        let a = round_trip(&mut lp, features(seq, 1, 0, &[v, f, x]));
        assert_eq!(a.flags, 0);
        assert_eq!(a.model_id as u64, g1);
        let want = 2.0 * v - 3.0 * x + 0.5;
        assert!(
            (a.force - want).abs() < 1e-5 * (1.0 + want.abs()),
            "step {seq}: {} vs {want}",
            a.force
        );
        seq += 1;
    }

    // Swap to the LSTM between two steps; compare with a local engine stepping the same inputs.
    // The served one is the fixture LSTM plus a term that is exactly 0 while f_previous_x <= 10
    // and NaN beyond (used below), so the two agree bit for bit on these inputs.
    let g2 = activator.offer(load("lstm_nan_above_10"));
    let mut reference = load("lstm");
    let inputs: Vec<[f64; 3]> = (0..200)
        .map(|t| {
            let t = t as f64;
            [0.0, (t * 0.37).sin() * 2.0, t * 0.05 - 1.0]
        })
        .collect();
    let mut first_run = Vec::new();
    for (k, x) in inputs.iter().enumerate() {
        let flags = if k == 0 { FeatureMsg::RUN_START } else { 0 };
        let a = round_trip(&mut lp, features(seq, 2, flags, x));
        seq += 1;
        assert_eq!(
            a.model_id as u64, g2,
            "the new model answers from the first step after the swap"
        );
        let want = reference.step(x).unwrap() as f64;
        assert_eq!(a.force, want, "step {k}");
        first_run.push(a.force);
    }
    // A new run id resets the state: the same inputs replay the same forces.
    for (k, x) in inputs.iter().enumerate().take(50) {
        let a = round_trip(&mut lp, features(seq, 3, 0, x));
        seq += 1;
        assert_eq!(a.force, first_run[k], "run 3 step {k}");
    }

    // A NaN feature is refused before the model runs (flag BAD_FEATURES, state untouched: the
    // next step continues the run as if the bad one had not happened).
    let a = round_trip(&mut lp, features(seq, 3, 0, &[0.0, f64::NAN, 0.0]));
    seq += 1;
    assert_eq!(a.flags, force_flags::BAD_FEATURES);
    assert!(a.force.is_nan());
    // ... but a NaN in a column the model does not use (velocity) is no problem.
    let x = inputs[50];
    let a = round_trip(&mut lp, features(seq, 3, 0, &[f64::NAN, x[1], x[2]]));
    seq += 1;
    assert_eq!(a.flags, 0);
    let mut check = load("lstm");
    for x in &inputs[..50] {
        check.step(x).unwrap();
    }
    assert_eq!(
        a.force,
        check.step(&x).unwrap() as f64,
        "the state skipped the refused step"
    );

    // A step that makes the model NaN poisons its state: the answer is passed on flagged
    // NON_FINITE, and the server resets the state, so the next step is a fresh start rather
    // than a run computed from NaN state.
    let a = round_trip(&mut lp, features(seq, 3, 0, &[0.0, 11.0, 0.0]));
    seq += 1;
    assert_eq!(a.flags, force_flags::NON_FINITE);
    assert!(a.force.is_nan());
    let a = round_trip(&mut lp, features(seq, 3, 0, &inputs[0]));
    seq += 1;
    assert_eq!(a.flags, 0);
    assert_eq!(
        a.force, first_run[0],
        "the state was reset after the NaN step"
    );

    // A vector shorter than the schema gets a flagged NaN, not a crash.
    let a = round_trip(&mut lp, features(seq, 3, 0, &[0.1]));
    assert!(a.force.is_nan());
    assert_eq!(a.flags, force_flags::STEP_ERROR);

    // The thread counts a step just after sending its answer: give it that moment.
    let end = std::time::Instant::now() + TIMEOUT;
    while thread.stats().snapshot().answered < seq && std::time::Instant::now() < end {
        std::thread::sleep(Duration::from_millis(1));
    }
    let stats = thread.stats().snapshot();
    assert_eq!(stats.answered, seq);
    assert_eq!(stats.no_model, 1);
    assert_eq!(stats.step_errors, 1);
    assert_eq!(stats.predicted, 500 + 200 + 50 + 3);
    assert_eq!(stats.bad_features, 1);
    assert_eq!(stats.non_finite, 1);
    assert_eq!(stats.switches, 2);
    assert!(stats.resets >= 1);
    assert_eq!(stats.last_seq, seq);
    let latency = thread.latency().snapshot();
    assert_eq!(latency.samples(), seq);
    assert!(latency.quantile(0.5) > 0 && latency.max >= latency.quantile(0.5));

    // The loop goes away: the thread notices and ends (exit_when_loop_gone).
    drop(lp);
    let end = std::time::Instant::now();
    while !thread.is_finished() {
        assert!(
            end.elapsed() < TIMEOUT,
            "the inference thread did not notice the loop left"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    thread.join().unwrap();
    activator.collect_retired();
}

/// A fused LSTM's next recurrent product is done after each answer (fused-ops ahead.rs, the
/// thread's `ahead_runs`); every answer is still the same bits as a local engine's, which does
/// all of the work inside each step, across a reset to a zero state (a new run id).
#[test]
fn the_work_done_ahead_changes_no_answer() {
    let Some(dir) = common::fixtures() else {
        return;
    };
    let rt = common::runtime();
    let schema_names = ["position_x", "velocity"];
    let schema = FeatureSchema::new(schema_names).unwrap();
    let name = segment_name("ahead");
    let config = config_for(&schema_names);
    let (mut lp, mut activator, thread) = common::parked_inference_thread(&name, &config);
    wait_attached(&thread);
    let load = || {
        StepEngine::load(
            rt,
            &dir.join("lstm_fused.onnx"),
            &schema,
            &SessionConfig::default(),
        )
        .unwrap()
    };
    let g = activator.offer(load());
    assert!(activator.wait_active(g, TIMEOUT));
    let mut reference = load();
    let mut seq = 1;
    for run in [1u32, 2] {
        reference.reset();
        for k in 0..200 {
            let t = k as f64;
            let x = [0.004 * (t * 0.05).sin(), 0.02 * (t * 0.11).cos()];
            let flags = if k == 0 { FeatureMsg::RUN_START } else { 0 };
            let a = round_trip(&mut lp, features(seq, run, flags, &x));
            seq += 1;
            assert_eq!(a.flags, 0);
            let want = reference.step(&x).unwrap() as f64;
            assert_eq!(
                a.force.to_bits(),
                want.to_bits(),
                "run {run} step {k}: {} vs {want}",
                a.force
            );
        }
    }
    let end = std::time::Instant::now() + TIMEOUT;
    while thread.stats().snapshot().ahead_runs < 400 && std::time::Instant::now() < end {
        std::thread::sleep(Duration::from_millis(1));
    }
    let stats = thread.stats().snapshot();
    assert_eq!(stats.ahead_runs, 400, "work ahead after every answer");
    assert!(stats.ahead_ns > 0);
    drop(lp);
    thread.join().unwrap();
    activator.collect_retired();
}

#[test]
fn a_model_for_another_schema_is_not_fed_wrong_columns() {
    let Some(dir) = common::fixtures() else {
        return;
    };
    let rt = common::runtime();
    let name = segment_name("mismatch");
    // Segment schema: standard nine. Model validated against a different schema.
    let (mut lp, mut activator, thread) =
        common::parked_inference_thread(&name, &haptics_proto::layout::config());
    let other = FeatureSchema::parse("position_x,velocity").unwrap();
    let g = activator.offer(
        StepEngine::load(
            rt,
            &dir.join("linear.onnx"),
            &other,
            &SessionConfig::default(),
        )
        .unwrap(),
    );
    assert!(activator.wait_active(g, TIMEOUT));
    let a = round_trip(&mut lp, features(1, 1, FeatureMsg::RUN_START, &[0.5; 9]));
    assert!(a.force.is_nan());
    assert_eq!(a.flags, force_flags::SCHEMA_MISMATCH);
    assert_eq!(thread.stats().snapshot().schema_mismatch, 1);
    thread.stop().unwrap();
}

#[test]
fn server_activates_refuses_and_revalidates_when_a_new_loop_brings_another_schema() {
    use infer_server::control::inference_control::{InferenceControl, MaintenanceEvent};
    let Some(dir) = common::fixtures() else {
        return;
    };
    let rt = common::runtime();
    let name = segment_name("server");
    let first: Vec<String> = ["position_x", "velocity"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    let mut lp = Segment::create(
        &name,
        &Config {
            feature_names: first,
            ..haptics_proto::layout::config()
        },
    )
    .unwrap()
    .loop_side()
    .unwrap();
    lp.forces_rx.set_wait_strategy(WaitStrategy::Park);
    let server = InferenceControl::start(
        rt,
        InferenceConfig {
            segment: name.clone(),
            wait: WaitStrategy::Park,
            cpu: None,
            rt_priority: None,
            exit_when_loop_gone: false, // wait for the next loop
            keep_awake: false,
        },
        SessionConfig::default(),
    )
    .unwrap();
    let end = std::time::Instant::now() + TIMEOUT;
    while !server.stats().attached {
        assert!(std::time::Instant::now() < end);
        std::thread::sleep(Duration::from_millis(5));
    }
    assert_eq!(server.schema().names(), ["position_x", "velocity"]);

    let a = server.activate(&dir.join("linear.onnx")).unwrap();
    assert_eq!(a.info.input_map, [1, 0]);
    // A model that needs a feature this loop lacks is refused; the linear model stays.
    let e = server.activate(&dir.join("tree.onnx")).unwrap_err();
    assert!(
        matches!(e, infer_server::ModelError::MissingFeature { ref name, .. } if name == "f_previous_x"),
        "{e}"
    );
    assert_eq!(server.active().unwrap().generation, a.generation);
    let f = round_trip(&mut lp, features(1, 1, FeatureMsg::RUN_START, &[0.2, 0.7]));
    assert!(
        (f.force - (2.0 * 0.7 - 3.0 * 0.2 + 0.5)).abs() < 1e-6,
        "{f:?}"
    );
    assert_eq!(f.model_id as u64, a.generation);
    assert_eq!(
        server.wait_effective(a.generation, TIMEOUT),
        Some(1),
        "first step it answered"
    );

    // The loop restarts with another schema order; the server re-attaches by itself and
    // `maintain` revalidates the model for the new columns.
    drop(lp);
    while server.stats().attached {
        assert!(std::time::Instant::now() < end + TIMEOUT);
        std::thread::sleep(Duration::from_millis(5));
    }
    let second: Vec<String> = ["cycle_no", "velocity", "position_x"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    let mut lp = Segment::create(
        &name,
        &Config {
            feature_names: second,
            ..haptics_proto::layout::config()
        },
    )
    .unwrap()
    .loop_side()
    .unwrap();
    lp.forces_rx.set_wait_strategy(WaitStrategy::Park);
    let revalidated = loop {
        assert!(
            std::time::Instant::now() < end + 2 * TIMEOUT,
            "no revalidation"
        );
        match server.maintain() {
            Some(MaintenanceEvent::Revalidated(a)) => break *a,
            Some(other) => panic!("{other:?}"),
            None => std::thread::sleep(Duration::from_millis(5)),
        }
    };
    assert_eq!(revalidated.info.input_map, [1, 2]);
    let f = round_trip(
        &mut lp,
        features(1, 7, FeatureMsg::RUN_START, &[3.0, 0.7, 0.2]),
    );
    assert_eq!(f.flags, 0, "{f:?}");
    assert_eq!(f.model_id as u64, revalidated.generation);
    assert!(
        (f.force - (2.0 * 0.7 - 3.0 * 0.2 + 0.5)).abs() < 1e-6,
        "{f:?}"
    );
    assert_eq!(server.stats().attachments, 2);
    drop(lp);
    server.shutdown().unwrap();
}

/// The `dedicated` profile's spinning wait notices a loop that left, and the server waits for
/// the next one (before, a spinning wait with a deadline checked only the deadline: the server
/// stayed on the dead segment and the next loop's run found no server; bench-loaded's tuned
/// rows found it).
#[test]
fn a_spinning_server_notices_the_loop_leaving_and_attaches_to_the_next() {
    use infer_server::control::inference_control::InferenceControl;
    let name = segment_name("spin-left");
    let make = || {
        Segment::create(&name, &haptics_proto::layout::config())
            .unwrap()
            .loop_side()
            .unwrap()
    };
    let lp = make();
    let server = InferenceControl::start(
        common::runtime(),
        InferenceConfig {
            segment: name.clone(),
            wait: WaitStrategy::Spin,
            cpu: None,
            rt_priority: None,
            exit_when_loop_gone: false,
            keep_awake: false,
        },
        SessionConfig::default(),
    )
    .unwrap();
    let end = std::time::Instant::now() + TIMEOUT;
    while !server.stats().attached {
        assert!(std::time::Instant::now() < end, "never attached");
        std::thread::sleep(Duration::from_millis(5));
    }
    drop(lp);
    while server.stats().attached {
        assert!(
            std::time::Instant::now() < end + TIMEOUT,
            "the spinning server did not notice the loop leaving"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    let _lp = make();
    while server.stats().attachments < 2 {
        assert!(
            std::time::Instant::now() < end + 2 * TIMEOUT,
            "no attachment to the next loop"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    server.shutdown().unwrap();
}
