//! A stand-alone peer for a haptics shm-ring segment: inspects a header, or plays the loop or
//! the server with deterministic messages (`shm_ring_testing::pattern`). The multi-process
//! tests drive it; it is also handy by hand, e.g. `shm-ring-peer inspect /haptics-default`.

mod peer;

fn main() -> std::process::ExitCode {
    peer::main()
}
