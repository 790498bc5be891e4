// SPDX-License-Identifier: GPL-2.0

//! hap_simulator's channels to userspace (the spec's simulator RT-FIFOs):
//! - `/dev/hap_effort`: the user's effort on the handle. One `write()` of a
//!   whole effort-sequence text (hap-core's `.eff` format, at most 64 KiB)
//!   loads it; it plays from the servo cycle it was loaded at. A parse error
//!   gets `EINVAL` and a dmesg line with its line and column. A single line
//!   `live fx fy fz tx ty tz` (N, N·m) sets a live effort that overrides the
//!   sequence; `live off` ends it; `clear` unloads the sequence.
//!   The writer parses and validates the text itself (hap-core), without any
//!   lock of SERVO's, and hands the result over in one record of a lock-free
//!   ring (`Shared::effort`); SERVO takes it at the top of its next cycle
//!   without waiting, and the `write()` returns once it has (`EBUSY` if
//!   SERVO does not take it within 100 ms, e.g. after the fail-safe).
//! - `/dev/hap_simlog`: the position log, whole `LogRecord`s (560 bytes
//!   each, hap-core's layout); a read returns as many whole records as fit,
//!   blocking until one is there (`EAGAIN` with `O_NONBLOCK`, end of file
//!   after the fail-safe). SERVO pushes one record per cycle without
//!   waiting; when nobody reads and the log is full, new records are refused
//!   (counted in `simlog.dropped`). Each fail-safe step
//!   adds a record of mode `FailSafe` ([`log_fail_safe_step`]).

use crate::{
    device::{HapDevice, OpenFile},
    hap_core::{
        effort::{
            parse_effort_command, parse_effort_sequence, EffortCommand, EffortCommandError,
            EffortHandoff, EffortKeyframe, EFFORT_CAPACITY, EFFORT_RECORD_BYTES,
        },
        simulator::{LogMode, LogRecord, LogTiming},
        vp::alarm,
    },
    ring::Refused,
    shared::{ServoData, Shared},
};
use core::sync::atomic::Ordering;
use kernel::{
    iov::{IovIterDest, IovIterSource},
    prelude::*,
    sync::{
        atomic::{Acquire, Release},
        Arc,
    },
};

/// Largest effort-sequence write.
const EFFORT_MAX_BYTES: usize = 64 * 1024;

/// SERVO, at the top of its cycle (with `mtx_data`, which only SERVO
/// takes): apply the effort commands handed over since its last cycle.
/// Never waits; a few KiB copied at most per command.
pub(crate) fn take_effort(sh: &Shared, d: &mut ServoData) {
    let mut taken = false;
    while let Some(n) = sh.effort.pop(&mut d.handoff) {
        taken = true;
        let rec = d.handoff.get(..n).unwrap_or(&[]);
        match EffortHandoff::decode(rec, &mut d.keys) {
            Some(EffortHandoff::Clear) => {
                let _ = d.cycle.servo.load_effort(&[]);
                sh.effort_loaded_cycle.store(d.cycle.servo.cycle(), Release);
            }
            Some(EffortHandoff::LiveOff) => d.cycle.servo.set_live_effort(None),
            Some(EffortHandoff::Live(sample)) => d.cycle.servo.set_live_effort(Some(sample)),
            Some(EffortHandoff::Sequence(keys)) => {
                d.cycle.servo.load_effort(keys);
                sh.effort_loaded_cycle.store(d.cycle.servo.cycle(), Release);
            }
            None => {}
        }
        sh.effort_applied.fetch_add(1, Ordering::AcqRel);
    }
    if taken {
        sh.effort_taken.complete();
    }
}

/// `/dev/hap_effort`.
pub(crate) struct Effort;

/// Effort writers wait for SERVO to take their record this long at most (ns).
const EFFORT_TAKE_NS: i64 = 100_000_000;

/// The effort writers' scratch (`Shared::effort_writer`, a lock only the
/// writers take).
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
    const NAME: &'static CStr = c"hap_effort";

    fn open(_sh: &Arc<Shared>) -> Result<Self> {
        Ok(Effort)
    }

    fn write(f: &OpenFile<Self>, iov: &mut IovIterSource<'_>) -> Result<usize> {
        let sh = &f.shared;
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
        let mut guard = sh.effort_writer.lock();
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
        let ticket = sh.effort.counts().1.saturating_add(1);
        match sh.effort.push(s.record.get(..rec_len).unwrap_or(&[])) {
            Ok(()) => {}
            Err(Refused::Full) => return Err(EBUSY),
            Err(Refused::Closed) => return Err(EPIPE),
        }
        // Wait (the writer, not SERVO) until SERVO has taken it. The
        // completion may hold wake-ups of records already seen taken: each
        // wait consumes one, the deadline bounds the whole.
        let deadline = sh.now_ns().saturating_add(EFFORT_TAKE_NS);
        while sh.effort_applied.load(Ordering::Acquire) < ticket {
            if sh.now_ns() > deadline || sh.is_stopping() {
                return Err(EBUSY);
            }
            sh.effort_taken.wait_timeout(1);
        }
        if let Some(keyframes) = loaded_keys {
            pr_info!(
                "effort sequence loaded: {} keyframes at cycle {}\n",
                keyframes,
                sh.effort_loaded_cycle.load(Acquire)
            );
        }
        drop(guard);
        Ok(n)
    }
}

/// `/dev/hap_simlog`.
pub(crate) struct SimLog;

impl HapDevice for SimLog {
    const NAME: &'static CStr = c"hap_simlog";

    fn open(_sh: &Arc<Shared>) -> Result<Self> {
        Ok(SimLog)
    }

    fn read(f: &OpenFile<Self>, _pos: &mut i64, iov: &mut IovIterDest<'_>) -> Result<usize> {
        let sh = &f.shared;
        if iov.len() < LogRecord::SIZE {
            return Err(EINVAL);
        }
        // One record, waiting for it if need be; then whatever else fits.
        let mut rec = [0u8; LogRecord::SIZE];
        if sh.simlog.pop_wait(&mut rec, f.nonblock)? == 0 {
            return Ok(0);
        }
        let mut total = 0usize;
        loop {
            if iov.copy_to_iter(&rec) != LogRecord::SIZE {
                return if total > 0 { Ok(total) } else { Err(EFAULT) };
            }
            total = total.saturating_add(LogRecord::SIZE);
            if iov.len() < LogRecord::SIZE || sh.simlog.pop_serialised(&mut rec).is_none() {
                return Ok(total);
            }
        }
    }
}

/// Log fail-safe step `step` (1-based, `FAIL_SAFE_SEQUENCE` order) as it
/// starts: the servo's last record with mode `FailSafe`, the arm status
/// now, and the tick. If SERVO holds `mtx_data` (a hung or overrunning
/// cycle), its state is unknown: an empty record flagged `POSE_UNKNOWN`,
/// which the analysis does not read as a pose.
pub(crate) fn log_fail_safe_step(sh: &Shared, step: u8) {
    let mut rec = match sh.data.try_lock() {
        Some(d) => *d.cycle.servo.log_record(),
        None => LogRecord {
            flags: crate::hap_core::servo::log_flags::POSE_UNKNOWN,
            ..LogRecord::ZERO
        },
    };
    rec.mode = LogMode::FailSafe;
    rec.fail_safe_step = step;
    // What the motors apply now, read from the line (not SERVO's last record).
    rec.motor_torque = sh.motor_line.applied();
    if sh.motor_line.gate() == crate::hap_core::io::Gate::FailSafe {
        rec.flags |= crate::hap_core::servo::log_flags::LINE_CUT;
    }
    rec.status = crate::io::arm_status(sh);
    rec.alarms |= alarm::FAIL_SAFE;
    rec.timing = LogTiming {
        tick: sh.cycle.tick(),
        start_ns: u64::try_from(sh.now_ns()).unwrap_or(0),
        wakeup_ns: 0,
        exec_ns: 0,
        session: 0,
    };
    let mut buf = [0u8; LogRecord::SIZE];
    rec.encode(&mut buf);
    // SERVO may be mid-push (CLOCK preempted it): the record is refused and
    // counted rather than waited for, since the next step cuts the motors.
    let _ = sh.simlog.try_push_exclusive(&buf);
}
