// SPDX-License-Identifier: GPL-2.0

//! The position log (the spec's simulator position RT-FIFO) and
//! `/dev/hap_simlog`: whole `LogRecord`s (560 bytes each, hap-core's
//! layout); a read returns as many whole records as fit, blocking until one
//! is there (`EAGAIN` with `O_NONBLOCK`, end of file after the fail-safe).
//! SERVO pushes one record per cycle without waiting; when nobody reads and
//! the log is full, new records are refused (counted in `simlog.dropped`).
//! Each fail-safe step adds a record of mode `FailSafe`, pushed by CLOCK.

use crate::{
    device::{HapDevice, OpenFile},
    hap_core::position_log::LogRecord,
    ring::Fifo,
};
use kernel::{iov::IovIterDest, prelude::*, sync::Arc};

/// Position-log records kept until read (about 2 s at 1 kHz; 560-byte
/// records, one ~1.1 MB allocation).
pub(crate) const SIMLOG_RECORDS: usize = 2048;

/// The position log.
///
/// Protocol: two real-time producers, SERVO (one record per cycle) and
/// CLOCK's fail-safe (one per step), which never wait for each other
/// (`Fifo::try_push_exclusive`: the one that finds the other mid-push is
/// refused and counted); the device's readers are the consumers,
/// serialised among themselves.
#[pin_data]
pub(crate) struct PositionLog {
    #[pin]
    ring: Fifo<{ LogRecord::SIZE }>,
}

impl PositionLog {
    pub(crate) fn new() -> Result<impl PinInit<Self, Error>> {
        let ring = Fifo::new(SIMLOG_RECORDS)?;
        Ok(try_pin_init!(Self { ring <- ring }? Error))
    }

    /// Append one record: refused (counted in `simlog.dropped`) when the
    /// log is full or the other producer is pushing at that moment; never
    /// waits.
    pub(crate) fn push(&self, rec: &LogRecord) {
        let mut buf = [0u8; LogRecord::SIZE];
        rec.encode(&mut buf);
        let _ = self.ring.try_push_exclusive(&buf);
    }

    /// No more records; with `discard`, readers see end of file at once,
    /// else they drain the log first (kept for post-mortem analysis).
    pub(crate) fn close(&self, discard: bool) {
        self.ring.close(discard);
    }

    /// (records queued, records pushed, records refused)
    pub(crate) fn counts(&self) -> (usize, u64, u64) {
        self.ring.counts()
    }
}

/// `/dev/hap_simlog`.
pub(crate) struct SimLog;

impl HapDevice for SimLog {
    const NAMES: &'static [&'static CStr] = &[c"hap_simlog", c"hap1_simlog"];

    type Part = PositionLog;

    fn open(_log: &Arc<PositionLog>) -> Result<Self> {
        Ok(SimLog)
    }

    fn read(f: &OpenFile<Self>, _pos: &mut i64, iov: &mut IovIterDest<'_>) -> Result<usize> {
        let log = &f.part;
        if iov.len() < LogRecord::SIZE {
            return Err(EINVAL);
        }
        // One record, waiting for it if need be; then whatever else fits.
        let mut rec = [0u8; LogRecord::SIZE];
        if log.ring.pop_wait(&mut rec, f.nonblock)? == 0 {
            return Ok(0);
        }
        let mut total = 0usize;
        loop {
            if iov.copy_to_iter(&rec) != LogRecord::SIZE {
                return if total > 0 { Ok(total) } else { Err(EFAULT) };
            }
            total = total.saturating_add(LogRecord::SIZE);
            if iov.len() < LogRecord::SIZE || log.ring.pop_serialised(&mut rec).is_none() {
                return Ok(total);
            }
        }
    }
}
