//! `rt-loop`: parses the command line and runs the subcommand with the process's shutdown signal
//! (SIGINT/SIGTERM: a run stops at its next step with 0 A and a complete recording). What the
//! subcommands do is in the library ([`rt_loop::app`]), so tests can run them in-process.

use rt_loop::cli::Cli;
use std::process::ExitCode;

fn main() -> ExitCode {
    let cli: Cli = haptics_proto::cli_parse::parse();
    let result = shm_ring::os::shutdown::install_signal_handlers()
        .map_err(|e| anyhow::anyhow!("cannot install the SIGINT/SIGTERM handlers: {e}"))
        .and_then(|shutdown| rt_loop::app::run(&cli.cmd, &shutdown));
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("rt-loop: error: {e:#}");
            ExitCode::from(2)
        }
    }
}
