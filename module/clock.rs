// SPDX-License-Identifier: GPL-2.0

//! CLOCK (the spec's hap_clock): the synchronous cycle supervisor.
//!
//! - The cycle timer (absolute, hard-IRQ hrtimer on the period grid) is the
//!   top of each cycle: it posts `cycle_start` to SERVO if SERVO waits at the
//!   barrier (rendezvous: a SERVO still busy gets no second cycle queued; the
//!   tick is counted as not posted).
//! - The check timer fires at 3/4 of each period and wakes the CLOCK thread
//!   (SCHED_FIFO 99, above SERVO), which asks hap-core's `Supervisor` whether
//!   SERVO finished, updates the statistics, sets SERVO's mode (main or
//!   degraded), and on a stop request or exactly 5 consecutive misses runs
//!   the fail-safe in `FAIL_SAFE_SEQUENCE` order, then exits.
//! - `/dev/hap_stop` (the spec's stop RT-FIFO handler) sets `servo_stop`.

use crate::{
    completion::Wait,
    hap_core::clock::{
        FailSafeAction, FailSafeCause, Mode, Supervisor, Verdict, FAIL_SAFE_SEQUENCE,
    },
    shared::{state, DeviceFile, Shared},
};
use kernel::{
    fs::{File, Kiocb},
    impl_has_hr_timer,
    iov::IovIterSource,
    miscdevice::{MiscDevice, MiscDeviceRegistration},
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
        Delta, Instant, Monotonic,
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
        let period = Delta::from_nanos(shared.period_ns());
        let first = Instant::<Monotonic>::now() + period;
        let check_offset = Delta::from_nanos(shared.period_ns() / 4 * 3);
        let cycle = Arc::pin_init(
            pin_init!(CycleTimer { timer <- HrTimer::new(), shared: shared.clone() }),
            GFP_KERNEL,
        )?;
        let check = Arc::pin_init(
            pin_init!(CheckTimer { timer <- HrTimer::new(), shared: shared.clone() }),
            GFP_KERNEL,
        )?;
        Ok(Timers {
            _cycle: cycle.start(first),
            _check: check.start(first + check_offset),
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
        let expiry = sh.ns_of(this.timer.expires());
        sh.expiry_ns.store(expiry, Release);
        let now = sh.now_ns();
        sh.tick_ns.store(now, Relaxed);
        sh.tick.fetch_add(1, Release);
        // Rendezvous with SERVO at the barrier.
        if sh.servo_waiting.load(Acquire) {
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

/// The hrtimer resolution in ns: 1 once the kernel runs high-resolution
/// timers, the tick length (1 ms at HZ=1000) before the switch (early boot,
/// or no high-resolution clock event device).
pub(crate) fn hrtimer_resolution_ns() -> u32 {
    // SAFETY: `hrtimer_resolution` is an exported, naturally aligned `unsigned
    // int` that the kernel only writes when it switches timer modes; a racy
    // read gives the old or the new value, both meaningful.
    unsafe { core::ptr::read_volatile(&raw const kernel::bindings::hrtimer_resolution) }
}

pub(crate) fn mode_to_u32(m: Mode) -> u32 {
    match m {
        Mode::Normal => 0,
        Mode::Degraded => 1,
        Mode::FailSafe => 2,
    }
}

/// CLOCK's thread body.
pub(crate) fn clock_main(sh: &Shared) {
    let mut sup = Supervisor::new();
    let mut last_tick_seen = 0u64;
    while !crate::kthread::should_stop() && !sh.is_stopping() {
        if sh.check_due.wait_timeout(100) == Wait::TimedOut {
            continue;
        }
        if sh.is_stopping() {
            break;
        }
        if sh.stop_request.load(Acquire) && !sup.stop_requested() {
            sup.request_stop();
        }
        // SERVO finished this cycle iff it is not working and its last
        // finished cycle is the current tick.
        let tick = sh.tick.load(Acquire);
        let working = sh.servo_working.load(Acquire) || sh.servo_done_tick.load(Acquire) != tick;
        let verdict = sup.check(working);
        sh.mode.store(mode_to_u32(sup.mode()), Release);
        {
            let mut st = sh.stats.lock();
            if tick != last_tick_seen {
                st.record_cycle(
                    sh.expiry_ns.load(Acquire),
                    sh.tick_ns.load(Relaxed),
                    sh.servo_start_ns.load(Acquire),
                    sh.servo_end_ns.load(Acquire),
                    !working,
                );
                last_tick_seen = tick;
            }
            st.record_verdict(&verdict);
        }
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
    sh.state.store(state::FAIL_SAFE, Release);
    pr_warn!(
        "fail-safe ({}): start (tick {}, servo done tick {}, working {}, not posted {})\n",
        cause.name(),
        sh.tick.load(Relaxed),
        sh.servo_done_tick.load(Relaxed),
        sh.servo_working.load(Relaxed),
        sh.ticks_not_posted.load(Relaxed)
    );
    for (i, action) in FAIL_SAFE_SEQUENCE.iter().enumerate() {
        match action {
            // The first two steps act on hap_io's motor line, outside every
            // lock: the motors apply 0 from here on, whether SERVO is
            // waiting, inside its cycle holding `mtx_data`, or hung.
            FailSafeAction::InhibitMotorCommands => sh.motor_line.fail_safe_inhibit(),
            FailSafeAction::PowerOffArm => sh.motor_line.power_off(),
            FailSafeAction::CloseProtocol => {
                sh.proto.lock().close();
                sh.rtf_out.close(true);
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
                while sh.servo_working.load(Acquire) && waited < RELEASE_WAIT_PERIODS {
                    kernel::time::delay::fsleep(Delta::from_nanos(sh.period_ns()));
                    waited += 1;
                }
                if sh.servo_working.load(Acquire) {
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
            i + 1,
            FAIL_SAFE_SEQUENCE.len(),
            action.name(),
            if sh.servo_working.load(Acquire) {
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
pub(crate) struct StopDevice {
    f: DeviceFile,
}

#[vtable]
impl MiscDevice for StopDevice {
    type Ptr = KBox<Self>;

    fn open(file: &File, _misc: &MiscDeviceRegistration<Self>) -> Result<KBox<Self>> {
        Ok(KBox::new(
            StopDevice {
                f: DeviceFile::open(file)?,
            },
            GFP_KERNEL,
        )?)
    }

    fn write_iter(kiocb: Kiocb<'_, Self::Ptr>, iov: &mut IovIterSource<'_>) -> Result<usize> {
        let n = iov.len();
        iov.advance(n);
        kiocb.file().f.shared.stop_request.store(true, Release);
        Ok(n)
    }
}
