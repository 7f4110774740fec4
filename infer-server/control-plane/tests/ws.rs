//! The telemetry WebSocket: binary frames per docs/web-protocol.md, status text frames, and a
//! loop that goes away and comes back.
mod common;

use std::time::{Duration, Instant};

use common::*;
use control_plane::telemetry::{decode_frame, series};
use control_plane_sim::{SPIKE_EVERY, SPIKE_N};
use futures_util::StreamExt;
use tokio_tungstenite::tungstenite::Message;

type Ws =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

async fn connect(s: &TestServer, fps: u32) -> Ws {
    let url = format!("ws://{}/ws/telemetry?fps={fps}", s.http);
    tokio_tungstenite::connect_async(url).await.unwrap().0
}

/// t, (min, max) of F_res, (min, max) of F_pred.
type BucketSeen = (f64, (f32, f32), (f32, f32));

#[derive(Default)]
struct Collected {
    /// (t, min/max of F_res) of every bucket, in order.
    buckets: Vec<BucketSeen>,
    frames: usize,
    statuses: Vec<serde_json::Value>,
}

async fn collect(ws: &mut Ws, for_how_long: Duration, into: &mut Collected) {
    let end = Instant::now() + for_how_long;
    while let Ok(Some(msg)) = tokio::time::timeout_at(end.into(), ws.next()).await {
        match msg.unwrap() {
            Message::Binary(bytes) => {
                let f = decode_frame(&bytes).unwrap();
                assert_eq!(f.n_series, control_plane::telemetry::N_SERIES);
                assert!(!f.t.is_empty(), "no empty frames");
                into.frames += 1;
                for (t, mm) in f.t.iter().zip(&f.min_max) {
                    into.buckets
                        .push((*t, mm[series::RTOB_FORCE], mm[series::F_PRED]));
                }
            }
            Message::Text(text) => into.statuses.push(serde_json::from_str(&text).unwrap()),
            other => panic!("unexpected {other:?}"),
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frames_decode_keep_spikes_and_come_at_the_asked_rate() {
    let s = start().await;
    let mut ws = connect(&s, 50).await;
    let mut c = Collected::default();
    let window = Duration::from_millis(1500);
    collect(&mut ws, window, &mut c).await;

    // 50 frames per second asked; a loaded test machine may deliver fewer, never more.
    assert!(
        c.frames >= 20 && c.frames <= 80,
        "{} frames in {window:?}",
        c.frames
    );
    assert!(
        c.statuses.len() >= 2 && c.statuses.len() <= 5,
        "{} status frames",
        c.statuses.len()
    );
    // The first status frame can go out within a millisecond of the server's start, before the
    // simulated loop has run a step; the steps must grow from frame to frame and be under way by
    // the last one.
    let mut last_steps = 0;
    for st in &c.statuses {
        assert_eq!(st["type"], "status");
        assert_eq!(st["loop"]["alive"], true);
        let steps = st["loop"]["steps"].as_u64().unwrap();
        assert!(steps >= last_steps, "steps went back: {st}");
        last_steps = steps;
    }
    assert!(last_steps > 0, "the loop's steps never moved");

    // Buckets are contiguous in time, each at least 10 steps (1 ms at 10 kHz), and a bucket
    // holds a spike exactly when one of its steps is a spike step.
    let step_of = |t: f64| (t * RATE_HZ).round() as u64;
    let mut spikes = 0;
    for w in c.buckets.windows(2) {
        let (from, to) = (step_of(w[0].0), step_of(w[1].0));
        assert!(to > from, "time moves forward");
        let has_spike = (from..to).any(|i| i % SPIKE_EVERY == 0);
        let (lo, hi) = w[0].1;
        assert!(lo <= hi);
        if has_spike {
            spikes += 1;
            assert!(
                f64::from(hi) > SPIKE_N / 2.0,
                "spike in [{from}, {to}) hidden: max {hi}"
            );
        } else {
            assert!(f64::from(hi) < SPIKE_N / 2.0, "[{from}, {to}) max {hi}");
        }
        assert!(w[0].2 .0.is_nan(), "F_pred is NaN without a model");
    }
    assert!(spikes >= 10, "{spikes} spikes seen");
    let lengths: Vec<u64> = c
        .buckets
        .windows(2)
        .map(|w| step_of(w[1].0) - step_of(w[0].0))
        .collect();
    let full = lengths.iter().filter(|&&n| n >= 10).count();
    assert!(
        full * 10 >= lengths.len() * 8,
        "most buckets are >= 10 steps: {lengths:?}"
    );
    assert!(
        lengths.iter().all(|&n| n <= 400),
        "buckets stay short at 10 kHz"
    );
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn loop_gone_and_back_without_reconnecting() {
    let s = start().await;
    let mut ws = connect(&s, 30).await;
    let mut before = Collected::default();
    collect(&mut ws, Duration::from_millis(400), &mut before).await;
    assert!(before.frames > 0);
    let last_t = before.buckets.last().unwrap().0;

    s.backend.set_loop_alive(false);
    // Drain what was in flight, then the socket stays open with status frames only.
    collect(
        &mut ws,
        Duration::from_millis(150),
        &mut Collected::default(),
    )
    .await;
    let mut gone = Collected::default();
    collect(&mut ws, Duration::from_millis(1100), &mut gone).await;
    assert_eq!(gone.frames, 0, "no data while the loop is gone");
    assert!(!gone.statuses.is_empty());
    assert!(gone.statuses.iter().all(|st| st["loop"]["alive"] == false));

    s.backend.set_loop_alive(true);
    let mut back = Collected::default();
    collect(&mut ws, Duration::from_millis(600), &mut back).await;
    assert!(back.frames > 0, "data resumes");
    assert!(
        back.buckets[0].0 < last_t,
        "a new run starts again at t = 0"
    );
    assert!(back.statuses.iter().any(|st| st["loop"]["alive"] == true));
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_page_of_another_site_cannot_open_the_socket() {
    use tokio_tungstenite::tungstenite::client::IntoClientRequest;
    let s = start().await;
    let url = format!("ws://{}/ws/telemetry", s.http);
    let mut req = url.as_str().into_client_request().unwrap();
    req.headers_mut()
        .insert("origin", "https://evil.example".parse().unwrap());
    match tokio_tungstenite::connect_async(req).await {
        Err(tokio_tungstenite::tungstenite::Error::Http(resp)) => assert_eq!(resp.status(), 403),
        other => panic!("expected 403, got {other:?}"),
    }
    let mut req = url.as_str().into_client_request().unwrap();
    req.headers_mut()
        .insert("origin", format!("http://{}", s.http).parse().unwrap());
    tokio_tungstenite::connect_async(req)
        .await
        .expect("same origin is fine");
    s.stop().await;
}
