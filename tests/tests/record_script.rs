//! `scripts/record-dataset.sh` when a recording run stops before its end (a position-limit
//! stop, a board fault, a full disk): the script must stop with a clear message, and the
//! partial file must not pass for a recording, or the next run would skip it as done and train
//! on half a programme.
//!
//! rt-loop is replaced by a small script through the recording scripts' own hook
//! (`HAPTICS_RT_LOOP`, record-lib.sh): it writes the file `--record` names, prints rt-loop's
//! stop line, and exits as the real one does after an unplanned stop. What is tested is the
//! recording script's handling; the turn that keeps soft objects off the limit is
//! rt-loop/tests/cli.rs's.

use haptics_system_tests::{repo_root, temp_dir};
use std::os::unix::fs::PermissionsExt;
use std::process::Command;

/// A stand-in rt-loop: writes `--record`'s file, then exits with `code` (1: stopped early).
fn fake_rt_loop(dir: &std::path::Path, code: i32) -> std::path::PathBuf {
    let path = dir.join(format!("rt-loop-exit-{code}"));
    let body = format!(
        "#!/bin/bash\nwhile [ $# -gt 0 ]; do [ \"$1\" = --record ] && out=$2; shift; done\n\
         echo rows > \"$out\"\n\
         echo 'rt-loop: abstraction (lockstep clock): 10 steps, stop: position-limit' >&2\n\
         exit {code}\n"
    );
    std::fs::write(&path, body).unwrap();
    std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o755)).unwrap();
    path
}

fn record(fake: &std::path::Path, out: &std::path::Path) -> std::process::Output {
    Command::new("bash")
        .arg(repo_root().join("scripts/record-dataset.sh"))
        .arg(out)
        .env("HAPTICS_RT_LOOP", fake)
        .output()
        .unwrap()
}

#[test]
fn a_recording_that_stops_early_is_kept_aside_and_recorded_again() {
    let dir = temp_dir("record-script");
    let out = dir.join("dataset");
    let o = record(&fake_rt_loop(&dir, 1), &out);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("stop: position-limit"),
        "rt-loop's own line: {err}"
    );
    assert!(
        err.contains("record-dataset: train_0.8 did not finish (rt-loop exit 1"),
        "{err}"
    );
    assert!(
        !out.join("train_0.8.parquet").exists(),
        "a partial run passed for a recording"
    );
    assert!(
        out.join(".train_0.8.partial.parquet").exists(),
        "its rows are kept aside"
    );
    assert!(
        !out.join("train_1.8.parquet").exists(),
        "the script went on"
    );
    // the next run records it again instead of skipping it, then goes on
    let o = record(&fake_rt_loop(&dir, 0), &out);
    let err = String::from_utf8_lossy(&o.stderr);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{err}");
    assert!(
        !text.contains("train_0.8.parquet exists, skipped"),
        "{text}"
    );
    for name in [
        "train_0.8",
        "train_6.2",
        "test_2.1",
        "validation_5.0",
        "train_air",
    ] {
        assert!(
            out.join(format!("{name}.parquet")).exists(),
            "{name}: {text}"
        );
    }
}
