//! hap_simulator: the simulated Virtuose arm (`simulate_arm`) and the binary
//! position-log record it produces each cycle.
//!
//! One call integrates the joint dynamics of [`super::arm`] over one servo
//! period with [`substeps`]`(period)` semi-implicit Euler sub-steps (no
//! longer than [`MAX_SUBSTEP_NS`]):
//!
//! ```text
//! τ = Jᵀ·w_user + τ_gravity                                       (once per period)
//!     + τ_motor (the motor line, read now: 0 unless enabled and powered)
//!     − b·q̇ − fc·sat(q̇/0.01) + τ_stop(q, q̇)                      (every sub-step)
//! q̇ ← q̇ + dt·τ / I(q)      q ← q + dt·q̇                           (dt = period / n)   
//! ```
//!
//! Kinematics, gravity, inertia and the Jacobian are evaluated once per period
//! at the configuration the period starts from. The outputs are what the
//! hardware gives: 6 encoder counts, 6 joint speeds (tachometers), the 6-axis
//! force sensor (the user's wrench expressed in the handle frame), and the
//! power / dead-man / button state.
//!
//! Motors: the torque they produce is read from hap_io's
//! [`MotorLine`] at every sub-step, so a fail-safe cut takes effect at the
//! next sub-step whatever the servo is doing. Unpowered, inhibited or cut,
//! the motors produce no torque whatever was commanded, so the arm
//! moves only under gravity, the user's effort and its stops; left alone it
//! settles to [`super::arm::REST_Q`] (shoulder on its stop, forearm hanging).

use super::arm::{self, Kinematics};
use super::effort::EffortSample;
use super::fixed::{unit30, Fx, Joints, Vec3, Wrench, JOINTS_ZERO};
use super::io::{Gate, MotorLine};

/// Longest integration sub-step, ns. Semi-implicit Euler at this step is
/// far inside its stability region for every joint of [`super::arm`]: the
/// stiffest stop (`STOP_STIFFNESS / I`, joint 6: 20 / 0.001) gives
/// `ω·dt = 141 rad/s · 0.5 ms = 0.07` (stable below 2), and the strongest
/// damping, Coulomb friction in its linear band plus viscous and stop damping
/// (joint 6: (0.3 + 0.03 + 0.3) N·m·s/rad / 0.001 kg·m²), gives
/// `b·dt/I = 0.32`: below 1, so no sub-step overshoots (a joint never
/// reverses under its own damping within a step).
pub const MAX_SUBSTEP_NS: u32 = 500_000;

/// Largest sub-step count (a 32 ms period).
pub const MAX_SUBSTEPS: u32 = 64;

/// Integration sub-steps for a servo period of `period_ns`: the fewest with
/// sub-steps no longer than [`MAX_SUBSTEP_NS`] (1 at 100 µs to 500 µs, 2 at
/// 1 ms, 20 at 10 ms), at least 1, at most [`MAX_SUBSTEPS`].
pub const fn substeps(period_ns: u32) -> u32 {
    let n = period_ns.div_ceil(MAX_SUBSTEP_NS);
    if n < 1 {
        1
    } else if n > MAX_SUBSTEPS {
        MAX_SUBSTEPS
    } else {
        n
    }
}

/// What the hardware returns (hap_io `get_measures`).
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

/// The simulated arm.
#[derive(Clone, Debug)]
pub struct Simulator {
    /// Joint positions, rad.
    pub q: Joints,
    /// Joint speeds, rad/s.
    pub qd: Joints,
    /// Torques the motors produced in the last sub-step of the last period.
    applied: Joints,
    /// The motor line was cut by the fail-safe during the last period.
    line_cut: bool,
    period: Fx,
    /// [`substeps`] of the period.
    substeps: u32,
    user: EffortSample,
    kin: Kinematics,
    kin_valid: bool,
    joint_limit: bool,
}

impl Simulator {
    /// An unpowered arm at rest, for a servo period of `period_ns`.
    pub const fn new(period_ns: u32) -> Simulator {
        Simulator {
            q: arm::REST_Q,
            qd: JOINTS_ZERO,
            applied: JOINTS_ZERO,
            line_cut: false,
            period: Fx::from_ns(period_ns as u64),
            substeps: substeps(period_ns),
            user: EffortSample::NONE,
            kin: Kinematics::ZERO,
            kin_valid: false,
            joint_limit: false,
        }
    }

    /// Initial calibration: put the arm at rest (`arm::REST_Q`), motionless.
    pub fn calibrate(&mut self) {
        self.set_state(&arm::REST_Q, &JOINTS_ZERO);
    }

    /// Place the arm (tests, scenario setup).
    pub fn set_state(&mut self, q: &Joints, qd: &Joints) {
        self.q = *q;
        self.qd = *qd;
        self.kin_valid = false;
    }

    pub fn period(&self) -> Fx {
        self.period
    }

    /// The torques the motors produced in the last sub-step of the last
    /// `simulate_arm` (what the position log records).
    pub fn applied_torques(&self) -> Joints {
        self.applied
    }

    /// The fail-safe had cut the motor line at some sub-step of the last period.
    pub fn line_cut(&self) -> bool {
        self.line_cut
    }

    /// The user's action for the coming period.
    pub fn set_user_effort(&mut self, e: &EffortSample) {
        self.user = *e;
    }

    pub fn user_effort(&self) -> &EffortSample {
        &self.user
    }

    /// Kinematics at the current configuration (the parts the simulated arm
    /// uses, [`arm::Parts::SIMULATOR`]: no handle quaternion).
    pub fn kinematics(&mut self) -> &Kinematics {
        if !self.kin_valid {
            self.kin = arm::kinematics_with(&self.q, arm::Parts::SIMULATOR);
            self.kin_valid = true;
        }
        &self.kin
    }

    /// The hardware's view of the arm now (`line`: the supply's state).
    #[inline(never)]
    pub fn measures(&mut self, line: &MotorLine) -> Measures {
        let user = self.user;
        let kin = self.kinematics();
        let force_sensor = Wrench {
            force: kin.rot_tmul(user.wrench.force),
            torque: kin.rot_tmul(user.wrench.torque),
        };
        Measures {
            encoders: self.q.map(arm::encoder_counts),
            joint_speeds: self.qd,
            force_sensor,
            power_on: line.supply_on(),
            dead_man: user.dead_man,
            buttons: user.buttons,
            joint_limit: self.joint_limit,
        }
    }

    /// `simulate_arm`: advance the arm by one servo period. The motors'
    /// torque is read from `line` at every sub-step.
    #[allow(clippy::needless_range_loop)]
    #[inline(never)]
    pub fn simulate_arm(&mut self, line: &MotorLine) {
        // `substeps` is 1..=MAX_SUBSTEPS (the fallback cannot be taken).
        let dt = Fx(self
            .period
            .0
            .checked_div(i64::from(self.substeps))
            .unwrap_or(self.period.0));
        let wrench = self.user.wrench;
        let mut base = JOINTS_ZERO;
        let mut dt_over_i = JOINTS_ZERO;
        {
            // Borrowed, not copied: only the Jacobian, gravity and inertia.
            let kin = self.kinematics();
            let user_tau = kin.jacobian_transpose_mul(&wrench);
            for i in 0..6 {
                base[i] = user_tau[i].add_sat(kin.gravity[i]);
                dt_over_i[i] = dt.div_sat(kin.inertia[i]);
            }
        }
        // Per joint and period: whether the sum below can skip its
        // saturation checks as far as the once-per-period torque goes.
        let base_small = base.map(|b| within(b, 1 << 45));
        let mut limit = false;
        let mut cut = false;
        for _ in 0..self.substeps {
            // The motors apply what the line lets through, now.
            let motor = line.applied();
            cut |= line.gate() == Gate::FailSafe;
            self.applied = motor;
            for i in 0..6 {
                let (q, qd) = (self.q[i], self.qd[i]);
                let mut tau = if within(qd, 1 << 40) && base_small[i] && within(motor[i], 1 << 45) {
                    // No sum below can saturate (|base + motor| < 2^46,
                    // |b·q̇| < 2^42 raw, |fc·sat| ≤ 2^33): plain sums, the
                    // same result as the saturating ones. q̇·100 clamped to
                    // ±1 by comparing q̇ with ⌈2^32/100⌉ raw (the product
                    // below it cannot overflow). The damping and friction
                    // products are `mul_unit`'s with the constant's Q2.30
                    // factor taken once (`DAMPING_Q30`, `COULOMB_Q30`) and
                    // no saturation (|q̇|, |sat| < 2^8: the high partial
                    // product is below 2^40): the same values.
                    let sat = if qd.0 >= COULOMB_KNEE {
                        Fx::ONE.0
                    } else if qd.0 <= -COULOMB_KNEE {
                        -Fx::ONE.0
                    } else {
                        qd.0.wrapping_mul(COULOMB_GAIN)
                    };
                    Fx(base[i]
                        .0
                        .wrapping_add(motor[i].0)
                        .wrapping_sub(mul_q30(qd.0, DAMPING_Q30[i]))
                        .wrapping_sub(mul_q30(sat, COULOMB_Q30[i])))
                } else {
                    base[i]
                        .add_sat(motor[i])
                        .sub_sat(qd.mul_unit(arm::DAMPING[i]))
                        .sub_sat(
                            qd.mul_int(COULOMB_GAIN)
                                .clamp_abs(Fx::ONE)
                                .mul_unit(arm::COULOMB[i]),
                        )
                };
                if q > arm::Q_MAX[i] {
                    limit = true;
                    let t = arm::STOP_STIFFNESS[i]
                        .mul_sat(q.sub_sat(arm::Q_MAX[i]))
                        .add_sat(arm::STOP_DAMPING[i].mul_sat(qd));
                    tau = tau.sub_sat(t.max(Fx::ZERO));
                } else if q < arm::Q_MIN[i] {
                    limit = true;
                    let t = arm::STOP_STIFFNESS[i]
                        .mul_sat(q.sub_sat(arm::Q_MIN[i]))
                        .add_sat(arm::STOP_DAMPING[i].mul_sat(qd));
                    tau = tau.sub_sat(t.min(Fx::ZERO));
                }
                let qd = qd.add_sat(tau.mul_sat(dt_over_i[i]));
                self.qd[i] = qd;
                self.q[i] = q.add_sat(qd.mul_sat(dt));
            }
        }
        self.joint_limit = limit;
        self.line_cut = cut;
        self.kin_valid = false;
    }
}

/// 1 / `arm::COULOMB_LINEAR_SPEED`.
const COULOMB_GAIN: i64 = 100;

/// The smallest raw q̇ with `q̇ · COULOMB_GAIN ≥ 1` (⌈2^32 / 100⌉).
const COULOMB_KNEE: i64 = (Fx::ONE.0 + COULOMB_GAIN - 1) / COULOMB_GAIN;

/// Six joint factors as `mul_unit` takes them (`unit30` each), at compile time.
const fn unit30_joints(j: Joints) -> [i64; 6] {
    let [a, b, c, d, e, f] = j;
    [
        unit30(a),
        unit30(b),
        unit30(c),
        unit30(d),
        unit30(e),
        unit30(f),
    ]
}

/// `arm::DAMPING` and `arm::COULOMB` as `mul_unit` factors.
const DAMPING_Q30: [i64; 6] = unit30_joints(arm::DAMPING);
const COULOMB_Q30: [i64; 6] = unit30_joints(arm::COULOMB);

/// Raw `x.mul_unit(u)` for `u30 = unit30(u)` and `|x| < 2^40` raw: then
/// `|u30·⌊x/2^32⌋| < 2^39`, so none of `mul_unit`'s saturations can act and
/// the wrapping operations are exact: the same value.
const fn mul_q30(x: i64, u30: i64) -> i64 {
    (u30.wrapping_mul(x >> 32) << 2).wrapping_add(u30.wrapping_mul(x & 0xFFFF_FFFF) >> 30)
}

/// `|x| < lim` raw.
const fn within(x: Fx, lim: i64) -> bool {
    x.0 > -lim && x.0 < lim
}

/// Which path produced a [`LogRecord`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LogMode {
    /// SERVO's main path.
    #[default]
    Main,
    /// SERVO's auxiliary (degraded) path, after a deadline miss.
    Degraded,
    /// A fail-safe step (written by the supervisor, not by a servo cycle).
    FailSafe,
}

impl LogMode {
    pub const fn to_u8(self) -> u8 {
        match self {
            LogMode::Main => 0,
            LogMode::Degraded => 1,
            LogMode::FailSafe => 2,
        }
    }

    pub const fn from_u8(v: u8) -> Option<LogMode> {
        match v {
            0 => Some(LogMode::Main),
            1 => Some(LogMode::Degraded),
            2 => Some(LogMode::FailSafe),
            _ => None,
        }
    }

    pub const fn name(self) -> &'static str {
        match self {
            LogMode::Main => "main",
            LogMode::Degraded => "degraded",
            LogMode::FailSafe => "fail_safe",
        }
    }
}

/// One cycle of the binary position log (little-endian, version 2,
/// [`LogRecord::SIZE`] bytes), streamed by the kernel to `/dev/hap_simlog`
/// and read by the off-line analysis. Fx values are i64 Q32.32.
///
/// | offset | size | field |
/// |---|---|---|
/// | 0 | 4 | magic `b"HAPL"` |
/// | 4 | 2 | version (2) |
/// | 6 | 2 | flags: bit0 power, bit1 motors enabled, bit2 dead-man, bit3 button1, bit4 button2, bit5 degraded, bit6 coupled, bit7 motor line cut by the fail-safe during the period, bit8 (fail-safe step records only) servo fields unknown: only mode, step, status, alarms, applied torques and tick are valid |
/// | 8 | 8 | cycle (u64), consecutive from 0 at insmod |
/// | 16 | 8 | servo time at the cycle start, µs (cycle × period) |
/// | 24 | 1 | mode: 0 main, 1 degraded, 2 fail-safe step |
/// | 25 | 1 | fail-safe step done (1..=5, `FAIL_SAFE_SEQUENCE` order), else 0 |
/// | 26 | 2 | reserved (0) |
/// | 28 | 4 | age of the VPr in use, cycles (u32, saturating; `NO_VPR` if none) |
/// | 32 | 48 | joint positions q, 6 × rad (from the encoders) |
/// | 80 | 48 | joint speeds q̇, 6 × rad/s |
/// | 128 | 24 | handle position, 3 × m (arm base frame) |
/// | 152 | 32 | handle orientation x, y, z, w |
/// | 184 | 24 | handle linear velocity, 3 × m/s (base frame) |
/// | 208 | 24 | handle angular velocity, 3 × rad/s (base frame) |
/// | 232 | 48 | joint torques commanded by the controller, 6 × N·m |
/// | 280 | 48 | joint torques the motors produced (what `simulate_arm` applied, last sub-step of the period), 6 × N·m |
/// | 328 | 24 | coupling force on the handle, 3 × N (base frame) |
/// | 352 | 24 | coupling torque on the handle, 3 × N·m (base frame) |
/// | 376 | 48 | user wrench fx fy fz tx ty tz (N, N·m, base frame) |
/// | 424 | 24 | VPr in use (estimate at this cycle): position, 3 × client units |
/// | 448 | 32 | VPr in use: orientation x, y, z, w |
/// | 480 | 24 | handle position in the client's frame, 3 × client units |
/// | 504 | 4 | status bits (`vp::status`, as answered) |
/// | 508 | 4 | alarm bits (`vp::alarm`) |
/// | 512 | 8 | passivity observer energy, J |
/// | 520 | 8 | link watchdog gain, [0, 1] |
/// | 528 | 8 | kernel: cycle-timer tick that started the cycle (u64) |
/// | 536 | 8 | kernel: cycle start, ns since insmod (u64) |
/// | 544 | 4 | kernel: wake-up latency, ns (u32, saturating) |
/// | 548 | 4 | kernel: execution time, ns (u32, saturating) |
/// | 552 | 2 | kernel: protocol session id (0: no session) |
/// | 554 | 6 | reserved (0) |
///
/// The last 32 bytes ([`LogRecord::TIMING`]) are filled by the kernel's
/// SERVO thread and are 0 in a host replay; everything before is the servo
/// step's own output, bit for bit the same on the host.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LogRecord {
    pub flags: u16,
    pub cycle: u64,
    pub time_us: u64,
    pub mode: LogMode,
    pub fail_safe_step: u8,
    pub vpr_age_cycles: u32,
    pub q: Joints,
    pub qd: Joints,
    pub handle_position: Vec3,
    pub handle_orientation: [Fx; 4],
    pub handle_velocity: Vec3,
    pub handle_angular_velocity: Vec3,
    pub torque_command: Joints,
    /// The torques the motors produced (0 unpowered, clamped to `arm::TAU_MAX`).
    pub motor_torque: Joints,
    pub coupling_force: Vec3,
    pub coupling_torque: Vec3,
    pub user_wrench: [Fx; 6],
    pub vpr_position: Vec3,
    pub vpr_orientation: [Fx; 4],
    pub handle_position_client: Vec3,
    pub status: u32,
    pub alarms: u32,
    pub po_energy: Fx,
    pub link_gain: Fx,
    pub timing: LogTiming,
}

/// The kernel's timing of one cycle (0 in a host replay).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LogTiming {
    /// Cycle-timer tick that started the cycle.
    pub tick: u64,
    /// Cycle start (SERVO woke), ns since insmod.
    pub start_ns: u64,
    /// SERVO's wake-up latency after the tick, ns.
    pub wakeup_ns: u32,
    /// SERVO's execution time, ns.
    pub exec_ns: u32,
    /// The protocol session open at the cycle (0: none).
    pub session: u16,
}

impl LogTiming {
    pub const ZERO: LogTiming = LogTiming {
        tick: 0,
        start_ns: 0,
        wakeup_ns: 0,
        exec_ns: 0,
        session: 0,
    };
}

/// Error decoding a [`LogRecord`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LogDecodeError {
    BadMagic,
    BadVersion,
    BadMode,
}

impl LogRecord {
    pub const SIZE: usize = 560;
    pub const MAGIC: [u8; 4] = *b"HAPL";
    pub const VERSION: u16 = 2;
    /// `vpr_age_cycles` when no VPr has been received.
    pub const NO_VPR: u32 = u32::MAX;
    /// Byte range of the kernel's timing fields.
    pub const TIMING: core::ops::Range<usize> = 528..560;

    pub const ZERO: LogRecord = LogRecord {
        flags: 0,
        cycle: 0,
        time_us: 0,
        mode: LogMode::Main,
        fail_safe_step: 0,
        vpr_age_cycles: LogRecord::NO_VPR,
        q: JOINTS_ZERO,
        qd: JOINTS_ZERO,
        handle_position: Vec3::ZERO,
        handle_orientation: [Fx::ZERO; 4],
        handle_velocity: Vec3::ZERO,
        handle_angular_velocity: Vec3::ZERO,
        torque_command: JOINTS_ZERO,
        motor_torque: JOINTS_ZERO,
        coupling_force: Vec3::ZERO,
        coupling_torque: Vec3::ZERO,
        user_wrench: [Fx::ZERO; 6],
        vpr_position: Vec3::ZERO,
        vpr_orientation: [Fx::ZERO; 4],
        handle_position_client: Vec3::ZERO,
        status: 0,
        alarms: 0,
        po_energy: Fx::ZERO,
        link_gain: Fx::ZERO,
        timing: LogTiming::ZERO,
    };

    pub fn encode(&self, out: &mut [u8; LogRecord::SIZE]) {
        let mut w = Writer { buf: out, pos: 0 };
        w.put(&LogRecord::MAGIC);
        w.put(&LogRecord::VERSION.to_le_bytes());
        w.put(&self.flags.to_le_bytes());
        w.put(&self.cycle.to_le_bytes());
        w.put(&self.time_us.to_le_bytes());
        w.put(&[self.mode.to_u8(), self.fail_safe_step, 0, 0]);
        w.put(&self.vpr_age_cycles.to_le_bytes());
        w.fxs(&self.q);
        w.fxs(&self.qd);
        w.fxs(&self.handle_position.to_array());
        w.fxs(&self.handle_orientation);
        w.fxs(&self.handle_velocity.to_array());
        w.fxs(&self.handle_angular_velocity.to_array());
        w.fxs(&self.torque_command);
        w.fxs(&self.motor_torque);
        w.fxs(&self.coupling_force.to_array());
        w.fxs(&self.coupling_torque.to_array());
        w.fxs(&self.user_wrench);
        w.fxs(&self.vpr_position.to_array());
        w.fxs(&self.vpr_orientation);
        w.fxs(&self.handle_position_client.to_array());
        w.put(&self.status.to_le_bytes());
        w.put(&self.alarms.to_le_bytes());
        w.fxs(&[self.po_energy, self.link_gain]);
        w.put(&self.timing.tick.to_le_bytes());
        w.put(&self.timing.start_ns.to_le_bytes());
        w.put(&self.timing.wakeup_ns.to_le_bytes());
        w.put(&self.timing.exec_ns.to_le_bytes());
        w.put(&self.timing.session.to_le_bytes());
        w.put(&[0u8; 6]);
    }

    pub fn decode(buf: &[u8; LogRecord::SIZE]) -> Result<LogRecord, LogDecodeError> {
        let mut r = Reader { buf, pos: 0 };
        if r.arr::<4>() != LogRecord::MAGIC {
            return Err(LogDecodeError::BadMagic);
        }
        if u16::from_le_bytes(r.arr()) != LogRecord::VERSION {
            return Err(LogDecodeError::BadVersion);
        }
        let flags = u16::from_le_bytes(r.arr());
        let cycle = u64::from_le_bytes(r.arr());
        let time_us = u64::from_le_bytes(r.arr());
        let [mode, fail_safe_step, _, _] = r.arr::<4>();
        let mode = LogMode::from_u8(mode).ok_or(LogDecodeError::BadMode)?;
        let vpr_age_cycles = u32::from_le_bytes(r.arr());
        let q = r.fxs::<6>();
        let qd = r.fxs::<6>();
        let handle_position = Vec3::from_array(r.fxs::<3>());
        let handle_orientation = r.fxs::<4>();
        let handle_velocity = Vec3::from_array(r.fxs::<3>());
        let handle_angular_velocity = Vec3::from_array(r.fxs::<3>());
        let torque_command = r.fxs::<6>();
        let motor_torque = r.fxs::<6>();
        let coupling_force = Vec3::from_array(r.fxs::<3>());
        let coupling_torque = Vec3::from_array(r.fxs::<3>());
        let user_wrench = r.fxs::<6>();
        let vpr_position = Vec3::from_array(r.fxs::<3>());
        let vpr_orientation = r.fxs::<4>();
        let handle_position_client = Vec3::from_array(r.fxs::<3>());
        let status = u32::from_le_bytes(r.arr());
        let alarms = u32::from_le_bytes(r.arr());
        let [po_energy, link_gain] = r.fxs::<2>();
        let timing = LogTiming {
            tick: u64::from_le_bytes(r.arr()),
            start_ns: u64::from_le_bytes(r.arr()),
            wakeup_ns: u32::from_le_bytes(r.arr()),
            exec_ns: u32::from_le_bytes(r.arr()),
            session: u16::from_le_bytes(r.arr()),
        };
        Ok(LogRecord {
            flags,
            cycle,
            time_us,
            mode,
            fail_safe_step,
            vpr_age_cycles,
            q,
            qd,
            handle_position,
            handle_orientation,
            handle_velocity,
            handle_angular_velocity,
            torque_command,
            motor_torque,
            coupling_force,
            coupling_torque,
            user_wrench,
            vpr_position,
            vpr_orientation,
            handle_position_client,
            status,
            alarms,
            po_energy,
            link_gain,
            timing,
        })
    }
}

struct Writer<'a> {
    buf: &'a mut [u8; LogRecord::SIZE],
    pos: usize,
}

impl Writer<'_> {
    fn put(&mut self, b: &[u8]) {
        let end = self.pos.saturating_add(b.len());
        if let Some(d) = self.buf.get_mut(self.pos..end) {
            d.copy_from_slice(b);
        }
        self.pos = end;
    }

    fn fxs(&mut self, v: &[Fx]) {
        for x in v {
            self.put(&x.0.to_le_bytes());
        }
    }
}

struct Reader<'a> {
    buf: &'a [u8; LogRecord::SIZE],
    pos: usize,
}

impl Reader<'_> {
    fn arr<const N: usize>(&mut self) -> [u8; N] {
        let mut a = [0u8; N];
        let end = self.pos.saturating_add(N);
        if let Some(s) = self.buf.get(self.pos..end) {
            a.copy_from_slice(s);
        }
        self.pos = end;
        a
    }

    fn fxs<const N: usize>(&mut self) -> [Fx; N] {
        let mut v = [Fx::ZERO; N];
        for x in v.iter_mut() {
            *x = Fx(i64::from_le_bytes(self.arr()));
        }
        v
    }
}
