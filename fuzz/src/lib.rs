//! What several fuzz targets share: a scratch file for the readers that take a path.

use std::path::PathBuf;

/// A per-process scratch file, on tmpfs when there is one (it is rewritten on every
/// execution): in `$HAPTICS_FUZZ_SCRATCH` when set (scripts/fuzz.sh sets it to a directory it
/// removes at its end, since libFuzzer exits without running destructors), else in /dev/shm.
pub fn scratch(name: &str) -> PathBuf {
    if let Some(dir) = std::env::var_os("HAPTICS_FUZZ_SCRATCH").filter(|d| !d.is_empty()) {
        return PathBuf::from(dir).join(format!("{}-{name}", std::process::id()));
    }
    let shm = PathBuf::from("/dev/shm");
    let dir = if shm.is_dir() {
        shm
    } else {
        std::env::temp_dir()
    };
    dir.join(format!("haptics-fuzz-{}-{name}", std::process::id()))
}
