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
//! Gains are chosen inside the passivity bound `b > K·T/2 + |B|`, applied per
//! joint with the largest lever arm (see `Documentation/control.md`):
//! `b_i > (K_t·r_i² + K_r)·T/2 + B_t·r_i² + B_r`.

use super::arm::{self, Kinematics};
use super::config::{CommandType, IndexingMode, ServoConfig};
use super::fixed::{Fx, Joints, Pose, Quat, Twist, Vec3, Wrench, JOINTS_ZERO};
use super::servo::ServoMode;
use super::state_model::{LogicalState, PhysicalState};
use super::vp::{alarm, status, VpReceived};

/// Nominal translational stiffness, N/m (capped by the bound).
pub const K_LIN_NOMINAL: Fx = Fx::from_int(1500);
/// Translational coupling damping, N·s/m.
pub const B_LIN: Fx = Fx::from_ratio(2, 10);
/// Nominal rotational stiffness, N·m/rad (capped by the bound).
pub const K_ROT_NOMINAL: Fx = Fx::from_int(10);
/// Rotational coupling damping, N·m·s/rad.
pub const B_ROT: Fx = Fx::from_ratio(5, 1000);
/// Fraction of the bound used by the nominal gains.
pub const BOUND_MARGIN: Fx = Fx::from_ratio(8, 10);
/// `virtSaturateTorque` thresholds: force N, torque N·m.
pub const MAX_FORCE: Fx = Fx::from_int(20);
pub const MAX_TORQUE: Fx = Fx::from_ratio(6, 10);
/// Handle speed limits, m/s and rad/s, and the braking damping beyond them.
pub const V_MAX: Fx = Fx::from_ratio(15, 10);
pub const W_MAX: Fx = Fx::from_int(10);
pub const B_VLIM: Fx = Fx::from_int(10);
pub const B_WLIM: Fx = Fx::from_ratio(2, 100);
/// Passivity controller damping caps, N·s/m and N·m·s/rad.
pub const PC_ALPHA_MAX: Fx = Fx::from_int(5);
pub const PC_ALPHA_ROT_MAX: Fx = Fx::from_ratio(2, 100);
/// Joint damping injected in degraded mode, N·m·s/rad (each below the
/// arm's own damping, so the discrete damper stays passive).
pub const DEGRADED_DAMPING: Joints = [
    Fx::from_ratio(3, 10),
    Fx::from_ratio(3, 10),
    Fx::from_ratio(2, 10),
    Fx::from_ratio(5, 1000),
    Fx::from_ratio(5, 1000),
    Fx::from_ratio(5, 1000),
];

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

    /// Largest rotational stiffness the bound allows with `k_lin = 0`.
    pub fn max_rot_stiffness(period: Fx) -> Fx {
        let two_over_t = Fx::TWO.div_sat(period);
        let mut best = Fx::MAX;
        for (b, r) in arm::DAMPING.iter().zip(arm::LEVER_MAX.iter()) {
            let slack = b.sub_sat(B_ROT).sub_sat(B_LIN.mul_sat(r.mul_sat(*r)));
            best = best.min(slack.mul_sat(two_over_t));
        }
        best.max(Fx::ZERO)
    }

    /// Largest translational stiffness the bound allows given `k_rot`:
    /// `min_i [2(b_i − B_r − B_t r_i²)/T − K_r] / r_i²`.
    pub fn max_lin_stiffness(period: Fx, k_rot: Fx) -> Fx {
        let two_over_t = Fx::TWO.div_sat(period);
        let mut best = Fx::MAX;
        for (b, r) in arm::DAMPING.iter().zip(arm::LEVER_MAX.iter()) {
            let r2 = r.mul_sat(*r);
            if r2.0 <= 0 {
                continue;
            }
            let slack = b.sub_sat(B_ROT).sub_sat(B_LIN.mul_sat(r2));
            let k = slack.mul_sat(two_over_t).sub_sat(k_rot).div_sat(r2);
            best = best.min(k);
        }
        best.max(Fx::ZERO)
    }

    /// Nominal gains for `period` (s): `K_r = min(10, ½·K_r,max)`,
    /// `K_t = min(1500, 0.8·K_t,max)`.
    pub fn for_period(period: Fx) -> Gains {
        let k_rot = K_ROT_NOMINAL.min(Gains::max_rot_stiffness(period).mul_sat(Fx::HALF));
        let k_lin =
            K_LIN_NOMINAL.min(Gains::max_lin_stiffness(period, k_rot).mul_sat(BOUND_MARGIN));
        Gains {
            k_lin,
            b_lin: B_LIN,
            k_rot,
            b_rot: B_ROT,
        }
    }

    /// The stiffest gains the bound allows (margin 1): for wall tests.
    pub fn at_bound(period: Fx) -> Gains {
        let k_rot = K_ROT_NOMINAL.min(Gains::max_rot_stiffness(period).mul_sat(Fx::HALF));
        let k_lin = Gains::max_lin_stiffness(period, k_rot);
        Gains {
            k_lin,
            b_lin: B_LIN,
            k_rot,
            b_rot: B_ROT,
        }
    }
}

/// The controller's memory (filters, observer, indexing).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Controller {
    pub gains: Gains,
    /// Gravity compensation on (default); tests switch it off.
    pub gravity_compensation: bool,
    /// Passivity controller on (default).
    pub passivity_control: bool,
    period: Fx,
    /// Passivity observer: energy that entered the coupling, J (≥ 0 when passive).
    po_energy: Fx,
    coupled: bool,
    prev_handle: Vec3,
    prev_target: Pose,
    prev_wrench: Wrench,
    /// Indexing offset: indexed handle = (offset_pos + p, offset_rot ⊗ q).
    offset_pos: Vec3,
    offset_rot: Quat,
    indexing: bool,
    frozen: Pose,
}

/// What `cartesian_control` produces.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ControlOutput {
    /// Joint torques to command (saturated to the motor limits), N·m.
    pub joint_torques: Joints,
    /// Coupling wrench applied to the handle (after saturation and PC), base frame.
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
}

impl Controller {
    pub const fn new() -> Controller {
        Controller {
            gains: Gains::ZERO,
            gravity_compensation: true,
            passivity_control: true,
            period: Fx::ZERO,
            po_energy: Fx::ZERO,
            coupled: false,
            prev_handle: Vec3::ZERO,
            prev_target: Pose::IDENTITY,
            prev_wrench: Wrench::ZERO,
            offset_pos: Vec3::ZERO,
            offset_rot: Quat::IDENTITY,
            indexing: false,
            frozen: Pose::IDENTITY,
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
    }

    pub fn po_energy(&self) -> Fx {
        self.po_energy
    }

    pub fn coupled(&self) -> bool {
        self.coupled
    }

    /// Reset the indexing offset (e.g. new session).
    pub fn reset_indexing(&mut self) {
        self.offset_pos = Vec3::ZERO;
        self.offset_rot = Quat::IDENTITY;
        self.indexing = false;
    }
}

impl Default for Controller {
    fn default() -> Self {
        Controller::new()
    }
}

/// Stored energy of the (saturated) coupling spring for a linear error `d`
/// and rotational error `e`.
fn spring_energy(g: &Gains, d: Vec3, e: Vec3) -> Fx {
    let dn = d.norm();
    let kd = g.k_lin.mul_sat(dn);
    let lin = if kd > MAX_FORCE && g.k_lin.0 > 0 {
        // F_max·(|d| − F_max/(2K))
        MAX_FORCE.mul_sat(dn.sub_sat(MAX_FORCE.div_sat(g.k_lin.mul_sat(Fx::TWO))))
    } else {
        kd.mul_sat(dn).mul_sat(Fx::HALF)
    };
    let rot = g.k_rot.mul_sat(e.norm_sq()).mul_sat(Fx::HALF);
    lin.add_sat(rot)
}

/// Braking force beyond a speed limit: `−B·(|v| − v_max)·v̂`.
fn speed_brake(v: Vec3, v_max: Fx, b: Fx) -> (Vec3, bool) {
    let n = v.norm();
    if n <= v_max || n.0 <= 0 {
        return (Vec3::ZERO, false);
    }
    let k = b.mul_sat(n.sub_sat(v_max)).div_sat(n);
    (v.scale(k).neg(), true)
}

/// `cartesian_control`.
#[allow(clippy::too_many_lines)]
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
    let want_coupling = ls.motors_enabled
        && ls.dead_man
        && vpr.valid
        && match config.command_type {
            CommandType::None => false,
            CommandType::Impedance => true,
            CommandType::VirtMech => config.attached_object.is_some(),
        };
    let mut g = ctrl.gains;
    if ls.mode == ServoMode::Degraded {
        // The auxiliary path keeps the coupling (spec §3.5: same code) but a
        // deadline was just missed, so the effective period may be twice as
        // long: halving the stiffnesses keeps the b > K·T/2 margin.
        g.k_lin = Fx(g.k_lin.0 / 2);
        g.k_rot = Fx(g.k_rot.0 / 2);
    }
    if config.command_type == CommandType::VirtMech {
        // Mass-aware cap so the client's explicit integration stays stable:
        // K ≤ m / ts².
        if let Some(obj) = config.attached_object {
            let ts = config.time_step;
            if ts.0 > 0 {
                let cap = obj.mass.div_sat(ts.mul_sat(ts));
                g.k_lin = g.k_lin.min(cap);
            }
        }
    }

    let mut handle_wrench = Wrench::ZERO;
    let mut coupling_wrench = Wrench::ZERO;
    if want_coupling {
        // Target in the indexed arm frame, then in the raw arm frame.
        let t_idx = base_inv.compose(&vpr.pose);
        let t_pos = t_idx.position.scale(inv_sf).sub(ctrl.offset_pos);
        let t_rot = ctrl.offset_rot.conjugate().mul(&t_idx.orientation);
        let back = ctrl.offset_rot.conjugate().mul(&base_inv.orientation);
        let t_v = back.rotate(vpr.twist.linear).scale(inv_sf);
        let t_w = back.rotate(vpr.twist.angular);
        let target = Pose {
            position: t_pos,
            orientation: t_rot,
        };

        let d = t_pos.sub(p_h);
        let e = t_rot.error_vector(&q_h);
        if !ctrl.coupled {
            // Start of coupling: the observer starts with the spring's energy.
            ctrl.po_energy = spring_energy(&g, d, e);
            ctrl.prev_target = target;
            ctrl.prev_handle = p_h;
            ctrl.prev_wrench = Wrench::ZERO;
        } else {
            // Passivity observer: energy that entered the coupling during the
            // last period through both ports, with the wrench that was applied.
            let dp_t = t_pos.sub(ctrl.prev_target.position);
            let dth_t = t_rot.error_vector(&ctrl.prev_target.orientation);
            let dp_h = p_h.sub(ctrl.prev_handle);
            let dth_h = w_h.scale(ctrl.period);
            let de = ctrl
                .prev_wrench
                .force
                .dot(dp_t.sub(dp_h))
                .add_sat(ctrl.prev_wrench.torque.dot(dth_t.sub(dth_h)));
            ctrl.po_energy = ctrl.po_energy.add_sat(de);
        }
        let f = d.scale(g.k_lin).add(t_v.sub(v_h).scale(g.b_lin));
        let tq = e.scale(g.k_rot).add(t_w.sub(w_h).scale(g.b_rot));
        let (mut w, sat) = Wrench {
            force: f,
            torque: tq,
        }
        .saturate(MAX_FORCE, MAX_TORQUE);
        if sat {
            alarms |= alarm::TORQUE_SATURATED;
        }
        // Passivity controller: dissipate the energy the coupling created.
        if ctrl.passivity_control && ctrl.po_energy.0 < 0 {
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
        // The PC force stays inside the same saturation.
        w = w.saturate(MAX_FORCE, MAX_TORQUE).0;
        ctrl.prev_target = target;
        ctrl.prev_handle = p_h;
        ctrl.coupled = true;
        if ff_inhibited {
            w = Wrench::ZERO;
        } else {
            st |= status::COUPLED;
        }
        ctrl.prev_wrench = w;
        handle_wrench = w;
        // The object feels the reaction, in client frame and units.
        let react = w.neg().rotate(&base.orientation);
        coupling_wrench = Wrench {
            force: react.force.scale(config.force_factor),
            torque: react.torque.scale(config.force_factor.mul_sat(sf)),
        };
    } else {
        ctrl.coupled = false;
        ctrl.prev_wrench = Wrench::ZERO;
    }

    // ---- Velocity limit (all modes).
    let (fb, over_v) = speed_brake(v_h, V_MAX, B_VLIM);
    let (tb, over_w) = speed_brake(w_h, W_MAX, B_WLIM);
    if over_v || over_w {
        alarms |= alarm::VELOCITY_LIMIT;
    }
    let total = Wrench {
        force: handle_wrench.force.add(fb),
        torque: handle_wrench.torque.add(tb),
    };

    // ---- Joint torques: Jᵀ·w + gravity compensation (+ degraded damping).
    let mut tau = arm::jacobian_transpose_mul(&kin.jacobian, &total);
    if ctrl.gravity_compensation {
        for (t, g) in tau.iter_mut().zip(kin.gravity.iter()) {
            *t = t.sub_sat(*g);
        }
    }
    if ls.mode == ServoMode::Degraded {
        for ((t, b), qd) in tau
            .iter_mut()
            .zip(DEGRADED_DAMPING.iter())
            .zip(ps.qd.iter())
        {
            *t = t.sub_sat(b.mul_sat(*qd));
        }
    }
    let mut joint_torques = JOINTS_ZERO;
    for ((o, t), lim) in joint_torques
        .iter_mut()
        .zip(tau.iter())
        .zip(arm::TAU_MAX.iter())
    {
        *o = t.clamp_abs(*lim);
        if *o != *t {
            alarms |= alarm::TORQUE_SATURATED;
        }
    }

    ControlOutput {
        joint_torques,
        handle_wrench,
        coupling_wrench,
        handle_pose_client,
        handle_twist_client,
        status: st,
        alarms,
        po_energy: ctrl.po_energy,
    }
}
