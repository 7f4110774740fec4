//! The hot path allocates nothing on the Rust side: a counting global allocator watches the
//! stepping thread. (ONNX Runtime's own C++ allocations do not pass through Rust's allocator;
//! `benches/step_latency.rs` counts those with a malloc interposer and reports them.)

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use infer_server::serving::latency;
use infer_server::{FeatureSchema, SessionConfig, StepEngine};

struct Counting;

thread_local! {
    static ALLOCS: Cell<u64> = const { Cell::new(0) };
}

// SAFETY: forwards to the system allocator; the counter is a const-initialised thread-local
// (no allocation, no recursion).
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCS.with(|c| c.set(c.get() + 1));
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        ALLOCS.with(|c| c.set(c.get() + 1));
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCS.with(|c| c.set(c.get() + 1));
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations() -> u64 {
    ALLOCS.with(|c| c.get())
}

#[test]
fn stepping_allocates_nothing_on_the_rust_side() {
    let Some(dir) = common::fixtures() else {
        return;
    };
    let rt = common::runtime();
    let schema = FeatureSchema::standard();
    let (mut recorder, reader) = latency::histogram();
    // *_fused: one node of the fused operators (fused-ops/), whose kernels are Rust code
    // counted here too
    let names = [
        "linear",
        "tree",
        "lstm",
        "structured_fused",
        "lawfree_fused",
        "dense_fused",
        "prony_fused",
        "lstm_fused",
        "slow_lstm_fused",
        "svr_fused",
        "spring_damper_fused",
        "forest_fused",
    ];
    for name in names {
        let mut engine = StepEngine::load(
            rt,
            &dir.join(format!("{name}.onnx")),
            &schema,
            &SessionConfig::default(),
        )
        .unwrap();
        let mut input = [0.0f64; 9];
        let before = allocations();
        let mut sum = 0.0f32;
        for t in 0..5_000u64 {
            input[0] = (t % 100) as f64 * 0.01;
            input[3] = (t % 37) as f64 * 0.1 - 1.0;
            let start = std::time::Instant::now();
            sum += engine.step(&input).unwrap();
            recorder.record(start.elapsed().as_nanos() as u64);
            if t % 1000 == 999 {
                engine.reset();
            }
        }
        let during = allocations() - before;
        assert!(sum.is_finite());
        assert_eq!(during, 0, "{name}: {during} Rust allocations in 5000 steps");
    }
    assert_eq!(reader.snapshot().samples(), 5_000 * names.len() as u64);
}
