//! The control plane over the simulated backend (`testing::SimBackend`): a 10 kHz sine "loop"
//! with F_res spikes, two models `a.onnx` and `b.onnx`. For developing the page and trying
//! hapticctl before infer-server runs; it is not the product.
//!
//! cargo run -p control-plane --features testing --example sim_server -- \
//!     [--grpc 127.0.0.1:50051] [--http 127.0.0.1:8080] [--token TOKEN] [--rate 10000]
use control_plane::testing::SimBackend;
use control_plane::{Config, Shutdown};

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
    control_plane::serve(config, SimBackend::with_two_models(rate), Shutdown::new())
}
