// SPDX-License-Identifier: GPL-2.0

//! hap_simulator's channels to userspace (the spec's simulator RT-FIFOs):
//! - `/dev/hap_effort`: the user's effort on the handle. One `write()` of a
//!   whole effort-sequence text (hap-core's `.eff` format, at most 64 KiB)
//!   loads it; it plays from the servo cycle it was loaded at. A parse error
//!   gets `EINVAL` and a dmesg line with its line and column. A single line
//!   `live fx fy fz tx ty tz` (N, N·m) sets a live effort that overrides the
//!   sequence; `live off` ends it; `clear` unloads the sequence.
//! - `/dev/hap_simlog`: the position log, whole `LogRecord`s (560 bytes
//!   each, hap-core's layout); a read returns as many whole records as fit,
//!   blocking until one is there (`EAGAIN` with `O_NONBLOCK`, end of file
//!   after the fail-safe). When nobody reads, the oldest records are dropped
//!   (counted: `simlog.dropped` in `/dev/hap_stats`). Each fail-safe step
//!   adds a record of mode `FailSafe` ([`log_fail_safe_step`]).

use crate::{
    hap_core::{
        effort::{parse_effort_command, EffortCommand, EffortCommandError, EFFORT_CAPACITY},
        simulator::{LogMode, LogRecord, LogTiming},
        vp::alarm,
    },
    shared::{DeviceFile, Shared},
};
use kernel::{
    fs::{File, Kiocb},
    iov::{IovIterDest, IovIterSource},
    miscdevice::{MiscDevice, MiscDeviceRegistration},
    prelude::*,
    sync::atomic::{Acquire, Relaxed, Release},
};

/// Largest effort-sequence write.
const EFFORT_MAX_BYTES: usize = 64 * 1024;

pub(crate) struct EffortDevice {
    f: DeviceFile,
}

#[vtable]
impl MiscDevice for EffortDevice {
    type Ptr = KBox<Self>;

    fn open(file: &File, _misc: &MiscDeviceRegistration<Self>) -> Result<KBox<Self>> {
        Ok(KBox::new(
            EffortDevice {
                f: DeviceFile::open(file)?,
            },
            GFP_KERNEL,
        )?)
    }

    fn write_iter(kiocb: Kiocb<'_, Self::Ptr>, iov: &mut IovIterSource<'_>) -> Result<usize> {
        let sh = &kiocb.file().f.shared;
        let len = iov.len();
        if len == 0 || len > EFFORT_MAX_BYTES {
            return Err(EINVAL);
        }
        let mut text = KVVec::new();
        let n = iov.copy_from_iter_vec(&mut text, GFP_KERNEL)?;
        // Parsed and validated by hap-core before mtx_data is taken: a refused
        // write changes nothing and never holds SERVO's lock while parsing.
        match parse_effort_command(&text, EFFORT_CAPACITY) {
            Ok(EffortCommand::Clear) => {
                let mut d = sh.data.lock();
                let _ = d.cycle.servo.load_effort(&[]);
                sh.effort_loaded_cycle.store(d.cycle.servo.cycle(), Relaxed);
            }
            Ok(EffortCommand::LiveOff) => sh.data.lock().cycle.servo.set_live_effort(None),
            Ok(EffortCommand::Live(sample)) => {
                sh.data.lock().cycle.servo.set_live_effort(Some(sample))
            }
            Ok(EffortCommand::Sequence { text, .. }) => {
                let mut d = sh.data.lock();
                let keys = d.cycle.servo.load_effort_text(text).map_err(|_| EINVAL)?;
                let cycle = d.cycle.servo.cycle();
                drop(d);
                sh.effort_loaded_cycle.store(cycle, Release);
                pr_info!(
                    "effort sequence loaded: {} keyframes at cycle {}\n",
                    keys,
                    cycle
                );
            }
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
        }
        Ok(n)
    }
}

pub(crate) struct SimLogDevice {
    f: DeviceFile,
}

#[vtable]
impl MiscDevice for SimLogDevice {
    type Ptr = KBox<Self>;

    fn open(file: &File, _misc: &MiscDeviceRegistration<Self>) -> Result<KBox<Self>> {
        Ok(KBox::new(
            SimLogDevice {
                f: DeviceFile::open(file)?,
            },
            GFP_KERNEL,
        )?)
    }

    fn read_iter(kiocb: Kiocb<'_, Self::Ptr>, iov: &mut IovIterDest<'_>) -> Result<usize> {
        let me = kiocb.file();
        let sh = &me.f.shared;
        if iov.len() < LogRecord::SIZE {
            return Err(EINVAL);
        }
        // One record, waiting for it if need be; then whatever else fits.
        let mut rec = [0u8; LogRecord::SIZE];
        if sh.simlog.pop_wait(&mut rec, me.f.nonblock)? == 0 {
            return Ok(0);
        }
        let mut total = 0usize;
        loop {
            if iov.copy_to_iter(&rec) != LogRecord::SIZE {
                return if total > 0 { Ok(total) } else { Err(EFAULT) };
            }
            total += LogRecord::SIZE;
            if iov.len() < LogRecord::SIZE || sh.simlog.pop(&mut rec).is_none() {
                return Ok(total);
            }
        }
    }
}

/// Log fail-safe step `step` (1-based, `FAIL_SAFE_SEQUENCE` order) as it
/// starts: the servo's last record (or an empty one if SERVO holds
/// `mtx_data`) with mode `FailSafe`, the arm status now, and the tick.
pub(crate) fn log_fail_safe_step(sh: &Shared, step: u8) {
    let mut rec = match sh.data.try_lock() {
        Some(d) => *d.cycle.servo.log_record(),
        None => LogRecord::ZERO,
    };
    rec.mode = LogMode::FailSafe;
    rec.fail_safe_step = step;
    rec.status = crate::io::arm_status(sh);
    rec.alarms |= alarm::FAIL_SAFE;
    rec.timing = LogTiming {
        tick: sh.tick.load(Acquire),
        start_ns: u64::try_from(sh.now_ns()).unwrap_or(0),
        wakeup_ns: 0,
        exec_ns: 0,
        session: 0,
    };
    let mut buf = [0u8; LogRecord::SIZE];
    rec.encode(&mut buf);
    sh.simlog.push_overwrite(&buf);
}
