//! `control-plane-sim`: the control plane over the simulated backend ([`SimBackend`]): a 10 kHz
//! sine "loop" with force spikes, two models `a.onnx` and `b.onnx`. For developing the page and
//! trying hapticctl without rt-loop and infer-server (`scripts/up.sh` runs the real ones); it is
//! not the product. Prints one line on stdout once both listeners are bound (so a test can start
//! it on port 0 and read the addresses), and stops on SIGINT/SIGTERM.
//!
//! cargo run -p control-plane-sim -- \
//!     [--grpc 127.0.0.1:50051] [--http 127.0.0.1:8080] [--token TOKEN] [--rate 10000]
use std::io::Write;

use control_plane::{Config, Shutdown};
use control_plane_sim::SimBackend;

fn main() -> anyhow::Result<()> {
    let mut config = Config {
        stop_on_signals: true,
        ..Config::default()
    };
    let mut rate = 10_000.0;
    let mut args = std::env::args().skip(1);
    while let Some(flag) = args.next() {
        let mut value = || {
            args.next()
                .ok_or_else(|| anyhow::anyhow!("{flag} needs a value"))
        };
        match flag.as_str() {
            "--grpc" => config.grpc_addr = value()?.parse()?,
            "--http" => config.http_addr = value()?.parse()?,
            "--token" => config.token = Some(value()?),
            "--rate" => rate = value()?.parse()?,
            other => anyhow::bail!("unknown argument {other}"),
        }
    }
    // Ctrl-C or SIGTERM stops it.
    let running = control_plane::start(config, SimBackend::with_two_models(rate), Shutdown::new())?;
    println!(
        "control-plane-sim: gRPC {} HTTP http://{}",
        running.grpc_addr(),
        running.http_addr()
    );
    std::io::stdout().flush()?;
    running.join()
}
