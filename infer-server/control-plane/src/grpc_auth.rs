//! The token check of `haptics.v1` gRPC calls (mutating and reads) as a tower layer in front of every service: it sees the
//! method path and the headers before the request body is read, so an unauthenticated 64 MiB
//! upload is refused without being received and decoded. The handlers check again (the same
//! `Auth`), so a mutating call never depends on this layer alone.
//!
//! The same layer holds `LoadModel` calls to the cap on uploads in flight: before the body is
//! read, the call reserves what its message may take (its `content-length` when given, else the
//! decoding limit), and a call that would pass the cap is refused with RESOURCE_EXHAUSTED
//! without being read.
use std::future::Future;
use std::pin::Pin;
use std::task::{Context, Poll};

use crate::auth::Auth;
use crate::uploads::UploadBudget;

/// The method whose request carries an upload.
pub const LOAD_MODEL: &str = "/haptics.v1.ModelService/LoadModel";

/// The prefix of every method of this product's services (`haptics.v1.ModelService`,
/// `haptics.v1.LoopService`): with a token, all of them need it, the reads too (status,
/// models and telemetry show live forces, positions and the models' provenance). Health and
/// reflection (`grpc.health.v1`, `grpc.reflection.*`) stay open: they show neither.
pub const GUARDED_PREFIX: &str = "/haptics.v1.";

#[derive(Debug, Clone)]
pub struct AuthLayer {
    auth: Auth,
    uploads: Option<(UploadBudget, usize)>,
}

impl AuthLayer {
    pub fn new(auth: Auth) -> Self {
        Self {
            auth,
            uploads: None,
        }
    }

    /// Reserves up to `message_limit` bytes of `budget` for every `LoadModel` call.
    pub fn with_upload_budget(mut self, budget: UploadBudget, message_limit: usize) -> Self {
        self.uploads = Some((budget, message_limit));
        self
    }
}

impl<S> tower::Layer<S> for AuthLayer {
    type Service = AuthService<S>;

    fn layer(&self, inner: S) -> AuthService<S> {
        AuthService {
            inner,
            auth: self.auth.clone(),
            uploads: self.uploads.clone(),
        }
    }
}

#[derive(Debug, Clone)]
pub struct AuthService<S> {
    inner: S,
    auth: Auth,
    uploads: Option<(UploadBudget, usize)>,
}

type BoxFuture<T> = Pin<Box<dyn Future<Output = T> + Send>>;

impl<S, B> tower::Service<http::Request<B>> for AuthService<S>
where
    S: tower::Service<http::Request<B>, Response = http::Response<tonic::body::Body>>,
    S::Future: Send + 'static,
{
    type Response = S::Response;
    type Error = S::Error;
    type Future = BoxFuture<Result<Self::Response, Self::Error>>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, request: http::Request<B>) -> Self::Future {
        if self.auth.required() && request.uri().path().starts_with(GUARDED_PREFIX) {
            let header = request
                .headers()
                .get(http::header::AUTHORIZATION)
                .and_then(|v| v.to_str().ok());
            if let Err(e) = self.auth.check(header) {
                let response = tonic::Status::from(e).into_http();
                return Box::pin(async move { Ok(response) });
            }
        }
        let mut reservation = None;
        if let Some((budget, limit)) = &self.uploads {
            if request.uri().path() == LOAD_MODEL {
                let declared = request
                    .headers()
                    .get(http::header::CONTENT_LENGTH)
                    .and_then(|v| v.to_str().ok())
                    .and_then(|v| v.parse::<usize>().ok());
                match budget.reserve(declared.unwrap_or(*limit).min(*limit)) {
                    Ok(r) => reservation = Some(r),
                    Err(e) => {
                        let response = tonic::Status::from(e).into_http();
                        return Box::pin(async move { Ok(response) });
                    }
                }
            }
        }
        let call = self.inner.call(request);
        Box::pin(async move {
            let response = call.await;
            // Held until the call has answered: the decoded upload lives that long.
            drop(reservation);
            response
        })
    }
}
