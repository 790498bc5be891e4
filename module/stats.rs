// SPDX-License-Identifier: GPL-2.0

//! `/dev/hap_stats`: a text snapshot taken at open (`cat` it), rendered by
//! hap-core (`key: value` lines, cyclictest-style summary first), followed by
//! the kernel's own lines (state, mode, device and protocol counters, the
//! module's effective parameters). See Documentation/timing.md.
//!
//! `/dev/hap_hist`: the 1 µs histograms of the three timing series
//! (wake-up, execution, period jitter), rendered by hap-core
//! (`render_histograms`).
//!
//! Both copy CLOCK's published statistics (`StatsPublication`, a seqcount
//! over `u64` words) into their own allocation and render from the copy:
//! no lock is taken, CLOCK never waits for a reader (a copy that overlaps
//! CLOCK's write is retried by the reader). PROTO_IN's counters come from
//! its own publication, never from `mtx_proto`. The two devices are the
//! controller's monitor: they are registered with the whole `Controller`.

use crate::{
    arm::Arm,
    controller::Controller,
    device::{HapDevice, OpenFile},
    hap_core::{
        clock::MISS_LIMIT,
        stats::{
            render_histograms, render_summary, HapStats, HistogramView, SliceWriter,
            HIST_RENDER_MAX, STATS_WORDS,
        },
    },
    rtf::RTF_FRAMES,
    servo_data::NEVER,
    stats_publication::new_stats,
};
use core::fmt::Write;
use kernel::{
    iov::IovIterDest,
    prelude::*,
    sync::{atomic::Relaxed, Arc},
};

const STATS_TEXT_MAX: usize = 8192;

/// What one arm's statistics device shows: CLOCK's statistics and arm
/// `arm`'s counters.
pub(crate) struct StatsView {
    pub(crate) ctrl: Arc<Controller>,
    pub(crate) arm: Arc<Arm>,
}

/// `/dev/hap_stats` (arm 0), `/dev/hap1_stats` (arm 1): the text rendered
/// at open.
pub(crate) struct StatsDevice {
    text: KVVec<u8>,
}

fn cycle_or_never(v: u64) -> i64 {
    if v == NEVER {
        -1
    } else {
        i64::try_from(v).unwrap_or(i64::MAX)
    }
}

/// A copy of CLOCK's published statistics, in its own allocation.
fn copy_stats(sh: &Controller) -> Result<KBox<HapStats>> {
    let mut words = KVVec::<u64>::zeroed(STATS_WORDS, GFP_KERNEL)?;
    let mut st = new_stats(sh.time.period_us)?;
    sh.stats.read(&mut words, &mut st)?;
    Ok(st)
}

fn render(sh: &Controller, arm: &Arm, st: &mut HapStats, out: &mut [u8]) -> usize {
    let publication = arm.proto.publication();
    let proto_counters = &publication.counters;
    let (rtf_out_len, _, _) = arm.rtf.rtf_out.counts();
    let (replies_len, _, _) = arm.rtf.rtf_replies.counts();
    let (rtf_in_len, _, _) = arm.rtf.rtf_in.counts();
    let (simlog_len, simlog_pushed, simlog_dropped) = arm.log.counts();
    let summary = {
        let c = &mut st.counters;
        c.frames_in = proto_counters.accepted;
        c.frames_out = arm.rtf.answers_sent.load(Relaxed);
        c.frames_rejected = proto_counters.decode_rejects;
        // Frames a full rtf_out refused: counted by SERVO and PROTO_IN.
        c.answers_dropped = arm.rtf.answers_dropped.load(Relaxed);
        c.vpr_extrapolated = arm.servo.vpr_extrapolated.load(Relaxed);
        st.summary()
    };
    let n = render_summary(&summary, out).len;
    let Some(rest) = out.get_mut(n..) else {
        return n;
    };
    let mut w = SliceWriter::new(rest);
    let state = sh.life.state();
    let mode = sh.clock.handshake.mode().stats_word();
    let status = arm.io.arm_status();
    let _ = (|| -> core::fmt::Result {
        writeln!(w, "state: {}", state.name())?;
        writeln!(w, "mode: {mode}")?;
        writeln!(w, "miss_limit: {MISS_LIMIT}")?;
        writeln!(w, "timer_ticks: {}", sh.clock.handshake.tick())?;
        writeln!(w, "ticks_not_posted: {}", sh.clock.ticks_not_posted())?;
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
        let gate = arm.io.motor_line.gate();
        writeln!(
            w,
            "motors_inhibited: {}",
            u8::from(gate == crate::hap_core::io::Gate::FailSafe)
        )?;
        writeln!(w, "motor_gate: {}", gate.name())?;
        publication.render(&mut w)?;
        writeln!(
            w,
            "rtf_in.bad_length: {}",
            arm.rtf.rtf_in_counters.bad_length.load(Relaxed)
        )?;
        writeln!(
            w,
            "rtf_in.full: {}",
            arm.rtf.rtf_in_counters.full.load(Relaxed)
        )?;
        writeln!(w, "rtf_in.queued: {rtf_in_len}")?;
        writeln!(w, "rtf_out.queued: {rtf_out_len}")?;
        writeln!(w, "rtf_out.capacity: {RTF_FRAMES}")?;
        writeln!(w, "rtf_out.replies_queued: {replies_len}")?;
        writeln!(w, "simlog.queued: {simlog_len}")?;
        writeln!(w, "simlog.pushed: {simlog_pushed}")?;
        writeln!(w, "simlog.dropped: {simlog_dropped}")?;
        writeln!(w, "stats_read_busy: {}", sh.stats.read_busy())?;
        writeln!(w, "answers_sent: {}", arm.rtf.answers_sent.load(Relaxed))?;
        writeln!(
            w,
            "answers_skipped_latch_busy: {}",
            arm.rtf.answers_skipped_latch_busy.load(Relaxed)
        )?;
        writeln!(w, "config_busy: {}", arm.servo.config_busy.load(Relaxed))?;
        writeln!(
            w,
            "effort_loaded_cycle: {}",
            cycle_or_never(arm.effort.loaded_cycle())
        )?;
        writeln!(
            w,
            "power_on_cycle: {}",
            cycle_or_never(arm.servo.power_on_cycle())
        )?;
        writeln!(
            w,
            "fault_overruns_pending: {}",
            sh.faults.overruns_pending()
        )?;
        writeln!(w, "last.timer_late_ns: {}", sh.clock.timer_late_ns())?;
        writeln!(
            w,
            "hrtimer_resolution_ns: {}",
            crate::kconfig::hrtimer_resolution_ns()
        )?;
        writeln!(w, "arms: {}", sh.arm_count())?;
        writeln!(w, "arm: {}", arm.index)
    })();
    n.saturating_add(w.len())
}

/// The text a read-only device shows for one open: `render` writes at most
/// `max` bytes and returns how many.
fn snapshot(max: usize, render: impl FnOnce(&mut [u8]) -> usize) -> Result<KVVec<u8>> {
    let mut text = KVVec::<u8>::zeroed(max, GFP_KERNEL)?;
    let n = render(&mut text);
    text.truncate(n);
    Ok(text)
}

impl HapDevice for StatsDevice {
    const NAMES: &'static [&'static CStr] = &[c"hap_stats", c"hap1_stats"];

    type Part = StatsView;

    fn open(view: &Arc<StatsView>) -> Result<Self> {
        let mut st = copy_stats(&view.ctrl)?;
        let text = snapshot(STATS_TEXT_MAX, |out| {
            render(&view.ctrl, &view.arm, &mut st, out)
        })?;
        Ok(StatsDevice { text })
    }

    fn read(f: &OpenFile<Self>, pos: &mut i64, iov: &mut IovIterDest<'_>) -> Result<usize> {
        crate::uaccess::read_at(iov, pos, &f.dev.text)
    }
}

/// `/dev/hap_hist`: the text rendered at open.
pub(crate) struct HistDevice {
    text: KVVec<u8>,
}

impl HapDevice for HistDevice {
    const NAMES: &'static [&'static CStr] = &[c"hap_hist"];

    type Part = Controller;

    fn open(sh: &Arc<Controller>) -> Result<Self> {
        let st = copy_stats(sh)?;
        let series = st.histograms().map(|(name, h)| HistogramView {
            name,
            buckets: h.buckets(),
            overflow: h.overflow(),
        });
        let text = snapshot(HIST_RENDER_MAX, |out| render_histograms(&series, out).len)?;
        Ok(HistDevice { text })
    }

    fn read(f: &OpenFile<Self>, pos: &mut i64, iov: &mut IovIterDest<'_>) -> Result<usize> {
        crate::uaccess::read_at(iov, pos, &f.dev.text)
    }
}
