//! Binding and running both servers until shutdown.
use std::future::Future;
use std::net::SocketAddr;
use std::sync::Arc;

use anyhow::{Context, Result};
use tonic::transport::server::TcpIncoming;

use crate::backend::Backend;
use crate::config::Config;
use crate::core::Core;
use crate::grpc::{LoopSvc, ModelSvc};
use crate::pb;
use crate::shutdown::Shutdown;

/// Both listeners, bound (so the addresses are known, e.g. with port 0 in tests) but not serving.
pub struct Bound {
    core: Core,
    grpc: tokio::net::TcpListener,
    http: tokio::net::TcpListener,
}

/// Binds the gRPC and HTTP addresses of `config`. Fails on a configuration that would expose
/// mutating calls without a token, or on an address in use.
pub async fn bind(config: Config, backend: Arc<dyn Backend>, shutdown: Shutdown) -> Result<Bound> {
    config.check().map_err(anyhow::Error::msg)?;
    let grpc = tokio::net::TcpListener::bind(config.grpc_addr)
        .await
        .with_context(|| format!("cannot listen for gRPC on {}", config.grpc_addr))?;
    let http = tokio::net::TcpListener::bind(config.http_addr)
        .await
        .with_context(|| format!("cannot listen for HTTP on {}", config.http_addr))?;
    Ok(Bound {
        core: Core::new(config, backend, shutdown),
        grpc,
        http,
    })
}

impl Bound {
    pub fn grpc_addr(&self) -> SocketAddr {
        self.grpc.local_addr().expect("bound listener")
    }

    pub fn http_addr(&self) -> SocketAddr {
        self.http.local_addr().expect("bound listener")
    }

    /// Serves until the shutdown is triggered; open streams and WebSockets end then, and
    /// connections that still hang on are dropped after `shutdown_grace`.
    pub async fn run(self) -> Result<()> {
        let core = self.core;
        let shutdown = core.shutdown.clone();
        let grace = core.config.shutdown_grace;
        let limit = core.config.max_upload_bytes;

        let (health, health_svc) = tonic_health::server::health_reporter();
        health
            .set_serving::<pb::model_service_server::ModelServiceServer<ModelSvc>>()
            .await;
        health
            .set_serving::<pb::loop_service_server::LoopServiceServer<LoopSvc>>()
            .await;
        // Both reflection versions list every service, each other included.
        let reflection = || {
            tonic_reflection::server::Builder::configure()
                .include_reflection_service(false)
                .register_encoded_file_descriptor_set(pb::FILE_DESCRIPTOR_SET)
                .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
                .register_encoded_file_descriptor_set(tonic_reflection::pb::v1::FILE_DESCRIPTOR_SET)
                .register_encoded_file_descriptor_set(
                    tonic_reflection::pb::v1alpha::FILE_DESCRIPTOR_SET,
                )
        };
        let reflection_v1 = reflection().build_v1().context("reflection v1")?;
        let reflection_v1alpha = reflection().build_v1alpha().context("reflection v1alpha")?;
        // The message limit leaves room for the request's other fields, so an upload just over
        // the limit gets our explanation, and a far larger one tonic's RESOURCE_EXHAUSTED.
        let model_svc =
            pb::model_service_server::ModelServiceServer::new(ModelSvc::new(core.clone()))
                .max_decoding_message_size(limit.saturating_add(64 << 10))
                .max_encoding_message_size(pb::MAX_MESSAGE_BYTES);
        let loop_svc = pb::loop_service_server::LoopServiceServer::new(LoopSvc::new(core.clone()))
            .max_encoding_message_size(pb::MAX_MESSAGE_BYTES);

        let grpc_shutdown = shutdown.clone();
        let health_on_shutdown = health.clone();
        let grpc = tonic::transport::Server::builder()
            .layer(
                crate::grpc_auth::AuthLayer::new(core.auth.clone())
                    .with_upload_budget(core.uploads.clone(), limit),
            )
            .add_service(health_svc)
            .add_service(reflection_v1)
            .add_service(reflection_v1alpha)
            .add_service(model_svc)
            .add_service(loop_svc)
            .serve_with_incoming_shutdown(
                TcpIncoming::from(self.grpc).with_nodelay(Some(true)),
                async move {
                    grpc_shutdown.wait().await;
                    health_on_shutdown
                        .set_service_status("", tonic_health::ServingStatus::NotServing)
                        .await;
                },
            );

        let http_shutdown = shutdown.clone();
        // Small frames at 30-60 fps: no Nagle delay.
        let listener = axum::serve::ListenerExt::tap_io(self.http, |tcp| {
            let _ = tcp.set_nodelay(true);
        });
        let http = axum::serve(listener, crate::http::router(core.clone()))
            .with_graceful_shutdown(async move { http_shutdown.wait().await });

        let grpc = with_grace(grpc, &shutdown, grace);
        let http = with_grace(async move { http.await }, &shutdown, grace);
        let (g, h) = tokio::join!(grpc, http);
        g.context("gRPC server")?;
        h.context("HTTP server")?;
        Ok(())
    }
}

/// Runs a server future; once the shutdown is triggered, gives it `grace` to finish and then
/// drops it (a health Watch stream, say, would otherwise hold graceful shutdown forever).
async fn with_grace<E: std::error::Error + Send + Sync + 'static>(
    server: impl Future<Output = Result<(), E>>,
    shutdown: &Shutdown,
    grace: std::time::Duration,
) -> Result<()> {
    let deadline = async {
        shutdown.wait().await;
        tokio::time::sleep(grace).await;
    };
    tokio::select! {
        r = server => r.map_err(anyhow::Error::from),
        _ = deadline => Ok(()),
    }
}

/// Binds and serves on the current tokio runtime until `shutdown` is triggered.
pub async fn serve_async(
    config: Config,
    backend: Arc<dyn Backend>,
    shutdown: Shutdown,
) -> Result<()> {
    if config.stop_on_signals {
        trigger_on_signals(shutdown.clone())?;
    }
    let bound = bind(config, backend, shutdown).await?;
    eprintln!(
        "control plane: gRPC on {}, HTTP on http://{}",
        bound.grpc_addr(),
        bound.http_addr()
    );
    bound.run().await
}

/// Triggers `shutdown` on the first SIGINT or SIGTERM: the process's one stop request
/// (`shm_ring::os::shutdown`, the handler both processes use), awaited through its eventfd.
fn trigger_on_signals(shutdown: Shutdown) -> Result<()> {
    use tokio::io::unix::AsyncFd;
    use tokio::io::Interest;
    let process =
        shm_ring::os::shutdown::install_signal_handlers().context("SIGINT/SIGTERM handlers")?;
    let fd = process.wait_fd().context("the stop request's eventfd")?;
    // SAFETY: the AsyncFd owns the descriptor (an OwnedFd duplicate of the eventfd: one runtime
    // registers a descriptor once) for its whole life, as the call's contract asks.
    let readable = unsafe { AsyncFd::register_with_interest(fd, Interest::READABLE) }
        .context("register eventfd")?;
    tokio::spawn(async move {
        tokio::select! {
            _ = readable.readable() => {}
            _ = shutdown.wait() => return,
        }
        eprintln!("control plane: signal received, shutting down");
        shutdown.trigger();
    });
    Ok(())
}

/// The control plane serving on a runtime and a thread of its own (what infer-server runs beside
/// its inference thread): bound, so its addresses are known, and running until the shutdown.
pub struct Running {
    grpc_addr: SocketAddr,
    http_addr: SocketAddr,
    thread: std::thread::JoinHandle<Result<()>>,
}

impl Running {
    pub fn grpc_addr(&self) -> SocketAddr {
        self.grpc_addr
    }

    pub fn http_addr(&self) -> SocketAddr {
        self.http_addr
    }

    /// True once the servers have stopped (after the shutdown, or on an error).
    pub fn is_finished(&self) -> bool {
        self.thread.is_finished()
    }

    /// Waits for the servers to stop (trigger the shutdown first).
    pub fn join(self) -> Result<()> {
        self.thread
            .join()
            .unwrap_or_else(|_| Err(anyhow::anyhow!("the control plane panicked")))
    }
}

/// Creates a small multi-thread tokio runtime whose threads run under the normal scheduling
/// policy (never real-time), binds gRPC and HTTP on it and serves them on a thread of its own
/// ("control-plane") until `shutdown` is triggered. Returns once both listeners are bound.
pub fn start(config: Config, backend: Arc<dyn Backend>, shutdown: Shutdown) -> Result<Running> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(config.worker_threads.max(1))
        .max_blocking_threads(16)
        .thread_name("control-plane")
        .on_thread_start(normal_scheduling)
        .enable_all()
        .build()
        .context("cannot start the control plane's runtime")?;
    let bound = runtime.block_on(async {
        if config.stop_on_signals {
            trigger_on_signals(shutdown.clone())?;
        }
        bind(config, backend, shutdown).await
    })?;
    let (grpc_addr, http_addr) = (bound.grpc_addr(), bound.http_addr());
    let thread = std::thread::Builder::new()
        .name("control-plane".into())
        .spawn(move || {
            let result = runtime.block_on(bound.run());
            // Connection tasks still alive after the grace period are dropped here.
            runtime.shutdown_timeout(std::time::Duration::from_millis(200));
            result
        })
        .context("cannot start the control plane's thread")?;
    Ok(Running {
        grpc_addr,
        http_addr,
        thread,
    })
}

/// [`start`], then waits until `shutdown` is triggered and the servers have stopped. Blocks the
/// caller.
pub fn serve(config: Config, backend: Arc<dyn Backend>, shutdown: Shutdown) -> Result<()> {
    let running = start(config, backend, shutdown)?;
    eprintln!(
        "control plane: gRPC on {}, HTTP on http://{}",
        running.grpc_addr(),
        running.http_addr()
    );
    running.join()
}

/// The control plane's threads must never compete with the loop: if the thread that called
/// `start` had a real-time policy, its children would inherit it, so reset it.
fn normal_scheduling() {
    // Refused only by a system that forbids SCHED_OTHER, which does not exist on Linux.
    let _ = shm_ring::os::rt_thread::set_normal();
}
