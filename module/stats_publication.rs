// SPDX-License-Identifier: GPL-2.0

//! CLOCK's statistics and their publication to /dev/hap_stats and
//! /dev/hap_hist.
//!
//! Protocol: CLOCK takes its own `HapStats` once when it starts
//! ([`StatsPublication::take_for_clock`]) and from then on is the only
//! writer of the published words (a seqcount over `u64` words, hap-core's
//! `HapStats::visit_words` layout), once per period. Readers copy the
//! words into their own allocation and never block CLOCK: a copy that
//! overlaps a write is retried, and one that overlapped on every attempt
//! is counted in `read_busy` and refused (`EBUSY`).

use crate::{
    hap_core::{
        seqlock::{self, SeqWords},
        stats::{HapStats, WordSet, STATS_WORDS},
    },
    ring::{storage, AtomicU64},
};
use kernel::{
    new_mutex,
    prelude::*,
    sync::{
        atomic::{Atomic, Relaxed},
        Mutex,
    },
};
use pin_init::init_zeroed;

// SAFETY: every field of `HapStats` is an integer, a `bool` or an array or
// struct of them (see hap-core's stats.rs, which builds it from zeroes in
// `HapStats::reset`'s test): all-zero is a valid value.
unsafe impl Zeroable for HapStats {}

/// A `HapStats` built in its allocation (zeroed in place, then reset): the
/// ~24 KiB never touch the stack.
pub(crate) fn new_stats(period_us: u32) -> Result<KBox<HapStats>> {
    let mut st = KBox::<HapStats>::init(init_zeroed(), GFP_KERNEL)?;
    st.reset(period_us);
    Ok(st)
}

/// Read attempts before a statistics read gives up (each copies ~3 000
/// words; CLOCK writes a few dozen once per period).
const STATS_READ_ATTEMPTS: usize = 1000;

#[pin_data]
pub(crate) struct StatsPublication {
    /// CLOCK's own statistics until CLOCK takes them.
    #[pin]
    clock_stats: Mutex<Option<KBox<HapStats>>>,
    words: SeqWords<KVVec<AtomicU64>>,
    read_busy: Atomic<u64>,
}

/// CLOCK's statistics, held by CLOCK with the publication's writer role:
/// the only writer of the publication.
pub(crate) struct StatsWriter<'a> {
    writer: seqlock::Writer<'a, KVVec<AtomicU64>>,
    pub(crate) stats: KBox<HapStats>,
}

impl StatsWriter<'_> {
    /// Publish the statistics (`set`: what changed since the last time).
    pub(crate) fn publish(&mut self, set: WordSet) {
        let w = self.writer.write();
        self.stats.visit_words(set, |i, v| w.set(i, *v));
    }
}

impl StatsPublication {
    pub(crate) fn new(period_us: u32) -> Result<impl PinInit<Self, Error>> {
        let mut own = new_stats(period_us)?;
        let words = SeqWords::new(storage(STATS_WORDS)?);
        // The first publication, before anybody can claim the role.
        if let Some(mut writer) = words.claim_writer() {
            let w = writer.write();
            own.visit_words(WordSet::All, |i, v| w.set(i, *v));
        }
        Ok(try_pin_init!(Self {
            clock_stats <- new_mutex!(Some(own)),
            words,
            read_busy: Atomic::new(0),
        }? Error))
    }

    /// CLOCK, once: its statistics and the right to publish them. `None`
    /// if they were already taken.
    pub(crate) fn take_for_clock(&self) -> Option<StatsWriter<'_>> {
        let writer = self.words.claim_writer()?;
        let stats = self.clock_stats.lock().take()?;
        Some(StatsWriter { writer, stats })
    }

    /// Copy the published statistics into `st` (built by `new_stats`),
    /// through `words` (`STATS_WORDS` long). Never blocks CLOCK: retries
    /// while a copy overlaps a write; `EBUSY` if every attempt did.
    pub(crate) fn read(&self, words: &mut [u64], st: &mut HapStats) -> Result {
        if self.words.read(words, STATS_READ_ATTEMPTS).is_none() {
            self.read_busy.add(1, Relaxed);
            return Err(EBUSY);
        }
        st.load_words(words);
        Ok(())
    }

    pub(crate) fn read_busy(&self) -> u64 {
        self.read_busy.load(Relaxed)
    }
}
