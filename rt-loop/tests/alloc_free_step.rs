//! The loop step allocates nothing: a counting global allocator around `Rig::step` (and the
//! recorder ring push) for every experiment.

#[path = "support/alloc_count.rs"]
mod alloc_count;
mod common;

use rt_loop::config::ExperimentKind;

fn count_step_allocs(cfg: &rt_loop::config::RunConfig, steps: usize) -> (u64, usize) {
    let mut rig = rt_loop::run::build_rig(cfg, None).unwrap();
    let (mut prod, mut cons) = rtrb::RingBuffer::<rt_loop::record::Row>::new(1024);
    alloc_count::start();
    let mut done = 0;
    for _ in 0..steps {
        match rig.step() {
            Ok(row) => {
                let _ = prod.push(row);
                done += 1;
            }
            Err(_) => break,
        }
        if prod.slots() == 0 {
            // drain without allocating (the test thread plays the recorder)
            while cons.pop().is_ok() {}
        }
    }
    (alloc_count::stop(), done)
}

// One test function only: the counter is global, parallel tests would pollute it.
#[test]
fn step_allocates_nothing_in_any_experiment() {
    let cfg = common::short_cfg(2, 8.0, 2.0);
    let (n, done) = count_step_allocs(&cfg, 30_000);
    assert!(done >= 30_000);
    assert_eq!(n, 0, "abstraction step allocated {n} times");

    let dir = common::tmpdir("alloc");
    let rec = dir.join("traj.csv");
    // a tiny trajectory file for position replay
    let mut s = String::from("time,position_x\n");
    for i in 0..=200 {
        let t = i as f64 * 0.01;
        s += &format!("{t},{}\n", 0.01 * (t * 2.0).sin().abs());
    }
    std::fs::write(&rec, s).unwrap();
    let mut pr = common::short_cfg(1, 8.0, 2.0);
    pr.experiment = ExperimentKind::PositionReplay;
    pr.trajectory = Some(rec);
    let (n, done) = count_step_allocs(&pr, 15_000);
    assert!(done >= 15_000);
    assert_eq!(n, 0, "position replay step allocated {n} times");

    for kind in [ExperimentKind::Reproduction, ExperimentKind::Shadow] {
        let mut r = common::short_cfg(1, 8.0, 2.0);
        r.experiment = kind;
        let (n, done) = count_step_allocs(&r, 30_000);
        assert!(done >= 30_000);
        assert_eq!(n, 0, "{kind:?} step allocated {n} times");
    }

    // the passivity layer acting on every path (observing, damping, withholding): an active
    // object (negative damping) rendered with the layer on
    let mut p = common::short_cfg(1, 8.0, 2.0);
    p.experiment = ExperimentKind::Reproduction;
    p.passivity.mode = rt_loop::passivity::PassivityMode::On;
    p.reproduction.fallback.b = -100.0;
    let mut rig = rt_loop::run::build_rig(&p, None).unwrap();
    alloc_count::start();
    let mut done = 0;
    while done < 40_000 && rig.step().is_ok() {
        done += 1;
    }
    let n = alloc_count::stop();
    let rep = rig.passivity.report();
    assert!(
        done >= 40_000 && rep.active_steps > 0,
        "{done} steps, {rep:?}"
    );
    assert_eq!(
        n, 0,
        "a step with the passivity layer on allocated {n} times"
    );

    // the counter itself works: a Vec allocates
    alloc_count::start();
    let v = vec![1u8; 10];
    assert!(alloc_count::stop() > 0);
    drop(v);
}
