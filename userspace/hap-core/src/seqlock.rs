//! A sequence-counted publication of `u64` words: one writer publishes
//! (CLOCK's statistics, PROTO_IN's counters), any number of readers copy
//! a consistent snapshot, and the writer never waits for a reader.
//!
//! # Protocol (a seqcount over atomic words)
//!
//! - **Write** (by the one task holding the publication's [`Writer`] role,
//!   claimed with [`SeqWords::claim_writer`]): `seq ← seq + 1` (odd: a write is in
//!   progress), Release fence, then the changed words (Relaxed), then
//!   `seq ← seq + 1` (even) with Release. The writer takes no lock and
//!   never looks at readers: a write is a bounded number of stores.
//! - **Read**: `s1 ← seq` (Acquire); if odd, the attempt fails; copy every
//!   word (Relaxed); Acquire fence; `s2 ← seq`. The copy is a snapshot of
//!   the words as one completed write left them iff `s1 = s2`; else the
//!   attempt fails and the reader tries again (readers retry, the writer
//!   never does).
//!
//! Every word is an atomic, so a racing copy is no data race, only a
//! failed attempt. Words a write does not set keep their value, so a writer
//! may publish only what changed.
//!
//! Each operation is a small state machine ([`WriteOp`], [`ReadOp`]) whose
//! `step` does exactly one access to shared memory; the tests interleave
//! writer and reader steps exhaustively.

use core::cell::Cell;
use core::marker::PhantomData;
use core::ops::Deref;
use core::sync::atomic::{fence, AtomicBool, AtomicU64, Ordering};

/// A read attempt overlapped a write.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Busy;

/// Words published under a sequence count (see the module doc).
#[derive(Debug)]
pub struct SeqWords<S> {
    seq: AtomicU64,
    words: S,
    /// A [`Writer`] token is held.
    writer_held: AtomicBool,
}

/// The publication's single writer role, held by the task that publishes:
/// claimed once ([`SeqWords::claim_writer`]; a second claim while it is
/// held gets `None`), given back when dropped, and not `Sync` (it cannot be
/// shared between threads, only moved). One write at a time through it
/// ([`Writer::write`] borrows it mutably).
///
/// ```compile_fail
/// fn shared_between_threads<T: Sync>() {}
/// shared_between_threads::<hap_core::seqlock::Writer<'static, Vec<core::sync::atomic::AtomicU64>>>();
/// ```
#[derive(Debug)]
pub struct Writer<'a, S: Deref<Target = [AtomicU64]>> {
    lock: &'a SeqWords<S>,
    _one_task: PhantomData<Cell<()>>,
}

impl<S: Deref<Target = [AtomicU64]>> Writer<'_, S> {
    /// Start a write; the words set through the returned guard become
    /// visible together when it drops.
    pub fn write(&mut self) -> SeqWriter<'_, S> {
        let lock = self.lock;
        let s = lock.seq.load(Ordering::Relaxed);
        lock.seq.store(s.wrapping_add(1), Ordering::Relaxed);
        fence(Ordering::Release);
        SeqWriter { lock, seq: s }
    }
}

impl<S: Deref<Target = [AtomicU64]>> Drop for Writer<'_, S> {
    fn drop(&mut self) {
        self.lock.writer_held.store(false, Ordering::Release);
    }
}

impl<S: Deref<Target = [AtomicU64]>> SeqWords<S> {
    pub fn new(words: S) -> Self {
        SeqWords {
            seq: AtomicU64::new(0),
            words,
            writer_held: AtomicBool::new(false),
        }
    }

    /// The writer role, if no task holds it.
    pub fn claim_writer(&self) -> Option<Writer<'_, S>> {
        self.writer_held
            .compare_exchange(false, true, Ordering::Acquire, Ordering::Relaxed)
            .ok()?;
        Some(Writer {
            lock: self,
            _one_task: PhantomData,
        })
    }

    /// Words published.
    pub fn len(&self) -> usize {
        self.words.len()
    }

    pub fn is_empty(&self) -> bool {
        self.words.is_empty()
    }

    /// Completed writes so far (the sequence count / 2).
    pub fn generation(&self) -> u64 {
        self.seq.load(Ordering::Acquire) / 2
    }

    /// One read attempt: copy the words into `out` (as many as fit);
    /// `Ok(generation)` if the copy is consistent.
    pub fn try_read(&self, out: &mut [u64]) -> Result<u64, Busy> {
        let mut op = ReadOp::new(out);
        loop {
            if let Some(r) = op.step(self) {
                return r;
            }
        }
    }

    /// Up to `attempts` read attempts; `None` if every one overlapped a write.
    pub fn read(&self, out: &mut [u64], attempts: usize) -> Option<u64> {
        (0..attempts).find_map(|_| self.try_read(out).ok())
    }
}

/// A write in progress (see [`Writer::write`]).
pub struct SeqWriter<'a, S: Deref<Target = [AtomicU64]>> {
    lock: &'a SeqWords<S>,
    seq: u64,
}

impl<S: Deref<Target = [AtomicU64]>> SeqWriter<'_, S> {
    /// Set word `i` (ignored if out of range).
    pub fn set(&self, i: usize, v: u64) {
        if let Some(w) = self.lock.words.get(i) {
            w.store(v, Ordering::Relaxed);
        }
    }
}

impl<S: Deref<Target = [AtomicU64]>> Drop for SeqWriter<'_, S> {
    fn drop(&mut self) {
        self.lock
            .seq
            .store(self.seq.wrapping_add(2), Ordering::Release);
    }
}

#[derive(Clone, Copy, Debug)]
enum WriteState {
    Begin,
    Set(usize),
    End,
    Done,
}

/// One write of `(index, value)` pairs, as single shared-memory steps.
#[derive(Clone, Debug)]
pub struct WriteOp<'a> {
    updates: &'a [(usize, u64)],
    seq: u64,
    state: WriteState,
}

impl<'a> WriteOp<'a> {
    pub fn new(updates: &'a [(usize, u64)]) -> Self {
        WriteOp {
            updates,
            seq: 0,
            state: WriteState::Begin,
        }
    }

    /// Do the next step; `true` once the write is complete.
    pub fn step<S: Deref<Target = [AtomicU64]>>(&mut self, l: &SeqWords<S>) -> bool {
        match self.state {
            WriteState::Begin => {
                // The writer's own last store: no step of its own.
                self.seq = l.seq.load(Ordering::Relaxed);
                l.seq.store(self.seq.wrapping_add(1), Ordering::Relaxed);
                fence(Ordering::Release);
                self.state = WriteState::Set(0);
                false
            }
            WriteState::Set(k) => {
                if let Some(&(i, v)) = self.updates.get(k) {
                    if let Some(w) = l.words.get(i) {
                        w.store(v, Ordering::Relaxed);
                    }
                }
                let next = k.saturating_add(1);
                self.state = if next < self.updates.len() {
                    WriteState::Set(next)
                } else {
                    WriteState::End
                };
                false
            }
            WriteState::End => {
                l.seq.store(self.seq.wrapping_add(2), Ordering::Release);
                self.state = WriteState::Done;
                true
            }
            WriteState::Done => true,
        }
    }
}

#[derive(Clone, Copy, Debug)]
enum ReadState {
    LoadSeq,
    Copy { s1: u64, k: usize },
    Recheck { s1: u64 },
    Done,
}

/// One read attempt, as single shared-memory steps.
#[derive(Debug)]
pub struct ReadOp<'a> {
    out: &'a mut [u64],
    state: ReadState,
}

impl<'a> ReadOp<'a> {
    pub fn new(out: &'a mut [u64]) -> Self {
        ReadOp {
            out,
            state: ReadState::LoadSeq,
        }
    }

    /// Do the next step; `Some(result)` once the attempt is over.
    pub fn step<S: Deref<Target = [AtomicU64]>>(
        &mut self,
        l: &SeqWords<S>,
    ) -> Option<Result<u64, Busy>> {
        let n = self.out.len().min(l.words.len());
        match self.state {
            ReadState::LoadSeq => {
                let s1 = l.seq.load(Ordering::Acquire);
                if s1 % 2 == 1 {
                    self.state = ReadState::Done;
                    return Some(Err(Busy));
                }
                self.state = if n == 0 {
                    ReadState::Recheck { s1 }
                } else {
                    ReadState::Copy { s1, k: 0 }
                };
                None
            }
            ReadState::Copy { s1, k } => {
                if let (Some(d), Some(w)) = (self.out.get_mut(k), l.words.get(k)) {
                    *d = w.load(Ordering::Relaxed);
                }
                let next = k.saturating_add(1);
                self.state = if next < n {
                    ReadState::Copy { s1, k: next }
                } else {
                    ReadState::Recheck { s1 }
                };
                None
            }
            ReadState::Recheck { s1 } => {
                fence(Ordering::Acquire);
                let s2 = l.seq.load(Ordering::Relaxed);
                self.state = ReadState::Done;
                Some(if s1 == s2 { Ok(s1 / 2) } else { Err(Busy) })
            }
            ReadState::Done => Some(Err(Busy)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Documentation/architecture.md quotes the count of each exploration
    /// on the row that names these tests: the count a run gives must be
    /// there (written with spaces between groups of three digits).
    fn quoted_in_architecture(tests: &str, runs: usize) {
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../Documentation/architecture.md"
        );
        let doc = std::fs::read_to_string(path).unwrap();
        let row = doc
            .lines()
            .find(|l| l.contains(tests))
            .unwrap_or_else(|| panic!("architecture.md has no row naming {tests}"));
        let digits = runs.to_string();
        let mut grouped = String::new();
        for (i, c) in digits.chars().enumerate() {
            if i > 0 && (digits.len() - i) % 3 == 0 {
                grouped.push(' ');
            }
            grouped.push(c);
        }
        let quoted = row.match_indices(&grouped).any(|(at, _)| {
            let before = row[..at].chars().next_back();
            let after = row[at + grouped.len()..].chars().next();
            !before.is_some_and(|c| {
                c.is_ascii_digit()
                    || c == ' ' && row[..at].trim_end().ends_with(|d: char| d.is_ascii_digit())
            }) && !after.is_some_and(|c| c.is_ascii_digit())
        });
        assert!(
            quoted,
            "architecture.md's row of {tests} does not quote {grouped} interleavings: {row}"
        );
    }

    fn words(n: usize) -> SeqWords<Vec<AtomicU64>> {
        SeqWords::new((0..n).map(|_| AtomicU64::new(0)).collect())
    }

    #[test]
    fn write_then_read() {
        let l = words(4);
        let mut writer = l.claim_writer().unwrap();
        {
            let w = writer.write();
            w.set(0, 7);
            w.set(3, 9);
            w.set(99, 1); // out of range: ignored
        }
        let mut out = [0u64; 4];
        assert_eq!(l.try_read(&mut out), Ok(1));
        assert_eq!(out, [7, 0, 0, 9]);
        assert_eq!(l.generation(), 1);
    }

    #[test]
    fn a_read_during_a_write_fails_and_the_writer_goes_on() {
        let l = words(2);
        let mut writer = l.claim_writer().unwrap();
        let w = writer.write();
        w.set(0, 1);
        let mut out = [0u64; 2];
        assert_eq!(l.try_read(&mut out), Err(Busy));
        assert_eq!(l.read(&mut out, 10), None);
        drop(w);
        assert_eq!(l.read(&mut out, 10), Some(1));
        assert_eq!(out, [1, 0]);
    }

    /// A role token moves to the thread that plays it (the doc tests show
    /// it is not `Sync`: no two threads share it).
    #[test]
    fn a_role_moves_between_threads() {
        fn moved_between_threads<T: Send>() {}
        moved_between_threads::<Writer<'static, Vec<AtomicU64>>>();
    }

    #[test]
    fn the_writer_role_is_held_once_and_given_back_when_dropped() {
        let l = words(1);
        let mut writer = l.claim_writer().unwrap();
        assert!(l.claim_writer().is_none(), "a second writer");
        writer.write().set(0, 5);
        drop(writer);
        l.claim_writer().unwrap().write().set(0, 6);
        let mut out = [0u64; 1];
        assert_eq!(l.read(&mut out, 1), Some(2));
        assert_eq!(out, [6]);
    }

    /// Every interleaving of `writes` writer operations (each setting all
    /// words to its generation number) and `reads` reader attempts, one
    /// shared-memory step at a time. Every successful read must see all
    /// words equal to one generation, and a generation that was complete
    /// at some point during the attempt; the writer always completes.
    fn explore(n_words: usize, writes: usize, reads: usize) -> usize {
        let updates: Vec<Vec<(usize, u64)>> = (1..=writes as u64)
            .map(|g| (0..n_words).map(|i| (i, g)).collect())
            .collect();
        let mut choices: Vec<bool> = Vec::new();
        let mut runs = 0;
        loop {
            let branch = run(n_words, &updates, reads, &mut choices);
            runs += 1;
            let mut next = None;
            for (i, &both) in branch.iter().enumerate().rev() {
                if choices[i] && both {
                    next = Some(i);
                    break;
                }
            }
            match next {
                None => return runs,
                Some(i) => {
                    choices.truncate(i);
                    choices.push(false);
                }
            }
        }
    }

    fn run(
        n_words: usize,
        updates: &[Vec<(usize, u64)>],
        reads: usize,
        choices: &mut Vec<bool>,
    ) -> Vec<bool> {
        let l = words(n_words);
        let mut w_idx = 0;
        let mut w_op: Option<WriteOp> = None;
        let mut r_left = reads;
        let mut r_state: Option<ReadState> = None;
        let mut buf = vec![u64::MAX; n_words];
        // Completed generations when the current read attempt started.
        let mut completed = 0u64;
        let mut completed_at_start = 0u64;
        let mut branch = Vec::new();
        let mut ok_reads = 0;
        let mut step = 0;
        loop {
            let w_can = w_idx < updates.len();
            let r_can = r_left > 0;
            if !w_can && !r_can {
                break;
            }
            let take_w = match choices.get(step) {
                Some(&c) => c,
                None => {
                    choices.push(w_can);
                    w_can
                }
            };
            branch.push(w_can && r_can);
            step += 1;
            if take_w {
                let op = w_op.get_or_insert_with(|| WriteOp::new(&updates[w_idx]));
                if op.step(&l) {
                    w_op = None;
                    w_idx += 1;
                    completed += 1;
                }
            } else {
                if r_state.is_none() {
                    completed_at_start = completed;
                }
                let mut op = ReadOp::new(&mut buf);
                if let Some(s) = r_state {
                    op.state = s;
                }
                let res = op.step(&l);
                let st = op.state;
                match res {
                    None => r_state = Some(st),
                    Some(r) => {
                        r_state = None;
                        r_left -= 1;
                        if let Ok(gen) = r {
                            ok_reads += 1;
                            assert!(buf.iter().all(|&v| v == gen), "torn read {buf:?} gen {gen}");
                            assert!(gen >= completed_at_start && gen <= completed);
                        }
                    }
                }
            }
        }
        assert_eq!(l.generation(), updates.len() as u64);
        assert!(ok_reads <= reads);
        branch
    }

    #[test]
    fn every_interleaving_two_words() {
        let runs = explore(2, 2, 3);
        eprintln!("{runs} interleavings");
        quoted_in_architecture("seqlock::tests::every_interleaving_", runs);
        assert!(runs > 1000, "{runs}");
    }

    #[test]
    fn every_interleaving_three_words_one_write() {
        let runs = explore(3, 1, 3);
        eprintln!("{runs} interleavings");
        quoted_in_architecture("seqlock::tests::every_interleaving_", runs);
        assert!(runs > 100, "{runs}");
    }

    #[test]
    fn a_reader_alone_always_succeeds() {
        // No writer running: the first attempt succeeds.
        let l = words(3);
        let mut out = [0u64; 3];
        for _ in 0..10 {
            assert!(l.try_read(&mut out).is_ok());
        }
    }
}
