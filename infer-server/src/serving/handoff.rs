//! Handing a new model to the inference thread between two steps, and taking the old one back.
//!
//! The control side (gRPC, CLI, the web layer) loads and validates a [`StepEngine`] on its own
//! thread, then [`Activator::offer`]s it. The inference thread calls [`Taker::take`] between
//! steps: one atomic swap picks up the pending engine. The engine it replaces is *not* dropped
//! there (dropping an ONNX Runtime session frees memory and can take milliseconds); it goes into
//! a "retired" slot that the control side empties and drops on its thread.
//!
//! Two `AtomicPtr` slots, each with one producer and one consumer:
//! - `pending`: written by the control side, emptied by the inference thread;
//! - `retired`: written by the inference thread, emptied by the control side.
//!
//! The inference thread only takes a pending engine while `retired` is empty, so it never has to
//! drop anything. No lock, no allocation, no syscall on the inference thread.

use std::ptr;
use std::sync::atomic::{AtomicPtr, AtomicU64, Ordering};
use std::sync::Arc;

use crate::model::engine::StepEngine;
use crate::model::ModelInfo;

/// An engine on its way, with the generation number the control side gave it.
#[derive(Debug)]
pub struct Offered {
    pub engine: StepEngine,
    pub generation: u64,
}

struct Slots {
    pending: AtomicPtr<Offered>,
    retired: AtomicPtr<Offered>,
    /// Generation of the engine the inference thread is running (0: none yet).
    active_generation: AtomicU64,
}

impl Drop for Slots {
    fn drop(&mut self) {
        for slot in [&self.pending, &self.retired] {
            let p = slot.swap(ptr::null_mut(), Ordering::Acquire);
            if !p.is_null() {
                // SAFETY: every non-null pointer in a slot came from Box::into_raw and is owned
                // by the slot; both halves are gone (we are in the last Arc's drop).
                drop(unsafe { Box::from_raw(p) });
            }
        }
    }
}

/// The control side. Not `Clone`: one owner serialises activations (wrap it in a mutex on the
/// control plane if several requests can race; the inference thread never touches that lock).
pub struct Activator {
    slots: Arc<Slots>,
    next_generation: u64,
    active_info: Option<ModelInfo>,
    offered_info: Option<(u64, ModelInfo)>,
    /// Retired engines collected by `offer` on the caller's behalf; `collect_retired` hands
    /// them out first, so a registry that keeps engines gets every one of them back.
    #[allow(clippy::vec_box)] // handed out as the boxes they came in
    stashed: Vec<Box<Offered>>,
}

/// The inference thread's side.
pub struct Taker {
    slots: Arc<Slots>,
}

pub fn channel() -> (Activator, Taker) {
    let slots = Arc::new(Slots {
        pending: AtomicPtr::new(ptr::null_mut()),
        retired: AtomicPtr::new(ptr::null_mut()),
        active_generation: AtomicU64::new(0),
    });
    (
        Activator {
            slots: Arc::clone(&slots),
            next_generation: 1,
            active_info: None,
            offered_info: None,
            stashed: Vec::new(),
        },
        Taker { slots },
    )
}

impl Activator {
    /// Offers a validated engine; the inference thread switches to it before its next step.
    /// Returns its generation. An earlier offer not yet taken is withdrawn and dropped here.
    pub fn offer(&mut self, mut engine: StepEngine) -> u64 {
        // The slot must be empty for the thread to take the new engine; keep what was there.
        let p = self.slots.retired.swap(ptr::null_mut(), Ordering::AcqRel);
        if !p.is_null() {
            // SAFETY: the inference thread put it there with Box::into_raw and forgot it.
            self.stashed.push(unsafe { Box::from_raw(p) });
        }
        // An engine that served before (kept by a registry) starts again from a zero state.
        engine.reset();
        let generation = self.next_generation;
        self.next_generation += 1;
        let info = engine.info().clone();
        let boxed = Box::into_raw(Box::new(Offered { engine, generation }));
        let previous = self.slots.pending.swap(boxed, Ordering::AcqRel);
        if !previous.is_null() {
            // SAFETY: the inference thread did not take it (it would have nulled the slot);
            // the swap made us its only owner.
            drop(unsafe { Box::from_raw(previous) });
        }
        self.offered_info = Some((generation, info));
        generation
    }

    /// Takes back an offer the inference thread has not taken yet (e.g. no loop is attached
    /// to take it). `None` when it was taken already (or nothing was offered).
    pub fn withdraw(&mut self) -> Option<Box<Offered>> {
        let p = self.slots.pending.swap(ptr::null_mut(), Ordering::AcqRel);
        if p.is_null() {
            return None;
        }
        self.offered_info = None;
        // SAFETY: published with Box::into_raw by `offer`; the swap made us its only owner.
        Some(unsafe { Box::from_raw(p) })
    }

    /// Generation of the engine the inference thread runs now (0: none).
    pub fn active_generation(&self) -> u64 {
        self.slots.active_generation.load(Ordering::Acquire)
    }

    /// Takes back the engine the inference thread has replaced, if any (drop it, or keep it to
    /// activate again later). Call it now and then (every `offer` does); until it is called,
    /// the inference thread will not take a newer offer.
    pub fn collect_retired(&mut self) -> Option<Box<Offered>> {
        if let Some(o) = self.stashed.pop() {
            return Some(o);
        }
        let p = self.slots.retired.swap(ptr::null_mut(), Ordering::AcqRel);
        if p.is_null() {
            return None;
        }
        // SAFETY: the inference thread put it there with Box::into_raw and forgot it.
        Some(unsafe { Box::from_raw(p) })
    }

    /// The info of the engine now active, as far as this side knows (updated when the inference
    /// thread has acknowledged the switch).
    pub fn active_info(&mut self) -> Option<&ModelInfo> {
        let active = self.active_generation();
        if let Some((g, _)) = &self.offered_info {
            if *g <= active {
                self.active_info = self.offered_info.take().map(|(_, i)| i);
            }
        }
        self.active_info.as_ref()
    }

    /// Waits (sleeping, not spinning) until the inference thread runs `generation`, up to
    /// `timeout`. Returns whether it did.
    pub fn wait_active(&self, generation: u64, timeout: std::time::Duration) -> bool {
        let deadline = std::time::Instant::now() + timeout;
        loop {
            if self.active_generation() >= generation {
                return true;
            }
            if std::time::Instant::now() >= deadline {
                return false;
            }
            std::thread::sleep(std::time::Duration::from_micros(200));
        }
    }
}

impl Taker {
    /// Between two steps: if a new engine is pending (and the previous retiree has been
    /// collected), swaps it into `active` and hands the old one back for the control side to
    /// drop. Returns true when the engine changed (the caller starts the new model's state from
    /// zero: a fresh engine's state is already reset).
    ///
    /// Real-time safe: two atomic loads in the common case; a swap and a store on a switch.
    #[inline]
    pub fn take(&mut self, active: &mut Option<Box<Offered>>) -> bool {
        if self.slots.pending.load(Ordering::Relaxed).is_null() {
            return false;
        }
        if !self.slots.retired.load(Ordering::Acquire).is_null() {
            return false; // the control side has not dropped the last one yet; try next step
        }
        let p = self.slots.pending.swap(ptr::null_mut(), Ordering::AcqRel);
        if p.is_null() {
            return false;
        }
        // SAFETY: the control side published it with Box::into_raw; the swap made us its owner.
        let new = unsafe { Box::from_raw(p) };
        let generation = new.generation;
        if let Some(old) = active.replace(new) {
            self.slots
                .retired
                .store(Box::into_raw(old), Ordering::Release);
        }
        self.slots
            .active_generation
            .store(generation, Ordering::Release);
        true
    }
}
