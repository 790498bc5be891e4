//! hap_control: `cartesian_control` — impedance virtual coupling between the
//! handle and the client's virtual object, gravity compensation, Jᵀ mapping,
//! wrench and joint-torque saturation, velocity limit, passivity
//! observer/controller, and the coupling wrench returned to the client.
//!
//! Frames: the controller works in the arm base frame. The client's world
//! sees the handle through the indexing offset, the speed factor (client
//! length = `speed_factor` × arm length) and the base frame (`config.base_frame`,
//! world → arm base). Forces go back scaled by `force_factor` (client force =
//! `force_factor` × arm force; torques by `force_factor·speed_factor`).
//!
//! Gains are scheduled with the period so that the joint-space passivity
//! condition `D − (T/2)(K_t J_vᵀJ_v + K_r J_ωᵀJ_ω) − (B_t J_vᵀJ_v + B_r J_ωᵀJ_ω) ≻ 0`
//! holds over the workspace at the nominal period T (main and degraded path
//! alike), with the exact largest mobility of the arm over its workspace.
//! The coupling force reaches the motors through an envelope (soft start,
//! link fade, ramps), a force-first allocation that gives the largest force
//! the motors can in the commanded direction, and a spring that stays
//! anchored to its target (see `Documentation/control.md`).

use super::arm::{self, Kinematics};
use super::config::{CommandType, IndexingMode, ServoConfig};
use super::fixed::{Fx, Joints, Pose, Quat, Twist, Vec3, Wrench, JOINTS_ZERO};
use super::link::PortLedger;
use super::state_model::{LogicalState, PhysicalState};
use super::vp::{alarm, status, VpReceived};

/// Largest translational stiffness offered, N/m (the bound is lower above
/// 100 µs).
pub const K_LIN_NOMINAL: Fx = Fx::from_int(8000);
/// Translational coupling damping, N·s/m.
pub const B_LIN: Fx = Fx::from_ratio(5, 100);
/// Nominal rotational stiffness, N·m/rad (capped by the bound).
pub const K_ROT_NOMINAL: Fx = Fx::from_int(10);
/// Rotational coupling damping, N·m·s/rad.
pub const B_ROT: Fx = Fx::from_ratio(5, 10_000);
/// Fraction of the joint-space bound used by the nominal gains.
pub const BOUND_MARGIN: Fx = Fx::from_ratio(95, 100);
/// Fraction used by [`Gains::at_bound`] (the stiffest gains offered).
pub const BOUND_MARGIN_MAX: Fx = Fx::from_ratio(98, 100);
/// Share of the stiffness budget given to the rotational spring.
pub const ROT_SHARE: Fx = Fx::from_ratio(1, 16);
/// Largest `λ_max(J_v D⁻¹ J_vᵀ)` over the workspace, 1/(N·s/m): the arm's
/// largest mobility at the handle. Sampled maximum 1.376 (f64, 2·10⁵ random
/// poses plus a local ascent from the 50 largest, `tests/safety.rs`); this
/// constant is 1.7 % above it. The trace bound `Σ r_i²/b_i` would be 2.40.
pub const LIN_MOBILITY_MAX: Fx = Fx::from_ratio(140, 100);
/// Joint speeds beyond which the coupling may no longer drive a joint along
/// its motion: the coupling's scale falls linearly from 1 at `BRAKE_START`
/// to 0 at `COUPLING_JOINT_STOP` (`BRAKE_START`·5/4).
pub const COUPLING_JOINT_STOP_NUM: i64 = 5;
pub const COUPLING_JOINT_STOP_DEN: i64 = 4;
/// Handle speed from which the Cartesian brake acts, m/s (free motion below).
pub const V_BRAKE_ONSET: Fx = Fx::ONE;
/// Handle speed at which the coupling no longer pushes along the motion,
/// m/s: its scale falls linearly from 1 at `V_BRAKE_ONSET` to 0 here.
pub const V_COUPLING_STOP: Fx = Fx::from_ratio(15, 10);
/// cos θ from which the speed scale of the coupling's push along a fast
/// motion acts in full (θ ≤ 75.5°); below it the scale fades to 1 at 90°.
pub const PUSH_COS_FULL: Fx = Fx::from_ratio(1, 4);
/// Cartesian brake gain, N·s/m (capped at `½·M_HANDLE_MIN/T`).
pub const B_BRAKE: Fx = Fx::from_int(40);
/// Smallest effective mass of the handle along any direction, kg (the
/// wrist: (I_rotor,5 + m_3 (L3/2)²)/L3² ≈ 0.39 kg; 0.3 with margin): the
/// sampled brake's `B·T/m ≤ ½` never reverses the handle within a period.
pub const M_HANDLE_MIN: Fx = Fx::from_ratio(3, 10);
/// Force-impulse limit: a change of the client's target moves the spring's
/// anchor by at most what changes its force by this much per millisecond,
/// N/ms (OpenHaptics' `HD_SOFTWARE_FORCE_IMPULSE_LIMIT` in the same role).
pub const FORCE_IMPULSE_N_PER_MS: Fx = Fx::from_ratio(15, 10);
/// The anchor may always move this fast, m/s (the speed up to which the
/// coupling drives the handle, `V_COUPLING_STOP`): an object moving at a
/// hand's speed is followed as it moves; only its jumps are spread.
pub const V_ANCHOR_MAX: Fx = V_COUPLING_STOP;
/// The same for the rotational spring, N·m/ms.
pub const TORQUE_IMPULSE_NM_PER_MS: Fx = Fx::from_ratio(5, 100);
/// `virtSaturateTorque` thresholds: force N, torque N·m.
pub const MAX_FORCE: Fx = Fx::from_int(20);
pub const MAX_TORQUE: Fx = Fx::from_ratio(6, 10);
/// Joint speeds beyond which the joint velocity brake acts, rad/s: motor
/// protection only, far above what a hand does at the handle (the handle's
/// speed is bounded by the Cartesian brake, `V_BRAKE_ONSET`).
pub const BRAKE_START: Joints = [
    Fx::from_int(4),
    Fx::from_int(4),
    Fx::from_int(5),
    Fx::from_int(20),
    Fx::from_int(20),
    Fx::from_int(20),
];
/// Elbow angle below which the elbow's soft stop acts, rad: it keeps the
/// arm off its stretched singularity (elbow straight, q3 = 0). Past it,
/// the elbow can bend the other way down to its end stop (`arm::Q_MIN`),
/// and there a spring pulling the handle toward the base bends the elbow
/// further into that stop instead of back: the wall is lost.
pub const ELBOW_SOFT_STOP: Fx = Fx::from_ratio(15, 100);
/// Share of the elbow's viscous damping `b_3` the soft stop's sampled
/// spring may use: `K_e = share·b_3 / (T_e/2)` (`effective_half_period`),
/// so `(T_e/2)·K_e ≤ share·b_3` (Colgate's condition for a one-sided
/// sampled spring at the joint), capped at `ELBOW_STOP_K_MAX`. The
/// coupling's stiffest gains use `BOUND_MARGIN_MAX` (98 %) of the damping:
/// together 99.5 % (`Documentation/control.md`).
pub const ELBOW_STOP_SHARE: Fx = Fx::from_ratio(15, 1000);
/// Elbow speed (bending back, rad/s) at which the soft stop's push has
/// faded to nothing.
pub const ELBOW_STOP_RELEASE: Fx = Fx::from_int(2);
/// Largest torque of the elbow's soft stop, N·m. With it, the fidelity
/// bench's push past full reach (WORK_Q outward, 73.5 N) finds the wall
/// again after 191–215 ms; uncapped (up to 11 N·m) the stop threw the
/// handle to 3.6 m/s when a 25 N push folded the arm over its base.
pub const ELBOW_STOP_TORQUE_MAX: Fx = Fx::from_int(5);
/// Largest elbow soft-stop stiffness, N·m/rad.
pub const ELBOW_STOP_K_MAX: Fx = Fx::from_int(100);

/// The elbow soft stop's stiffness for `period`, N·m/rad.
pub fn elbow_stop_gain(period: Fx) -> Fx {
    let b3 = arm::DAMPING[2];
    ELBOW_STOP_SHARE
        .mul_sat(b3)
        .div_sat(effective_half_period(period))
        .min(ELBOW_STOP_K_MAX)
}

/// Brake gain as a fraction of `I_rotor,i / T` (`B_i·T/I_i ≤ ½`: the sampled
/// brake never reverses a joint within one period).
pub const BRAKE_GAIN_FRACTION: Fx = Fx::HALF;
/// Observer energy below which the passivity controller acts, J (−2^-20 J:
/// fixed-point rounding of the observer stays above it).
pub const PO_TOLERANCE: Fx = Fx(-(1 << 12));
/// Passivity controller damping caps, N·s/m and N·m·s/rad.
pub const PC_ALPHA_MAX: Fx = Fx::from_int(5);
pub const PC_ALPHA_ROT_MAX: Fx = Fx::from_ratio(2, 100);
/// The controller grants the client energy every this many cycles (its
/// grants travel in `answer_twist`, sent every `proto_synchro::TWIST_EVERY`).
pub const LINK_GRANT_EVERY: u32 = 4;
/// Coupling force ramp: the envelope goes from 0 to 1 (and 1 to 0) in
/// `RAMP_US` µs at the most (slew ≤ `MAX_FORCE`/`RAMP_US` = 0.4 N/ms). It is
/// the link watchdog's fade slope, so the envelope follows the fade exactly.
pub const RAMP_US: u64 = 50_000;

/// λ_max bound of `J_v D⁻¹ J_vᵀ` over the workspace, 1/(N·s/m):
/// [`LIN_MOBILITY_MAX`].
pub fn lin_mobility_bound() -> Fx {
    LIN_MOBILITY_MAX
}

/// The trace bound `Σ r_i²/b_i` of the same (`r_i` = `arm::LEVER_MAX`),
/// 2.40: kept to show how much the exact maximum gains.
pub fn lin_mobility_trace_bound() -> Fx {
    let mut a = Fx::ZERO;
    for (b, r) in arm::DAMPING.iter().zip(arm::LEVER_MAX.iter()) {
        a = a.add_sat(r.mul_sat(*r).div_sat(*b));
    }
    a.add_sat(Fx(64))
}

/// λ_max bound of `J_ω D⁻¹ J_ωᵀ` over the workspace, 1/(N·m·s/rad):
/// joints 2 and 3 share one axis, the wrist pitch axis is orthogonal to the
/// two wrist roll axes, so `λ_max ≤ 1/b1 + (1/b2 + 1/b3) + max(1/b5, 1/b4 + 1/b6)`.
pub fn rot_mobility_bound() -> Fx {
    let inv = |i: usize| match arm::DAMPING.get(i) {
        Some(b) if b.0 > 0 => Fx::ONE.div_sat(*b),
        _ => Fx::MAX,
    };
    let wrist = inv(4).max(inv(3).add_sat(inv(5)));
    inv(0)
        .add_sat(inv(1))
        .add_sat(inv(2))
        .add_sat(wrist)
        .add_sat(Fx(64))
}

/// The period the gains are scheduled at, halved (`T_e/2`): T up to 1 ms,
/// then rising linearly to 2T at 2 ms and beyond. At long periods the joint
/// speed varies within a period, and the observer's proven dissipation
/// (`Σ b_i Δq_i²/T`, Cauchy–Schwarz) falls short of what the dampers take:
/// measured, the campaign's motor-side ledger went below 0 at 10 ms with
/// gains at T (seeds 32, 33, 1003), and holds with them at 2T.
pub fn effective_half_period(period: Fx) -> Fx {
    let t = period.max(Fx(1));
    // Compared in the representation periods arrive in (`Fx::from_ns`).
    let ms = Fx::from_ns(1_000_000);
    let extra = t.sub_sat(ms).max(Fx::ZERO).min(ms);
    // T·(1 + (T − 1 ms)/1 ms) for 1 ms ≤ T ≤ 2 ms, 2T beyond.
    let factor = Fx::ONE.add_sat(extra.div_sat(ms));
    t.mul_sat(factor).half().max(Fx(1))
}

/// Coupling gains for one servo period.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Gains {
    /// N/m
    pub k_lin: Fx,
    /// N·s/m
    pub b_lin: Fx,
    /// N·m/rad
    pub k_rot: Fx,
    /// N·m·s/rad
    pub b_rot: Fx,
}

impl Gains {
    pub const ZERO: Gains = Gains {
        k_lin: Fx::ZERO,
        b_lin: Fx::ZERO,
        k_rot: Fx::ZERO,
        b_rot: Fx::ZERO,
    };

    /// Gains using `margin` of the joint-space bound at the nominal period
    /// T (the same gains on the main and the degraded path; a late cycle is
    /// the observer's and the passivity controller's, control.md):
    /// `(T/2·K_t + B_t)·a + (T/2·K_r + B_r)·c ≤ margin`, `a`, `c` the
    /// mobility bounds; `K_r` takes `ROT_SHARE` of the stiffness budget.
    pub fn scheduled(period: Fx, margin: Fx) -> Gains {
        let a = lin_mobility_bound();
        let c = rot_mobility_bound();
        let slack = margin
            .sub_sat(B_LIN.mul_sat(a))
            .sub_sat(B_ROT.mul_sat(c))
            .max(Fx::ZERO);
        let t = effective_half_period(period);
        let k_rot = K_ROT_NOMINAL
            .min(ROT_SHARE.mul_sat(slack).div_sat(t.mul_sat(c)))
            .max(Fx::ZERO);
        let left = slack.sub_sat(t.mul_sat(k_rot).mul_sat(c)).max(Fx::ZERO);
        let k_lin = K_LIN_NOMINAL.min(left.div_sat(t.mul_sat(a))).max(Fx::ZERO);
        Gains {
            k_lin,
            b_lin: B_LIN,
            k_rot,
            b_rot: B_ROT,
        }
    }

    /// Nominal gains for `period` (s): [`Gains::scheduled`] at `BOUND_MARGIN`.
    pub fn for_period(period: Fx) -> Gains {
        Gains::scheduled(period, BOUND_MARGIN)
    }

    /// The stiffest gains offered (margin `BOUND_MARGIN_MAX`); every gain
    /// the controller uses is clamped to these.
    pub fn at_bound(period: Fx) -> Gains {
        Gains::scheduled(period, BOUND_MARGIN_MAX)
    }

    /// Each gain in `[0, bound]`.
    pub fn clamped(&self, bound: &Gains) -> Gains {
        let c = |v: Fx, hi: Fx| v.max(Fx::ZERO).min(hi);
        Gains {
            k_lin: c(self.k_lin, bound.k_lin),
            b_lin: c(self.b_lin, bound.b_lin),
            k_rot: c(self.k_rot, bound.k_rot),
            b_rot: c(self.b_rot, bound.b_rot),
        }
    }
}

/// Cartesian brake gain for `period`: `min(B_BRAKE, ½·M_HANDLE_MIN/T)`,
/// N·s/m.
pub fn cartesian_brake_gain(period: Fx) -> Fx {
    let t = period.max(Fx(1));
    B_BRAKE.min(M_HANDLE_MIN.half().div_sat(t))
}

/// The slip is taken back once every this many cycles at short periods
/// (the energies it costs take a few roots); every cycle from
/// `TAKEBACK_EVERY_CYCLE_FROM` on, so that one take-back step stays one ramp
/// step (0.4 N at 1 ms) where a cycle is long enough to feel.
const TAKEBACK_EVERY: u32 = 4;

/// Period from which the slip is taken back every cycle (500 µs).
const TAKEBACK_EVERY_CYCLE_FROM: Fx = Fx::from_ratio(1, 2000);

/// Cycles the force limit holds after it was lowered: 5 ms worth
/// (`RAMP_US`/10), from the ramp step `T/RAMP_US`.
fn limit_hold_cycles(ramp_step: Fx) -> u32 {
    // 1/(10·ramp_step), at least 1.
    let n = Fx::ONE
        .div_sat(ramp_step.mul_int(10).max(Fx(1)))
        .floor_to_i64();
    u32::try_from(n).unwrap_or(1).max(1)
}

/// The coupling's scale for a speed `v` between `start` (1) and `stop` (0).
fn speed_scale(v: Fx, start: Fx, stop: Fx) -> Fx {
    if v <= start {
        return Fx::ONE;
    }
    ratio_le1(stop.sub_sat(v).max(Fx::ZERO), stop.sub_sat(start))
}

/// Velocity brake gains for `period`: `B_i = ½·I_rotor,i/T`, N·m·s/rad.
pub fn brake_gains(period: Fx) -> Joints {
    let t = period.max(Fx(1));
    arm::ROTOR_INERTIA.map(|i| BRAKE_GAIN_FRACTION.mul_sat(i).div_sat(t))
}

/// The controller's memory (filters, observer, indexing, envelope).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Controller {
    /// Requested gains; every cycle uses them clamped to `bound`.
    pub gains: Gains,
    /// Gravity compensation on (default); tests switch it off.
    pub gravity_compensation: bool,
    /// Passivity controller on (default).
    pub passivity_control: bool,
    period: Fx,
    bound: Gains,
    brake: Joints,
    /// Envelope step per cycle: `T / RAMP_US`.
    ramp_step: Fx,
    /// Link watchdog gain for this cycle, [0, 1] (set by the cycle).
    link_gain: Fx,
    /// Coupling force envelope, [0, 1]: the force that reaches the motors is
    /// at most `envelope · MAX_FORCE`.
    envelope: Fx,
    /// Passivity observer: energy that entered the coupling plus the arm's
    /// proven viscous dissipation, J (≥ 0 when passive).
    po_energy: Fx,
    coupled: bool,
    /// Spring slip (translation m, rotation rad): see `cartesian_control`.
    slip: Vec3,
    slip_rot: Vec3,
    /// The coupling's joint torques the motors got last cycle.
    prev_tau_c: Joints,
    /// The gains used last cycle.
    prev_k: Gains,
    prev_target: Pose,
    prev_wrench: Wrench,
    /// The spring's force saturation, N (before the envelope): `MAX_FORCE`,
    /// or the force the motors could give along the spring when that was
    /// less (their capacity at the pose). Lowered at once to what was applied;
    /// raised back no faster than the force ramp, and only with energy the
    /// observer holds.
    force_limit: Fx,
    /// Cycles left before the force limit may rise again after it was
    /// lowered (`limit_hold_cycles`).
    limit_hold: u32,
    /// Counts cycles for the slip's take-back (every `takeback_every`).
    takeback_phase: u32,
    /// Cycles between two take-back steps (`TAKEBACK_EVERY`, or 1 from
    /// `TAKEBACK_EVERY_CYCLE_FROM`).
    takeback_every: u32,
    prev_q: Joints,
    /// The spring's anchor (raw arm frame): the client's target, reached
    /// within the force-impulse limit; held while the envelope ramps down.
    held_target: Pose,
    /// Largest move of the anchor per cycle as force and torque of the
    /// spring: `FORCE_IMPULSE_N_PER_MS`·T, `TORQUE_IMPULSE_NM_PER_MS`·T.
    impulse_force: Fx,
    impulse_torque: Fx,
    /// Cartesian brake gain for the period, N·s/m.
    brake_lin: Fx,
    /// The magnitude of the Cartesian brake's force the motors gave the
    /// handle last cycle, N (0 while they were not enabled): the brake
    /// engages no faster than the force ramp from it.
    brake_applied: Fx,
    /// `elbow_stop_gain` for the period, N·m/rad.
    elbow_k: Fx,
    /// Whether the elbow soft stop pushed in the last cycle (the observer
    /// then leaves its share of the elbow's damping to it).
    elbow_pushed: bool,
    /// The elbow soft stop's scale in [0, 1]: rises only while the elbow is
    /// outside the stop's range.
    elbow_gate: Fx,
    /// The elbow soft stop's share of this cycle's elbow torque, N·m.
    elbow_torque: Fx,
    /// `V_ANCHOR_MAX`·T, m.
    anchor_step: Fx,
    /// Indexing offset: indexed handle = (offset_pos + p, offset_rot ⊗ q).
    offset_pos: Vec3,
    offset_rot: Quat,
    indexing: bool,
    frozen: Pose,
    /// The controller's port on the link (`link`): energy the handle put
    /// into the coupling and the coupling gave to the handle, and the
    /// client's total as received.
    link: PortLedger,
    /// Cycles on which the link's passivity controller took force off.
    link_limited: u64,
    /// `f·d + τ·e` of the spring at the envelope, J: twice its energy
    /// when linear (the reservoir keeps a quarter of it).
    link_keep: Fx,
    /// Counts the link-passive coupled cycles (grants every
    /// `LINK_GRANT_EVERY`).
    link_phase: u32,
}

/// What `cartesian_control` produces.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ControlOutput {
    /// Joint torques to command (within the motor limits), N·m:
    /// `fixed_torques + Jᵀ·handle_wrench`.
    pub joint_torques: Joints,
    /// Gravity compensation plus velocity brake, N·m (the part of
    /// `joint_torques` that is not the coupling).
    pub fixed_torques: Joints,
    /// Coupling wrench applied to the handle through the motors (after the
    /// envelope, saturation, PC and the torque-vector scaling), base frame.
    pub handle_wrench: Wrench,
    /// Wrench for the client's virtual object, client frame and units.
    pub coupling_wrench: Wrench,
    /// Handle pose / twist in the client's frame (indexed, scaled).
    pub handle_pose_client: Pose,
    pub handle_twist_client: Twist,
    /// Status bits added by control (`COUPLED`).
    pub status: u32,
    /// Alarms raised this cycle.
    pub alarms: u32,
    /// Passivity observer energy after this cycle, J.
    pub po_energy: Fx,
    /// Coupling envelope this cycle, [0, 1].
    pub envelope: Fx,
    /// Scale applied to the coupling's joint torques to fit the motor
    /// limits (1: none), [0, 1].
    pub torque_scale: Fx,
    /// The allocation's scale of the force (1: all of it reached the
    /// motors) and the speed scale (1: no fast motion withheld it), [0, 1].
    pub force_scale: Fx,
    pub speed_scale: Fx,
    /// The spring–damper wrench after the saturation, at last cycle's
    /// envelope and slip, before the passivity controller and the torque
    /// scaling: the force the target port sees right after the client's
    /// step, before the envelope moves (what the observer integrates).
    pub spring_wrench: Wrench,
    /// The Cartesian brake's force on the handle commanded this cycle
    /// (scaled to the motors' room the coupling left; zero below
    /// `V_BRAKE_ONSET`), base frame, N: with `handle_wrench.force`, the
    /// Cartesian force the motors give the handle beyond gravity
    /// compensation while they are enabled (the joint brakes and the elbow's
    /// soft stop aside; the line applies nothing while they are not).
    pub brake_force: Vec3,
}

impl Controller {
    pub const fn new() -> Controller {
        Controller {
            gains: Gains::ZERO,
            gravity_compensation: true,
            passivity_control: true,
            period: Fx::ZERO,
            bound: Gains::ZERO,
            brake: JOINTS_ZERO,
            ramp_step: Fx::ONE,
            link_gain: Fx::ONE,
            envelope: Fx::ZERO,
            po_energy: Fx::ZERO,
            coupled: false,
            slip: Vec3::ZERO,
            slip_rot: Vec3::ZERO,
            prev_tau_c: JOINTS_ZERO,
            prev_k: Gains::ZERO,
            prev_target: Pose::IDENTITY,
            prev_wrench: Wrench::ZERO,
            force_limit: MAX_FORCE,
            limit_hold: 0,
            takeback_phase: 0,
            takeback_every: TAKEBACK_EVERY,
            prev_q: JOINTS_ZERO,
            held_target: Pose::IDENTITY,
            impulse_force: Fx::ZERO,
            impulse_torque: Fx::ZERO,
            brake_lin: Fx::ZERO,
            brake_applied: Fx::ZERO,
            elbow_k: Fx::ZERO,
            elbow_pushed: false,
            elbow_gate: Fx::ZERO,
            elbow_torque: Fx::ZERO,
            anchor_step: Fx::ZERO,
            offset_pos: Vec3::ZERO,
            offset_rot: Quat::IDENTITY,
            indexing: false,
            frozen: Pose::IDENTITY,
            link: PortLedger::new(),
            link_limited: 0,
            link_keep: Fx::ZERO,
            link_phase: 0,
        }
    }

    /// Initialise filters and gains for a period (s).
    pub fn init(&mut self, period: Fx) {
        let gc = self.gravity_compensation;
        let pc = self.passivity_control;
        *self = Controller::new();
        self.gravity_compensation = gc;
        self.passivity_control = pc;
        self.period = period;
        self.gains = Gains::for_period(period);
        self.bound = Gains::at_bound(period);
        self.brake = brake_gains(period);
        // T / RAMP: Q32.32 of (period_s · 10^6 / RAMP_US).
        let step = period
            .mul_int(1_000_000)
            .div_sat(Fx::from_int(RAMP_US as i32));
        self.ramp_step = step.max(Fx(1)).min(Fx::ONE);
        let ms = period.mul_int(1000);
        self.impulse_force = FORCE_IMPULSE_N_PER_MS.mul_sat(ms);
        self.impulse_torque = TORQUE_IMPULSE_NM_PER_MS.mul_sat(ms);
        self.brake_lin = cartesian_brake_gain(period);
        self.brake_applied = Fx::ZERO;
        self.elbow_k = elbow_stop_gain(period);
        self.anchor_step = V_ANCHOR_MAX.mul_sat(period);
        self.takeback_every = if period >= TAKEBACK_EVERY_CYCLE_FROM {
            1
        } else {
            TAKEBACK_EVERY
        };
    }

    pub fn po_energy(&self) -> Fx {
        self.po_energy
    }

    /// The controller's port ledger on the link (`link`).
    pub const fn link(&self) -> &PortLedger {
        &self.link
    }

    /// Cycles on which the link's passivity controller took force off.
    pub const fn link_limited_cycles(&self) -> u64 {
        self.link_limited
    }

    /// Whether the elbow soft stop pushed in the last cycle
    /// ([`ELBOW_SOFT_STOP`]).
    pub fn elbow_pushed(&self) -> bool {
        self.elbow_pushed
    }

    /// The elbow soft stop's share of the last cycle's elbow torque (after
    /// the motor limit), N·m.
    pub fn elbow_torque(&self) -> Fx {
        self.elbow_torque
    }

    /// The elbow soft stop's stiffness, N·m/rad ([`elbow_stop_gain`]).
    pub fn elbow_gain(&self) -> Fx {
        self.elbow_k
    }

    pub fn coupled(&self) -> bool {
        self.coupled
    }

    /// The target the coupling pulls toward (raw arm frame; held while the
    /// envelope ramps down).
    pub fn target(&self) -> Pose {
        self.held_target
    }

    /// The spring's force saturation, N (before the envelope).
    pub fn force_limit(&self) -> Fx {
        self.force_limit
    }

    /// The spring's slip (translation m, rotation rad).
    pub fn slip(&self) -> (Vec3, Vec3) {
        (self.slip, self.slip_rot)
    }

    /// The coupling envelope, [0, 1].
    pub fn envelope(&self) -> Fx {
        self.envelope
    }

    /// Envelope change per cycle (`T / RAMP_US`).
    pub fn ramp_step(&self) -> Fx {
        self.ramp_step
    }

    /// The gains in use: `gains` clamped to the bound.
    pub fn effective_gains(&self) -> Gains {
        self.gains.clamped(&self.bound)
    }

    /// The link watchdog's gain for the coming cycle (clamped to [0, 1]).
    pub fn set_link_gain(&mut self, g: Fx) {
        self.link_gain = g.max(Fx::ZERO).min(Fx::ONE);
    }

    /// Reset the indexing offset (e.g. new session).
    pub fn reset_indexing(&mut self) {
        self.offset_pos = Vec3::ZERO;
        self.offset_rot = Quat::IDENTITY;
        self.indexing = false;
    }
}

impl Default for ControlOutput {
    fn default() -> Self {
        ControlOutput {
            joint_torques: JOINTS_ZERO,
            fixed_torques: JOINTS_ZERO,
            handle_wrench: Wrench::ZERO,
            coupling_wrench: Wrench::ZERO,
            handle_pose_client: Pose::IDENTITY,
            handle_twist_client: Twist::ZERO,
            status: 0,
            alarms: 0,
            po_energy: Fx::ZERO,
            envelope: Fx::ZERO,
            torque_scale: Fx::ONE,
            force_scale: Fx::ONE,
            speed_scale: Fx::ONE,
            spring_wrench: Wrench::ZERO,
            brake_force: Vec3::ZERO,
        }
    }
}

impl Default for Controller {
    fn default() -> Self {
        Controller::new()
    }
}

/// Stored energy of the coupling spring saturated at `f_max` for a linear
/// error `d` and rotational error `e`: a function of the stretch, whose
/// force never exceeds `f_max`, so the motors can give all of it back.
fn spring_energy(g: &Gains, f_max: Fx, d: Vec3, e: Vec3) -> Fx {
    let rot = g.k_rot.mul_sat(e.norm_sq()).half();
    lin_spring_energy(g.k_lin, f_max, d.norm()).add_sat(rot)
}

/// The translational part of [`spring_energy`] for a stretch of length `dn`.
fn lin_spring_energy(k: Fx, f_max: Fx, dn: Fx) -> Fx {
    let kd = k.mul_sat(dn);
    if kd > f_max && k.0 > 0 {
        // F_max·(|d| − F_max/(2K))
        f_max.mul_sat(dn.sub_sat(f_max.div_sat(k.mul_sat(Fx::TWO))))
    } else {
        kd.mul_sat(dn).half()
    }
}

/// Per-component bounds of the coupling errors: position m, speed m/s,
/// angular speed rad/s (far beyond the arm's reach and speeds).
pub const D_CLAMP: Fx = Fx::from_int(4);
const V_CLAMP: Fx = Fx::from_int(100);
const W_CLAMP: Fx = Fx::from_int(1000);

/// `num / den` in [0, 1] (1 when `den` is 0).
fn ratio_le1(num: Fx, den: Fx) -> Fx {
    if den.0 <= 0 {
        return Fx::ONE;
    }
    num.div_sat(den).max(Fx::ZERO).min(Fx::ONE)
}

fn clamp_vec(v: Vec3, lim: Fx) -> Vec3 {
    Vec3::new(v.x.clamp_abs(lim), v.y.clamp_abs(lim), v.z.clamp_abs(lim))
}

/// Largest `s` in [0, 1] with `|base + s·add| ≤ lim` (given `|base| ≤ lim`).
fn fit_scale(base: Fx, add: Fx, lim: Fx) -> Fx {
    let sum = base.add_sat(add);
    if sum.abs() <= lim || add.0 == 0 {
        return Fx::ONE;
    }
    let room = if add.0 > 0 {
        lim.sub_sat(base)
    } else {
        lim.add_sat(base)
    };
    room.max(Fx::ZERO).div_sat(add.abs()).min(Fx::ONE)
}

/// The link's passivity controller (see `cartesian_control`): takes off
/// `w` the part of its push along the handle's motion (force first, then
/// torque) that would give the handle more than `ctrl.link`'s budget over
/// one period.
///
/// Returns the port's energy `w·(v_h, ω_h)·T` when it left `w` as it was
/// (the common case: the caller records it without computing it again).
fn link_limit(ctrl: &mut Controller, w: &mut Wrench, v_h: Vec3, w_h: Vec3) -> Option<Fx> {
    let t = ctrl.period;
    let e_f = w.force.dot(v_h).mul_sat(t);
    let e_t = w.torque.dot(w_h).mul_sat(t);
    let (p_f, p_t) = (e_f.max(Fx::ZERO), e_t.max(Fx::ZERO));
    let mut over = p_f
        .add_sat(p_t)
        .sub_sat(ctrl.link.reservoir().max(Fx::ZERO));
    if over.0 <= 0 {
        return Some(e_f.add_sat(e_t));
    }
    ctrl.link_limited = ctrl.link_limited.saturating_add(1);
    // A hair more than the excess, for the rounding of the products.
    over = over.add_sat(Fx(over.0 >> 10)).add_sat(Fx(16));
    let take_f = over.min(p_f);
    w.force = w.force.sub(along(v_h, take_f, t));
    let take_t = over.sub_sat(take_f).min(p_t);
    w.torque = w.torque.sub(along(w_h, take_t, t));
    None
}

/// The vector along `v` whose power on `v` over `t` seconds is `e` (J):
/// `e/(t·|v|)·v̂`. Zero for `e ≤ 0` or `v` = 0. (Through the unit vector:
/// `t·|v|²` has too few bits at low speeds.)
pub fn along(v: Vec3, e: Fx, t: Fx) -> Vec3 {
    if e.0 <= 0 || t.0 <= 0 {
        return Vec3::ZERO;
    }
    let n = v.norm();
    if n.0 <= 0 {
        return Vec3::ZERO;
    }
    v.scale(n.recip()).scale(e.div_sat(t).div_sat(n))
}

/// `cartesian_control`.
#[allow(clippy::too_many_lines)]
#[inline(never)]
pub fn cartesian_control(
    ctrl: &mut Controller,
    ls: &LogicalState,
    ps: &PhysicalState,
    config: &ServoConfig,
    vpr: &VpReceived,
) -> ControlOutput {
    let kin: &Kinematics = &ps.kin;
    let p_h = ps.handle.position;
    let q_h = ps.handle.orientation;
    let v_h = ps.twist.linear;
    let w_h = ps.twist.angular;
    let mut alarms = 0u32;
    let mut st = 0u32;

    // The client's link energy grants (`link`): a session starts with an
    // invalid VPr, and both ends' totals with it.
    if !vpr.valid {
        ctrl.link = PortLedger::new();
    } else if vpr.link_energy {
        ctrl.link.peer.receive(vpr.client_time_us);
    }

    let sf = if config.speed_factor.0 > 0 {
        config.speed_factor
    } else {
        Fx::ONE
    };
    let inv_sf = sf.recip();
    let base = &config.base_frame;
    let base_inv = base.inverse();

    // ---- Indexing (button 1): freeze the indexed handle while held.
    let trans_only = matches!(
        config.indexing_mode,
        IndexingMode::Trans | IndexingMode::TransForceFeedbackInhibition
    );
    if ls.indexing {
        let cur = Pose {
            position: p_h.add(ctrl.offset_pos),
            orientation: ctrl.offset_rot.mul(&q_h),
        };
        if !ctrl.indexing {
            ctrl.frozen = cur;
        }
        ctrl.offset_pos = ctrl.frozen.position.sub(p_h);
        if !trans_only {
            ctrl.offset_rot = ctrl.frozen.orientation.mul(&q_h.conjugate()).renormalize();
        }
    }
    ctrl.indexing = ls.indexing;
    let ff_inhibited = ls.indexing
        && matches!(
            config.indexing_mode,
            IndexingMode::AllForceFeedbackInhibition | IndexingMode::TransForceFeedbackInhibition
        );

    // ---- Handle seen by the client.
    let idx_pose = Pose {
        position: p_h.add(ctrl.offset_pos),
        orientation: ctrl.offset_rot.mul(&q_h),
    };
    let scaled = Pose {
        position: idx_pose.position.scale(sf),
        orientation: idx_pose.orientation,
    };
    let handle_pose_client = base.compose(&scaled);
    let handle_twist_client = Twist {
        linear: base
            .orientation
            .rotate(ctrl.offset_rot.rotate(v_h))
            .scale(sf),
        angular: base.orientation.rotate(ctrl.offset_rot.rotate(w_h)),
    };

    // ---- Coupling.
    // The motors can push (power, gate, dead-man); the client asks for a
    // coupling (valid VPr, command type, no force-feedback inhibition).
    let can_push = ls.motors_enabled && ls.dead_man;
    let want_coupling = can_push
        && vpr.valid
        && !ff_inhibited
        && match config.command_type {
            CommandType::None => false,
            CommandType::Impedance => true,
            CommandType::VirtMech => config.attached_object.is_some(),
        };
    // One gain set for the main and the degraded path (scheduled at 2T):
    // switching path changes nothing in the coupling. Whatever was asked,
    // the gains stay inside the bound.
    let mut g = ctrl.gains.clamped(&ctrl.bound);
    if config.command_type == CommandType::VirtMech {
        // Mass-aware cap so the client's explicit integration stays stable:
        // K ≤ m / ts² (only ever lowers K).
        if let Some(obj) = config.attached_object {
            let ts = config.time_step;
            if ts.0 > 0 {
                let cap = obj.mass.max(Fx::ZERO).div_sat(ts.mul_sat(ts));
                g.k_lin = g.k_lin.min(cap);
            }
        }
    }

    // Envelope: rises by at most `ramp_step` per cycle and never above the
    // link gain while the client is wanted; falls by `ramp_step` per cycle
    // (on the held target) when it is not; 0 at once when the motors cannot
    // push or nobody holds the handle.
    let env_prev = ctrl.envelope;
    let env = if !can_push {
        Fx::ZERO
    } else if want_coupling {
        env_prev.add_sat(ctrl.ramp_step).min(ctrl.link_gain)
    } else if ctrl.coupled {
        env_prev
            .sub_sat(ctrl.ramp_step)
            .max(Fx::ZERO)
            .min(ctrl.link_gain)
    } else {
        Fx::ZERO
    };
    ctrl.envelope = env;

    let mut handle_wrench = Wrench::ZERO;
    // The link port's energy as the limiter computed it, with its wrench.
    let mut link_port: Option<(Fx, Wrench)> = None;
    let mut target = ctrl.held_target;
    // (error, its slipped part) of an active spring; saturation factors.
    let mut spring: Option<(Vec3, Vec3, Vec3, Vec3, Vec3)> = None;
    let mut spring_wrench = Wrench::ZERO;
    let mut t_v = Vec3::ZERO;
    let mut t_w = Vec3::ZERO;
    let active = env.0 > 0 && (want_coupling || ctrl.coupled);
    if want_coupling {
        // Target in the indexed arm frame, then in the raw arm frame.
        let t_idx = base_inv.compose(&vpr.pose);
        let t_pos = t_idx.position.scale(inv_sf).sub(ctrl.offset_pos);
        let t_rot = ctrl.offset_rot.conjugate().mul(&t_idx.orientation);
        let back = ctrl.offset_rot.conjugate().mul(&base_inv.orientation);
        t_v = back.rotate(vpr.twist.linear).scale(inv_sf);
        t_w = back.rotate(vpr.twist.angular);
        target = Pose {
            position: t_pos,
            orientation: t_rot,
        };
        if ctrl.coupled && env_prev.0 > 0 && config.command_type != CommandType::VirtMech {
            // Force-impulse limit: the anchor follows the client's target by
            // at most what changes the spring's force by `impulse_force`
            // (torque by `impulse_torque`) this cycle. The spring stays a
            // function of the handle's pose around its anchor; the anchor's
            // move is the target port's step (observer, below).
            let a = ctrl.held_target;
            // At least `V_ANCHOR_MAX`·T, so that an object moving as fast
            // as the coupling lets the handle go is followed as it moves.
            let step_lin = if g.k_lin.0 > 0 {
                ctrl.impulse_force.div_sat(g.k_lin).max(ctrl.anchor_step)
            } else {
                D_CLAMP
            };
            let dp = clamp_vec(t_pos.sub(a.position), D_CLAMP)
                .clamp_norm(step_lin)
                .0;
            let step_rot = if g.k_rot.0 > 0 {
                ctrl.impulse_torque.div_sat(g.k_rot)
            } else {
                Fx::TWO
            };
            let orientation = if t_rot == a.orientation {
                t_rot
            } else {
                let e = t_rot.error_vector(&a.orientation);
                let (e, clamped) = e.clamp_norm(step_rot);
                if clamped {
                    let h = e.half();
                    Quat::new(h.x, h.y, h.z, Fx::ONE)
                        .mul(&a.orientation)
                        .renormalize()
                } else {
                    t_rot
                }
            };
            target = Pose {
                position: a.position.add(dp),
                orientation,
            };
        }
        ctrl.held_target = target;
    }
    if active {
        let t_pos = target.position;
        let t_rot = target.orientation;
        // Errors bounded before the products (a hostile target far away
        // saturates the force anyway; this keeps every product in range).
        let d = clamp_vec(t_pos.sub(p_h), D_CLAMP);
        // |e| ≤ 2 for unit quaternions; a client's non-unit frame cannot
        // make it larger.
        let e = clamp_vec(t_rot.error_vector(&q_h), Fx::TWO);
        if !ctrl.coupled {
            ctrl.slip = Vec3::ZERO;
            ctrl.slip_rot = Vec3::ZERO;
            ctrl.force_limit = MAX_FORCE;
        }
        let f_lim = ctrl.force_limit;
        // The spring acts on the error less its slip (see below).
        let mut d_eff = d.sub(ctrl.slip);
        let mut e_eff = e.sub(ctrl.slip_rot);
        if ctrl.coupled && (g.k_lin > ctrl.prev_k.k_lin || g.k_rot > ctrl.prev_k.k_rot) {
            // A stiffer spring (command type, attached object, time step
            // changed) keeps the force it had: the anchor slips to K₀/K of
            // the stretch, so no energy enters with the new gains.
            let kl = ratio_le1(ctrl.prev_k.k_lin, g.k_lin);
            let kr = ratio_le1(ctrl.prev_k.k_rot, g.k_rot);
            d_eff = d_eff.scale(kl);
            e_eff = e_eff.scale(kr);
            ctrl.slip = d.sub(d_eff);
            ctrl.slip_rot = e.sub(e_eff);
        }
        ctrl.prev_k = g;
        let dv = clamp_vec(t_v.sub(v_h), V_CLAMP);
        let dw = clamp_vec(t_w.sub(w_h), W_CLAMP);
        // The spring–damper wrench of a stretch, saturated at the force
        // limit (and whether it saturated).
        let spring_at = |d_eff: Vec3, e_eff: Vec3| {
            Wrench {
                force: d_eff.scale_add(g.k_lin, dv, g.b_lin),
                torque: e_eff.scale_add(g.k_rot, dw, g.b_rot),
            }
            .saturate(f_lim, MAX_TORQUE)
        };
        let mut sw = spring_at(d_eff, e_eff);
        // The spring right after the client's step, before the envelope
        // moves: the end of the target port's trapezoid. The step is taken
        // on the spring of the last period (its envelope, its slip); the
        // envelope's change is paid (or slipped, or dissipated) apart.
        let w_step = Wrench {
            force: sw.0.force.scale(env_prev),
            torque: sw.0.torque.scale(env_prev),
        };
        if !ctrl.coupled {
            // Start of coupling: the observer starts with the spring's energy.
            ctrl.po_energy = spring_energy(&g, f_lim, d_eff, e_eff);
            ctrl.prev_wrench = Wrench::ZERO;
            ctrl.prev_tau_c = JOINTS_ZERO;
        } else {
            // Passivity observer: energy that entered the coupling during the
            // last period through both ports, plus the viscous dissipation
            // of the arm's joints that the encoders prove (Cauchy–Schwarz:
            // ∫q̇² dt ≥ Δq²/T). Handle port: the coupling's joint torques
            // the motors held over the period (ZOH), times the joint
            // displacement: the exact work at the motors. Target port: the
            // client's pose is a sampled signal, so the spring's change on
            // its step is the trapezoid of the wrench before and after it.
            // The step as the spring sees it: the change of the (bounded)
            // error it made, so a target beyond `D_CLAMP` moves no energy
            // the spring does not store or give back.
            let dp_t = d.sub(clamp_vec(ctrl.prev_target.position.sub(p_h), D_CLAMP));
            // (The same target orientation: the same error as `e`, no step,
            // and a zero term in the sum.)
            let dth_t = if ctrl.prev_target.orientation == t_rot {
                Vec3::ZERO
            } else {
                e.sub(clamp_vec(
                    ctrl.prev_target.orientation.error_vector(&q_h),
                    Fx::TWO,
                ))
            };
            let pw = ctrl.prev_wrench;
            let avg_f = pw.force.add(w_step.force).half();
            let avg_t = pw.torque.add(w_step.torque).half();
            let mut de = avg_f.dot(dp_t);
            if dth_t != Vec3::ZERO {
                de = de.add_sat(avg_t.dot(dth_t));
            }
            for ((q, q0), t) in
                ps.q.iter()
                    .zip(ctrl.prev_q.iter())
                    .zip(ctrl.prev_tau_c.iter())
            {
                de = de.sub_sat(t.mul_sat(q.sub_sat(*q0)));
            }
            if ctrl.period.0 > 0 {
                for ((q, q0), b) in ps.q.iter().zip(ctrl.prev_q.iter()).zip(arm::DAMPING.iter()) {
                    let dq = q.sub_sat(*q0);
                    de = de.add_sat(b.mul_sat(dq.mul_sat(dq)).div_sat(ctrl.period));
                }
                if ctrl.elbow_pushed {
                    // The elbow soft stop's sampled spring may gain at most
                    // ½·K_e·Δq₃² over the period: that much of the elbow's
                    // dissipation is its own, not the coupling's.
                    let dq = ps.q[2].sub_sat(ctrl.prev_q[2]);
                    de = de.sub_sat(ctrl.elbow_k.mul_sat(dq.mul_sat(dq)).half());
                }
            }
            ctrl.po_energy = ctrl.po_energy.add_sat(de);
        }
        if ctrl.coupled && env > env_prev {
            // A rising envelope stores ½(g − g₀)·K|d|² more in the spring:
            // allowed when the observer holds the spring's energy after it
            // (with this period's energy already in, so what it holds is
            // now; E already counts V, so nothing is taken from it), else the anchor
            // slips so that the force stays continuous (g₀/g of the stretch).
            let v = spring_energy(&g, f_lim, d_eff, e_eff);
            if ctrl.po_energy < v.mul_sat(env) {
                let k = ratio_le1(env_prev, env);
                d_eff = d_eff.scale(k);
                e_eff = e_eff.scale(k);
                ctrl.slip = d.sub(d_eff);
                ctrl.slip_rot = e.sub(e_eff);
                sw = spring_at(d_eff, e_eff);
            }
        }
        spring = Some((d, e, d_eff, e_eff, sw.0.force));
        let (mut w, sat) = sw;
        if sat {
            // The saturated spring is a function of the handle's pose around
            // its anchor: it stores V(d) (`spring_energy`) and gives back
            // exactly that; nothing slips.
            alarms |= alarm::TORQUE_SATURATED;
        }
        w = w.scale(env);
        spring_wrench = w_step;
        // Passivity controller: dissipate the energy the coupling created.
        if ctrl.passivity_control && ctrl.po_energy < PO_TOLERANCE {
            alarms |= alarm::PASSIVITY;
            let deficit = ctrl.po_energy.neg_sat();
            let v2 = v_h.norm_sq();
            let w2 = w_h.norm_sq();
            let tv2 = ctrl.period.mul_sat(v2);
            let tw2 = ctrl.period.mul_sat(w2);
            if tv2.0 > 0 && v2 > Fx::from_ratio(1, 1_000_000) {
                let a = deficit.div_sat(tv2).min(PC_ALPHA_MAX);
                w.force = w.force.sub(v_h.scale(a));
            } else if tw2.0 > 0 && w2 > Fx::from_ratio(1, 1_000_000) {
                let a = deficit.div_sat(tw2).min(PC_ALPHA_ROT_MAX);
                w.torque = w.torque.sub(w_h.scale(a));
            }
        }
        // The PC force stays inside the same saturation, scaled by the
        // envelope: |f| ≤ env·F_max.
        w = w
            .saturate(MAX_FORCE.mul_sat(env), MAX_TORQUE.mul_sat(env))
            .0;
        // Link passivity controller (`link`): with a client that reports
        // its energy, the coupling may give the handle, over this period,
        // only the energy the client put into the link (as received) less
        // what it already gave. The port's power sample is `F·v_h·T` (and
        // `τ·ω_h·T`); the part of the force along the handle's motion that
        // would exceed the budget is taken off (`F − c·v̂`, `0 ≤ c ≤ F·v̂`:
        // never more than the force's own push along the motion, so no
        // active damping). The allocation below only scales the wrench
        // down, which keeps the positive parts within the budget.
        if vpr.link_energy {
            // ½·(f·d + τ·e) at the envelope: the linear spring's energy,
            // a little above the saturated one's (no root: any share kept
            // leaves the link passive; this one is what the spring holds).
            // Needed when the controller grants: every `LINK_GRANT_EVERY`
            // cycles (the grants travel in `answer_twist`, every 4th).
            ctrl.link_phase = ctrl.link_phase.wrapping_add(1);
            if ctrl.link_phase % LINK_GRANT_EVERY == 0 {
                ctrl.link_keep =
                    sw.0.force
                        .dot(d_eff)
                        .add_sat(sw.0.torque.dot(e_eff))
                        .mul_sat(env)
                        .max(Fx::ZERO);
            }
            link_port = link_limit(ctrl, &mut w, v_h, w_h).map(|e| (e, w));
        } else {
            ctrl.link_keep = Fx::ZERO;
        }
        ctrl.prev_target = target;
        ctrl.prev_q = ps.q;
        ctrl.coupled = true;
        if want_coupling {
            st |= status::COUPLED;
        }
        handle_wrench = w;
    } else {
        ctrl.coupled = false;
        ctrl.envelope = Fx::ZERO;
        ctrl.prev_wrench = Wrench::ZERO;
        ctrl.link_keep = Fx::ZERO;
        ctrl.link.grant_beyond(Fx::ZERO);
    }

    // ---- Fixed torques: gravity compensation, then the joint velocity
    // brake (motor protection); the Cartesian brake comes after the
    // coupling's allocation, with the motor torque the coupling left.
    let mut fixed = JOINTS_ZERO;
    if ctrl.gravity_compensation {
        for ((t, gr), lim) in fixed
            .iter_mut()
            .zip(kin.gravity.iter())
            .zip(arm::TAU_MAX.iter())
        {
            *t = gr.neg_sat().clamp_abs(*lim);
        }
    }
    // The elbow's soft stop: a one-sided joint spring below
    // `ELBOW_SOFT_STOP` that keeps the arm off its stretched singularity,
    // capped at `ELBOW_STOP_TORQUE_MAX`, scaled by its gate. The gate
    // follows the coupling's envelope down at once, and up only while the
    // elbow is outside the stop's range, where the spring stores nothing:
    // its energy never grows but by the arm's work on it (a spring whose
    // scale only falls gives back at most what it holds). A coupling that
    // starts with the elbow past the onset leaves the stop off until the
    // elbow is out.
    let env_now = if active { ctrl.envelope } else { Fx::ZERO };
    if env_now < ctrl.elbow_gate || ps.q[2] >= ELBOW_SOFT_STOP {
        ctrl.elbow_gate = env_now;
    }
    let elbow_pushed = ctrl.elbow_gate.0 > 0 && ps.q[2] < ELBOW_SOFT_STOP;
    ctrl.elbow_torque = Fx::ZERO;
    if elbow_pushed {
        let mut push = ctrl
            .elbow_k
            .mul_sat(ELBOW_SOFT_STOP.sub_sat(ps.q[2]))
            .min(ELBOW_STOP_TORQUE_MAX)
            .mul_sat(ctrl.elbow_gate);
        // In full while the elbow is still or straightens, fading to
        // nothing as it bends back at `ELBOW_STOP_RELEASE`: the fade is
        // the spring's force times `q̇₃/ω_r` taken off, a damper of
        // nonnegative gain (it only takes energy), and the stop never
        // drives the elbow beyond that speed.
        let qd = ps.qd[2];
        if qd.0 > 0 {
            push = push.mul_sat(speed_scale(qd, Fx::ZERO, ELBOW_STOP_RELEASE));
        }
        let before = fixed[2];
        fixed[2] = fixed[2].add_sat(push).clamp_abs(arm::TAU_MAX[2]);
        ctrl.elbow_torque = fixed[2].sub_sat(before);
    }
    ctrl.elbow_pushed = elbow_pushed;
    // The coupling's scale from the joint speeds: 1 below the joint
    // brakes' onsets, falling linearly to 0 where the coupling may no
    // longer drive a joint along its motion (motor protection,
    // `BRAKE_START`).
    // Continuous in the speeds; it switches on where a coupling torque turns
    // to drive such a fast joint. The handle's own bound is continuous in
    // speed and direction too (`push_s`, below).
    let mut speed_s = Fx::ONE;
    // The share of the force's push along a fast motion kept (1: all).
    let mut push_s = Fx::ONE;
    let mut over = [false; 6];
    // A bounded index range, not `enumerate()` (its counter is an
    // overflow-checked addition: a panic path in the kernel).
    for (i, ((t, qd), (start, b))) in (0..fixed.len()).zip(
        fixed
            .iter_mut()
            .zip(ps.qd.iter())
            .zip(BRAKE_START.iter().zip(ctrl.brake.iter())),
    ) {
        let speed = qd.abs();
        if speed > *start {
            alarms |= alarm::VELOCITY_LIMIT;
            if let Some(o) = over.get_mut(i) {
                *o = true;
            }
            let lim = arm::TAU_MAX.get(i).copied().unwrap_or(Fx::ZERO);
            let room = lim.sub_sat(t.abs()).max(Fx::ZERO);
            let mag = b.mul_sat(speed.sub_sat(*start)).min(room);
            *t = if qd.0 > 0 {
                t.sub_sat(mag)
            } else {
                t.add_sat(mag)
            };
        }
    }
    // |v| only above the onset (compared squared first: no root in the
    // common case).
    let v_norm = v_h.norm_where_sq_above(V_BRAKE_ONSET.mul_sat(V_BRAKE_ONSET));
    let fast = v_norm.is_some();
    let v_lin = v_norm.unwrap_or(Fx::ZERO);

    // ---- Coupling torques: force first. The force's joint torques J_vᵀf
    // get the largest scale s_f ≤ 1 the motors' room (left by gravity
    // compensation and the joint brake) allows (with the torque in full
    // where that gives the force more), then the torque's J_ωᵀτ the largest
    // s_t that still
    // fits: the force keeps its direction and gets all the device has; the
    // torque gets what is left. Both are scaled by the speed scale where the
    // coupling would drive a fast joint or the handle along its motion.
    // The spring is not changed by any of this: it stays anchored.
    if handle_wrench != Wrench::ZERO && over.contains(&true) {
        for (((qd, o), start), tc) in ps
            .qd
            .iter()
            .zip(over.iter())
            .zip(BRAKE_START.iter())
            .zip(kin.jacobian_transpose_mul(&handle_wrench).iter())
        {
            if *o && tc.mul_sat(*qd).0 > 0 {
                let stop = Fx(start
                    .0
                    .saturating_mul(COUPLING_JOINT_STOP_NUM)
                    .wrapping_div(COUPLING_JOINT_STOP_DEN));
                speed_s = speed_s.min(speed_scale(qd.abs(), *start, stop));
            }
        }
    }
    if handle_wrench != Wrench::ZERO {
        if speed_s < Fx::ONE {
            handle_wrench = handle_wrench.scale(speed_s);
        }
        // Above the onset, a coupling that pushes along the handle's motion
        // is scaled by `1 − (1 − s(|v|))·min(1, cos θ / PUSH_COS_FULL)`, θ
        // the angle between force and motion: s(|v|) (0 from
        // `V_COUPLING_STOP`) once the push is within 75.5° of the motion,
        // rising to 1 as it turns across. A scale of the whole wrench, so
        // the motors give at most what the spring gives at every instant
        // (a projection that keeps the cross-motion force does not: within
        // a long period the motion turns and the kept part does work), and
        // continuous in speed and direction (a switch at θ = 90° stepped
        // the force by up to 4.5 N in one 100 µs cycle).
        let push = if v_lin > V_BRAKE_ONSET {
            handle_wrench.force.dot(v_h)
        } else {
            Fx::ZERO
        };
        if push.0 > 0 {
            let s_v = speed_scale(v_lin, V_BRAKE_ONSET, V_COUPLING_STOP);
            // cos θ / PUSH_COS_FULL, ≤ 1 (|f|·|v| ≥ push > 0).
            let full = handle_wrench
                .force
                .norm()
                .mul_sat(v_lin)
                .mul_sat(PUSH_COS_FULL);
            let c = if push >= full {
                Fx::ONE
            } else {
                push.div_sat(full)
            };
            let s_push = Fx::ONE.sub_sat(Fx::ONE.sub_sat(s_v).mul_sat(c));
            handle_wrench = handle_wrench.scale(s_push);
            push_s = s_push;
        }
    }
    // One product: the whole wrench's joint torques, and the force's
    // share for the split below.
    let (tau_w, tau_f) = kin.jacobian_transpose_mul_split(&handle_wrench);
    let fits = tau_w
        .iter()
        .zip(fixed.iter())
        .zip(arm::TAU_MAX.iter())
        .all(|((tc, tf), lim)| tf.add_sat(*tc).abs() <= *lim);
    let (mut s_f, mut s_t) = (Fx::ONE, Fx::ONE);
    let mut tau_c = tau_w;
    if !fits {
        // Jᵀ is linear: the torque's share is what is left of the whole.
        let mut tau_t = JOINTS_ZERO;
        for ((tt, tw), tf) in tau_t.iter_mut().zip(tau_w.iter()).zip(tau_f.iter()) {
            *tt = tw.sub_sat(*tf);
        }
        // The force's largest scale with the torque in full (where the
        // torque's joint torques offset the force's, the force keeps that
        // room: no step when the whole wrench stops fitting), and without
        // the torque; the larger wins, and the torque gets what is left.
        let (mut s_full, mut s_none, mut torque_fits) = (Fx::ONE, Fx::ONE, true);
        for (((tc, tt), tf), lim) in tau_f
            .iter()
            .zip(tau_t.iter())
            .zip(fixed.iter())
            .zip(arm::TAU_MAX.iter())
        {
            let with_t = tf.add_sat(*tt);
            torque_fits &= with_t.abs() <= *lim;
            s_full = s_full.min(fit_scale(with_t, *tc, *lim));
            s_none = s_none.min(fit_scale(*tf, *tc, *lim));
        }
        if torque_fits && s_full >= s_none {
            s_f = s_full;
        } else {
            s_f = s_none;
            for (((tt, tc), tf), lim) in tau_t
                .iter()
                .zip(tau_f.iter())
                .zip(fixed.iter())
                .zip(arm::TAU_MAX.iter())
            {
                s_t = s_t.min(fit_scale(tf.add_sat(tc.mul_sat(s_f)), *tt, *lim));
            }
        }
        alarms |= alarm::TORQUE_SATURATED;
        handle_wrench = Wrench {
            force: handle_wrench.force.scale(s_f),
            torque: handle_wrench.torque.scale(s_t),
        };
        for ((o, tc), tt) in tau_c.iter_mut().zip(tau_f.iter()).zip(tau_t.iter()) {
            *o = tc.mul_sat(s_f).add_sat(tt.mul_sat(s_t));
        }
    }
    // ---- The Cartesian brake, with the motors' room the coupling left: a
    // spring that already resists the motion with all the motors have keeps
    // it (its force limit does not fall because a brake took its share),
    // and the brake adds what is left along the motion.
    let mut brake_force = Vec3::ZERO;
    if fast && v_lin > V_BRAKE_ONSET {
        alarms |= alarm::VELOCITY_LIMIT;
        // −B_c (|v| − v_on) v̂, as one vector scaled to the motors' room.
        // Its engagement is a controller event: it rises from what it gave
        // last cycle by at most the force ramp (`MAX_FORCE·T/RAMP_US`,
        // 0.4 N/ms), and falls with the speed. Never above B_c (|v| − v_on),
        // so it is a damper of gain in [0, B_c].
        let mag = ctrl.brake_lin.mul_sat(v_lin.sub_sat(V_BRAKE_ONSET)).min(
            ctrl.brake_applied
                .add_sat(MAX_FORCE.mul_sat(ctrl.ramp_step)),
        );
        let f_b = v_h.scale(mag.div_sat(v_lin)).neg();
        let brake_tau = kin.jacobian_transpose_mul_force(f_b);
        let mut sb = Fx::ONE;
        for (((bt, tf), tc), lim) in brake_tau
            .iter()
            .zip(fixed.iter())
            .zip(tau_c.iter())
            .zip(arm::TAU_MAX.iter())
        {
            sb = sb.min(fit_scale(tf.add_sat(*tc), *bt, *lim));
        }
        for (t, bt) in fixed.iter_mut().zip(brake_tau.iter()) {
            *t = t.add_sat(bt.mul_sat(sb));
        }
        brake_force = f_b.scale(sb);
        // What the motors gave: nothing while they are not enabled (the
        // line applies no torque), so a brake that meets a fast handle at
        // power-on engages at the ramp from 0.
        ctrl.brake_applied = if ls.motors_enabled {
            mag.mul_sat(sb)
        } else {
            Fx::ZERO
        };
    } else {
        ctrl.brake_applied = Fx::ZERO;
    }
    let s = s_f.min(s_t).mul_sat(speed_s.min(push_s));
    let mut joint_torques = JOINTS_ZERO;
    for (((o, tf), tc), lim) in joint_torques
        .iter_mut()
        .zip(fixed.iter())
        .zip(tau_c.iter())
        .zip(arm::TAU_MAX.iter())
    {
        // Within the limit up to rounding of the scaled products.
        *o = tf.add_sat(*tc).clamp_abs(*lim);
    }
    if ctrl.coupled && vpr.link_energy {
        // The handle port's energy on the link this period (> 0: the
        // coupling gave it to the handle): the limiter's when the wrench
        // reached the motors as it left it.
        let e_port = match link_port {
            Some((e, w)) if w == handle_wrench => e,
            _ => handle_wrench
                .force
                .dot(v_h)
                .mul_sat(ctrl.period)
                .add_sat(handle_wrench.torque.dot(w_h).mul_sat(ctrl.period)),
        };
        ctrl.link.record(e_port);
        // Grant the client what the reservoir holds beyond half the energy
        // the spring stores (the handle's share if the spring gives it back):
        // `link_keep` is twice the linear spring's energy, so keep a quarter.
        if ctrl.link_phase % LINK_GRANT_EVERY == 0 {
            ctrl.link.grant_beyond(Fx(ctrl.link_keep.0 >> 2));
        }
    }
    if ctrl.coupled {
        ctrl.prev_wrench = handle_wrench;
        for ((p, o), tf) in ctrl
            .prev_tau_c
            .iter_mut()
            .zip(joint_torques.iter())
            .zip(fixed.iter())
        {
            *p = o.sub_sat(*tf);
        }
    }
    // ---- The spring's saturation follows what the motors gave. When the
    // motors could not give the spring's force along it (capacity at this
    // pose), the spring saturates at the force applied from
    // now on: it stays anchored (the wall is where it was), and beyond its
    // knee its energy grows by exactly the work the motors absorb, so it
    // holds nothing they cannot give back. The limit rises back toward
    // `MAX_FORCE` no faster than the force ramp (0.4 N/ms), and only with
    // energy the observer holds (the spring's energy stays covered by the
    // observer's). The rotational spring, which gets the motors' room after
    // the force, slips instead (its anchor), taken back the same way.
    // Slip also comes from stiffer gains and an envelope rise the observer
    // could not pay (above).
    if let (Some((d, e, d_eff, e_eff, f_spring)), true) = (spring, ctrl.coupled) {
        // (The speed scale is not a limit of the spring: it only withholds
        // force along a fast motion, so the spring keeps more energy than
        // it gives, and comes back as the motion slows.)
        let lf = s_f;
        let lt = s_t;
        if lt < Fx::ONE {
            ctrl.slip_rot = e.sub(e_eff.scale(lt));
        }
        if lf < Fx::ONE {
            // A hair below what was applied, so that the next cycle fits
            // the motors without the split (rounding of the scaled product).
            let applied = f_spring.norm().mul_sat(lf);
            let applied = applied.sub_sat(Fx(applied.0 >> 10));
            ctrl.force_limit = ctrl.force_limit.min(applied).max(Fx::ZERO);
            ctrl.limit_hold = limit_hold_cycles(ctrl.ramp_step);
        } else if ctrl.limit_hold > 0 {
            // Just limited: stay at the capacity a while before trying
            // higher (a limit that tries every cycle would split the
            // allocation every other cycle).
            ctrl.limit_hold -= 1;
        } else if ctrl.force_limit < MAX_FORCE {
            let raised = ctrl
                .force_limit
                .add_sat(MAX_FORCE.mul_sat(ctrl.ramp_step))
                .min(MAX_FORCE);
            if ctrl.po_energy >= spring_energy(&g, raised, d_eff, e_eff) {
                ctrl.force_limit = raised;
            }
        }
        // Taken back once every `takeback_every` cycles by that many ramp
        // steps (at most 0.4 N/ms still; the energies cost a few roots).
        ctrl.takeback_phase = ctrl.takeback_phase.wrapping_add(1);
        let due = ctrl.takeback_phase >= ctrl.takeback_every;
        if due {
            ctrl.takeback_phase = 0;
        }
        if (ctrl.slip != Vec3::ZERO || ctrl.slip_rot != Vec3::ZERO) && lt >= Fx::ONE && due {
            let step = MAX_FORCE
                .mul_sat(ctrl.ramp_step)
                .mul_int(i64::from(ctrl.takeback_every));
            let dl = if g.k_lin.0 > 0 {
                step.div_sat(g.k_lin)
            } else {
                D_CLAMP
            };
            let step_t = MAX_TORQUE
                .mul_sat(ctrl.ramp_step)
                .mul_int(i64::from(ctrl.takeback_every));
            let dr = if g.k_rot.0 > 0 {
                step_t.div_sat(g.k_rot)
            } else {
                Fx::TWO
            };
            let slip = ctrl.slip.sub(ctrl.slip.clamp_norm(dl).0);
            let slip_rot = ctrl.slip_rot.sub(ctrl.slip_rot.clamp_norm(dr).0);
            let v_new = spring_energy(&g, ctrl.force_limit, d.sub(slip), e.sub(slip_rot));
            if ctrl.po_energy >= v_new {
                ctrl.slip = slip;
                ctrl.slip_rot = slip_rot;
            }
        }
    }

    // ---- The object feels the reaction of what the motors apply, in
    // client frame and units.
    let react = handle_wrench.neg().rotate(&base.orientation);
    let coupling_wrench = Wrench {
        force: react.force.scale(config.force_factor),
        torque: react.torque.scale(config.force_factor.mul_sat(sf)),
    };

    ControlOutput {
        joint_torques,
        fixed_torques: fixed,
        handle_wrench,
        coupling_wrench,
        handle_pose_client,
        handle_twist_client,
        status: st,
        alarms,
        po_energy: ctrl.po_energy,
        envelope: ctrl.envelope,
        torque_scale: s,
        force_scale: s_f,
        speed_scale: speed_s.min(push_s),
        spring_wrench,
        brake_force,
    }
}
