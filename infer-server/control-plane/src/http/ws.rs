//! `/ws/telemetry?fps=30`: binary frames of min/max buckets at the given rate, and the status
//! object as a text frame about twice a second (docs/web-protocol.md). The page asks for the rate
//! it draws at, and changes it on the open socket with a text frame `{"fps": N}` (fewer while its
//! tab is hidden), so the server never encodes and sends frames nobody draws.
use std::time::Duration;

use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{Query, State};
use axum::http::HeaderMap;
use axum::response::{IntoResponse, Response};
use serde::Deserialize;
use tokio::sync::broadcast::error::TryRecvError;
use tokio::time::MissedTickBehavior;

use super::json::StatusJson;
use crate::core::Core;
use crate::stats::{GaugeGuard, Stats};
use crate::telemetry::{encode_frame, Bucket, Decimator};

pub const DEFAULT_FPS: u32 = 30;
pub const MAX_FPS: u32 = 60;
const STATUS_PERIOD: Duration = Duration::from_millis(500);

#[derive(Debug, Deserialize)]
pub struct WsQuery {
    fps: Option<u32>,
}

pub async fn telemetry(
    State(core): State<Core>,
    Query(q): Query<WsQuery>,
    headers: HeaderMap,
    ws: WebSocketUpgrade,
) -> Response {
    // A page of another site must not read the telemetry either: the host (DNS rebinding),
    // then the origin, then the token when one is set (a browser cannot set `Authorization` on
    // a WebSocket: the page offers it as a subprotocol, see `Auth::check_ws`).
    let host = headers
        .get(axum::http::header::HOST)
        .and_then(|v| v.to_str().ok());
    if let Err(e) = core
        .hosts
        .check(host)
        .and_then(|()| super::api::check_origin(&headers))
        .and_then(|()| core.auth.check_ws(&headers))
    {
        return e.into_response();
    }
    let ws = ws.protocols([crate::auth::WS_PROTOCOL]);
    let fps = q.fps.unwrap_or(DEFAULT_FPS).clamp(1, MAX_FPS);
    ws.on_upgrade(move |socket| run(core, socket, fps))
}

async fn run(core: Core, mut socket: WebSocket, fps: u32) {
    let stats = &core.stats;
    let _open = GaugeGuard::new(&stats.ws_clients);
    let mut telemetry = core.backend.subscribe_telemetry();
    let mut frame_tick = tokio::time::interval(frame_period(fps));
    frame_tick.set_missed_tick_behavior(MissedTickBehavior::Skip);
    let mut status_tick = tokio::time::interval(STATUS_PERIOD);
    status_tick.set_missed_tick_behavior(MissedTickBehavior::Skip);
    let mut pending: Vec<Bucket> = Vec::new();
    let mut buckets: Vec<Bucket> = Vec::new();
    let mut bytes: Vec<u8> = Vec::new();
    let mut decimator = Decimator::new(core.config.ws_bucket_steps);
    loop {
        let message = tokio::select! {
            _ = core.shutdown.wait() => {
                let _ = socket.send(Message::Close(None)).await;
                return;
            }
            incoming = socket.recv() => match incoming {
                // A close or an error ends the session.
                Some(Ok(Message::Close(_))) | None | Some(Err(_)) => return,
                // The page's frame rate changed (its tab was hidden or shown): send at the new
                // rate. Anything else from the page is ignored.
                Some(Ok(Message::Text(text))) => {
                    if let Some(new_fps) = requested_fps(&text) {
                        frame_tick = tokio::time::interval(frame_period(new_fps));
                        frame_tick.set_missed_tick_behavior(MissedTickBehavior::Skip);
                    }
                    continue;
                }
                Some(Ok(_)) => continue,
            },
            _ = status_tick.tick() => match core.status().await {
                Ok(s) => {
                    let json = StatusJson::new(
                        &s,
                        core.auth.required(),
                        core.config.max_upload_bytes,
                        Some("status"),
                    );
                    Message::Text(serde_json::to_string(&json).unwrap_or_default().into())
                }
                Err(_) => continue,
            },
            _ = frame_tick.tick() => {
                drain(&mut telemetry, &mut pending, stats);
                if pending.is_empty() {
                    continue;
                }
                decimate(&core, &mut decimator, &pending, &mut buckets);
                pending.clear();
                encode_frame(&buckets, &mut bytes);
                Stats::add(&stats.ws_frames, 1);
                Stats::add(&stats.ws_bytes, bytes.len() as u64);
                Message::Binary(bytes.clone().into())
            }
        };
        if socket.send(message).await.is_err() {
            return;
        }
    }
}

/// The interval between binary frames at `fps` (clamped to 1..=MAX_FPS).
fn frame_period(fps: u32) -> Duration {
    Duration::from_secs_f64(1.0 / f64::from(fps.clamp(1, MAX_FPS)))
}

/// `{"fps": N}` from the page: the rate it now draws at. None for anything else.
fn requested_fps(text: &str) -> Option<u32> {
    #[derive(Deserialize)]
    struct Rate {
        fps: u32,
    }
    serde_json::from_str::<Rate>(text).ok().map(|r| r.fps)
}

/// Takes every batch published since the last frame.
fn drain(
    telemetry: &mut tokio::sync::broadcast::Receiver<crate::telemetry::TelemetryBatch>,
    pending: &mut Vec<Bucket>,
    stats: &Stats,
) {
    loop {
        match telemetry.try_recv() {
            Ok(batch) => pending.extend_from_slice(&batch),
            Err(TryRecvError::Lagged(n)) => Stats::add(&stats.lagged_batches, n),
            Err(TryRecvError::Empty) | Err(TryRecvError::Closed) => return,
        }
    }
}

/// Merges the frame's steps into buckets of at least `ws_bucket_steps` steps, longer when the
/// loop runs so fast that the frame would exceed `ws_max_buckets_per_frame`.
fn decimate(core: &Core, decimator: &mut Decimator, pending: &[Bucket], out: &mut Vec<Bucket>) {
    let steps: u64 = pending.iter().map(|b| u64::from(b.steps)).sum();
    let max_buckets = u64::from(core.config.ws_max_buckets_per_frame.max(1));
    let target = steps
        .div_ceil(max_buckets)
        .max(u64::from(core.config.ws_bucket_steps));
    decimator.set_target(u32::try_from(target).unwrap_or(u32::MAX));
    out.clear();
    for b in pending {
        decimator.push(b, out);
    }
    // Each frame carries all its steps: no bucket waits for the next frame.
    decimator.flush(out);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_page_changes_the_rate_with_a_text_frame() {
        assert_eq!(requested_fps(r#"{"fps": 2}"#), Some(2));
        assert_eq!(requested_fps(r#"{"fps": -1}"#), None);
        assert_eq!(requested_fps("hello"), None);
        assert_eq!(frame_period(0), Duration::from_secs(1));
        assert_eq!(frame_period(1000), frame_period(MAX_FPS));
        assert_eq!(frame_period(2), Duration::from_millis(500));
    }
}
