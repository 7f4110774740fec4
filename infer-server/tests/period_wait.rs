//! The inference thread's waits over a real shared-memory segment, this test playing rt-loop:
//! the period-synchronised wait locks onto a periodic loop, answers every step, and lets go
//! (parks) when the loop stops; a feature message that does not decode is skipped, not fatal.
//! No model is needed (every answer is NaN with NO_MODEL), so these run without ONNX Runtime.

use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use haptics_proto::{FeatureMsg, LoopSide, Segment, MAX_FEATURES};
use infer_server::serving::handoff;
use infer_server::serving::inference_thread::{force_flags, InferenceConfig, InferenceThread};
use shm_ring::{monotonic_ns, sleep_until_ns, SegmentName, WaitStrategy};

const TIMEOUT: Duration = Duration::from_secs(10);

fn start(tag: &str, wait: WaitStrategy) -> (LoopSide, InferenceThread) {
    let name =
        SegmentName::new(&format!("/infer-server-wait-{tag}-{}", std::process::id())).unwrap();
    let mut lp = Segment::create(&name, &haptics_proto::layout::config())
        .unwrap()
        .loop_side()
        .unwrap();
    lp.forces_rx.set_wait_strategy(WaitStrategy::Park);
    let (_activator, taker) = handoff::channel();
    let thread = InferenceThread::spawn(
        InferenceConfig {
            segment: name,
            wait,
            cpu: None,
            rt_priority: None,
            exit_when_loop_gone: true,
            keep_awake: false,
        },
        taker,
    )
    .unwrap();
    let end = Instant::now() + TIMEOUT;
    while thread.segment_schema().is_none() {
        assert!(Instant::now() < end, "the inference thread did not attach");
        std::thread::sleep(Duration::from_millis(5));
    }
    (lp, thread)
}

/// The thread bumps its counters just after sending the answer: wait for them to catch up.
fn wait_answered(thread: &InferenceThread, n: u64) {
    let end = Instant::now() + TIMEOUT;
    while thread.stats().answered.load(Ordering::Relaxed) < n {
        assert!(Instant::now() < end, "answered counter stuck");
        std::thread::sleep(Duration::from_millis(1));
    }
}

fn msg(seq: u64, timestamp_ns: u64) -> FeatureMsg {
    FeatureMsg {
        seq,
        timestamp_ns,
        run_id: 1,
        flags: 0,
        len: 9,
        values: [0.0; MAX_FEATURES],
    }
}

#[test]
fn an_undecodable_feature_message_is_skipped_and_the_next_one_answered() {
    let (mut lp, thread) = start("undecodable", WaitStrategy::Park);
    // len 17 > MAX_FEATURES: the server's decode refuses it (a corrupt or hostile writer).
    let mut bad = msg(1, 1_000);
    bad.len = MAX_FEATURES as u8 + 1;
    lp.features_tx.try_send(bad).unwrap();
    lp.features_tx.try_send(msg(2, 2_000)).unwrap();
    let answer = lp
        .forces_rx
        .recv_timeout(TIMEOUT)
        .expect("the next step is answered");
    assert_eq!(
        answer.seq, 2,
        "the undecodable step gets no answer, the next one does"
    );
    assert_eq!(answer.flags, force_flags::NO_MODEL);
    wait_answered(&thread, 1);
    let stats = thread.stats().snapshot();
    assert_eq!(stats.undecodable, 1);
    assert_eq!(stats.answered, 1);
    let why = thread.stats().last_undecodable.lock().unwrap().unwrap();
    assert!(why.to_string().contains("FeatureMsg.len"), "{why}");
    assert!(!thread.is_finished(), "the inference thread serves on");
    // And it keeps serving.
    lp.features_tx.try_send(msg(3, 3_000)).unwrap();
    assert_eq!(lp.forces_rx.recv_timeout(TIMEOUT).unwrap().seq, 3);
}

#[test]
fn the_period_wait_locks_onto_a_periodic_loop_answers_every_step_and_lets_go_when_it_stops() {
    let (mut lp, thread) = start("period", WaitStrategy::PeriodSync);
    // A 1 kHz loop (not 10 kHz: the server spins only through its margin, but this machine may
    // have two cores and other tests beside this one): sleep to an absolute grid, send, wait
    // (parked) for the answer.
    let period = 1_000_000u64;
    let origin = monotonic_ns();
    let steps = 600u64;
    let mut next = origin + period;
    for seq in 1..=steps {
        sleep_until_ns(next);
        let now = monotonic_ns();
        lp.features_tx.try_send(msg(seq, now - origin)).unwrap();
        let answer = lp.forces_rx.recv_timeout(TIMEOUT).expect("an answer");
        assert_eq!(answer.seq, seq);
        next += period;
        while next <= monotonic_ns() {
            next += period; // overran (a loaded machine): skip to the next grid point
        }
    }
    wait_answered(&thread, steps);
    let stats = thread.stats();
    assert_eq!(stats.answered.load(Ordering::Relaxed), steps);
    assert!(
        stats.sync_locks.load(Ordering::Relaxed) >= 1,
        "locked onto the loop"
    );
    let learnt = stats.sync_period_ns.load(Ordering::Relaxed);
    assert!(
        (learnt as f64 - period as f64).abs() < 0.02 * period as f64,
        "learnt period {learnt} ns"
    );
    let margin = stats.sync_margin_ns.load(Ordering::Relaxed);
    assert!(margin > 0 && margin <= period / 2, "margin {margin} ns");

    // The loop stops sending (stays attached): after MISS_LIMIT periods the thread lets go.
    let end = Instant::now() + TIMEOUT;
    while stats.sync_period_ns.load(Ordering::Relaxed) != 0 {
        assert!(
            Instant::now() < end,
            "still locked long after the loop stopped"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    assert!(stats.sync_missed_wakes.load(Ordering::Relaxed) >= 20);
    // It still answers (parked, woken by the futex) when a step comes later.
    let t = monotonic_ns() - origin;
    lp.features_tx.try_send(msg(steps + 1, t)).unwrap();
    assert_eq!(lp.forces_rx.recv_timeout(TIMEOUT).unwrap().seq, steps + 1);
}
