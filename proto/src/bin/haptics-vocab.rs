//! Writes the generated name lists (`train/src/haptics_train/vocab.py`, `web-ui/src/vocab.ts`)
//! from haptics-proto, or with `--check` exits non-zero naming each one that is stale.
//!
//! Usage: `haptics-vocab [--check] [--root DIR]` (DIR: the repository root; default: the one
//! this crate was built in).

use std::path::PathBuf;
use std::process::ExitCode;

fn main() -> ExitCode {
    let mut check = false;
    let mut root = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/.."));
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--check" => check = true,
            "--root" => match args.next() {
                Some(dir) => root = PathBuf::from(dir),
                None => return usage("--root needs a directory"),
            },
            "-h" | "--help" => {
                println!("usage: haptics-vocab [--check] [--root DIR]");
                return ExitCode::SUCCESS;
            }
            other => return usage(&format!("unknown argument `{other}`")),
        }
    }
    let mut stale = 0;
    for g in haptics_proto::vocab_gen::all() {
        let path = root.join(g.path);
        let current = std::fs::read_to_string(&path).ok();
        if current.as_deref() == Some(g.text.as_str()) {
            continue;
        }
        if check {
            let why = if current.is_none() {
                "missing"
            } else {
                "stale"
            };
            eprintln!(
                "haptics-vocab: {} is {why}: run `{}`",
                g.path,
                haptics_proto::vocab_gen::COMMAND
            );
            stale += 1;
        } else if let Err(e) = std::fs::write(&path, &g.text) {
            eprintln!("haptics-vocab: cannot write {}: {e}", path.display());
            return ExitCode::FAILURE;
        } else {
            println!("wrote {}", g.path);
        }
    }
    if stale > 0 {
        return ExitCode::FAILURE;
    }
    if check {
        println!("haptics-vocab: the generated name lists are current");
    }
    ExitCode::SUCCESS
}

fn usage(msg: &str) -> ExitCode {
    eprintln!("haptics-vocab: {msg}\nusage: haptics-vocab [--check] [--root DIR]");
    ExitCode::from(2)
}
