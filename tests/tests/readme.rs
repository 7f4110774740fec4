//! The README's documentation test: the commands of its `sh` blocks, taken from the README
//! itself, run as written, in order, against a live system started the way `scripts/up.sh`
//! starts it (rt-loop serve with the shadow run autostarted, infer-server serving a model of
//! the names up.sh trains), from a scratch copy of the working folder (`target/`, `.venv/`,
//! `docs/`, ... linked; `data/` and `models/` its own), so the README cannot go stale.
//!
//! The commands that take longer than a minute, or need what only up.sh makes (the recorded
//! dataset, the trained models), are listed in [`LONG`] with the reason: the test checks they
//! are still in the README and prints that it did not run them. A command the README gains is
//! run unless it is added there. Commands that run until Ctrl-C ([`UNTIL_INTERRUPTED`]) are
//! interrupted once they have printed, and must then exit 0.
//!
//! hapticctl finds the test's server as a user's finds up.sh's: through the environment
//! (`HAPTICS_ADDR`, `HAPTICS_INSTANCE`: the instance's connection file, where the server writes
//! one, holds its address and token), never through flags the README does not show.
//!
//! The checks that need no live system are in `tests/tests/docs_agree.rs`.

use haptics_system_tests::skip::skip;
use haptics_system_tests::{
    bin, bin_dir, instance, repo_root, shm_entries, start_infer_server, temp_dir,
    write_linear_model, Proc, TempDir,
};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

/// README commands not run here, each with why.
const LONG: &[(&str, &str)] = &[
    ("bash scripts/up.sh", "the system itself: this test starts it as up.sh does"),
    ("bash scripts/test.sh", "the test command, which runs this test"),
    ("bash scripts/fuzz.sh", "10 million executions per target"),
    (
        "bash scripts/record-dataset.sh",
        "30 s and 500 MB from nothing (up.sh has made the dataset; then it keeps the files)",
    ),
    (".venv/bin/haptics-train pipeline", "about 25 minutes"),
    (
        "target/release/hapticctl swap models/mine/rf_memory.onnx --as mine_rf_memory.onnx",
        "needs the models of the pipeline above, which is not run here",
    ),
    (
        ".venv/bin/haptics-train train --models rf:six && .venv/bin/haptics-train export --names rf_six",
        "needs the recorded dataset; about a minute",
    ),
    ("bash scripts/reproduction-study.sh", "about 2.5 minutes plus builds; needs trained models"),
    ("bash scripts/fidelity-study.sh", "records and trains from nothing: an hour"),
    ("bash scripts/record-ood.sh", "records the suite"),
    ("bash scripts/bench-loaded.sh", "a benchmark of several minutes"),
];

/// Commands (by a part of them) that run until Ctrl-C.
const UNTIL_INTERRUPTED: &[&str] = &["hapticctl status --watch", "hapticctl telemetry"];

/// A safety timeout per everyday command, not a speed goal (each takes under a minute on an idle
/// machine; the test prints the times): a loaded machine must not fail the test.
const EVERYDAY: Duration = Duration::from_secs(300);

/// The commands of the README's `sh` blocks, in order: comments dropped (a whole-line comment,
/// or from two spaces and `#` on), continuation lines joined, spaces collapsed.
fn readme_commands(readme: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut in_sh = false;
    let mut pending = String::new();
    for line in readme.lines() {
        let t = line.trim();
        if t.starts_with("```") {
            in_sh = !in_sh && t == "```sh";
            continue;
        }
        if !in_sh || t.starts_with('#') || t.is_empty() {
            continue;
        }
        let code = match line.find("  #") {
            Some(i) if !line[..i].contains('"') || line[..i].matches('"').count() % 2 == 0 => {
                &line[..i]
            }
            _ => line,
        };
        let code = code.trim();
        match code.strip_suffix('\\') {
            Some(head) => {
                pending.push_str(head);
                pending.push(' ');
            }
            None => {
                pending.push_str(code);
                out.push(pending.split_whitespace().collect::<Vec<_>>().join(" "));
                pending.clear();
            }
        }
    }
    out
}

#[test]
fn commands_are_extracted_as_a_shell_would_read_them() {
    let md = "text\n```sh\n# a comment\nfoo --a 1 \\\n    --b \"x  y\"   # says\nbar\n```\n```json\n{}\n```\n";
    assert_eq!(readme_commands(md), ["foo --a 1 --b \"x y\"", "bar"]);
}

/// The names the README's models have: those up.sh trains (HAPTICS_CANDIDATES' default, a spec
/// `algo:set` giving the file `algo_set`), with the feature sets they take.
fn up_sh_models() -> Vec<(String, Vec<&'static str>)> {
    let up = std::fs::read_to_string(repo_root().join("scripts/up.sh")).expect("scripts/up.sh");
    let line = up
        .lines()
        .find(|l| l.starts_with("candidates=${HAPTICS_CANDIDATES:-"))
        .expect("up.sh sets candidates from HAPTICS_CANDIDATES");
    let specs = line
        .trim_start_matches("candidates=${HAPTICS_CANDIDATES:-")
        .trim_end_matches('}');
    specs
        .split(',')
        .map(|spec| {
            let name = spec.replace(':', "_");
            // A linear stand-in over features each of these models takes (the README's commands
            // list, swap and serve them; what they predict is not what this test checks).
            let features = if name.ends_with("memory") {
                vec!["position_x", "velocity", "cycle_no"]
            } else {
                vec!["position_x", "velocity"]
            };
            (name, features)
        })
        .collect()
}

/// A scratch working folder: the repository's inputs linked, its own `data/` and `models/`.
fn scratch(models: &[(String, Vec<&'static str>)]) -> TempDir {
    let root = repo_root();
    let dir = temp_dir("readme");
    std::fs::create_dir_all(dir.join("target")).unwrap();
    std::os::unix::fs::symlink(bin_dir(), dir.join("target/release")).unwrap();
    for name in [
        "docs",
        "materials",
        "scripts",
        "train",
        ".venv",
        ".ort",
        "README.md",
    ] {
        if root.join(name).exists() {
            std::os::unix::fs::symlink(root.join(name), dir.join(name)).unwrap();
        }
    }
    std::fs::create_dir_all(dir.join("data")).unwrap();
    std::fs::create_dir_all(dir.join("models")).unwrap();
    for (name, features) in models {
        let w: Vec<f32> = features.iter().map(|_| 100.0).collect();
        write_linear_model(&dir.join(format!("models/{name}.onnx")), features, &w, 0.0);
    }
    dir
}

struct Live {
    dir: PathBuf,
    addr: String,
    inst: String,
}

impl Live {
    /// `bash -c CMD` in the scratch folder with the system's address in the environment.
    fn command(&self, cmd: &str) -> Command {
        let mut c = Command::new("bash");
        c.arg("-c")
            .arg(format!("cd '{}' && exec {cmd}", self.dir.display()))
            .env("HAPTICS_ADDR", format!("http://{}", self.addr))
            .env("HAPTICS_INSTANCE", &self.inst)
            .env("CARGO_TERM_COLOR", "never");
        c
    }

    /// Runs an everyday command to its end (at most [`EVERYDAY`]); (exit 0, output).
    fn run(&self, cmd: &str) -> (bool, String, Duration) {
        let t0 = Instant::now();
        let mut p = Proc::spawn(cmd, &mut self.command(cmd));
        let st = p.wait_exit(EVERYDAY);
        (st.success(), p.output(), t0.elapsed())
    }

    /// Runs a command that lasts until Ctrl-C: waits until its output is `ready`, then SIGINT.
    fn run_interrupted(&self, cmd: &str, ready: impl Fn(&str) -> bool) -> (bool, String, Duration) {
        let t0 = Instant::now();
        let mut p = Proc::spawn(cmd, &mut self.command(cmd));
        let end = Instant::now() + Duration::from_secs(20);
        while !ready(&p.output()) {
            assert!(
                Instant::now() < end && p.child.try_wait().unwrap().is_none(),
                "{cmd}: not ready within 20 s:\n{}",
                p.output()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
        p.signal(libc::SIGINT);
        let st = p.wait_exit(Duration::from_secs(10));
        (st.success(), p.output(), t0.elapsed())
    }

    fn status(&self) -> String {
        let (ok, out, _) = self.run("target/release/hapticctl status");
        assert!(ok, "hapticctl status: {out}");
        out
    }

    fn wait_status(&self, what: &str, f: impl Fn(&str) -> bool) -> String {
        let end = Instant::now() + Duration::from_secs(20);
        loop {
            let s = self.status();
            if f(&s) {
                return s;
            }
            assert!(Instant::now() < end, "{what}: last status\n{s}");
            std::thread::sleep(Duration::from_millis(200));
        }
    }
}

/// Telemetry sample lines in `hapticctl telemetry`'s output (a step number first).
fn samples(out: &str) -> usize {
    out.lines()
        .filter(|l| {
            let w: Vec<&str> = l.split_whitespace().collect();
            w.len() >= 9 && w[0].parse::<u64>().is_ok()
        })
        .count()
}

/// What each README command must show besides exiting 0, by a part of the command.
fn check_output(cmd: &str, out: &str, dir: &Path, models: &[(String, Vec<&'static str>)]) {
    if cmd.contains("hapticctl models") {
        // the columns the README's comment names: state, cost, reference steps checked
        let head = out.lines().next().unwrap_or("");
        for col in ["STATE", "COST", "REFERENCE"] {
            assert!(head.contains(col), "{cmd}: no {col} column\n{out}");
        }
        for (name, _) in models {
            assert!(out.contains(name.as_str()), "{cmd}: no {name}\n{out}");
        }
    } else if cmd.contains("hapticctl swap") {
        assert!(
            out.contains("is active from feature message"),
            "{cmd}: {out}"
        );
    } else if cmd.contains("hapticctl status") {
        assert!(
            out.contains("loop:        running") && out.contains("of the run"),
            "{cmd}: {out}"
        );
    } else if cmd.contains("experiment stop") {
        assert!(out.trim_end().ends_with("stopped"), "{cmd}: {out}");
    } else if cmd.contains("experiment start") {
        assert!(out.contains("started abstraction"), "{cmd}: {out}");
    } else if cmd.contains("hapticctl telemetry") {
        assert!(samples(out) >= 3, "{cmd}: too few samples\n{out}");
        // F_pred is NaN while no model predicts (abstraction): said once, in words
        let nan = out.lines().any(|l| l.contains("NaN"));
        let said = out.matches("F_pred is NaN while no model predicts").count();
        assert_eq!(said, usize::from(nan), "{cmd}: {out}");
    } else if cmd.contains("rt-loop run") {
        assert!(dir.join("data/my_run.parquet").is_file(), "{cmd}: {out}");
    } else if cmd.contains("haptics-train import") {
        assert!(!out.contains("warning"), "{cmd}: a unit was assumed\n{out}");
        for unit in [
            "time s (option)",
            "position mm (option)",
            "force mN (option)",
        ] {
            assert!(out.contains(unit), "{cmd}: {out}");
        }
    } else if cmd.contains("haptics-train pipeline") {
        assert!(out.contains("[pipeline] done"), "{cmd}: {out}");
    }
}

#[test]
fn readme_commands_run_as_written_against_a_live_system() {
    let root = repo_root();
    if !root.join(".venv/bin/haptics-train").is_file() {
        skip(".venv/bin/haptics-train is missing: run `bash scripts/setup.sh`");
        return;
    }
    for b in ["rt-loop", "infer-server", "hapticctl"] {
        bin(b); // panics with how to build it
    }
    let readme = std::fs::read_to_string(root.join("README.md")).expect("README.md");
    let commands = readme_commands(&readme);
    for (long, _) in LONG {
        assert!(
            commands.iter().any(|c| c == long),
            "LONG lists `{long}`, which the README no longer has: update the list"
        );
    }

    let models = up_sh_models();
    let dir = scratch(&models);
    // Served: the last candidate (the one up.sh's recommendation picked when this was written;
    // any of them would do), as up.sh serves `--model NAME.onnx`.
    let served = format!("{}.onnx", models.last().unwrap().0);
    let inst = instance("readme");
    // As scripts/up.sh: `rt-loop serve --clock realtime --instance I --autostart shadow` and
    // `infer-server serve --profile auto --instance I --models models --model M.onnx`, on free
    // ports, the loop at 1 kHz and parking to stay light on a shared machine.
    let mut lp = Proc::spawn(
        "rt-loop serve",
        Command::new(bin("rt-loop"))
            .args(["serve", "--clock", "realtime", "--instance", &inst])
            .args(["--autostart", "shadow", "--rate-hz", "1000"])
            .args(["--deadline-us", "900", "--wait", "park"]),
    );
    lp.wait_for("serving segment", Duration::from_secs(30));
    let (mut server, addr) = start_infer_server(&inst, &dir.join("models"), Some(&served));
    let live = Live {
        dir: dir.to_path_buf(),
        addr,
        inst: inst.clone(),
    };

    // The state up.sh leaves: the shadow run going, named the same everywhere.
    let model_line = format!("model:       {served}");
    live.wait_status("the autostarted shadow run with the served model", |s| {
        s.contains("experiment:  shadow") && s.contains(&model_line)
    });
    let (ok, out, _) = live.run("target/release/hapticctl experiment start abstraction --cycles 1");
    assert!(
        !ok && out.contains("already running (shadow)")
            && out.contains("hapticctl experiment stop"),
        "a start during the shadow run is refused, naming it: {out}"
    );

    let t0 = Instant::now();
    let mut ran = Vec::new();
    for cmd in &commands {
        if let Some((_, why)) = LONG.iter().find(|(l, _)| l == cmd) {
            eprintln!("readme: not run (long: {why}): {cmd}");
            continue;
        }
        let (ok, out, took) = match UNTIL_INTERRUPTED.iter().find(|u| cmd.contains(*u)) {
            Some(u) if u.contains("status") => {
                live.run_interrupted(cmd, |o| o.contains("recorder:"))
            }
            // the header, then three samples
            Some(_) => live.run_interrupted(cmd, |o| samples(o) >= 3),
            None => live.run(cmd),
        };
        assert!(ok, "README command failed: {cmd}\n{out}");
        check_output(cmd, &out, &dir, &models);
        eprintln!("readme: ok in {:.1} s: {cmd}", took.as_secs_f64());
        ran.push(cmd.clone());
        if cmd.contains("experiment start") {
            live.wait_status("the README's abstraction run", |s| {
                s.contains("experiment:  abstraction")
            });
        }
    }
    eprintln!(
        "readme: {} commands run in {:.1} s, {} long ones not run",
        ran.len(),
        t0.elapsed().as_secs_f64(),
        LONG.len()
    );
    assert!(ran.len() >= 8, "the README's everyday commands: {ran:?}");

    // The loop's log gives each run the settings it uses: the ramp for abstraction only.
    let log = lp.output();
    let runs: Vec<&str> = log.lines().filter(|l| l.contains(": run ")).collect();
    assert!(
        runs.iter()
            .any(|l| l.contains("Shadow (command") && !l.contains("ramp")),
        "the shadow run's log line: {runs:?}"
    );
    assert!(
        runs.iter()
            .any(|l| l.contains("Abstraction (command") && l.contains("ramp 2.1 N/s, 10 cycles")),
        "the README's abstraction run's log line: {runs:?}"
    );

    // Ctrl-C, as up.sh's: both end cleanly and leave no segment.
    server.signal(libc::SIGINT);
    lp.signal(libc::SIGINT);
    assert!(
        server.wait_exit(Duration::from_secs(15)).success(),
        "{}",
        server.output()
    );
    assert!(
        lp.wait_exit(Duration::from_secs(15)).success(),
        "{}",
        lp.output()
    );
    assert!(shm_entries(&inst).is_empty(), "{:?}", shm_entries(&inst));
}
