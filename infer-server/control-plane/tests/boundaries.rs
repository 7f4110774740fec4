//! Who may use the HTTP side (docs/control-plane.md, "Safety"): the `Host` allowlist against
//! DNS rebinding (checked before `Origin`, on every route and on the WebSocket upgrade), the
//! token on the WebSocket, and the cap on uploads held in memory.
mod common;

use std::time::Duration;

use common::*;
use control_plane::pb;
use control_plane::pb::model_service_client::ModelServiceClient;
use control_plane::Config;
use control_plane_sim::SimBackend;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::http::HeaderValue;

/// A WebSocket upgrade with the given headers; Ok(selected subprotocol) or Err(HTTP status).
async fn ws_upgrade(s: &TestServer, headers: &[(&str, &str)]) -> Result<Option<String>, u16> {
    let mut req = format!("ws://{}/ws/telemetry?fps=5", s.http)
        .into_client_request()
        .unwrap();
    for (k, v) in headers {
        let name: tokio_tungstenite::tungstenite::http::HeaderName = k.parse().unwrap();
        req.headers_mut()
            .insert(name, HeaderValue::from_str(v).unwrap());
    }
    match tokio_tungstenite::connect_async(req).await {
        Ok((_ws, resp)) => Ok(resp
            .headers()
            .get("sec-websocket-protocol")
            .map(|v| v.to_str().unwrap().to_string())),
        Err(tokio_tungstenite::tungstenite::Error::Http(resp)) => Err(resp.status().as_u16()),
        Err(e) => panic!("websocket: {e}"),
    }
}

/// `POST /api/experiment/start` (ramp cycles) with the given headers.
async fn start_ramps(s: &TestServer, headers: &[(&str, &str)]) -> (u16, serde_json::Value) {
    let body = br#"{"kind":"abstraction"}"#.to_vec();
    http_json(s, "POST", "/api/experiment/start", headers, body).await
}

fn hex(s: &str) -> String {
    s.bytes().map(|b| format!("{b:02x}")).collect()
}

/// The attack of issue 13: a page on evil.test, re-bound to 127.0.0.1, sends a same-origin
/// request. Before the Host allowlist this answered 200 and started the experiment.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn dns_rebinding_is_refused_on_every_route() {
    let s = start().await;
    let port = s.http.port();
    let evil_host = format!("evil.test:{port}");
    let evil_origin = format!("http://evil.test:{port}");
    let rebound = [
        ("host", evil_host.as_str()),
        ("origin", evil_origin.as_str()),
    ];
    let (code, e) = start_ramps(&s, &rebound).await;
    assert_eq!(code, 403, "{e}");
    assert!(e["error"].as_str().unwrap().contains("evil.test"), "{e}");
    for path in [
        "/api/models/a.onnx/load",
        "/api/models/a.onnx/activate",
        "/api/models/a.onnx/unload",
        "/api/experiment/stop",
    ] {
        let (code, e) = http_json(&s, "POST", path, &rebound, vec![]).await;
        assert_eq!(code, 403, "{path}: {e}");
    }
    // Reads and the page itself: refused too (a rebound page gets nothing to read).
    for path in ["/", "/index.html", "/api/status", "/api/models", "/metrics"] {
        let (code, _, _) = http(&s, "GET", path, &rebound, vec![]).await;
        assert_eq!(code, 403, "{path}");
    }
    // Without an Origin (a script that is not a browser, or a browser's plain navigation).
    let (code, _) = http_json(
        &s,
        "POST",
        "/api/experiment/stop",
        &[("host", &evil_host)],
        vec![],
    )
    .await;
    assert_eq!(code, 403);
    assert_eq!(
        ws_upgrade(&s, &[("host", &evil_host), ("origin", &evil_origin)]).await,
        Err(403)
    );
    assert!(s.backend.last_experiment().is_none() && s.backend.swaps().is_empty());

    // The same page under the server's own names works.
    for name in [format!("127.0.0.1:{port}"), format!("localhost:{port}")] {
        let origin = format!("http://{name}");
        let h = [("host", name.as_str()), ("origin", origin.as_str())];
        let (code, e) = start_ramps(&s, &h).await;
        assert_eq!(code, 200, "{name}: {e}");
        let (code, e) = http_json(&s, "POST", "/api/experiment/stop", &h, vec![]).await;
        assert_eq!(code, 200, "{name}: {e}");
        assert!(ws_upgrade(&s, &h).await.is_ok(), "{name}");
    }
    assert!(s.backend.last_experiment().is_some());
    s.stop().await;
}

/// The host is checked first: a valid token does not let a request to a foreign name through,
/// and a known host still needs a same-site Origin.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn host_before_origin_before_token() {
    let config = Config {
        token: Some("tok".into()),
        allowed_hosts: vec!["lab-pc".into()],
        ..test_config()
    };
    let s = start_with(config, SimBackend::with_two_models(RATE_HZ)).await;
    let port = s.http.port();
    let auth = ("authorization", "Bearer tok");
    let (code, e) = http_json(
        &s,
        "POST",
        "/api/models/a.onnx/activate",
        &[auth, ("host", &format!("evil.test:{port}"))],
        vec![],
    )
    .await;
    assert_eq!(code, 403, "{e}");
    let (code, e) = http_json(
        &s,
        "POST",
        "/api/models/a.onnx/activate",
        &[auth, ("origin", "http://evil.test")],
        vec![],
    )
    .await;
    assert_eq!(code, 403, "{e}");
    assert!(s.backend.swaps().is_empty());
    // A configured name passes, with its own origin and the token.
    let lab = format!("lab-pc:{port}");
    let lab_origin = format!("http://{lab}");
    let (code, e) = http_json(
        &s,
        "POST",
        "/api/models/a.onnx/activate",
        &[auth, ("host", &lab), ("origin", &lab_origin)],
        vec![],
    )
    .await;
    assert_eq!(code, 200, "{e}");
    s.stop().await;
}

/// With a token, the telemetry socket needs it too: by header, or as the page sends it, as a
/// subprotocol; the server then selects `haptics.v1`.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_websocket_needs_the_token_when_one_is_set() {
    let config = Config {
        token: Some("s3cret".into()),
        ..test_config()
    };
    let s = start_with(config, SimBackend::with_two_models(RATE_HZ)).await;
    assert_eq!(ws_upgrade(&s, &[]).await, Err(401));
    assert_eq!(
        ws_upgrade(&s, &[("authorization", "Bearer wrong")]).await,
        Err(401)
    );
    let wrong = format!("haptics.v1, haptics-token.{}", hex("wrong"));
    assert_eq!(
        ws_upgrade(&s, &[("sec-websocket-protocol", &wrong)]).await,
        Err(401)
    );
    assert_eq!(
        ws_upgrade(&s, &[("authorization", "Bearer s3cret")]).await,
        Ok(None)
    );
    let right = format!("haptics.v1, haptics-token.{}", hex("s3cret"));
    assert_eq!(
        ws_upgrade(&s, &[("sec-websocket-protocol", &right)]).await,
        Ok(Some("haptics.v1".into()))
    );
    s.stop().await;

    // Without a token the socket stays open to every known host.
    let s = start().await;
    assert_eq!(ws_upgrade(&s, &[]).await, Ok(None));
    s.stop().await;
}

/// Starts an HTTP upload that declares `len` bytes and sends only a few: the server holds its
/// reservation while it waits for the rest.
async fn stalled_upload(s: &TestServer, name: &str, len: usize) -> tokio::net::TcpStream {
    let mut tcp = tokio::net::TcpStream::connect(s.http).await.unwrap();
    let head = format!(
        "POST /api/models/{name}/load HTTP/1.1\r\nhost: {}\r\ncontent-length: {len}\r\n\r\nxx",
        s.http
    );
    tcp.write_all(head.as_bytes()).await.unwrap();
    tcp
}

/// Uploads being received are capped in total, over HTTP and gRPC together: one more is refused
/// at once (413 / RESOURCE_EXHAUSTED) without its body being read, and accepted again once the
/// others are gone.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn uploads_in_flight_are_capped_in_total() {
    let config = Config {
        max_upload_bytes: 1000,
        max_uploads_in_flight_bytes: 2000,
        ..test_config()
    };
    let s = start_with(config, SimBackend::with_two_models(RATE_HZ)).await;
    // The two stalled uploads must hold their reservations before the probe arrives: a probe
    // that the server reads first reserves its own 500 bytes, and then the second stalled upload
    // is the one refused (which is the cap working, but not this test's scenario). So each try
    // gives the server longer to read both heads, and starts over if the probe got in first.
    let mut refused = (0, serde_json::Value::Null);
    let mut stalled = None;
    for attempt in 1..=10u64 {
        let a = stalled_upload(&s, "x.onnx", 1000).await;
        let b = stalled_upload(&s, "y.onnx", 1000).await;
        tokio::time::sleep(Duration::from_millis(50 * attempt)).await;
        refused = http_json(&s, "POST", "/api/models/z.onnx/load", &[], vec![b' '; 500]).await;
        if refused.0 == 413 {
            stalled = Some((a, b));
            break;
        }
        drop((a, b));
        tokio::time::sleep(Duration::from_millis(100)).await; // their reservations come back
    }
    assert_eq!(refused.0, 413, "{}", refused.1);
    assert!(
        refused.1["error"]
            .as_str()
            .unwrap()
            .contains("too many model uploads at once"),
        "{}",
        refused.1
    );
    let mut models = ModelServiceClient::connect(s.grpc_url()).await.unwrap();
    let err = models
        .load_model(pb::LoadModelRequest {
            name: "g.onnx".into(),
            onnx: vec![b' '; 10],
        })
        .await
        .unwrap_err();
    assert_eq!(err.code(), tonic::Code::ResourceExhausted, "{err}");
    assert!(err.message().contains("too many model uploads"), "{err}");

    // The stalled uploads give up: their reservations come back.
    let (a, mut b) = stalled.expect("a refused probe means both uploads are held");
    drop(a);
    b.shutdown().await.unwrap();
    let mut rest = Vec::new();
    let _ = tokio::time::timeout(Duration::from_secs(5), b.read_to_end(&mut rest)).await;
    drop(b);
    let t0 = std::time::Instant::now();
    loop {
        let (code, e) =
            http_json(&s, "POST", "/api/models/z.onnx/load", &[], vec![b' '; 500]).await;
        if code != 413 {
            // The simulated backend refuses the bytes as a model: that is past the cap.
            assert_eq!(code, 400, "{e}");
            break;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(5),
            "reservations not given back: {e}"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    s.stop().await;
}
