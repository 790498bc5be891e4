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
    completion::Completion,
    device::{HapDevice, OpenFile},
    hap_core::protocol,
    ring::{Fifo, Refused},
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

/// The RT-FIFO pair between the bridge and the kernel tasks, and what is
/// counted on its way.
///
/// Protocol:
/// - `rtf_in`: producers are the device's writers, serialised among
///   themselves (`Fifo::push_serialised`); the consumer is PROTO_IN. Each
///   accepted frame posts `rtf_in_ready` (the spec's `sem_rtf_in`), which
///   only PROTO_IN waits on.
/// - `rtf_out`: SERVO's answers, SERVO the only producer; `rtf_replies`:
///   PROTO_IN's replies, PROTO_IN the only producer, who then rings
///   rtf_out's doorbell. The readers of /dev/hap_rtf_out are the consumers
///   of both, serialised among themselves.
/// - The counters are statistics (Relaxed): `answer_seq` numbers the frames
///   SERVO and PROTO_IN send (one sequence for both, as on the wire);
///   `answers_sent` and `answers_skipped_latch_busy` are SERVO's;
///   `answers_dropped` counts the frames a full lane refused, SERVO's and
///   PROTO_IN's.
#[pin_data]
pub(crate) struct RtfPair {
    #[pin]
    pub(crate) rtf_in: Fifo<MAX_FRAME_LEN>,
    #[pin]
    pub(crate) rtf_in_ready: Completion,
    #[pin]
    pub(crate) rtf_out: Fifo<MAX_FRAME_LEN>,
    #[pin]
    pub(crate) rtf_replies: Fifo<MAX_FRAME_LEN>,
    pub(crate) rtf_in_counters: RtfInCounters,
    answer_seq: Atomic<u32>,
    pub(crate) answers_sent: Atomic<u64>,
    /// Cycles whose answers SERVO skipped: its read of the VPr latch's
    /// session overlapped PROTO_IN's publication on every attempt.
    pub(crate) answers_skipped_latch_busy: Atomic<u64>,
    pub(crate) answers_dropped: Atomic<u64>,
}

impl RtfPair {
    pub(crate) fn new() -> Result<impl PinInit<Self, Error>> {
        let rtf_in = Fifo::new(RTF_FRAMES)?;
        let rtf_out = Fifo::new(RTF_FRAMES)?;
        let rtf_replies = Fifo::new(RTF_FRAMES)?;
        Ok(try_pin_init!(Self {
            rtf_in <- rtf_in,
            rtf_in_ready <- Completion::new(),
            rtf_out <- rtf_out,
            rtf_replies <- rtf_replies,
            rtf_in_counters: RtfInCounters::new(),
            answer_seq: Atomic::new(0),
            answers_sent: Atomic::new(0),
            answers_skipped_latch_busy: Atomic::new(0),
            answers_dropped: Atomic::new(0),
        }? Error))
    }

    /// The next sequence number of a frame the controller sends.
    pub(crate) fn next_seq(&self) -> u32 {
        self.answer_seq.fetch_add(1, Relaxed).wrapping_add(1)
    }

    /// Close the pair (the fail-safe's `CloseProtocol`, rmmod): readers and
    /// writers see end of file at once, what is queued is dropped.
    pub(crate) fn close(&self) {
        self.rtf_out.close(true);
        self.rtf_replies.close(true);
        self.rtf_in.close(true);
    }
}

/// `/dev/hap_rtf_in`.
pub(crate) struct RtfIn;

impl HapDevice for RtfIn {
    const NAMES: &'static [&'static CStr] = &[c"hap_rtf_in", c"hap1_rtf_in"];

    type Part = RtfPair;

    fn open(_rtf: &Arc<RtfPair>) -> Result<Self> {
        Ok(RtfIn)
    }

    fn write(f: &OpenFile<Self>, iov: &mut IovIterSource<'_>) -> Result<usize> {
        let sh = &f.part;
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
    const NAMES: &'static [&'static CStr] = &[c"hap_rtf_out", c"hap1_rtf_out"];

    type Part = RtfPair;

    fn open(_rtf: &Arc<RtfPair>) -> Result<Self> {
        Ok(RtfOut)
    }

    fn read(f: &OpenFile<Self>, _pos: &mut i64, iov: &mut IovIterDest<'_>) -> Result<usize> {
        if iov.len() < MAX_FRAME_LEN {
            return Err(EINVAL);
        }
        let sh = &f.part;
        let mut frame = [0u8; MAX_FRAME_LEN];
        let n = sh
            .rtf_out
            .pop_wait_with(Some(&sh.rtf_replies), &mut frame, f.nonblock)?;
        Ok(iov.copy_to_iter(frame.get(..n).unwrap_or(&[])))
    }
}
