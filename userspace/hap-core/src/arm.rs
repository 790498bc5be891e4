//! The simulated 6-DoF Virtuose arm model: geometry, limits, dynamics
//! parameters, forward kinematics, Jacobian, gravity and inertia.
//!
//! # Geometry (arm base frame: x forward, y left, z up; m, rad)
//!
//! Three positioning axes (yaw, shoulder pitch, elbow pitch) and a 3-axis
//! roll–pitch–roll wrist, dimensions close to a Virtuose 6D35-45:
//!
//! | joint | axis (in the frame of the previous link) | located at | link after it |
//! |---|---|---|---|
//! | q1 base yaw | z of the base | origin | shoulder offset `H0` = 0.20 m along z |
//! | q2 shoulder pitch | y of R1 | shoulder `p_s = (0,0,H0)` | upper arm `L1` = 0.40 m along x |
//! | q3 elbow pitch | y of R1·R2 | elbow `p_e` | forearm `L2` = 0.45 m along x |
//! | q4 wrist roll | x of R1·R2·R3 | wrist centre `p_w` | — |
//! | q5 wrist pitch | y of R1…R4 | wrist centre `p_w` | handle arm `L3` = 0.08 m along x |
//! | q6 handle roll | x of R1…R5 | wrist centre / handle | — |
//!
//! Rotations are `R1 = Rz(q1)`, `R2 = Ry(q2)`, `R3 = Ry(q3)`, `R4 = Rx(q4)`,
//! `R5 = Ry(q5)`, `R6 = Rx(q6)`; a positive pitch turns x toward −z, so a
//! positive `q2` lowers the upper arm. The handle frame is `R1…R6` at
//! `p_h = p_w + R1…R5·(L3, 0, 0)`; its x axis points out of the handle.
//! The 6-axis force sensor sits in the handle frame.
//!
//! # Dynamics (simplified, documented in `Documentation/simulator.md`)
//!
//! Three point masses: upper arm `M1` = 1.0 kg at `L1/2`, forearm `M2` = 0.8 kg
//! at `L2/2`, wrist + handle `M3` = 0.3 kg at `L3/2` beyond the wrist centre.
//! No counterweights (so gravity compensation matters). The mass matrix is
//! taken diagonal: `I_i = Ir_i + Σ_k m_k·d_ik²` (reflected rotor inertia plus
//! the point masses distal to joint `i` at their distance `d_ik` from its axis);
//! Coriolis/centrifugal terms are neglected. Each joint has viscous damping
//! `b_i` and Coulomb friction `fc_i` (linear below 0.01 rad/s), a stiff
//! spring–damper stop at each position limit, and a motor torque limit.

use super::fixed::{Fx, Joints, Mat3, Pose, Quat, Twist, Vec3, Wrench};

/// Base yaw axis to shoulder, m.
pub const H0: Fx = Fx::from_ratio(20, 100);
/// Upper arm, m.
pub const L1: Fx = Fx::from_ratio(40, 100);
/// Forearm (elbow to wrist centre), m.
pub const L2: Fx = Fx::from_ratio(45, 100);
/// Wrist centre to handle centre, m.
pub const L3: Fx = Fx::from_ratio(8, 100);
/// Link masses (upper arm, forearm, wrist+handle), kg.
pub const MASS: [Fx; 3] = [Fx::ONE, Fx::from_ratio(8, 10), Fx::from_ratio(3, 10)];
/// Gravity, m/s².
pub const GRAVITY: Fx = Fx::from_ratio(981, 100);

/// Joint position limits (min), rad.
pub const Q_MIN: Joints = [
    Fx::from_ratio(-15, 10),
    Fx::from_ratio(-14, 10),
    Fx::from_ratio(-3, 10),
    Fx::from_ratio(-25, 10),
    Fx::from_ratio(-12, 10),
    Fx::from_ratio(-25, 10),
];
/// Joint position limits (max), rad.
pub const Q_MAX: Joints = [
    Fx::from_ratio(15, 10),
    Fx::from_ratio(6, 10),
    Fx::from_ratio(26, 10),
    Fx::from_ratio(25, 10),
    Fx::from_ratio(12, 10),
    Fx::from_ratio(25, 10),
];
/// Motor torque limits (at the joint, after gearing), N·m.
pub const TAU_MAX: Joints = [
    Fx::from_int(12),
    Fx::from_int(20),
    Fx::from_int(12),
    Fx::from_ratio(8, 10),
    Fx::from_ratio(8, 10),
    Fx::from_ratio(6, 10),
];
/// Reflected rotor inertia, kg·m².
pub const ROTOR_INERTIA: Joints = [
    Fx::from_ratio(5, 100),
    Fx::from_ratio(5, 100),
    Fx::from_ratio(3, 100),
    Fx::from_ratio(2, 1000),
    Fx::from_ratio(2, 1000),
    Fx::from_ratio(1, 1000),
];
/// Viscous joint damping, N·m·s/rad (the physical damping `b` of the
/// passivity bound, see Documentation/control.md).
pub const DAMPING: Joints = [
    Fx::ONE,
    Fx::ONE,
    Fx::from_ratio(8, 10),
    Fx::from_ratio(4, 100),
    Fx::from_ratio(4, 100),
    Fx::from_ratio(3, 100),
];
/// Coulomb friction, N·m.
pub const COULOMB: Joints = [
    Fx::from_ratio(5, 100),
    Fx::from_ratio(5, 100),
    Fx::from_ratio(4, 100),
    Fx::from_ratio(5, 1000),
    Fx::from_ratio(5, 1000),
    Fx::from_ratio(3, 1000),
];
/// Speed below which Coulomb friction is linear (rad/s).
pub const COULOMB_LINEAR_SPEED: Fx = Fx::from_ratio(1, 100);
/// End-stop stiffness, N·m/rad.
pub const STOP_STIFFNESS: Joints = [
    Fx::from_int(300),
    Fx::from_int(300),
    Fx::from_int(300),
    Fx::from_int(20),
    Fx::from_int(20),
    Fx::from_int(20),
];
/// End-stop damping, N·m·s/rad (only while in the stop, never pulling).
pub const STOP_DAMPING: Joints = [
    Fx::from_int(5),
    Fx::from_int(5),
    Fx::from_int(5),
    Fx::from_ratio(3, 10),
    Fx::from_ratio(3, 10),
    Fx::from_ratio(3, 10),
];
/// Largest lever arm from each joint axis to the handle over the workspace, m
/// (used by the passivity bound): `L1+L2+L3`, `L1+L2+L3`, `L2+L3`, `L3`, `L3`, 0.
pub const LEVER_MAX: Joints = [
    Fx::from_ratio(93, 100),
    Fx::from_ratio(93, 100),
    Fx::from_ratio(53, 100),
    Fx::from_ratio(8, 100),
    Fx::from_ratio(8, 100),
    Fx::ZERO,
];
/// Encoder resolution: counts per radian at the joint (2^20 counts per
/// revolution ≈ 166 886 counts/rad, resolution 6.0e-6 rad).
pub const ENCODER_COUNTS_PER_RAD: Fx = Fx::from_ratio(166_886, 1);

/// The calibrated rest configuration: the unpowered arm's stable equilibrium,
/// shoulder resting on its lower stop (`q2 = Q_MAX[1]` = 0.6 rad, upper arm
/// 34° below horizontal), forearm and wrist hanging vertically
/// (`q3 = π/2 − 0.6`), yaw/roll axes at 0. Handle ≈ (0.330, 0, −0.556) m.
pub const REST_Q: Joints = [
    Fx::ZERO,
    Fx::from_ratio(6, 10),
    Fx(Fx::HALF_PI.0 - Fx::from_ratio(6, 10).0),
    Fx::ZERO,
    Fx::ZERO,
    Fx::ZERO,
];

/// A working configuration (upper arm raised 30°, forearm horizontal-ish),
/// handle ≈ (0.80, 0, 0.35) m; used by tests and as a typical pose.
pub const WORK_Q: Joints = [
    Fx::ZERO,
    Fx::from_ratio(-5, 10),
    Fx::from_ratio(5, 10),
    Fx::ZERO,
    Fx::ZERO,
    Fx::ZERO,
];

/// Everything computed from one joint configuration.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Kinematics {
    /// Handle pose in the arm base frame.
    pub handle: Pose,
    /// Handle rotation matrix (R1…R6).
    pub handle_rot: Mat3,
    /// Geometric Jacobian columns: column i is the handle twist for q̇_i = 1
    /// (linear velocity of the handle point, angular velocity), base frame.
    pub jacobian: [Twist; 6],
    /// Gravity torque on each joint (what gravity does; compensation is −this), N·m.
    pub gravity: Joints,
    /// Diagonal joint inertia, kg·m².
    pub inertia: Joints,
}

impl Kinematics {
    pub const ZERO: Kinematics = Kinematics {
        handle: Pose::IDENTITY,
        handle_rot: Mat3::IDENTITY,
        jacobian: [Twist::ZERO; 6],
        gravity: [Fx::ZERO; 6],
        inertia: ROTOR_INERTIA,
    };
}

/// Squared distance from point `c` to the axis through `p` along unit `z`.
const fn perp_sq(c: Vec3, p: Vec3, z: Vec3) -> Fx {
    let r = c.sub(p);
    let a = r.dot(z);
    r.norm_sq().sub_sat(a.mul_sat(a)).max(Fx::ZERO)
}

/// Forward kinematics, Jacobian, gravity torques and diagonal inertia.
pub fn kinematics(q: &Joints) -> Kinematics {
    let [q1, q2, q3, q4, q5, q6] = *q;
    let (s1, c1) = q1.sin_cos();
    let (s2, c2) = q2.sin_cos();
    let (s23, c23) = q2.add_sat(q3).sin_cos();
    let (s4, c4) = q4.sin_cos();
    let (s5, c5) = q5.sin_cos();
    let (s6, c6) = q6.sin_cos();
    let r1 = Mat3::rot_z(s1, c1);
    let r12 = r1.mul(&Mat3::rot_y(s2, c2));
    let r123 = r1.mul(&Mat3::rot_y(s23, c23));
    let r1234 = r123.mul(&Mat3::rot_x(s4, c4));
    let r5 = r1234.mul(&Mat3::rot_y(s5, c5));
    let r6 = r5.mul(&Mat3::rot_x(s6, c6));

    let p_s = Vec3::new(Fx::ZERO, Fx::ZERO, H0);
    let x12 = r12.col(0);
    let x123 = r123.col(0);
    let x5 = r5.col(0);
    let p_e = p_s.add(x12.scale(L1));
    let p_w = p_e.add(x123.scale(L2));
    let p_h = p_w.add(x5.scale(L3));

    // Joint axes (world) and points on them.
    let z = [Vec3::Z, r1.col(1), r1.col(1), x123, r1234.col(1), r6.col(0)];
    let p = [Vec3::ZERO, p_s, p_e, p_w, p_w, p_w];

    let mut jacobian = [Twist::ZERO; 6];
    for ((col, zi), pi) in jacobian.iter_mut().zip(z.iter()).zip(p.iter()) {
        *col = Twist {
            linear: zi.cross(p_h.sub(*pi)),
            angular: *zi,
        };
    }

    // Centres of mass and the joints each body is distal to.
    let half = Fx::HALF;
    let com = [
        p_s.add(x12.scale(L1.mul_sat(half))),
        p_e.add(x123.scale(L2.mul_sat(half))),
        p_w.add(x5.scale(L3.mul_sat(half))),
    ];
    // body k is moved by joints 0..=last_joint[k]
    let last_joint = [1usize, 2, 5];
    let mut gravity = [Fx::ZERO; 6];
    let mut inertia = ROTOR_INERTIA;
    // A bounded index range, not `enumerate()`: the latter's counter is an
    // overflow-checked addition (a panic path in the kernel).
    for (i, ((g, inn), (zi, pi))) in (0..gravity.len()).zip(
        gravity
            .iter_mut()
            .zip(inertia.iter_mut())
            .zip(z.iter().zip(p.iter())),
    ) {
        for ((c, m), lj) in com.iter().zip(MASS.iter()).zip(last_joint.iter()) {
            if i <= *lj {
                let f = Vec3::new(Fx::ZERO, Fx::ZERO, m.mul_sat(GRAVITY).neg_sat());
                *g = g.add_sat(zi.dot(c.sub(*pi).cross(f)));
                *inn = inn.add_sat(m.mul_sat(perp_sq(*c, *pi, *zi)));
            }
        }
    }

    Kinematics {
        handle: Pose {
            position: p_h,
            orientation: Quat::from_mat3(&r6),
        },
        handle_rot: r6,
        jacobian,
        gravity,
        inertia,
    }
}

/// `J · q̇`: the handle twist for joint speeds `qd`.
pub fn jacobian_mul(j: &[Twist; 6], qd: &Joints) -> Twist {
    let mut t = Twist::ZERO;
    for (col, v) in j.iter().zip(qd.iter()) {
        t = t.add(&col.scale(*v));
    }
    t
}

/// `Jᵀ · w`: joint torques producing the handle wrench `w` (force at the
/// handle point, torque), base frame.
pub fn jacobian_transpose_mul(j: &[Twist; 6], w: &Wrench) -> Joints {
    let mut tau = [Fx::ZERO; 6];
    for (t, col) in tau.iter_mut().zip(j.iter()) {
        *t = col.power(w);
    }
    tau
}

/// Encoder counts for a joint angle (rounded, saturating to i32).
pub fn encoder_counts(q: Fx) -> i32 {
    let c = q.mul_sat(ENCODER_COUNTS_PER_RAD).round_to_i64();
    if c > i32::MAX as i64 {
        i32::MAX
    } else if c < i32::MIN as i64 {
        i32::MIN
    } else {
        c as i32
    }
}

/// 2^48 / `ENCODER_COUNTS_PER_RAD`: radians per count with 48 fractional bits.
const RAD_PER_COUNT_Q48: i64 = (1i64 << 48) / 166_886;

/// Joint angle from encoder counts (multiply by a 48-bit reciprocal; relative
/// error 3e-10).
pub fn encoder_angle(counts: i32) -> Fx {
    // |counts| < 2^31, RAD_PER_COUNT_Q48 < 2^31: the product fits in i64.
    Fx(((counts as i64) * RAD_PER_COUNT_Q48) >> 16)
}
