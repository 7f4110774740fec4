//! `/api/*`: the same operations as the gRPC services, as JSON. Errors are `{ "error": text }`
//! with the HTTP status of `ControlError::http_status`.
use axum::body::{to_bytes, Body};
use axum::extract::{Path, Query, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::Deserialize;
use serde_json::json;

use super::json::{ModelJson, StatusJson};
use crate::backend::ExperimentRequest;
use crate::core::Core;
use crate::error::ControlError;

impl IntoResponse for ControlError {
    fn into_response(self) -> Response {
        (
            self.http_status(),
            Json(json!({ "error": self.to_string() })),
        )
            .into_response()
    }
}

type ApiResult = Result<Response, ControlError>;

/// Host, origin and token checks of a mutating call, in that order. The router's middleware
/// checks the host of every request already; checking it here again means a mutating route
/// never depends on that layer alone.
fn authorize(core: &Core, headers: &HeaderMap) -> Result<(), ControlError> {
    core.hosts
        .check(headers.get(header::HOST).and_then(|v| v.to_str().ok()))?;
    check_origin(headers)?;
    let auth = headers
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok());
    core.auth.check(auth)
}

/// The token check of a read that shows live data or provenance (`/api/status`, `/api/models`,
/// `/metrics`): the router's middleware has checked the host already, and a read changes
/// nothing, so no `Origin` check (another site's page cannot read the answer anyway).
pub fn authorize_read(core: &Core, headers: &HeaderMap) -> Result<(), ControlError> {
    let auth = headers
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok());
    core.auth.check(auth)
}

/// Refuses a mutating request that a browser sent from another site (a page elsewhere posting to
/// 127.0.0.1:8080 without a token). Same-origin requests and loopback origins (a dev server on
/// another port) pass; clients that are not browsers send no Origin. "Same origin" is only
/// meaningful once `Host` is known to name this server (a DNS-rebound page sends an Origin equal
/// to its Host): callers check the host first.
pub fn check_origin(headers: &HeaderMap) -> Result<(), ControlError> {
    let Some(origin) = headers.get(header::ORIGIN) else {
        return Ok(());
    };
    // Present but not visible ASCII: refused, never read as "no Origin" (which passes).
    let Some(origin) = origin
        .to_str()
        .ok()
        .filter(|o| !o.is_empty() && o.bytes().all(|b| b.is_ascii_graphic()))
    else {
        return Err(ControlError::Forbidden(
            "the Origin header is not a visible-ASCII origin: refused".into(),
        ));
    };
    let host = headers
        .get(header::HOST)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("");
    // `scheme://host[:port]` and nothing else (no path, no user info); `null` (a sandboxed or
    // opaque origin) and malformed values are cross-site.
    let origin_host = origin
        .strip_prefix("http://")
        .or_else(|| origin.strip_prefix("https://"))
        .filter(|rest| !rest.is_empty() && !rest.contains(['/', '@', '?', '#']));
    let Some(origin_host) = origin_host else {
        return Err(ControlError::Forbidden(format!(
            "cross-origin request from {origin} refused"
        )));
    };
    let origin_name = origin_host
        .rsplit_once(':')
        .filter(|(_, port)| !port.is_empty() && port.bytes().all(|b| b.is_ascii_digit()))
        .map(|(h, _)| h)
        .unwrap_or(origin_host);
    let loopback = matches!(origin_name, "localhost" | "127.0.0.1" | "[::1]");
    if origin_host == host || loopback {
        Ok(())
    } else {
        Err(ControlError::Forbidden(format!(
            "cross-origin request from {origin} refused"
        )))
    }
}

#[cfg(test)]
mod origin_tests {
    use super::*;

    fn headers(origin: &[u8]) -> HeaderMap {
        let mut h = HeaderMap::new();
        h.insert(header::HOST, "127.0.0.1:8080".parse().unwrap());
        h.insert(
            header::ORIGIN,
            axum::http::HeaderValue::from_bytes(origin).unwrap(),
        );
        h
    }

    #[test]
    fn origin_is_parsed_strictly() {
        assert!(check_origin(&HeaderMap::new()).is_ok());
        for ok in [
            &b"http://127.0.0.1:8080"[..],
            b"http://localhost:5173",
            b"http://[::1]:8080",
        ] {
            assert!(check_origin(&headers(ok)).is_ok(), "{ok:?}");
        }
        for bad in [
            &b"http://evil.test:8080"[..],
            b"http://127.0.0.1:8080\xff",
            b"http://localhost\xe9:8080",
            b"null",
            b"127.0.0.1:8080",
            b"http://127.0.0.1:8080/path",
            b"http://evil@127.0.0.1:8080",
            b"ftp://127.0.0.1:8080",
        ] {
            assert!(
                matches!(check_origin(&headers(bad)), Err(ControlError::Forbidden(_))),
                "{:?}",
                String::from_utf8_lossy(bad)
            );
        }
    }
}

pub async fn status(State(core): State<Core>, headers: HeaderMap) -> ApiResult {
    authorize_read(&core, &headers)?;
    let s = core.status().await?;
    Ok(Json(StatusJson::new(
        &s,
        core.auth.required(),
        core.config.max_upload_bytes,
        None,
    ))
    .into_response())
}

pub async fn list_models(State(core): State<Core>, headers: HeaderMap) -> ApiResult {
    authorize_read(&core, &headers)?;
    let models = core.list_models().await?;
    let models: Vec<ModelJson> = models.iter().map(ModelJson::from).collect();
    Ok(Json(models).into_response())
}

pub async fn active_model(State(core): State<Core>, headers: HeaderMap) -> ApiResult {
    authorize_read(&core, &headers)?;
    match core.active_model().await? {
        Some(m) => Ok(Json(ModelJson::from(&m)).into_response()),
        None => Ok(Json(serde_json::Value::Null).into_response()),
    }
}

/// Loads `name` from the model directory, or, with a non-empty body, the uploaded bytes as
/// `name`.
pub async fn load_model(
    State(core): State<Core>,
    Path(name): Path<String>,
    headers: HeaderMap,
    body: Body,
) -> ApiResult {
    authorize(&core, &headers)?;
    let limit = core.config.max_upload_bytes;
    let declared = headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<usize>().ok());
    if let Some(n) = declared {
        // Declared over the limit: refused before a byte of it is read.
        core.check_upload_size(n)?;
    }
    // The body is held in memory: reserve it from the cap on uploads in flight first.
    let reserve = declared.unwrap_or(limit + 1);
    let _reservation = if reserve > 0 {
        Some(core.uploads.reserve(reserve)?)
    } else {
        None
    };
    let bytes = read_upload(&core, body, limit).await?;
    let upload = (!bytes.is_empty()).then_some(bytes);
    let model = core.load_model(name, upload).await?;
    Ok(Json(ModelJson::from(&model)).into_response())
}

/// Reads an upload's body, at most `limit` bytes, giving up when the client sends nothing for
/// `Config::upload_idle_timeout` (a stalled upload would otherwise hold its share of the cap on
/// uploads in flight for as long as the connection stays open). Whatever was read is dropped
/// with the error, and the caller's reservation with it.
async fn read_upload(core: &Core, body: Body, limit: usize) -> Result<Vec<u8>, ControlError> {
    use http_body_util::BodyExt;
    let idle = core.config.upload_idle_timeout;
    let mut body = body;
    let mut bytes = Vec::new();
    loop {
        let frame = match tokio::time::timeout(idle, body.frame()).await {
            Err(_) => {
                return Err(ControlError::InvalidArgument(format!(
                    "the upload stalled: nothing received for {} s after {} bytes (the \
                     server's upload read timeout)",
                    idle.as_secs_f64(),
                    bytes.len()
                )))
            }
            Ok(None) => return Ok(bytes),
            Ok(Some(Err(e))) => {
                return Err(ControlError::InvalidArgument(format!(
                    "the upload broke off after {} bytes: {e}",
                    bytes.len()
                )))
            }
            Ok(Some(Ok(frame))) => frame,
        };
        if let Ok(data) = frame.into_data() {
            if bytes.len() + data.len() > limit {
                // Over the limit: say which limit.
                core.check_upload_size(limit + 1)?;
            }
            bytes.extend_from_slice(&data);
        }
    }
}

#[derive(Debug, Deserialize)]
pub struct ActivateQuery {
    /// Load the model first when it is only available (default true).
    load_if_needed: Option<bool>,
}

pub async fn activate_model(
    State(core): State<Core>,
    Path(name): Path<String>,
    Query(q): Query<ActivateQuery>,
    headers: HeaderMap,
) -> ApiResult {
    authorize(&core, &headers)?;
    let a = core
        .activate_model(name, q.load_if_needed.unwrap_or(true))
        .await?;
    Ok(Json(json!({
        "effective_step": a.effective_step,
        "model": ModelJson::from(&a.model),
        "warnings": a.warnings,
    }))
    .into_response())
}

pub async fn unload_model(
    State(core): State<Core>,
    Path(name): Path<String>,
    headers: HeaderMap,
) -> ApiResult {
    authorize(&core, &headers)?;
    core.unload_model(name).await?;
    Ok(Json(json!({})).into_response())
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StartBody {
    kind: String,
    ramp_rate: Option<f64>,
    cycles: Option<u32>,
    f_max_start: Option<f64>,
    f_max_step: Option<f64>,
}

pub async fn start_experiment(
    State(core): State<Core>,
    headers: HeaderMap,
    body: Body,
) -> ApiResult {
    authorize(&core, &headers)?;
    let bytes = to_bytes(body, 64 << 10)
        .await
        .map_err(|e| ControlError::InvalidArgument(format!("request body: {e}")))?;
    let b: StartBody = serde_json::from_slice(&bytes).map_err(|e| {
        ControlError::InvalidArgument(format!(
            "expected {{ kind, ramp_rate?, cycles?, f_max_start?, f_max_step? }}: {e}"
        ))
    })?;
    let req = ExperimentRequest::new(&b.kind, b.ramp_rate, b.cycles, b.f_max_start, b.f_max_step)?;
    core.start_experiment(req).await?;
    Ok(Json(json!({})).into_response())
}

pub async fn stop_experiment(State(core): State<Core>, headers: HeaderMap) -> ApiResult {
    authorize(&core, &headers)?;
    core.stop_experiment().await?;
    Ok(Json(json!({})).into_response())
}

pub async fn no_such_api(Path(rest): Path<String>) -> Response {
    (
        StatusCode::NOT_FOUND,
        Json(json!({ "error": format!("no API /api/{rest}") })),
    )
        .into_response()
}
