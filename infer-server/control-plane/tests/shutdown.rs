//! Shutdown is prompt even with open telemetry streams and WebSockets.
mod common;

use std::time::Duration;

use common::*;
use control_plane::pb;
use control_plane::pb::loop_service_client::LoopServiceClient;
use control_plane::{Config, Shutdown};
use control_plane_sim::SimBackend;
use futures_util::StreamExt;
use tokio_tungstenite::tungstenite::Message;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn open_streams_end_cleanly_and_the_server_stops_promptly() {
    // A long grace: if the streams did not end by themselves, stopping would take 60 s.
    let config = Config {
        shutdown_grace: Duration::from_secs(60),
        ..test_config()
    };
    let s = start_with(config, SimBackend::with_two_models(RATE_HZ)).await;
    let mut looper = LoopServiceClient::connect(s.grpc_url()).await.unwrap();
    let mut streams = Vec::new();
    for _ in 0..3 {
        let mut st = looper
            .stream_telemetry(pb::StreamTelemetryRequest { decimation: 10 })
            .await
            .unwrap()
            .into_inner();
        st.message().await.unwrap().expect("streaming");
        streams.push(st);
    }
    let (mut ws, _) = tokio_tungstenite::connect_async(format!("ws://{}/ws/telemetry", s.http))
        .await
        .unwrap();
    assert!(matches!(ws.next().await, Some(Ok(_))));

    let took = s.stop().await;
    assert!(took < Duration::from_secs(10), "stopping took {took:?}");
    for mut st in streams {
        // Whatever was buffered, then a clean end (status OK), not an error.
        loop {
            match tokio::time::timeout(Duration::from_secs(5), st.message())
                .await
                .unwrap()
            {
                Ok(Some(_)) => continue,
                Ok(None) => break,
                Err(e) => panic!("stream ended with {e:?}"),
            }
        }
    }
    let mut closed = false;
    while let Ok(Some(msg)) = tokio::time::timeout(Duration::from_secs(5), ws.next()).await {
        if matches!(msg, Ok(Message::Close(_)) | Err(_)) {
            closed = true;
            break;
        }
    }
    assert!(closed, "the WebSocket was closed");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stream_we_do_not_control_is_cut_after_the_grace_period() {
    use tonic_health::pb::{health_client::HealthClient, HealthCheckRequest};
    let config = Config {
        shutdown_grace: Duration::from_millis(300),
        ..test_config()
    };
    let s = start_with(config, SimBackend::with_two_models(RATE_HZ)).await;
    let channel = tonic::transport::Endpoint::from_shared(s.grpc_url())
        .unwrap()
        .connect()
        .await
        .unwrap();
    let mut health = HealthClient::new(channel);
    let mut watch = health
        .watch(HealthCheckRequest {
            service: String::new(),
        })
        .await
        .unwrap()
        .into_inner();
    watch.message().await.unwrap().unwrap();
    let took = s.stop().await;
    assert!(took < Duration::from_secs(10), "stopping took {took:?}");
}

#[test]
fn blocking_serve_returns_after_trigger() {
    let free = |_| {
        std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
    };
    let config = Config {
        grpc_addr: free(0),
        http_addr: free(1),
        ..Config::default()
    };
    let shutdown = Shutdown::new();
    let backend = SimBackend::with_two_models(RATE_HZ);
    let (addr, trigger) = (config.http_addr, shutdown.clone());
    let server = std::thread::spawn(move || control_plane::serve(config, backend, shutdown));
    // Wait until it answers, then stop it from this thread.
    let t0 = std::time::Instant::now();
    while std::net::TcpStream::connect(addr).is_err() {
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "server never listened"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    trigger.trigger();
    let t1 = std::time::Instant::now();
    server.join().unwrap().unwrap();
    assert!(t1.elapsed() < Duration::from_secs(10));
}

#[test]
fn public_address_without_token_is_refused() {
    let config = Config {
        grpc_addr: "0.0.0.0:0".parse().unwrap(),
        ..test_config()
    };
    let err = control_plane::serve(
        config,
        SimBackend::with_two_models(RATE_HZ),
        Shutdown::new(),
    )
    .unwrap_err();
    assert!(err.to_string().contains("without a token"), "{err}");
}
