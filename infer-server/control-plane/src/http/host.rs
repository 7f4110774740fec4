//! The HTTP side of the `Host` allowlist (`crate::host_policy`): the middleware in front of
//! every route that refuses a request to a name this server does not know, before any handler
//! runs.
use axum::extract::{Request, State};
use axum::http::header;
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

use crate::core::Core;

/// The name a request was sent to: the `Host` header, else the URI's authority (HTTP/2).
pub fn request_host(headers: &axum::http::HeaderMap, uri: &axum::http::Uri) -> Option<String> {
    headers
        .get(header::HOST)
        .map(|v| String::from_utf8_lossy(v.as_bytes()).into_owned())
        .or_else(|| uri.authority().map(|a| a.as_str().to_string()))
}

/// The middleware in front of every route: refuses a request to an unknown name with 403 before
/// any handler (and so any `Origin` or token check) runs.
pub async fn require_known_host(
    State(core): State<Core>,
    request: Request,
    next: Next,
) -> Response {
    let host = request_host(request.headers(), request.uri());
    match core.hosts.check(host.as_deref()) {
        Ok(()) => next.run(request).await,
        Err(e) => {
            crate::stats::Stats::add(&core.stats.requests_failed, 1);
            e.into_response()
        }
    }
}
