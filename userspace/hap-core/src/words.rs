//! One walk over the words of a published record, for both directions.
//!
//! The kernel publishes small records (PROTO_IN's counters, the VPr latch)
//! as `u64` words under a seqcount. Each record's layout is one
//! `visit_words` function next to its type that hands every word to a
//! closure as `(index, &mut value)`: reading `*value` encodes, writing it
//! decodes, so the two directions cannot disagree. [`WordWalk`] numbers the
//! words and converts the field types.

use super::fixed::Fx;

/// Numbers the words of one walk and hands each to `f`.
pub struct WordWalk<F> {
    next: usize,
    f: F,
}

impl<F: FnMut(usize, &mut u64)> WordWalk<F> {
    /// A walk starting at word `first`.
    pub const fn new(first: usize, f: F) -> Self {
        WordWalk { next: first, f }
    }

    /// Words visited so far (the index of the next one).
    pub const fn next_index(&self) -> usize {
        self.next
    }

    /// The closure back (to hand on to a nested record's walk).
    pub fn into_inner(self) -> F {
        self.f
    }

    pub fn word(&mut self, w: &mut u64) {
        (self.f)(self.next, w);
        self.next = self.next.saturating_add(1);
    }

    pub fn words(&mut self, ws: &mut [u64]) {
        for w in ws {
            self.word(w);
        }
    }

    /// An `Fx` as its bits.
    pub fn fx(&mut self, x: &mut Fx) {
        let mut w = x.0 as u64;
        self.word(&mut w);
        x.0 = w as i64;
    }

    /// A `u32` (a decoded word out of range reads as 0).
    pub fn u32(&mut self, x: &mut u32) {
        let mut w = u64::from(*x);
        self.word(&mut w);
        *x = u32::try_from(w).unwrap_or(0);
    }

    /// A `u16` (a decoded word out of range reads as 0).
    pub fn u16(&mut self, x: &mut u16) {
        let mut w = u64::from(*x);
        self.word(&mut w);
        *x = u16::try_from(w).unwrap_or(0);
    }

    /// A `bool` (any non-zero word reads as `true`).
    pub fn bool(&mut self, x: &mut bool) {
        let mut w = u64::from(*x);
        self.word(&mut w);
        *x = w != 0;
    }
}

/// Test helpers: a record's words as an array and back, checking that the
/// walk visits `0..N` in order.
#[cfg(test)]
pub(crate) mod check {
    pub(crate) fn to_words<const N: usize>(
        visit: impl FnOnce(&mut dyn FnMut(usize, &mut u64)),
    ) -> [u64; N] {
        let mut out = [0u64; N];
        let mut seen = 0usize;
        visit(&mut |i, w| {
            assert_eq!(i, seen, "words visited in order");
            out[i] = *w;
            seen += 1;
        });
        assert_eq!(seen, N, "every word visited once");
        out
    }
}
