//! hap_state_model: the robot's logical state (power, motors, mode, alarms,
//! dead-man, buttons) and physical state (joint state, forward kinematics →
//! handle pose, J·q̇ → cartesian twist, measured wrench) built from the
//! measures of one cycle.

use super::arm::{self, Kinematics};
use super::arm_io::Measures;
use super::config::{CommandType, IndexingMode, ServoConfig};
use super::fixed::{Joints, Pose, Twist, Wrench};
use super::io::Gate;
use super::mode::Mode;
use super::vp::{alarm, status};

/// What the controller knows about the arm's logic this cycle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LogicalState {
    pub power_on: bool,
    /// Power on and motor commands not inhibited.
    pub motors_enabled: bool,
    pub mode: Mode,
    pub command_type: CommandType,
    pub dead_man: bool,
    /// Bit 0: button 1 (indexing), bit 1: button 2.
    pub buttons: u8,
    /// Button 1 held and the indexing mode is not `None`.
    pub indexing: bool,
    /// Latched alarms so far plus this cycle's measured ones.
    pub alarms: u32,
    /// `vp::status` bits known before control (power, motors, dead-man,
    /// buttons, degraded).
    pub status: u32,
}

/// `build_logical_state`.
pub fn build_logical_state(
    m: &Measures,
    gate: Gate,
    config: &ServoConfig,
    mode: Mode,
    latched_alarms: u32,
) -> LogicalState {
    let motors_enabled = gate == Gate::Enabled && m.power_on;
    let indexing = m.buttons & 1 != 0 && config.indexing_mode != IndexingMode::None;
    let mut st = 0;
    if m.power_on {
        st |= status::POWER_ON;
    }
    if motors_enabled {
        st |= status::MOTORS_ENABLED;
    }
    if m.dead_man {
        st |= status::DEAD_MAN;
    }
    if m.buttons & 1 != 0 {
        st |= status::BUTTON_1;
    }
    if m.buttons & 2 != 0 {
        st |= status::BUTTON_2;
    }
    if mode == Mode::Degraded {
        st |= status::DEGRADED;
    }
    let mut alarms = latched_alarms;
    if m.joint_limit {
        alarms |= alarm::JOINT_LIMIT;
    }
    if gate == Gate::FailSafe {
        alarms |= alarm::FAIL_SAFE;
    }
    LogicalState {
        power_on: m.power_on,
        motors_enabled,
        mode,
        command_type: config.command_type,
        dead_man: m.dead_man,
        buttons: m.buttons,
        indexing,
        alarms,
        status: st,
    }
}

/// What the controller knows about the arm's motion this cycle (arm base frame).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PhysicalState {
    /// Joint positions from the encoders, rad.
    pub q: Joints,
    /// Joint speeds, rad/s.
    pub qd: Joints,
    /// FK, Jacobian and gravity at `q` ([`arm::Parts::STATE_MODEL`]: the
    /// inertia is the simulated arm's business, left at the rotor's).
    pub kin: Kinematics,
    /// Handle pose.
    pub handle: Pose,
    /// Handle twist `J·q̇`.
    pub twist: Twist,
    /// The user's wrench measured by the force sensor, rotated to the base frame.
    pub wrench: Wrench,
}

/// `build_physical_state`.
#[inline(never)]
pub fn build_physical_state(m: &Measures) -> PhysicalState {
    let q = m.encoders.map(arm::encoder_angle);
    let kin = arm::kinematics_with(&q, arm::Parts::STATE_MODEL);
    let twist = kin.jacobian_mul(&m.joint_speeds);
    let wrench = Wrench {
        force: kin.rot_mul(m.force_sensor.force),
        torque: kin.rot_mul(m.force_sensor.torque),
    };
    PhysicalState {
        q,
        qd: m.joint_speeds,
        handle: kin.handle,
        twist,
        wrench,
        kin,
    }
}
