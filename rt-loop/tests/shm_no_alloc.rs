//! `ShmClient::exchange` (the loop's side of every served step) allocates nothing: counted on
//! the loop thread only, against an echo server thread on a real segment.

#[path = "support/alloc_count.rs"]
mod alloc_count;

use haptics_proto::{ForceMsg, LoopStatusLink, Segment};
use rt_loop::features::Features;
use rt_loop::serving::shm_io::create_segment;
use rt_loop::serving::shm_model::AnswerWait;
use shm_ring::{RecvError, WaitStrategy};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

#[test]
fn exchange_allocates_nothing() {
    let seg = create_segment(
        &format!("rtloop-test-alloc-{}", std::process::id()),
        WaitStrategy::Park,
    )
    .unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let stop2 = stop.clone();
    let sv_seg = Segment::attach_timeout(&seg.name, Duration::from_secs(5)).unwrap();
    let mut sv = sv_seg.server_side().unwrap();
    sv.features_rx.set_wait_strategy(WaitStrategy::Park);
    let server = std::thread::spawn(move || {
        while !stop2.load(Ordering::Relaxed) {
            match sv.features_rx.recv_timeout(Duration::from_millis(20)) {
                Ok(m) => sv
                    .forces_tx
                    .send(ForceMsg {
                        seq: m.seq,
                        force: m.values[0],
                        model_id: 1,
                        flags: 0,
                        inference_ns: 0,
                    })
                    .unwrap(),
                Err(RecvError::Timeout) => {}
                Err(_) => break,
            }
        }
    });
    let mut client = seg.client;
    let mut io = seg.io;
    assert!(client.wait_for_server(Duration::from_secs(5)));
    client.begin_run();
    let wait = AnswerWait::Lockstep {
        safety: Duration::from_secs(2),
        give_up_after: 3,
    };
    let row = rt_loop::record::Row::default();
    // the loop-status block: set up off the real-time path (allocates), then published in the
    // loop below on the step path (must not)
    let cfg = rt_loop::config::RunConfig::default();
    io.begin_run_status(
        &cfg,
        "SCHED_OTHER (test)",
        Some(std::path::Path::new("/tmp/some/recording.parquet")),
    );
    alloc_count::start();
    let mut answered = 0;
    for step in 0..5000u64 {
        let f = Features {
            position_x: step as f64,
            ..Features::default()
        };
        if client.exchange(step, &f, wait) == Some(step as f64) {
            answered += 1;
        }
        io.on_step(&row);
        if step % 500 == 0 {
            io.set_recorder_rows(step);
            client.report_status(io.status_mut());
            io.publish_status();
        }
    }
    let allocs = alloc_count::stop();
    assert_eq!(answered, 5000);
    let st = io.link().loop_status().expect("published");
    assert_eq!(
        st.recorder.as_str(),
        "writing /tmp/some/recording.parquet rows 4500"
    );
    assert_eq!(st.round_trip.count, 4501, "{st:?}");
    assert_eq!(st.scheduling.as_str(), "SCHED_OTHER (test)");
    assert_eq!(allocs, 0, "allocations on the loop thread");
    stop.store(true, Ordering::Relaxed);
    server.join().unwrap();
}
