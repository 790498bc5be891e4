// SPDX-License-Identifier: GPL-2.0

//! CLOCK (the spec's hap_clock): the synchronous cycle supervisor.
//!
//! - The cycle timer (absolute, hard-IRQ hrtimer on the period grid) is the
//!   top of each cycle: it advances the cycle handshake's tick and posts
//!   `cycle_start` to SERVO if SERVO waits at the barrier (rendezvous: a
//!   SERVO still busy gets no second cycle queued; the tick is counted as
//!   not posted).
//! - The check timer fires at 3/4 of each period and wakes the CLOCK thread
//!   (SCHED_FIFO 90, above SERVO), which reads the cycle handshake
//!   (`hap_core::handshake`: did SERVO finish this tick?), asks hap-core's
//!   `Supervisor` for the verdict, records the statistics in its own
//!   `HapStats` and publishes them through a seqcount (`StatsPublication`:
//!   readers copy, CLOCK never waits for them), sets SERVO's mode (normal,
//!   degraded or fail-safe), and on a stop request (`/dev/hap_stop`, see
//!   `lifecycle.rs`) or exactly 5 consecutive misses runs the fail-safe in
//!   `FAIL_SAFE_SEQUENCE` order, then exits. CLOCK takes no lock in its
//!   cycle.

use crate::{
    arm::Arm,
    completion::{Timeout, Wait},
    controller::Controller,
    hap_core::{
        clock::{FailSafeAction, FailSafeCause, Supervisor, Verdict, FAIL_SAFE_SEQUENCE},
        io::Gate,
        mode::Mode,
        position_log::{LogRecord, LogTiming},
        servo::log_flags,
        stats::WordSet,
        vp::alarm,
    },
    kthread::CurrentKThread,
    lifecycle::ControllerState,
    time::Ktime,
};
use kernel::{
    impl_has_hr_timer,
    prelude::*,
    sync::{Arc, ArcBorrow},
    time::{
        hrtimer::{
            AbsoluteHardMode, ArcHrTimerHandle, HrTimer, HrTimerCallback, HrTimerCallbackContext,
            HrTimerPointer, HrTimerRestart,
        },
        Delta, Monotonic,
    },
};

/// The CLOCK thread wakes at least this often to check for a stop.
const CHECK_WAIT: Timeout = Timeout::from_millis(100);

/// The cycle timer: posts the cycle start.
#[pin_data]
pub(crate) struct CycleTimer {
    #[pin]
    timer: HrTimer<Self>,
    shared: Arc<Controller>,
}

/// The check timer: 3/4 of a period after each cycle start.
#[pin_data]
pub(crate) struct CheckTimer {
    #[pin]
    timer: HrTimer<Self>,
    shared: Arc<Controller>,
}

/// Both timers, started on the same grid; dropping them cancels them.
pub(crate) struct Timers {
    _cycle: ArcHrTimerHandle<CycleTimer>,
    _check: ArcHrTimerHandle<CheckTimer>,
}

impl Timers {
    pub(crate) fn start(shared: &Arc<Controller>) -> Result<Self> {
        let period = shared.time.period_ns();
        let first = Ktime::now().saturating_add_ns(period);
        let check_first = first.saturating_add_ns(period / 4 * 3);
        let cycle = Arc::pin_init(
            pin_init!(CycleTimer { timer <- HrTimer::new(), shared: shared.clone() }),
            GFP_KERNEL,
        )?;
        let check = Arc::pin_init(
            pin_init!(CheckTimer { timer <- HrTimer::new(), shared: shared.clone() }),
            GFP_KERNEL,
        )?;
        Ok(Timers {
            _cycle: cycle.start(first.to_instant()),
            _check: check.start(check_first.to_instant()),
        })
    }
}

impl HrTimerCallback for CycleTimer {
    type Pointer<'a> = Arc<Self>;

    fn run(this: ArcBorrow<'_, Self>, mut ctx: HrTimerCallbackContext<'_, Self>) -> HrTimerRestart {
        let sh = &this.shared;
        if sh.life.is_stopping() {
            return HrTimerRestart::NoRestart;
        }
        let clock = &sh.clock;
        let expiry = sh.time.ns_of(Ktime::from_instant(this.timer.expires()));
        clock.stamp_tick(expiry, sh.time.now_ns());
        clock.handshake.top();
        // Rendezvous with SERVO at the barrier.
        if clock.handshake.servo_waiting() {
            clock.cycle_start.complete();
        } else {
            clock.count_not_posted();
        }
        ctx.forward_now(Delta::from_nanos(sh.time.period_ns()));
        HrTimerRestart::Restart
    }
}

impl_has_hr_timer! {
    impl HasHrTimer<Self> for CycleTimer {
        mode: AbsoluteHardMode<Monotonic>, field: self.timer
    }
}

impl HrTimerCallback for CheckTimer {
    type Pointer<'a> = Arc<Self>;

    fn run(this: ArcBorrow<'_, Self>, mut ctx: HrTimerCallbackContext<'_, Self>) -> HrTimerRestart {
        let sh = &this.shared;
        if sh.life.is_stopping() {
            return HrTimerRestart::NoRestart;
        }
        sh.clock.check_due.complete();
        ctx.forward_now(Delta::from_nanos(sh.time.period_ns()));
        HrTimerRestart::Restart
    }
}

impl_has_hr_timer! {
    impl HasHrTimer<Self> for CheckTimer {
        mode: AbsoluteHardMode<Monotonic>, field: self.timer
    }
}

/// CLOCK's thread body.
pub(crate) fn clock_main(kt: &CurrentKThread, sh: &Controller) {
    let mut sup = Supervisor::new();
    let mut last_tick_seen = 0u64;
    let clock = &sh.clock;
    // CLOCK's own statistics and their publication, taken once: from here
    // on no lock.
    let Some(mut stats) = sh.stats.take_for_clock() else {
        pr_err!("CLOCK: statistics already taken\n");
        return;
    };
    stats.publish(WordSet::All);
    while !kt.should_stop() && !sh.life.is_stopping() {
        if clock.check_due.wait_timeout(CHECK_WAIT) == Wait::TimedOut {
            continue;
        }
        if sh.life.is_stopping() {
            break;
        }
        if sh.life.stop_requested() && !sup.stop_requested() {
            sup.request_stop();
        }
        let c = clock.handshake.check();
        let verdict = sup.check(!c.finished);
        clock.handshake.set_mode(sup.mode());
        if c.tick != last_tick_seen {
            let t = clock.stamps();
            stats.stats.record_cycle(
                t.expiry_ns,
                t.tick_ns,
                t.servo_start_ns,
                t.servo_end_ns,
                c.finished,
            );
            last_tick_seen = c.tick;
        }
        stats.stats.record_verdict(&verdict);
        stats.publish(WordSet::Recent);
        if let Verdict::FailSafe(cause) = verdict {
            fail_safe(sh, cause);
            return;
        }
    }
}

/// Periods the fail-safe's last step waits for a SERVO still in its cycle.
const RELEASE_WAIT_PERIODS: u32 = 4;

/// The fail-safe (spec §3.4, §4.1), in hap-core's order. Runs in CLOCK.
pub(crate) fn fail_safe(sh: &Controller, cause: FailSafeCause) {
    let hs = &sh.clock.handshake;
    sh.life.set_state(ControllerState::FailSafe);
    let c = hs.check();
    pr_warn!(
        "fail-safe ({}): start (tick {}, servo done tick {}, working {}, not posted {})\n",
        cause.name(),
        c.tick,
        c.done_tick,
        c.working,
        sh.clock.ticks_not_posted()
    );
    for (i, action) in FAIL_SAFE_SEQUENCE.iter().enumerate() {
        for arm in sh.arms() {
            log_fail_safe_step(
                sh,
                arm,
                u8::try_from(i.saturating_add(1)).unwrap_or(u8::MAX),
            );
        }
        match action {
            FailSafeAction::ReleaseResources => {
                // A SERVO still inside its cycle (an overrun) gets a few
                // periods to finish it, so that the position log holds the
                // record of that last cycle, run on the cut line. A hung
                // SERVO does not finish: the log is closed without it.
                let mut waited = 0;
                while hs.servo_working() && waited < RELEASE_WAIT_PERIODS {
                    kernel::time::delay::fsleep(Delta::from_nanos(sh.time.period_ns()));
                    waited = waited.saturating_add(1);
                }
                if hs.servo_working() {
                    pr_warn!(
                        "fail-safe ({}): SERVO still inside its cycle after {} periods (hung)\n",
                        cause.name(),
                        RELEASE_WAIT_PERIODS
                    );
                }
                // The position logs stay readable until drained; the rest
                // is released by rmmod.
                for arm in sh.arms() {
                    arm.log.close(false);
                }
            }
            other => sh.act(*other),
        }
        for arm in sh.arms() {
            let line = &arm.io.motor_line;
            let applied = line.applied();
            pr_warn!(
                "fail-safe ({}): step {}/{}: {} ({}servo {}, gate {}, supply {}, applied torque {})\n",
                cause.name(),
                i.saturating_add(1),
                FAIL_SAFE_SEQUENCE.len(),
                action.name(),
                arm_label(sh, arm),
                if hs.servo_working() {
                    "in cycle"
                } else {
                    "waiting"
                },
                line.gate().name(),
                u8::from(line.supply_on()),
                if applied.iter().all(|t| t.0 == 0) {
                    "0"
                } else {
                    "non-zero"
                }
            );
        }
    }
    pr_warn!(
        "fail-safe ({}): done, tasks stopped; rmmod to unload\n",
        cause.name()
    );
}

/// `arm N, ` in a dmesg line of a controller of several arms (one arm's
/// lines read as they always have).
fn arm_label(sh: &Controller, arm: &Arm) -> &'static str {
    match (sh.arm_count(), arm.index) {
        (1, _) => "",
        (_, 0) => "arm 0, ",
        _ => "arm 1, ",
    }
}

/// Log fail-safe step `step` (1-based, `FAIL_SAFE_SEQUENCE` order) as it
/// starts: the servo's last record with mode `FailSafe`, the arm status
/// now, and the tick. If SERVO holds `mtx_data` (a hung or overrunning
/// cycle), its state is unknown: an empty record flagged `POSE_UNKNOWN`,
/// which the analysis does not read as a pose.
fn log_fail_safe_step(sh: &Controller, arm: &Arm, step: u8) {
    let mut rec = match arm.servo.data.try_lock() {
        Some(d) => *d.cycle.servo.log_record(),
        None => LogRecord {
            flags: log_flags::POSE_UNKNOWN,
            ..LogRecord::ZERO
        },
    };
    rec.mode = Mode::FailSafe;
    rec.fail_safe_step = step;
    // What the motors apply now, read from the line (not SERVO's last record).
    let line = &arm.io.motor_line;
    rec.motor_torque = line.applied();
    if line.gate() == Gate::FailSafe {
        rec.flags |= log_flags::LINE_CUT;
    }
    rec.status = arm.io.arm_status();
    rec.alarms |= alarm::FAIL_SAFE;
    rec.timing = LogTiming {
        tick: sh.clock.handshake.tick(),
        start_ns: u64::try_from(sh.time.now_ns()).unwrap_or(0),
        wakeup_ns: 0,
        exec_ns: 0,
        session: 0,
    };
    // SERVO may be mid-push (CLOCK preempted it): the record is refused and
    // counted rather than waited for, since the next step cuts the motors.
    arm.log.push(&rec);
}
