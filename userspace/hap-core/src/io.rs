//! hap_io: `get_measures` / `send_commands`, redirected to the simulator in
//! this version (a real arm would read encoders and write DACs here).
//!
//! Motor commands are INHIBITED from start-up until a power-on request from
//! the arm (`power_request(true)`: the simulated arm's power button, a device
//! write in the kernel). A power-off request inhibits them again and cuts the
//! simulated supply. The fail-safe (`fail_safe_inhibit`, the first action of
//! the fail-safe sequence) inhibits them for good: later power-on requests
//! are refused until `reset` (module reload).

use super::fixed::{Joints, JOINTS_ZERO};
use super::simulator::{Measures, Simulator};

/// Motor command gate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Io {
    inhibited: bool,
    fail_safe: bool,
}

impl Default for Io {
    fn default() -> Self {
        Io::new()
    }
}

impl Io {
    /// Inhibited, no fail-safe.
    pub const fn new() -> Io {
        Io {
            inhibited: true,
            fail_safe: false,
        }
    }

    /// Back to the start-up state (inhibited, fail-safe cleared).
    pub fn reset(&mut self) {
        *self = Io::new();
    }

    /// A power request from the arm: on → supply on and commands enabled
    /// (refused after a fail-safe; returns whether the arm is now powered);
    /// off → commands inhibited and supply off.
    pub fn power_request(&mut self, sim: &mut Simulator, on: bool) -> bool {
        if on && !self.fail_safe {
            sim.set_power(true);
            self.inhibited = false;
        } else {
            self.inhibited = true;
            sim.set_power(false);
        }
        sim.powered()
    }

    /// Fail-safe action 1: inhibit motor commands (latched).
    pub fn fail_safe_inhibit(&mut self, sim: &mut Simulator) {
        self.fail_safe = true;
        self.inhibited = true;
        sim.set_motor_torques(&JOINTS_ZERO);
    }

    /// Fail-safe action 2: power off the arm supply.
    pub fn power_off(&mut self, sim: &mut Simulator) {
        self.inhibited = true;
        sim.set_power(false);
    }

    pub fn inhibited(&self) -> bool {
        self.inhibited
    }

    pub fn fail_safe(&self) -> bool {
        self.fail_safe
    }

    /// Commands reach the motors.
    pub fn motors_enabled(&self) -> bool {
        !self.inhibited
    }

    /// `get_measures`: acquire encoders, speeds, force sensor and switches.
    pub fn get_measures(&self, sim: &mut Simulator) -> Measures {
        sim.measures()
    }

    /// `send_commands`: write joint torques to the motors, or zero while
    /// inhibited / unpowered. Returns the torques the motors will produce.
    pub fn send_commands(&self, sim: &mut Simulator, tau: &Joints) -> Joints {
        if self.inhibited || !sim.powered() {
            sim.set_motor_torques(&JOINTS_ZERO);
        } else {
            sim.set_motor_torques(tau);
        }
        sim.motor_torques()
    }
}
