// SPDX-License-Identifier: GPL-2.0

//! The running controller: its components, created once at insmod. Each
//! component is a type of its own that holds its fields and states who
//! writes and reads them: the shared ones here ([`CycleClock`],
//! [`StatsPublication`], [`FaultInjection`], [`Lifecycle`]) and each arm's
//! ([`Arm`]: SERVO state, protocol state, RT-FIFO pair, position log,
//! effort channel, `ArmIo` with the motor line). This type only aggregates
//! them: the tasks (CLOCK, SERVO, PROTO_IN) borrow it whole; each device is
//! registered with the one component it serves (an `Arc`), and
//! /dev/hap_stats, the monitor, with the whole.
//!
//! The fail-safe's actions are written once here ([`Controller::act`]):
//! CLOCK's fail-safe runs them one by one in hap-core's
//! `FAIL_SAFE_SEQUENCE` order, and rmmod runs the same list
//! ([`Controller::shut_down`]).

use crate::{
    arm::{Arm, MAX_ARMS},
    cycle_clock::CycleClock,
    fault::FaultInjection,
    hap_core::clock::{FailSafeAction, FAIL_SAFE_SEQUENCE},
    lifecycle::Lifecycle,
    stats_publication::StatsPublication,
    time::Timebase,
};
use kernel::{prelude::*, sync::Arc};

#[pin_data]
pub(crate) struct Controller {
    pub(crate) time: Timebase,
    pub(crate) life: Arc<Lifecycle>,
    #[pin]
    pub(crate) clock: CycleClock,
    #[pin]
    pub(crate) stats: StatsPublication,
    pub(crate) faults: Arc<FaultInjection>,
    /// The arms, 1 or 2 (arm 0 first, then arm 1 if served).
    arms: [Option<Arc<Arm>>; MAX_ARMS],
}

impl Controller {
    pub(crate) fn new(period_us: u32, arms: usize) -> Result<impl PinInit<Self, Error>> {
        if arms == 0 || arms > MAX_ARMS {
            return Err(EINVAL);
        }
        let stats = StatsPublication::new(period_us)?;
        let life = Arc::new(Lifecycle::new(), GFP_KERNEL)?;
        let faults = Arc::new(FaultInjection::new(), GFP_KERNEL)?;
        let mut all: [Option<Arc<Arm>>; MAX_ARMS] = [const { None }; MAX_ARMS];
        for (index, slot) in all.iter_mut().enumerate().take(arms) {
            *slot = Some(Arc::pin_init(Arm::new(index, period_us)?, GFP_KERNEL)?);
        }
        Ok(try_pin_init!(Self {
            time: Timebase::new(period_us),
            life,
            clock <- CycleClock::new(),
            stats <- stats,
            faults,
            arms: all,
        }? Error))
    }

    /// Arm `i`, if the controller serves it.
    pub(crate) fn arm(&self, i: usize) -> Option<&Arc<Arm>> {
        self.arms.get(i).and_then(Option::as_ref)
    }

    /// The arms served, arm 0 first.
    pub(crate) fn arms(&self) -> impl Iterator<Item = &Arc<Arm>> {
        self.arms.iter().flatten()
    }

    /// How many arms are served (1 or 2).
    pub(crate) fn arm_count(&self) -> usize {
        if self.arms.get(1).is_some_and(Option::is_some) {
            2
        } else {
            1
        }
    }

    /// One fail-safe action, the same for CLOCK's fail-safe and rmmod
    /// (`ReleaseResources` here is rmmod's: the fail-safe's own keeps the
    /// position log readable and waits for SERVO, see `clock::fail_safe`).
    pub(crate) fn act(&self, action: FailSafeAction) {
        match action {
            // The first two act on each arm's motor line, outside every
            // lock: the motors apply 0 from here on, whether SERVO is
            // waiting, inside its cycle holding `mtx_data`, or hung. Every
            // arm's line is cut before any is powered off.
            FailSafeAction::InhibitMotorCommands => {
                for arm in self.arms() {
                    arm.io.motor_line.fail_safe_inhibit();
                }
            }
            FailSafeAction::PowerOffArm => {
                for arm in self.arms() {
                    arm.io.motor_line.power_off();
                }
            }
            FailSafeAction::CloseProtocol => {
                for arm in self.arms() {
                    arm.proto.close();
                    arm.rtf.close();
                }
            }
            FailSafeAction::StopTasks => {
                self.life.set_stopping();
                self.clock.cycle_start.complete_all();
                self.clock.check_due.complete_all();
                for arm in self.arms() {
                    arm.rtf.rtf_in_ready.complete_all();
                }
            }
            FailSafeAction::ReleaseResources => {
                for arm in self.arms() {
                    arm.effort.close();
                    arm.log.close(true);
                }
            }
        }
    }

    /// rmmod (spec §3.2): the fail-safe's actions in their order, whatever
    /// SERVO is doing; the caller then stops the tasks and frees the rest.
    pub(crate) fn shut_down(&self) {
        for action in FAIL_SAFE_SEQUENCE {
            self.act(action);
        }
    }
}
