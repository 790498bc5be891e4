// SPDX-License-Identifier: GPL-2.0

//! The RT-FIFOs between the protocol bridge (userspace) and the kernel tasks,
//! after RTLinux's rtf_* API, and their char devices. Both are hap-core's
//! lock-free ring (`ring.rs`):
//! - `/dev/hap_rtf_in`: one `write()` = one whole frame. A write whose length
//!   is not the length of a valid frame (from its type byte) gets `EINVAL`
//!   and is counted; a full FIFO gets `EAGAIN` (counted, never silently lost).
//!   Writers queue among themselves on a lock PROTO_IN (the consumer) never
//!   takes. Each accepted frame posts `rtf_in_ready` (the spec's `sem_rtf_in`).
//! - `/dev/hap_rtf_out`: one `read()` = one whole frame (buffer of at least
//!   90 bytes, else `EINVAL`): PROTO_IN's replies first, then SERVO's
//!   answers, two single-producer lanes. Blocks until a frame is there, or
//!   `EAGAIN` if the file was opened `O_NONBLOCK`; returns 0 (end of file)
//!   once the protocol is closed. SERVO never waits for a reader and takes
//!   no lock a reader holds: a full FIFO refuses the new answer (counted in
//!   `answers_dropped`).

use crate::{
    device::{HapDevice, OpenFile},
    hap_core::protocol,
    ring::Refused,
    shared::Shared,
};
use kernel::{
    iov::{IovIterDest, IovIterSource},
    prelude::*,
    sync::{
        atomic::{Atomic, Relaxed},
        Arc,
    },
};

use protocol::MAX_FRAME_LEN;

/// Frames each FIFO (each lane of rtf_out) holds.
pub(crate) const RTF_FRAMES: usize = 128;

/// Counters of the rtf_in device itself (before PROTO_IN sees the frames).
pub(crate) struct RtfInCounters {
    pub(crate) bad_length: Atomic<u64>,
    pub(crate) full: Atomic<u64>,
}

impl RtfInCounters {
    pub(crate) const fn new() -> Self {
        RtfInCounters {
            bad_length: Atomic::new(0),
            full: Atomic::new(0),
        }
    }
}

/// `/dev/hap_rtf_in`.
pub(crate) struct RtfIn;

impl HapDevice for RtfIn {
    const NAME: &'static CStr = c"hap_rtf_in";

    fn open(_sh: &Arc<Shared>) -> Result<Self> {
        Ok(RtfIn)
    }

    fn write(f: &OpenFile<Self>, iov: &mut IovIterSource<'_>) -> Result<usize> {
        let sh = &f.shared;
        let len = iov.len();
        let mut frame = [0u8; MAX_FRAME_LEN];
        if !(protocol::MIN_FRAME_LEN..=MAX_FRAME_LEN).contains(&len) {
            sh.rtf_in_counters.bad_length.add(1, Relaxed);
            return Err(EINVAL);
        }
        let buf = frame.get_mut(..len).ok_or(EINVAL)?;
        let n = iov.copy_from_iter(buf);
        if n != len {
            return Err(EFAULT);
        }
        // Exactly one frame of the length its type byte announces; anything
        // else (including unknown types) is refused here. CRC and contents
        // are PROTO_IN's job.
        let bytes = frame.get(..n).ok_or(EINVAL)?;
        if protocol::expected_len(bytes) != Some(n) {
            sh.rtf_in_counters.bad_length.add(1, Relaxed);
            return Err(EINVAL);
        }
        match sh.rtf_in.push_serialised(bytes) {
            Ok(()) => {
                sh.rtf_in_ready.complete();
                Ok(n)
            }
            Err(Refused::Full) => {
                sh.rtf_in_counters.full.add(1, Relaxed);
                Err(EAGAIN)
            }
            Err(Refused::Closed) => Err(EPIPE),
        }
    }
}

/// `/dev/hap_rtf_out`.
pub(crate) struct RtfOut;

impl HapDevice for RtfOut {
    const NAME: &'static CStr = c"hap_rtf_out";

    fn open(_sh: &Arc<Shared>) -> Result<Self> {
        Ok(RtfOut)
    }

    fn read(f: &OpenFile<Self>, _pos: &mut i64, iov: &mut IovIterDest<'_>) -> Result<usize> {
        if iov.len() < MAX_FRAME_LEN {
            return Err(EINVAL);
        }
        let sh = &f.shared;
        let mut frame = [0u8; MAX_FRAME_LEN];
        let n = sh
            .rtf_out
            .pop_wait_with(Some(&sh.rtf_replies), &mut frame, f.nonblock)?;
        Ok(iov.copy_to_iter(frame.get(..n).unwrap_or(&[])))
    }
}
