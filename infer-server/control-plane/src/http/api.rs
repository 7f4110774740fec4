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

/// Refuses a mutating request that a browser sent from another site (a page elsewhere posting to
/// 127.0.0.1:8080 without a token). Same-origin requests and loopback origins (a dev server on
/// another port) pass; clients that are not browsers send no Origin. "Same origin" is only
/// meaningful once `Host` is known to name this server (a DNS-rebound page sends an Origin equal
/// to its Host): callers check the host first.
pub fn check_origin(headers: &HeaderMap) -> Result<(), ControlError> {
    let Some(origin) = headers.get(header::ORIGIN).and_then(|v| v.to_str().ok()) else {
        return Ok(());
    };
    let host = headers
        .get(header::HOST)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("");
    let origin_host = origin
        .split_once("://")
        .map(|(_, rest)| rest)
        .unwrap_or(origin);
    let origin_name = origin_host
        .rsplit_once(':')
        .filter(|(_, port)| port.chars().all(|c| c.is_ascii_digit()))
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

pub async fn status(State(core): State<Core>) -> ApiResult {
    let s = core.status().await?;
    Ok(Json(StatusJson::new(
        &s,
        core.auth.required(),
        core.config.max_upload_bytes,
        None,
    ))
    .into_response())
}

pub async fn list_models(State(core): State<Core>) -> ApiResult {
    let models = core.list_models().await?;
    let models: Vec<ModelJson> = models.iter().map(ModelJson::from).collect();
    Ok(Json(models).into_response())
}

pub async fn active_model(State(core): State<Core>) -> ApiResult {
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
    let bytes = match to_bytes(body, limit + 1).await {
        Ok(b) => b,
        Err(_) => {
            // Over the limit (or a broken body): say which limit.
            core.check_upload_size(limit + 1)?;
            unreachable!("check_upload_size refuses limit + 1");
        }
    };
    let upload = (!bytes.is_empty()).then(|| bytes.to_vec());
    let model = core.load_model(name, upload).await?;
    Ok(Json(ModelJson::from(&model)).into_response())
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
