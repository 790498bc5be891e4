//! The arm's I/O seam: what the servo step needs from an arm, whatever it
//! is. [`ArmIo`] is measures in (encoders, tachometers, the force sensor,
//! switches), the motors driven from hap_io's [`MotorLine`] out, and the
//! initial calibration. The servo step ([`super::servo::Servo`]), and
//! through it the position log, reach the arm only through this trait; the
//! fail-safe reaches the motors only through the motor line. The simulated
//! Virtuose ([`super::simulator::Simulator`]) is one implementation; the
//! host tests drive the same servo step on a recorded trajectory
//! (`tests/arm_io.rs`), and a real arm's encoder and DAC board would be
//! another.

use super::effort::EffortSample;
use super::fixed::{Joints, Wrench};
use super::io::MotorLine;

/// What the arm's sensors return (hap_io `get_measures`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Measures {
    /// Joint encoder counts (see `arm::ENCODER_COUNTS_PER_RAD`).
    pub encoders: [i32; 6],
    /// Joint speeds from the tachometers, rad/s.
    pub joint_speeds: Joints,
    /// 6-axis force sensor: the user's wrench on the handle, handle frame.
    pub force_sensor: Wrench,
    /// Arm supply on.
    pub power_on: bool,
    /// Dead-man switch held.
    pub dead_man: bool,
    /// Bit 0: button 1, bit 1: button 2.
    pub buttons: u8,
    /// Some joint is in its end stop.
    pub joint_limit: bool,
}

/// An arm as the servo step sees it.
///
/// Each servo period: [`ArmIo::set_user_effort`] (what a simulated user
/// does this period), [`ArmIo::measures`] (`get_measures`), the controller,
/// `send_commands` onto the motor line, then [`ArmIo::run_period`]: the arm
/// runs one period with what the motors produce from the line, which the
/// fail-safe may cut at any moment without the servo.
pub trait ArmIo {
    /// The initial calibration (spec §3.2) for a servo period of
    /// `period_ns`: the arm's I/O as at start-up, the arm at rest.
    fn calibrate_at_rest(&mut self, period_ns: u32);

    /// The user's action on the handle for the coming period. A simulated
    /// arm applies it; an arm whose user holds the real handle ignores it
    /// (its force sensor measures the user).
    fn set_user_effort(&mut self, effort: &EffortSample);

    /// `get_measures`: the sensors now; `line` tells the supply's state.
    fn measures(&mut self, line: &MotorLine) -> Measures;

    /// The arm runs one servo period, its motors producing what `line`
    /// gives at each moment (0 unless enabled and powered).
    fn run_period(&mut self, line: &MotorLine);

    /// The torques the motors produced at the end of the last period (what
    /// the position log records).
    fn applied_torques(&self) -> Joints;

    /// The fail-safe cut the motor line during the last period.
    fn line_cut(&self) -> bool;
}

/// `get_measures` (hap_io): acquire encoders, speeds, force sensor and
/// switches from `arm`.
pub fn get_measures(arm: &mut impl ArmIo, line: &MotorLine) -> Measures {
    arm.measures(line)
}
