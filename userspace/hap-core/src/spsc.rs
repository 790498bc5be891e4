//! A single-producer single-consumer ring of variable-length byte records,
//! on atomics only: the storage behind the RT-FIFOs (SERVO → rtf_out,
//! userspace → rtf_in), the simulator's position log (SERVO → readers) and
//! the effort handoff (writer → SERVO).
//!
//! # Protocol
//!
//! The storage is a slice of `AtomicU64` words, cut into `capacity` slots of
//! `1 + ⌈record_bytes / 8⌉` words: the record's length in bytes, then its
//! bytes packed little-endian. Two free-running counters order everything:
//! `head` (records published, written only by the producer) and `tail`
//! (records consumed, written only by the consumer). Slot `n % capacity`
//! holds record `n`.
//!
//! - **Push** (producer): load `tail` (Acquire); if `head − tail = capacity`
//!   the ring is full: the record is refused and counted in `dropped` (the
//!   producer never waits and never overwrites). Else write the slot's words
//!   (Relaxed), then store `head + 1` (Release).
//! - **Pop** (consumer): load `head` (Acquire); if `head = tail` the ring is
//!   empty. Else read the slot's words (Relaxed), then store `tail + 1`
//!   (Release).
//!
//! The Release store of `head` orders the slot's words before it, and the
//! consumer's Acquire load of `head` makes them visible before it reads
//! them; symmetrically, the consumer's Release store of `tail` happens after
//! its reads, so the producer (Acquire load of `tail`) only rewrites a slot
//! that has been read. Neither side ever waits for the other: a push and a
//! pop are a bounded number of steps each.
//!
//! # Roles
//!
//! At most one producer and one consumer at a time, as types: a push needs
//! the ring's [`Producer`], a pop or a discard its [`Consumer`]. Each is
//! claimed from the ring ([`Spsc::claim_producer`],
//! [`Spsc::claim_consumer`]; a second claim while one is held gets `None`),
//! held by the task that plays the role (it is not `Sync`: it cannot be
//! shared between threads, only moved) and gives the role back when
//! dropped. A task that pushes for the whole run keeps its token; several
//! writers that take turns (device writes under a lock, two real-time
//! producers that must never wait for each other) claim it for one push.
//! Every word is an atomic, so even a protocol violation would be no data
//! race: at worst a record reads torn, and a length word out of range reads
//! as a refused record, never a panic.
//!
//! Each operation is a small state machine (`PushOp`, `PopOp`) whose
//! `step` does exactly one access to shared memory, so that tests can
//! interleave producer and consumer steps exhaustively (see the tests at the
//! end). [`Producer::push`] and [`Consumer::pop`] run the same machines to
//! the end.

use core::cell::Cell;
use core::marker::PhantomData;
use core::ops::Deref;
use core::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// Words a slot needs for records of at most `record_bytes` bytes.
pub const fn slot_words(record_bytes: usize) -> usize {
    record_bytes.div_ceil(8).saturating_add(1)
}

/// Words of storage for `capacity` records of at most `record_bytes` bytes.
pub const fn storage_words(capacity: usize, record_bytes: usize) -> usize {
    capacity.saturating_mul(slot_words(record_bytes))
}

/// Why a push was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PushError {
    /// The ring holds `capacity` records (counted in `dropped`).
    Full,
    /// The record is longer than a slot (counted in `dropped`).
    TooLong,
}

/// A single-producer single-consumer ring over `S` (see the module doc).
#[derive(Debug)]
pub struct Spsc<S> {
    head: AtomicU64,
    tail: AtomicU64,
    dropped: AtomicU64,
    record_bytes: usize,
    capacity: usize,
    words: S,
    /// A [`Producer`] / [`Consumer`] token is held.
    producer_held: AtomicBool,
    consumer_held: AtomicBool,
}

/// The ring's single producer role, held by the task that pushes (see the
/// module doc): not `Sync`, so no two threads push through it at once.
///
/// ```compile_fail
/// fn shared_between_threads<T: Sync>() {}
/// shared_between_threads::<hap_core::spsc::Producer<'static, Vec<core::sync::atomic::AtomicU64>>>();
/// ```
#[derive(Debug)]
pub struct Producer<'a, S: Deref<Target = [AtomicU64]>> {
    ring: &'a Spsc<S>,
    _one_task: PhantomData<Cell<()>>,
}

/// The ring's single consumer role, held by the task that pops; not
/// `Sync` either.
///
/// ```compile_fail
/// fn shared_between_threads<T: Sync>() {}
/// shared_between_threads::<hap_core::spsc::Consumer<'static, Vec<core::sync::atomic::AtomicU64>>>();
/// ```
#[derive(Debug)]
pub struct Consumer<'a, S: Deref<Target = [AtomicU64]>> {
    ring: &'a Spsc<S>,
    _one_task: PhantomData<Cell<()>>,
}

impl<S: Deref<Target = [AtomicU64]>> Producer<'_, S> {
    /// Queue `rec`, or refuse it (counted).
    pub fn push(&self, rec: &[u8]) -> Result<(), PushError> {
        let mut op = PushOp::new(rec);
        loop {
            if let Some(r) = op.step(self.ring) {
                return r;
            }
        }
    }
}

impl<S: Deref<Target = [AtomicU64]>> Drop for Producer<'_, S> {
    fn drop(&mut self) {
        self.ring.producer_held.store(false, Ordering::Release);
    }
}

impl<S: Deref<Target = [AtomicU64]>> Consumer<'_, S> {
    /// Take the oldest record into `out` (at least `record_bytes` long);
    /// its length, or `None` when empty. A record whose stored length is
    /// out of range (impossible under the protocol) is consumed and
    /// returned as length 0.
    pub fn pop(&self, out: &mut [u8]) -> Option<usize> {
        let mut op = PopOp::new(out);
        loop {
            if let Some(r) = op.step(self.ring) {
                return r;
            }
        }
    }

    /// Drop everything queued now.
    pub fn discard(&self) {
        let h = self.ring.head.load(Ordering::Acquire);
        self.ring.tail.store(h, Ordering::Release);
    }
}

impl<S: Deref<Target = [AtomicU64]>> Drop for Consumer<'_, S> {
    fn drop(&mut self) {
        self.ring.consumer_held.store(false, Ordering::Release);
    }
}

impl<S: Deref<Target = [AtomicU64]>> Spsc<S> {
    /// A ring of records of at most `record_bytes` bytes over `words`: as
    /// many slots as fit (`words.len() / slot_words(record_bytes)`).
    pub fn new(words: S, record_bytes: usize) -> Self {
        let capacity = words
            .len()
            .checked_div(slot_words(record_bytes))
            .unwrap_or(0);
        Spsc {
            head: AtomicU64::new(0),
            tail: AtomicU64::new(0),
            dropped: AtomicU64::new(0),
            record_bytes,
            capacity,
            words,
            producer_held: AtomicBool::new(false),
            consumer_held: AtomicBool::new(false),
        }
    }

    /// The producer role, if no task holds it.
    pub fn claim_producer(&self) -> Option<Producer<'_, S>> {
        self.producer_held
            .compare_exchange(false, true, Ordering::Acquire, Ordering::Relaxed)
            .ok()?;
        Some(Producer {
            ring: self,
            _one_task: PhantomData,
        })
    }

    /// The consumer role, if no task holds it.
    pub fn claim_consumer(&self) -> Option<Consumer<'_, S>> {
        self.consumer_held
            .compare_exchange(false, true, Ordering::Acquire, Ordering::Relaxed)
            .ok()?;
        Some(Consumer {
            ring: self,
            _one_task: PhantomData,
        })
    }

    pub fn capacity(&self) -> usize {
        self.capacity
    }

    pub fn record_bytes(&self) -> usize {
        self.record_bytes
    }

    /// Records queued now (a snapshot: either side may move it at once).
    pub fn len(&self) -> usize {
        let t = self.tail.load(Ordering::Acquire);
        let h = self.head.load(Ordering::Acquire);
        usize::try_from(h.wrapping_sub(t))
            .unwrap_or(usize::MAX)
            .min(self.capacity)
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Records published since creation.
    pub fn pushed(&self) -> u64 {
        self.head.load(Ordering::Relaxed)
    }

    /// Records refused (full ring or too long).
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    fn slot_base(&self, n: u64) -> usize {
        let cap = u64::try_from(self.capacity).unwrap_or(0);
        let idx = n.checked_rem(cap).unwrap_or(0);
        usize::try_from(idx)
            .unwrap_or(0)
            .saturating_mul(slot_words(self.record_bytes))
    }

    fn word(&self, base: usize, k: usize) -> Option<&AtomicU64> {
        self.words.get(base.checked_add(k)?)
    }
}

/// Little-endian word `k` of `bytes` (zero-padded).
fn pack(bytes: &[u8], k: usize) -> u64 {
    let mut w = [0u8; 8];
    let start = k.saturating_mul(8);
    if let Some(src) = bytes.get(start..) {
        for (d, s) in w.iter_mut().zip(src.iter()) {
            *d = *s;
        }
    }
    u64::from_le_bytes(w)
}

/// Store word `k` into `out` (as far as it reaches).
fn unpack(out: &mut [u8], k: usize, v: u64) {
    let start = k.saturating_mul(8);
    if let Some(dst) = out.get_mut(start..) {
        for (d, s) in dst.iter_mut().zip(v.to_le_bytes().iter()) {
            *d = *s;
        }
    }
}

#[derive(Clone, Copy, Debug)]
enum PushState {
    LoadTail,
    /// Writing word `k` of the slot at `base` (0: length) for record `head`.
    Write {
        head: u64,
        base: usize,
        k: usize,
    },
    Publish {
        head: u64,
    },
    Done,
}

/// One push, as single shared-memory steps (see the module doc).
#[derive(Clone, Debug)]
pub(crate) struct PushOp<'a> {
    rec: &'a [u8],
    state: PushState,
}

impl<'a> PushOp<'a> {
    pub(crate) fn new(rec: &'a [u8]) -> Self {
        PushOp {
            rec,
            state: PushState::LoadTail,
        }
    }

    /// Do the next step; `Some(outcome)` once the push is over.
    pub(crate) fn step<S: Deref<Target = [AtomicU64]>>(
        &mut self,
        r: &Spsc<S>,
    ) -> Option<Result<(), PushError>> {
        match self.state {
            PushState::LoadTail => {
                if self.rec.len() > r.record_bytes {
                    r.dropped.fetch_add(1, Ordering::Relaxed);
                    self.state = PushState::Done;
                    return Some(Err(PushError::TooLong));
                }
                let tail = r.tail.load(Ordering::Acquire);
                // Only the producer writes `head`: its own last store.
                let head = r.head.load(Ordering::Relaxed);
                let cap = u64::try_from(r.capacity).unwrap_or(0);
                if head.wrapping_sub(tail) >= cap {
                    r.dropped.fetch_add(1, Ordering::Relaxed);
                    self.state = PushState::Done;
                    return Some(Err(PushError::Full));
                }
                self.state = PushState::Write {
                    head,
                    base: r.slot_base(head),
                    k: 0,
                };
                None
            }
            PushState::Write { head, base, k } => {
                let v = match k.checked_sub(1) {
                    None => u64::try_from(self.rec.len()).unwrap_or(u64::MAX),
                    Some(d) => pack(self.rec, d),
                };
                if let Some(w) = r.word(base, k) {
                    w.store(v, Ordering::Relaxed);
                }
                let next = k.saturating_add(1);
                self.state = if next < slot_words(self.rec.len()) {
                    PushState::Write {
                        head,
                        base,
                        k: next,
                    }
                } else {
                    PushState::Publish { head }
                };
                None
            }
            PushState::Publish { head } => {
                r.head.store(head.wrapping_add(1), Ordering::Release);
                self.state = PushState::Done;
                Some(Ok(()))
            }
            PushState::Done => Some(Ok(())),
        }
    }
}

#[derive(Clone, Copy, Debug)]
enum PopState {
    LoadHead,
    /// Reading word `k` of the slot at `base` for record `tail`; `len` once
    /// word 0 is read.
    Read {
        tail: u64,
        base: usize,
        k: usize,
        len: usize,
    },
    Release {
        tail: u64,
        len: usize,
    },
    Done,
}

/// One pop, as single shared-memory steps (see the module doc).
#[derive(Debug)]
pub(crate) struct PopOp<'a> {
    out: &'a mut [u8],
    state: PopState,
}

impl<'a> PopOp<'a> {
    pub(crate) fn new(out: &'a mut [u8]) -> Self {
        PopOp {
            out,
            state: PopState::LoadHead,
        }
    }

    /// Do the next step; `Some(Some(len))` once a record is taken,
    /// `Some(None)` if the ring was empty.
    pub(crate) fn step<S: Deref<Target = [AtomicU64]>>(
        &mut self,
        r: &Spsc<S>,
    ) -> Option<Option<usize>> {
        match self.state {
            PopState::LoadHead => {
                let head = r.head.load(Ordering::Acquire);
                // Only the consumer writes `tail`.
                let tail = r.tail.load(Ordering::Relaxed);
                if head == tail || r.capacity == 0 {
                    self.state = PopState::Done;
                    return Some(None);
                }
                self.state = PopState::Read {
                    tail,
                    base: r.slot_base(tail),
                    k: 0,
                    len: 0,
                };
                None
            }
            PopState::Read { tail, base, k, len } => {
                let v = r.word(base, k).map_or(0, |w| w.load(Ordering::Relaxed));
                let len = match k.checked_sub(1) {
                    None => {
                        let n = usize::try_from(v).unwrap_or(usize::MAX);
                        if n > r.record_bytes || n > self.out.len() {
                            0
                        } else {
                            n
                        }
                    }
                    Some(d) => {
                        unpack(self.out.get_mut(..len).unwrap_or(&mut []), d, v);
                        len
                    }
                };
                let next = k.saturating_add(1);
                self.state = if next < slot_words(len) {
                    PopState::Read {
                        tail,
                        base,
                        k: next,
                        len,
                    }
                } else {
                    PopState::Release { tail, len }
                };
                None
            }
            PopState::Release { tail, len } => {
                r.tail.store(tail.wrapping_add(1), Ordering::Release);
                self.state = PopState::Done;
                Some(Some(len))
            }
            PopState::Done => Some(None),
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

    fn ring(cap: usize, rec: usize) -> Spsc<Vec<AtomicU64>> {
        let words = (0..storage_words(cap, rec))
            .map(|_| AtomicU64::new(0))
            .collect();
        Spsc::new(words, rec)
    }

    #[test]
    fn fifo_order_full_and_empty() {
        let r = ring(3, 20);
        let (p, c) = (r.claim_producer().unwrap(), r.claim_consumer().unwrap());
        assert_eq!(r.capacity(), 3);
        let mut out = [0u8; 20];
        assert_eq!(c.pop(&mut out), None);
        for i in 0..3u8 {
            let rec = [i; 20];
            p.push(&rec[..usize::from(i) + 9]).unwrap();
        }
        assert_eq!(p.push(b"x"), Err(PushError::Full));
        assert_eq!(r.dropped(), 1);
        assert_eq!(r.len(), 3);
        for i in 0..3u8 {
            let n = c.pop(&mut out).unwrap();
            assert_eq!(n, usize::from(i) + 9);
            assert!(out[..n].iter().all(|b| *b == i));
        }
        assert_eq!(c.pop(&mut out), None);
        assert_eq!(r.pushed(), 3);
    }

    #[test]
    fn wraps_around_many_times() {
        let r = ring(4, 13);
        let (p, c) = (r.claim_producer().unwrap(), r.claim_consumer().unwrap());
        let mut out = [0u8; 13];
        let mut next_out = 0u32;
        for i in 0..1000u32 {
            let rec: Vec<u8> = (0..13).map(|k| (i as u8).wrapping_add(k)).collect();
            p.push(&rec).unwrap();
            if i % 3 != 0 {
                while let Some(n) = c.pop(&mut out) {
                    assert_eq!(n, 13);
                    let expect: Vec<u8> =
                        (0..13).map(|k| (next_out as u8).wrapping_add(k)).collect();
                    assert_eq!(&out[..], &expect[..]);
                    next_out += 1;
                }
            }
        }
        assert_eq!(r.dropped(), 0);
    }

    #[test]
    fn too_long_and_zero_capacity_are_refused_not_panics() {
        let r = ring(2, 8);
        let (p, c) = (r.claim_producer().unwrap(), r.claim_consumer().unwrap());
        assert_eq!(p.push(&[0u8; 9]), Err(PushError::TooLong));
        let empty: Spsc<Vec<AtomicU64>> = Spsc::new(Vec::new(), 8);
        assert_eq!(empty.capacity(), 0);
        let (ep, ec) = (
            empty.claim_producer().unwrap(),
            empty.claim_consumer().unwrap(),
        );
        assert_eq!(ep.push(b"a"), Err(PushError::Full));
        assert_eq!(ec.pop(&mut [0u8; 8]), None);
        // A short output buffer: the record is consumed, reported as 0 bytes.
        p.push(b"12345678").unwrap();
        let mut small = [0u8; 4];
        assert_eq!(c.pop(&mut small), Some(0));
        assert!(r.is_empty());
    }

    #[test]
    fn discard_empties_the_ring() {
        let r = ring(4, 8);
        let (p, c) = (r.claim_producer().unwrap(), r.claim_consumer().unwrap());
        p.push(b"a").unwrap();
        p.push(b"b").unwrap();
        c.discard();
        assert_eq!(c.pop(&mut [0u8; 8]), None);
        p.push(b"c").unwrap();
        let mut out = [0u8; 8];
        assert_eq!(c.pop(&mut out), Some(1));
        assert_eq!(out[0], b'c');
    }

    /// A role token moves to the thread that plays it (the doc tests show
    /// it is not `Sync`: no two threads share it).
    #[test]
    fn a_role_moves_between_threads() {
        fn moved_between_threads<T: Send>() {}
        moved_between_threads::<Producer<'static, Vec<AtomicU64>>>();
        moved_between_threads::<Consumer<'static, Vec<AtomicU64>>>();
    }

    #[test]
    fn each_role_is_held_once_and_given_back_when_dropped() {
        let r = ring(4, 8);
        let p = r.claim_producer().unwrap();
        assert!(r.claim_producer().is_none(), "a second producer");
        let c = r.claim_consumer().unwrap();
        assert!(r.claim_consumer().is_none(), "a second consumer");
        p.push(b"a").unwrap();
        drop(p);
        // The role is free again: a next writer takes its turn.
        r.claim_producer().unwrap().push(b"b").unwrap();
        let mut out = [0u8; 8];
        assert_eq!(c.pop(&mut out), Some(1));
        assert_eq!(out[0], b'a');
        drop(c);
        assert_eq!(r.claim_consumer().unwrap().pop(&mut out), Some(1));
        assert_eq!(out[0], b'b');
    }

    #[test]
    fn a_producer_thread_and_a_consumer_thread() {
        let r = ring(8, 16);
        let n = 20_000u32;
        std::thread::scope(|s| {
            let r = &r;
            s.spawn(move || {
                let p = r.claim_producer().unwrap();
                let mut i = 0u32;
                while i < n {
                    if p.push(&i.to_le_bytes()).is_ok() {
                        i += 1;
                    }
                }
            });
            s.spawn(move || {
                let c = r.claim_consumer().unwrap();
                let mut out = [0u8; 16];
                let mut want = 0u32;
                while want < n {
                    if let Some(len) = c.pop(&mut out) {
                        assert_eq!(len, 4);
                        assert_eq!(u32::from_le_bytes([out[0], out[1], out[2], out[3]]), want);
                        want += 1;
                    }
                }
            });
        });
        assert!(r.is_empty());
    }

    /// One side's script: a list of operations, each run step by step.
    #[derive(Clone)]
    struct Side {
        ops_left: usize,
        in_op: bool,
    }

    /// The record producer operation `i` pushes: `len` bytes of `i + 1`.
    fn record(i: usize, rec_bytes: usize) -> Vec<u8> {
        // Full-length and one-shorter records alternate, so that a slot
        // holds words of different records over time.
        let len = rec_bytes.saturating_sub(i % 2).max(1);
        (0..len)
            .map(|k| (i as u8).wrapping_mul(16).wrapping_add(k as u8 + 1))
            .collect()
    }

    struct World {
        ring: Spsc<Vec<AtomicU64>>,
        push: Option<PushOp<'static>>,
        pushed_ok: Vec<usize>,
        push_idx: usize,
        pop_buf: Box<[u8; 64]>,
        popped: Vec<Vec<u8>>,
        pop_state: Option<PopState>,
    }

    /// Explore every interleaving of `pushes` producer operations and `pops`
    /// consumer operations, one shared-memory step at a time, and check
    /// each complete run: what the consumer got is exactly the accepted
    /// records, in order, none torn; what it did not get is still queued.
    fn explore(cap: usize, rec_bytes: usize, pushes: usize, pops: usize) -> usize {
        let records: Vec<&'static [u8]> = (0..pushes)
            .map(|i| &*Box::leak(record(i, rec_bytes).into_boxed_slice()))
            .collect();
        let mut runs = 0usize;
        // Depth-first over the choice sequence; each run is replayed from
        // scratch (the state holds atomics, which do not clone).
        let mut choices: Vec<bool> = Vec::new(); // true: producer step
        loop {
            // Replay `choices`, then extend with producer-first steps to the end.
            let (complete, branch_points) = run(cap, rec_bytes, &records, pops, &mut choices);
            assert!(complete);
            runs += 1;
            // Backtrack: the last point where we took the producer and the
            // consumer could also have moved.
            let mut next = None;
            for (i, &consumer_possible) in branch_points.iter().enumerate().rev() {
                if choices[i] && consumer_possible {
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

    /// Run one schedule: follow `choices` as far as they go, then prefer the
    /// producer. Returns (finished, for each step whether the consumer
    /// could have moved instead of the producer).
    fn run(
        cap: usize,
        rec_bytes: usize,
        records: &[&'static [u8]],
        pops: usize,
        choices: &mut Vec<bool>,
    ) -> (bool, Vec<bool>) {
        let mut w = World {
            ring: ring(cap, rec_bytes),
            push: None,
            pushed_ok: Vec::new(),
            push_idx: 0,
            pop_buf: Box::new([0u8; 64]),
            popped: Vec::new(),
            pop_state: None,
        };
        let mut prod = Side {
            ops_left: records.len(),
            in_op: false,
        };
        let mut cons = Side {
            ops_left: pops,
            in_op: false,
        };
        let mut branch = Vec::new();
        let mut step = 0usize;
        loop {
            let p_can = prod.ops_left > 0;
            let c_can = cons.ops_left > 0;
            if !p_can && !c_can {
                break;
            }
            let take_p = match choices.get(step) {
                Some(&c) => c,
                None => {
                    let c = p_can;
                    choices.push(c);
                    c
                }
            };
            assert!(if take_p { p_can } else { c_can });
            branch.push(p_can && c_can);
            step += 1;
            if take_p {
                if !prod.in_op {
                    w.push = Some(PushOp::new(records[w.push_idx]));
                    prod.in_op = true;
                }
                if let Some(res) = w.push.as_mut().unwrap().step(&w.ring) {
                    if res.is_ok() {
                        w.pushed_ok.push(w.push_idx);
                    }
                    w.push_idx += 1;
                    prod.in_op = false;
                    prod.ops_left -= 1;
                }
            } else {
                // PopOp borrows the buffer mutably; keep its state across
                // steps by rebuilding it around the same buffer.
                let mut op = PopOp::new(&mut w.pop_buf[..]);
                if let Some(s) = w.pop_state {
                    op.state = s;
                }
                let res = op.step(&w.ring);
                let st = op.state;
                match res {
                    None => {
                        w.pop_state = Some(st);
                        cons.in_op = true;
                    }
                    Some(r) => {
                        if let Some(n) = r {
                            w.popped.push(w.pop_buf[..n].to_vec());
                        }
                        w.pop_state = None;
                        cons.in_op = false;
                        cons.ops_left -= 1;
                    }
                }
            }
        }
        // Check the run.
        let accepted: Vec<&[u8]> = w.pushed_ok.iter().map(|&i| records[i]).collect();
        assert!(w.popped.len() <= accepted.len());
        for (got, want) in w.popped.iter().zip(accepted.iter()) {
            assert_eq!(&got[..], *want, "record torn or out of order");
        }
        // Refused pushes happened only with a full ring, and were counted.
        let refused = records.len() - w.pushed_ok.len();
        assert_eq!(w.ring.dropped() as usize, refused);
        // The rest is still there, in order.
        let mut rest = Vec::new();
        let mut buf = [0u8; 64];
        let c = w.ring.claim_consumer().unwrap();
        while let Some(n) = c.pop(&mut buf) {
            rest.push(buf[..n].to_vec());
        }
        assert_eq!(w.popped.len() + rest.len(), accepted.len());
        for (got, want) in rest.iter().zip(accepted[w.popped.len()..].iter()) {
            assert_eq!(&got[..], *want);
        }
        // With a ring never full, nothing is refused.
        if cap >= records.len() {
            assert_eq!(refused, 0);
        }
        (true, branch)
    }

    #[test]
    fn every_interleaving_capacity_1_two_data_words() {
        // Records of 9 then 8 bytes: 3 words a slot (length + 2 data words).
        let runs = explore(1, 9, 3, 3);
        eprintln!("{runs} interleavings");
        quoted_in_architecture("spsc::tests::every_interleaving_", runs);
        assert!(runs > 50, "{runs}");
    }

    #[test]
    fn every_interleaving_capacity_1_producer_ahead() {
        // Three pushes into one slot: some are refused (full), counted.
        let runs = explore(1, 4, 4, 3);
        eprintln!("{runs} interleavings");
        quoted_in_architecture("spsc::tests::every_interleaving_", runs);
        assert!(runs > 50, "{runs}");
    }

    #[test]
    fn every_interleaving_capacity_2() {
        let runs = explore(2, 8, 3, 3);
        eprintln!("{runs} interleavings");
        quoted_in_architecture("spsc::tests::every_interleaving_", runs);
        assert!(runs > 1000, "{runs}");
    }

    #[test]
    fn every_interleaving_capacity_3_consumer_ahead() {
        let runs = explore(3, 4, 3, 4);
        eprintln!("{runs} interleavings");
        quoted_in_architecture("spsc::tests::every_interleaving_", runs);
        assert!(runs > 1000, "{runs}");
    }
}
