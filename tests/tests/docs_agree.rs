//! Every statement the docs make that the code can produce is checked against the code: the
//! documents stand on their own (nothing points outside the repository), the defaults, file
//! counts, metric descriptions and model names they quote are the code's, every flag of every
//! `--help` says what it does, and the scripts' `--help` is plain text.
//!
//! The README's commands themselves run in `tests/tests/readme.rs`.

use haptics_system_tests::{bin, repo_root};
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::Command;

fn read(rel: &str) -> String {
    std::fs::read_to_string(repo_root().join(rel)).unwrap_or_else(|e| panic!("{rel}: {e}"))
}

/// The text after `prefix` up to the first `end` (or the end of the line).
fn after<'a>(text: &'a str, prefix: &str, end: char) -> Option<&'a str> {
    let i = text.find(prefix)? + prefix.len();
    let rest = &text[i..];
    let j = rest.find([end, '\n']).unwrap_or(rest.len());
    Some(&rest[..j])
}

/// The repository's files: `git ls-files` (tracked and untracked, not ignored), else a walk
/// that leaves out build outputs and installs.
fn repository_files() -> Vec<PathBuf> {
    let root = repo_root();
    let git = Command::new("git")
        .args([
            "ls-files",
            "-z",
            "--cached",
            "--others",
            "--exclude-standard",
        ])
        .current_dir(&root)
        .output();
    if let Ok(o) = git {
        if o.status.success() {
            return o
                .stdout
                .split(|b| *b == 0)
                .filter(|p| !p.is_empty())
                .map(|p| root.join(String::from_utf8_lossy(p).as_ref()))
                .filter(|p| p.is_file())
                .collect();
        }
    }
    fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
        const NOT_WALKED: &[&str] = &[
            ".git",
            "target",
            "node_modules",
            ".venv",
            ".ort",
            "data",
            "models",
            "dist",
        ];
        for e in std::fs::read_dir(dir).into_iter().flatten().flatten() {
            let p = e.path();
            let name = e.file_name().to_string_lossy().into_owned();
            if p.is_dir() {
                if !NOT_WALKED.contains(&name.as_str()) {
                    walk(&p, out);
                }
            } else {
                out.push(p);
            }
        }
    }
    let mut out = Vec::new();
    walk(&root, &mut out);
    out
}

#[test]
fn no_document_points_outside_the_repository() {
    // Spelled in pieces so that this file does not match itself.
    let outside = [
        format!("../{}/", "shared"),
        format!("{} section", "SPEC"),
        format!("{}.md", "SPEC"),
        format!("{}.md", "DESIGN"),
    ];
    let root = repo_root();
    let mut found = Vec::new();
    let files = repository_files();
    for path in &files {
        let Ok(text) = std::fs::read_to_string(path) else {
            continue; // not text
        };
        for (n, line) in text.lines().enumerate() {
            for o in &outside {
                if line.contains(o.as_str()) {
                    let rel = path.strip_prefix(&root).unwrap_or(path);
                    found.push(format!("{}:{}: {o}", rel.display(), n + 1));
                }
            }
        }
    }
    assert!(files.len() > 100, "found only {} files", files.len());
    assert!(
        found.is_empty(),
        "documents point outside the repository (write it into docs/physics.md or \
         docs/features.md and point there):\n{}",
        found.join("\n")
    );
}

#[test]
fn record_dataset_default_decimation_and_file_count_are_the_scripts() {
    let lib = read("scripts/record-lib.sh");
    let decimate = after(&lib, "decimate=${DECIMATE:-", '}').expect("record-lib.sh's default");
    let script = read("scripts/record-dataset.sh");
    assert!(
        script.contains(&format!("DECIMATE (default {decimate}:")),
        "record-dataset.sh's header quotes another DECIMATE default than {decimate}"
    );
    let train = read("docs/train.md");
    assert!(
        train.contains(&format!("defaults to DECIMATE={decimate}")),
        "docs/train.md quotes another DECIMATE default than {decimate}"
    );
    let names: Vec<&str> = script
        .lines()
        .filter_map(|l| {
            l.strip_prefix("record ")
                .or_else(|| l.strip_prefix("record_run "))
        })
        .filter_map(|l| l.split_whitespace().next())
        .collect();
    let words = [
        "zero", "one", "two", "three", "four", "five", "six", "seven", "eight",
    ];
    let count = words[names.len()];
    assert!(
        script.contains(&format!("for the {count} files")),
        "record-dataset.sh records {} files ({names:?}); its header says otherwise",
        names.len()
    );
    let rt = read("docs/rt-loop.md");
    for name in &names {
        assert!(
            rt.lines().any(|l| l.starts_with(&format!("| {name}"))),
            "docs/rt-loop.md's dataset table has no row for {name}"
        );
    }
}

#[test]
fn metrics_are_documented_with_the_codes_descriptions() {
    let code = read("infer-server/control-plane/src/http/metrics.rs");
    let doc = read("docs/control-plane.md");
    let mut n = 0;
    let mut rest = code.as_str();
    // m.gauge( / m.counter( / m.counter_with( / m.latency(  "name",  "help"
    while let Some(i) = rest.find("\"haptics_") {
        let tail = &rest[i + 1..];
        let name_end = tail.find('"').unwrap();
        let name = &tail[..name_end];
        let after_name = &tail[name_end + 1..];
        let help_start = after_name.find('"').unwrap() + 1;
        let help_len = after_name[help_start..].find('"').unwrap();
        let help = &after_name[help_start..help_start + help_len];
        let row = format!("| `{name}` | {help} |");
        assert!(
            doc.contains(&row),
            "docs/control-plane.md lacks the row `{row}` (the metric's # HELP text)"
        );
        n += 1;
        rest = &after_name[help_start + help_len..];
    }
    assert!(n >= 20, "found {n} metrics in metrics.rs");
}

/// The models named in examples exist after the README's own commands: those scripts/up.sh
/// trains (HAPTICS_CANDIDATES' default) and those the README trains and exports itself.
#[test]
fn model_names_in_examples_are_models_the_commands_make() {
    let up = read("scripts/up.sh");
    let candidates = after(&up, "candidates=${HAPTICS_CANDIDATES:-", '}').expect("up.sh");
    let mut made: BTreeSet<String> = candidates.split(',').map(|s| s.replace(':', "_")).collect();
    let readme = read("README.md");
    for w in readme.split("--names ").skip(1) {
        made.insert(w.split_whitespace().next().unwrap().to_string());
    }
    // A pipeline's models, as DIR/NAME: its `--models SPECS` into its `--models-dir DIR`.
    for w in readme.split("haptics-train pipeline ").skip(1) {
        let cmd = w
            .split("\n\n")
            .next()
            .unwrap_or_default()
            .replace("\\\n", " ");
        let value = |flag: &str| {
            cmd.split(flag)
                .nth(1)
                .and_then(|v| v.split_whitespace().next())
                .map(str::to_string)
        };
        if let (Some(specs), Some(dir)) = (value("--models "), value("--models-dir ")) {
            for spec in specs.split(',') {
                made.insert(format!("{dir}/{}", spec.replace(':', "_")));
            }
        }
    }
    let mut named = Vec::new();
    for w in readme.split("hapticctl swap ").skip(1) {
        named.push((
            "README.md",
            w.split_whitespace().next().unwrap().to_string(),
        ));
    }
    let help = read("hapticctl/src/main.rs");
    for w in help.split("hapticctl swap ").skip(1) {
        let name = w.split_whitespace().next().unwrap();
        if !name.contains('/') {
            named.push(("hapticctl's --help", name.to_string()));
        }
    }
    assert!(named.len() >= 2, "{named:?}");
    for (where_, name) in named {
        let stem = name.trim_end_matches(".onnx");
        assert!(
            made.contains(stem),
            "{where_} swaps to {name}, which no command of the README makes ({made:?})"
        );
    }
    let bench = read("scripts/bench-loaded.sh");
    let default = after(&bench, "model=${HAPTICS_MODEL:-", '}').expect("bench-loaded.sh");
    match default.strip_prefix("${recommended:-") {
        // The recommendation's model, else a fixed one: the header says both.
        Some(fallback) => assert!(
            bench.contains("HAPTICS_MODEL (default: the model")
                && bench.contains("models/recommendation.json recommends, else")
                && bench.contains(&format!("else {fallback})")),
            "bench-loaded.sh's header does not say its default model (the recommendation, else {fallback})"
        ),
        None => assert!(
            bench.contains(&format!("HAPTICS_MODEL (default {default}")),
            "bench-loaded.sh's header names another default model than {default}"
        ),
    }
}

#[test]
fn up_sh_settings_are_documented_with_their_defaults() {
    let up = read("scripts/up.sh");
    let readme = read("README.md");
    let mut n = 0;
    for part in up.split("${HAPTICS_").skip(1) {
        let Some((var, rest)) = part.split_once(":-") else {
            continue;
        };
        let default = &rest[..rest.find('}').unwrap()];
        let var = format!("HAPTICS_{var}");
        let row = readme
            .lines()
            .find(|l| l.starts_with(&format!("| `{var}` |")))
            .unwrap_or_else(|| panic!("README.md's up.sh settings table has no row for {var}"));
        if !default.is_empty() {
            assert!(
                row.contains(&format!("| `{default}` |")),
                "README.md gives {var} another default than up.sh's {default}: {row}"
            );
        }
        assert!(
            up.contains(&format!("#   {var} ")),
            "up.sh's --help does not describe {var}"
        );
        n += 1;
    }
    assert!(n >= 7, "found {n} settings in up.sh");
}

/// The options of a clap `--help` text without a description.
fn undescribed_options(help: &str) -> Vec<String> {
    let lines: Vec<&str> = help.lines().collect();
    let mut out = Vec::new();
    for (i, l) in lines.iter().enumerate() {
        let t = l.trim_start();
        if !(t.starts_with("--") || (t.starts_with('-') && t.chars().nth(2) == Some(','))) {
            continue;
        }
        let indent = l.len() - t.len();
        // the description follows on the same line after two spaces, or on the next line,
        // indented deeper
        // (clap's "[default: ...]" and "[possible values: ...]" are not descriptions)
        let describes = |d: &str| !d.trim().is_empty() && !d.trim().starts_with('[');
        let same_line = t.split_once("  ").is_some_and(|(_, d)| describes(d));
        let next = lines.get(i + 1).copied().unwrap_or("");
        let next_indent = next.len() - next.trim_start().len();
        let next_line =
            describes(next) && next_indent > indent && !next.trim_start().starts_with('-');
        if !same_line && !next_line {
            out.push(t.to_string());
        }
    }
    out
}

fn help_of(binary: &str, args: &[&str]) -> String {
    let o = Command::new(bin(binary))
        .args(args)
        .arg("--help")
        .output()
        .expect("run --help");
    assert!(o.status.success(), "{binary} {args:?} --help");
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// The subcommands a clap help lists (the "Commands:" section), `help` left out.
fn subcommands(help: &str) -> Vec<String> {
    help.lines()
        .skip_while(|l| !l.starts_with("Commands:"))
        .skip(1)
        .take_while(|l| l.starts_with("  "))
        .filter_map(|l| l.split_whitespace().next())
        .filter(|c| *c != "help")
        .map(String::from)
        .collect()
}

#[test]
fn every_flag_of_every_help_has_a_description() {
    assert_eq!(
        undescribed_options(
            "Options:\n  --a  does a\n  --b <X>\n      --c\n          does c\n  --d <D>  [default: 1]\n"
        ),
        ["--b <X>", "--d <D>  [default: 1]"]
    );
    let mut missing = Vec::new();
    let mut checked = 0;
    for binary in ["rt-loop", "infer-server", "hapticctl"] {
        let mut todo = vec![Vec::<String>::new()];
        while let Some(path) = todo.pop() {
            let args: Vec<&str> = path.iter().map(String::as_str).collect();
            let help = help_of(binary, &args);
            for o in undescribed_options(&help) {
                missing.push(format!("{binary} {} {o}", args.join(" ")));
            }
            checked += 1;
            for sub in subcommands(&help) {
                let mut p = path.clone();
                p.push(sub);
                todo.push(p);
            }
        }
    }
    assert!(checked >= 15, "checked {checked} help texts");
    assert!(
        missing.is_empty(),
        "flags without a description:\n{}",
        missing.join("\n")
    );
}

#[test]
fn scripts_help_is_plain_text() {
    let root = repo_root();
    for script in [
        "up.sh",
        "record-dataset.sh",
        "record-ood.sh",
        "fidelity-study.sh",
        "fuzz.sh",
    ] {
        let o = Command::new("bash")
            .arg(root.join("scripts").join(script))
            .arg("--help")
            .output()
            .expect("bash");
        let text = String::from_utf8_lossy(&o.stdout);
        assert!(o.status.success(), "{script} --help: {text}");
        assert!(text.lines().count() >= 3, "{script} --help: {text}");
        for l in text.lines() {
            assert!(
                !l.starts_with('#') && !l.starts_with("set -"),
                "{script} --help prints a comment marker or code: {l:?}"
            );
        }
    }
}
