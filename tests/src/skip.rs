//! A test that cannot run, said out loud: under `CI=true` it FAILS (a missing dependency must
//! never pass on CI); elsewhere it is an explicit skip, printed and appended as one line to the
//! file `$HAPTICS_SKIP_LOG` names, which `scripts/test.sh` counts into its summary. libtest has
//! no "skipped" outcome, so the test then returns and libtest shows it as passed: the log is
//! what tells the two apart.
//!
//! One file for every crate's tests: the system tests use it as `haptics_system_tests::skip`,
//! the others include it with `#[path = "../../tests/src/skip.rs"] mod skip;`.

use std::io::Write;

/// Records that the calling test cannot run because of `reason` (the caller returns next), or
/// panics under `CI=true`. The test's name is libtest's name for the thread running it.
pub fn skip(reason: &str) {
    let current = std::thread::current();
    let test = current.name().unwrap_or("unnamed test");
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!("{test} cannot run, and CI=true makes that a failure: {reason}");
    }
    eprintln!("SKIPPED {test}: {reason}");
    if let Some(path) = std::env::var_os("HAPTICS_SKIP_LOG") {
        let line = format!("{test}: {reason}\n");
        let written = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .and_then(|mut f| f.write_all(line.as_bytes()));
        if let Err(e) = written {
            panic!("cannot record the skip in {}: {e}", path.to_string_lossy());
        }
    }
}
