//! The checks on a segment's memory. `validate` runs once, when a segment is attached or
//! inspected: every header field against this build, before any ring is placed. `audit` runs
//! on demand while the segment is in use ([`Link::audit`](super::Link::audit)): the fixed
//! fields against this process's private copies, and each ring's shared indices, which a
//! hostile or broken peer could have written.

use std::sync::atomic::{AtomicU64, Ordering};

use super::channel::{ChannelKind, ChannelSpec, CHANNELS};
use super::config::MAX_CAPACITY;
use super::error::Error;
use super::header::{Header, Layout, LAYOUT_VERSION, MAGIC, MAX_SCHEMA_NAMES, SLOT_ALIGN};
use super::name::SegmentName;
use super::shared::Shared;
use crate::ring::mem::{slot_words, RingControl};

/// What a segment's memory was found to hold that the protocol forbids (see
/// [`Link::audit`](super::Link::audit)).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Corruption {
    #[error("header field `{field}` holds {found}, the segment was made with {expected}")]
    Header {
        field: &'static str,
        found: u64,
        expected: u64,
    },
    #[error("the header's feature schema no longer matches the segment's")]
    Schema,
    #[error("{channel} ring indices impossible: head {head}, tail {tail}, capacity {capacity}")]
    Indices {
        channel: &'static str,
        head: u64,
        tail: u64,
        capacity: u64,
    },
}

/// Checks everything in the header against this build; returns the layout and schema to use
/// (private copies: nothing is read from the header again to place or size a ring).
pub(crate) fn validate(
    header: &Header,
    name: &SegmentName,
    file_size: u64,
    specs: &[ChannelSpec; CHANNELS],
) -> Result<(Layout, Vec<String>), Error> {
    let r = Ordering::Relaxed;
    let name_s = || name.to_string();
    let magic = header.magic.load(r);
    if magic != MAGIC {
        return Err(Error::BadMagic {
            name: name_s(),
            found: magic,
        });
    }
    let version = header.layout_version.load(r);
    if version != LAYOUT_VERSION {
        return Err(Error::VersionMismatch {
            name: name_s(),
            found: version,
            expected: LAYOUT_VERSION,
        });
    }
    let mismatch = |what: String, found: u64, expected: u64| -> Result<(), Error> {
        if found == expected {
            Ok(())
        } else {
            Err(Error::LayoutMismatch {
                name: name_s(),
                what,
                found,
                expected,
            })
        }
    };
    mismatch(
        "header size".into(),
        header.header_size.load(r),
        std::mem::size_of::<Header>() as u64,
    )?;
    mismatch(
        "ring control size".into(),
        header.control_size.load(r),
        RingControl::SIZE as u64,
    )?;
    mismatch(
        "ring control alignment".into(),
        header.control_align.load(r),
        RingControl::ALIGN as u64,
    )?;
    let capacities = header.capacities();
    for (i, spec) in specs.iter().enumerate() {
        let desc = &header.channels[i];
        let (words, id) = (spec.shape.words, spec.shape.layout_id);
        let ch = spec.name;
        mismatch(
            format!("{ch} message layout id"),
            desc.layout_id.load(r),
            id,
        )?;
        mismatch(
            format!("{ch} payload words"),
            desc.payload_words.load(r),
            words as u64,
        )?;
        mismatch(
            format!("{ch} slot bytes"),
            desc.slot_bytes.load(r),
            slot_words(words) as u64 * 8,
        )?;
        mismatch(
            format!("{ch} slot alignment"),
            desc.slot_align.load(r),
            SLOT_ALIGN as u64,
        )?;
        let cap = capacities[i];
        if !cap.is_power_of_two() || !(2..=MAX_CAPACITY).contains(&cap) {
            return Err(Error::LayoutMismatch {
                name: name_s(),
                what: format!("{ch} capacity (not a power of two in 2..={MAX_CAPACITY})"),
                found: cap as u64,
                expected: 0,
            });
        }
    }
    let layout = Layout::compute(capacities, &specs.map(|c| c.shape));
    for (i, spec) in specs.iter().enumerate() {
        let desc = &header.channels[i];
        let ch = spec.name;
        mismatch(
            format!("{ch} control offset"),
            desc.control_offset.load(r),
            layout.control_offsets[i] as u64,
        )?;
        mismatch(
            format!("{ch} slots offset"),
            desc.slots_offset.load(r),
            layout.slots_offsets[i] as u64,
        )?;
    }
    mismatch(
        "total size".into(),
        header.total_size.load(r),
        layout.total as u64,
    )?;
    mismatch("file size".into(), file_size, layout.total as u64)?;
    let Some(schema) = header.schema() else {
        return Err(Error::LayoutMismatch {
            name: name_s(),
            what: "feature schema (bad length or names)".into(),
            found: header.schema_len.load(r),
            expected: MAX_SCHEMA_NAMES as u64,
        });
    };
    Ok((layout, schema))
}

/// Compares the header's fixed fields with this process's private copies and checks each
/// ring's shared indices (see [`Link::audit`](super::Link::audit)).
pub(super) fn audit(shared: &Shared) -> Result<(), Corruption> {
    let r = Ordering::Relaxed;
    let h = shared.header();
    let layout = &shared.layout;
    let field = |field: &'static str, cell: &AtomicU64, expected: u64| {
        let found = cell.load(r);
        if found == expected {
            Ok(())
        } else {
            Err(Corruption::Header {
                field,
                found,
                expected,
            })
        }
    };
    field("magic", &h.magic, MAGIC)?;
    field("layout_version", &h.layout_version, LAYOUT_VERSION)?;
    field(
        "header_size",
        &h.header_size,
        std::mem::size_of::<Header>() as u64,
    )?;
    field("control_size", &h.control_size, RingControl::SIZE as u64)?;
    field("control_align", &h.control_align, RingControl::ALIGN as u64)?;
    field("total_size", &h.total_size, layout.total as u64)?;
    field("creator_pid", &h.creator_pid, shared.creator_pid)?;
    for (i, spec) in shared.specs.iter().enumerate() {
        let d = &h.channels[i];
        let (words, id) = (spec.shape.words, spec.shape.layout_id);
        field("capacity", &d.capacity, layout.capacities[i] as u64)?;
        field("payload_words", &d.payload_words, words as u64)?;
        field("slot_bytes", &d.slot_bytes, slot_words(words) as u64 * 8)?;
        field("slot_align", &d.slot_align, SLOT_ALIGN as u64)?;
        field("layout_id", &d.layout_id, id)?;
        field(
            "control_offset",
            &d.control_offset,
            layout.control_offsets[i] as u64,
        )?;
        field(
            "slots_offset",
            &d.slots_offset,
            layout.slots_offsets[i] as u64,
        )?;
    }
    if h.schema().as_ref() != Some(&shared.schema) {
        return Err(Corruption::Schema);
    }
    for (i, spec) in shared.specs.iter().enumerate() {
        let capacity = layout.capacities[i] as u64;
        // SAFETY: as in `Shared::ring`: the private layout places the control block inside
        // the mapping, aligned, and it is only accessed through atomics.
        let ctrl = unsafe {
            shared
                .mapping
                .base()
                .add(layout.control_offsets[i])
                .cast::<RingControl>()
                .as_ref()
        };
        // Both indices only grow, so reading tail, head, tail again bounds what they were
        // at the moment head was read, with no false alarm from a racing push or pop:
        // head <= tail then <= t2, and head >= tail then - capacity >= t1 - capacity.
        let t1 = ctrl.tail.0.load(Ordering::Acquire);
        let head = ctrl.head.0.load(Ordering::Acquire);
        let t2 = ctrl.tail.0.load(Ordering::Acquire);
        let ok = if spec.kind == ChannelKind::Overwrite {
            // The overwrite ring's consumer may be any number of laps behind, never ahead.
            head <= t2
        } else {
            head <= t2 && head.checked_add(capacity).is_some_and(|max| t1 <= max)
        };
        if !ok {
            return Err(Corruption::Indices {
                channel: spec.name,
                head,
                tail: t2,
                capacity,
            });
        }
    }
    Ok(())
}
