//! Issue 5's hot swap against the real loop: `rt-loop serve --clock realtime` at 10 kHz runs a
//! shadow experiment (the served model is asked every step) while this test swaps between two
//! models 100 times over gRPC (the generated `haptics.v1` client) against a real
//! `infer-server serve`. From the loop's own recording it checks: no step lost (every step
//! present, in order, and each one sent to the server), every step the model answered in time
//! carries the output of the model its step's interval says (so each swap's reported effective
//! step is exactly where the served output changes), that a corrupt model, one whose warm-up
//! gives NaN, one with wrong inputs and one wanting a feature the loop lacks are refused
//! half-way with their reason while the active model serves on, and it prints the deadline
//! misses near swaps and away from them.
//!
//! Parking/spin-then-park waits on both sides: this machine has two cores.

use control_plane::pb::{
    loop_service_client::LoopServiceClient, model_service_client::ModelServiceClient,
    ActivateModelRequest, GetActiveModelRequest, GetStatusRequest, LoadModelRequest,
    StartExperimentRequest, StopExperimentRequest,
};
use haptics_system_tests::{
    bin, instance, start_infer_server, temp_dir, write_linear_model, Proc, TEST_TOKEN,
};
use std::process::Command;
use std::time::{Duration, Instant};

const SWAPS: usize = 100;
/// Steps on each side of a swap that count as "around" it (5 ms at 10 kHz).
const WINDOW: i64 = 50;
/// The two models answer constants (weight 0 on one feature), so every answered step says
/// which model answered it; both are exact in f32.
const VALUE_A: f64 = 1.0;
const VALUE_B: f64 = 2.0;

/// The server's token on every call (infer-server requires it on loopback too).
type WithToken = fn(tonic::Request<()>) -> Result<tonic::Request<()>, tonic::Status>;
type Authed = tonic::service::interceptor::InterceptedService<tonic::transport::Channel, WithToken>;
type Models = ModelServiceClient<Authed>;

fn with_token(mut r: tonic::Request<()>) -> Result<tonic::Request<()>, tonic::Status> {
    let value = format!("Bearer {TEST_TOKEN}").parse().expect("ASCII token");
    r.metadata_mut().insert("authorization", value);
    Ok(r)
}

async fn channel(url: &str) -> tonic::transport::Channel {
    tonic::transport::Endpoint::from_shared(url.to_string())
        .expect("gRPC address")
        .connect()
        .await
        .expect("connect gRPC")
}

/// ActivateModel over gRPC; the effective step it reports.
fn activate(rt: &tokio::runtime::Runtime, models: &mut Models, name: &str) -> u64 {
    rt.block_on(models.activate_model(ActivateModelRequest {
        name: name.into(),
        load_if_needed: false,
    }))
    .unwrap_or_else(|e| panic!("activate {name}: {e}"))
    .get_ref()
    .effective_step
}

#[test]
fn hundred_swaps_under_the_realtime_loop_lose_nothing() {
    let dir = temp_dir("swap");
    write_linear_model(&dir.join("a.onnx"), &["position_x"], &[0.0], VALUE_A as f32);
    write_linear_model(&dir.join("b.onnx"), &["position_x"], &[0.0], VALUE_B as f32);
    // A shadow run long enough for 100 swaps (1 s rest + 8 presses of 4 s); stopped early.
    // Models that must be refused while the loop runs, the active model serving on.
    std::fs::write(dir.join("corrupt.onnx"), b"this is not an ONNX model").unwrap();
    write_linear_model(&dir.join("nan.onnx"), &["position_x"], &[0.0], f32::NAN);
    write_linear_model(&dir.join("missing.onnx"), &["no_such_feature"], &[1.0], 0.0);
    haptics_system_tests::run_python(
        "import sys, onnx\n\
         m = onnx.load(sys.argv[1])\n\
         m.graph.input[0].name = 'x'\n\
         m.graph.node[0].input[0] = 'x'\n\
         onnx.save(m, sys.argv[2])\n",
        &[
            dir.join("a.onnx").to_str().unwrap(),
            dir.join("wrong_inputs.onnx").to_str().unwrap(),
        ],
    );
    let config = dir.join("loop.toml");
    std::fs::write(&config, "[hand]\nrepeats = 8\n").unwrap();
    let inst = instance("swap");
    let rec_dir = dir.join("rec");
    let mut lp = Proc::spawn(
        "rt-loop serve",
        Command::new(bin("rt-loop"))
            .args(["serve", "--instance", &inst, "--clock", "realtime"])
            .args(["--rate-hz", "10000", "--deadline-us", "100"])
            .args(["--wait", "spin-park", "--config"])
            .arg(&config)
            .arg("--record-dir")
            .arg(&rec_dir),
    );
    lp.wait_for("serving segment", Duration::from_secs(30));
    let (_server, addr) = start_infer_server(&inst, &dir, Some("a.onnx"));
    let url = format!("http://{addr}");

    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let (mut models, mut lps) = rt.block_on(async {
        (
            ModelServiceClient::with_interceptor(channel(&url).await, with_token as WithToken),
            LoopServiceClient::with_interceptor(channel(&url).await, with_token as WithToken),
        )
    });
    let end = Instant::now() + Duration::from_secs(20);
    while !rt
        .block_on(lps.get_status(GetStatusRequest {}))
        .is_ok_and(|s| s.get_ref().loop_alive && s.get_ref().active_model.is_some())
    {
        assert!(Instant::now() < end, "loop alive with a.onnx active");
        std::thread::sleep(Duration::from_millis(50));
    }
    rt.block_on(models.load_model(LoadModelRequest {
        name: "b.onnx".into(),
        onnx: vec![],
    }))
    .expect("load b.onnx");
    // Activated while the loop idles: the server cannot see the step yet (it reports the next
    // one it expects); once the run starts, `active_since_step` says which sequence number b
    // answered first: the run's step 0. That pins the loop's step <-> sequence number mapping
    // (the sequence number rises over the segment's life, the step restarts at 0 with each
    // run; every step of the run sends exactly one request, checked below).
    let idle_reported = activate(&rt, &mut models, "b.onnx");

    rt.block_on(lps.start_experiment(StartExperimentRequest {
        kind: "shadow".into(),
        ..Default::default()
    }))
    .expect("start shadow");
    lp.wait_for("run 1: Shadow", Duration::from_secs(10));
    std::thread::sleep(Duration::from_millis(300));
    let active = rt
        .block_on(models.get_active_model(GetActiveModelRequest {}))
        .expect("active model")
        .into_inner();
    assert_eq!(active.name, "b.onnx");
    let seq_of_step0 = active.active_since_step;
    assert!(
        seq_of_step0 >= idle_reported,
        "{seq_of_step0} vs {idle_reported}"
    );

    // 100 swaps, a 20 ms pause after each so that there are steps away from swaps too.
    let mut swaps: Vec<(u64, f64)> = Vec::with_capacity(SWAPS); // (effective seq, new value)
    let t_swaps = Instant::now();
    for k in 0..SWAPS {
        let (name, value) = if k % 2 == 0 {
            ("a.onnx", VALUE_A)
        } else {
            ("b.onnx", VALUE_B)
        };
        swaps.push((activate(&rt, &mut models, name), value));
        std::thread::sleep(Duration::from_millis(20));
        if k == SWAPS / 2 {
            // Half-way: bad models refused with their reason; nothing changes for the loop
            // (checked below: every answered step still carries the active model's output).
            for (bad, code, says) in [
                ("corrupt.onnx", tonic::Code::InvalidArgument, "corrupt"),
                ("nan.onnx", tonic::Code::InvalidArgument, "non_finite"),
                ("wrong_inputs.onnx", tonic::Code::InvalidArgument, "input"),
                (
                    "missing.onnx",
                    tonic::Code::FailedPrecondition,
                    "no_such_feature",
                ),
            ] {
                let e = rt
                    .block_on(models.activate_model(ActivateModelRequest {
                        name: bad.into(),
                        load_if_needed: true,
                    }))
                    .expect_err(bad);
                eprintln!("refused {bad}: {:?} {}", e.code(), e.message());
                assert_eq!(e.code(), code, "{bad}: {e}");
                assert!(
                    e.message().to_lowercase().contains(says),
                    "{bad}: the reason should mention {says:?}: {}",
                    e.message()
                );
            }
            let active = rt
                .block_on(models.get_active_model(GetActiveModelRequest {}))
                .unwrap()
                .into_inner();
            assert_eq!(active.name, name, "the active model stays after refusals");
        }
    }
    let swap_s = t_swaps.elapsed().as_secs_f64();
    std::thread::sleep(Duration::from_millis(100));
    let status = rt
        .block_on(lps.get_status(GetStatusRequest {}))
        .unwrap()
        .into_inner();
    rt.block_on(lps.stop_experiment(StopExperimentRequest {}))
        .expect("stop");
    let out = lp.wait_for("run 1 ended", Duration::from_secs(20));
    let ended = out.lines().find(|l| l.contains("run 1 ended")).unwrap();
    assert!(ended.contains("ended: stopped"), "{ended}");

    // The run's recording, written by the loop's recorder.
    let recs: Vec<_> = std::fs::read_dir(&rec_dir)
        .unwrap()
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "parquet"))
        .collect();
    assert_eq!(recs.len(), 1, "{recs:?}");
    let cols = rt_loop::record::read::read_columns(
        &recs[0],
        &["step", "F_pred", "fallback", "position_x"],
    )
    .unwrap();
    let (steps, f_pred, fallback, xs) = (&cols[0], &cols[1], &cols[2], &cols[3]);
    let n = steps.len();
    // The degradation ladder (docs/rt-loop.md): out of contact the loop renders 0 N (unilateral),
    // and after an outage long enough for the fallback to fade in, the model's answers are
    // faded back in over a few ms: such steps are not the bare model output.
    let blended: Vec<bool> = {
        let (mut out, mut run, mut until) = (vec![false; n], 0usize, 0usize);
        for i in 0..n {
            if fallback[i] != 0.0 {
                run += 1;
                if run > 20 {
                    until = i + 150;
                }
            } else {
                run = 0;
            }
            out[i] = i < until;
        }
        out
    };
    for i in 0..n {
        if xs[i] <= 0.0 {
            assert_eq!(
                f_pred[i], 0.0,
                "step {i}: out of contact the loop renders 0 N"
            );
        }
    }

    // Zero lost steps: every step of the run is in the recording, in order...
    for (i, s) in steps.iter().enumerate() {
        assert_eq!(*s, i as f64, "step {i} missing or out of order");
    }
    // The number just before `key` in the loop's run summary line.
    let field = |key: &str| -> u64 {
        let pos = ended
            .find(key)
            .unwrap_or_else(|| panic!("{key:?} in {ended:?}"));
        let word = ended[..pos].split_whitespace().last().unwrap_or("");
        word.parse()
            .unwrap_or_else(|e| panic!("{key:?} after {word:?}: {e} in {ended:?}"))
    };
    // ...and every one asked the server (one request per step: the sequence numbers of the run
    // are seq_of_step0 + step).
    assert_eq!(field(" steps,"), n as u64, "{ended}");
    assert_eq!(field(" sent,"), n as u64, "{ended}");

    // The served model's output, step by step, against the reported effective steps.
    let change: Vec<i64> = swaps
        .iter()
        .map(|(seq, _)| *seq as i64 - seq_of_step0 as i64)
        .collect();
    for w in change.windows(2) {
        assert!(w[0] < w[1], "effective steps rise: {change:?}");
    }
    assert!(
        change[0] > 0 && (*change.last().unwrap() as usize) < n,
        "swaps inside the run: {change:?}, {n} steps"
    );
    // Where the output actually changed, per swap (first model answer with the new value
    // after the previous change), for the failure message.
    let observed: Vec<i64> = {
        let (mut out, mut k, mut cur) = (Vec::new(), 0, VALUE_B);
        for i in 0..n {
            if k < SWAPS && fallback[i] == 0.0 && xs[i] > 0.0 && !blended[i] && f_pred[i] != cur {
                cur = f_pred[i];
                out.push(i as i64);
                k += 1;
            }
        }
        out
    };
    let diffs: Vec<i64> = change
        .iter()
        .zip(&observed)
        .map(|(c, o)| o - c)
        .take(12)
        .collect();
    let mut interval = 0; // swaps that took effect at or before this step
    let mut answered = 0u64;
    // After any flagged step the ladder's change of rung is slew-limited (docs/rt-loop.md,
    // ladder.rs): the rendered force walks from the held value to the model's answer by at
    // most `slew_n_per_step` (0.04 N by default) per step, and a fallback cross-fade that began
    // (after `hold_max_s` of loop time, which under load can be few steps) fades out the same
    // way. A miss right at a swap leaves the old model's value held, so the first on-time steps
    // after it are still catching up: they are checked to move within the slew limit, not to
    // equal the answer, until they reach it.
    const SLEW_N_PER_STEP: f64 = 0.04;
    let mut catching_up = false;
    let mut caught_up_steps = 0u64;
    for i in 0..n {
        while interval < SWAPS && change[interval] <= i as i64 {
            interval += 1;
        }
        if fallback[i] != 0.0 {
            catching_up = true;
        }
        if fallback[i] != 0.0 || xs[i] <= 0.0 || blended[i] {
            // not rendered by the on-time answer (late, flagged, ...), out of contact, or
            // the model fading back in: no bare model output to check
            continue;
        }
        let want = if interval == 0 {
            VALUE_B
        } else {
            swaps[interval - 1].1
        };
        if catching_up && f_pred[i] != want && i > 0 {
            let (prev, now) = (f_pred[i - 1], f_pred[i]);
            assert!(
                (now - prev).abs() <= SLEW_N_PER_STEP + 1e-9,
                "step {i}: catching up after a flagged step ({want} N wanted), {prev} -> {now} \
                 moves more than {SLEW_N_PER_STEP} N"
            );
            caught_up_steps += 1;
            continue;
        }
        catching_up = false;
        assert_eq!(
            f_pred[i], want,
            "step {i}: served {} but the reported effective steps say {want} (swap {interval} of {SWAPS}); \
             observed change minus reported, first swaps: {diffs:?}",
            f_pred[i]
        );
        answered += 1;
    }
    // Each swap's change is observable: a model answer right before and right after it.
    let seen_at = |from: i64, to: i64| {
        (from.max(0)..to.min(n as i64)).any(|i| fallback[i as usize] == 0.0 && xs[i as usize] > 0.0)
    };
    let sharp = change
        .iter()
        .filter(|&&c| seen_at(c - 3, c) && seen_at(c, c + 3))
        .count();

    // Deadline misses (fallback steps) within WINDOW steps of a swap vs away from swaps, from
    // the first swap's window on (the run's start is neither).
    let first = (change[0] - 4 * WINDOW).max(0) as usize;
    let mut near = vec![false; n];
    for &c in &change {
        for i in (c - WINDOW).max(0)..(c + WINDOW + 1).min(n as i64) {
            near[i as usize] = true;
        }
    }
    let (mut around, mut around_miss, mut away, mut away_miss) = (0u64, 0u64, 0u64, 0u64);
    for i in first..n {
        let miss = u64::from(fallback[i] != 0.0);
        if near[i] {
            around += 1;
            around_miss += miss;
        } else {
            away += 1;
            away_miss += miss;
        }
    }
    let per_million = |m: u64, s: u64| m as f64 * 1e6 / s.max(1) as f64;
    let (around_rate, away_rate) = (
        per_million(around_miss, around),
        per_million(away_miss, away),
    );
    let rtt = status.round_trip_latency.unwrap_or_default();
    eprintln!(
        "swap test: {n} steps, {answered} answered by the model in time ({caught_up_steps} more \
         slewing back to it after a flagged step), {SWAPS} swaps in {swap_s:.2} s, \
         {sharp} with a model answer within 3 steps on both sides\n\
         deadline misses (100 us): around swaps (+-{WINDOW} steps) {around_miss} of {around} steps = {around_rate:.0} per million \
         ({:.1} per swap); \
         away from swaps {away_miss} of {away} steps = {away_rate:.0} per million\n\
         loop status: scheduling {:?}, round trip p50 {:.1} us p99 {:.1} us p99.9 {:.1} us max {:.1} us ({} samples), \
         {} deadline misses in the run so far\n{ended}",
        around_miss as f64 / SWAPS as f64,
        status.scheduling,
        rtt.p50_us,
        rtt.p99_us,
        rtt.p999_us,
        rtt.max_us,
        rtt.count,
        status.deadline_misses,
    );
    let in_contact = xs.iter().filter(|x| **x > 0.0).count() as u64;
    assert!(
        answered > in_contact / 2,
        "most steps in contact answered by the model ({answered} of {in_contact})"
    );
    // The strict comparison (around <= away) is a benchmark matter (infer-server's hot_swap
    // bench): on this shared two-core machine the swap itself (the control plane's thread
    // re-warming and handing over the engine) competes with the inference thread for the one
    // core the loop does not hold, and whatever else runs adds bursts of misses unrelated to
    // swaps. Measured here: about 7 missed steps per swap at a 100 us deadline (the first
    // steps of the new model, while the server catches up), against under 1 % away from
    // swaps. What must hold whatever the load: a swap costs at most a few steps, never a
    // flood. Allowed: 10x the away-from-swap rate plus 10 steps (1 ms) per swap.
    let allowed = 10.0 * away_rate / 1e6 * around as f64 + 10.0 * SWAPS as f64;
    assert!(
        (around_miss as f64) <= allowed,
        "misses around swaps {around_miss} (of {around} steps) > allowed {allowed:.0}"
    );
}
