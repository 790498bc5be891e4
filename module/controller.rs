// SPDX-License-Identifier: GPL-2.0

//! The running controller: its components, created once at insmod. Each
//! component is a type of its own that holds its fields and states who
//! writes and reads them ([`CycleClock`], [`ServoState`], [`ProtoState`],
//! [`RtfPair`], [`PositionLog`], [`EffortChannel`], [`StatsPublication`],
//! [`ArmIo`] with the motor line, [`FaultInjection`], [`Lifecycle`]). This
//! type only aggregates them: the tasks (CLOCK, SERVO, PROTO_IN) borrow
//! it whole; each device is registered with the one component it serves
//! (an `Arc`), and /dev/hap_stats, the monitor, with the whole.
//!
//! The fail-safe's actions are written once here ([`Controller::act`]):
//! CLOCK's fail-safe runs them one by one in hap-core's
//! `FAIL_SAFE_SEQUENCE` order, and rmmod runs the same list
//! ([`Controller::shut_down`]).

use crate::{
    cycle_clock::CycleClock,
    effort::EffortChannel,
    fault::FaultInjection,
    hap_core::clock::{FailSafeAction, FAIL_SAFE_SEQUENCE},
    io::ArmIo,
    lifecycle::Lifecycle,
    position_log::PositionLog,
    proto_state::ProtoState,
    rtf::RtfPair,
    servo_data::ServoState,
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
    pub(crate) servo: ServoState,
    #[pin]
    pub(crate) proto: ProtoState,
    #[pin]
    pub(crate) stats: StatsPublication,
    pub(crate) rtf: Arc<RtfPair>,
    pub(crate) io: Arc<ArmIo>,
    pub(crate) log: Arc<PositionLog>,
    pub(crate) effort: Arc<EffortChannel>,
    pub(crate) faults: Arc<FaultInjection>,
}

impl Controller {
    pub(crate) fn new(period_us: u32) -> Result<impl PinInit<Self, Error>> {
        let servo = ServoState::new(period_us)?;
        let proto = ProtoState::new()?;
        let stats = StatsPublication::new(period_us)?;
        let life = Arc::new(Lifecycle::new(), GFP_KERNEL)?;
        let rtf = Arc::pin_init(RtfPair::new()?, GFP_KERNEL)?;
        let io = Arc::new(ArmIo::new(), GFP_KERNEL)?;
        let log = Arc::pin_init(PositionLog::new()?, GFP_KERNEL)?;
        let effort = Arc::pin_init(EffortChannel::new()?, GFP_KERNEL)?;
        let faults = Arc::new(FaultInjection::new(), GFP_KERNEL)?;
        Ok(try_pin_init!(Self {
            time: Timebase::new(period_us),
            life,
            clock <- CycleClock::new(),
            servo <- servo,
            proto <- proto,
            stats <- stats,
            rtf,
            io,
            log,
            effort,
            faults,
        }? Error))
    }

    /// One fail-safe action, the same for CLOCK's fail-safe and rmmod
    /// (`ReleaseResources` here is rmmod's: the fail-safe's own keeps the
    /// position log readable and waits for SERVO, see `clock::fail_safe`).
    pub(crate) fn act(&self, action: FailSafeAction) {
        match action {
            // The first two act on hap_io's motor line, outside every lock:
            // the motors apply 0 from here on, whether SERVO is waiting,
            // inside its cycle holding `mtx_data`, or hung.
            FailSafeAction::InhibitMotorCommands => self.io.motor_line.fail_safe_inhibit(),
            FailSafeAction::PowerOffArm => self.io.motor_line.power_off(),
            FailSafeAction::CloseProtocol => {
                self.proto.close();
                self.rtf.close();
            }
            FailSafeAction::StopTasks => {
                self.life.set_stopping();
                self.clock.cycle_start.complete_all();
                self.clock.check_due.complete_all();
                self.rtf.rtf_in_ready.complete_all();
            }
            FailSafeAction::ReleaseResources => {
                self.effort.close();
                self.log.close(true);
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
