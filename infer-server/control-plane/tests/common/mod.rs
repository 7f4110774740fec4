//! Starts the control plane on free loopback ports over a `SimBackend`.
#![allow(dead_code)]
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use control_plane::{Config, Shutdown};
use control_plane_sim::SimBackend;

pub const RATE_HZ: f64 = 10_000.0;

pub struct TestServer {
    pub grpc: SocketAddr,
    pub http: SocketAddr,
    pub shutdown: Shutdown,
    pub task: tokio::task::JoinHandle<anyhow::Result<()>>,
    pub backend: Arc<SimBackend>,
}

impl TestServer {
    pub fn grpc_url(&self) -> String {
        format!("http://{}", self.grpc)
    }

    pub fn http_url(&self, path: &str) -> String {
        format!("http://{}{}", self.http, path)
    }

    /// Triggers the shutdown and waits for both servers to stop.
    pub async fn stop(self) -> Duration {
        let t0 = std::time::Instant::now();
        self.shutdown.trigger();
        tokio::time::timeout(Duration::from_secs(20), self.task)
            .await
            .expect("server stopped")
            .expect("server task")
            .expect("server result");
        t0.elapsed()
    }
}

pub fn test_config() -> Config {
    Config {
        grpc_addr: "127.0.0.1:0".parse().unwrap(),
        http_addr: "127.0.0.1:0".parse().unwrap(),
        ..Config::default()
    }
}

pub async fn start_with(config: Config, backend: Arc<SimBackend>) -> TestServer {
    let shutdown = Shutdown::new();
    let bound = control_plane::bind(config, backend.clone(), shutdown.clone())
        .await
        .expect("bind");
    let (grpc, http) = (bound.grpc_addr(), bound.http_addr());
    let task = tokio::spawn(bound.run());
    TestServer {
        grpc,
        http,
        shutdown,
        task,
        backend,
    }
}

pub async fn start() -> TestServer {
    start_with(test_config(), SimBackend::with_two_models(RATE_HZ)).await
}

/// A plain HTTP/1.1 request; returns the status, the content type and the body.
pub async fn http(
    s: &TestServer,
    method: &str,
    path: &str,
    headers: &[(&str, &str)],
    body: Vec<u8>,
) -> (u16, String, Vec<u8>) {
    use http_body_util::{BodyExt, Full};
    let stream = tokio::net::TcpStream::connect(s.http).await.unwrap();
    let (mut sender, conn) =
        hyper::client::conn::http1::handshake(hyper_util::rt::TokioIo::new(stream))
            .await
            .unwrap();
    tokio::spawn(conn);
    let mut req = hyper::Request::builder().method(method).uri(path);
    // The server's own address as Host, unless the test names another.
    if !headers.iter().any(|(k, _)| k.eq_ignore_ascii_case("host")) {
        req = req.header("host", s.http.to_string());
    }
    for (k, v) in headers {
        req = req.header(*k, *v);
    }
    let resp = sender
        .send_request(req.body(Full::new(hyper::body::Bytes::from(body))).unwrap())
        .await
        .unwrap();
    let status = resp.status().as_u16();
    let ctype = resp
        .headers()
        .get("content-type")
        .map(|v| v.to_str().unwrap().to_string())
        .unwrap_or_default();
    let body = resp
        .into_body()
        .collect()
        .await
        .unwrap()
        .to_bytes()
        .to_vec();
    (status, ctype, body)
}

pub async fn http_json(
    s: &TestServer,
    method: &str,
    path: &str,
    headers: &[(&str, &str)],
    body: Vec<u8>,
) -> (u16, serde_json::Value) {
    let (status, ctype, body) = http(s, method, path, headers, body).await;
    assert!(ctype.starts_with("application/json"), "{path}: {ctype}");
    (status, serde_json::from_slice(&body).unwrap())
}
