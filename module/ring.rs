// SPDX-License-Identifier: GPL-2.0

//! The kernel side of hap-core's lock-free ring (`hap_core::spsc`): the
//! RT-FIFOs (rtf_in, rtf_out), the simulator's position log and the effort
//! handoff. hap-core holds the protocol (and its host tests); this file
//! adds the storage (a `KVVec`: vmalloc-backed when large, as the 1.2 MB
//! position log), end of file, and waking blocked readers.
//!
//! Sides:
//! - the **producer** is one task holding the ring's [`Producer`] token
//!   (SERVO for rtf_out's answers, PROTO_IN for rtf_out's replies lane), or
//!   several writers serialised among themselves by `producers`, a lock the
//!   consumer never takes (rtf_in, the effort hand-off), or two real-time
//!   tasks that never wait for each other ([`Fifo::try_push_exclusive`]:
//!   the position log);
//! - the **consumer** is one task holding the ring's [`Consumer`] token
//!   (PROTO_IN for rtf_in, SERVO for the effort hand-off), or the readers
//!   of a device, serialised among themselves by `consumers`, a lock the
//!   producer never takes.
//!
//! The roles are hap-core's: the ring's `spsc::Producer` and
//! `spsc::Consumer` tokens, claimed from the ring and given back when
//! dropped. A task that plays a side for the whole run holds the token in
//! this file's [`Producer`] / [`Consumer`] ([`Fifo::claim_producer`],
//! [`Fifo::claim_consumer`]; a second claim while one is held gets `None`),
//! which is not `Send` either (it stays in the task that claimed it); the
//! serialised writers and readers and the two real-time log producers
//! claim the role for one push or pop. Each ring is used with one kind of
//! producer side and one kind of consumer side.
//!
//! A push never waits: it succeeds or is refused (full ring, counted).
//! It then rings the `readable` doorbell only if a reader sleeps: a
//! `struct completion` (a raw spinlock held for a bounded wake-up, also on
//! PREEMPT_RT), never a lock a reader can hold while preempted.

use crate::{
    completion::Timeout,
    hap_core::spsc::{self, PushError, Spsc},
};
use core::sync::atomic::{fence, AtomicBool, AtomicU32, Ordering};
use kernel::{
    bindings, new_mutex,
    prelude::*,
    sync::Mutex,
    types::{NotThreadSafe, Opaque},
};

pub(crate) use core::sync::atomic::AtomicU64;

/// A `struct completion` used as a doorbell: rung by the producer, waited
/// on (interruptibly) by readers.
#[pin_data]
pub(crate) struct Doorbell {
    #[pin]
    inner: Opaque<bindings::completion>,
}

// SAFETY: a `struct completion` may be signalled and waited on from any task.
unsafe impl Send for Doorbell {}
// SAFETY: all operations go through the kernel's own locking.
unsafe impl Sync for Doorbell {}

impl Doorbell {
    pub(crate) fn new() -> impl PinInit<Self> {
        pin_init!(Self {
            inner <- Opaque::ffi_init(|slot: *mut bindings::completion| {
                // SAFETY: `slot` points to an uninitialised `struct completion`.
                unsafe { bindings::init_completion(slot) };
            }),
        })
    }

    pub(crate) fn ring(&self) {
        // SAFETY: `inner` is an initialised completion.
        unsafe { bindings::complete(self.inner.get()) };
    }

    pub(crate) fn ring_all(&self) {
        // SAFETY: `inner` is an initialised completion.
        unsafe { bindings::complete_all(self.inner.get()) };
    }

    /// Sleep until rung, a signal (`ERESTARTSYS`) or `timeout` elapsed.
    pub(crate) fn wait_interruptible(&self, timeout: Timeout) -> Result {
        // SAFETY: `inner` is an initialised completion; readers may sleep.
        let r = unsafe {
            bindings::wait_for_completion_interruptible_timeout(self.inner.get(), timeout.jiffies())
        };
        if r < 0 {
            Err(ERESTARTSYS)
        } else {
            Ok(())
        }
    }
}

/// A sleeping reader re-checks the ring at least this often.
const READER_WAIT: Timeout = Timeout::from_millis(100);

/// Allocate `words` zeroed atomic words (vmalloc-backed when large), in one
/// allocation.
pub(crate) fn storage(words: usize) -> Result<KVVec<AtomicU64>> {
    let mut v = KVVec::with_capacity(words, GFP_KERNEL)?;
    for _ in 0..words {
        v.push_within_capacity(AtomicU64::new(0))
            .map_err(|_| ENOMEM)?;
    }
    Ok(v)
}

/// A fixed array of atomic words (small publications, built inline).
pub(crate) struct Words<const N: usize>([AtomicU64; N]);

impl<const N: usize> Words<N> {
    pub(crate) const fn new() -> Self {
        Words([const { AtomicU64::new(0) }; N])
    }
}

impl<const N: usize> core::ops::Deref for Words<N> {
    type Target = [AtomicU64];
    fn deref(&self) -> &[AtomicU64] {
        &self.0
    }
}

/// A ring of records of at most `REC` bytes with its doorbell and end of file.
#[pin_data]
pub(crate) struct Fifo<const REC: usize> {
    ring: Spsc<KVVec<AtomicU64>>,
    /// Serialises several producers (device writers) among themselves.
    #[pin]
    producers: Mutex<()>,
    /// Serialises several consumers (device readers) among themselves.
    #[pin]
    consumers: Mutex<()>,
    #[pin]
    readable: Doorbell,
    /// Readers asleep on `readable`.
    sleepers: AtomicU32,
    /// No more pushes: readers drain what is queued, then see end of file.
    closed: AtomicBool,
    /// Closed and what is queued is dropped: readers see end of file at once.
    discarded: AtomicBool,
    /// Records refused because another producer held the ring's producer
    /// role ([`Fifo::try_push_exclusive`]: the position log's two real-time
    /// producers, SERVO's cycle record and CLOCK's fail-safe step record,
    /// never wait for each other).
    busy_refused: AtomicU64,
}

/// The ring's words.
type RingWords = KVVec<AtomicU64>;

/// The single producer's side of a [`Fifo`], held by its task: the ring's
/// producer role for as long as the task runs.
pub(crate) struct Producer<'a, const REC: usize> {
    fifo: &'a Fifo<REC>,
    role: spsc::Producer<'a, RingWords>,
    _not_send: NotThreadSafe,
}

/// The single consumer's side of a [`Fifo`], held by its task.
pub(crate) struct Consumer<'a, const REC: usize> {
    fifo: &'a Fifo<REC>,
    role: spsc::Consumer<'a, RingWords>,
    _not_send: NotThreadSafe,
}

assert_not_send!(Producer<'static, 1>);
assert_not_send!(Consumer<'static, 1>);

impl<const REC: usize> Producer<'_, REC> {
    /// Push one record: never waits; refused when full or closed.
    pub(crate) fn push(&self, rec: &[u8]) -> core::result::Result<(), Refused> {
        self.fifo.push_with(&self.role, rec)
    }
}

impl<const REC: usize> Consumer<'_, REC> {
    /// Pop the oldest record: never waits.
    pub(crate) fn pop(&self, out: &mut [u8; REC]) -> Option<usize> {
        self.fifo.pop_with(&self.role, out)
    }
}

/// Why a push was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Refused {
    Full,
    Closed,
}

impl<const REC: usize> Fifo<REC> {
    pub(crate) fn new(capacity: usize) -> Result<impl PinInit<Self>> {
        let words = storage(spsc::storage_words(capacity, REC))?;
        Ok(pin_init!(Self {
            ring: Spsc::new(words, REC),
            producers <- new_mutex!(()),
            consumers <- new_mutex!(()),
            readable <- Doorbell::new(),
            sleepers: AtomicU32::new(0),
            closed: AtomicBool::new(false),
            discarded: AtomicBool::new(false),
            busy_refused: AtomicU64::new(0),
        }))
    }

    /// The single producer's side, if nobody holds it.
    pub(crate) fn claim_producer(&self) -> Option<Producer<'_, REC>> {
        Some(Producer {
            fifo: self,
            role: self.ring.claim_producer()?,
            _not_send: NotThreadSafe,
        })
    }

    /// The single consumer's side, if nobody holds it.
    pub(crate) fn claim_consumer(&self) -> Option<Consumer<'_, REC>> {
        Some(Consumer {
            fifo: self,
            role: self.ring.claim_consumer()?,
            _not_send: NotThreadSafe,
        })
    }

    /// One push, by whichever producer side holds the ring's role.
    fn push_with(
        &self,
        role: &spsc::Producer<'_, RingWords>,
        rec: &[u8],
    ) -> core::result::Result<(), Refused> {
        if self.closed.load(Ordering::Acquire) {
            return Err(Refused::Closed);
        }
        match role.push(rec) {
            Ok(()) => {}
            Err(PushError::Full) | Err(PushError::TooLong) => return Err(Refused::Full),
        }
        self.wake_readers();
        Ok(())
    }

    /// A push by one of two producers that never wait for each other
    /// (CLOCK preempts SERVO on one CPU, so a wait could never end): the
    /// one that finds the ring's producer role held by the other is
    /// refused, and the record is counted with the ring's refusals.
    pub(crate) fn try_push_exclusive(&self, rec: &[u8]) -> core::result::Result<(), Refused> {
        let Some(role) = self.ring.claim_producer() else {
            self.busy_refused.fetch_add(1, Ordering::Relaxed);
            return Err(Refused::Full);
        };
        self.push_with(&role, rec)
    }

    /// Ring the doorbell if a reader sleeps on it (after a push here, or in
    /// a lane read together with this one, see [`Fifo::pop_wait_with`]).
    pub(crate) fn wake_readers(&self) {
        // Pairs with the fence in `pop_wait_with`: either the reader sees
        // the record, or we see it asleep and ring.
        fence(Ordering::SeqCst);
        if self.sleepers.load(Ordering::Relaxed) != 0 {
            self.readable.ring();
        }
    }

    /// A push from one of several writers (device `write()`s): they queue
    /// among themselves on `producers`, which the consumer never takes.
    /// The writer in turn claims the ring's producer role for its push
    /// (only these writers claim it, under `producers`: it is free).
    pub(crate) fn push_serialised(&self, rec: &[u8]) -> core::result::Result<(), Refused> {
        let _g = self.producers.lock();
        self.try_push_exclusive(rec)
    }

    /// One pop, by whichever consumer side holds the ring's role.
    fn pop_with(&self, role: &spsc::Consumer<'_, RingWords>, out: &mut [u8; REC]) -> Option<usize> {
        if self.discarded.load(Ordering::Acquire) {
            return None;
        }
        role.pop(out)
    }

    /// One pop by a reader in turn (under `consumers`, which only the
    /// readers take: they claim the ring's consumer role for one pop).
    fn pop_in_turn(&self, out: &mut [u8; REC]) -> Option<usize> {
        let role = self.ring.claim_consumer()?;
        self.pop_with(&role, out)
    }

    /// A pop from one of several readers, without waiting.
    pub(crate) fn pop_serialised(&self, out: &mut [u8; REC]) -> Option<usize> {
        let _g = self.consumers.lock();
        self.pop_in_turn(out)
    }

    /// A reader's pop: the oldest record, waiting for one unless `nonblock`.
    /// `Ok(0)`: end of file (closed and drained, or discarded).
    pub(crate) fn pop_wait(&self, out: &mut [u8; REC], nonblock: bool) -> Result<usize> {
        self.pop_wait_with(None, out, nonblock)
    }

    /// [`Fifo::pop_wait`] over two lanes: `first` (if any) is taken before
    /// this ring; readers sleep on this ring's doorbell, so `first`'s
    /// producer calls [`Fifo::wake_readers`] on this ring after each push.
    pub(crate) fn pop_wait_with(
        &self,
        first: Option<&Fifo<REC>>,
        out: &mut [u8; REC],
        nonblock: bool,
    ) -> Result<usize> {
        let take = |out: &mut [u8; REC]| {
            let _g = self.consumers.lock();
            first
                .and_then(|f| f.pop_in_turn(out))
                .or_else(|| self.pop_in_turn(out))
        };
        loop {
            if let Some(n) = take(out) {
                return Ok(n);
            }
            if self.closed.load(Ordering::Acquire) {
                // A record pushed just before the close is still read.
                return Ok(take(out).unwrap_or(0));
            }
            if nonblock {
                return Err(EAGAIN);
            }
            self.sleepers.fetch_add(1, Ordering::SeqCst);
            fence(Ordering::SeqCst);
            let empty = self.ring.is_empty() && first.is_none_or(|f| f.ring.is_empty());
            let r = if empty && !self.closed.load(Ordering::Acquire) {
                // The time-out only bounds a stale wake-up count's effect.
                self.readable.wait_interruptible(READER_WAIT)
            } else {
                Ok(())
            };
            self.sleepers.fetch_sub(1, Ordering::SeqCst);
            r?;
        }
    }

    /// Close: no more pushes; wake every reader. With `discard`, readers see
    /// end of file at once (rtf_in, rtf_out); without, they drain what is
    /// queued first (the position log, kept for post-mortem analysis).
    /// Takes no lock: the fail-safe calls it.
    pub(crate) fn close(&self, discard: bool) {
        if discard {
            self.discarded.store(true, Ordering::Release);
        }
        self.closed.store(true, Ordering::Release);
        self.readable.ring_all();
    }

    /// Closed (no more pushes).
    pub(crate) fn is_closed(&self) -> bool {
        self.closed.load(Ordering::Acquire)
    }

    /// (records queued now, records pushed, records refused: full ring or,
    /// for [`Fifo::try_push_exclusive`], the other producer pushing)
    pub(crate) fn counts(&self) -> (usize, u64, u64) {
        let refused = self
            .ring
            .dropped()
            .saturating_add(self.busy_refused.load(Ordering::Relaxed));
        (self.ring.len(), self.ring.pushed(), refused)
    }
}
