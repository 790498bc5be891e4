// SPDX-License-Identifier: GPL-2.0

//! `/dev/hap_stats`: a text snapshot taken at open (`cat` it), rendered by
//! hap-core (`key: value` lines, cyclictest-style summary first), followed by
//! the kernel's own lines (state, mode, device and protocol counters, the
//! module's effective parameters). See Documentation/timing.md.
//!
//! `/dev/hap_hist`: the 1 µs histograms of the three timing series
//! (wake-up, execution, period jitter), copied at open under the stats lock
//! and rendered by hap-core outside it (`render_histograms`).

use crate::{
    hap_core::{
        clock::MISS_LIMIT,
        proto_in::Reject,
        stats::{
            render_histograms, render_summary, HistogramView, SliceWriter, HIST_BUCKETS,
            HIST_RENDER_MAX, HIST_SERIES,
        },
    },
    rtf::RTF_FRAMES,
    shared::{self, state, Shared, NEVER},
};
use core::fmt::Write;
use kernel::{
    fs::{File, Kiocb},
    iov::IovIterDest,
    miscdevice::{MiscDevice, MiscDeviceRegistration},
    prelude::*,
    sync::atomic::{Acquire, Relaxed},
};

/// A fixed-capacity text buffer for `core::fmt` (no allocation while formatting).
pub(crate) struct TextBuf<const N: usize> {
    buf: [u8; N],
    len: usize,
}

impl<const N: usize> TextBuf<N> {
    pub(crate) fn new() -> Self {
        TextBuf {
            buf: [0; N],
            len: 0,
        }
    }

    pub(crate) fn as_bytes(&self) -> &[u8] {
        self.buf.get(..self.len).unwrap_or(&[])
    }
}

impl<const N: usize> Write for TextBuf<N> {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        let end = self.len.saturating_add(s.len()).min(N);
        let n = end - self.len;
        if let (Some(dst), Some(src)) = (self.buf.get_mut(self.len..end), s.as_bytes().get(..n)) {
            dst.copy_from_slice(src);
            self.len = end;
        }
        if n < s.len() {
            Err(core::fmt::Error)
        } else {
            Ok(())
        }
    }
}

const STATS_TEXT_MAX: usize = 8192;

pub(crate) struct StatsDevice {
    text: KVVec<u8>,
}

fn cycle_or_never(v: u64) -> i64 {
    if v == NEVER {
        -1
    } else {
        v as i64
    }
}

fn render(sh: &Shared, out: &mut [u8]) -> usize {
    let (proto_counters, session) = {
        let p = sh.proto.lock();
        (*p.counters(), p.session())
    };
    let (rtf_out_len, _, rtf_out_dropped) = sh.rtf_out.counts();
    let (rtf_in_len, _, _) = sh.rtf_in.counts();
    let summary = {
        let mut st = sh.stats.lock();
        let c = &mut st.counters;
        c.frames_in = proto_counters.accepted;
        c.frames_out = sh.answers_sent.load(Relaxed);
        c.frames_rejected = proto_counters.decode_rejects;
        c.answers_dropped = sh
            .answers_dropped
            .load(Relaxed)
            .saturating_add(rtf_out_dropped);
        c.vpr_extrapolated = sh.vpr_extrapolated.load(Relaxed);
        st.summary()
    };
    let n = render_summary(&summary, out).len;
    let Some(rest) = out.get_mut(n..) else {
        return n;
    };
    let mut w = SliceWriter::new(rest);
    let st = sh.state.load(Acquire) as usize;
    let mode = match sh.mode.load(Acquire) {
        0 => "normal",
        1 => "degraded",
        _ => "fail_safe",
    };
    let status = crate::io::arm_status(sh);
    let _ = (|| -> core::fmt::Result {
        writeln!(
            w,
            "state: {}",
            state::NAMES.get(st).copied().unwrap_or("unknown")
        )?;
        writeln!(w, "mode: {mode}")?;
        writeln!(w, "miss_limit: {MISS_LIMIT}")?;
        writeln!(w, "timer_ticks: {}", sh.tick.load(Relaxed))?;
        writeln!(w, "ticks_not_posted: {}", sh.ticks_not_posted.load(Relaxed))?;
        writeln!(w, "status: {status:#06x}")?;
        writeln!(
            w,
            "power: {}",
            u8::from(status & crate::hap_core::vp::status::POWER_ON != 0)
        )?;
        writeln!(
            w,
            "motors_enabled: {}",
            u8::from(status & crate::hap_core::vp::status::MOTORS_ENABLED != 0)
        )?;
        let gate = sh.motor_line.gate();
        writeln!(
            w,
            "motors_inhibited: {}",
            u8::from(gate == crate::hap_core::io::Gate::FailSafe)
        )?;
        writeln!(w, "motor_gate: {}", gate.name())?;
        writeln!(w, "session: {session}")?;
        writeln!(w, "sessions_opened: {}", proto_counters.sessions_opened)?;
        writeln!(w, "vpr_frames: {}", proto_counters.vpr_frames)?;
        writeln!(w, "config_frames: {}", proto_counters.config_frames)?;
        writeln!(w, "replies: {}", proto_counters.replies)?;
        for (name, v) in Reject::PROTOCOL_NAMES
            .iter()
            .zip(proto_counters.protocol_rejects.iter())
        {
            writeln!(w, "rejected.{name}: {v}")?;
        }
        writeln!(
            w,
            "rtf_in.bad_length: {}",
            sh.rtf_in_counters.bad_length.load(Relaxed)
        )?;
        writeln!(w, "rtf_in.full: {}", sh.rtf_in_counters.full.load(Relaxed))?;
        writeln!(w, "rtf_in.queued: {rtf_in_len}")?;
        writeln!(w, "rtf_out.queued: {rtf_out_len}")?;
        writeln!(w, "rtf_out.capacity: {RTF_FRAMES}")?;
        writeln!(w, "answers_sent: {}", sh.answers_sent.load(Relaxed))?;
        writeln!(
            w,
            "answers_skipped_lock_busy: {}",
            sh.answers_skipped.load(Relaxed)
        )?;
        writeln!(w, "config_busy: {}", sh.config_busy.load(Relaxed))?;
        writeln!(
            w,
            "effort_loaded_cycle: {}",
            cycle_or_never(sh.effort_loaded_cycle.load(Relaxed))
        )?;
        writeln!(
            w,
            "power_on_cycle: {}",
            cycle_or_never(sh.power_on_cycle.load(Relaxed))
        )?;
        writeln!(
            w,
            "fault_overruns_pending: {}",
            sh.fault_overruns.load(Relaxed)
        )?;
        let e = sh.expiry_ns.load(Relaxed);
        writeln!(w, "last.timer_late_ns: {}", sh.tick_ns.load(Relaxed) - e)?;
        writeln!(
            w,
            "hrtimer_resolution_ns: {}",
            crate::clock::hrtimer_resolution_ns()
        )
    })();
    n + w.len()
}

/// The text a read-only device shows for one open: `render` writes at most
/// `max` bytes and returns how many.
fn snapshot(max: usize, render: impl FnOnce(&mut [u8]) -> usize) -> Result<KVVec<u8>> {
    let mut text = KVVec::with_capacity(max, GFP_KERNEL)?;
    text.resize(max, 0, GFP_KERNEL)?;
    let n = render(&mut text);
    text.truncate(n);
    Ok(text)
}

#[vtable]
impl MiscDevice for StatsDevice {
    type Ptr = KBox<Self>;

    fn open(_file: &File, _misc: &MiscDeviceRegistration<Self>) -> Result<KBox<Self>> {
        let sh = shared::get()?;
        let text = snapshot(STATS_TEXT_MAX, |out| render(&sh, out))?;
        Ok(KBox::new(StatsDevice { text }, GFP_KERNEL)?)
    }

    fn read_iter(mut kiocb: Kiocb<'_, Self::Ptr>, iov: &mut IovIterDest<'_>) -> Result<usize> {
        let me = kiocb.file();
        iov.simple_read_from_buffer(kiocb.ki_pos_mut(), &me.text)
    }
}

pub(crate) struct HistDevice {
    text: KVVec<u8>,
}

#[vtable]
impl MiscDevice for HistDevice {
    type Ptr = KBox<Self>;

    fn open(_file: &File, _misc: &MiscDeviceRegistration<Self>) -> Result<KBox<Self>> {
        let sh = shared::get()?;
        // Allocate first; under the lock only copy (CLOCK takes this lock
        // once per period: rendering ~100 KB there would hold it up).
        let mut buckets =
            KVVec::<u32>::with_capacity(HIST_SERIES.len() * HIST_BUCKETS, GFP_KERNEL)?;
        let mut overflow = [0u64; HIST_SERIES.len()];
        {
            let st = sh.stats.lock();
            for ((_, h), o) in st.histograms().iter().zip(overflow.iter_mut()) {
                buckets.extend_from_slice(h.buckets(), GFP_KERNEL)?;
                *o = h.overflow();
            }
        }
        let view = |i: usize| HistogramView {
            name: HIST_SERIES.get(i).copied().unwrap_or(""),
            buckets: buckets
                .get(i * HIST_BUCKETS..(i + 1) * HIST_BUCKETS)
                .unwrap_or(&[]),
            overflow: overflow.get(i).copied().unwrap_or(0),
        };
        let series = [view(0), view(1), view(2)];
        let text = snapshot(HIST_RENDER_MAX, |out| render_histograms(&series, out).len)?;
        Ok(KBox::new(HistDevice { text }, GFP_KERNEL)?)
    }

    fn read_iter(mut kiocb: Kiocb<'_, Self::Ptr>, iov: &mut IovIterDest<'_>) -> Result<usize> {
        let me = kiocb.file();
        iov.simple_read_from_buffer(kiocb.ki_pos_mut(), &me.text)
    }
}
