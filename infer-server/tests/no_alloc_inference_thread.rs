//! The inference thread's steady state allocates nothing: a global counting allocator is armed
//! while 5000 steps go through a real segment (this binary holds this one test only, so no
//! other test thread allocates meanwhile; the test's own loop side allocates nothing either).

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use haptics_proto::FeatureMsg;
use infer_server::{FeatureSchema, SessionConfig, StepEngine};
use shm_ring::SegmentName;

struct Counting;
static ARMED: AtomicBool = AtomicBool::new(false);
static ALLOCS: AtomicU64 = AtomicU64::new(0);

// SAFETY: forwards to the system allocator; counting is two atomics.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if ARMED.load(Ordering::Relaxed) {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        if ARMED.load(Ordering::Relaxed) {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn the_inference_thread_allocates_nothing_per_step() {
    let Some(dir) = common::fixtures() else {
        return;
    };
    let rt = common::runtime();
    let name = SegmentName::new(&format!("/infer-server-noalloc-{}", std::process::id())).unwrap();
    let (mut lp, mut activator, thread) =
        common::parked_inference_thread(&name, &haptics_proto::layout::config());
    let mut msg = FeatureMsg {
        len: 9,
        run_id: 1,
        flags: FeatureMsg::RUN_START,
        ..FeatureMsg::default()
    };
    let mut seq = 0;
    // The ONNX LSTM, then the fused one, whose next recurrent product the thread does after
    // each answer (fused-ops ahead.rs): that work allocates nothing either.
    for model in ["lstm", "lstm_fused"] {
        let engine = StepEngine::load(
            rt,
            &dir.join(format!("{model}.onnx")),
            &FeatureSchema::standard(),
            &SessionConfig::default(),
        )
        .unwrap();
        let g = activator.offer(engine);
        assert!(activator.wait_active(g, Duration::from_secs(10)));
        while thread.segment_schema().is_none() {
            std::thread::sleep(Duration::from_millis(1));
        }
        let mut step = |seq: u64, msg: &mut FeatureMsg| {
            msg.seq = seq;
            msg.values[0] = (seq % 100) as f64 * 0.01;
            msg.values[3] = (seq % 37) as f64 * 0.1 - 1.0;
            lp.features_tx.try_send(*msg).unwrap();
            let a = lp.forces_rx.recv_timeout(Duration::from_secs(10)).unwrap();
            msg.flags = 0;
            if a.seq != seq || a.flags != 0 || !a.force.is_finite() {
                panic!("{model}: bad answer {a:?} to step {seq}");
            }
        };
        for _ in 0..200 {
            seq += 1;
            step(seq, &mut msg);
        }
        let resets = thread.stats().snapshot().resets;
        ALLOCS.store(0, Ordering::SeqCst);
        ARMED.store(true, Ordering::SeqCst);
        for _ in 0..5000 {
            seq += 1;
            if seq % 1000 == 0 {
                msg.run_id += 1; // a reset on the way
            }
            step(seq, &mut msg);
        }
        // the last answer's work ahead runs just after it was sent
        std::thread::sleep(Duration::from_millis(20));
        ARMED.store(false, Ordering::SeqCst);
        let n = ALLOCS.load(Ordering::SeqCst);
        assert_eq!(
            n, 0,
            "{model}: {n} allocations while 5000 steps went through the inference thread"
        );
        assert!(thread.stats().snapshot().resets >= resets + 5);
    }
    let ahead = thread.stats().snapshot().ahead_runs;
    assert!(ahead >= 5000, "{ahead} answers with work ahead");
    drop(lp);
    thread.join().unwrap();
}
