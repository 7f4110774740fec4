//! What `serve` needs to know: addresses, token, limits.
use std::net::SocketAddr;
use std::time::Duration;

#[derive(Debug, Clone)]
pub struct Config {
    /// gRPC address; 127.0.0.1:50051 by default.
    pub grpc_addr: SocketAddr,
    /// HTTP address (page, /api, /ws/telemetry, /metrics); 127.0.0.1:8080 by default.
    pub http_addr: SocketAddr,
    /// When set, every call that changes something or reads live data or provenance needs
    /// `authorization: Bearer <token>` (HTTP: all of `/api/*`, the WebSocket and `/metrics`
    /// unless `metrics_open`; gRPC: every `haptics.v1` method). The page's own files, gRPC
    /// health and reflection stay open.
    pub token: Option<String>,
    /// Serve `/metrics` without the token (a Prometheus that cannot send one). Off by default:
    /// the metrics name the active model and the loop's state.
    pub metrics_open: bool,
    /// Listening on a non-loopback address without a token is refused unless this is set.
    pub allow_public_without_token: bool,
    /// Largest model upload accepted, in bytes (64 MiB by default).
    pub max_upload_bytes: usize,
    /// Most bytes of uploads being received at once, over gRPC and HTTP together (256 MiB by
    /// default). Each upload in progress reserves `max_upload_bytes` of it before its body is
    /// read, so at most `max_uploads_in_flight_bytes / max_upload_bytes` uploads are received at
    /// once; one more is refused with RESOURCE_EXHAUSTED / 413 without being read.
    pub max_uploads_in_flight_bytes: usize,
    /// How long an HTTP upload may send nothing before it is given up (its bytes and its share
    /// of the cap on uploads in flight released); 10 s by default.
    pub upload_idle_timeout: Duration,
    /// Names (besides the loopback names and the bound addresses) that HTTP requests may carry
    /// in `Host`; any other name is refused with 403 (DNS rebinding; see `host_policy`).
    pub allowed_hosts: Vec<String>,
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
            metrics_open: false,
            allow_public_without_token: false,
            max_upload_bytes: 64 << 20,
            max_uploads_in_flight_bytes: 256 << 20,
            upload_idle_timeout: Duration::from_secs(10),
            allowed_hosts: Vec::new(),
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
        if let Some(token) = &self.token {
            crate::auth::check_token(token)?;
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
        if self.max_upload_bytes == 0 || self.max_upload_bytes > MAX_UPLOAD_LIMIT {
            return Err(format!(
                "the upload limit is {} bytes; it must be between 1 byte and {} MiB",
                self.max_upload_bytes,
                MAX_UPLOAD_LIMIT >> 20
            ));
        }
        if self.max_uploads_in_flight_bytes < self.max_upload_bytes {
            return Err(format!(
                "the cap on uploads in flight ({} bytes) is below one upload's limit ({} bytes): \
                 no upload could ever be received",
                self.max_uploads_in_flight_bytes, self.max_upload_bytes
            ));
        }
        for (what, v, max) in [
            ("ws_bucket_steps", self.ws_bucket_steps, 1_000_000),
            (
                "ws_max_buckets_per_frame",
                self.ws_max_buckets_per_frame,
                100_000,
            ),
        ] {
            if v == 0 || v > max {
                return Err(format!("{what} is {v}; it must be between 1 and {max}"));
            }
        }
        if self.worker_threads == 0 || self.worker_threads > 64 {
            return Err(format!(
                "worker_threads is {}; it must be between 1 and 64",
                self.worker_threads
            ));
        }
        if self.upload_idle_timeout.is_zero() || self.upload_idle_timeout > Duration::from_secs(600)
        {
            return Err(format!(
                "upload_idle_timeout is {:?}; it must be more than 0 and at most 600 s",
                self.upload_idle_timeout
            ));
        }
        if self.shutdown_grace > Duration::from_secs(60) {
            return Err(format!(
                "shutdown_grace is {:?}; at most 60 s",
                self.shutdown_grace
            ));
        }
        for name in &self.allowed_hosts {
            let ok = !name.is_empty()
                && name.len() <= 253
                && name
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '-' | '_'));
            if !ok {
                return Err(format!(
                    "allowed host {name:?} is not a host name (letters, digits, '.', '-', '_'; \
                     no port, no scheme)"
                ));
            }
        }
        Ok(())
    }
}

/// The largest upload limit a configuration may set (1 GiB): uploads are held in memory.
pub const MAX_UPLOAD_LIMIT: usize = 1 << 30;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_numeric_setting_is_checked() {
        assert!(Config::default().check().is_ok());
        let bad = [
            Config {
                max_upload_bytes: 0,
                ..Config::default()
            },
            Config {
                max_upload_bytes: MAX_UPLOAD_LIMIT + 1,
                max_uploads_in_flight_bytes: usize::MAX,
                ..Config::default()
            },
            Config {
                max_uploads_in_flight_bytes: (64 << 20) - 1,
                ..Config::default()
            },
            Config {
                ws_bucket_steps: 0,
                ..Config::default()
            },
            Config {
                ws_max_buckets_per_frame: 0,
                ..Config::default()
            },
            Config {
                upload_idle_timeout: Duration::ZERO,
                ..Config::default()
            },
            Config {
                worker_threads: 0,
                ..Config::default()
            },
            Config {
                shutdown_grace: Duration::from_secs(3600),
                ..Config::default()
            },
            Config {
                allowed_hosts: vec!["http://lab-pc:8080".into()],
                ..Config::default()
            },
            Config {
                allowed_hosts: vec![String::new()],
                ..Config::default()
            },
        ];
        for c in bad {
            assert!(c.check().is_err(), "{c:?} accepted");
        }
    }
}
