//! The loop's per-step calls allocate nothing: a counting global allocator watches a thousand
//! steps of the real-time path (features out, force in, telemetry out, commands polled,
//! heartbeat) through a real segment.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use haptics_proto::{Segment, TelemetryRow};
use shm_ring::{SegmentName, WaitStrategy};
use shm_ring_testing::pattern;

struct Counting;

static WATCHING: AtomicBool = AtomicBool::new(false);
static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

// SAFETY: forwards to the system allocator; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if WATCHING.load(Ordering::Relaxed) {
            ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        System.alloc(layout)
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout)
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn loop_step_allocates_nothing() {
    let name = SegmentName::for_instance(&format!("na{}", std::process::id())).unwrap();
    let mut lp = Segment::create(&name, &haptics_proto::layout::config())
        .unwrap()
        .loop_side()
        .unwrap();
    let mut sv = Segment::attach(&name).unwrap().server_side().unwrap();
    lp.forces_rx.set_wait_strategy(WaitStrategy::Spin);

    WATCHING.store(true, Ordering::SeqCst);
    let mut answered = 0;
    for seq in 0..1000u64 {
        // loop side
        lp.features_tx.try_send(pattern::feature(seq)).unwrap();
        lp.telemetry_tx.send(&TelemetryRow {
            step: seq,
            ..Default::default()
        });
        while lp.commands_rx.try_recv().unwrap().is_some() {}
        lp.heartbeat();
        // server side (same thread, so the loop's bounded wait below finds the answer)
        let f = sv.features_rx.try_recv().unwrap().unwrap();
        sv.forces_tx.try_send(pattern::force(f.seq)).unwrap();
        // loop side: the bounded wait for the force
        let force = lp
            .forces_rx
            .recv_deadline(Instant::now() + Duration::from_millis(100))
            .unwrap();
        if force.seq == seq {
            answered += 1;
        }
        let _ = sv.telemetry_rx.try_recv().unwrap();
    }
    WATCHING.store(false, Ordering::SeqCst);
    assert_eq!(answered, 1000);
    assert_eq!(
        ALLOCATIONS.load(Ordering::SeqCst),
        0,
        "the per-step path allocated"
    );
}
