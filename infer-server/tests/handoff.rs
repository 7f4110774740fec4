//! Swapping the model between two steps of a running inference thread.

mod common;

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use infer_server::serving::handoff::{self, Offered};
use infer_server::{FeatureSchema, SessionConfig, StepEngine};

#[test]
fn a_running_thread_switches_models_between_steps() {
    let Some(dir) = common::fixtures() else {
        return;
    };
    let rt = common::runtime();
    let schema = FeatureSchema::standard();
    let load = |name: &str| {
        StepEngine::load(
            rt,
            &dir.join(format!("{name}.onnx")),
            &schema,
            &SessionConfig::default(),
        )
        .unwrap()
    };
    let (mut activator, mut taker) = handoff::channel();
    let stop = Arc::new(AtomicBool::new(false));
    let stop2 = Arc::clone(&stop);
    // While `hold` is set the worker keeps stepping but does not look for a new engine (and
    // says so through `holding`), so the test can queue two offers deterministically.
    let hold = Arc::new(AtomicBool::new(false));
    let holding = Arc::new(AtomicBool::new(false));
    let (hold2, holding2) = (Arc::clone(&hold), Arc::clone(&holding));

    // The "inference thread": steps a fixed input; records (generation, force) whenever the
    // output changes. position_x = 0.75, velocity = 0.5, f_previous_x = 3:
    //   linear: 2*0.5 - 3*0.75 + 0.5 = -0.75;  tree: 3 + 20 + 0.25 = 23.25
    let worker = std::thread::spawn(move || {
        let mut input = [0.0f64; 9];
        input[0] = 0.75;
        input[1] = 0.5;
        input[3] = 3.0;
        let mut active: Option<Box<Offered>> = None;
        let mut seen: Vec<(u64, f32)> = Vec::new();
        let mut steps_without_model = 0u64;
        while !stop2.load(Ordering::Relaxed) {
            if hold2.load(Ordering::Acquire) {
                holding2.store(true, Ordering::Release);
            } else {
                holding2.store(false, Ordering::Release);
                taker.take(&mut active);
            }
            match active.as_mut() {
                Some(a) => {
                    let f = a.engine.step(&input).unwrap();
                    if seen.last().map(|&(g, _)| g) != Some(a.generation) {
                        seen.push((a.generation, f));
                    }
                }
                None => steps_without_model += 1,
            }
            std::thread::sleep(Duration::from_micros(50));
        }
        (seen, steps_without_model)
    });

    let g1 = activator.offer(load("linear"));
    assert!(activator.wait_active(g1, Duration::from_secs(10)));
    assert_eq!(
        activator.active_info().unwrap().features,
        ["velocity", "position_x"]
    );
    let g2 = activator.offer(load("tree"));
    assert!(activator.wait_active(g2, Duration::from_secs(10)));
    let retired = activator
        .collect_retired()
        .expect("the old engine came back");
    assert_eq!(retired.generation, g1);
    assert_eq!(retired.engine.info().features, ["velocity", "position_x"]);
    assert_eq!(
        activator.active_info().unwrap().features,
        ["position_x", "f_previous_x"]
    );
    // Two offers in a row before the thread looks: only the last one is ever activated.
    let (third, fourth) = (load("linear"), load("tree"));
    hold.store(true, Ordering::Release);
    while !holding.load(Ordering::Acquire) {
        std::thread::sleep(Duration::from_micros(100));
    }
    let g3 = activator.offer(third);
    let g4 = activator.offer(fourth);
    hold.store(false, Ordering::Release);
    assert!(activator.wait_active(g4, Duration::from_secs(10)));
    stop.store(true, Ordering::Relaxed);
    let (seen, _) = worker.join().unwrap();

    let gens: Vec<u64> = seen.iter().map(|&(g, _)| g).collect();
    assert!(!gens.contains(&g3), "a withdrawn offer ran: {seen:?}");
    assert_eq!(gens, [g1, g2, g4]);
    assert!((seen[0].1 - (-0.75)).abs() < 1e-6, "{seen:?}");
    assert_eq!(seen[1].1, 23.25);
    assert_eq!(seen[2].1, 23.25);
}
