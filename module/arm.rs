// SPDX-License-Identifier: GPL-2.0

//! One arm served by the controller: its own session and protocol state,
//! RT-FIFO pair, SERVO state (coupling, simulated arm), motor line,
//! position log and effort hand-off. The controller serves `arms` of them
//! (module parameter, 1 or 2) from one CLOCK and one SERVO, which steps
//! every arm in the same period; each arm has its own PROTO_IN.
//!
//! Arm 0's devices keep the names of a one-arm controller (`/dev/hap_*`);
//! arm 1's are `/dev/hap1_*`.

use crate::{
    effort::EffortChannel, io::ArmIo, position_log::PositionLog, proto_state::ProtoState,
    rtf::RtfPair, servo_data::ServoState,
};
use kernel::{prelude::*, sync::Arc};

/// Arms one controller serves at most.
pub(crate) const MAX_ARMS: usize = 2;

/// One arm's components (each states its own protocol).
#[pin_data]
pub(crate) struct Arm {
    /// 0 or 1: which devices and PROTO_IN serve it.
    pub(crate) index: usize,
    #[pin]
    pub(crate) servo: ServoState,
    #[pin]
    pub(crate) proto: ProtoState,
    pub(crate) rtf: Arc<RtfPair>,
    pub(crate) io: Arc<ArmIo>,
    pub(crate) log: Arc<PositionLog>,
    pub(crate) effort: Arc<EffortChannel>,
}

impl Arm {
    pub(crate) fn new(index: usize, period_us: u32) -> Result<impl PinInit<Self, Error>> {
        let servo = ServoState::new(period_us)?;
        let proto = ProtoState::new()?;
        let rtf = Arc::pin_init(RtfPair::new()?, GFP_KERNEL)?;
        let io = Arc::new(ArmIo::new(), GFP_KERNEL)?;
        let log = Arc::pin_init(PositionLog::new()?, GFP_KERNEL)?;
        let effort = Arc::pin_init(EffortChannel::new()?, GFP_KERNEL)?;
        Ok(try_pin_init!(Self {
            index,
            servo <- servo,
            proto <- proto,
            rtf,
            io,
            log,
            effort,
        }? Error))
    }
}
