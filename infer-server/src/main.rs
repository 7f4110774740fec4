//! `infer-server`: validate models, predict from a feature table, serve a model to rt-loop.
//! Parses the command line and calls the library: the one-shot subcommands in
//! [`infer_server::commands`], `serve` in [`infer_server::app::run`] with the process's stop
//! request (SIGINT/SIGTERM, `shm_ring::os::shutdown`).

use std::process::ExitCode;

use infer_server::cli::{Cli, Command};
use infer_server::exit::EXIT_REFUSED;
use infer_server::{app, commands};
use shm_ring::os::shutdown;

fn main() -> ExitCode {
    let cli: Cli = haptics_proto::cli_parse::parse();
    let ort_lib = cli.ort_lib.as_deref();
    match cli.command {
        Command::Validate {
            model,
            schema,
            json,
        } => commands::validate(ort_lib, &model, schema.as_deref(), json),
        Command::Predict { model, csv } => commands::predict(ort_lib, &model, &csv),
        Command::Runtime { json } => commands::runtime_info(ort_lib, json),
        Command::Serve(args) => {
            let stop = match shutdown::install_signal_handlers() {
                Ok(s) => s,
                Err(e) => {
                    eprintln!("infer-server: cannot install the SIGINT/SIGTERM handlers: {e}");
                    return ExitCode::from(EXIT_REFUSED);
                }
            };
            match args
                .into_config(cli.ort_lib.clone())
                .and_then(|config| app::run(config, stop))
            {
                Ok(()) => ExitCode::SUCCESS,
                Err(e) => {
                    eprintln!("infer-server: {e}");
                    ExitCode::from(e.exit_code())
                }
            }
        }
    }
}
