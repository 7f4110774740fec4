//! Work done ahead: the part of a stateful model's next step that reads only the state this
//! step wrote, done after the answer has gone out, while the serving thread would otherwise
//! wait for the next request.
//!
//! Why: three quarters of an LSTM step at H = 100 is its recurrent product W_hh h, 160 KB of
//! weights streamed from L2 on every step (docs/infer-server.md, "The support vectors in
//! blocks": the step 3.0-3.9 us, 0.67-0.99 without the product). h is known the moment a step
//! ends and the next step's product reads nothing else, so it can be done before the next
//! request arrives (the period is 100 us). The answer's latency loses it; the CPU time per
//! step does not (measured, it grew by about 0.9 us: docs/infer-server.md, "The LSTMs'
//! recurrent product, done after the answer"; infer-server counts it: `ahead_ns`).
//!
//! Who does what:
//! - a thread that serves (infer-server's inference thread) calls [`serve_ahead_on_this_thread`]
//!   once, then [`run_ahead`] after each answer has been sent;
//! - a kernel with such work, at the end of its step, queues it on the thread that ran the step
//!   ([`queue`]), only if that thread serves ahead. On every other thread (Python's onnxruntime,
//!   rt-loop's ONNX objects, a model's warm-up, the tests) nothing is queued and every step does
//!   all of its work.
//!
//! Correctness never depends on the work having run: a step uses what was done ahead only if it
//! was done for exactly the state the step is given (bit for bit), and otherwise does it itself
//! with the same arithmetic in the same order, so the answer is the same bits either way
//! (lstm.rs's tests check this).
//!
//! Ordering: the work's input and result live in a [`Slot`], shared by the kernel and the queue
//! (an `Arc`: a kernel dropped by a model swap leaves the queue's copy valid until it is
//! dropped, unrun). Whoever moves the slot's state to `BUSY` (a compare-exchange, Acquire) owns
//! its contents until it stores the next state (Release); whoever finds it `BUSY` works without
//! it. Nothing waits: no lock, no allocation, no syscall on either side.

use std::cell::{Cell, RefCell, UnsafeCell};
use std::ops::{Deref, DerefMut};
use std::sync::atomic::{AtomicBool, AtomicU8, Ordering};
use std::sync::Arc;

/// Work a kernel queued for after the answer.
pub(crate) trait Ahead: Send + Sync {
    /// Does the work for the input the last step left, if it is still wanted.
    fn run_ahead(&self);
    /// The flag [`queue`] and [`run_ahead`] keep: whether this work sits in a queue.
    fn queued(&self) -> &AtomicBool;
}

/// The most kernels one thread queues between two answers (a served graph has one stateful
/// node; more are stepped without work ahead).
const CAPACITY: usize = 8;

struct Queue {
    items: [Option<Arc<dyn Ahead>>; CAPACITY],
    len: usize,
}

impl Drop for Queue {
    /// A serving thread that ends with work queued: that work is in no queue any more, so the
    /// next serving thread to step its kernel may queue it again (else its flag would say
    /// "queued" forever and the kernel would never be served ahead again).
    fn drop(&mut self) {
        for work in self.items[..self.len].iter().flatten() {
            work.queued().store(false, Ordering::Relaxed);
        }
    }
}

thread_local! {
    /// Whether this thread serves ahead. Read before [`QUEUE`] is touched: a `Cell<bool>` needs
    /// no destructor, so a thread that never serves (rt-loop's loop thread stepping an ONNX
    /// object, Python's) never registers one, which could allocate, in its first step.
    static SERVES: Cell<bool> = const { Cell::new(false) };
    /// The work queued on a serving thread (`None` until it serves).
    static QUEUE: RefCell<Option<Queue>> = const { RefCell::new(None) };
}

/// Makes this thread one that runs work ahead: kernels stepped on it queue their next step's
/// state-only work, which [`run_ahead`] then does. Call once, before serving (its first call
/// sets up the thread's queue: the only allocation here, if any).
pub fn serve_ahead_on_this_thread() {
    SERVES.with(|s| s.set(true));
    QUEUE.with(|q| {
        let mut q = q.borrow_mut();
        if q.is_none() {
            *q = Some(Queue {
                items: [const { None }; CAPACITY],
                len: 0,
            });
        }
    });
}

/// Does the work the kernels stepped on this thread queued since the last call; returns how
/// many ran. Call it after the answer has been sent and before waiting for the next request.
/// Allocates nothing and takes no lock; the one exception is a kernel that a model swap dropped
/// meanwhile: its work is skipped and its weights are freed here, once per swap.
pub fn run_ahead() -> usize {
    if !SERVES.with(Cell::get) {
        return 0;
    }
    QUEUE.with(|q| {
        let Ok(mut q) = q.try_borrow_mut() else {
            return 0;
        };
        let Some(q) = q.as_mut() else {
            return 0;
        };
        let mut ran = 0;
        for item in &mut q.items[..q.len] {
            if let Some(work) = item.take() {
                work.queued().store(false, Ordering::Relaxed);
                // The queue's is the last reference: the kernel is gone, nobody will read it.
                if Arc::strong_count(&work) > 1 {
                    work.run_ahead();
                    ran += 1;
                }
            }
        }
        q.len = 0;
        ran
    })
}

/// Queues `work` on this thread if it serves ahead; returns whether the work is in a queue
/// (now, or already from an earlier step). Allocates nothing (an `Arc` clone).
pub(crate) fn queue<W: Ahead + 'static>(work: &Arc<W>) -> bool {
    if work.queued().load(Ordering::Relaxed) {
        return true;
    }
    if !SERVES.with(Cell::get) {
        return false;
    }
    QUEUE.with(|q| {
        let Ok(mut q) = q.try_borrow_mut() else {
            return false;
        };
        let Some(q) = q.as_mut() else {
            return false;
        };
        if q.len == CAPACITY {
            return false;
        }
        work.queued().store(true, Ordering::Relaxed);
        q.items[q.len] = Some(work.clone() as Arc<dyn Ahead>);
        q.len += 1;
        true
    })
}

/// The slot's contents hold nothing usable.
pub(crate) const EMPTY: u8 = 0;
/// The contents hold a step's input; the work for it is queued, not done.
pub(crate) const QUEUED: u8 = 1;
/// The contents hold an input and the work done for it.
pub(crate) const DONE: u8 = 2;
/// Someone owns the contents right now.
const BUSY: u8 = 3;

/// Contents shared by a kernel and a queue, owned by whoever claims them (module docs).
pub(crate) struct Slot<T> {
    state: AtomicU8,
    queued: AtomicBool,
    value: UnsafeCell<T>,
}

// SAFETY: `value` is only reached through a `Claim`, and at most one `Claim` exists at a time
// (the compare-exchange to BUSY); the Acquire of the claim and the Release of its end order the
// contents' accesses between threads.
unsafe impl<T: Send> Sync for Slot<T> {}

impl<T> Slot<T> {
    pub fn new(value: T) -> Self {
        Self {
            state: AtomicU8::new(EMPTY),
            queued: AtomicBool::new(false),
            value: UnsafeCell::new(value),
        }
    }

    pub fn queued(&self) -> &AtomicBool {
        &self.queued
    }

    /// Claims the contents whatever they hold; `None` if someone else has them.
    #[inline]
    pub fn claim(&self) -> Option<Claim<'_, T>> {
        let mut s = self.state.load(Ordering::Relaxed);
        loop {
            if s == BUSY {
                return None;
            }
            match self
                .state
                .compare_exchange_weak(s, BUSY, Ordering::Acquire, Ordering::Relaxed)
            {
                Ok(_) => return Some(Claim { slot: self, was: s }),
                Err(now) => s = now,
            }
        }
    }

    /// Claims the contents only if they wait for their work ([`QUEUED`]).
    #[inline]
    pub fn claim_queued(&self) -> Option<Claim<'_, T>> {
        self.state
            .compare_exchange(QUEUED, BUSY, Ordering::Acquire, Ordering::Relaxed)
            .ok()
            .map(|was| Claim { slot: self, was })
    }
}

/// The contents, owned until [`Claim::release`] (dropped without it: [`EMPTY`]).
pub(crate) struct Claim<'a, T> {
    slot: &'a Slot<T>,
    was: u8,
}

impl<T> Claim<'_, T> {
    /// The state the contents were claimed in.
    pub fn was(&self) -> u8 {
        self.was
    }

    /// Gives the contents back in `state` (EMPTY, QUEUED or DONE).
    pub fn release(self, state: u8) {
        debug_assert!(state != BUSY);
        self.slot.state.store(state, Ordering::Release);
        std::mem::forget(self);
    }
}

impl<T> Deref for Claim<'_, T> {
    type Target = T;
    fn deref(&self) -> &T {
        // SAFETY: this claim is the only one (Slot's Sync impl).
        unsafe { &*self.slot.value.get() }
    }
}

impl<T> DerefMut for Claim<'_, T> {
    fn deref_mut(&mut self) -> &mut T {
        // SAFETY: this claim is the only one (Slot's Sync impl).
        unsafe { &mut *self.slot.value.get() }
    }
}

impl<T> Drop for Claim<'_, T> {
    fn drop(&mut self) {
        self.slot.state.store(EMPTY, Ordering::Release);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::AtomicUsize;

    struct Count {
        slot: Slot<u32>,
        runs: AtomicUsize,
    }

    impl Ahead for Count {
        fn run_ahead(&self) {
            if let Some(mut c) = self.slot.claim_queued() {
                *c += 1;
                self.runs.fetch_add(1, Ordering::Relaxed);
                c.release(DONE);
            }
        }
        fn queued(&self) -> &AtomicBool {
            self.slot.queued()
        }
    }

    fn count() -> Arc<Count> {
        Arc::new(Count {
            slot: Slot::new(0),
            runs: AtomicUsize::new(0),
        })
    }

    #[test]
    fn a_thread_that_does_not_serve_ahead_queues_nothing() {
        let w = count();
        assert!(!queue(&w));
        assert_eq!(run_ahead(), 0);
        assert_eq!(Arc::strong_count(&w), 1);
    }

    #[test]
    fn queued_work_runs_once_after_the_answer_and_never_for_a_dropped_kernel() {
        std::thread::spawn(|| {
            serve_ahead_on_this_thread();
            let w = count();
            w.slot.claim().unwrap().release(QUEUED);
            assert!(queue(&w));
            assert!(queue(&w), "queued twice: one entry");
            assert_eq!(run_ahead(), 1);
            assert_eq!(w.runs.load(Ordering::Relaxed), 1);
            assert_eq!(run_ahead(), 0, "nothing queued since");
            let c = w.slot.claim().unwrap();
            assert_eq!((c.was(), *c), (DONE, 1));
            c.release(QUEUED);

            // The kernel goes (a model swap) while its work is queued: skipped, freed.
            assert!(queue(&w));
            let weak = Arc::downgrade(&w);
            drop(w);
            assert_eq!(run_ahead(), 0);
            assert!(weak.upgrade().is_none());
        })
        .join()
        .unwrap();
    }

    #[test]
    fn work_left_queued_by_a_thread_that_ended_is_queued_again_elsewhere() {
        let w = count();
        let w2 = w.clone();
        std::thread::spawn(move || {
            serve_ahead_on_this_thread();
            w2.slot.claim().unwrap().release(QUEUED);
            assert!(queue(&w2));
            // ends without run_ahead
        })
        .join()
        .unwrap();
        assert!(!w.queued().load(Ordering::Relaxed));
        std::thread::spawn(move || {
            serve_ahead_on_this_thread();
            assert!(queue(&w));
            assert_eq!(run_ahead(), 1);
            assert_eq!(w.runs.load(Ordering::Relaxed), 1);
        })
        .join()
        .unwrap();
    }

    #[test]
    fn a_claimed_slot_is_not_claimed_again_until_released() {
        let s = Slot::new(7u32);
        let c = s.claim().unwrap();
        assert!(s.claim().is_none());
        assert!(s.claim_queued().is_none());
        drop(c);
        let c = s.claim().unwrap();
        assert_eq!(c.was(), EMPTY, "dropped without release: nothing usable");
        c.release(DONE);
        assert!(s.claim_queued().is_none(), "done: no work waits");
    }

    #[test]
    fn a_full_queue_says_so() {
        std::thread::spawn(|| {
            serve_ahead_on_this_thread();
            let ws: Vec<_> = (0..=CAPACITY).map(|_| count()).collect();
            let queued = ws.iter().filter(|w| queue(w)).count();
            assert_eq!(queued, CAPACITY);
            assert_eq!(run_ahead(), CAPACITY);
        })
        .join()
        .unwrap();
    }
}
