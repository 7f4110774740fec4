//! Thin wrappers over the Linux calls the segment needs: POSIX shared memory, `mmap`,
//! open-file-description (OFD) byte-range locks and `/proc` process start times.
//!
//! Why OFD locks for liveness: the kernel releases them when the last descriptor of the open
//! file description closes, which includes the process dying by SIGKILL, so "is the peer
//! alive?" needs no heartbeat thread. Unlike classic POSIX `fcntl` locks they belong to the
//! open description, not the process, so two handles in one process (tests) still conflict,
//! and unlike `flock` they lock byte ranges, so one descriptor carries a lock per side.

use std::ffi::CString;
use std::fs::File;
use std::io;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::ptr::NonNull;

fn cvt(rc: libc::c_int) -> io::Result<libc::c_int> {
    if rc == -1 {
        Err(io::Error::last_os_error())
    } else {
        Ok(rc)
    }
}

/// `shm_open` with `O_CLOEXEC` (a spawned child must not inherit the fd, or it would keep
/// our liveness locks alive after we die).
pub(crate) fn shm_open(name: &str, create_exclusive: bool) -> io::Result<OwnedFd> {
    let cname = CString::new(name).map_err(|_| io::Error::from(io::ErrorKind::InvalidInput))?;
    let mut flags = libc::O_RDWR | libc::O_CLOEXEC;
    if create_exclusive {
        flags |= libc::O_CREAT | libc::O_EXCL;
    }
    // SAFETY: valid NUL-terminated name; the returned fd is owned by us alone.
    let fd = cvt(unsafe { libc::shm_open(cname.as_ptr(), flags, 0o600 as libc::mode_t) })?;
    // SAFETY: `fd` was just opened and is not owned by anything else.
    Ok(unsafe { OwnedFd::from_raw_fd(fd) })
}

pub(crate) fn shm_unlink(name: &str) -> io::Result<()> {
    let cname = CString::new(name).map_err(|_| io::Error::from(io::ErrorKind::InvalidInput))?;
    // SAFETY: valid NUL-terminated name.
    cvt(unsafe { libc::shm_unlink(cname.as_ptr()) }).map(|_| ())
}

/// Size, owner and mode of an open file.
pub(crate) struct FileStat {
    pub(crate) size: u64,
    pub(crate) uid: u32,
    pub(crate) mode: u32,
}

pub(crate) fn fstat(fd: &OwnedFd) -> io::Result<FileStat> {
    // SAFETY: `stat` is plain data; fstat fills it on success.
    let mut st: libc::stat = unsafe { std::mem::zeroed() };
    cvt(unsafe { libc::fstat(fd.as_raw_fd(), &mut st) })?;
    Ok(FileStat {
        size: st.st_size as u64,
        uid: st.st_uid,
        mode: st.st_mode & 0o7777,
    })
}

pub(crate) fn set_mode_0600(fd: &OwnedFd) -> io::Result<()> {
    // SAFETY: plain syscall on an fd we own.
    cvt(unsafe { libc::fchmod(fd.as_raw_fd(), 0o600) }).map(|_| ())
}

pub(crate) fn ftruncate(fd: &OwnedFd, len: u64) -> io::Result<()> {
    // SAFETY: plain syscall on an fd we own.
    cvt(unsafe { libc::ftruncate(fd.as_raw_fd(), len as libc::off_t) }).map(|_| ())
}

pub(crate) fn euid() -> u32 {
    // SAFETY: geteuid cannot fail.
    unsafe { libc::geteuid() }
}

/// A shared, read-write mapping of a whole file; unmapped on drop.
pub(crate) struct Mapping {
    ptr: NonNull<u8>,
    len: usize,
}

// SAFETY: the mapping is plain memory, only accessed through atomics (see `segment`).
unsafe impl Send for Mapping {}
unsafe impl Sync for Mapping {}

impl Mapping {
    /// Maps `len` bytes of `fd` shared. `MAP_POPULATE` faults every page in now, so the
    /// real-time loop never takes a page fault on first touch of a slot.
    pub(crate) fn map(fd: &OwnedFd, len: usize) -> io::Result<Mapping> {
        // SAFETY: a fresh mapping at a kernel-chosen address; no existing memory is affected.
        let ptr = unsafe {
            libc::mmap(
                std::ptr::null_mut(),
                len,
                libc::PROT_READ | libc::PROT_WRITE,
                libc::MAP_SHARED | libc::MAP_POPULATE,
                fd.as_raw_fd(),
                0,
            )
        };
        if ptr == libc::MAP_FAILED {
            return Err(io::Error::last_os_error());
        }
        let ptr =
            NonNull::new(ptr.cast::<u8>()).ok_or_else(|| io::Error::from(io::ErrorKind::Other))?;
        Ok(Mapping { ptr, len })
    }

    pub(crate) fn base(&self) -> NonNull<u8> {
        self.ptr
    }
}

impl Drop for Mapping {
    fn drop(&mut self) {
        // SAFETY: we own the mapping; nothing borrows it any more (owners hold an Arc).
        unsafe {
            libc::munmap(self.ptr.as_ptr().cast(), self.len);
        }
    }
}

fn flock_struct(kind: libc::c_short, byte: u64) -> libc::flock {
    // SAFETY: plain data.
    let mut fl: libc::flock = unsafe { std::mem::zeroed() };
    fl.l_type = kind;
    fl.l_whence = libc::SEEK_SET as libc::c_short;
    fl.l_start = byte as libc::off_t;
    fl.l_len = 1;
    fl.l_pid = 0; // must be 0 for OFD locks
    fl
}

/// Tries to take an exclusive OFD lock on one byte; `Ok(false)` if someone else holds it.
pub(crate) fn try_lock_byte(fd: &impl AsRawFd, byte: u64) -> io::Result<bool> {
    let fl = flock_struct(libc::F_WRLCK as libc::c_short, byte);
    // SAFETY: valid fd and flock struct.
    match cvt(unsafe { libc::fcntl(fd.as_raw_fd(), libc::F_OFD_SETLK, &fl) }) {
        Ok(_) => Ok(true),
        Err(e) if matches!(e.raw_os_error(), Some(libc::EAGAIN) | Some(libc::EACCES)) => Ok(false),
        Err(e) => Err(e),
    }
}

/// Releases our OFD lock on one byte (a loop that supersedes its segment: the server's next
/// liveness probe of the old one says "gone", so it re-attaches to the new one).
pub(crate) fn unlock_byte(fd: &impl AsRawFd, byte: u64) -> io::Result<()> {
    let fl = flock_struct(libc::F_UNLCK as libc::c_short, byte);
    // SAFETY: valid fd and flock struct.
    cvt(unsafe { libc::fcntl(fd.as_raw_fd(), libc::F_OFD_SETLK, &fl) }).map(|_| ())
}

/// Whether another open file description holds a lock on `byte` (asks without taking it,
/// so probing never disturbs the holder or a newcomer racing for it).
pub(crate) fn byte_is_locked(fd: &impl AsRawFd, byte: u64) -> io::Result<bool> {
    let mut fl = flock_struct(libc::F_WRLCK as libc::c_short, byte);
    // SAFETY: valid fd and flock struct; F_OFD_GETLK writes into it.
    cvt(unsafe { libc::fcntl(fd.as_raw_fd(), libc::F_OFD_GETLK, &mut fl) })?;
    Ok(fl.l_type != libc::F_UNLCK as libc::c_short)
}

/// Opens (creating, mode 0600) a lock file.
pub(crate) fn open_lock_file(path: &std::path::Path) -> io::Result<File> {
    use std::os::unix::fs::OpenOptionsExt;
    std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .mode(0o600)
        .open(path)
}

/// This process's id.
pub(crate) fn pid() -> u32 {
    std::process::id()
}

/// Start time of process `pid` in clock ticks since boot (`/proc/<pid>/stat` field 22):
/// with the pid it names a process uniquely, even after the pid is reused.
pub(crate) fn process_start_ticks(pid: u32) -> Option<u64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // The command name (field 2) is in parentheses and may contain spaces: skip past it.
    let after = &stat[stat.rfind(')')? + 1..];
    after.split_whitespace().nth(19)?.parse().ok()
}

/// Whether the process `pid` that started at `start_ticks` still runs (not a zombie).
pub(crate) fn process_alive(pid: u32, start_ticks: u64) -> bool {
    let Ok(stat) = std::fs::read_to_string(format!("/proc/{pid}/stat")) else {
        return false;
    };
    let Some(close) = stat.rfind(')') else {
        return false;
    };
    let mut fields = stat[close + 1..].split_whitespace();
    let state = fields.next().unwrap_or("X");
    let start = fields.nth(18).and_then(|s| s.parse::<u64>().ok());
    state != "Z" && state != "X" && start == Some(start_ticks)
}
