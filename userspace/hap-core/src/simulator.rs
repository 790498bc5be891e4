//! hap_simulator: the simulated Virtuose arm (`simulate_arm`), one
//! implementation of the arm's I/O seam ([`super::arm_io::ArmIo`]).
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
use super::fixed::{unit30, Fx, Joints, Wrench, JOINTS_ZERO};
use super::io::{Gate, MotorLine};

use super::arm_io::{ArmIo, Measures};

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

/// The simulated arm behind the I/O seam.
impl ArmIo for Simulator {
    fn calibrate_at_rest(&mut self, period_ns: u32) {
        *self = Simulator::new(period_ns);
        self.calibrate();
    }

    fn set_user_effort(&mut self, effort: &EffortSample) {
        Simulator::set_user_effort(self, effort);
    }

    fn measures(&mut self, line: &MotorLine) -> Measures {
        Simulator::measures(self, line)
    }

    fn run_period(&mut self, line: &MotorLine) {
        self.simulate_arm(line);
    }

    fn applied_torques(&self) -> Joints {
        Simulator::applied_torques(self)
    }

    fn line_cut(&self) -> bool {
        Simulator::line_cut(self)
    }
}
