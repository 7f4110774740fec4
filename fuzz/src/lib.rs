//! What several fuzz targets share: a scratch file for the readers that take a path.

use std::path::PathBuf;

/// A per-process scratch file, on tmpfs when there is one (it is rewritten on every
/// execution).
pub fn scratch(name: &str) -> PathBuf {
    let shm = PathBuf::from("/dev/shm");
    let dir = if shm.is_dir() {
        shm
    } else {
        std::env::temp_dir()
    };
    dir.join(format!("haptics-fuzz-{}-{name}", std::process::id()))
}
