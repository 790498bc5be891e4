//! hap_io: the motor line between the servo's commands and the motors, and
//! `send_commands` onto it. `get_measures` is the arm's side of the I/O
//! seam ([`super::arm_io`]): the simulator in this version, a real arm's
//! encoders and DACs behind the same trait.
//!
//! # The motor line
//!
//! [`MotorLine`] is the state of the wire between the servo's commands and
//! the motors: the last commanded joint torques (the DAC), the command gate
//! ([`Gate`]: inhibited, enabled, or cut by the fail-safe) and the arm supply.
//! It is made of atomics and lives outside every lock, so that
//! - the motors (here `Simulator::simulate_arm`, at each integration
//!   sub-step) read it at the moment they apply torque: the torque applied is
//!   the command when the gate is `Enabled` and the supply on, else exactly 0;
//! - the fail-safe cuts it directly ([`MotorLine::fail_safe_inhibit`],
//!   [`MotorLine::power_off`]): one atomic store each, no lock, so it takes
//!   effect whether SERVO is mid-cycle, hung, or gone.
//!
//! Protocol: one writer of commands (SERVO through `send_commands`), any
//! number of gate writers (SERVO on power requests, the fail-safe), any
//! number of readers (the motors, status devices). The gate only moves
//! `Inhibited ⇄ Enabled` by compare-and-exchange, and to `FailSafe` by a
//! plain store; nothing leaves `FailSafe` but [`MotorLine::reset`] (module
//! reload). The supply is switched on only while the gate is not `FailSafe`.
//! The torque applied is decided by one `Acquire` load of the gate and one of
//! the supply, both after the fail-safe's `SeqCst` stores once they are
//! visible: every sub-step that starts after the cut applies 0.
//!
//! Motor commands are INHIBITED from start-up until a power-on request from
//! the arm (the simulated arm's power button, a device write in the kernel).
//! A power-off request inhibits them again and cuts the simulated supply. The
//! fail-safe inhibits them for good: later power-on requests are refused.

use core::sync::atomic::{AtomicBool, AtomicI64, AtomicU8, Ordering};

use super::arm;
use super::fixed::{Fx, Joints, JOINTS_ZERO};

/// The motor command gate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum Gate {
    /// Commands do not reach the motors (start-up, after a power-off).
    Inhibited = 0,
    /// Commands reach the motors.
    Enabled = 1,
    /// Cut by the fail-safe, latched until [`MotorLine::reset`].
    FailSafe = 2,
}

impl Gate {
    /// The gate stored as `v` (unknown values read as `FailSafe`, the safe side).
    pub const fn from_u8(v: u8) -> Gate {
        match v {
            0 => Gate::Inhibited,
            1 => Gate::Enabled,
            _ => Gate::FailSafe,
        }
    }

    pub const fn as_u8(self) -> u8 {
        self as u8
    }

    pub const fn name(self) -> &'static str {
        match self {
            Gate::Inhibited => "inhibited",
            Gate::Enabled => "enabled",
            Gate::FailSafe => "fail_safe",
        }
    }
}

/// The line between the servo's commands and the motors (see the module doc).
#[derive(Debug)]
pub struct MotorLine {
    gate: AtomicU8,
    supply: AtomicBool,
    command: [AtomicI64; 6],
}

/// A snapshot copy (host tests and tools that fork a servo's state).
impl Clone for MotorLine {
    fn clone(&self) -> Self {
        let line = MotorLine::new();
        line.gate
            .store(self.gate.load(Ordering::Acquire), Ordering::Relaxed);
        line.supply.store(self.supply_on(), Ordering::Relaxed);
        line.write_command(&self.command());
        line
    }
}

impl Default for MotorLine {
    fn default() -> Self {
        MotorLine::new()
    }
}

impl MotorLine {
    /// Inhibited, supply off, command 0.
    pub const fn new() -> MotorLine {
        MotorLine {
            gate: AtomicU8::new(Gate::Inhibited as u8),
            supply: AtomicBool::new(false),
            command: [
                AtomicI64::new(0),
                AtomicI64::new(0),
                AtomicI64::new(0),
                AtomicI64::new(0),
                AtomicI64::new(0),
                AtomicI64::new(0),
            ],
        }
    }

    /// Back to the start-up state (module reload): inhibited, supply off,
    /// command 0. Only while nothing else uses the line.
    pub fn reset(&self) {
        self.command_zero();
        self.supply.store(false, Ordering::SeqCst);
        self.gate.store(Gate::Inhibited as u8, Ordering::SeqCst);
    }

    pub fn gate(&self) -> Gate {
        Gate::from_u8(self.gate.load(Ordering::Acquire))
    }

    /// The arm supply is on.
    pub fn supply_on(&self) -> bool {
        self.supply.load(Ordering::Acquire)
    }

    /// Commands reach the motors (gate enabled and supply on).
    pub fn motors_enabled(&self) -> bool {
        self.gate() == Gate::Enabled && self.supply_on()
    }

    /// A power-on request: supply on and commands enabled, unless the
    /// fail-safe cut the line. Returns whether the arm is now powered.
    pub fn power_on(&self) -> bool {
        if self.gate() == Gate::FailSafe {
            return false;
        }
        self.supply.store(true, Ordering::SeqCst);
        let _ = self.gate.compare_exchange(
            Gate::Inhibited as u8,
            Gate::Enabled as u8,
            Ordering::SeqCst,
            Ordering::SeqCst,
        );
        // The fail-safe may have cut the line between the check and the
        // stores: it then also cuts the supply after us (its second step),
        // or already did; either way the gate is FailSafe and nothing flows.
        if self.gate() == Gate::FailSafe {
            self.supply.store(false, Ordering::SeqCst);
            return false;
        }
        true
    }

    /// A power-off request: commands inhibited, supply off.
    pub fn power_request_off(&self) {
        let _ = self.gate.compare_exchange(
            Gate::Enabled as u8,
            Gate::Inhibited as u8,
            Ordering::SeqCst,
            Ordering::SeqCst,
        );
        self.supply.store(false, Ordering::SeqCst);
        self.command_zero();
    }

    /// Fail-safe action 1: inhibit motor commands, latched. One store: no
    /// lock, whatever SERVO is doing.
    pub fn fail_safe_inhibit(&self) {
        self.gate.store(Gate::FailSafe as u8, Ordering::SeqCst);
    }

    /// Fail-safe action 2: power off the arm supply. One store.
    pub fn power_off(&self) {
        self.supply.store(false, Ordering::SeqCst);
    }

    /// `send_commands`' write: the DAC takes `tau`, clamped to the motor
    /// limits. Whether it reaches the motors is the gate's business.
    pub fn write_command(&self, tau: &Joints) {
        for ((c, t), lim) in self.command.iter().zip(tau.iter()).zip(arm::TAU_MAX.iter()) {
            c.store(t.clamp_abs(*lim).0, Ordering::Relaxed);
        }
    }

    fn command_zero(&self) {
        for c in self.command.iter() {
            c.store(0, Ordering::Relaxed);
        }
    }

    /// The last command written (what the DAC holds).
    pub fn command(&self) -> Joints {
        let mut out = JOINTS_ZERO;
        for (o, c) in out.iter_mut().zip(self.command.iter()) {
            *o = Fx(c.load(Ordering::Relaxed));
        }
        out
    }

    /// The torques the motors produce now: the command while the gate is
    /// enabled and the supply on, else exactly 0.
    pub fn applied(&self) -> Joints {
        if self.motors_enabled() {
            self.command()
        } else {
            JOINTS_ZERO
        }
    }
}

/// `send_commands`: write joint torques to the motors through the line.
/// Returns the torques the motors produce now (0 while inhibited, unpowered
/// or cut).
pub fn send_commands(line: &MotorLine, tau: &Joints) -> Joints {
    if line.motors_enabled() {
        line.write_command(tau);
    } else {
        line.command_zero();
    }
    line.applied()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn some_torque() -> Joints {
        [
            Fx::from_int(3),
            Fx::from_int(-4),
            Fx::ONE,
            Fx::from_ratio(1, 10),
            Fx::from_ratio(-1, 10),
            Fx::from_ratio(1, 20),
        ]
    }

    #[test]
    fn inhibited_until_power_on() {
        let line = MotorLine::new();
        assert_eq!(line.gate(), Gate::Inhibited);
        assert_eq!(send_commands(&line, &some_torque()), JOINTS_ZERO);
        assert!(line.power_on());
        assert_eq!(send_commands(&line, &some_torque()), some_torque());
        line.power_request_off();
        assert_eq!(line.gate(), Gate::Inhibited);
        assert_eq!(line.applied(), JOINTS_ZERO);
        assert_eq!(line.command(), JOINTS_ZERO);
    }

    #[test]
    fn fail_safe_cuts_a_held_command_and_latches() {
        let line = MotorLine::new();
        assert!(line.power_on());
        send_commands(&line, &some_torque());
        // SERVO hung after this write: the DAC holds the command...
        assert_eq!(line.applied(), some_torque());
        // ...and the fail-safe's first step alone makes the motors produce 0.
        line.fail_safe_inhibit();
        assert_eq!(line.applied(), JOINTS_ZERO);
        assert_eq!(line.command(), some_torque());
        line.power_off();
        assert!(!line.supply_on());
        // A late write or power-on changes nothing.
        assert_eq!(send_commands(&line, &some_torque()), JOINTS_ZERO);
        assert!(!line.power_on());
        line.power_request_off();
        assert_eq!(line.gate(), Gate::FailSafe);
        assert_eq!(line.applied(), JOINTS_ZERO);
        line.reset();
        assert_eq!(line.gate(), Gate::Inhibited);
    }

    #[test]
    fn commands_are_clamped_to_the_motor_limits() {
        let line = MotorLine::new();
        line.power_on();
        let big = [Fx::from_int(1000); 6];
        let applied = send_commands(&line, &big);
        assert_eq!(applied, arm::TAU_MAX);
    }

    #[test]
    fn concurrent_cut_wins_over_power_on() {
        // A power-on racing the fail-safe never leaves the line enabled.
        for _ in 0..200 {
            let line = MotorLine::new();
            std::thread::scope(|s| {
                s.spawn(|| {
                    for _ in 0..50 {
                        line.power_on();
                        send_commands(&line, &some_torque());
                    }
                });
                s.spawn(|| {
                    line.fail_safe_inhibit();
                    line.power_off();
                });
            });
            assert_eq!(line.gate(), Gate::FailSafe);
            assert_eq!(line.applied(), JOINTS_ZERO);
        }
    }
}
