//! `Config::stop_on_signals`: SIGTERM ends `serve` cleanly. In its own test binary (process),
//! because the signal goes to the whole process.
use std::time::Duration;

use control_plane::{Config, Shutdown};
use control_plane_sim::SimBackend;

#[test]
fn sigterm_ends_serve_cleanly() {
    let free = || {
        std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
    };
    let config = Config {
        grpc_addr: free(),
        http_addr: free(),
        stop_on_signals: true,
        ..Config::default()
    };
    let addr = config.http_addr;
    let shutdown = Shutdown::new();
    let observed = shutdown.clone();
    let server = std::thread::spawn(move || {
        control_plane::serve(config, SimBackend::with_two_models(1000.0), shutdown)
    });
    let t0 = std::time::Instant::now();
    // The handler is installed before the listeners are bound.
    while std::net::TcpStream::connect(addr).is_err() {
        assert!(t0.elapsed() < Duration::from_secs(10), "never listened");
        std::thread::sleep(Duration::from_millis(20));
    }
    // SAFETY: kill(2) on this process; tokio's handler catches it.
    unsafe { libc::kill(libc::getpid(), libc::SIGTERM) };
    let t1 = std::time::Instant::now();
    server.join().unwrap().unwrap();
    assert!(observed.is_triggered(), "the caller sees the shutdown too");
    assert!(t1.elapsed() < Duration::from_secs(10));
}
