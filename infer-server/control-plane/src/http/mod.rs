//! The HTTP side (axum): the page, `/api/*` JSON, `/ws/telemetry`, `/metrics`. See
//! `docs/web-protocol.md`.
pub mod api;
pub mod assets;
pub mod host;
pub mod json;
pub mod metrics;
pub mod ws;

use axum::extract::DefaultBodyLimit;
use axum::routing::{get, post};
use axum::Router;

use crate::core::Core;

pub fn router(core: Core) -> Router {
    Router::new()
        .route("/api/status", get(api::status))
        .route("/api/models", get(api::list_models))
        .route("/api/models/active", get(api::active_model))
        .route("/api/models/{name}/load", post(api::load_model))
        .route("/api/models/{name}/activate", post(api::activate_model))
        .route("/api/models/{name}/unload", post(api::unload_model))
        .route("/api/experiment/start", post(api::start_experiment))
        .route("/api/experiment/stop", post(api::stop_experiment))
        .route("/api/{*rest}", get(api::no_such_api).post(api::no_such_api))
        .route("/metrics", get(metrics::metrics))
        .route("/ws/telemetry", get(ws::telemetry))
        .fallback(get(assets::asset))
        // Uploads are read by the handler with the configured limit and a clear error.
        .layer(DefaultBodyLimit::disable())
        // Outermost: a request to a name this server does not know is refused before any
        // handler, Origin or token check (DNS rebinding, see host.rs).
        .layer(axum::middleware::from_fn_with_state(
            core.clone(),
            host::require_known_host,
        ))
        .with_state(core)
}
