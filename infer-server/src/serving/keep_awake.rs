//! Keeps the inference thread's CPU awake between steps: the shared spinner
//! (`shm_ring::os::keep_awake`, which says why and what it costs), driven by the inference
//! thread's `answered` counter and reporting into its counters.
//!
//! With the period-synchronised wait ([`crate::serving::period_sync`]) the inference thread
//! sleeps most of each period; on a virtual machine its CPU then halts and the wake-up is now and
//! then tens of microseconds late. Measured: docs/infer-server.md, "Keeping the inference CPU
//! awake".

use std::sync::atomic::Ordering;

use shm_ring::os::keep_awake::Activity;
pub use shm_ring::os::keep_awake::KeepAwake;

use crate::serving::inference_thread::InferenceCounters;

impl Activity for InferenceCounters {
    fn steps(&self) -> u64 {
        self.answered.load(Ordering::Relaxed)
    }
    fn set_up(&self, cpu: usize) {
        self.keep_awake_cpu.store(cpu as i64, Ordering::Relaxed);
    }
    fn add_spun_us(&self, us: u64) {
        self.keep_awake_spun_us.fetch_add(us, Ordering::Relaxed);
    }
}
