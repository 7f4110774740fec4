//! Control-plane latencies and throughputs, printed as percentiles (no pass/fail):
//! gRPC GetStatus and ActivateModel round trips, HTTP /api/status, WebSocket frame intervals at
//! 60 fps, frame encoding and decimation costs. Over the simulated backend at 10 kHz.
//!
//! cargo bench -p control-plane --bench control_plane
use std::time::{Duration, Instant};

use control_plane::pb;
use control_plane::telemetry::{encode_frame, Bucket, Decimator, N_SERIES};
use control_plane::{Config, Shutdown};
use control_plane_sim::SimBackend;
use futures_util::StreamExt;

fn report(what: &str, mut samples: Vec<Duration>) {
    samples.sort();
    let q = |p: f64| samples[((samples.len() - 1) as f64 * p).round() as usize].as_secs_f64() * 1e6;
    println!(
        "{what:<44} n={:<6} p50 {:>9.1} us  p99 {:>9.1} us  p99.9 {:>9.1} us  max {:>9.1} us",
        samples.len(),
        q(0.5),
        q(0.99),
        q(0.999),
        q(1.0)
    );
}

fn main() {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(servers());
    offline();
}

async fn servers() {
    let config = Config {
        grpc_addr: "127.0.0.1:0".parse().unwrap(),
        http_addr: "127.0.0.1:0".parse().unwrap(),
        ..Config::default()
    };
    let shutdown = Shutdown::new();
    let bound = control_plane::bind(
        config,
        SimBackend::with_two_models(10_000.0),
        shutdown.clone(),
    )
    .await
    .unwrap();
    let (grpc, http) = (bound.grpc_addr(), bound.http_addr());
    let server = tokio::spawn(bound.run());

    let url = format!("http://{grpc}");
    let mut looper = pb::loop_service_client::LoopServiceClient::connect(url.clone())
        .await
        .unwrap();
    let mut models = pb::model_service_client::ModelServiceClient::connect(url)
        .await
        .unwrap();
    let mut t = Vec::new();
    for i in 0..3000 {
        let t0 = Instant::now();
        looper.get_status(pb::GetStatusRequest {}).await.unwrap();
        if i >= 100 {
            t.push(t0.elapsed());
        }
    }
    report("gRPC GetStatus round trip", t);

    for name in ["a.onnx", "b.onnx"] {
        models
            .load_model(pb::LoadModelRequest {
                name: name.into(),
                onnx: vec![],
            })
            .await
            .unwrap();
    }
    let mut t = Vec::new();
    for i in 0..1000 {
        let name = if i % 2 == 0 { "a.onnx" } else { "b.onnx" };
        let t0 = Instant::now();
        models
            .activate_model(pb::ActivateModelRequest {
                name: name.into(),
                load_if_needed: false,
            })
            .await
            .unwrap();
        t.push(t0.elapsed());
    }
    report("gRPC ActivateModel round trip (sim swap)", t);

    // HTTP/1.1 keep-alive GET /api/status.
    {
        use http_body_util::{BodyExt, Empty};
        let stream = tokio::net::TcpStream::connect(http).await.unwrap();
        let (mut sender, conn) =
            hyper::client::conn::http1::handshake(hyper_util::rt::TokioIo::new(stream))
                .await
                .unwrap();
        tokio::spawn(conn);
        let mut t = Vec::new();
        for i in 0..3000 {
            let req = hyper::Request::get("/api/status")
                .header("host", http.to_string())
                .body(Empty::<hyper::body::Bytes>::new())
                .unwrap();
            let t0 = Instant::now();
            let resp = sender.send_request(req).await.unwrap();
            resp.into_body().collect().await.unwrap();
            if i >= 100 {
                t.push(t0.elapsed());
            }
        }
        report("HTTP GET /api/status round trip", t);
    }

    // WebSocket frames at 60 fps: intervals between binary frames, and their size.
    {
        let (mut ws, _) =
            tokio_tungstenite::connect_async(format!("ws://{http}/ws/telemetry?fps=60"))
                .await
                .unwrap();
        let mut last = None;
        let mut t = Vec::new();
        let mut bytes = 0usize;
        let end = Instant::now() + Duration::from_secs(4);
        while Instant::now() < end {
            let Some(Ok(msg)) = ws.next().await else {
                break;
            };
            if let tokio_tungstenite::tungstenite::Message::Binary(b) = msg {
                let now = Instant::now();
                if let Some(l) = last {
                    t.push(now - l);
                }
                last = Some(now);
                bytes += b.len();
            }
        }
        let n = t.len().max(1);
        report("WebSocket frame interval at fps=60", t);
        println!(
            "{:<44} {:.1} frames/s, {:.0} bytes/frame",
            "",
            n as f64 / 4.0,
            bytes as f64 / n as f64
        );
    }
    shutdown.trigger();
    server.await.unwrap().unwrap();
}

fn offline() {
    let buckets: Vec<Bucket> = (0..400u64)
        .map(|i| Bucket::step(i, i as f64 * 1e-4, [i as f64; N_SERIES], false))
        .collect();
    let mut out = Vec::new();
    let mut t = Vec::new();
    for _ in 0..20_000 {
        let t0 = Instant::now();
        encode_frame(&buckets, &mut out);
        t.push(t0.elapsed());
    }
    report("encode_frame, 400 buckets", t);

    let steps: Vec<Bucket> = (0..1_000_000u64)
        .map(|i| Bucket::step(i, i as f64 * 1e-4, [(i % 97) as f64; N_SERIES], i % 3 == 0))
        .collect();
    let mut d = Decimator::new(10);
    let mut merged = Vec::with_capacity(100_000);
    let t0 = Instant::now();
    for b in &steps {
        d.push(b, &mut merged);
    }
    let el = t0.elapsed();
    println!(
        "{:<44} {:.1} ns/step ({} buckets)",
        "Decimator (1e6 single steps -> 10-step buckets)",
        el.as_secs_f64() * 1e9 / steps.len() as f64,
        merged.len()
    );
}
