// SPDX-License-Identifier: GPL-2.0

//! A fixed-capacity ring of fixed-size records, the storage behind the
//! RT-FIFOs (frames) and the simulator's position log (log records).
//! Allocated once at insmod; pushing never allocates.

use kernel::prelude::*;

pub(crate) struct Ring<const REC: usize> {
    slots: KVec<[u8; REC]>,
    lens: KVec<u16>,
    head: usize,
    len: usize,
    /// Records overwritten (oldest dropped) or refused because the ring was full.
    pub(crate) dropped: u64,
    /// Records pushed in total.
    pub(crate) pushed: u64,
}

impl<const REC: usize> Ring<REC> {
    pub(crate) fn new(capacity: usize) -> Result<Self> {
        let mut slots = KVec::with_capacity(capacity, GFP_KERNEL)?;
        let mut lens = KVec::with_capacity(capacity, GFP_KERNEL)?;
        for _ in 0..capacity {
            slots.push([0u8; REC], GFP_KERNEL)?;
            lens.push(0u16, GFP_KERNEL)?;
        }
        Ok(Ring {
            slots,
            lens,
            head: 0,
            len: 0,
            dropped: 0,
            pushed: 0,
        })
    }

    pub(crate) fn capacity(&self) -> usize {
        self.slots.len()
    }

    pub(crate) fn len(&self) -> usize {
        self.len
    }

    pub(crate) fn is_full(&self) -> bool {
        self.len >= self.capacity()
    }

    /// Append `rec` (at most `REC` bytes); when full, the oldest record is
    /// dropped (counted). Returns false if a record was dropped.
    pub(crate) fn push_overwrite(&mut self, rec: &[u8]) -> bool {
        let cap = self.capacity();
        if cap == 0 || rec.len() > REC {
            self.dropped = self.dropped.saturating_add(1);
            return false;
        }
        let mut kept_all = true;
        if self.len == cap {
            self.head = self.head.wrapping_add(1) % cap;
            self.len = self.len.saturating_sub(1);
            self.dropped = self.dropped.saturating_add(1);
            kept_all = false;
        }
        let idx = self.head.wrapping_add(self.len) % cap;
        if let (Some(slot), Some(l)) = (self.slots.get_mut(idx), self.lens.get_mut(idx)) {
            slot[..rec.len()].copy_from_slice(rec);
            *l = rec.len() as u16;
            self.len = self.len.saturating_add(1);
            self.pushed = self.pushed.saturating_add(1);
        }
        kept_all
    }

    /// Append `rec` only if there is room; a full ring refuses it (counted).
    pub(crate) fn push_if_room(&mut self, rec: &[u8]) -> bool {
        if self.is_full() {
            self.dropped = self.dropped.saturating_add(1);
            return false;
        }
        self.push_overwrite(rec)
    }

    /// Remove the oldest record into `out`; its length.
    pub(crate) fn pop(&mut self, out: &mut [u8; REC]) -> Option<usize> {
        if self.len == 0 {
            return None;
        }
        let idx = self.head;
        let n = usize::from(*self.lens.get(idx)?);
        out.copy_from_slice(self.slots.get(idx)?);
        self.head = self.head.wrapping_add(1) % self.capacity().max(1);
        self.len = self.len.saturating_sub(1);
        Some(n)
    }

    pub(crate) fn clear(&mut self) {
        self.head = 0;
        self.len = 0;
    }
}
