//! A stand-alone peer for a shm-ring segment: inspects a header, or plays the loop or the
//! server with deterministic messages (`shm_ring::pattern`). The multi-process tests drive it;
//! it is also handy by hand, e.g. `shm-ring-peer inspect /haptics-default`.

// Under `--cfg loom` the library has no segment (loom atomics cannot live in shared memory),
// so the peer compiles to nothing there.
#[cfg(not(loom))]
mod peer;

#[cfg(not(loom))]
fn main() -> std::process::ExitCode {
    peer::main()
}

#[cfg(loom)]
fn main() {}
