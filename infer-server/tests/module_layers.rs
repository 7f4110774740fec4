//! The layers of infer-server's own modules (src/lib.rs, "Layout"): `model` names nothing above
//! it, `serving` names `model` but not `control` or the process (`app`, `cli`, `commands`);
//! `control` may name both. A lower layer that names a higher one makes a cycle that the
//! compiler allows within one crate, so it is checked here, on the sources as they are.

use std::path::Path;

/// Every `crate::X` path a source file names (code, `use` lines and doc links alike).
fn named_modules(text: &str) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let mut rest = line;
        while let Some(i) = rest.find("crate::") {
            let after = &rest[i + "crate::".len()..];
            let name: String = after
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                .collect();
            out.push((n + 1, name));
            rest = after;
        }
    }
    out
}

/// The violations in folder `layer` (under src/): paths to any of `above`.
fn violations(layer: &str, above: &[&str]) -> Vec<String> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("src")
        .join(layer);
    let mut found = Vec::new();
    let mut files = 0;
    for entry in std::fs::read_dir(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "rs") {
            files += 1;
            let text = std::fs::read_to_string(&path).unwrap();
            for (line, name) in named_modules(&text) {
                if above.contains(&name.as_str()) {
                    found.push(format!("{}:{line} names crate::{name}", path.display()));
                }
            }
        }
    }
    assert!(files > 0, "no sources in {}", dir.display());
    found
}

const PROCESS: [&str; 4] = ["app", "cli", "commands", "exit"];

#[test]
fn model_names_nothing_above_it() {
    let mut above = vec!["serving", "control"];
    above.extend(PROCESS);
    let v = violations("model", &above);
    assert!(
        v.is_empty(),
        "model names a higher layer:\n{}",
        v.join("\n")
    );
}

#[test]
fn serving_names_neither_control_nor_the_process() {
    let mut above = vec!["control"];
    above.extend(PROCESS);
    let v = violations("serving", &above);
    assert!(
        v.is_empty(),
        "serving names a higher layer:\n{}",
        v.join("\n")
    );
}

#[test]
fn control_names_not_the_process() {
    let v = violations("control", &PROCESS);
    assert!(v.is_empty(), "control names the process:\n{}", v.join("\n"));
}

#[test]
fn the_scanner_finds_every_path_on_a_line() {
    let found = named_modules("use crate::serving::x; // see [`crate::control::y`]\nno path");
    assert_eq!(
        found,
        vec![(1, "serving".to_string()), (1, "control".to_string())]
    );
}
