//! Issue 4 benchmark: rt-loop in realtime at 10 kHz against the real infer-server process, per
//! model (random forest 100 trees depth 9, dense 9-150-25-1, LSTM 100 units), beside the same
//! model called in process and over a tonic gRPC unary call, in the same run.
//!
//! Per model:
//! 1. `infer-server serve --model M` as a separate process (inference thread pinned to CPU 0,
//!    spinning `--spins` polls between steps, SCHED_OTHER); this benchmark process is the loop:
//!    rt-loop's own `run_with` (simulated hand, reproduction, the `ShmModel` client), realtime
//!    clock at 10 kHz, SCHED_FIFO/pinning/mlockall as rt-loop asks for them.
//!    - pass A, 50 us deadline: deadline misses per million steps (the loop's `late` counter);
//!    - pass B, 5 ms deadline: the loop-observed round trip (send to matching answer) uncensored
//!      by the deadline, p50/p99/p99.9/max.
//! 2. in process: `infer_server::StepEngine::step` on this thread, back to back.
//! 3. gRPC: a tonic unary call over TCP loopback to a server thread running the same
//!    `StepEngine` (shm-ring's bench proto), paced at 10 kHz.
//!
//! Env: BENCH_SECONDS (per pass, default 3), BENCH_SERVER_ARGS (extra infer-server serve flags,
//! default `--wait spin-park --spins 300000 --cpu 0`), BENCH_MODELS (e.g. `rf,lstm`).
//! Models: infer-server/benches/make_bench_models.py into target/bench-models.

use haptics_system_tests::{bin, repo_root, Proc};
use hdrhistogram::Histogram;
use infer_server::{FeatureSchema, Runtime, SessionConfig, StepEngine};
use rt_loop::config::{ClockKind, ExperimentKind, RunConfig};
use rt_loop::serving::shm_model::{AnswerWait, ShmClient, ShmModel};
use shm_ring::WaitStrategy;
use shm_ring_bench_grpc::predictor_client::PredictorClient;
use shm_ring_bench_grpc::predictor_server::{Predictor, PredictorServer};
use std::path::PathBuf;
use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

fn models_dir() -> PathBuf {
    let dir = repo_root().join("target/bench-models");
    if ["rf", "dense", "lstm"]
        .iter()
        .all(|m| dir.join(format!("{m}.onnx")).exists())
    {
        return dir;
    }
    let st = Command::new(haptics_system_tests::python())
        .arg(repo_root().join("infer-server/benches/make_bench_models.py"))
        .arg(&dir)
        .status()
        .expect("python");
    assert!(st.success(), "make_bench_models.py failed");
    dir
}

fn hist() -> Histogram<u64> {
    Histogram::new_with_bounds(1, 60_000_000_000, 3).unwrap()
}

#[derive(Clone, Copy)]
struct Q {
    p50: f64,
    p99: f64,
    p999: f64,
    max: f64,
    n: u64,
}

fn q(h: &Histogram<u64>) -> Q {
    let us = |v: u64| v as f64 / 1000.0;
    Q {
        p50: us(h.value_at_quantile(0.5)),
        p99: us(h.value_at_quantile(0.99)),
        p999: us(h.value_at_quantile(0.999)),
        max: us(h.max()),
        n: h.len(),
    }
}

fn features(t: u64) -> [f64; 9] {
    // plausible magnitudes: depth m, velocity m/s, acceleration m/s^2, the ratios, cycle...
    let s = (t as f64 * 1e-3).sin();
    [
        0.015 + 0.01 * s,
        0.01 * (t as f64 * 1e-3).cos(),
        0.5 * s,
        300.0 + 50.0 * s,
        200.0 * s,
        10.0 * s,
        (1 + t / 20_000) as f64,
        0.002,
        0.01,
    ]
}

fn in_process(engine: &mut StepEngine, steps: u64) -> Histogram<u64> {
    let mut h = hist();
    for t in 0..steps {
        let f = features(t);
        let t0 = Instant::now();
        let y = engine.step(&f[..]).expect("step");
        let dt = t0.elapsed().as_nanos() as u64;
        std::hint::black_box(y);
        if t >= steps / 10 {
            h.saturating_record(dt.max(1));
        }
    }
    h
}

struct EngineService(Mutex<StepEngine>);

#[tonic::async_trait]
impl Predictor for EngineService {
    async fn predict(
        &self,
        request: tonic::Request<shm_ring_bench_grpc::Features>,
    ) -> Result<tonic::Response<shm_ring_bench_grpc::Force>, tonic::Status> {
        let t0 = Instant::now();
        let f = request.into_inner();
        let force = self
            .0
            .lock()
            .unwrap()
            .step(&f.values[..])
            .map_err(|e| tonic::Status::internal(e.to_string()))?;
        Ok(tonic::Response::new(shm_ring_bench_grpc::Force {
            seq: f.seq,
            force: force as f64,
            model_id: 1,
            inference_ns: t0.elapsed().as_nanos() as u64,
        }))
    }
}

/// Pins the calling thread to `cpu` (shm-ring's OS layer; a refusal only costs the pinning).
fn pin(cpu: usize) {
    let _ = shm_ring::os::rt_thread::pin_current_thread(cpu);
}

fn unpin() {
    let _ = shm_ring::os::rt_thread::unpin_current_thread();
}

/// Unary gRPC calls paced at 10 kHz for `secs`.
fn grpc(engine: StepEngine, secs: f64) -> Histogram<u64> {
    let addr = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let stop_server = stop.clone();
    let service = EngineService(Mutex::new(engine));
    let server = std::thread::spawn(move || {
        pin(0);
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .enable_all()
            .build()
            .unwrap();
        rt.block_on(async move {
            let shutdown = async move {
                while !stop_server.load(Ordering::Acquire) {
                    tokio::time::sleep(Duration::from_millis(20)).await;
                }
            };
            tonic::transport::Server::builder()
                .tcp_nodelay(true)
                .add_service(PredictorServer::new(service))
                .serve_with_shutdown(addr, shutdown)
                .await
                .unwrap();
        });
    });
    pin(1);
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let h = rt.block_on(async {
        let endpoint = tonic::transport::Endpoint::from_shared(format!("http://{addr}"))
            .unwrap()
            .tcp_nodelay(true);
        let channel = loop {
            match endpoint.connect().await {
                Ok(c) => break c,
                Err(_) => tokio::time::sleep(Duration::from_millis(10)).await,
            }
        };
        let mut client = PredictorClient::new(channel);
        let mut h = hist();
        let n = (secs * 10_000.0) as u64;
        let warmup = n / 10;
        let start = Instant::now();
        for seq in 0..warmup + n {
            let due = start + Duration::from_micros(100 * seq);
            while Instant::now() < due {
                std::hint::spin_loop();
            }
            let t0 = Instant::now();
            let request = shm_ring_bench_grpc::Features {
                seq,
                timestamp_ns: 0,
                values: features(seq).to_vec(),
            };
            let answer = client.predict(request).await.unwrap().into_inner();
            assert_eq!(answer.seq, seq);
            if seq >= warmup {
                h.saturating_record((t0.elapsed().as_nanos() as u64).max(1));
            }
        }
        h
    });
    drop(rt);
    stop.store(true, Ordering::Release);
    server.join().unwrap();
    unpin();
    h
}

struct LoopPass {
    rtt: Histogram<u64>,
    steps: u64,
    late: u64,
    fallbacks: u64,
    overruns: u64,
}

/// One realtime reproduction run of `secs` through rt-loop's `run_with`: the client goes in as
/// the run's model and comes back with its result.
fn loop_pass(
    client: ShmClient,
    io: &mut rt_loop::serving::shm_io::LoopIo,
    deadline: Duration,
    secs: f64,
) -> (LoopPass, ShmClient) {
    let mut cfg = RunConfig {
        experiment: ExperimentKind::Reproduction,
        clock: ClockKind::Realtime,
        rate_hz: 10_000.0,
        ..RunConfig::default()
    };
    cfg.material = repo_root().join("materials/sponge.toml");
    cfg.max_duration_s = Some(secs);
    let before = client.counters.snapshot();
    let model = ShmModel::new(client, AnswerWait::Deadline(deadline), Duration::ZERO);
    let never = rt_loop::stop::Shutdown::new().expect("eventfd");
    let out = rt_loop::run::run_with(&cfg, Some(Box::new(model)), &never, None, Some(io));
    let s = out.result.expect("run");
    let c = out
        .model
        .and_then(ShmModel::from_model)
        .expect("the model comes back")
        .into_client();
    let after = c.counters.snapshot();
    let pass = LoopPass {
        rtt: c.round_trip_ns.clone(),
        steps: s.steps,
        late: after.late - before.late,
        fallbacks: s.model.map_or(0, |m| m.fallbacks),
        overruns: s.jitter.map_or(0, |j| j.overruns),
    };
    (pass, c)
}

fn main() {
    let secs: f64 = std::env::var("BENCH_SECONDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(3.0);
    let server_args = std::env::var("BENCH_SERVER_ARGS")
        .unwrap_or_else(|_| "--wait spin-park --spins 300000 --cpu 0".into());
    let only = std::env::var("BENCH_MODELS").unwrap_or_default();
    let dir = models_dir();
    let rt = Runtime::init(None).unwrap_or_else(|e| panic!("{e}"));
    let schema = FeatureSchema::standard();
    let _ = bin("infer-server");
    println!(
        "model-in-the-loop benchmark: {secs} s per pass at 10 kHz; infer-server serve {server_args}"
    );
    let mut table = Vec::new();
    for (name, label) in [
        ("rf", "random forest 100 x d9"),
        ("dense", "dense 9-150-25-1"),
        ("lstm", "LSTM 100 units"),
    ] {
        if !only.is_empty() && !only.split(',').any(|m| m == name) {
            continue;
        }
        let path = dir.join(format!("{name}.onnx"));
        // in process, then gRPC, then the loop against the real server
        pin(1);
        let mut engine = StepEngine::load(rt, &path, &schema, &SessionConfig::default())
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        let inproc = q(&in_process(&mut engine, 200_000));
        unpin();
        let grpc_q = q(&grpc(engine, secs));

        let instance = format!("bench-{}-{name}", std::process::id());
        let seg = rt_loop::serving::shm_io::create_segment(&instance, WaitStrategy::Spin)
            .expect("segment");
        let mut io = seg.io;
        let mut client = seg.client;
        let mut extra: Vec<String> = server_args.split_whitespace().map(String::from).collect();
        extra.extend(["--model".into(), path.display().to_string()]);
        let mut cmd = Command::new(bin("infer-server"));
        cmd.args(["serve", "--instance", &instance, "--grpc", "127.0.0.1:0"])
            .args(["--http", "127.0.0.1:0"])
            .args(&extra)
            .current_dir(repo_root());
        let mut server = Proc::spawn("infer-server", &mut cmd);
        server.wait_for("infer-server: gRPC ", Duration::from_secs(60));
        assert!(
            client.wait_for_server(Duration::from_secs(60)),
            "infer-server did not attach:\n{}",
            server.output()
        );
        // warm-up (model activation, caches), then the two passes
        let (_, client) = loop_pass(client, &mut io, Duration::from_millis(5), 0.5);
        let (a, client) = loop_pass(client, &mut io, Duration::from_micros(50), secs);
        let (b, _) = loop_pass(client, &mut io, Duration::from_millis(5), secs);
        server.signal(libc::SIGINT);
        let _ = server.wait_exit(Duration::from_secs(10));
        let rtt = q(&b.rtt);
        println!(
            "{label}: pass A {} steps, {} late at 50 us, {} fallbacks, {} overruns; pass B {} steps, {} round trips, {} late at 5 ms, {} overruns",
            a.steps, a.late, a.fallbacks, a.overruns, b.steps, rtt.n, b.late, b.overruns
        );
        table.push((
            label,
            inproc,
            rtt,
            grpc_q,
            a.late as f64 * 1e6 / a.steps.max(1) as f64,
        ));
    }
    println!();
    println!("| model | path | p50 us | p99 us | p99.9 us | max us | misses/M @50us |");
    println!("| --- | --- | ---: | ---: | ---: | ---: | ---: |");
    for (label, inproc, rtt, g, misses) in &table {
        for (path, x, m) in [
            (
                "loop -> shm -> infer-server -> loop",
                rtt,
                format!("{misses:.0}"),
            ),
            ("in process (StepEngine)", inproc, "-".into()),
            ("gRPC unary (tonic, loopback)", g, "-".into()),
        ] {
            println!(
                "| {label} | {path} | {:.2} | {:.2} | {:.2} | {:.1} | {m} |",
                x.p50, x.p99, x.p999, x.max
            );
        }
    }
    println!();
    println!("| model | shm p50 / in-process p50 | gRPC p50 / shm p50 | gRPC p99 / shm p99 | 4 ms / shm p99.9 |");
    println!("| --- | ---: | ---: | ---: | ---: |");
    for (label, inproc, rtt, g, _) in &table {
        println!(
            "| {label} | {:.2} | {:.1} | {:.1} | {:.0} |",
            rtt.p50 / inproc.p50,
            g.p50 / rtt.p50,
            g.p99 / rtt.p99,
            4000.0 / rtt.p999
        );
    }
}
