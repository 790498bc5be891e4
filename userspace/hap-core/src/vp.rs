//! The two records exchanged between the protocol and the servo loop
//! (the spec's shared memories): `VpReceived` (VPr, the client's virtual
//! object as PROTO_IN decoded it) and `VpSent` (VP, what SERVO answers).

use super::fixed::{Pose, Twist, Wrench};

/// VPr: the client's virtual object, as last received.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct VpReceived {
    /// Pose of the virtual object in the client's world frame.
    pub pose: Pose,
    /// Twist of the virtual object (used to extrapolate when a frame is late).
    pub twist: Twist,
    /// Sequence number of the frame it came from.
    pub seq: u32,
    /// The client's timestamp of that frame, µs (wraps).
    pub client_time_us: u32,
    /// Controller time (servo cycle counter) at which it was decoded.
    pub received_cycle: u64,
    /// False until the first valid VPr frame of the session.
    pub valid: bool,
}

/// Status bits of the arm, sent in every answer (VirtuoseAPI `virtGetPowerOn`,
/// `virtGetDeadMan`, `virtGetEmergencyStop`, buttons...).
pub mod status {
    /// Arm supply powered.
    pub const POWER_ON: u32 = 1 << 0;
    /// Motor commands enabled (power on and not inhibited).
    pub const MOTORS_ENABLED: u32 = 1 << 1;
    /// The user holds the handle (dead-man switch).
    pub const DEAD_MAN: u32 = 1 << 2;
    /// Emergency stop pressed.
    pub const EMERGENCY_STOP: u32 = 1 << 3;
    /// Handle button 1 (indexing) pressed.
    pub const BUTTON_1: u32 = 1 << 4;
    /// Handle button 2 pressed.
    pub const BUTTON_2: u32 = 1 << 5;
    /// SERVO ran its auxiliary (degraded) path this cycle.
    pub const DEGRADED: u32 = 1 << 6;
    /// A virtual object is attached and coupled.
    pub const COUPLED: u32 = 1 << 7;
    /// The link watchdog is fading the coupling (client silent).
    pub const LINK_FADING: u32 = 1 << 8;
    /// VPr was extrapolated this cycle (protocol lock busy or frame late).
    pub const VPR_EXTRAPOLATED: u32 = 1 << 9;
}

/// Alarm bits (latched until cleared by a power cycle).
pub mod alarm {
    /// A joint reached its position limit.
    pub const JOINT_LIMIT: u32 = 1 << 0;
    /// A motor torque was saturated.
    pub const TORQUE_SATURATED: u32 = 1 << 1;
    /// The handle speed exceeded the velocity limit.
    pub const VELOCITY_LIMIT: u32 = 1 << 2;
    /// The passivity observer had to dissipate energy.
    pub const PASSIVITY: u32 = 1 << 3;
    /// A deadline was missed (see the cycle supervisor).
    pub const DEADLINE_MISS: u32 = 1 << 4;
    /// Fail-safe engaged.
    pub const FAIL_SAFE: u32 = 1 << 5;
}

/// VP: SERVO's answer to the client for one cycle.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct VpSent {
    /// Handle pose in the client's world frame (after base frame and factors).
    pub handle_pose: Pose,
    /// Handle twist in the client's world frame.
    pub handle_twist: Twist,
    /// Wrench to apply to the coupled virtual object (client units).
    pub coupling_wrench: Wrench,
    /// `status::*` bits.
    pub status: u32,
    /// `alarm::*` bits.
    pub alarms: u32,
    /// Servo cycle counter.
    pub cycle: u64,
    /// Sequence number of the last VPr used.
    pub vpr_seq: u32,
}
