//! The real server in-process (issue 15, thin binaries): the configuration built by the same
//! code as `infer-server serve`'s flags ([`infer_server::cli::ServeArgs::into_config`]), the
//! server started by [`infer_server::app::App::start`] on free ports and run by `run_until` with
//! a private stop request, while this test plays rt-loop on a real shared-memory segment. No
//! process is spawned and no signal is sent: the stop request is the shutdown signal.

mod common;

use std::net::TcpStream;
use std::time::{Duration, Instant};

use clap::Parser;
use haptics_proto::Segment;
use infer_server::app::App;
use infer_server::cli::{Cli, Command};
use shm_ring::os::shutdown::Shutdown;
use shm_ring::{SegmentName, WaitStrategy};

const TIMEOUT: Duration = Duration::from_secs(20);

#[test]
fn the_real_server_runs_in_process_and_stops_on_its_shutdown_signal() {
    let Some(fixtures) = common::fixtures() else {
        return;
    };
    common::runtime();
    let name = SegmentName::new(&format!("/infer-server-app-{}", std::process::id())).unwrap();
    let cli = Cli::try_parse_from([
        "infer-server",
        "serve",
        "--wait",
        "park",
        "--stats-every",
        "0",
        "--grpc",
        "127.0.0.1:0",
        "--http",
        "127.0.0.1:0",
        "--models",
        fixtures.to_str().unwrap(),
        "--model",
        "linear.onnx",
        "--segment",
        name.as_str(),
    ])
    .unwrap();
    let Command::Serve(args) = cli.command else {
        panic!("parsed as another subcommand")
    };
    let config = args.into_config(None).unwrap();
    assert_eq!(config.start_model.as_deref(), Some("linear.onnx"));
    // No --token and no HAPTICS_TOKEN: infer-server made one (16 random bytes in hex).
    let token = config
        .control
        .token
        .clone()
        .expect("a token created at start");
    assert!(
        token.len() == 32 && token.bytes().all(|b| b.is_ascii_hexdigit()),
        "{token}"
    );

    let app = App::start(config).unwrap();
    let http = app.http_addr();
    assert_ne!(http.port(), 0, "port 0 resolved to the bound port");
    assert_ne!(app.grpc_addr().port(), 0);
    let stop = Shutdown::new().unwrap();
    let server = {
        let stop = stop.clone();
        std::thread::spawn(move || app.run_until(&stop))
    };

    // The loop arrives after the server: it attaches, and activates the start model.
    let mut lp = Segment::create(&name, &haptics_proto::layout::config())
        .unwrap()
        .loop_side()
        .unwrap();
    lp.forces_rx.set_wait_strategy(WaitStrategy::Park);
    let deadline = Instant::now() + TIMEOUT;
    while !lp.peer_alive() {
        assert!(Instant::now() < deadline, "the server did not attach");
        std::thread::sleep(Duration::from_millis(10));
    }
    let mut answered_by_model = 0;
    for seq in 1.. {
        let (x, v) = (1e-3 * (seq % 7) as f64, 0.25);
        let a = common::lockstep(&mut lp, seq, x, v);
        if a.flags == 0 {
            // linear.onnx: 2 v - 3 x + 0.5.
            let want = 2.0 * v - 3.0 * x + 0.5;
            assert!((a.force - want).abs() < 1e-5, "{} vs {want}", a.force);
            answered_by_model += 1;
            if answered_by_model == 200 {
                break;
            }
        } else {
            assert!(a.force.is_nan(), "no model yet: NaN");
            assert!(
                Instant::now() < deadline,
                "the start model never became active"
            );
            std::thread::sleep(Duration::from_millis(2));
        }
    }

    // The control plane of the same server answers on its bound port.
    let (line, _) = common::http_get(&http.to_string(), "/api/status", None);
    assert!(
        line.starts_with("HTTP/1.1 401"),
        "the status needs the token: {line}"
    );
    let (line, status) = common::http_get(&http.to_string(), "/api/status", Some(&token));
    assert!(line.starts_with("HTTP/1.1 200"), "{line}");
    assert!(status.contains("linear.onnx"), "the active model: {status}");

    // The shutdown signal ends `run_until`: the control plane closes, the threads stop.
    let t0 = Instant::now();
    stop.request();
    server.join().unwrap().expect("a clean stop");
    assert!(t0.elapsed() < Duration::from_secs(5), "{:?}", t0.elapsed());
    assert!(
        TcpStream::connect(http).is_err(),
        "the HTTP listener is closed once run_until returns"
    );
}
