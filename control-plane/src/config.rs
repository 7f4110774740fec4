//! What `serve` needs to know: addresses, token, limits.
use std::net::SocketAddr;
use std::time::Duration;

#[derive(Debug, Clone)]
pub struct Config {
    /// gRPC address; 127.0.0.1:50051 by default.
    pub grpc_addr: SocketAddr,
    /// HTTP address (page, /api, /ws/telemetry, /metrics); 127.0.0.1:8080 by default.
    pub http_addr: SocketAddr,
    /// When set, mutating calls need `authorization: Bearer <token>`.
    pub token: Option<String>,
    /// Listening on a non-loopback address without a token is refused unless this is set.
    pub allow_public_without_token: bool,
    /// Largest model upload accepted, in bytes (64 MiB by default).
    pub max_upload_bytes: usize,
    /// Smallest bucket of the WebSocket frames, in loop steps (10 = 1 ms at 10 kHz).
    pub ws_bucket_steps: u32,
    /// Most buckets in one WebSocket frame: faster loops get longer buckets.
    pub ws_max_buckets_per_frame: u32,
    /// How long open connections get after shutdown before they are dropped.
    pub shutdown_grace: Duration,
    /// Worker threads of the runtime `serve` creates (the control plane needs few).
    pub worker_threads: usize,
    /// Trigger the shutdown on SIGINT or SIGTERM (for a main that has no handler of its own).
    pub stop_on_signals: bool,
    /// Reported as the server version.
    pub version: String,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            grpc_addr: SocketAddr::from(([127, 0, 0, 1], 50051)),
            http_addr: SocketAddr::from(([127, 0, 0, 1], 8080)),
            token: None,
            allow_public_without_token: false,
            max_upload_bytes: 64 << 20,
            ws_bucket_steps: 10,
            ws_max_buckets_per_frame: 400,
            shutdown_grace: Duration::from_secs(2),
            worker_threads: 2,
            stop_on_signals: false,
            version: env!("CARGO_PKG_VERSION").to_string(),
        }
    }
}

impl Config {
    /// Refuses a configuration that would expose mutating calls to the network.
    pub fn check(&self) -> Result<(), String> {
        if self.token.as_deref() == Some("") {
            return Err("the token is empty: give a non-empty token or none".into());
        }
        if self.token.is_none() && !self.allow_public_without_token {
            for (what, addr) in [("gRPC", self.grpc_addr), ("HTTP", self.http_addr)] {
                if !addr.ip().is_loopback() {
                    return Err(format!(
                        "{what} would listen on {addr}, which is not a loopback address, \
                         without a token: set one (--token or HAPTICS_TOKEN) first"
                    ));
                }
            }
        }
        if self.max_upload_bytes == 0 {
            return Err("the upload limit must be > 0".into());
        }
        Ok(())
    }
}
