// SPDX-License-Identifier: GPL-2.0

//! The controller's char devices.

use crate::{hap_core, shared::Shared, SHARED};
use core::fmt::Write;
use kernel::{
    fs::{File, Kiocb},
    iov::{IovIterDest, IovIterSource},
    miscdevice::{MiscDevice, MiscDeviceRegistration},
    prelude::*,
    sync::{
        atomic::{Relaxed, Release},
        Arc,
    },
};

/// The shared state, or ENODEV while the controller is not running.
fn shared() -> Result<Arc<Shared>> {
    SHARED.lock().as_ref().cloned().ok_or(ENODEV)
}

/// A fixed-capacity text buffer for `core::fmt` (no allocation while formatting).
pub(crate) struct TextBuf<const N: usize> {
    buf: [u8; N],
    len: usize,
}

impl<const N: usize> TextBuf<N> {
    pub(crate) fn new() -> Self {
        TextBuf { buf: [0; N], len: 0 }
    }
    pub(crate) fn as_bytes(&self) -> &[u8] {
        &self.buf[..self.len]
    }
}

impl<const N: usize> Write for TextBuf<N> {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        let room = N - self.len;
        let n = s.len().min(room);
        self.buf[self.len..self.len + n].copy_from_slice(&s.as_bytes()[..n]);
        self.len += n;
        if n < s.len() {
            Err(core::fmt::Error)
        } else {
            Ok(())
        }
    }
}

/// `/dev/hap_stats`: a text snapshot taken at open, read like a file.
pub(crate) struct StatsDevice {
    text: KBox<TextBuf<2048>>,
}

#[vtable]
impl MiscDevice for StatsDevice {
    type Ptr = KBox<Self>;

    fn open(_file: &File, _misc: &MiscDeviceRegistration<Self>) -> Result<KBox<Self>> {
        let shared = shared()?;
        let mut text = KBox::new(TextBuf::new(), GFP_KERNEL)?;
        let _ = writeln!(text, "period_us: {}", shared.period_ns / 1000);
        let _ = writeln!(text, "timer_ticks: {}", shared.timer_ticks.load(Relaxed));
        let _ = writeln!(text, "servo_cycles: {}", shared.servo_cycles.load(Relaxed));
        let _ = writeln!(text, "latency_last_ns: {}", shared.last_latency_ns.load(Relaxed));
        let _ = writeln!(text, "latency_max_ns: {}", shared.max_latency_ns.load(Relaxed));
        let _ = writeln!(text, "rtf_in_writes: {}", shared.rtf_in_writes.load(Relaxed));
        let _ = writeln!(text, "rtf_in_last_crc32c: {:#010x}", shared.rtf_in_last_crc.load(Relaxed));
        Ok(KBox::new(StatsDevice { text }, GFP_KERNEL)?)
    }

    fn read_iter(mut kiocb: Kiocb<'_, Self::Ptr>, iov: &mut IovIterDest<'_>) -> Result<usize> {
        let me = kiocb.file();
        let text = me.text.as_bytes();
        iov.simple_read_from_buffer(kiocb.ki_pos_mut(), text)
    }
}

/// `/dev/hap_rtf_in`: frames from the protocol bridge (skeleton: checksummed and counted).
pub(crate) struct RtfInDevice;

#[vtable]
impl MiscDevice for RtfInDevice {
    type Ptr = KBox<Self>;

    fn open(_file: &File, _misc: &MiscDeviceRegistration<Self>) -> Result<KBox<Self>> {
        shared()?;
        Ok(KBox::new(RtfInDevice, GFP_KERNEL)?)
    }

    fn write_iter(_kiocb: Kiocb<'_, Self::Ptr>, iov: &mut IovIterSource<'_>) -> Result<usize> {
        let shared = shared()?;
        let mut frame = [0u8; 90];
        if iov.len() > frame.len() || iov.is_empty() {
            return Err(EINVAL);
        }
        let n = iov.copy_from_iter(&mut frame);
        let crc = hap_core::crc::crc32c(&frame[..n]);
        shared.rtf_in_last_crc.store(crc, Release);
        shared.rtf_in_writes.add(1, Relaxed);
        Ok(n)
    }
}
