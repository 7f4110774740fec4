//! The one-shot subcommands: `validate` (a model against the contract and a feature schema),
//! `predict` (a model over a CSV table of features) and `runtime` (which ONNX Runtime would be
//! loaded). Each prints its result and returns the process's exit code ([`crate::exit`]).

use std::io::{BufRead, Write};
use std::path::Path;
use std::process::ExitCode;

use crate::exit::{EXIT_REFUSED, EXIT_RUNTIME};
use crate::model::contract::FeatureSchema;
use crate::model::engine::StepEngine;
use crate::model::runtime::{Runtime, RuntimeError};
use crate::model::{ModelError, SessionConfig};

fn load_runtime(ort_lib: Option<&Path>, json: bool) -> Result<&'static Runtime, ExitCode> {
    Runtime::init(ort_lib).map_err(|e| {
        report_runtime_error(&e, json);
        ExitCode::from(EXIT_RUNTIME)
    })
}

fn report_runtime_error(e: &RuntimeError, json: bool) {
    if json {
        let v = serde_json::json!({
            "ok": false,
            "error": { "code": "runtime_missing", "message": e.to_string() },
        });
        println!("{v}");
    }
    eprintln!("infer-server: {e}");
}

pub fn runtime_info(ort_lib: Option<&Path>, json: bool) -> ExitCode {
    let rt = match load_runtime(ort_lib, json) {
        Ok(rt) => rt,
        Err(code) => return code,
    };
    if json {
        let v = serde_json::json!({
            "ok": true,
            "library": rt.library(),
            "version": rt.version(),
        });
        println!("{v}");
    } else {
        println!(
            "ONNX Runtime {} from {}",
            rt.version(),
            rt.library().display()
        );
    }
    ExitCode::SUCCESS
}

fn parse_schema(schema: Option<&str>) -> Result<FeatureSchema, String> {
    match schema {
        None => Ok(FeatureSchema::standard()),
        Some(s) => FeatureSchema::parse(s).map_err(|e| format!("bad --schema: {e}")),
    }
}

pub fn validate(
    ort_lib: Option<&Path>,
    model: &Path,
    schema: Option<&str>,
    json: bool,
) -> ExitCode {
    let schema = match parse_schema(schema) {
        Ok(s) => s,
        Err(msg) => {
            if json {
                let v = serde_json::json!({
                    "ok": false,
                    "model": model,
                    "error": { "code": "bad_schema", "message": msg },
                });
                println!("{v}");
            }
            eprintln!("infer-server: {msg}");
            return ExitCode::from(EXIT_REFUSED);
        }
    };
    let rt = match load_runtime(ort_lib, json) {
        Ok(rt) => rt,
        Err(code) => return code,
    };
    match StepEngine::load(rt, model, &schema, &SessionConfig::default()) {
        Ok(engine) => {
            let info = engine.info();
            if json {
                let v = serde_json::json!({
                    "ok": true,
                    "model": info,
                    "runtime": { "library": rt.library(), "version": rt.version() },
                });
                println!("{v}");
            } else {
                println!("{}: valid {} model", model.display(), info.kind);
                println!("  features: {}", info.features.join(", "));
                println!(
                    "  schema indices: {:?} (schema: {})",
                    info.input_map,
                    info.schema.join(", ")
                );
                println!("  units: {}", info.units);
                if let Some(s) = &info.state_shape {
                    println!("  state shape: {s:?}");
                }
                println!("  provenance: {}", info.provenance);
                match info.reference_steps {
                    Some(n) => println!(
                        "  reference: {n} steps computed as at its export (haptics.reference)"
                    ),
                    None => println!("  reference: none carried (not checked)"),
                }
                println!(
                    "  ONNX Runtime {} ({})",
                    rt.version(),
                    rt.library().display()
                );
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            report_model_error(model, &e, json);
            ExitCode::from(EXIT_REFUSED)
        }
    }
}

fn report_model_error(model: &Path, e: &ModelError, json: bool) {
    if json {
        let v = serde_json::json!({
            "ok": false,
            "model": model,
            "error": { "code": e.code(), "message": e.to_string() },
        });
        println!("{v}");
    }
    eprintln!("infer-server: {} refused: {e}", model.display());
}

pub fn predict(ort_lib: Option<&Path>, model: &Path, csv: &str) -> ExitCode {
    let reader: Box<dyn BufRead> = if csv == "-" {
        Box::new(std::io::stdin().lock())
    } else {
        match std::fs::File::open(csv) {
            Ok(f) => Box::new(std::io::BufReader::new(f)),
            Err(e) => {
                eprintln!("infer-server: cannot open {csv}: {e}");
                return ExitCode::from(EXIT_REFUSED);
            }
        }
    };
    let mut lines = reader.lines();
    let header = match lines.next() {
        Some(Ok(h)) => h,
        _ => {
            eprintln!("infer-server: {csv}: empty table (expected a header of feature names)");
            return ExitCode::from(EXIT_REFUSED);
        }
    };
    let schema = match FeatureSchema::parse(&header) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("infer-server: {csv}: bad header: {e}");
            return ExitCode::from(EXIT_REFUSED);
        }
    };
    let rt = match load_runtime(ort_lib, false) {
        Ok(rt) => rt,
        Err(code) => return code,
    };
    let mut engine = match StepEngine::load(rt, model, &schema, &SessionConfig::default()) {
        Ok(e) => e,
        Err(e) => {
            report_model_error(model, &e, false);
            return ExitCode::from(EXIT_REFUSED);
        }
    };
    let stdout = std::io::stdout();
    let mut out = std::io::BufWriter::new(stdout.lock());
    let mut row = vec![0f64; schema.len()];
    for (i, line) in lines.enumerate() {
        let line_no = i + 2;
        let line = match line {
            Ok(l) => l,
            Err(e) => {
                eprintln!("infer-server: {csv}: line {line_no}: {e}");
                return ExitCode::from(EXIT_REFUSED);
            }
        };
        if line.trim().is_empty() {
            continue;
        }
        let fields: Vec<&str> = line.split(',').collect();
        if fields.len() != schema.len() {
            eprintln!(
                "infer-server: {csv}: line {line_no} has {} fields, the header has {}",
                fields.len(),
                schema.len()
            );
            return ExitCode::from(EXIT_REFUSED);
        }
        for (slot, f) in row.iter_mut().zip(&fields) {
            match f.trim().parse::<f64>() {
                Ok(v) => *slot = v,
                Err(_) => {
                    eprintln!("infer-server: {csv}: line {line_no}: {f:?} is not a number");
                    return ExitCode::from(EXIT_REFUSED);
                }
            }
        }
        match engine.step(&row) {
            // Full f32 precision, round-trippable.
            Ok(force) => {
                let _ = writeln!(out, "{force:?}");
            }
            Err(e) => {
                eprintln!(
                    "infer-server: line {line_no}: {e}: {}",
                    engine.last_error_message()
                );
                return ExitCode::from(EXIT_REFUSED);
            }
        }
    }
    let _ = out.flush();
    ExitCode::SUCCESS
}
