//! One way to stop, for both processes: SIGINT/SIGTERM (or a call, in tests) set a stop flag
//! and make an `eventfd` readable. Three kinds of code wait on it, each in its own way:
//!
//! - a real-time loop polls [`Shutdown::is_requested`] every step: one relaxed atomic load, no
//!   syscall, no lock;
//! - a plain thread blocks in [`Shutdown::wait`] / [`Shutdown::wait_timeout`] (`poll(2)` on the
//!   eventfd, no busy loop);
//! - async code awaits the eventfd: with tokio, register [`Shutdown::wait_fd`] (a duplicate per
//!   waiter: one runtime cannot register the same descriptor twice) with
//!   `AsyncFd::register_with_interest(fd, Interest::READABLE)` and await `readable()`, or
//!   `spawn_blocking(move || shutdown.wait())`.
//!
//! The eventfd is written once and never read, so it stays readable: every waiter, early or
//! late, sees the stop. The flag never goes back: a stopped process does not restart.
//!
//! [`Shutdown::new`] makes a private one (a server run in-process by a test, stopped with
//! [`Shutdown::request`]); [`install_signal_handlers`] returns the process's own, the one the
//! signal handler triggers, installing the handler the first time. The handler is
//! async-signal-safe: atomics and `write(2)` only (errno saved and restored around it).

use std::io;
use std::os::fd::{AsFd, AsRawFd, BorrowedFd, FromRawFd, OwnedFd, RawFd};
use std::sync::atomic::{AtomicBool, AtomicI32, AtomicPtr, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

struct Inner {
    requested: AtomicBool,
    /// The signal that asked for the stop (0: none, or a call).
    signal: AtomicI32,
    /// Readable once a stop was requested (never read, so it stays readable).
    event: OwnedFd,
}

impl Inner {
    /// Async-signal-safe: atomics and one `write(2)`.
    fn trigger(&self, signal: i32) {
        if signal != 0 {
            let _ = self
                .signal
                .compare_exchange(0, signal, Ordering::Relaxed, Ordering::Relaxed);
        }
        self.requested.store(true, Ordering::Release);
        let one: u64 = 1;
        // SAFETY: writes 8 bytes from a local to an eventfd we own. A full counter (EAGAIN,
        // after 2^64-2 stops) still leaves it readable, which is all that matters.
        unsafe {
            libc::write(
                self.event.as_raw_fd(),
                (&one as *const u64).cast(),
                std::mem::size_of::<u64>(),
            );
        }
    }
}

/// A stop request that can be polled, waited for, awaited and triggered; cheap to clone (every
/// clone is the same request).
#[derive(Clone)]
pub struct Shutdown {
    inner: Arc<Inner>,
}

impl std::fmt::Debug for Shutdown {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Shutdown")
            .field("requested", &self.is_requested())
            .field("signal", &self.signal())
            .finish()
    }
}

impl Shutdown {
    /// A fresh, private stop request (not tied to any signal).
    pub fn new() -> io::Result<Shutdown> {
        // SAFETY: plain syscall; the returned descriptor is ours alone.
        let fd = unsafe { libc::eventfd(0, libc::EFD_CLOEXEC | libc::EFD_NONBLOCK) };
        if fd < 0 {
            return Err(io::Error::last_os_error());
        }
        Ok(Shutdown {
            inner: Arc::new(Inner {
                requested: AtomicBool::new(false),
                signal: AtomicI32::new(0),
                // SAFETY: `fd` was just opened and is owned by nothing else.
                event: unsafe { OwnedFd::from_raw_fd(fd) },
            }),
        })
    }

    /// Whether a stop was requested. One relaxed atomic load: the real-time loop's per-step
    /// poll (no syscall, no lock, no allocation).
    #[inline]
    pub fn is_requested(&self) -> bool {
        self.inner.requested.load(Ordering::Relaxed)
    }

    /// Requests the stop (what the signal handler does; for tests and for code that decides to
    /// stop on its own). Idempotent.
    pub fn request(&self) {
        self.inner.trigger(0);
    }

    /// The signal that requested the stop, if a signal did (`libc::SIGINT`, `libc::SIGTERM`).
    pub fn signal(&self) -> Option<i32> {
        match self.inner.signal.load(Ordering::Relaxed) {
            0 => None,
            s => Some(s),
        }
    }

    /// Blocks until a stop is requested.
    pub fn wait(&self) {
        while !self.wait_timeout(Duration::from_secs(3600)) {}
    }

    /// Blocks until a stop is requested or `timeout` passes; true if a stop was requested.
    pub fn wait_timeout(&self, timeout: Duration) -> bool {
        let deadline = Instant::now() + timeout;
        loop {
            if self.inner.requested.load(Ordering::Acquire) {
                return true;
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return false;
            }
            let mut pfd = libc::pollfd {
                fd: self.inner.event.as_raw_fd(),
                events: libc::POLLIN,
                revents: 0,
            };
            let ms = left.as_millis().clamp(1, i32::MAX as u128) as libc::c_int;
            // SAFETY: one valid pollfd on the stack. EINTR (a signal, maybe ours) just loops.
            unsafe { libc::poll(&mut pfd, 1, ms) };
        }
    }

    /// A new descriptor (`O_CLOEXEC`) of the eventfd, readable once a stop is requested: for an
    /// async runtime's readiness (tokio: `AsyncFd::register_with_interest(fd,
    /// Interest::READABLE)`, then `.readable().await`; the `AsyncFd` owns the descriptor, which
    /// is what that call's safety contract asks). Do not read from it (the other waiters would
    /// miss the stop).
    pub fn wait_fd(&self) -> io::Result<OwnedFd> {
        self.inner.event.as_fd().try_clone_to_owned()
    }
}

impl AsFd for Shutdown {
    fn as_fd(&self) -> BorrowedFd<'_> {
        self.inner.event.as_fd()
    }
}

impl AsRawFd for Shutdown {
    fn as_raw_fd(&self) -> RawFd {
        self.inner.event.as_raw_fd()
    }
}

/// The process's stop request, once created; the handler reaches it through this pointer (a
/// `OnceLock` read is not documented as async-signal-safe, an atomic load is).
static HANDLER_TARGET: AtomicPtr<Inner> = AtomicPtr::new(std::ptr::null_mut());
static PROCESS: OnceLock<io::Result<Shutdown>> = OnceLock::new();

extern "C" fn on_signal(signal: libc::c_int) {
    // SAFETY: errno is thread-local; saving and restoring it keeps the interrupted code's value.
    let errno = unsafe { *libc::__errno_location() };
    let target = HANDLER_TARGET.load(Ordering::Acquire);
    // SAFETY: the pointer is set once to an `Inner` that `PROCESS` keeps alive for the life of
    // the process.
    if let Some(inner) = unsafe { target.as_ref() } {
        inner.trigger(signal);
    }
    // SAFETY: as above.
    unsafe { *libc::__errno_location() = errno };
}

fn install(signal: libc::c_int) -> io::Result<()> {
    // SAFETY: a zeroed sigaction is valid; the handler is async-signal-safe (see `on_signal`).
    // SA_RESTART: interrupted blocking calls elsewhere resume, as with `signal(2)` before.
    unsafe {
        let mut sa: libc::sigaction = std::mem::zeroed();
        sa.sa_sigaction = on_signal as *const () as libc::sighandler_t;
        sa.sa_flags = libc::SA_RESTART;
        libc::sigemptyset(&mut sa.sa_mask);
        if libc::sigaction(signal, &sa, std::ptr::null_mut()) != 0 {
            return Err(io::Error::last_os_error());
        }
    }
    Ok(())
}

/// The process's stop request, triggered by SIGINT and SIGTERM. The first call installs the
/// handlers; later calls return the same request.
pub fn install_signal_handlers() -> io::Result<Shutdown> {
    let process = PROCESS.get_or_init(|| {
        let shutdown = Shutdown::new()?;
        HANDLER_TARGET.store(Arc::as_ptr(&shutdown.inner).cast_mut(), Ordering::Release);
        install(libc::SIGINT)?;
        install(libc::SIGTERM)?;
        Ok(shutdown)
    });
    match process {
        Ok(s) => Ok(s.clone()),
        Err(e) => Err(io::Error::new(e.kind(), e.to_string())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn request_is_seen_by_every_clone_and_stays() {
        let s = Shutdown::new().unwrap();
        let c = s.clone();
        assert!(!c.is_requested());
        assert!(
            !c.wait_timeout(Duration::from_millis(20)),
            "times out when not requested"
        );
        s.request();
        s.request();
        assert!(c.is_requested());
        assert!(c.wait_timeout(Duration::ZERO));
        c.wait();
        assert_eq!(c.signal(), None, "a call, not a signal");
        // Private requests are independent.
        assert!(!Shutdown::new().unwrap().is_requested());
    }

    #[test]
    fn a_blocked_thread_wakes_on_request() {
        let s = Shutdown::new().unwrap();
        let waiter = {
            let s = s.clone();
            std::thread::spawn(move || {
                let t = Instant::now();
                s.wait();
                t.elapsed()
            })
        };
        std::thread::sleep(Duration::from_millis(50));
        assert!(!waiter.is_finished());
        s.request();
        let took = waiter.join().unwrap();
        assert!(took >= Duration::from_millis(40), "{took:?}");
    }

    /// Async waiters: each on its own duplicate of the eventfd, early and late ones both woken.
    #[test]
    fn tokio_awaits_the_eventfd() {
        use tokio::io::unix::AsyncFd;
        use tokio::io::Interest;
        // SAFETY: the AsyncFd owns the descriptor (an OwnedFd) for its whole life.
        let register = |fd: OwnedFd| unsafe {
            AsyncFd::register_with_interest(fd, Interest::READABLE).unwrap()
        };
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        let s = Shutdown::new().unwrap();
        rt.block_on(async {
            let early = register(s.wait_fd().unwrap());
            let other = register(s.wait_fd().unwrap());
            let pending = tokio::time::timeout(Duration::from_millis(30), early.readable()).await;
            assert!(pending.is_err(), "not readable before the request");
            let trigger = s.clone();
            tokio::spawn(async move {
                tokio::time::sleep(Duration::from_millis(20)).await;
                trigger.request();
            });
            let _ = tokio::time::timeout(Duration::from_secs(5), early.readable())
                .await
                .expect("woken by the request")
                .unwrap();
            let _ = tokio::time::timeout(Duration::from_secs(5), other.readable())
                .await
                .expect("a second waiter too")
                .unwrap();
            let late = register(s.wait_fd().unwrap());
            let _ = tokio::time::timeout(Duration::from_secs(5), late.readable())
                .await
                .expect("a waiter that comes after the request")
                .unwrap();
        });
    }

    /// The process's request: SIGTERM sets it (and says which signal), a blocked waiter wakes,
    /// and the process is not killed. The only test in this binary that installs the handlers.
    #[test]
    fn sigterm_triggers_the_process_request() {
        let s = install_signal_handlers().unwrap();
        let again = install_signal_handlers().unwrap();
        assert!(
            Arc::ptr_eq(&s.inner, &again.inner),
            "installed once, one request"
        );
        let waiter = {
            let s = s.clone();
            std::thread::spawn(move || s.wait_timeout(Duration::from_secs(10)))
        };
        // SAFETY: kill(2) to this process; our handler catches SIGTERM.
        unsafe { libc::kill(libc::getpid(), libc::SIGTERM) };
        assert!(waiter.join().unwrap(), "the waiter woke");
        assert!(s.is_requested());
        assert_eq!(s.signal(), Some(libc::SIGTERM));
    }
}
