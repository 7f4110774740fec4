//! The segment's name: a validated POSIX shared-memory name (`/haptics-<instance>`), and the
//! path of the creator's instance lock derived from it.

use std::path::PathBuf;

use super::error::Error;

/// A validated POSIX shared-memory name: `/` then 1..=200 of `[A-Za-z0-9._-]`.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct SegmentName(String);

impl SegmentName {
    /// The segment of loop instance `instance`: `/haptics-<instance>`.
    pub fn for_instance(instance: &str) -> Result<SegmentName, Error> {
        SegmentName::new(&format!("/haptics-{instance}"))
    }

    /// An explicit name (must start with `/`).
    pub fn new(name: &str) -> Result<SegmentName, Error> {
        let bad = |reason| {
            Err(Error::InvalidName {
                name: name.to_owned(),
                reason,
            })
        };
        let Some(rest) = name.strip_prefix('/') else {
            return bad("must start with `/`");
        };
        if rest.is_empty() || rest.len() > 200 {
            return bad("must have 1 to 200 characters after `/`");
        }
        if !rest
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'.' | b'_' | b'-'))
        {
            return bad("only letters, digits, `.`, `_` and `-` are allowed after `/`");
        }
        if rest.starts_with('.') {
            return bad("must not start with `.` after `/`");
        }
        Ok(SegmentName(name.to_owned()))
    }

    pub fn as_str(&self) -> &str {
        &self.0
    }

    /// The creator's instance lock file (a dot file, so it never collides with a segment).
    pub fn lock_path(&self) -> PathBuf {
        let dir = if std::path::Path::new("/dev/shm").is_dir() {
            PathBuf::from("/dev/shm")
        } else {
            std::env::temp_dir()
        };
        dir.join(format!(".shm-ring.{}.lock", &self.0[1..]))
    }
}

impl std::fmt::Display for SegmentName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}
