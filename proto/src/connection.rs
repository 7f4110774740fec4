//! The connection file: how a client of the owner finds infer-server and its token without
//! the person copying anything (docs/control-plane.md, "The connection file"). infer-server
//! writes it once it listens and removes it at a clean exit; hapticctl, the Python client and
//! the README's doc test read it.
//!
//! - Directory: `$XDG_RUNTIME_DIR/haptics` when `XDG_RUNTIME_DIR` is set, non-empty and an
//!   existing directory, else `/tmp/haptics-<uid>`. Created 0700; refused when it is not owned
//!   by the current user or group/other may enter it (another user could then read the token,
//!   or plant a file that sends this user's client, and its token, elsewhere).
//! - File: `<dir>/<instance>.json`, mode 0600, written atomically (temp file + rename).
//! - JSON: `{"instance", "pid", "grpc", "http", "token" (string or null), "page"}`.
use std::fs;
use std::io::Write;
use std::os::unix::fs::{DirBuilderExt, MetadataExt, OpenOptionsExt, PermissionsExt};
use std::path::{Path, PathBuf};

/// What infer-server writes and its clients read.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ConnectionInfo {
    pub instance: String,
    pub pid: u32,
    /// `http://HOST:PORT` of the gRPC server.
    pub grpc: String,
    /// `http://HOST:PORT` of the HTTP server.
    pub http: String,
    pub token: Option<String>,
    /// The page's address, with `#token=<token>` when there is one.
    pub page: String,
}

#[derive(Debug, thiserror::Error)]
pub enum ConnectionError {
    #[error("instance name {0:?}: only letters, digits, `.`, `_` and `-`, not starting with `.`")]
    BadInstance(String),
    #[error("{path}: {what}")]
    Unsafe { path: PathBuf, what: String },
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: not a connection file ({what})")]
    Malformed { path: PathBuf, what: String },
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> ConnectionError + '_ {
    move |source| ConnectionError::Io {
        path: path.to_path_buf(),
        source,
    }
}

impl ConnectionInfo {
    /// The page's address for `http` and `token`: `http://HOST:PORT/#token=<token>`.
    pub fn page_for(http: &str, token: Option<&str>) -> String {
        match token {
            Some(t) => format!("{http}/#token={t}"),
            None => format!("{http}/"),
        }
    }

    pub fn to_json(&self) -> String {
        // Keys in the agreed order (a person reads the file too).
        format!(
            "{{\"instance\": {}, \"pid\": {}, \"grpc\": {}, \"http\": {}, \"token\": {}, \"page\": {}}}",
            serde_json::Value::from(self.instance.as_str()),
            self.pid,
            serde_json::Value::from(self.grpc.as_str()),
            serde_json::Value::from(self.http.as_str()),
            self.token
                .as_deref()
                .map_or(serde_json::Value::Null, serde_json::Value::from),
            serde_json::Value::from(self.page.as_str()),
        )
    }

    /// Parses the file's JSON (other writers' whitespace, key order and extra keys accepted).
    pub fn from_json(text: &str) -> Result<Self, String> {
        let v: serde_json::Value = serde_json::from_str(text).map_err(|e| e.to_string())?;
        let string = |k: &str| {
            v.get(k)
                .and_then(|s| s.as_str())
                .map(String::from)
                .ok_or_else(|| format!("no string {k:?}"))
        };
        Ok(Self {
            instance: string("instance")?,
            pid: v
                .get("pid")
                .and_then(|p| p.as_u64())
                .and_then(|p| u32::try_from(p).ok())
                .ok_or("no pid")?,
            grpc: string("grpc")?,
            http: string("http")?,
            token: match v.get("token") {
                Some(serde_json::Value::String(t)) => Some(t.clone()),
                Some(serde_json::Value::Null) => None,
                _ => return Err("\"token\" is neither a string nor null".into()),
            },
            page: string("page")?,
        })
    }
}

/// The instance name as a file name: the segment's rules (letters, digits, `.`, `_`, `-`).
pub fn check_instance(instance: &str) -> Result<(), ConnectionError> {
    let ok = !instance.is_empty()
        && instance.len() <= 200
        && !instance.starts_with('.')
        && instance
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'.' | b'_' | b'-'));
    if ok {
        Ok(())
    } else {
        Err(ConnectionError::BadInstance(instance.to_string()))
    }
}

/// The directory, as resolved from the environment (not created, not checked).
pub fn dir() -> PathBuf {
    if let Some(xdg) = std::env::var_os("XDG_RUNTIME_DIR").filter(|v| !v.is_empty()) {
        let xdg = PathBuf::from(xdg);
        if xdg.is_dir() {
            return xdg.join("haptics");
        }
    }
    PathBuf::from(format!("/tmp/haptics-{}", current_uid()))
}

/// The file of `instance` (not checked).
pub fn path(instance: &str) -> Result<PathBuf, ConnectionError> {
    check_instance(instance)?;
    Ok(dir().join(format!("{instance}.json")))
}

/// The current user's id.
pub fn current_uid() -> u32 {
    // SAFETY: geteuid has no preconditions and cannot fail.
    unsafe { libc::geteuid() }
}

/// Refuses a directory that is a symlink, not a directory, not ours, or open to others.
fn check_dir(dir: &Path) -> Result<(), ConnectionError> {
    let meta = fs::symlink_metadata(dir).map_err(io(dir))?;
    let unsafe_dir = |what: String| ConnectionError::Unsafe {
        path: dir.to_path_buf(),
        what,
    };
    if !meta.file_type().is_dir() {
        return Err(unsafe_dir(
            "is not a directory (a symlink is refused too)".into(),
        ));
    }
    if meta.uid() != current_uid() {
        return Err(unsafe_dir(format!(
            "is owned by uid {}, not by this user (uid {}): refusing to trust it",
            meta.uid(),
            current_uid()
        )));
    }
    if meta.mode() & 0o077 != 0 {
        return Err(unsafe_dir(format!(
            "has mode {:o}: group or others may enter it; `chmod 700` it or remove it",
            meta.mode() & 0o777
        )));
    }
    Ok(())
}

/// Writes `info` to its file atomically (temp file 0600 in the same directory, then rename),
/// creating the directory 0700 first. Returns the file's path.
pub fn write(info: &ConnectionInfo) -> Result<PathBuf, ConnectionError> {
    let file = path(&info.instance)?;
    let dir = file
        .parent()
        .expect("the file is in a directory")
        .to_path_buf();
    match fs::DirBuilder::new().mode(0o700).create(&dir) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {}
        Err(e) => return Err(io(&dir)(e)),
    }
    check_dir(&dir)?;
    let tmp = dir.join(format!(
        ".{}.json.{}.tmp",
        info.instance,
        std::process::id()
    ));
    let _ = fs::remove_file(&tmp);
    let mut f = fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(0o600)
        .open(&tmp)
        .map_err(io(&tmp))?;
    f.set_permissions(fs::Permissions::from_mode(0o600))
        .and_then(|()| f.write_all(info.to_json().as_bytes()))
        .and_then(|()| f.write_all(b"\n"))
        .and_then(|()| f.sync_all())
        .map_err(io(&tmp))?;
    fs::rename(&tmp, &file).map_err(|e| {
        let _ = fs::remove_file(&tmp);
        io(&file)(e)
    })?;
    Ok(file)
}

/// Reads the file of `instance`: `Ok(None)` when there is none (no server, or an older one),
/// an error when the directory is not safe or the file is not a connection file.
pub fn read(instance: &str) -> Result<Option<ConnectionInfo>, ConnectionError> {
    let file = path(instance)?;
    let dir = file.parent().expect("the file is in a directory");
    match fs::symlink_metadata(dir) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        _ => check_dir(dir)?,
    }
    let text = match fs::read_to_string(&file) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(io(&file)(e)),
    };
    ConnectionInfo::from_json(&text)
        .map(Some)
        .map_err(|what| ConnectionError::Malformed { path: file, what })
}

/// Removes the file of `instance` when it is still the one process `pid` wrote (a newer
/// server of the same instance may have replaced it).
pub fn remove_if_owned(instance: &str, pid: u32) {
    if let (Ok(Some(info)), Ok(file)) = (read(instance), path(instance)) {
        if info.pid == pid {
            let _ = fs::remove_file(file);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn info(token: Option<&str>) -> ConnectionInfo {
        ConnectionInfo {
            instance: "default".into(),
            pid: 1234,
            grpc: "http://127.0.0.1:50051".into(),
            http: "http://127.0.0.1:8080".into(),
            token: token.map(String::from),
            page: ConnectionInfo::page_for("http://127.0.0.1:8080", token),
        }
    }

    #[test]
    fn json_round_trips_with_and_without_a_token() {
        for t in [Some("0123abcd"), None] {
            let i = info(t);
            assert_eq!(ConnectionInfo::from_json(&i.to_json()).unwrap(), i);
        }
        assert_eq!(
            info(Some("ab")).to_json(),
            r#"{"instance": "default", "pid": 1234, "grpc": "http://127.0.0.1:50051", "http": "http://127.0.0.1:8080", "token": "ab", "page": "http://127.0.0.1:8080/#token=ab"}"#
        );
        // Another writer's layout (Python's json.dump with indent) reads too.
        let pretty = "{\n  \"page\": \"p\",\n  \"token\": null,\n  \"http\": \"h\",\n  \"grpc\": \"g\",\n  \"pid\": 7,\n  \"instance\": \"x\",\n  \"extra\": true\n}\n";
        let i = ConnectionInfo::from_json(pretty).unwrap();
        assert_eq!((i.pid, i.token, i.grpc.as_str()), (7, None, "g"));
        for bad in ["", "[]", "{\"pid\": 1}", "{\"instance\": 3}"] {
            assert!(ConnectionInfo::from_json(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn instance_names_are_file_names() {
        for ok in ["default", "bench-2", "a.b_c"] {
            assert!(check_instance(ok).is_ok(), "{ok}");
        }
        for bad in ["", "../x", "a/b", ".hidden", "a b"] {
            assert!(check_instance(bad).is_err(), "{bad}");
        }
    }
}
