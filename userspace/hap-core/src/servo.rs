//! hap_servo: one servo step, the same function for the kernel's SERVO thread
//! and the host tests (bit-for-bit identical: integer arithmetic only).
//!
//! `Servo::step` runs, in order: power request → user effort for this cycle →
//! `get_measures` → `build_logical_state` → `build_physical_state` →
//! `cartesian_control` → `send_commands` (inhibited unless powered) →
//! `simulate_arm` (one period) → fill VP and the `LogRecord`.
//!
//! `Mode::Main` is the normal path. `Mode::Degraded` is the spec's
//! auxiliary SERVO path, entered after a deadline miss: the same code (spec
//! §3.5) and the same gains, which are scheduled for an effective period of
//! 2T (a missed deadline may double it), so switching path injects no
//! energy; `status::DEGRADED` set.
//!
//! Initial calibration: the simulated arm starts at rest in
//! [`super::arm::REST_Q`] (shoulder on its stop, forearm and wrist hanging),
//! motionless, unpowered, motor commands inhibited.
//!
//! Size: about 6 KB (the 128-keyframe effort storage is 4 KB); `Servo::new`
//! is `const`, so the kernel can keep it in a static or a boxed allocation and
//! call `init` once (or let the first `step` do it).

use super::arm_io::{get_measures, ArmIo};
use super::config::ServoConfig;
use super::control::{cartesian_control, ControlOutput, Controller};
use super::effort::{EffortKeyframe, EffortParseError, EffortPlayer, EffortSample};
use super::fixed::Fx;
use super::io::{self, MotorLine};
use super::position_log::{LogRecord, LogTiming};
use super::proto_synchro::VprEstimate;
use super::simulator::Simulator;
use super::state_model::{build_logical_state, build_physical_state};
use super::vp::{alarm, status, VpReceived, VpSent};

use super::mode::Mode;

/// A power request from the (simulated) arm's power button.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum PowerRequest {
    /// Keep the current state.
    #[default]
    None,
    /// Power on the arm supply and enable motor commands.
    On,
    /// Inhibit motor commands and power off.
    Off,
}

impl PowerRequest {
    /// The request as it crosses an atomic (a device write → SERVO);
    /// [`PowerRequest::from_u8`] is its inverse.
    pub const fn as_u8(self) -> u8 {
        match self {
            PowerRequest::None => 0,
            PowerRequest::On => 1,
            PowerRequest::Off => 2,
        }
    }

    /// The request stored as `v`; unknown values read as `None`.
    pub const fn from_u8(v: u8) -> PowerRequest {
        match v {
            1 => PowerRequest::On,
            2 => PowerRequest::Off,
            _ => PowerRequest::None,
        }
    }
}

/// Per-cycle inputs from outside the servo (device writes in the kernel).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ServoInputs {
    pub power_request: PowerRequest,
    /// A live user effort overriding the pre-computed sequence this cycle.
    pub live_effort: Option<EffortSample>,
}

/// LogRecord flag bits.
pub mod log_flags {
    pub const POWER: u16 = 1 << 0;
    pub const MOTORS_ENABLED: u16 = 1 << 1;
    pub const DEAD_MAN: u16 = 1 << 2;
    pub const BUTTON_1: u16 = 1 << 3;
    pub const BUTTON_2: u16 = 1 << 4;
    pub const DEGRADED: u16 = 1 << 5;
    pub const COUPLED: u16 = 1 << 6;
    /// The fail-safe had cut the motor line during this period.
    pub const LINE_CUT: u16 = 1 << 7;
    /// A fail-safe step record whose servo fields are unknown: SERVO held
    /// its data when the step ran, so only the mode, the step, the status,
    /// the alarms, the applied torques (read from the motor line) and the
    /// tick are valid; the pose, speeds, forces, cycle and time are 0.
    pub const POSE_UNKNOWN: u16 = 1 << 8;
}

/// Everything the servo loop owns. `A` is the arm behind the I/O seam
/// (the simulated Virtuose by default).
#[derive(Clone, Debug)]
pub struct Servo<A: ArmIo = Simulator> {
    period_ns: u32,
    period: Fx,
    initialized: bool,
    /// The arm (the field keeps its name: it is part of the state's `Debug`
    /// text, which `examples/cycle_hash.rs` fingerprints).
    sim: A,
    ctrl: Controller,
    effort: EffortPlayer,
    cycle: u64,
    alarms: u32,
    vp: VpSent,
    log: LogRecord,
    out: ControlOutput,
}

const VP_ZERO: VpSent = VpSent {
    handle_pose: super::fixed::Pose::IDENTITY,
    handle_twist: super::fixed::Twist::ZERO,
    coupling_wrench: super::fixed::Wrench::ZERO,
    status: 0,
    alarms: 0,
    cycle: 0,
    vpr_seq: 0,
    link_energy: 0,
};

impl Servo<Simulator> {
    /// A servo of the simulated arm for a period of `period_ns` (1 ms:
    /// 1_000_000), not yet initialised (the first `step` calls `init`).
    pub const fn new(period_ns: u32) -> Servo {
        Servo::with_arm(Simulator::new(period_ns), period_ns)
    }

    pub fn simulator(&self) -> &Simulator {
        &self.sim
    }

    pub fn simulator_mut(&mut self) -> &mut Simulator {
        &mut self.sim
    }
}

impl<A: ArmIo> Servo<A> {
    /// A servo of `arm` for a period of `period_ns`, not yet initialised
    /// (the first `step` calls `init`, which calibrates the arm).
    pub const fn with_arm(arm: A, period_ns: u32) -> Servo<A> {
        Servo {
            period_ns,
            period: Fx::from_ns(period_ns as u64),
            initialized: false,
            sim: arm,
            ctrl: Controller::new(),
            effort: EffortPlayer::new(),
            cycle: 0,
            alarms: 0,
            vp: VP_ZERO,
            log: LogRecord::ZERO,
            out: ControlOutput {
                joint_torques: super::fixed::JOINTS_ZERO,
                fixed_torques: super::fixed::JOINTS_ZERO,
                handle_wrench: super::fixed::Wrench::ZERO,
                coupling_wrench: super::fixed::Wrench::ZERO,
                handle_pose_client: super::fixed::Pose::IDENTITY,
                handle_twist_client: super::fixed::Twist::ZERO,
                status: 0,
                alarms: 0,
                po_energy: Fx::ZERO,
                envelope: Fx::ZERO,
                torque_scale: Fx::ONE,
                force_scale: Fx::ONE,
                speed_scale: Fx::ONE,
                spring_wrench: super::fixed::Wrench::ZERO,
                brake_force: super::fixed::Vec3::ZERO,
            },
        }
    }

    /// Initialise: calibrate the arm at rest (the simulated one: its rest
    /// configuration),
    /// controller filters and gains, cycle 0. The loaded effort sequence is
    /// kept (playback restarts). The motor line is the caller's (a new
    /// [`MotorLine`] is inhibited and unpowered).
    pub fn init(&mut self) {
        self.sim.calibrate_at_rest(self.period_ns);
        self.ctrl.init(self.period);
        self.cycle = 0;
        self.alarms = 0;
        self.vp = VP_ZERO;
        self.log = LogRecord::ZERO;
        let keep = self.effort.live();
        self.effort.set_live(keep);
        self.initialized = true;
    }

    pub fn period_ns(&self) -> u32 {
        self.period_ns
    }

    pub fn cycle(&self) -> u64 {
        self.cycle
    }

    /// The answer of the last step.
    pub fn vp(&self) -> &VpSent {
        &self.vp
    }

    /// What the controller computed in the last step (joint torques, the
    /// coupling wrench applied through the motors, envelope).
    pub fn control_output(&self) -> &ControlOutput {
        &self.out
    }

    /// The log record of the last step.
    pub fn log_record(&self) -> &LogRecord {
        &self.log
    }

    /// Complete the last `LogRecord` with the synchronizer's view of the
    /// VPr used by the step: its status bits (`VPR_EXTRAPOLATED`,
    /// `LINK_FADING`), the link watchdog gain applied to the coupling and
    /// the age of the data.
    pub fn log_link(&mut self, est: &VprEstimate, gain: Fx) {
        self.log.status |= est.status;
        self.log.link_gain = gain;
        self.log.vpr_age_cycles = if est.vpr.valid {
            // A non-zero divisor by its type: no division-by-zero path.
            let period_us = core::num::NonZeroU64::new(u64::from(self.period_ns / 1000))
                .unwrap_or(core::num::NonZeroU64::MIN);
            u32::try_from(est.age_us / period_us).unwrap_or(u32::MAX)
        } else {
            LogRecord::NO_VPR
        };
    }

    /// The arm behind the I/O seam.
    pub fn arm(&self) -> &A {
        &self.sim
    }

    pub fn arm_mut(&mut self) -> &mut A {
        &mut self.sim
    }

    pub fn controller(&self) -> &Controller {
        &self.ctrl
    }

    pub fn controller_mut(&mut self) -> &mut Controller {
        &mut self.ctrl
    }

    /// The link watchdog's gain for the next step, [0, 1]: the coupling
    /// force that reaches the motors is at most this fraction of its bound
    /// (`ServoCycle::run` sets it every cycle; a bare `Servo` keeps 1).
    pub fn set_link_gain(&mut self, g: Fx) {
        if !self.initialized {
            self.init();
        }
        self.ctrl.set_link_gain(g);
    }

    pub fn effort(&self) -> &EffortPlayer {
        &self.effort
    }

    pub fn effort_mut(&mut self) -> &mut EffortPlayer {
        &mut self.effort
    }

    /// Load a pre-computed effort sequence (text format, see `effort`).
    pub fn load_effort_text(&mut self, text: &[u8]) -> Result<usize, EffortParseError> {
        self.effort.load_text(text)
    }

    /// Load pre-parsed keyframes (at most `EFFORT_CAPACITY`).
    pub fn load_effort(&mut self, keys: &[EffortKeyframe]) -> usize {
        self.effort.load(keys)
    }

    /// Set/clear a persistent live effort (overrides the sequence).
    pub fn set_live_effort(&mut self, e: Option<EffortSample>) {
        self.effort.set_live(e);
    }

    /// Latched alarms.
    pub fn alarms(&self) -> u32 {
        self.alarms
    }

    /// Microseconds since init at the start of the current cycle.
    pub fn time_us(&self) -> u64 {
        self.cycle.saturating_mul(self.period_ns as u64) / 1000
    }

    /// One servo step. Returns the answer (VP) for the client. `line` is
    /// hap_io's motor line: commands go through it, the simulated motors
    /// read it at every sub-step, the fail-safe cuts it without this call.
    pub fn step(
        &mut self,
        line: &MotorLine,
        inputs: &ServoInputs,
        config: &ServoConfig,
        vpr: &VpReceived,
        mode: Mode,
    ) -> &VpSent {
        if !self.initialized {
            self.init();
        }
        let mode = mode.servo_path();
        // Power request (the arm's power button).
        match inputs.power_request {
            PowerRequest::None => {}
            PowerRequest::On => {
                let was = line.supply_on();
                if line.power_on() && !was {
                    // A power cycle clears the latched alarms.
                    self.alarms &= alarm::FAIL_SAFE;
                }
            }
            PowerRequest::Off => line.power_request_off(),
        }
        // The user's effort for this period.
        let t_us = self.time_us();
        let user = match inputs.live_effort {
            Some(e) => e,
            None => self.effort.sample(t_us),
        };
        self.sim.set_user_effort(&user);

        if mode == Mode::Degraded {
            // The supervisor puts SERVO on its degraded path after a miss.
            self.alarms |= alarm::DEADLINE_MISS;
        }
        let m = get_measures(&mut self.sim, line);
        let ls = build_logical_state(&m, line.gate(), config, mode, self.alarms);
        let ps = build_physical_state(&m);
        let out = cartesian_control(&mut self.ctrl, &ls, &ps, config, vpr);
        io::send_commands(line, &out.joint_torques);
        self.sim.run_period(line);
        self.out = out;

        self.alarms = ls.alarms | out.alarms;
        let st = ls.status | out.status;
        self.vp = VpSent {
            handle_pose: out.handle_pose_client,
            handle_twist: out.handle_twist_client,
            coupling_wrench: out.coupling_wrench,
            status: st,
            alarms: self.alarms,
            cycle: self.cycle,
            vpr_seq: vpr.seq,
            link_energy: self.ctrl.link().wire_granted(),
        };
        let mut flags = 0u16;
        for (bit, lf) in [
            (status::POWER_ON, log_flags::POWER),
            (status::MOTORS_ENABLED, log_flags::MOTORS_ENABLED),
            (status::DEAD_MAN, log_flags::DEAD_MAN),
            (status::BUTTON_1, log_flags::BUTTON_1),
            (status::BUTTON_2, log_flags::BUTTON_2),
            (status::DEGRADED, log_flags::DEGRADED),
            (status::COUPLED, log_flags::COUPLED),
        ] {
            if st & bit != 0 {
                flags |= lf;
            }
        }
        if self.sim.line_cut() {
            flags |= log_flags::LINE_CUT;
        }
        let o = ps.handle.orientation;
        let vo = vpr.pose.orientation;
        self.log = LogRecord {
            flags,
            cycle: self.cycle,
            time_us: t_us,
            mode,
            fail_safe_step: 0,
            vpr_age_cycles: if vpr.valid {
                u32::try_from(self.cycle.saturating_sub(vpr.received_cycle)).unwrap_or(u32::MAX)
            } else {
                LogRecord::NO_VPR
            },
            q: ps.q,
            qd: ps.qd,
            handle_position: ps.handle.position,
            handle_orientation: [o.x, o.y, o.z, o.w],
            handle_velocity: ps.twist.linear,
            handle_angular_velocity: ps.twist.angular,
            torque_command: out.joint_torques,
            motor_torque: self.sim.applied_torques(),
            coupling_force: out.handle_wrench.force,
            coupling_torque: out.handle_wrench.torque,
            user_wrench: user.wrench.to_array(),
            vpr_position: vpr.pose.position,
            vpr_orientation: [vo.x, vo.y, vo.z, vo.w],
            handle_position_client: out.handle_pose_client.position,
            status: st,
            alarms: self.alarms,
            po_energy: out.po_energy,
            link_gain: Fx::ONE,
            timing: LogTiming::ZERO,
        };
        self.cycle = self.cycle.wrapping_add(1);
        &self.vp
    }
}

/// A servo with its own motor line, for host tools, tests and replays, where
/// nothing outside the servo cuts the line (the kernel keeps its line outside
/// `mtx_data` and calls [`Servo::step`] with it). `step` here is that same
/// call; everything else of [`Servo`] is reached through `Deref`.
#[derive(Clone, Debug)]
pub struct StandaloneServo {
    pub servo: Servo,
    pub line: MotorLine,
}

impl StandaloneServo {
    pub const fn new(period_ns: u32) -> StandaloneServo {
        StandaloneServo {
            servo: Servo::new(period_ns),
            line: MotorLine::new(),
        }
    }

    /// [`Servo::step`] on this servo's own line.
    pub fn step(
        &mut self,
        inputs: &ServoInputs,
        config: &ServoConfig,
        vpr: &VpReceived,
        mode: Mode,
    ) -> &VpSent {
        self.servo.step(&self.line, inputs, config, vpr, mode)
    }
}

impl core::ops::Deref for StandaloneServo {
    type Target = Servo;
    fn deref(&self) -> &Servo {
        &self.servo
    }
}

impl core::ops::DerefMut for StandaloneServo {
    fn deref_mut(&mut self) -> &mut Servo {
        &mut self.servo
    }
}
