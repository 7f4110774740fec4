//! Round-trip latency, loop to server and back: the loop writes one feature vector, a server
//! thread answers with a force, the loop reads it. Compared across transports:
//!
//! - this crate's shared-memory rings, with each wait strategy;
//! - a Unix domain socket (blocking reads/writes of the same bytes);
//! - a tonic gRPC unary call over TCP loopback (the thesis's client-server split done well).
//!
//! `cargo bench -p shm-ring` runs it all and prints p50/p99/p99.9/max and round trips per
//! second. Scale the counts with `SHM_BENCH_SCALE` (default 1.0).
//!
//! On a 2-core machine the "spin" row spins on both sides: one thread per core, acceptable in a
//! benchmark only (the tests and the product park on at least one side).

use std::io::{Read, Write};
use std::os::unix::net::UnixStream;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use haptics_proto::{FeatureMsg, ForceMsg, Segment, MAX_FEATURES};
use hdrhistogram::Histogram;
use shm_ring::os::rt_thread::{self, online_cpus};
use shm_ring::{SegmentName, WaitStrategy};
use shm_ring_bench_grpc::predictor_client::PredictorClient;
use shm_ring_bench_grpc::predictor_server::{Predictor, PredictorServer};

/// What the "model" computes in every transport: cheap, but it reads every feature.
fn model(values: &[f64]) -> f64 {
    values
        .iter()
        .enumerate()
        .map(|(i, v)| v * (i as f64 + 1.0))
        .sum::<f64>()
        * 1e-3
}

fn features(seq: u64) -> FeatureMsg {
    let mut values = [0.0; MAX_FEATURES];
    for (i, v) in values.iter_mut().enumerate().take(9) {
        *v = (seq as f64 * 0.001 + i as f64).sin();
    }
    FeatureMsg {
        seq,
        timestamp_ns: seq * 1_000_000,
        run_id: 1,
        flags: 0,
        len: 9,
        values,
    }
}

/// Back to back (throughput, the other side rarely gets to sleep) or one exchange per
/// millisecond like the real loop at 1 kHz (the server parks between steps, so its wake-up
/// latency is in every round trip).
#[derive(Clone, Copy)]
enum Pace {
    BackToBack,
    Hz1000,
}

impl Pace {
    fn wait(self) {
        if let Pace::Hz1000 = self {
            // Sleep most of the period, then spin to the tick: the sleep is not part of the
            // measured round trip.
            let until = Instant::now() + Duration::from_millis(1);
            std::thread::sleep(Duration::from_micros(900));
            while Instant::now() < until {
                std::hint::spin_loop();
            }
        }
    }

    fn label(self, transport: &'static str) -> &'static str {
        match (self, transport) {
            (Pace::BackToBack, t) => t,
            (Pace::Hz1000, "shm ring") => "shm ring @1 kHz",
            (Pace::Hz1000, "unix socket") => "unix socket @1 kHz",
            (Pace::Hz1000, _) => "gRPC @1 kHz",
        }
    }
}

struct Row {
    transport: &'static str,
    wait: &'static str,
    hist: Histogram<u64>,
    per_sec: f64,
}

fn new_hist() -> Histogram<u64> {
    Histogram::new_with_bounds(1, 60_000_000_000, 3).unwrap()
}

fn count(base: u64) -> u64 {
    let scale: f64 = std::env::var("SHM_BENCH_SCALE")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1.0);
    ((base as f64 * scale) as u64).max(1000)
}

/// Pins the calling thread to one CPU (when the machine has more than one), so the two sides
/// of a spinning exchange do not fight over a core (shm-ring's OS layer; a refusal only costs
/// the pinning).
fn pin(cpu: usize) {
    let cpus = online_cpus();
    if cpus >= 2 {
        let _ = rt_thread::pin_current_thread(cpu % cpus);
    }
}

fn unpin() {
    let _ = rt_thread::unpin_current_thread();
}

fn bench_shm(
    label: &'static str,
    loop_wait: WaitStrategy,
    server_wait: WaitStrategy,
    n: u64,
    pace: Pace,
) -> Row {
    let name = SegmentName::for_instance(&format!("bench-{}", std::process::id())).unwrap();
    let mut lp = Segment::create(&name, &haptics_proto::layout::config())
        .unwrap()
        .loop_side()
        .unwrap();
    lp.forces_rx.set_wait_strategy(loop_wait);
    let mut sv = Segment::attach(&name).unwrap().server_side().unwrap();
    sv.features_rx.set_wait_strategy(server_wait);
    let server = std::thread::spawn(move || {
        pin(1);
        while let Ok(f) = sv.features_rx.recv() {
            let t0 = Instant::now();
            let force = model(f.features());
            let answer = ForceMsg {
                seq: f.seq,
                force,
                model_id: 1,
                flags: 0,
                inference_ns: t0.elapsed().as_nanos() as u64,
            };
            if sv.forces_tx.send(answer).is_err() {
                break;
            }
        }
    });
    pin(0);
    let warmup = n / 10;
    let mut hist = new_hist();
    let mut started = Instant::now();
    for seq in 0..warmup + n {
        if seq == warmup {
            started = Instant::now();
        }
        pace.wait();
        let msg = features(seq);
        let t0 = Instant::now();
        lp.features_tx
            .try_send(msg)
            .expect("ring has room: one request in flight");
        let force = lp
            .forces_rx
            .recv_timeout(Duration::from_secs(5))
            .expect("answer");
        let rtt = t0.elapsed().as_nanos() as u64;
        assert_eq!(force.seq, seq);
        assert_eq!(force.force, model(msg.features()));
        if seq >= warmup {
            hist.record(rtt.max(1)).unwrap();
        }
    }
    let per_sec = n as f64 / started.elapsed().as_secs_f64();
    drop(lp); // the server sees the loop go and exits
    server.join().unwrap();
    unpin();
    Row {
        transport: pace.label("shm ring"),
        wait: label,
        hist,
        per_sec,
    }
}

const FEATURE_BYTES: usize = 8 + 8 + 8 * MAX_FEATURES;
const FORCE_BYTES: usize = 32;

fn bench_uds(n: u64, pace: Pace) -> Row {
    let (mut client, mut server_end) = UnixStream::pair().unwrap();
    let server = std::thread::spawn(move || {
        pin(1);
        let mut buf = [0u8; FEATURE_BYTES];
        while server_end.read_exact(&mut buf).is_ok() {
            let t0 = Instant::now();
            let seq = u64::from_le_bytes(buf[..8].try_into().unwrap());
            let mut values = [0.0; MAX_FEATURES];
            for (i, v) in values.iter_mut().enumerate() {
                *v = f64::from_le_bytes(buf[16 + 8 * i..24 + 8 * i].try_into().unwrap());
            }
            let force = model(&values[..9]);
            let mut out = [0u8; FORCE_BYTES];
            out[..8].copy_from_slice(&seq.to_le_bytes());
            out[8..16].copy_from_slice(&force.to_le_bytes());
            out[16..24].copy_from_slice(&1u64.to_le_bytes());
            out[24..].copy_from_slice(&(t0.elapsed().as_nanos() as u64).to_le_bytes());
            if server_end.write_all(&out).is_err() {
                break;
            }
        }
    });
    pin(0);
    let warmup = n / 10;
    let mut hist = new_hist();
    let mut started = Instant::now();
    let mut frame = [0u8; FEATURE_BYTES];
    let mut answer = [0u8; FORCE_BYTES];
    for seq in 0..warmup + n {
        if seq == warmup {
            started = Instant::now();
        }
        pace.wait();
        let msg = features(seq);
        let t0 = Instant::now();
        frame[..8].copy_from_slice(&seq.to_le_bytes());
        frame[8..16].copy_from_slice(&msg.timestamp_ns.to_le_bytes());
        for (i, v) in msg.values.iter().enumerate() {
            frame[16 + 8 * i..24 + 8 * i].copy_from_slice(&v.to_le_bytes());
        }
        client.write_all(&frame).unwrap();
        client.read_exact(&mut answer).unwrap();
        let rtt = t0.elapsed().as_nanos() as u64;
        assert_eq!(u64::from_le_bytes(answer[..8].try_into().unwrap()), seq);
        if seq >= warmup {
            hist.record(rtt.max(1)).unwrap();
        }
    }
    let per_sec = n as f64 / started.elapsed().as_secs_f64();
    drop(client);
    server.join().unwrap();
    unpin();
    Row {
        transport: pace.label("unix socket"),
        wait: "blocking",
        hist,
        per_sec,
    }
}

struct EchoModel;

#[tonic::async_trait]
impl Predictor for EchoModel {
    async fn predict(
        &self,
        request: tonic::Request<shm_ring_bench_grpc::Features>,
    ) -> Result<tonic::Response<shm_ring_bench_grpc::Force>, tonic::Status> {
        let t0 = Instant::now();
        let f = request.into_inner();
        let force = model(&f.values);
        Ok(tonic::Response::new(shm_ring_bench_grpc::Force {
            seq: f.seq,
            force,
            model_id: 1,
            inference_ns: t0.elapsed().as_nanos() as u64,
        }))
    }
}

fn bench_grpc(n: u64, pace: Pace) -> Row {
    // Server: its own OS thread with a one-worker runtime (like the shm server thread).
    let addr = {
        let probe = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        probe.local_addr().unwrap()
    };
    let stop = Arc::new(AtomicBool::new(false));
    let stop_server = stop.clone();
    let server = std::thread::spawn(move || {
        pin(1);
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
                .add_service(PredictorServer::new(EchoModel))
                .serve_with_shutdown(addr, shutdown)
                .await
                .unwrap();
        });
    });
    pin(0);
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let row = rt.block_on(async {
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
        let warmup = n / 10;
        let mut hist = new_hist();
        let mut started = Instant::now();
        for seq in 0..warmup + n {
            if seq == warmup {
                started = Instant::now();
            }
            pace.wait();
            let msg = features(seq);
            let t0 = Instant::now();
            let request = shm_ring_bench_grpc::Features {
                seq,
                timestamp_ns: msg.timestamp_ns,
                values: msg.features().to_vec(),
            };
            let answer = client.predict(request).await.unwrap().into_inner();
            let rtt = t0.elapsed().as_nanos() as u64;
            assert_eq!(answer.seq, seq);
            if seq >= warmup {
                hist.record(rtt.max(1)).unwrap();
            }
        }
        let per_sec = n as f64 / started.elapsed().as_secs_f64();
        Row {
            transport: pace.label("gRPC (tonic, TCP loopback)"),
            wait: "tokio",
            hist,
            per_sec,
        }
    });
    drop(rt); // closes the client's connection, so the server's graceful shutdown can finish
    stop.store(true, Ordering::Release);
    server.join().unwrap();
    unpin();
    row
}

fn us(ns: u64) -> f64 {
    ns as f64 / 1000.0
}

fn main() {
    // `cargo bench` passes `--bench`; a libtest-style filter is accepted but ignored.
    let cpus = online_cpus();
    println!(
        "shm-ring round trip (loop writes features, server thread answers a force, loop reads it)"
    );
    println!("{cpus} CPUs; loop thread pinned to CPU 0, server thread to CPU 1\n");

    let spin_then_park = match std::env::var("SHM_BENCH_SPINS")
        .ok()
        .and_then(|s| s.parse().ok())
    {
        Some(spins) => WaitStrategy::SpinThenPark { spins },
        None => WaitStrategy::DEFAULT_SPIN_THEN_PARK,
    };
    use Pace::{BackToBack, Hz1000};
    let (spin, park) = (WaitStrategy::Spin, WaitStrategy::Park);
    let mut rows = vec![
        bench_shm("spin / spin", spin, spin, count(1_000_000), BackToBack),
        bench_shm(
            "spin-then-park / spin-then-park",
            spin_then_park,
            spin_then_park,
            count(500_000),
            BackToBack,
        ),
        bench_shm("spin / park", spin, park, count(200_000), BackToBack),
        bench_shm("park / park", park, park, count(200_000), BackToBack),
        bench_uds(count(200_000), BackToBack),
        bench_grpc(count(50_000), BackToBack),
    ];
    let grpc_p99 = rows.last().unwrap().hist.value_at_quantile(0.99) as f64;
    let paced = count(20_000) / 10; // 1 ms each
    rows.push(bench_shm("spin / park", spin, park, paced, Hz1000));
    rows.push(bench_shm(
        "spin-then-park / spin-then-park",
        spin_then_park,
        spin_then_park,
        paced,
        Hz1000,
    ));
    rows.push(bench_uds(paced, Hz1000));
    rows.push(bench_grpc(paced, Hz1000));

    println!(
        "{:<28} {:<32} {:>9} {:>9} {:>9} {:>10} {:>12} {:>12}",
        "transport",
        "wait (loop / server)",
        "p50 us",
        "p99 us",
        "p99.9 us",
        "max us",
        "round trips/s",
        "gRPC p99 / p99"
    );
    for r in &rows {
        let h = &r.hist;
        println!(
            "{:<28} {:<32} {:>9.2} {:>9.2} {:>9.2} {:>10.1} {:>12.0} {:>11.1}x",
            r.transport,
            r.wait,
            us(h.value_at_quantile(0.5)),
            us(h.value_at_quantile(0.99)),
            us(h.value_at_quantile(0.999)),
            us(h.max()),
            r.per_sec,
            grpc_p99 / h.value_at_quantile(0.99) as f64,
        );
    }
    let spin = &rows[0].hist;
    println!(
        "\ngoals: spin p50 < 1 us: {} ({:.2} us); spin p99.9 < 10 us: {} ({:.2} us); >= 50x faster than gRPC at p99: {} ({:.0}x)",
        yes(spin.value_at_quantile(0.5) < 1000),
        us(spin.value_at_quantile(0.5)),
        yes(spin.value_at_quantile(0.999) < 10_000),
        us(spin.value_at_quantile(0.999)),
        yes(grpc_p99 / spin.value_at_quantile(0.99) as f64 >= 50.0),
        grpc_p99 / spin.value_at_quantile(0.99) as f64
    );
}

fn yes(ok: bool) -> &'static str {
    if ok {
        "met"
    } else {
        "NOT met"
    }
}
