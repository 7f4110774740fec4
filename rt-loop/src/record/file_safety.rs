//! What the recorder may replace, and how it creates its files: never anything but a regular
//! file. `--overwrite` means "replace the recording that is there", not "replace whatever is
//! there": a device (`/dev/full`, `/dev/null`), a directory, a FIFO or a socket is refused,
//! and a symlink is refused rather than followed or replaced (rt-loop may run as root, and a
//! symlink planted at the recording's path would otherwise aim its write anywhere). The checks
//! use `lstat` (`symlink_metadata`), and the `.partial` file is opened with `O_NOFOLLOW |
//! O_CREAT | O_EXCL` after a regular leftover is removed, so no symlink is ever followed.
use std::fs::{File, OpenOptions};
use std::io::ErrorKind;
use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
use std::path::Path;

/// What sits at a path, in words ("a symlink", "a character device", ...).
fn kind(ft: &std::fs::FileType) -> &'static str {
    if ft.is_symlink() {
        "a symlink"
    } else if ft.is_dir() {
        "a directory"
    } else if ft.is_char_device() {
        "a character device"
    } else if ft.is_block_device() {
        "a block device"
    } else if ft.is_fifo() {
        "a FIFO"
    } else if ft.is_socket() {
        "a socket"
    } else {
        "not a regular file"
    }
}

/// Refuses `path` unless nothing is there or it is a regular file (checked without following
/// a symlink). `what` names the file in the error ("recording", "sidecar").
pub fn check_replaceable(path: &Path, what: &str) -> anyhow::Result<()> {
    match std::fs::symlink_metadata(path) {
        Err(e) if e.kind() == ErrorKind::NotFound => Ok(()),
        Err(e) => anyhow::bail!("cannot check the {what} path {}: {e}", path.display()),
        Ok(m) if m.file_type().is_file() => Ok(()),
        Ok(m) => anyhow::bail!(
            "{} is {}, not a regular file: the {what} never replaces it, even with --overwrite \
             (choose a path for a new file)",
            path.display(),
            kind(&m.file_type())
        ),
    }
}

/// Creates `path` (the `.partial` file) fresh: a regular leftover of an earlier run is removed,
/// anything else refused, and the new file is opened without following a symlink and only if
/// it does not exist (a symlink planted in between makes the open fail, never redirects it).
pub fn create_new(path: &Path, what: &str) -> anyhow::Result<File> {
    check_replaceable(path, what)?;
    match std::fs::remove_file(path) {
        Ok(()) => {}
        Err(e) if e.kind() == ErrorKind::NotFound => {}
        Err(e) => anyhow::bail!("cannot remove the old {}: {e}", path.display()),
    }
    OpenOptions::new()
        .write(true)
        .create_new(true)
        .custom_flags(libc::O_NOFOLLOW)
        .mode(0o644)
        .open(path)
        .map_err(|e| anyhow::anyhow!("cannot create the {what} {}: {e}", path.display()))
}

/// Renames the finished `tmp` onto `path` after checking again what `path` is now (something
/// may have appeared during the run).
pub fn replace(tmp: &Path, path: &Path, what: &str) -> anyhow::Result<()> {
    check_replaceable(path, what)?;
    std::fs::rename(tmp, path)
        .map_err(|e| anyhow::anyhow!("cannot rename {} to {}: {e}", tmp.display(), path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_regular_files_are_replaced() {
        let dir = std::env::temp_dir().join(format!("rt-loop-file-safety-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let regular = dir.join("old.parquet");
        std::fs::write(&regular, b"old").unwrap();
        assert!(check_replaceable(&regular, "recording").is_ok());
        assert!(check_replaceable(&dir.join("absent"), "recording").is_ok());
        let link = dir.join("link");
        std::os::unix::fs::symlink(&regular, &link).unwrap();
        let dangling = dir.join("dangling");
        std::os::unix::fs::symlink(dir.join("nowhere"), &dangling).unwrap();
        let fifo = dir.join("fifo");
        let c = std::ffi::CString::new(fifo.as_os_str().as_encoded_bytes()).unwrap();
        // SAFETY: a valid NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        for (p, word) in [
            (&link, "symlink"),
            (&dangling, "symlink"),
            (&dir, "directory"),
            (&fifo, "FIFO"),
            (&std::path::PathBuf::from("/dev/null"), "character device"),
        ] {
            let e = check_replaceable(p, "recording").unwrap_err().to_string();
            assert!(e.contains(word) && e.contains("not a regular file"), "{e}");
            assert!(create_new(p, "recording").is_err(), "{}", p.display());
        }
        // The symlink's target is untouched by the refused create.
        assert_eq!(std::fs::read(&regular).unwrap(), b"old");
        assert!(std::fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink());
        let f = create_new(&regular, "recording").unwrap();
        drop(f);
        assert_eq!(std::fs::read(&regular).unwrap(), b"");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
