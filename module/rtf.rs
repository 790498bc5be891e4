// SPDX-License-Identifier: GPL-2.0

//! The RT-FIFOs between the protocol bridge (userspace) and the kernel tasks,
//! after RTLinux's rtf_* API, and their char devices:
//! - `/dev/hap_rtf_in`: one `write()` = one whole frame. A write whose length
//!   is not the length of a valid frame (from its type byte) gets `EINVAL`
//!   and is counted; a full FIFO gets `EAGAIN` (counted, never silently lost).
//!   Each accepted frame posts `rtf_in_ready` (the spec's `sem_rtf_in`).
//! - `/dev/hap_rtf_out`: one `read()` = one whole answer frame (buffer of at
//!   least 90 bytes, else `EINVAL`). Blocks until a frame is there, or
//!   `EAGAIN` if the file was opened `O_NONBLOCK`; returns 0 (end of file)
//!   once the protocol is closed. SERVO never blocks on a reader: a full FIFO
//!   drops its oldest frame (counted).

use crate::{hap_core::protocol, shared::DeviceFile};
use kernel::{
    fs::{File, Kiocb},
    iov::{IovIterDest, IovIterSource},
    miscdevice::{MiscDevice, MiscDeviceRegistration},
    new_condvar, new_mutex,
    prelude::*,
    sync::{
        atomic::{Atomic, Relaxed},
        CondVar, Mutex,
    },
};

use crate::ring::Ring;
use protocol::MAX_FRAME_LEN;

/// Frames each FIFO holds.
pub(crate) const RTF_FRAMES: usize = 128;

pub(crate) struct FifoState<const REC: usize> {
    ring: Ring<REC>,
    /// Closed by the fail-safe or at teardown: readers see end of file once
    /// what is queued has been read.
    closed: bool,
}

/// An RT-FIFO of records of at most `REC` bytes: rtf_in and rtf_out hold
/// frames, the simulator's position log holds `LogRecord`s.
#[pin_data]
pub(crate) struct RtFifo<const REC: usize> {
    #[pin]
    state: Mutex<FifoState<REC>>,
    #[pin]
    readable: CondVar,
}

/// Why a push was refused.
pub(crate) enum PushError {
    Full,
    Closed,
}

impl<const REC: usize> RtFifo<REC> {
    pub(crate) fn new(capacity: usize) -> Result<impl PinInit<Self>> {
        let ring = Ring::new(capacity)?;
        Ok(pin_init!(Self {
            state <- new_mutex!(FifoState { ring, closed: false }),
            readable <- new_condvar!(),
        }))
    }

    /// Queue a frame, dropping the oldest when full (SERVO's side). Returns
    /// false if a frame was dropped.
    pub(crate) fn push_overwrite(&self, frame: &[u8]) -> bool {
        let mut s = self.state.lock();
        if s.closed {
            return false;
        }
        let kept = s.ring.push_overwrite(frame);
        drop(s);
        self.readable.notify_one();
        kept
    }

    /// Queue a frame only if there is room (userspace's side of rtf_in).
    pub(crate) fn push_if_room(&self, frame: &[u8]) -> core::result::Result<(), PushError> {
        let mut s = self.state.lock();
        if s.closed {
            return Err(PushError::Closed);
        }
        if !s.ring.push_if_room(frame) {
            return Err(PushError::Full);
        }
        drop(s);
        self.readable.notify_one();
        Ok(())
    }

    /// Take the oldest frame, without waiting.
    pub(crate) fn pop(&self, out: &mut [u8; REC]) -> Option<usize> {
        self.state.lock().ring.pop(out)
    }

    /// Take the oldest frame, waiting for one unless `nonblock`. `Ok(0)`: closed.
    pub(crate) fn pop_wait(&self, out: &mut [u8; REC], nonblock: bool) -> Result<usize> {
        let mut s = self.state.lock();
        loop {
            if let Some(n) = s.ring.pop(out) {
                return Ok(n);
            }
            if s.closed {
                return Ok(0);
            }
            if nonblock {
                return Err(EAGAIN);
            }
            if self.readable.wait_interruptible(&mut s) {
                return Err(ERESTARTSYS);
            }
        }
    }

    /// Close: no more pushes; wake every reader. With `discard`, what is
    /// queued is dropped (readers see end of file at once); without, readers
    /// drain it first (the position log, kept for post-mortem analysis).
    pub(crate) fn close(&self, discard: bool) {
        let mut s = self.state.lock();
        s.closed = true;
        if discard {
            s.ring.clear();
        }
        drop(s);
        self.readable.notify_all();
    }

    /// (frames queued now, frames pushed, frames dropped)
    pub(crate) fn counts(&self) -> (usize, u64, u64) {
        let s = self.state.lock();
        (s.ring.len(), s.ring.pushed, s.ring.dropped)
    }
}

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
pub(crate) struct RtfInDevice {
    f: DeviceFile,
}

#[vtable]
impl MiscDevice for RtfInDevice {
    type Ptr = KBox<Self>;

    fn open(file: &File, _misc: &MiscDeviceRegistration<Self>) -> Result<KBox<Self>> {
        Ok(KBox::new(
            RtfInDevice {
                f: DeviceFile::open(file)?,
            },
            GFP_KERNEL,
        )?)
    }

    fn write_iter(kiocb: Kiocb<'_, Self::Ptr>, iov: &mut IovIterSource<'_>) -> Result<usize> {
        let sh = &kiocb.file().f.shared;
        let len = iov.len();
        let mut frame = [0u8; MAX_FRAME_LEN];
        if len < protocol::MIN_FRAME_LEN || len > MAX_FRAME_LEN {
            sh.rtf_in_counters.bad_length.add(1, Relaxed);
            return Err(EINVAL);
        }
        let n = iov.copy_from_iter(&mut frame[..len]);
        if n != len {
            return Err(EFAULT);
        }
        // Exactly one frame of the length its type byte announces; anything
        // else (including unknown types) is refused here. CRC and contents
        // are PROTO_IN's job.
        if protocol::expected_len(&frame[..n]) != Some(n) {
            sh.rtf_in_counters.bad_length.add(1, Relaxed);
            return Err(EINVAL);
        }
        match sh.rtf_in.push_if_room(&frame[..n]) {
            Ok(()) => {
                sh.rtf_in_ready.complete();
                Ok(n)
            }
            Err(PushError::Full) => {
                sh.rtf_in_counters.full.add(1, Relaxed);
                Err(EAGAIN)
            }
            Err(PushError::Closed) => Err(EPIPE),
        }
    }
}

/// `/dev/hap_rtf_out`.
pub(crate) struct RtfOutDevice {
    f: DeviceFile,
}

#[vtable]
impl MiscDevice for RtfOutDevice {
    type Ptr = KBox<Self>;

    fn open(file: &File, _misc: &MiscDeviceRegistration<Self>) -> Result<KBox<Self>> {
        Ok(KBox::new(
            RtfOutDevice {
                f: DeviceFile::open(file)?,
            },
            GFP_KERNEL,
        )?)
    }

    fn read_iter(kiocb: Kiocb<'_, Self::Ptr>, iov: &mut IovIterDest<'_>) -> Result<usize> {
        let me = kiocb.file();
        if iov.len() < MAX_FRAME_LEN {
            return Err(EINVAL);
        }
        let mut frame = [0u8; MAX_FRAME_LEN];
        let n = me.f.shared.rtf_out.pop_wait(&mut frame, me.f.nonblock)?;
        Ok(iov.copy_to_iter(&frame[..n]))
    }
}
