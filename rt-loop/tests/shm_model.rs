//! `ShmClient`/`ShmModel` against a scripted server on a real segment (the server side runs on a
//! thread of this test; cross-process runs with the real infer-server are in
//! `tests/tests/model_in_loop.rs` of the workspace).

use haptics_proto::{FeatureMsg, ForceMsg, Segment};
use rt_loop::features::Features;
use rt_loop::serving::model::ForceModel;
use rt_loop::serving::shm_io::create_segment;
use rt_loop::serving::shm_model::{AnswerWait, ShmClient, ShmModel, SETTLE_AFTER_ATTACH};
use shm_ring::{RecvError, SegmentName, WaitStrategy};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

fn feats(i: u64) -> Features {
    Features {
        position_x: 0.001 * i as f64,
        velocity: 0.5,
        cycle_no: 3,
        f_previous: 0.5 * i as f64,
        ..Features::default()
    }
}

/// The model the scripted server computes: 100 x + v.
fn formula(m: &FeatureMsg) -> f64 {
    100.0 * m.values[0] + m.values[1]
}

/// A server thread: answers every request; `seq % 5 == 0` late (after 60 ms), `seq % 7 == 0`
/// with flag 1 (NO_MODEL); records every request it saw.
fn scripted_server(
    name: SegmentName,
    stop: Arc<AtomicBool>,
    seen: Arc<Mutex<Vec<FeatureMsg>>>,
) -> JoinHandle<()> {
    let seg = Segment::attach_timeout(&name, Duration::from_secs(5)).expect("attach");
    let mut sv = seg.server_side().expect("server side");
    sv.features_rx.set_wait_strategy(WaitStrategy::Park);
    std::thread::spawn(move || {
        while !stop.load(Ordering::Relaxed) {
            match sv.features_rx.recv_timeout(Duration::from_millis(20)) {
                Ok(m) => {
                    seen.lock().unwrap().push(m);
                    if m.seq % 5 == 0 {
                        std::thread::sleep(Duration::from_millis(60));
                    }
                    let flags = if m.seq % 7 == 0 { 1 } else { 0 };
                    let force = if flags != 0 { f64::NAN } else { formula(&m) };
                    sv.forces_tx
                        .send(ForceMsg {
                            seq: m.seq,
                            force,
                            model_id: 1,
                            flags,
                            inference_ns: 0,
                        })
                        .expect("answer");
                }
                Err(RecvError::Timeout) => {}
                Err(_) => break,
            }
        }
    })
}

fn instance(tag: &str) -> String {
    format!("rtloop-test-{tag}-{}", std::process::id())
}

#[test]
fn answers_by_seq_deadline_flags_and_stale_discard() {
    let seg = create_segment(&instance("proto"), WaitStrategy::Park).unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let seen = Arc::new(Mutex::new(Vec::new()));
    let server = scripted_server(seg.name.clone(), stop.clone(), seen.clone());
    let mut client: ShmClient = seg.client;
    assert!(client.wait_for_server(Duration::from_secs(5)));
    client.begin_run();
    let wait = AnswerWait::Deadline(Duration::from_millis(20));
    let (mut ok, mut late, mut flagged) = (0, 0, 0);
    for step in 0..70u64 {
        let f = feats(step);
        let got = client.exchange(step, &f, wait);
        // seq = step + 1 (the client counts from 1 over the segment's life)
        let seq = step + 1;
        if seq % 5 == 0 {
            assert_eq!(got, None, "step {step}: a late answer is never used");
            late += 1;
        } else if seq % 7 == 0 {
            assert_eq!(got, None, "step {step}: a flagged answer is never used");
            flagged += 1;
        } else {
            let want = 100.0 * f.position_x + f.velocity;
            assert_eq!(got, Some(want), "step {step}: this step's own answer");
            ok += 1;
        }
        if seq % 5 == 0 {
            // let the late answer arrive: the next exchange must skip it, not take it
            std::thread::sleep(Duration::from_millis(70));
        }
    }
    let c = client.counters.snapshot();
    assert_eq!(c.sent, 70);
    assert_eq!(c.answered, ok);
    assert_eq!(c.late, late);
    assert_eq!(c.flagged, flagged);
    // seq 70 was late too: its answer is still in the ring, the next run throws it away
    assert_eq!(
        c.stale_discarded,
        late - 1,
        "late answers thrown away by the next step"
    );
    std::thread::sleep(Duration::from_millis(80));
    client.begin_run();
    assert_eq!(client.counters.snapshot().stale_discarded, late);
    // round trips: every answer in time, and each late one that arrived during the next step
    // (the last late answer arrived after the run)
    assert_eq!(client.round_trip_ns.len(), ok + flagged + late - 1);
    stop.store(true, Ordering::Relaxed);
    server.join().unwrap();
    let seen = seen.lock().unwrap();
    assert_eq!(seen.len(), 70);
    assert!(
        seen[0].is_run_start(),
        "the run's first message is flagged RUN_START"
    );
    assert!(seen[1..].iter().all(|m| !m.is_run_start()));
    assert!(seen
        .iter()
        .all(|m| m.run_id == seen[0].run_id && m.len == 10));
    assert_eq!(
        seen[3].values[6], 3.0,
        "cycle_no travels as f64 in schema slot 6"
    );
}

#[test]
fn server_gone_falls_back_without_waiting_and_a_new_server_resumes() {
    let seg = create_segment(&instance("gone"), WaitStrategy::Park).unwrap();
    let name = seg.name.clone();
    let stop = Arc::new(AtomicBool::new(false));
    let seen = Arc::new(Mutex::new(Vec::new()));
    let server = scripted_server(name.clone(), stop.clone(), seen.clone());
    // lockstep: the model waits for every answer (safety 2 s)
    let wait = AnswerWait::Lockstep {
        safety: Duration::from_secs(2),
        give_up_after: 3,
    };
    let mut model = ShmModel::new(seg.client, wait, Duration::from_secs(5));
    model.begin_run();
    // seq 1..4: answered
    for s in 0..4 {
        assert!(model.predict(s, &feats(s)).is_some(), "step {s}");
    }
    stop.store(true, Ordering::Relaxed);
    server.join().unwrap(); // the server side is dropped: its liveness lock is released
    let t = std::time::Instant::now();
    let mut none = 0;
    for s in 4..3000 {
        if model.predict(s, &feats(s)).is_none() {
            none += 1;
        }
    }
    assert!(
        none >= 2990,
        "without a server every step falls back ({none})"
    );
    assert!(
        t.elapsed() < Duration::from_millis(1500),
        "no step waited for the safety timeout: {:?}",
        t.elapsed()
    );
    let c = model.client().counters.snapshot();
    assert!(c.no_server > 2900, "{c:?}");
    // a new server: after the settle time, answers flow again, flagged as a run start
    let stop2 = Arc::new(AtomicBool::new(false));
    let seen2 = Arc::new(Mutex::new(Vec::new()));
    let server2 = scripted_server(name, stop2.clone(), seen2.clone());
    let _ = model.predict(3000, &feats(3000)); // sees the attachment
    std::thread::sleep(SETTLE_AFTER_ATTACH + Duration::from_millis(20));
    let mut answered = 0;
    for s in 3001..3030 {
        if model.predict(s, &feats(s)).is_some() {
            answered += 1;
        }
    }
    assert!(answered >= 20, "model rendering resumed ({answered} of 29)");
    stop2.store(true, Ordering::Relaxed);
    server2.join().unwrap();
    let seen2 = seen2.lock().unwrap();
    assert!(
        seen2[0].is_run_start(),
        "the new server's first message starts a run"
    );
    assert_eq!(model.client().counters.snapshot().attachments_seen, 1);
    // a run gives its model back as a `dyn ForceModel`: recognised, with its client's state
    let back: Box<dyn ForceModel> = Box::new(model);
    let model = ShmModel::from_model(back).expect("the served model is recognised");
    assert_eq!(model.client().counters.snapshot().attachments_seen, 1);
    let other: Box<dyn ForceModel> = Box::new(rt_loop::serving::model::SpringDamperModel(
        Default::default(),
    ));
    assert!(
        ShmModel::from_model(other).is_none(),
        "another model is not"
    );
}

#[test]
fn run_with_model_shm_and_no_server_says_what_to_start_and_leaves_no_segment() {
    let inst = instance("cli");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_rt-loop"))
        .args(["run", "--experiment", "reproduction", "--model", "shm"])
        .args([
            "--instance",
            &inst,
            "--server-wait-s",
            "0.3",
            "--no-progress",
        ])
        .current_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("no infer-server attached") && err.contains(&format!("--instance {inst}")),
        "{err}"
    );
    assert!(
        !std::path::Path::new(&format!("/dev/shm/haptics-{inst}")).exists(),
        "segment removed on exit"
    );
}

/// Issue 15 item 8, the loop's side: every row says which served model drew it (the answer's
/// `model_id`, 1 here; 0 where the fallback did), and carries the `f_previous` the server was
/// sent. (Before contact F(t-1) is 0 on every step, so the f_previous comparison here only
/// checks that the row and the request agree.)
#[test]
fn rows_carry_the_answering_model_id() {
    let seg = create_segment(&instance("modelid"), WaitStrategy::Park).unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let seen = Arc::new(Mutex::new(Vec::new()));
    let server = scripted_server(seg.name.clone(), stop.clone(), seen.clone());
    let model = ShmModel::new(
        seg.client,
        AnswerWait::Deadline(Duration::from_millis(20)),
        Duration::from_secs(5),
    );
    let cfg = rt_loop::config::RunConfig {
        experiment: rt_loop::config::ExperimentKind::Reproduction,
        material: concat!(env!("CARGO_MANIFEST_DIR"), "/../materials/sponge.toml").into(),
        ..Default::default()
    };
    let mut rig = rt_loop::run::build_rig(&cfg, Some(Box::new(model))).unwrap();
    let rows: Vec<_> = (0..60).map(|_| rig.step().unwrap()).collect();
    stop.store(true, Ordering::Relaxed);
    server.join().unwrap();
    let on_time = rows.iter().filter(|r| !r.fallback).count();
    assert!(on_time >= 30, "most steps answered in time ({on_time})");
    for r in &rows {
        if !r.fallback {
            assert_eq!(
                r.model_id, 1,
                "step {}: drawn by the server's model 1",
                r.step
            );
        }
        assert!(r.model_id <= 1, "step {}: {}", r.step, r.model_id);
    }
    // what the server was sent as f_previous (schema slot 9) is what the row carries
    let seen = seen.lock().unwrap();
    for m in seen.iter().filter(|m| !m.is_run_start()) {
        let step = m.seq - seen[0].seq;
        assert_eq!(
            rows[step as usize].f_previous, m.values[9],
            "step {step}: f_previous"
        );
    }
    // the server gone: after the ladder's hold the fallback renders, drawn by no served model
    let later: Vec<_> = (0..3000).map(|_| rig.step().unwrap()).collect();
    assert!(
        later[2000..].iter().all(|r| r.fallback && r.model_id == 0),
        "fallback steps carry model 0"
    );
}
