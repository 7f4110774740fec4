//! A read-only array in memory aligned to 2 MiB and marked for transparent huge pages, so a
//! kernel that reads a few hundred scattered places of a large table (ForestStep's nodes)
//! needs one TLB entry for each 2 MiB instead of one for each 4 KiB.
//!
//! Why: with cold caches (after another process ran on the core) each 4 KiB page a call
//! touches first costs a page walk too, and a core walks only a couple at a time: the forest's
//! row went from 0.7 us warm to about 6 us after 8 MiB were written elsewhere, the same with 8,
//! 16 or 32 trees walked together (examples/forest_cost.rs: more misses in flight did not
//! help). In huge pages the cold row took 3.8-4.3 us (depth 9; 8.1 instead of 10.5 at depth
//! 12): the page walks were part of the cost, the cache misses the rest. Linux backs a 2 MiB-aligned range with huge pages when
//! `madvise(MADV_HUGEPAGE)` asks before it is first written (the kernel's THP mode `madvise`,
//! as here, or `always`); elsewhere (THP `never`, other systems) the array is a plain aligned
//! allocation and works the same, slower only when cold.

use core::ptr::NonNull;
use std::alloc::{self, Layout};

/// 2 MiB: a huge page on x86-64 and aarch64 (4 KiB base pages).
const HUGE: usize = 2 << 20;

/// `len` values of `T`, copied once at creation, in a 2 MiB-aligned block.
pub(crate) struct HugeArray<T: Copy> {
    ptr: NonNull<T>,
    len: usize,
    layout: Layout,
}

// SAFETY: the block is owned (freed once, in Drop) and never written after creation.
unsafe impl<T: Copy + Send> Send for HugeArray<T> {}
// SAFETY: as above: shared references only read.
unsafe impl<T: Copy + Sync> Sync for HugeArray<T> {}

impl<T: Copy> HugeArray<T> {
    /// A copy of `values`; `None` when the allocation fails (the caller keeps its Vec).
    pub fn copy_of(values: &[T]) -> Option<Self> {
        let bytes = core::mem::size_of_val(values).max(1).next_multiple_of(HUGE);
        let layout = Layout::from_size_align(bytes, HUGE.max(core::mem::align_of::<T>())).ok()?;
        // SAFETY: a non-zero size.
        let ptr = NonNull::new(unsafe { alloc::alloc(layout) })?;
        #[cfg(target_os = "linux")]
        // SAFETY: the whole block just allocated; advice only, its failure changes nothing.
        unsafe {
            libc::madvise(ptr.as_ptr().cast(), bytes, libc::MADV_HUGEPAGE);
        }
        let ptr = ptr.cast::<T>();
        // SAFETY: the block holds `bytes` >= size_of_val(values), aligned for T; the two do
        // not overlap (the block is new).
        unsafe { core::ptr::copy_nonoverlapping(values.as_ptr(), ptr.as_ptr(), values.len()) };
        Some(Self {
            ptr,
            len: values.len(),
            layout,
        })
    }
}

impl<T: Copy> core::ops::Deref for HugeArray<T> {
    type Target = [T];
    fn deref(&self) -> &[T] {
        // SAFETY: `len` values written at creation, alive until Drop.
        unsafe { core::slice::from_raw_parts(self.ptr.as_ptr(), self.len) }
    }
}

impl<T: Copy> Drop for HugeArray<T> {
    fn drop(&mut self) {
        // SAFETY: allocated with this layout, freed once.
        unsafe { alloc::dealloc(self.ptr.as_ptr().cast(), self.layout) };
    }
}

impl<T: Copy> Clone for HugeArray<T> {
    fn clone(&self) -> Self {
        Self::copy_of(self).unwrap_or_else(|| alloc::handle_alloc_error(self.layout))
    }
}

impl<T: Copy + core::fmt::Debug> core::fmt::Debug for HugeArray<T> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_list().entries(self.iter()).finish()
    }
}

impl<T: Copy + PartialEq> PartialEq for HugeArray<T> {
    fn eq(&self, other: &Self) -> bool {
        self[..] == other[..]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn holds_a_copy_aligned_to_a_huge_page() {
        let v: Vec<u64> = (0..1000).collect();
        let h = HugeArray::copy_of(&v).unwrap();
        assert_eq!(&h[..], &v[..]);
        assert_eq!(h.as_ptr() as usize % HUGE, 0);
        assert_eq!(h.clone(), h);
        let empty = HugeArray::<u64>::copy_of(&[]).unwrap();
        assert!(empty.is_empty());
    }
}
