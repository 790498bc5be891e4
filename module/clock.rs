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
//!   `HapStats` and publishes them through a seqcount (`Shared::stats`:
//!   readers copy, CLOCK never waits for them), sets SERVO's mode (normal,
//!   degraded or fail-safe), and on a stop request or exactly 5 consecutive
//!   misses runs the fail-safe in `FAIL_SAFE_SEQUENCE` order, then exits.
//!   CLOCK takes no lock in its cycle.
//! - `/dev/hap_stop` (the spec's stop RT-FIFO handler) sets `servo_stop`.

use crate::{
    completion::Wait,
    device::{HapDevice, OpenFile},
    hap_core::clock::{FailSafeAction, FailSafeCause, Supervisor, Verdict, FAIL_SAFE_SEQUENCE},
    hap_core::stats::{HapStats, WordSet},
    shared::{ControllerState, Shared},
    time::Ktime,
};
use kernel::{
    impl_has_hr_timer,
    iov::IovIterSource,
    prelude::*,
    sync::{
        atomic::{Acquire, Relaxed, Release},
        Arc, ArcBorrow,
    },
    time::{
        hrtimer::{
            AbsoluteHardMode, ArcHrTimerHandle, HrTimer, HrTimerCallback, HrTimerCallbackContext,
            HrTimerPointer, HrTimerRestart,
        },
        Delta, Monotonic,
    },
};

/// The cycle timer: posts the cycle start.
#[pin_data]
pub(crate) struct CycleTimer {
    #[pin]
    timer: HrTimer<Self>,
    shared: Arc<Shared>,
}

/// The check timer: 3/4 of a period after each cycle start.
#[pin_data]
pub(crate) struct CheckTimer {
    #[pin]
    timer: HrTimer<Self>,
    shared: Arc<Shared>,
}

/// Both timers, started on the same grid; dropping them cancels them.
pub(crate) struct Timers {
    _cycle: ArcHrTimerHandle<CycleTimer>,
    _check: ArcHrTimerHandle<CheckTimer>,
}

impl Timers {
    pub(crate) fn start(shared: &Arc<Shared>) -> Result<Self> {
        let period = shared.period_ns();
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
        if sh.is_stopping() {
            return HrTimerRestart::NoRestart;
        }
        let expiry = sh.ns_of(Ktime::from_instant(this.timer.expires()));
        sh.expiry_ns.store(expiry, Release);
        let now = sh.now_ns();
        sh.tick_ns.store(now, Relaxed);
        sh.cycle.top();
        // Rendezvous with SERVO at the barrier.
        if sh.cycle.servo_waiting() {
            sh.cycle_start.complete();
        } else {
            sh.ticks_not_posted.add(1, Relaxed);
        }
        ctx.forward_now(Delta::from_nanos(sh.period_ns()));
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
        if sh.is_stopping() {
            return HrTimerRestart::NoRestart;
        }
        sh.check_due.complete();
        ctx.forward_now(Delta::from_nanos(sh.period_ns()));
        HrTimerRestart::Restart
    }
}

impl_has_hr_timer! {
    impl HasHrTimer<Self> for CheckTimer {
        mode: AbsoluteHardMode<Monotonic>, field: self.timer
    }
}

pub(crate) use crate::kconfig::hrtimer_resolution_ns;

/// Publish CLOCK's statistics (`set`: what changed since the last time).
fn publish(sh: &Shared, st: &mut HapStats, set: WordSet) {
    let w = sh.stats.write();
    st.visit_words(set, |i, v| w.set(i, *v));
}

/// CLOCK's thread body.
pub(crate) fn clock_main(kt: &crate::kthread::CurrentKThread, sh: &Shared) {
    let mut sup = Supervisor::new();
    let mut last_tick_seen = 0u64;
    // CLOCK's own statistics, taken once: from here on no lock.
    let Some(mut stats) = sh.clock_stats.lock().take() else {
        pr_err!("CLOCK: statistics already taken\n");
        return;
    };
    publish(sh, &mut stats, WordSet::All);
    while !kt.should_stop() && !sh.is_stopping() {
        if sh.check_due.wait_timeout(100) == Wait::TimedOut {
            continue;
        }
        if sh.is_stopping() {
            break;
        }
        if sh.stop_request.load(Acquire) && !sup.stop_requested() {
            sup.request_stop();
        }
        let c = sh.cycle.check();
        let verdict = sup.check(!c.finished);
        sh.cycle.set_mode(sup.mode());
        if c.tick != last_tick_seen {
            stats.record_cycle(
                sh.expiry_ns.load(Acquire),
                sh.tick_ns.load(Relaxed),
                sh.servo_start_ns.load(Acquire),
                sh.servo_end_ns.load(Acquire),
                c.finished,
            );
            last_tick_seen = c.tick;
        }
        stats.record_verdict(&verdict);
        publish(sh, &mut stats, WordSet::Recent);
        if let Verdict::FailSafe(cause) = verdict {
            fail_safe(sh, cause);
            return;
        }
    }
}

/// Periods the fail-safe's last step waits for a SERVO still in its cycle.
const RELEASE_WAIT_PERIODS: u32 = 4;

/// The fail-safe (spec §3.4, §4.1), in hap-core's order. Runs in CLOCK.
pub(crate) fn fail_safe(sh: &Shared, cause: FailSafeCause) {
    sh.set_state(ControllerState::FailSafe);
    let c = sh.cycle.check();
    pr_warn!(
        "fail-safe ({}): start (tick {}, servo done tick {}, working {}, not posted {})\n",
        cause.name(),
        c.tick,
        c.done_tick,
        c.working,
        sh.ticks_not_posted.load(Relaxed)
    );
    for (i, action) in FAIL_SAFE_SEQUENCE.iter().enumerate() {
        crate::simulator::log_fail_safe_step(
            sh,
            u8::try_from(i.saturating_add(1)).unwrap_or(u8::MAX),
        );
        match action {
            // The first two steps act on hap_io's motor line, outside every
            // lock: the motors apply 0 from here on, whether SERVO is
            // waiting, inside its cycle holding `mtx_data`, or hung.
            FailSafeAction::InhibitMotorCommands => sh.motor_line.fail_safe_inhibit(),
            FailSafeAction::PowerOffArm => sh.motor_line.power_off(),
            FailSafeAction::CloseProtocol => {
                sh.close_protocol();
                sh.rtf_out.close(true);
                sh.rtf_replies.close(true);
                sh.rtf_in.close(true);
            }
            FailSafeAction::StopTasks => {
                sh.stopping.store(true, Release);
                sh.cycle_start.complete_all();
                sh.rtf_in_ready.complete_all();
            }
            FailSafeAction::ReleaseResources => {
                // A SERVO still inside its cycle (an overrun) gets a few
                // periods to finish it, so that the position log holds the
                // record of that last cycle, run on the cut line. A hung
                // SERVO does not finish: the log is closed without it.
                let mut waited = 0;
                while sh.cycle.servo_working() && waited < RELEASE_WAIT_PERIODS {
                    kernel::time::delay::fsleep(Delta::from_nanos(sh.period_ns()));
                    waited = waited.saturating_add(1);
                }
                if sh.cycle.servo_working() {
                    pr_warn!(
                        "fail-safe ({}): SERVO still inside its cycle after {} periods (hung)\n",
                        cause.name(),
                        RELEASE_WAIT_PERIODS
                    );
                }
                // The position log stays readable until drained.
                sh.simlog.close(false);
            }
        }
        let applied = sh.motor_line.applied();
        pr_warn!(
            "fail-safe ({}): step {}/{}: {} (servo {}, gate {}, supply {}, applied torque {})\n",
            cause.name(),
            i.saturating_add(1),
            FAIL_SAFE_SEQUENCE.len(),
            action.name(),
            if sh.cycle.servo_working() {
                "in cycle"
            } else {
                "waiting"
            },
            sh.motor_line.gate().name(),
            u8::from(sh.motor_line.supply_on()),
            if applied.iter().all(|t| t.0 == 0) {
                "0"
            } else {
                "non-zero"
            }
        );
    }
    pr_warn!(
        "fail-safe ({}): done, tasks stopped; rmmod to unload\n",
        cause.name()
    );
}

/// `/dev/hap_stop`: any write requests the application's termination.
pub(crate) struct Stop;

impl HapDevice for Stop {
    const NAME: &'static CStr = c"hap_stop";

    fn open(_sh: &Arc<Shared>) -> Result<Self> {
        Ok(Stop)
    }

    fn write(f: &OpenFile<Self>, iov: &mut IovIterSource<'_>) -> Result<usize> {
        let n = iov.len();
        iov.advance(n);
        f.shared.stop_request.store(true, Release);
        Ok(n)
    }
}
