// SPDX-License-Identifier: GPL-2.0

//! `/dev/hap_effort`, the user's effort on the handle (the spec's simulator
//! RT-FIFO for it). One `write()` of a whole effort-sequence text (hap-core's
//! `.eff` format, at most 64 KiB) loads it; it plays from the servo cycle it
//! was loaded at. A parse error gets `EINVAL` and a dmesg line with its line
//! and column. A single line `live fx fy fz tx ty tz` (N, N·m) sets a live
//! effort that overrides the sequence; `live off` ends it; `clear` unloads
//! the sequence.
//!
//! The writer parses and validates the text itself (hap-core), without any
//! lock of SERVO's, and hands the result over as one hap-core
//! `EffortHandoff` record in a lock-free ring ([`EffortChannel`]); SERVO
//! takes it at the top of its next cycle without waiting, and the `write()`
//! returns once it has (`EBUSY` if SERVO does not take it within 100 ms,
//! e.g. after the fail-safe).

use crate::{
    completion::{Completion, Timeout},
    device::{HapDevice, OpenFile},
    hap_core::effort::{
        parse_effort_command, parse_effort_sequence, EffortCommand, EffortCommandError,
        EffortHandoff, EffortKeyframe, EFFORT_CAPACITY, EFFORT_RECORD_BYTES,
    },
    ring::{Consumer, Fifo, Refused},
    servo_data::{ServoData, NEVER},
    time::Ktime,
};
use core::sync::atomic::{AtomicU64, Ordering};
use kernel::{iov::IovIterSource, new_mutex, prelude::*, sync::Arc, sync::Mutex};

/// Largest effort-sequence write.
const EFFORT_MAX_BYTES: usize = 64 * 1024;

/// Effort hand-off records in flight (writers wait for SERVO to take theirs).
const EFFORT_SLOTS: usize = 2;

/// The effort hand-off from the device's writers to SERVO.
///
/// Protocol:
/// - `ring`: producers are the writers, serialised among themselves by
///   `writer` (a lock SERVO never takes); SERVO is the only consumer.
/// - `applied`: SERVO adds one (AcqRel) per record taken, then completes
///   `taken` once per cycle that took any; a writer waits on `taken` until
///   `applied` (Acquire) reaches its record's ticket.
/// - `loaded_cycle`: SERVO stores (Release) the servo cycle at which it
///   loaded or cleared a sequence; the writer and /dev/hap_stats read it.
#[pin_data]
pub(crate) struct EffortChannel {
    #[pin]
    ring: Fifo<EFFORT_RECORD_BYTES>,
    #[pin]
    taken: Completion,
    #[pin]
    writer: Mutex<KBox<EffortScratch>>,
    applied: AtomicU64,
    loaded_cycle: AtomicU64,
}

impl EffortChannel {
    pub(crate) fn new() -> Result<impl PinInit<Self, Error>> {
        let ring = Fifo::new(EFFORT_SLOTS)?;
        let scratch = EffortScratch::new_boxed()?;
        Ok(try_pin_init!(Self {
            ring <- ring,
            taken <- Completion::new(),
            writer <- new_mutex!(scratch),
            applied: AtomicU64::new(0),
            loaded_cycle: AtomicU64::new(NEVER),
        }? Error))
    }

    /// The servo cycle at which a sequence was last (un)loaded, or [`NEVER`].
    pub(crate) fn loaded_cycle(&self) -> u64 {
        self.loaded_cycle.load(Ordering::Acquire)
    }

    /// No more hand-offs (rmmod): writers get `EPIPE`, a waiting writer
    /// is released.
    pub(crate) fn close(&self) {
        self.ring.close(true);
        self.taken.complete_all();
    }
}

/// Effort writers wait for SERVO to take their record this long at most (ns).
const EFFORT_TAKE_NS: i64 = 100_000_000;
/// A writer re-checks whether SERVO took its record at least this often.
const EFFORT_POLL: Timeout = Timeout::from_millis(1);

/// SERVO's side of the hand-off: the ring's consumer token.
pub(crate) struct EffortTaker<'a> {
    ch: &'a EffortChannel,
    ring: Consumer<'a, EFFORT_RECORD_BYTES>,
}

impl EffortChannel {
    /// SERVO's side, claimed once by SERVO (`None` if it is held).
    pub(crate) fn claim_taker(&self) -> Option<EffortTaker<'_>> {
        Some(EffortTaker {
            ch: self,
            ring: self.ring.claim_consumer()?,
        })
    }
}

impl EffortTaker<'_> {
    /// SERVO, at the top of its cycle (with `mtx_data`, which only SERVO
    /// takes): apply the effort commands handed over since its last cycle.
    /// Never waits; a few KiB copied at most per command.
    pub(crate) fn take(&self, d: &mut ServoData) {
        take_effort(self.ch, &self.ring, d);
    }
}

fn take_effort(ch: &EffortChannel, ring: &Consumer<'_, EFFORT_RECORD_BYTES>, d: &mut ServoData) {
    let mut taken = false;
    while let Some(n) = ring.pop(&mut d.handoff) {
        taken = true;
        let rec = d.handoff.get(..n).unwrap_or(&[]);
        match EffortHandoff::decode(rec, &mut d.keys) {
            Some(EffortHandoff::Clear) => {
                let _ = d.cycle.servo.load_effort(&[]);
                ch.loaded_cycle
                    .store(d.cycle.servo.cycle(), Ordering::Release);
            }
            Some(EffortHandoff::LiveOff) => d.cycle.servo.set_live_effort(None),
            Some(EffortHandoff::Live(sample)) => d.cycle.servo.set_live_effort(Some(sample)),
            Some(EffortHandoff::Sequence(keys)) => {
                d.cycle.servo.load_effort(keys);
                ch.loaded_cycle
                    .store(d.cycle.servo.cycle(), Ordering::Release);
            }
            None => {}
        }
        ch.applied.fetch_add(1, Ordering::AcqRel);
    }
    if taken {
        ch.taken.complete();
    }
}

/// `/dev/hap_effort`.
pub(crate) struct Effort;

/// The effort writers' scratch (under `EffortChannel::writer`, a lock only
/// the writers take).
pub(crate) struct EffortScratch {
    keys: [EffortKeyframe; EFFORT_CAPACITY],
    record: [u8; EFFORT_RECORD_BYTES],
}

impl EffortScratch {
    /// Built zeroed in its allocation (~8 KiB, never on the stack).
    pub(crate) fn new_boxed() -> Result<KBox<EffortScratch>> {
        KBox::init(
            init!(EffortScratch {
                keys <- pin_init::init_zeroed(),
                record <- pin_init::init_zeroed(),
            }),
            GFP_KERNEL,
        )
    }
}

impl HapDevice for Effort {
    const NAMES: &'static [&'static CStr] = &[c"hap_effort", c"hap1_effort"];

    type Part = EffortChannel;

    fn open(_ch: &Arc<EffortChannel>) -> Result<Self> {
        Ok(Effort)
    }

    fn write(f: &OpenFile<Self>, iov: &mut IovIterSource<'_>) -> Result<usize> {
        let ch = &f.part;
        let len = iov.len();
        if len == 0 || len > EFFORT_MAX_BYTES {
            return Err(EINVAL);
        }
        let mut text = KVVec::new();
        let n = iov.copy_from_iter_vec(&mut text, GFP_KERNEL)?;
        // Parsed and validated here, in the writer, without any lock of
        // SERVO's: a refused write changes nothing.
        let cmd = match parse_effort_command(&text, EFFORT_CAPACITY) {
            Ok(c) => c,
            Err(EffortCommandError::BadLive) => return Err(EINVAL),
            Err(EffortCommandError::Sequence(e)) => {
                pr_warn!(
                    "effort sequence refused: line {} column {}: {:?}\n",
                    e.line,
                    e.column,
                    e.kind
                );
                return Err(EINVAL);
            }
        };
        let loaded_keys = match &cmd {
            EffortCommand::Sequence { keyframes, .. } => Some(*keyframes),
            _ => None,
        };
        let mut guard = ch.writer.lock();
        let s = &mut **guard;
        let rec_len = match cmd {
            EffortCommand::Clear => EffortHandoff::Clear.encode(&mut s.record),
            EffortCommand::LiveOff => EffortHandoff::LiveOff.encode(&mut s.record),
            EffortCommand::Live(sample) => EffortHandoff::Live(sample).encode(&mut s.record),
            EffortCommand::Sequence { text, .. } => {
                let keys = parse_effort_sequence(text, &mut s.keys).map_err(|_| EINVAL)?;
                EffortHandoff::Sequence(s.keys.get(..keys).unwrap_or(&[])).encode(&mut s.record)
            }
        };
        let ticket = ch.ring.counts().1.saturating_add(1);
        match ch
            .ring
            .push_serialised(s.record.get(..rec_len).unwrap_or(&[]))
        {
            Ok(()) => {}
            Err(Refused::Full) => return Err(EBUSY),
            Err(Refused::Closed) => return Err(EPIPE),
        }
        // Wait (the writer, not SERVO) until SERVO has taken it. The
        // completion may hold wake-ups of records already seen taken: each
        // wait consumes one, the deadline bounds the whole.
        let deadline = Ktime::now().saturating_add_ns(EFFORT_TAKE_NS);
        while ch.applied.load(Ordering::Acquire) < ticket {
            if Ktime::now() > deadline || ch.ring.is_closed() {
                return Err(EBUSY);
            }
            ch.taken.wait_timeout(EFFORT_POLL);
        }
        if let Some(keyframes) = loaded_keys {
            pr_info!(
                "effort sequence loaded: {} keyframes at cycle {}\n",
                keyframes,
                ch.loaded_cycle()
            );
        }
        drop(guard);
        Ok(n)
    }
}
