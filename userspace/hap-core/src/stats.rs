//! Timing statistics and counters, integer only (spec §3.4: "perform
//! jitters computation and update statistics"), and their text rendering
//! for `cat /dev/hap_stats` plus a parser for that text (hapctl).
//!
//! Three timing series, each with min/avg/max in ns and a 1 µs-bucket
//! histogram (`HIST_BUCKETS` buckets for 0..999 µs + an overflow count)
//! giving p50/p99/p99.9 in µs:
//! - `wakeup`: SERVO wake-up latency after CLOCK released it;
//! - `exec`: SERVO cycle execution time;
//! - `jitter`: |actual period − nominal period| of CLOCK's tops, with the
//!   signed extremes kept apart.
//!
//! Counters and histogram buckets are `u64`: at 1 kHz a u32 bucket would
//! saturate after ~49.7 days.
//!
//! Size: one [`TimingStat`] is ~8 KiB, [`HapStats`] ~24.3 KiB — allocate it
//! (kernel: built in place in its allocation, never on the stack; see
//! [`HapStats::reset`]).
//!
//! Publication: CLOCK records into its own `HapStats` and publishes it as
//! `STATS_WORDS` `u64` words ([`HapStats::visit_words`]) through a
//! [`crate::seqlock::SeqWords`]; readers copy the words and decode them into
//! their own `HapStats` with the same visitor.
//!
//! Text format (one `key: value` per line, `#` lines are comments,
//! values are decimal integers; see [`render_summary`]).

use core::fmt::{self, Write};

use super::clock::Verdict;
use super::protocol::{DecodeError, REASON_NAMES};

/// Histogram buckets, 1 µs each: bucket `i` counts values in [i, i+1) µs.
pub const HIST_BUCKETS: usize = 1000;

/// Version of the text format (`version:` line).
pub const TEXT_VERSION: u64 = 1;

/// A buffer big enough for [`HapStats::render`].
pub const RENDER_MAX: usize = 4096;

/// 1 µs-bucket histogram with overflow count.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Histogram {
    buckets: [u64; HIST_BUCKETS],
    overflow: u64,
    count: u64,
    /// Bucket of the last value recorded (`HIST_BUCKETS`: none or overflow),
    /// for publishing only what changed.
    last: u64,
}

impl Default for Histogram {
    fn default() -> Self {
        Self::new()
    }
}

impl Histogram {
    pub const fn new() -> Self {
        Histogram {
            buckets: [0; HIST_BUCKETS],
            overflow: 0,
            count: 0,
            last: HIST_BUCKETS as u64,
        }
    }

    /// Count one value given in µs (values ≥ `HIST_BUCKETS` go to overflow).
    pub fn record_us(&mut self, us: u64) {
        self.count = self.count.saturating_add(1);
        let slot = usize::try_from(us)
            .ok()
            .and_then(|i| self.buckets.get_mut(i));
        match slot {
            Some(b) => {
                *b = b.saturating_add(1);
                self.last = us;
            }
            None => {
                self.overflow = self.overflow.saturating_add(1);
                self.last = HIST_BUCKETS as u64;
            }
        }
    }

    /// Values recorded.
    pub const fn count(&self) -> u64 {
        self.count
    }

    /// Values ≥ `HIST_BUCKETS` µs.
    pub const fn overflow(&self) -> u64 {
        self.overflow
    }

    /// Count of bucket `i` (0 if out of range).
    pub fn bucket(&self, i: usize) -> u64 {
        self.buckets.get(i).copied().unwrap_or(0)
    }

    /// All `HIST_BUCKETS` buckets (bucket `i`: values in [i, i+1) µs).
    pub fn buckets(&self) -> &[u64] {
        &self.buckets
    }

    /// The `num/den` quantile in µs: the smallest bucket `v` such that at
    /// least ⌈count·num/den⌉ (≥ 1) values are ≤ `v`. Returns
    /// `HIST_BUCKETS` if that rank falls in the overflow, 0 when empty.
    pub fn quantile_us(&self, num: u64, den: u64) -> u32 {
        if self.count == 0 || den == 0 {
            return 0;
        }
        let prod = self.count.saturating_mul(num.min(den));
        // ⌈prod / den⌉ (`div_ceil` adds with an overflow check).
        let rank = (prod / den)
            .saturating_add(u64::from(prod % den != 0))
            .max(1);
        let mut cum: u64 = 0;
        for (i, &b) in (0..HIST_BUCKETS as u32).zip(self.buckets.iter()) {
            cum = cum.saturating_add(b);
            if cum >= rank {
                return i;
            }
        }
        HIST_BUCKETS as u32
    }

    /// Empty it, in place (no temporary on the stack).
    pub fn clear(&mut self) {
        self.buckets.fill(0);
        self.overflow = 0;
        self.count = 0;
        self.last = HIST_BUCKETS as u64;
    }
}

/// min/avg/max (ns) + histogram (µs) of one timing series.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct TimingStat {
    min_ns: u64,
    max_ns: u64,
    sum_ns: u64,
    last_ns: u64,
    hist: Histogram,
}

/// p50 in parts per million.
pub const P50: u64 = 500_000;
/// p99 in parts per million.
pub const P99: u64 = 990_000;
/// p99.9 in parts per million.
pub const P999: u64 = 999_000;
const PPM: u64 = 1_000_000;

impl TimingStat {
    pub const fn new() -> Self {
        TimingStat {
            min_ns: u64::MAX,
            max_ns: 0,
            sum_ns: 0,
            last_ns: 0,
            hist: Histogram::new(),
        }
    }

    pub fn record_ns(&mut self, ns: u64) {
        if ns < self.min_ns {
            self.min_ns = ns;
        }
        if ns > self.max_ns {
            self.max_ns = ns;
        }
        self.sum_ns = self.sum_ns.saturating_add(ns);
        self.last_ns = ns;
        self.hist.record_us(ns / 1_000);
    }

    pub const fn count(&self) -> u64 {
        self.hist.count
    }

    /// 0 when empty.
    pub const fn min_ns(&self) -> u64 {
        if self.hist.count == 0 {
            0
        } else {
            self.min_ns
        }
    }

    pub const fn max_ns(&self) -> u64 {
        self.max_ns
    }

    pub const fn last_ns(&self) -> u64 {
        self.last_ns
    }

    /// Mean, rounded down; 0 when empty (the sum saturates at ~584 years).
    pub const fn avg_ns(&self) -> u64 {
        match self.sum_ns.checked_div(self.hist.count) {
            Some(a) => a,
            None => 0,
        }
    }

    pub fn histogram(&self) -> &Histogram {
        &self.hist
    }

    pub fn summary(&self) -> TimingSummary {
        TimingSummary {
            count: self.count(),
            min_ns: self.min_ns(),
            avg_ns: self.avg_ns(),
            max_ns: self.max_ns,
            p50_us: self.hist.quantile_us(P50, PPM),
            p99_us: self.hist.quantile_us(P99, PPM),
            p999_us: self.hist.quantile_us(P999, PPM),
            overflow: self.hist.overflow,
        }
    }

    /// Empty it, in place.
    pub fn clear(&mut self) {
        self.min_ns = u64::MAX;
        self.max_ns = 0;
        self.sum_ns = 0;
        self.last_ns = 0;
        self.hist.clear();
    }
}

/// Period jitter of CLOCK's tops.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct PeriodJitter {
    nominal_ns: u64,
    /// The previous top (valid once `has_last_top`).
    last_top_ns: u64,
    has_last_top: bool,
    min_ns: i64,
    max_ns: i64,
    abs: TimingStat,
}

impl PeriodJitter {
    pub const fn new(nominal_ns: u64) -> Self {
        PeriodJitter {
            nominal_ns,
            last_top_ns: 0,
            has_last_top: false,
            min_ns: 0,
            max_ns: 0,
            abs: TimingStat::new(),
        }
    }

    /// A CLOCK top at monotonic time `now_ns`. The first top only sets the
    /// reference. Returns the signed jitter (actual − nominal period, ns).
    pub fn top(&mut self, now_ns: u64) -> Option<i64> {
        let last = self.last_top_ns;
        self.last_top_ns = now_ns;
        if !core::mem::replace(&mut self.has_last_top, true) {
            return None;
        }
        let actual = now_ns.wrapping_sub(last);
        let j = i64::try_from(actual)
            .unwrap_or(i64::MAX)
            .saturating_sub(i64::try_from(self.nominal_ns).unwrap_or(i64::MAX));
        if self.abs.count() == 0 {
            self.min_ns = j;
            self.max_ns = j;
        } else {
            self.min_ns = self.min_ns.min(j);
            self.max_ns = self.max_ns.max(j);
        }
        self.abs.record_ns(j.unsigned_abs());
        Some(j)
    }

    /// Most negative jitter seen (0 before two tops).
    pub const fn min_ns(&self) -> i64 {
        self.min_ns
    }

    /// Most positive jitter seen.
    pub const fn max_ns(&self) -> i64 {
        self.max_ns
    }

    /// |jitter| statistics.
    pub fn abs(&self) -> &TimingStat {
        &self.abs
    }
}

/// Event counters.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counters {
    /// Supervisor checks (one per period).
    pub cycles: u64,
    /// Deadline misses.
    pub misses: u64,
    pub max_consecutive_misses: u64,
    /// Cycles run on the auxiliary (degraded) path.
    pub degraded_cycles: u64,
    /// 1 once fail-safe has been engaged.
    pub fail_safe: u64,
    /// Frames decoded successfully.
    pub frames_in: u64,
    /// Answer frames handed to rtf_out.
    pub frames_out: u64,
    /// Rejected frames, by `DecodeError::reason_index`.
    pub frames_rejected: [u64; DecodeError::COUNT],
    /// Answer frames not sent (protocol lock busy or FIFO full).
    pub answers_dropped: u64,
    /// Cycles where VPr was extrapolated (lock busy or frame late).
    pub vpr_extrapolated: u64,
}

impl Counters {
    /// Sum of `frames_rejected`.
    pub fn rejected_total(&self) -> u64 {
        self.frames_rejected
            .iter()
            .fold(0u64, |a, &b| a.saturating_add(b))
    }
}

/// Everything the text shows, without histograms.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TimingSummary {
    pub count: u64,
    pub min_ns: u64,
    pub avg_ns: u64,
    pub max_ns: u64,
    pub p50_us: u32,
    pub p99_us: u32,
    pub p999_us: u32,
    pub overflow: u64,
}

/// The content of `/dev/hap_stats`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StatsSummary {
    pub period_us: u32,
    pub counters: Counters,
    pub wakeup: TimingSummary,
    pub exec: TimingSummary,
    /// |period − nominal| statistics.
    pub jitter: TimingSummary,
    /// Signed jitter extremes, ns.
    pub jitter_min_ns: i64,
    pub jitter_max_ns: i64,
}

/// All statistics of a running controller.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct HapStats {
    pub period_us: u32,
    pub wakeup: TimingStat,
    pub exec: TimingStat,
    pub jitter: PeriodJitter,
    pub counters: Counters,
}

impl HapStats {
    pub const fn new(period_us: u32) -> Self {
        HapStats {
            period_us,
            wakeup: TimingStat::new(),
            exec: TimingStat::new(),
            jitter: PeriodJitter::new((period_us as u64) * 1_000),
            counters: Counters {
                cycles: 0,
                misses: 0,
                max_consecutive_misses: 0,
                degraded_cycles: 0,
                fail_safe: 0,
                frames_in: 0,
                frames_out: 0,
                frames_rejected: [0; DecodeError::COUNT],
                answers_dropped: 0,
                vpr_extrapolated: 0,
            },
        }
    }

    /// Account one supervisor verdict (CLOCK, once per period).
    pub fn record_verdict(&mut self, v: &Verdict) {
        let c = &mut self.counters;
        match *v {
            Verdict::Good { mode } => {
                c.cycles = c.cycles.saturating_add(1);
                if mode == super::mode::Mode::Degraded {
                    c.degraded_cycles = c.degraded_cycles.saturating_add(1);
                }
            }
            Verdict::Miss { consecutive } => {
                c.cycles = c.cycles.saturating_add(1);
                c.misses = c.misses.saturating_add(1);
                c.degraded_cycles = c.degraded_cycles.saturating_add(1);
                c.max_consecutive_misses = c.max_consecutive_misses.max(u64::from(consecutive));
            }
            Verdict::FailSafe(cause) => {
                if c.fail_safe == 0 {
                    c.cycles = c.cycles.saturating_add(1);
                    if cause == super::clock::FailSafeCause::MissLimit {
                        c.misses = c.misses.saturating_add(1);
                        c.max_consecutive_misses = c
                            .max_consecutive_misses
                            .max(u64::from(super::clock::MISS_LIMIT));
                    }
                }
                c.fail_safe = 1;
            }
        }
    }

    /// Account one cycle's timestamps (ns on one monotonic clock), taken by
    /// CLOCK at its check: the timer's scheduled expiry, its callback's run
    /// time, SERVO's start and end. SERVO's wake-up latency counts only if it
    /// started this cycle (`start >= expiry`), its execution time only if it
    /// also finished (`finished`).
    pub fn record_cycle(
        &mut self,
        expiry_ns: i64,
        tick_ns: i64,
        start_ns: i64,
        end_ns: i64,
        finished: bool,
    ) {
        if start_ns >= expiry_ns {
            self.wakeup
                .record_ns(start_ns.saturating_sub(expiry_ns).unsigned_abs());
            if finished && end_ns >= start_ns {
                self.exec
                    .record_ns(end_ns.saturating_sub(start_ns).unsigned_abs());
            }
        }
        if tick_ns > 0 {
            self.jitter.top(tick_ns.unsigned_abs());
        }
    }

    /// Account a rejected frame.
    pub fn record_reject(&mut self, e: DecodeError) {
        if let Some(n) = self.counters.frames_rejected.get_mut(e.reason_index()) {
            *n = n.saturating_add(1);
        }
    }

    pub fn summary(&self) -> StatsSummary {
        StatsSummary {
            period_us: self.period_us,
            counters: self.counters,
            wakeup: self.wakeup.summary(),
            exec: self.exec.summary(),
            jitter: self.jitter.abs().summary(),
            jitter_min_ns: self.jitter.min_ns(),
            jitter_max_ns: self.jitter.max_ns(),
        }
    }

    /// Render the text of `/dev/hap_stats` into `out`; see [`render_summary`].
    pub fn render(&self, out: &mut [u8]) -> Rendered {
        render_summary(&self.summary(), out)
    }
}

/// A `core::fmt::Write` into a byte slice; output past the end is dropped
/// and `truncated` set.
#[derive(Debug)]
pub struct SliceWriter<'a> {
    buf: &'a mut [u8],
    pos: usize,
    truncated: bool,
}

impl<'a> SliceWriter<'a> {
    pub fn new(buf: &'a mut [u8]) -> Self {
        SliceWriter {
            buf,
            pos: 0,
            truncated: false,
        }
    }

    pub fn len(&self) -> usize {
        self.pos
    }

    pub fn is_empty(&self) -> bool {
        self.pos == 0
    }

    pub fn truncated(&self) -> bool {
        self.truncated
    }
}

impl Write for SliceWriter<'_> {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        let room = self.buf.len().saturating_sub(self.pos);
        let n = s.len().min(room);
        let end = self.pos.saturating_add(n);
        if let (Some(dst), Some(src)) = (self.buf.get_mut(self.pos..end), s.as_bytes().get(..n)) {
            for (d, b) in dst.iter_mut().zip(src) {
                *d = *b;
            }
            self.pos = end;
        }
        if n < s.len() {
            self.truncated = true;
            return Err(fmt::Error);
        }
        Ok(())
    }
}

/// Outcome of a rendering.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rendered {
    /// Bytes written.
    pub len: usize,
    /// The buffer was too small (output cut at `len`).
    pub truncated: bool,
}

fn write_timing(w: &mut SliceWriter<'_>, name: &str, t: &TimingSummary) -> fmt::Result {
    writeln!(w, "{name}.count: {}", t.count)?;
    writeln!(w, "{name}.min_ns: {}", t.min_ns)?;
    writeln!(w, "{name}.avg_ns: {}", t.avg_ns)?;
    writeln!(w, "{name}.max_ns: {}", t.max_ns)?;
    writeln!(w, "{name}.p50_us: {}", t.p50_us)?;
    writeln!(w, "{name}.p99_us: {}", t.p99_us)?;
    writeln!(w, "{name}.p99_9_us: {}", t.p999_us)?;
    writeln!(w, "{name}.overflow: {}", t.overflow)
}

fn write_all(w: &mut SliceWriter<'_>, s: &StatsSummary) -> fmt::Result {
    let c = &s.counters;
    writeln!(w, "# hapticctrl statistics (times: *_ns in ns, *_us in us; p*_us = {HIST_BUCKETS} means >= {HIST_BUCKETS} us)")?;
    // cyclictest-style one-liners (comments: the key lines below are the API).
    writeln!(
        w,
        "# T: 0 (servo) I:{} C:{} Min:{} Avg:{} Max:{} (wakeup, us)",
        s.period_us,
        s.wakeup.count,
        s.wakeup.min_ns / 1000,
        s.wakeup.avg_ns / 1000,
        s.wakeup.max_ns / 1000
    )?;
    writeln!(w, "version: {TEXT_VERSION}")?;
    writeln!(w, "period_us: {}", s.period_us)?;
    writeln!(w, "cycles: {}", c.cycles)?;
    writeln!(w, "misses: {}", c.misses)?;
    writeln!(w, "max_consecutive_misses: {}", c.max_consecutive_misses)?;
    writeln!(w, "degraded_cycles: {}", c.degraded_cycles)?;
    writeln!(w, "fail_safe: {}", c.fail_safe)?;
    writeln!(w, "frames_in: {}", c.frames_in)?;
    writeln!(w, "frames_out: {}", c.frames_out)?;
    writeln!(w, "frames_rejected: {}", c.rejected_total())?;
    for (name, n) in REASON_NAMES.iter().zip(c.frames_rejected.iter()) {
        writeln!(w, "rejected.{name}: {n}")?;
    }
    writeln!(w, "answers_dropped: {}", c.answers_dropped)?;
    writeln!(w, "vpr_extrapolated: {}", c.vpr_extrapolated)?;
    write_timing(w, "wakeup", &s.wakeup)?;
    write_timing(w, "exec", &s.exec)?;
    write_timing(w, "jitter", &s.jitter)?;
    writeln!(w, "jitter.signed_min_ns: {}", s.jitter_min_ns)?;
    writeln!(w, "jitter.signed_max_ns: {}", s.jitter_max_ns)
}

/// Names of the timing series of [`HapStats::histograms`], in that order.
pub const HIST_SERIES: [&str; 3] = ["wakeup", "exec", "jitter"];

/// A buffer big enough for [`render_histograms`] of [`HIST_SERIES`]: every
/// bucket of every series non-zero, each line at most
/// `"jitter.hist_us.999: 18446744073709551615\n"` (41 bytes), plus headers.
pub const HIST_RENDER_MAX: usize = HIST_SERIES.len() * (HIST_BUCKETS * 42 + 128) + 256;

impl HapStats {
    /// The histograms of the three series, named as in [`HIST_SERIES`]
    /// (`jitter` is |actual − nominal period|).
    pub fn histograms(&self) -> [(&'static str, &Histogram); 3] {
        [
            (HIST_SERIES[0], self.wakeup.histogram()),
            (HIST_SERIES[1], self.exec.histogram()),
            (HIST_SERIES[2], self.jitter.abs().histogram()),
        ]
    }
}

/// Which histogram buckets [`HapStats::visit_words`] visits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WordSet {
    /// Every word.
    All,
    /// Every scalar, and of each histogram only the bucket of the last value
    /// recorded: what one `record_cycle` + `record_verdict` can change.
    Recent,
}

/// Words of one [`TimingStat`]: min, max, sum, last, count, overflow, last
/// bucket, then the buckets.
const TIMING_WORDS: usize = 7 + HIST_BUCKETS;
/// Words of [`Counters`].
const COUNTER_WORDS: usize = 9 + DecodeError::COUNT;
/// Words of [`HapStats`] as [`HapStats::visit_words`] lays them out.
pub const STATS_WORDS: usize = 1 + COUNTER_WORDS + 2 * TIMING_WORDS + 5 + TIMING_WORDS;

/// Walks the word layout, handing each visited word to `f` by index.
struct Visitor<F> {
    next: usize,
    set: WordSet,
    f: F,
}

impl<F: FnMut(usize, &mut u64)> Visitor<F> {
    fn word(&mut self, v: &mut u64) {
        (self.f)(self.next, v);
        self.next = self.next.saturating_add(1);
    }

    fn u32(&mut self, v: &mut u32) {
        let mut w = u64::from(*v);
        self.word(&mut w);
        *v = u32::try_from(w).unwrap_or(u32::MAX);
    }

    fn i64(&mut self, v: &mut i64) {
        let mut w = *v as u64;
        self.word(&mut w);
        *v = w as i64;
    }

    fn bool(&mut self, v: &mut bool) {
        let mut w = u64::from(*v);
        self.word(&mut w);
        *v = w != 0;
    }

    fn timing(&mut self, t: &mut TimingStat) {
        self.word(&mut t.min_ns);
        self.word(&mut t.max_ns);
        self.word(&mut t.sum_ns);
        self.word(&mut t.last_ns);
        let h = &mut t.hist;
        self.word(&mut h.count);
        self.word(&mut h.overflow);
        self.word(&mut h.last);
        let base = self.next;
        match self.set {
            WordSet::All => {
                for b in h.buckets.iter_mut() {
                    self.word(b);
                }
            }
            WordSet::Recent => {
                let i = usize::try_from(h.last).unwrap_or(HIST_BUCKETS);
                if let Some(b) = h.buckets.get_mut(i) {
                    self.next = base.saturating_add(i);
                    self.word(b);
                }
            }
        }
        self.next = base.saturating_add(HIST_BUCKETS);
    }
}

impl HapStats {
    /// Reset to [`HapStats::new`]`(period_us)` in place: for a `HapStats`
    /// built in its allocation (all-zero memory is a valid `HapStats`: every
    /// field is an integer, a bool or an array of them), without the ~24 KiB
    /// temporary that `new` would put on the stack.
    pub fn reset(&mut self, period_us: u32) {
        self.period_us = period_us;
        self.wakeup.clear();
        self.exec.clear();
        let j = &mut self.jitter;
        j.nominal_ns = u64::from(period_us).saturating_mul(1_000);
        j.last_top_ns = 0;
        j.has_last_top = false;
        j.min_ns = 0;
        j.max_ns = 0;
        j.abs.clear();
        self.counters = Counters::default();
    }

    /// Visit the words of the published layout (`STATS_WORDS` of them, word
    /// `i` handed to `f` as `(i, &mut value)`): reading `*value` encodes,
    /// writing it decodes. With [`WordSet::Recent`] only what the last
    /// record can have changed is visited.
    pub fn visit_words(&mut self, set: WordSet, f: impl FnMut(usize, &mut u64)) {
        let mut v = Visitor { next: 0, set, f };
        v.u32(&mut self.period_us);
        let c = &mut self.counters;
        v.word(&mut c.cycles);
        v.word(&mut c.misses);
        v.word(&mut c.max_consecutive_misses);
        v.word(&mut c.degraded_cycles);
        v.word(&mut c.fail_safe);
        v.word(&mut c.frames_in);
        v.word(&mut c.frames_out);
        for r in c.frames_rejected.iter_mut() {
            v.word(r);
        }
        v.word(&mut c.answers_dropped);
        v.word(&mut c.vpr_extrapolated);
        v.timing(&mut self.wakeup);
        v.timing(&mut self.exec);
        let j = &mut self.jitter;
        v.word(&mut j.nominal_ns);
        v.word(&mut j.last_top_ns);
        v.bool(&mut j.has_last_top);
        v.i64(&mut j.min_ns);
        v.i64(&mut j.max_ns);
        v.timing(&mut j.abs);
    }

    /// Encode every word into `out` (`STATS_WORDS` long; extra words are
    /// left alone, missing ones skipped).
    pub fn to_words(&mut self, out: &mut [u64]) {
        self.visit_words(WordSet::All, |i, w| {
            if let Some(o) = out.get_mut(i) {
                *o = *w;
            }
        });
    }

    /// Decode from `words` (as [`HapStats::to_words`] wrote them).
    pub fn load_words(&mut self, words: &[u64]) {
        self.visit_words(WordSet::All, |i, w| {
            if let Some(v) = words.get(i) {
                *w = *v;
            }
        });
    }
}

/// One series for [`render_histograms`]: its name, its `HIST_BUCKETS`
/// buckets (copied out of [`HapStats`] under its lock) and its overflow.
#[derive(Clone, Copy, Debug)]
pub struct HistogramView<'a> {
    pub name: &'a str,
    pub buckets: &'a [u64],
    pub overflow: u64,
}

fn write_histograms(w: &mut SliceWriter<'_>, series: &[HistogramView<'_>]) -> fmt::Result {
    writeln!(
        w,
        "# hapticctrl histograms: <series>.hist_us.<i>: count of values in [i, i+1) us, non-zero buckets only; <series>.hist_overflow: values >= {HIST_BUCKETS} us"
    )?;
    writeln!(w, "version: {TEXT_VERSION}")?;
    for s in series {
        let mut total = s.overflow;
        for (i, &n) in s.buckets.iter().enumerate() {
            if n != 0 {
                writeln!(w, "{}.hist_us.{i}: {n}", s.name)?;
                total = total.saturating_add(n);
            }
        }
        writeln!(w, "{}.hist_overflow: {}", s.name, s.overflow)?;
        writeln!(w, "{}.hist_count: {total}", s.name)?;
    }
    Ok(())
}

/// Render histograms as `key: value` lines (`/dev/hap_hist`; cyclictest's
/// `-h` histogram in the stats device's shape). `HIST_RENDER_MAX` bytes
/// always fit the three series of [`HapStats`].
pub fn render_histograms(series: &[HistogramView<'_>], out: &mut [u8]) -> Rendered {
    let mut w = SliceWriter::new(out);
    let _ = write_histograms(&mut w, series);
    Rendered {
        len: w.len(),
        truncated: w.truncated(),
    }
}

/// The non-zero buckets `(µs, count)` of `series` in a [`render_histograms`]
/// text, in text order, plus its overflow as `(HIST_BUCKETS, overflow)` when
/// non-zero. Lines that are not of that series or do not parse are skipped.
pub fn histogram_entries<'a>(
    text: &'a str,
    series: &'a str,
) -> impl Iterator<Item = (u32, u64)> + 'a {
    key_values(text).filter_map(move |(k, v)| {
        let rest = k.strip_prefix(series)?;
        let n = v.parse::<u64>().ok()?;
        if let Some(us) = rest.strip_prefix(".hist_us.") {
            let us = us.parse::<u32>().ok()?;
            (us < HIST_BUCKETS as u32).then_some((us, n))
        } else if rest == ".hist_overflow" && n != 0 {
            Some((HIST_BUCKETS as u32, n))
        } else {
            None
        }
    })
}

/// Render `s` as `key: value` lines (≈1.4 KB; `RENDER_MAX` always fits).
pub fn render_summary(s: &StatsSummary, out: &mut [u8]) -> Rendered {
    let mut w = SliceWriter::new(out);
    let _ = write_all(&mut w, s);
    Rendered {
        len: w.len(),
        truncated: w.truncated(),
    }
}

/// Why the text could not be parsed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ParseErrorKind {
    /// A non-comment line without `": "`.
    NoColon,
    /// A value that is not a decimal integer of the field's type.
    BadNumber,
    /// `version:` missing or not `TEXT_VERSION`.
    BadVersion,
}

/// Parse error with its 1-based line number (0: whole text).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ParseError {
    pub line: usize,
    pub kind: ParseErrorKind,
}

/// `(before, after)` around the first ASCII byte `sep`.
fn split_at_byte(s: &str, sep: u8) -> Option<(&str, &str)> {
    let i = s.bytes().position(|b| b == sep)?;
    Some((s.get(..i)?, s.get(i.checked_add(1)?..)?))
}

fn set_timing(t: &mut TimingSummary, field: &str, v: &str) -> Result<bool, ParseErrorKind> {
    let u = || v.parse::<u64>().map_err(|_| ParseErrorKind::BadNumber);
    let u32v = || v.parse::<u32>().map_err(|_| ParseErrorKind::BadNumber);
    match field {
        "count" => t.count = u()?,
        "min_ns" => t.min_ns = u()?,
        "avg_ns" => t.avg_ns = u()?,
        "max_ns" => t.max_ns = u()?,
        "p50_us" => t.p50_us = u32v()?,
        "p99_us" => t.p99_us = u32v()?,
        "p99_9_us" => t.p999_us = u32v()?,
        "overflow" => t.overflow = u()?,
        _ => return Ok(false),
    }
    Ok(true)
}

fn set_field(s: &mut StatsSummary, key: &str, v: &str) -> Result<(), ParseErrorKind> {
    let u = || v.parse::<u64>().map_err(|_| ParseErrorKind::BadNumber);
    let i = || v.parse::<i64>().map_err(|_| ParseErrorKind::BadNumber);
    let c = &mut s.counters;
    match key {
        "version" => {
            if u()? != TEXT_VERSION {
                return Err(ParseErrorKind::BadVersion);
            }
        }
        "period_us" => s.period_us = v.parse::<u32>().map_err(|_| ParseErrorKind::BadNumber)?,
        "cycles" => c.cycles = u()?,
        "misses" => c.misses = u()?,
        "max_consecutive_misses" => c.max_consecutive_misses = u()?,
        "degraded_cycles" => c.degraded_cycles = u()?,
        "fail_safe" => c.fail_safe = u()?,
        "frames_in" => c.frames_in = u()?,
        "frames_out" => c.frames_out = u()?,
        "frames_rejected" => {
            u()?; // derived: the sum of the rejected.* lines
        }
        "answers_dropped" => c.answers_dropped = u()?,
        "vpr_extrapolated" => c.vpr_extrapolated = u()?,
        "jitter.signed_min_ns" => s.jitter_min_ns = i()?,
        "jitter.signed_max_ns" => s.jitter_max_ns = i()?,
        _ => {
            if let Some(reason) = key.strip_prefix("rejected.") {
                if let Some(idx) = REASON_NAMES.iter().position(|n| *n == reason) {
                    if let Some(slot) = c.frames_rejected.get_mut(idx) {
                        *slot = u()?;
                    }
                }
            } else if let Some((series, field)) = split_at_byte(key, b'.') {
                let t = match series {
                    "wakeup" => &mut s.wakeup,
                    "exec" => &mut s.exec,
                    "jitter" => &mut s.jitter,
                    _ => return Ok(()),
                };
                set_timing(t, field, v)?;
            }
            // Unknown keys are ignored (newer kernels may add lines).
        }
    }
    Ok(())
}

/// The `key: value` lines of a text in the `/dev/hap_stats` shape (also the
/// bridge's counters file), read leniently: lines without a colon or with an
/// empty key are skipped; keys and values are trimmed. For tools that show
/// or pick single values; [`parse_summary`] is the strict, typed reader.
pub fn key_values(text: &str) -> impl Iterator<Item = (&str, &str)> {
    text.lines().filter_map(|line| {
        let (k, v) = line.split_once(':')?;
        let k = k.trim();
        if k.is_empty() {
            None
        } else {
            Some((k, v.trim()))
        }
    })
}

/// Parse the text [`render_summary`] produces. Unknown keys are ignored;
/// missing keys keep their default (0); `version: 1` is required.
pub fn parse_summary(text: &str) -> Result<StatsSummary, ParseError> {
    let mut s = StatsSummary::default();
    let mut seen_version = false;
    let mut n: usize = 0;
    // Byte-wise splitting: no char searchers, no overflow-checked counters.
    for raw in text.as_bytes().split(|&b| b == b'\n') {
        n = n.saturating_add(1);
        let line = core::str::from_utf8(raw.trim_ascii()).unwrap_or("");
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let err = |kind| ParseError { line: n, kind };
        let (key, value) = split_at_byte(line, b':').ok_or(err(ParseErrorKind::NoColon))?;
        let (key, value) = (key.trim_ascii(), value.trim_ascii());
        if key == "version" {
            seen_version = true;
        }
        set_field(&mut s, key, value).map_err(err)?;
    }
    if !seen_version {
        return Err(ParseError {
            line: 0,
            kind: ParseErrorKind::BadVersion,
        });
    }
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::super::clock::FailSafeCause;
    use super::super::mode::Mode;
    use super::*;

    fn views(st: &HapStats) -> Vec<HistogramView<'_>> {
        st.histograms()
            .iter()
            .map(|(name, h)| HistogramView {
                name,
                buckets: h.buckets(),
                overflow: h.overflow(),
            })
            .collect()
    }

    #[test]
    fn histograms_render_and_parse_back_bucket_for_bucket() {
        let mut st = HapStats::new(1000);
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut expect: [std::collections::BTreeMap<u32, u64>; 3] = Default::default();
        for _ in 0..20_000 {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            let ns = seed % 1_200_000; // ~1/6 in the overflow
            st.wakeup.record_ns(ns);
            st.exec.record_ns(ns / 3);
            let us = (ns / 1000).min(HIST_BUCKETS as u64) as u32;
            *expect[0].entry(us).or_default() += 1;
            *expect[1].entry((ns / 3 / 1000) as u32).or_default() += 1;
        }
        let mut buf = vec![0u8; HIST_RENDER_MAX];
        let r = render_histograms(&views(&st), &mut buf);
        assert!(!r.truncated);
        let text = core::str::from_utf8(&buf[..r.len]).unwrap();
        for (i, name) in HIST_SERIES.iter().enumerate() {
            let got: std::collections::BTreeMap<u32, u64> = histogram_entries(text, name).collect();
            assert_eq!(got, expect[i], "{name}");
            let count: u64 = key_values(text)
                .find(|(k, _)| *k == format!("{name}.hist_count"))
                .map(|(_, v)| v.parse().unwrap())
                .unwrap();
            assert_eq!(count, expect[i].values().sum::<u64>(), "{name} count");
        }
        // "exec" must not pick up "exec2"-like prefixes nor other series.
        assert!(histogram_entries(text, "exe").next().is_none());
    }

    #[test]
    fn histograms_worst_case_fits_hist_render_max() {
        let full = [u64::MAX; HIST_BUCKETS];
        let series: Vec<HistogramView<'_>> = HIST_SERIES
            .iter()
            .map(|name| HistogramView {
                name,
                buckets: &full,
                overflow: u64::MAX,
            })
            .collect();
        let mut buf = vec![0u8; HIST_RENDER_MAX];
        let r = render_histograms(&series, &mut buf);
        assert!(!r.truncated, "{} bytes", r.len);
        let mut small = vec![0u8; r.len - 1];
        assert!(render_histograms(&series, &mut small).truncated);
    }

    fn reference_quantile(sorted_us: &[u64], num: u64, den: u64) -> u64 {
        let n = sorted_us.len() as u64;
        let rank = ((n * num).div_ceil(den)).max(1);
        sorted_us[(rank - 1) as usize].min(HIST_BUCKETS as u64)
    }

    #[test]
    fn quantiles_match_sorted_reference() {
        let mut seed = 0x1234_5678_9abc_def0u64;
        for len in [1usize, 2, 3, 10, 999, 1000, 1001, 12345] {
            let mut t = TimingStat::new();
            let mut v = Vec::new();
            for _ in 0..len {
                seed ^= seed << 13;
                seed ^= seed >> 7;
                seed ^= seed << 17;
                let ns = seed % 1_300_000; // some land in the overflow
                t.record_ns(ns);
                v.push(ns);
            }
            let mut us: Vec<u64> = v.iter().map(|x| x / 1000).collect();
            us.sort_unstable();
            for (num, den) in [(P50, PPM), (P99, PPM), (P999, PPM), (1, 1), (0, 1), (1, 3)] {
                assert_eq!(
                    u64::from(t.histogram().quantile_us(num, den)),
                    reference_quantile(&us, num, den),
                    "len={len} q={num}/{den}"
                );
            }
            assert_eq!(t.min_ns(), *v.iter().min().unwrap());
            assert_eq!(t.max_ns(), *v.iter().max().unwrap());
            assert_eq!(t.avg_ns(), v.iter().sum::<u64>() / len as u64);
            assert_eq!(
                t.histogram().overflow(),
                v.iter().filter(|&&x| x >= 1_000_000).count() as u64
            );
        }
    }

    #[test]
    fn empty_stats() {
        let t = TimingStat::new();
        assert_eq!(t.summary(), TimingSummary::default());
    }

    #[test]
    fn jitter_signed_and_abs() {
        let mut j = PeriodJitter::new(1_000_000);
        assert_eq!(j.top(5_000_000), None);
        assert_eq!(j.top(6_000_100), Some(100));
        assert_eq!(j.top(6_999_900), Some(-200));
        assert_eq!(j.top(8_000_000), Some(100));
        assert_eq!(j.min_ns(), -200);
        assert_eq!(j.max_ns(), 100);
        assert_eq!(j.abs().max_ns(), 200);
        assert_eq!(j.abs().count(), 3);
    }

    fn sample_stats() -> HapStats {
        let mut s = HapStats::new(1000);
        for i in 0..5000u64 {
            s.wakeup.record_ns(1_000 + (i * 37) % 9_000);
            s.exec
                .record_ns(3_000 + (i * 53) % 40_000 + if i % 997 == 0 { 2_000_000 } else { 0 });
            s.jitter.top(i * 1_000_000 + (i * 7919) % 3_000);
        }
        s.record_verdict(&Verdict::Good { mode: Mode::Main });
        s.record_verdict(&Verdict::Miss { consecutive: 1 });
        s.record_verdict(&Verdict::Miss { consecutive: 2 });
        s.record_verdict(&Verdict::Good {
            mode: Mode::Degraded,
        });
        s.record_verdict(&Verdict::FailSafe(FailSafeCause::StopRequested));
        s.record_reject(DecodeError::BadCrc);
        s.record_reject(DecodeError::BadCrc);
        s.record_reject(DecodeError::BadBool);
        s.counters.frames_in = 123;
        s.counters.frames_out = 4567;
        s.counters.answers_dropped = 3;
        s.counters.vpr_extrapolated = 8;
        s
    }

    #[test]
    fn render_parse_round_trip() {
        let s = sample_stats();
        let mut buf = [0u8; RENDER_MAX];
        let r = s.render(&mut buf);
        assert!(!r.truncated);
        let text = core::str::from_utf8(&buf[..r.len]).unwrap();
        assert!(text.contains("rejected.bad_crc: 2\n"), "{text}");
        assert!(text.contains("frames_rejected: 3\n"));
        assert!(text.contains("misses: 2\n"));
        assert_eq!(parse_summary(text), Ok(s.summary()));
        assert!(r.len < 2048, "{}", r.len);
    }

    #[test]
    fn render_truncates_without_panic() {
        let s = sample_stats();
        for n in [0usize, 1, 10, 100, 1000] {
            let mut buf = vec![0u8; n];
            let r = s.render(&mut buf);
            assert!(r.truncated);
            assert_eq!(r.len, n);
        }
    }

    #[test]
    fn parse_errors() {
        assert_eq!(
            parse_summary("cycles: 1\n").unwrap_err().kind,
            ParseErrorKind::BadVersion
        );
        assert_eq!(
            parse_summary("version: 1\ncycles 1\n"),
            Err(ParseError {
                line: 2,
                kind: ParseErrorKind::NoColon
            })
        );
        assert_eq!(
            parse_summary("version: 1\ncycles: -1\n"),
            Err(ParseError {
                line: 2,
                kind: ParseErrorKind::BadNumber
            })
        );
        assert_eq!(
            parse_summary("version: 2\n"),
            Err(ParseError {
                line: 1,
                kind: ParseErrorKind::BadVersion
            })
        );
        assert!(parse_summary("version: 1\nfuture.key: x\n").is_ok());
    }

    #[test]
    fn buckets_are_u64_and_do_not_saturate_at_u32() {
        let mut h = Histogram::new();
        h.buckets[3] = u64::from(u32::MAX);
        h.count = u64::from(u32::MAX);
        h.record_us(3);
        assert_eq!(h.bucket(3), u64::from(u32::MAX) + 1);
        assert_eq!(h.quantile_us(P999, PPM), 3);
    }

    fn busy_stats() -> HapStats {
        let mut st = HapStats::new(250);
        for i in 0..500i64 {
            let e = i * 250_000;
            st.record_cycle(
                e,
                e + 900 + i,
                e + 3_000 + 7 * i,
                e + 40_000 + 11 * i,
                i % 7 != 0,
            );
            st.record_verdict(&Verdict::Good {
                mode: super::super::mode::Mode::Main,
            });
        }
        st.record_cycle(1 << 40, (1 << 40) + 5, (1 << 40) + 2_000_000, 0, false);
        st.record_reject(DecodeError::BadCrc);
        st.counters.vpr_extrapolated = 12;
        st
    }

    #[test]
    fn words_round_trip_every_field() {
        let mut st = busy_stats();
        let mut words = vec![0u64; STATS_WORDS];
        st.to_words(&mut words);
        let mut n = 0;
        st.visit_words(WordSet::All, |i, _| {
            assert_eq!(i, n);
            n += 1;
        });
        assert_eq!(n, STATS_WORDS);
        let mut back = HapStats::new(1);
        back.load_words(&words);
        assert_eq!(back, st);
        assert_eq!(back.summary(), st.summary());
    }

    #[test]
    fn recent_words_are_what_one_record_changes() {
        // Publish everything once, then after each record only the recent
        // words: the published copy always decodes to the writer's state.
        let mut st = HapStats::new(1000);
        let mut published = vec![0u64; STATS_WORDS];
        st.to_words(&mut published);
        for i in 0..3000i64 {
            let e = i * 1_000_000;
            let late = (i * 7919) % 1_500_000;
            st.record_cycle(e, e + late / 3, e + late, e + late + 20_000 + i, i % 5 != 0);
            st.record_verdict(&if i % 11 == 0 {
                Verdict::Miss { consecutive: 1 }
            } else {
                Verdict::Good {
                    mode: super::super::mode::Mode::Main,
                }
            });
            st.visit_words(WordSet::Recent, |k, w| published[k] = *w);
            if i % 97 == 0 {
                let mut back = HapStats::new(1);
                back.load_words(&published);
                assert_eq!(back, st, "after record {i}");
            }
        }
        let mut back = HapStats::new(1);
        back.load_words(&published);
        assert_eq!(back, st);
    }

    #[test]
    fn reset_in_place_equals_new() {
        let mut st = busy_stats();
        st.reset(777);
        assert_eq!(st, HapStats::new(777));
        // From all-zero memory (how the kernel allocates it).
        let mut words = vec![0u64; STATS_WORDS];
        let mut z = HapStats::new(5);
        z.load_words(&words);
        z.reset(250);
        assert_eq!(z, HapStats::new(250));
        z.to_words(&mut words);
    }

    #[test]
    fn struct_size() {
        assert!(core::mem::size_of::<HapStats>() < 25 * 1024);
    }
}
