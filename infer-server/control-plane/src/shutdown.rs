//! A shutdown signal that can be triggered from any thread (a signal handler, infer-server's
//! main) and that ends the servers and every open stream.
use tokio_util::sync::CancellationToken;

#[derive(Debug, Clone, Default)]
pub struct Shutdown(CancellationToken);

impl Shutdown {
    pub fn new() -> Self {
        Self::default()
    }

    /// Starts the shutdown: servers stop accepting, streams and WebSockets end.
    pub fn trigger(&self) {
        self.0.cancel();
    }

    pub fn is_triggered(&self) -> bool {
        self.0.is_cancelled()
    }

    /// Resolves once `trigger` was called.
    pub async fn wait(&self) {
        self.0.cancelled().await;
    }
}
