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

use super::fixed::{Fx, Joints, Mat3, Pose, Quat, Twist, UnitFactor, Vec3, Wrench};

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
///
/// The rotation and the Jacobian are kept as the Q2.30 raws the kinematics
/// computes them in (`handle_rot()` and `jacobian()` give them as `Fx`,
/// exactly: each entry is the raw times 4). Every entry is below 2 in
/// magnitude (rotation entries ≤ 1; a Jacobian column is a unit axis `z`
/// and `z × r` with `|r| ≤ 1.13 m`; plus rounding of a few 2^-30), so a raw
/// is within ±2^31: exactly the factor [`Fx::mul_unit`] would take from the
/// `Fx` entry, and the products below are `mul_unit`'s without its clamp.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Kinematics {
    /// Handle pose in the arm base frame.
    pub handle: Pose,
    /// Handle rotation matrix (R1…R6), Q2.30 raws, column by column.
    rot30: [[i64; 3]; 3],
    /// Geometric Jacobian, Q2.30 raws: column i is the handle twist for
    /// q̇_i = 1 (linear velocity of the handle point x, y, z, angular
    /// velocity x, y, z), base frame.
    jac30: [[i64; 6]; 6],
    /// Gravity torque on each joint (what gravity does; compensation is −this), N·m.
    pub gravity: Joints,
    /// Diagonal joint inertia, kg·m².
    pub inertia: Joints,
}

/// The same text as a derived `Debug` of the fields `handle`, `handle_rot`,
/// `jacobian`, `gravity`, `inertia`.
impl core::fmt::Debug for Kinematics {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Kinematics")
            .field("handle", &self.handle)
            .field("handle_rot", &self.handle_rot())
            .field("jacobian", &self.jacobian())
            .field("gravity", &self.gravity)
            .field("inertia", &self.inertia)
            .finish()
    }
}

const fn q3_fx(c: [i64; 3]) -> Vec3 {
    Vec3::new(fx_of(c[0]), fx_of(c[1]), fx_of(c[2]))
}

impl Kinematics {
    pub const ZERO: Kinematics = Kinematics {
        handle: Pose::IDENTITY,
        rot30: [[1 << 30, 0, 0], [0, 1 << 30, 0], [0, 0, 1 << 30]],
        jac30: [[0; 6]; 6],
        gravity: [Fx::ZERO; 6],
        inertia: ROTOR_INERTIA,
    };

    /// Handle rotation matrix (R1…R6).
    pub const fn handle_rot(&self) -> Mat3 {
        let [x, y, z] = self.rot30;
        Mat3::from_cols(q3_fx(x), q3_fx(y), q3_fx(z))
    }

    /// Geometric Jacobian columns: column i is the handle twist for q̇_i = 1
    /// (linear velocity of the handle point, angular velocity), base frame.
    pub fn jacobian(&self) -> [Twist; 6] {
        self.jac30.map(|c| Twist::from_array(c.map(fx_of)))
    }

    /// `J · q̇`: exactly [`jacobian_mul`]`(&self.jacobian(), qd)`.
    pub fn jacobian_mul(&self, qd: &Joints) -> Twist {
        let mut t = [0i64; 6];
        for (col, v) in self.jac30.iter().zip(qd.iter()) {
            let f = UnitFactor::new(*v);
            for (o, u) in t.iter_mut().zip(col.iter()) {
                *o = o.wrapping_add(f.mul30(*u));
            }
        }
        Twist::from_array(t.map(Fx))
    }

    /// `Jᵀ · w`: exactly [`jacobian_transpose_mul`]`(&self.jacobian(), w)`.
    pub fn jacobian_transpose_mul(&self, w: &Wrench) -> Joints {
        let f = w.to_array().map(UnitFactor::new);
        let mut tau = [Fx::ZERO; 6];
        for (t, col) in tau.iter_mut().zip(self.jac30.iter()) {
            let mut s = 0i64;
            for (fi, u) in f.iter().zip(col.iter()) {
                s = s.wrapping_add(fi.mul30(*u));
            }
            *t = Fx(s);
        }
        tau
    }

    /// `(Jᵀ · w, J_vᵀ · f)`: the wrench's joint torques and its force's
    /// share (`w` with its torque zeroed), exactly
    /// `(self.jacobian_transpose_mul(w), self.jacobian_transpose_mul(&Wrench
    /// { force: w.force, torque: Vec3::ZERO }))` for the cost of the first:
    /// a zero torque's products are zero, and the wrapping sum of the six
    /// products is that of the force's three plus that of the torque's.
    pub fn jacobian_transpose_mul_split(&self, w: &Wrench) -> (Joints, Joints) {
        let [f0, f1, f2, f3, f4, f5] = w.to_array().map(UnitFactor::new);
        let mut tau = [Fx::ZERO; 6];
        let mut tau_f = [Fx::ZERO; 6];
        for ((t, tf), col) in tau.iter_mut().zip(tau_f.iter_mut()).zip(self.jac30.iter()) {
            let [u0, u1, u2, u3, u4, u5] = *col;
            let s = f0
                .mul30(u0)
                .wrapping_add(f1.mul30(u1))
                .wrapping_add(f2.mul30(u2));
            *tf = Fx(s);
            *t = Fx(s
                .wrapping_add(f3.mul30(u3))
                .wrapping_add(f4.mul30(u4))
                .wrapping_add(f5.mul30(u5)));
        }
        (tau, tau_f)
    }

    /// `J_vᵀ · f`: exactly `self.jacobian_transpose_mul(&Wrench { force: f,
    /// torque: Vec3::ZERO })` (a zero torque's products are zero) in half
    /// the products.
    pub fn jacobian_transpose_mul_force(&self, f: Vec3) -> Joints {
        let f = f.to_array().map(UnitFactor::new);
        let mut tau = [Fx::ZERO; 6];
        for (t, col) in tau.iter_mut().zip(self.jac30.iter()) {
            let mut s = 0i64;
            for (fi, u) in f.iter().zip(col.iter()) {
                s = s.wrapping_add(fi.mul30(*u));
            }
            *t = Fx(s);
        }
        tau
    }

    /// `R · v` for the handle rotation: exactly `handle_rot().mul_vec_unit(v)`.
    pub fn rot_mul(&self, v: Vec3) -> Vec3 {
        let f = v.to_array().map(UnitFactor::new);
        let mut r = [0i64; 3];
        for (fj, col) in f.iter().zip(self.rot30.iter()) {
            for (o, u) in r.iter_mut().zip(col.iter()) {
                *o = o.wrapping_add(fj.mul30(*u));
            }
        }
        Vec3::from_array(r.map(Fx))
    }

    /// `Rᵀ · v`: exactly `handle_rot().tmul_vec_unit(v)`.
    pub fn rot_tmul(&self, v: Vec3) -> Vec3 {
        let f = v.to_array().map(UnitFactor::new);
        let mut r = [Fx::ZERO; 3];
        for (o, col) in r.iter_mut().zip(self.rot30.iter()) {
            let mut s = 0i64;
            for (fj, u) in f.iter().zip(col.iter()) {
                s = s.wrapping_add(fj.mul30(*u));
            }
            *o = Fx(s);
        }
        Vec3::from_array(r)
    }
}

/// Which optional parts [`kinematics_with`] computes; a part left out keeps
/// its [`Kinematics::ZERO`] value (identity orientation, rotor inertia).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Parts {
    /// The handle orientation as a quaternion (`handle.orientation`).
    pub orientation: bool,
    /// The diagonal joint inertia.
    pub inertia: bool,
}

impl Parts {
    /// Everything.
    pub const ALL: Parts = Parts {
        orientation: true,
        inertia: true,
    };
    /// What the simulated arm uses: rotation (force sensor), Jacobian
    /// (user torques), gravity, inertia; not the quaternion.
    pub const SIMULATOR: Parts = Parts {
        orientation: false,
        inertia: true,
    };
    /// What the state model and the controller use: the pose with its
    /// quaternion, rotation, Jacobian, gravity; not the inertia.
    pub const STATE_MODEL: Parts = Parts {
        orientation: true,
        inertia: false,
    };
}

/// A Q2.30 raw value (30 fractional bits in an `i64`, see `fixed`'s
/// "Formats inside the arm's kinematics"). Every kinematic quantity of this
/// arm is below 2.3 in magnitude (axis and rotation entries ≤ 1, points and
/// lever arms ≤ `H0 + L1 + L2 + L3` = 1.13 m), so a raw is below 2^31.2 and
/// a product of two below 2^62.4: one 64-bit multiply, no saturation
/// needed, wrapping operations that cannot wrap.
type Q = i64;

/// Q2.30 product, rounded to nearest (error ≤ 2^-31 = 4.7e-10, and
/// unbiased: truncation would push every product the same way).
const fn qm(a: Q, b: Q) -> Q {
    a.wrapping_mul(b).wrapping_add(1 << 29) >> 30
}

/// Q32.32 → Q2.30 (drops two bits, toward −∞).
const fn q_of(x: Fx) -> Q {
    x.0 >> 2
}

/// Q2.30 → Q32.32 (exact: the result has two zero low bits, so a later
/// [`Fx::mul_unit`] by it is exactly `mul_sat`).
const fn fx_of(x: Q) -> Fx {
    Fx(x << 2)
}

/// A 3-vector of Q2.30 raws.
#[derive(Clone, Copy)]
struct Q3 {
    x: Q,
    y: Q,
    z: Q,
}

impl Q3 {
    const ZERO: Q3 = Q3::new(0, 0, 0);

    const fn new(x: Q, y: Q, z: Q) -> Q3 {
        Q3 { x, y, z }
    }

    const fn add(self, o: Q3) -> Q3 {
        Q3::new(
            self.x.wrapping_add(o.x),
            self.y.wrapping_add(o.y),
            self.z.wrapping_add(o.z),
        )
    }

    const fn sub(self, o: Q3) -> Q3 {
        Q3::new(
            self.x.wrapping_sub(o.x),
            self.y.wrapping_sub(o.y),
            self.z.wrapping_sub(o.z),
        )
    }

    const fn scale(self, k: Q) -> Q3 {
        Q3::new(qm(self.x, k), qm(self.y, k), qm(self.z, k))
    }

    const fn dot(self, o: Q3) -> Q {
        qm(self.x, o.x)
            .wrapping_add(qm(self.y, o.y))
            .wrapping_add(qm(self.z, o.z))
    }

    const fn cross(self, o: Q3) -> Q3 {
        Q3::new(
            qm(self.y, o.z).wrapping_sub(qm(self.z, o.y)),
            qm(self.z, o.x).wrapping_sub(qm(self.x, o.z)),
            qm(self.x, o.y).wrapping_sub(qm(self.y, o.x)),
        )
    }

    const fn fx(self) -> Vec3 {
        Vec3::new(fx_of(self.x), fx_of(self.y), fx_of(self.z))
    }
}

/// Weight of each body along z (−m·g), N.
const WEIGHT: [Fx; 3] = [
    MASS[0].mul_sat(GRAVITY).neg_sat(),
    MASS[1].mul_sat(GRAVITY).neg_sat(),
    MASS[2].mul_sat(GRAVITY).neg_sat(),
];

/// [`WEIGHT`] as product factors.
const WEIGHT_FACTOR: [UnitFactor; 3] = [
    UnitFactor::new(WEIGHT[0]),
    UnitFactor::new(WEIGHT[1]),
    UnitFactor::new(WEIGHT[2]),
];

/// Forward kinematics, Jacobian, gravity torques and diagonal inertia.
pub fn kinematics(q: &Joints) -> Kinematics {
    kinematics_with(q, Parts::ALL)
}

/// Forward kinematics, Jacobian and gravity torques, plus the optional
/// `parts`, in one evaluation at `q`.
///
/// Computed in Q2.30 (see [`Q`]): the frames come from the joint sines and
/// cosines ([`Fx::sin_cos_unit`], 6 evaluations, `q2 + q3` as one angle)
/// by elementary rotations, which touch two columns each, instead of full
/// matrix products. Error against the f64 model (asserted in
/// `tests/dynamics.rs`, bound 1e-7 for each): sines ≤ 1.3e-9, each Q2.30
/// product ≤ 4.7e-10 (rounded), about ten products deep: handle 2.3e-9 m,
/// Jacobian 3.9e-9, inertia 4.1e-9 kg·m², gravity (weights up to 9.8 N
/// times Q2.30 lever arms) 3.7e-8 N·m, the largest errors over 2000 random
/// configurations.
#[inline(never)]
pub fn kinematics_with(q: &Joints, parts: Parts) -> Kinematics {
    let [q1, q2, q3, q4, q5, q6] = *q;
    let sc = |a: Fx| {
        let (s, c) = a.sin_cos_unit();
        (q_of(s), q_of(c))
    };
    let (s1, c1) = sc(q1);
    let (s2, c2) = sc(q2);
    let (s23, c23) = sc(q2.add_sat(q3));
    let (s4, c4) = sc(q4);
    let (s5, c5) = sc(q5);
    let (s6, c6) = sc(q6);
    // Columns of R1 = Rz(q1), R1·Ry(q2), R1·Ry(q2+q3), then ·Rx(q4), ·Ry(q5),
    // ·Rx(q6): R·Ry mixes columns x and z, R·Rx columns y and z.
    let y1 = Q3::new(s1.wrapping_neg(), c1, 0);
    let x12 = Q3::new(qm(c2, c1), qm(c2, s1), s2.wrapping_neg());
    let x123 = Q3::new(qm(c23, c1), qm(c23, s1), s23.wrapping_neg());
    let z123 = Q3::new(qm(s23, c1), qm(s23, s1), c23);
    let y4 = y1.scale(c4).add(z123.scale(s4));
    let z4 = z123.scale(c4).sub(y1.scale(s4));
    let x5 = x123.scale(c5).sub(z4.scale(s5));
    let z5 = x123.scale(s5).add(z4.scale(c5));
    let y6 = y4.scale(c6).add(z5.scale(s6));
    let z6 = z5.scale(c6).sub(y4.scale(s6));

    let p_s = Q3::new(0, 0, q_of(H0));
    let p_e = p_s.add(x12.scale(q_of(L1)));
    let p_w = p_e.add(x123.scale(q_of(L2)));
    let p_h = p_w.add(x5.scale(q_of(L3)));

    // Joint axes (world) and points on them.
    let z = [Q3::new(0, 0, 1 << 30), y1, y1, x123, y4, x5];
    let p = [Q3::ZERO, p_s, p_e, p_w, p_w, p_w];

    let mut jac30 = [[0i64; 6]; 6];
    for ((col, zi), pi) in jac30.iter_mut().zip(z.iter()).zip(p.iter()) {
        let lin = zi.cross(p_h.sub(*pi));
        *col = [lin.x, lin.y, lin.z, zi.x, zi.y, zi.z];
    }

    // Centres of mass and the joints each body is distal to.
    let com = [
        p_s.add(x12.scale(q_of(L1) >> 1)),
        p_e.add(x123.scale(q_of(L2) >> 1)),
        p_w.add(x5.scale(q_of(L3) >> 1)),
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
        let mut moment_of_inertia: Q = 0;
        for (((c, w), m), lj) in com
            .iter()
            .zip(WEIGHT_FACTOR.iter())
            .zip(MASS.iter())
            .zip(last_joint.iter())
        {
            if i <= *lj {
                // z·(r × (0, 0, w)) = w·(z_x·r_y − z_y·r_x)
                let r = c.sub(*pi);
                let lever = qm(zi.x, r.y).wrapping_sub(qm(zi.y, r.x));
                // `w.mul_unit(fx_of(lever))` with the weight split at
                // compile time: |lever| ≤ 1.14·2^30 (a lever arm of this
                // arm) is the factor mul_unit takes, unclamped, and
                // |w·lever| < 12 N·m cannot saturate: the same value, and
                // so is the plain sum of three such torques.
                *g = Fx(g.0.wrapping_add(w.mul30(lever)));
                if parts.inertia {
                    // squared distance to the axis: |r|² − (r·z)²
                    let a = r.dot(*zi);
                    let d2 = r.dot(r).wrapping_sub(qm(a, a)).max(0);
                    moment_of_inertia = moment_of_inertia.wrapping_add(qm(q_of(*m), d2));
                }
            }
        }
        *inn = inn.add_sat(fx_of(moment_of_inertia));
    }

    let rot30 = [[x5.x, x5.y, x5.z], [y6.x, y6.y, y6.z], [z6.x, z6.y, z6.z]];
    Kinematics {
        handle: Pose {
            position: p_h.fx(),
            orientation: if parts.orientation {
                Quat::from_mat3(&Mat3::from_cols(x5.fx(), y6.fx(), z6.fx()))
            } else {
                Quat::IDENTITY
            },
        },
        rot30,
        jac30,
        gravity,
        inertia,
    }
}

/// `J · q̇`: the handle twist for joint speeds `qd`. `j`'s entries are at
/// most 2 in magnitude (this arm's: ≤ 1.13), so the products are
/// [`Fx::mul_unit`]'s, two multiplies each with each speed split once
/// (`fixed::UnitFactor`: speeds clamped to ±2^27): exactly `mul_sat` for
/// the Jacobian of [`kinematics`], and the sums cannot overflow.
pub fn jacobian_mul(j: &[Twist; 6], qd: &Joints) -> Twist {
    let mut t = [0i64; 6];
    for (col, v) in j.iter().zip(qd.iter()) {
        let f = UnitFactor::new(*v);
        for (o, u) in t.iter_mut().zip(col.to_array().iter()) {
            *o = o.wrapping_add(f.mul(*u));
        }
    }
    Twist::from_array(t.map(Fx))
}

/// `Jᵀ · w`: joint torques producing the handle wrench `w` (force at the
/// handle point, torque), base frame. Products as in [`jacobian_mul`]
/// (wrench components clamped to ±2^27 N, N·m).
pub fn jacobian_transpose_mul(j: &[Twist; 6], w: &Wrench) -> Joints {
    let f = w.to_array().map(UnitFactor::new);
    let mut tau = [Fx::ZERO; 6];
    for (t, col) in tau.iter_mut().zip(j.iter()) {
        let mut s = 0i64;
        for (fi, u) in f.iter().zip(col.to_array().iter()) {
            s = s.wrapping_add(fi.mul(*u));
        }
        *t = Fx(s);
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
