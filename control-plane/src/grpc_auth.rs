//! The token check of mutating gRPC calls as a tower layer in front of every service: it sees the
//! method path and the headers before the request body is read, so an unauthenticated 64 MiB
//! upload is refused without being received and decoded. The handlers check again (the same
//! `Auth`), so a mutating call never depends on this layer alone.
use std::future::Future;
use std::pin::Pin;
use std::task::{Context, Poll};

use crate::auth::Auth;

/// The gRPC methods that change the server or the loop.
pub const MUTATING_METHODS: [&str; 5] = [
    "/haptics.v1.ModelService/LoadModel",
    "/haptics.v1.ModelService/ActivateModel",
    "/haptics.v1.ModelService/UnloadModel",
    "/haptics.v1.LoopService/StartExperiment",
    "/haptics.v1.LoopService/StopExperiment",
];

#[derive(Debug, Clone)]
pub struct AuthLayer {
    auth: Auth,
}

impl AuthLayer {
    pub fn new(auth: Auth) -> Self {
        Self { auth }
    }
}

impl<S> tower::Layer<S> for AuthLayer {
    type Service = AuthService<S>;

    fn layer(&self, inner: S) -> AuthService<S> {
        AuthService {
            inner,
            auth: self.auth.clone(),
        }
    }
}

#[derive(Debug, Clone)]
pub struct AuthService<S> {
    inner: S,
    auth: Auth,
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
        if self.auth.required() && MUTATING_METHODS.contains(&request.uri().path()) {
            let header = request
                .headers()
                .get(http::header::AUTHORIZATION)
                .and_then(|v| v.to_str().ok());
            if let Err(e) = self.auth.check(header) {
                let response = tonic::Status::from(e).into_http();
                return Box::pin(async move { Ok(response) });
            }
        }
        Box::pin(self.inner.call(request))
    }
}
