//! What a hostile or broken peer can do to shared memory, for the fuzz targets (test-support
//! crate `shm-ring-testing`, `fuzzing`): rewrite any word of a ring (indices, wake signals,
//! slots) and any word of a segment header, then let this crate's real code read it.
//!
//! Hidden from the docs and not a stable API. It is here, not in the test-support crate,
//! because no public API can write a ring's or a header's shared words, by design: the rings
//! and the header keep them private so that only a foreign process can break them. These two
//! types are that foreign process, reduced to the two operations a fuzzer needs.

use std::sync::atomic::{AtomicU64, Ordering};

use crate::fixed_str::FixedStr;
use crate::ring::mem::{RingControl, RingMem};
use crate::ring::message::Message;
use crate::ring::overwrite::{OverwriteConsumer, OverwriteProducer};
use crate::ring::spsc::{Consumer, Producer};
use crate::segment::channel::{ChannelSpec, CHANNELS};
use crate::segment::error::Error;
use crate::segment::header::{Header, Layout, MAGIC};
use crate::segment::{validate, SegmentName};

/// A zeroed ring on the heap whose ends can be made (again, like a re-attaching process) and
/// whose shared words can be overwritten.
pub struct HostileRing {
    mem: RingMem,
}

impl HostileRing {
    /// `capacity` a power of two.
    pub fn new(capacity: usize, payload_words: usize) -> HostileRing {
        HostileRing {
            mem: RingMem::heap(capacity, payload_words),
        }
    }

    pub fn producer<M: Message>(&self) -> Producer<M> {
        Producer::new(self.mem.twin(), None)
    }

    pub fn consumer<M: Message>(&self) -> Consumer<M> {
        Consumer::new(self.mem.twin(), None)
    }

    pub fn overwrite_producer<M: Message>(&self) -> OverwriteProducer<M> {
        OverwriteProducer::new(self.mem.twin())
    }

    pub fn overwrite_consumer<M: Message>(&self) -> OverwriteConsumer<M> {
        OverwriteConsumer::new(self.mem.twin(), None)
    }

    /// Sets one shared word the way a foreign process would: `which % 8` picks the tail, the
    /// head, the data signal's parked flag, the space signal's epoch, or (4..8) a slot word
    /// chosen by `which / 8`.
    pub fn poke(&self, which: u64, value: u64) {
        let mem = &self.mem;
        let c = mem.ctrl();
        let stride = mem.slot(0).len() as u64;
        match which % 8 {
            0 => c.tail.0.store(value, Ordering::Release),
            1 => c.head.0.store(value, Ordering::Release),
            2 => c.data.0.parked.store(value as u32, Ordering::Relaxed),
            3 => c.space.0.epoch.store(value as u32, Ordering::Relaxed),
            _ => {
                let word = which / 8 % (mem.capacity() * stride);
                mem.slot(word / stride)[(word % stride) as usize].store(value, Ordering::Release);
            }
        }
    }
}

/// Where validation placed the rings (a copy of what an attacher would use).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Placement {
    pub capacities: [usize; CHANNELS],
    pub control_offsets: [usize; CHANNELS],
    pub slots_offsets: [usize; CHANNELS],
    pub total: usize,
    pub schema: Vec<String>,
}

/// A ring control block's size and alignment in the segment.
pub const RING_CONTROL_SIZE: usize = RingControl::SIZE;
pub const RING_CONTROL_ALIGN: usize = RingControl::ALIGN;

#[repr(C, align(128))]
struct HeaderWords([AtomicU64; std::mem::size_of::<Header>() / 8]);

/// A header-sized, header-aligned block of atomics: what an attacher finds at the start of a
/// mapping.
pub struct HostileHeader(Box<HeaderWords>);

impl HostileHeader {
    /// All zero (a fresh mapping).
    pub fn zeroed() -> HostileHeader {
        HostileHeader(Box::new(HeaderWords(std::array::from_fn(|_| {
            AtomicU64::new(0)
        }))))
    }

    /// A header as a creator writes it for `specs` at their default capacities and `schema`,
    /// magic published.
    pub fn valid(specs: &[ChannelSpec; CHANNELS], schema: &[&str]) -> HostileHeader {
        let h = HostileHeader::zeroed();
        let capacities = specs.map(|c| c.default_capacity);
        let shapes = specs.map(|c| c.shape);
        let layout = Layout::compute(capacities, &shapes);
        let names: Vec<_> = schema
            .iter()
            .map(|n| FixedStr::new(n).expect("a valid schema name"))
            .collect();
        h.header().init(capacities, &names, &layout, &shapes, 0);
        h.header().magic.store(MAGIC, Ordering::Relaxed);
        h
    }

    fn header(&self) -> &Header {
        const { assert!(std::mem::size_of::<HeaderWords>() == std::mem::size_of::<Header>()) };
        const { assert!(std::mem::align_of::<HeaderWords>() >= std::mem::align_of::<Header>()) };
        // SAFETY: same size, sufficient alignment, and `Header` is `repr(C)` made only of
        // atomics (any bit pattern is valid, all access is atomic).
        unsafe { &*(self.0.as_ref() as *const HeaderWords).cast::<Header>() }
    }

    /// The header's words, to overwrite at will.
    pub fn words(&self) -> &[AtomicU64] {
        &self.0 .0
    }

    /// What an attacher's validation makes of this header in a file of `file_size` bytes.
    pub fn validate(
        &self,
        specs: &[ChannelSpec; CHANNELS],
        file_size: u64,
    ) -> Result<Placement, Error> {
        // The decoders a diagnostic tool runs on any header, valid or not.
        let _ = self.header().schema();
        let _ = self.header().capacities();
        let name = SegmentName::new("/hostile").expect("a valid name");
        let (layout, schema) = validate(self.header(), &name, file_size, specs)?;
        Ok(Placement {
            capacities: layout.capacities,
            control_offsets: layout.control_offsets,
            slots_offsets: layout.slots_offsets,
            total: layout.total,
            schema,
        })
    }
}
