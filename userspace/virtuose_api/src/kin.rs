//! Client-side geometry of the VirtuoseAPI layer (f64): the arm's joint
//! angles from the handle pose (closed-form inverse of
//! `hap_core::arm::kinematics`), joint speeds from the handle twist, joint
//! bounds, the coupling set-point that makes the controller apply a given
//! wrench, and the homogeneous-matrix conversions.
//!
//! Frames: the controller reports the handle in the client's world frame,
//! `world = base ∘ (speed_factor · arm)` (see `hap_core::control`). The
//! *physical* pose is the handle in the arm base frame: `base⁻¹ ∘ world`
//! with the position divided by the speed factor. It is exact while no
//! indexing offset is active (the offset is the controller's and is not
//! reported).

use hap_core::arm;
use hap_core::fixed::{Fx, Joints};

/// Number of joints of the arm (`virtGetNbAxes`).
pub const NB_AXES: usize = 6;

pub type Quat = [f64; 4]; // x, y, z, w

pub fn qmul(a: &Quat, b: &Quat) -> Quat {
    [
        a[3] * b[0] + a[0] * b[3] + a[1] * b[2] - a[2] * b[1],
        a[3] * b[1] - a[0] * b[2] + a[1] * b[3] + a[2] * b[0],
        a[3] * b[2] + a[0] * b[1] - a[1] * b[0] + a[2] * b[3],
        a[3] * b[3] - a[0] * b[0] - a[1] * b[1] - a[2] * b[2],
    ]
}

pub fn qconj(q: &Quat) -> Quat {
    [-q[0], -q[1], -q[2], q[3]]
}

pub fn qnorm(q: &Quat) -> Quat {
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    if n < 1e-12 {
        [0.0, 0.0, 0.0, 1.0]
    } else {
        [q[0] / n, q[1] / n, q[2] / n, q[3] / n]
    }
}

pub fn qrot(q: &Quat, v: [f64; 3]) -> [f64; 3] {
    let p = qmul(&qmul(q, &[v[0], v[1], v[2], 0.0]), &qconj(q));
    [p[0], p[1], p[2]]
}

/// Row-major rotation matrix of a unit quaternion.
pub fn qmat(q: &Quat) -> [[f64; 3]; 3] {
    let [x, y, z, w] = qnorm(q);
    [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - z * w),
            2.0 * (x * z + y * w),
        ],
        [
            2.0 * (x * y + z * w),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - x * w),
        ],
        [
            2.0 * (x * z - y * w),
            2.0 * (y * z + x * w),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ]
}

/// Unit quaternion of a rotation matrix (Shepperd's method).
pub fn mat_q(m: &[[f64; 3]; 3]) -> Quat {
    let tr = m[0][0] + m[1][1] + m[2][2];
    let q = if tr > 0.0 {
        let s = (tr + 1.0).sqrt() * 2.0;
        [
            (m[2][1] - m[1][2]) / s,
            (m[0][2] - m[2][0]) / s,
            (m[1][0] - m[0][1]) / s,
            0.25 * s,
        ]
    } else if m[0][0] > m[1][1] && m[0][0] > m[2][2] {
        let s = (1.0 + m[0][0] - m[1][1] - m[2][2]).sqrt() * 2.0;
        [
            0.25 * s,
            (m[0][1] + m[1][0]) / s,
            (m[0][2] + m[2][0]) / s,
            (m[2][1] - m[1][2]) / s,
        ]
    } else if m[1][1] > m[2][2] {
        let s = (1.0 + m[1][1] - m[0][0] - m[2][2]).sqrt() * 2.0;
        [
            (m[0][1] + m[1][0]) / s,
            0.25 * s,
            (m[1][2] + m[2][1]) / s,
            (m[0][2] - m[2][0]) / s,
        ]
    } else {
        let s = (1.0 + m[2][2] - m[0][0] - m[1][1]).sqrt() * 2.0;
        [
            (m[0][2] + m[2][0]) / s,
            (m[1][2] + m[2][1]) / s,
            0.25 * s,
            (m[1][0] - m[0][1]) / s,
        ]
    };
    let q = qnorm(&q);
    if q[3] < 0.0 {
        [-q[0], -q[1], -q[2], -q[3]]
    } else {
        q
    }
}

/// `[x,y,z,qx,qy,qz,qw]` → row-major 4×4 homogeneous matrix (translation in
/// elements 3, 7, 11; last row 0 0 0 1).
pub fn pose_to_matrix(d: &[f32; 7]) -> [f32; 16] {
    let q = [d[3] as f64, d[4] as f64, d[5] as f64, d[6] as f64];
    let r = qmat(&q);
    let mut m = [0f32; 16];
    for i in 0..3 {
        for j in 0..3 {
            m[i * 4 + j] = r[i][j] as f32;
        }
        m[i * 4 + 3] = d[i];
    }
    m[15] = 1.0;
    m
}

/// Row-major 4×4 homogeneous matrix → `[x,y,z,qx,qy,qz,qw]` (qw ≥ 0).
pub fn matrix_to_pose(m: &[f32; 16]) -> [f32; 7] {
    let mut r = [[0f64; 3]; 3];
    for (i, row) in r.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = m[i * 4 + j] as f64;
        }
    }
    let q = mat_q(&r);
    [
        m[3],
        m[7],
        m[11],
        q[0] as f32,
        q[1] as f32,
        q[2] as f32,
        q[3] as f32,
    ]
}

/// The client's view of the arm: base frame and speed factor.
#[derive(Clone, Copy, Debug)]
pub struct Frames {
    pub base: [f32; 7],
    pub speed_factor: f64,
    pub force_factor: f64,
}

impl Default for Frames {
    fn default() -> Self {
        Frames {
            base: [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
            speed_factor: 1.0,
            force_factor: 1.0,
        }
    }
}

fn q7(p: &[f32; 7]) -> Quat {
    qnorm(&[p[3] as f64, p[4] as f64, p[5] as f64, p[6] as f64])
}

fn sub3(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

impl Frames {
    /// Handle pose in the world → handle pose in the arm base frame.
    pub fn physical_pose(&self, world: &[f32; 7]) -> [f32; 7] {
        let qb = q7(&self.base);
        let pb = [
            self.base[0] as f64,
            self.base[1] as f64,
            self.base[2] as f64,
        ];
        let pw = [world[0] as f64, world[1] as f64, world[2] as f64];
        let sf = if self.speed_factor > 0.0 {
            self.speed_factor
        } else {
            1.0
        };
        let p = qrot(&qconj(&qb), sub3(pw, pb));
        let q = qnorm(&qmul(&qconj(&qb), &q7(world)));
        [
            (p[0] / sf) as f32,
            (p[1] / sf) as f32,
            (p[2] / sf) as f32,
            q[0] as f32,
            q[1] as f32,
            q[2] as f32,
            q[3] as f32,
        ]
    }

    /// Handle twist in the world → in the arm base frame.
    pub fn physical_twist(&self, world: &[f32; 6]) -> [f32; 6] {
        let qi = qconj(&q7(&self.base));
        let sf = if self.speed_factor > 0.0 {
            self.speed_factor
        } else {
            1.0
        };
        let v = qrot(&qi, [world[0] as f64, world[1] as f64, world[2] as f64]);
        let w = qrot(&qi, [world[3] as f64, world[4] as f64, world[5] as f64]);
        [
            (v[0] / sf) as f32,
            (v[1] / sf) as f32,
            (v[2] / sf) as f32,
            w[0] as f32,
            w[1] as f32,
            w[2] as f32,
        ]
    }
}

/// Limit the norms of a wrench's force and torque (`virtSaturateTorque`).
pub fn saturate(w: &[f32; 6], max_force: f32, max_torque: f32) -> [f32; 6] {
    let mut out = *w;
    for (part, max) in [(0usize, max_force), (3usize, max_torque)] {
        let n = (w[part] as f64)
            .hypot(w[part + 1] as f64)
            .hypot(w[part + 2] as f64);
        if n > max as f64 && n > 0.0 {
            let k = max as f64 / n;
            for v in &mut out[part..part + 3] {
                *v = (*v as f64 * k) as f32;
            }
        }
    }
    out
}

/// The coupling set-point (virtual object pose, world frame) that makes the
/// controller's spring (`k_lin` N/m, `k_rot` N·m/rad, arm units) apply the
/// client wrench `w` (world frame, client units) to the handle at `handle`:
/// `F_arm = k_lin·(target − handle)` and `τ_arm = k_rot·2·sin(θ/2)·axis`
/// (`Quat::error_vector`), with client force = `force_factor`·arm force and
/// client torque = `force_factor·speed_factor`·arm torque. A torque beyond
/// the spring's reach (|τ_arm| > 2·k_rot) is limited to it.
pub fn force_setpoint(
    frames: &Frames,
    handle: &[f32; 7],
    w: &[f32; 6],
    k_lin: f64,
    k_rot: f64,
) -> [f32; 7] {
    let ff = if frames.force_factor > 0.0 {
        frames.force_factor
    } else {
        1.0
    };
    let sf = if frames.speed_factor > 0.0 {
        frames.speed_factor
    } else {
        1.0
    };
    let mut out = *handle;
    if k_lin > 0.0 {
        for i in 0..3 {
            // world offset = R_b·sf·(F_arm/k), F_world = R_b·ff·F_arm
            out[i] = (handle[i] as f64 + w[i] as f64 * sf / (ff * k_lin)) as f32;
        }
    }
    if k_rot > 0.0 {
        let t = [
            w[3] as f64 / (ff * sf * k_rot),
            w[4] as f64 / (ff * sf * k_rot),
            w[5] as f64 / (ff * sf * k_rot),
        ];
        let n = (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt();
        if n > 1e-12 {
            // |e| = 2·sin(θ/2) = n  →  θ = 2·asin(n/2)
            let half = (n / 2.0).min(1.0).asin();
            let s = half.sin() / n;
            let dq = [t[0] * s, t[1] * s, t[2] * s, half.cos()];
            let q = qnorm(&qmul(&dq, &q7(handle)));
            for i in 0..4 {
                out[3 + i] = q[i] as f32;
            }
        }
    }
    out
}

fn wrap(a: f64) -> f64 {
    let mut a = a;
    while a > std::f64::consts::PI {
        a -= 2.0 * std::f64::consts::PI;
    }
    while a < -std::f64::consts::PI {
        a += 2.0 * std::f64::consts::PI;
    }
    a
}

fn limits() -> ([f64; 6], [f64; 6]) {
    let mut lo = [0.0; 6];
    let mut hi = [0.0; 6];
    for i in 0..6 {
        lo[i] = arm::Q_MIN[i].to_f64();
        hi[i] = arm::Q_MAX[i].to_f64();
    }
    (lo, hi)
}

/// Distance outside the joint limits (0 inside).
fn excess(q: &[f64; 6]) -> f64 {
    let (lo, hi) = limits();
    q.iter()
        .zip(lo.iter().zip(hi.iter()))
        .map(|(q, (l, h))| (l - q).max(0.0) + (q - h).max(0.0))
        .sum()
}

/// Joint angles of the arm for a handle pose in the arm base frame
/// (inverse of `hap_core::arm::kinematics`). Among the solutions (elbow
/// sign, wrist flip) the one inside the joint limits, closest to `prev` if
/// given, is returned. `None` when the pose is out of reach.
pub fn inverse_kinematics(phys: &[f32; 7], prev: Option<&[f64; 6]>) -> Option<[f64; 6]> {
    let (h0, l1, l2, l3) = (
        arm::H0.to_f64(),
        arm::L1.to_f64(),
        arm::L2.to_f64(),
        arm::L3.to_f64(),
    );
    let r6 = qmat(&q7(phys));
    let ph = [phys[0] as f64, phys[1] as f64, phys[2] as f64];
    // x axis of the handle = x axis of R1…R5: the wrist centre is L3 behind.
    let pw = [
        ph[0] - l3 * r6[0][0],
        ph[1] - l3 * r6[1][0],
        ph[2] - l3 * r6[2][0],
    ];
    let r = pw[0].hypot(pw[1]);
    let h = pw[2] - h0;
    let c3 = (r * r + h * h - l1 * l1 - l2 * l2) / (2.0 * l1 * l2);
    if !(c3.is_finite()) || c3.abs() > 1.0 + 1e-3 {
        return None;
    }
    let c3 = c3.clamp(-1.0, 1.0);
    let mut best: Option<([f64; 6], f64)> = None;
    // Facing the wrist (q1) or reaching over the top (q1 + π, r → −r).
    for (q1, rr) in [
        (pw[1].atan2(pw[0]), r),
        (wrap(pw[1].atan2(pw[0]) + std::f64::consts::PI), -r),
    ] {
        for q3 in [c3.acos(), -c3.acos()] {
            // r = L1·c2 + L2·c23, h = −(L1·s2 + L2·s23)
            let q2 = (-h).atan2(rr) - (l2 * q3.sin()).atan2(l1 + l2 * q3.cos());
            let q2 = wrap(q2);
            // Wrist: R123ᵀ·R6 = Rx(q4)·Ry(q5)·Rx(q6)
            let (s1, c1) = q1.sin_cos();
            let (s23, c23) = (q2 + q3).sin_cos();
            // R123 = Rz(q1)·Ry(q2+q3), row-major
            let r123 = [
                [c1 * c23, -s1, c1 * s23],
                [s1 * c23, c1, s1 * s23],
                [-s23, 0.0, c23],
            ];
            let mut w = [[0.0; 3]; 3];
            for (i, row) in w.iter_mut().enumerate() {
                for (j, v) in row.iter_mut().enumerate() {
                    *v = (0..3).map(|k| r123[k][i] * r6[k][j]).sum();
                }
            }
            let c5 = w[0][0].clamp(-1.0, 1.0);
            for sign in [1.0, -1.0] {
                let q5 = sign * c5.acos();
                let (q4, q6) = if q5.sin().abs() < 1e-9 {
                    // Wrist singularity: only q4 + q6 is defined; keep q4.
                    let q4 = prev.map(|p| p[3]).unwrap_or(0.0);
                    let sum = w[2][1].atan2(w[1][1]);
                    (q4, wrap(sum - q4))
                } else {
                    (
                        (sign * w[1][0]).atan2(-sign * w[2][0]),
                        (sign * w[0][1]).atan2(sign * w[0][2]),
                    )
                };
                let q = [q1, q2, q3, q4, q5, q6];
                let mut cost = excess(&q) * 1e3;
                if let Some(p) = prev {
                    cost += q
                        .iter()
                        .zip(p.iter())
                        .map(|(a, b)| wrap(a - b).abs())
                        .sum::<f64>();
                }
                if best.map(|(_, c)| cost < c).unwrap_or(true) {
                    best = Some((q, cost));
                }
            }
        }
    }
    best.map(|(q, _)| q)
}

/// Joint speeds for a handle twist in the arm base frame at `q`: damped
/// least squares on the arm's Jacobian, `(JᵀJ + λ²I)·q̇ = Jᵀ·v`.
pub fn joint_speeds(q: &[f64; 6], twist: &[f32; 6]) -> [f64; 6] {
    let mut qj: Joints = [Fx::ZERO; 6];
    for (d, s) in qj.iter_mut().zip(q.iter()) {
        *d = Fx::from_f64(*s);
    }
    let k = arm::kinematics(&qj);
    // j[r][c]: row r of the twist (v, w), column c = joint c
    let mut j = [[0.0f64; 6]; 6];
    for (c, col) in k.jacobian().iter().enumerate() {
        let l = col.linear.to_f64();
        let a = col.angular.to_f64();
        for r in 0..3 {
            j[r][c] = l[r];
            j[r + 3][c] = a[r];
        }
    }
    let lambda2 = 1e-6;
    let mut m = [[0.0f64; 7]; 6];
    for r in 0..6 {
        for c in 0..6 {
            m[r][c] = (0..6).map(|k| j[k][r] * j[k][c]).sum::<f64>();
        }
        m[r][r] += lambda2;
        m[r][6] = (0..6).map(|k| j[k][r] * twist[k] as f64).sum::<f64>();
    }
    // Gaussian elimination with partial pivoting (m is SPD).
    for c in 0..6 {
        let p = (c..6)
            .max_by(|a, b| m[*a][c].abs().total_cmp(&m[*b][c].abs()))
            .unwrap_or(c);
        m.swap(c, p);
        let d = m[c][c];
        if d.abs() < 1e-15 {
            continue;
        }
        let pivot = m[c];
        for (r, row) in m.iter_mut().enumerate() {
            if r != c {
                let f = row[c] / d;
                for (v, p) in row.iter_mut().zip(pivot.iter()).skip(c) {
                    *v -= f * p;
                }
            }
        }
    }
    let mut out = [0.0; 6];
    for (i, o) in out.iter_mut().enumerate() {
        if m[i][i].abs() > 1e-15 {
            *o = m[i][6] / m[i][i];
        }
    }
    out
}

/// Rotation vector (axis × angle, rad, angle in [0, π]) of a unit quaternion.
pub fn rotvec(q: &Quat) -> [f64; 3] {
    let q = qnorm(q);
    let q = if q[3] < 0.0 {
        [-q[0], -q[1], -q[2], -q[3]]
    } else {
        q
    };
    let s = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt();
    if s < 1e-12 {
        return [2.0 * q[0], 2.0 * q[1], 2.0 * q[2]];
    }
    let angle = 2.0 * s.atan2(q[3]);
    [q[0] / s * angle, q[1] / s * angle, q[2] / s * angle]
}

/// Unit quaternion of a rotation vector (axis × angle, rad).
pub fn from_rotvec(v: [f64; 3]) -> Quat {
    let angle = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if angle < 1e-12 {
        return qnorm(&[v[0] / 2.0, v[1] / 2.0, v[2] / 2.0, 1.0]);
    }
    let k = (angle / 2.0).sin() / angle;
    [v[0] * k, v[1] * k, v[2] * k, (angle / 2.0).cos()]
}

/// An indexing offset kept by the library (`virtForceShiftButton`): the
/// application sees `avatar = offset ∘ handle`, position `handle + dp`,
/// orientation `dq ⊗ handle` (world frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Offset {
    pub dp: [f64; 3],
    pub dq: Quat,
}

impl Default for Offset {
    fn default() -> Self {
        Offset {
            dp: [0.0; 3],
            dq: [0.0, 0.0, 0.0, 1.0],
        }
    }
}

impl Offset {
    /// The controller's handle pose → the application's.
    pub fn apply(&self, p: &[f32; 7]) -> [f32; 7] {
        let q = qnorm(&qmul(&self.dq, &q7(p)));
        [
            (p[0] as f64 + self.dp[0]) as f32,
            (p[1] as f64 + self.dp[1]) as f32,
            (p[2] as f64 + self.dp[2]) as f32,
            q[0] as f32,
            q[1] as f32,
            q[2] as f32,
            q[3] as f32,
        ]
    }

    /// The application's pose → the controller's (inverse of `apply`).
    pub fn remove(&self, p: &[f32; 7]) -> [f32; 7] {
        let q = qnorm(&qmul(&qconj(&self.dq), &q7(p)));
        [
            (p[0] as f64 - self.dp[0]) as f32,
            (p[1] as f64 - self.dp[1]) as f32,
            (p[2] as f64 - self.dp[2]) as f32,
            q[0] as f32,
            q[1] as f32,
            q[2] as f32,
            q[3] as f32,
        ]
    }

    /// The offset that shows `handle` as `avatar`: translation always, the
    /// rotation too when `rotation`, else the rotation of `self` is kept.
    pub fn between(&self, avatar: &[f32; 7], handle: &[f32; 7], rotation: bool) -> Offset {
        let mut o = *self;
        for i in 0..3 {
            o.dp[i] = avatar[i] as f64 - handle[i] as f64;
        }
        if rotation {
            o.dq = qnorm(&qmul(&q7(avatar), &qconj(&q7(handle))));
        }
        o
    }
}

/// The coupling set-point of a quasi-static virtual object
/// (`virtAttachQSVO`): the controller's spring (stiffness K per axis)
/// pulled to a point between the handle and the object's `target`, at the
/// fraction `s = Ks / K` (each in [0, 1]) of the way, applies
/// `Ks·(target − handle)` on each translation axis and, on each axis of
/// the rotation vector from the handle's orientation to the target's,
/// `s_rot·K_rot` times that angle (for small angles: `Ks_rot·angle`).
pub fn qsvo_setpoint(
    handle: &[f32; 7],
    target: &[f32; 7],
    s_lin: [f64; 3],
    s_rot: [f64; 3],
) -> [f32; 7] {
    let mut out = *handle;
    for i in 0..3 {
        let s = s_lin[i].clamp(0.0, 1.0);
        out[i] = (handle[i] as f64 + s * (target[i] as f64 - handle[i] as f64)) as f32;
    }
    let qh = q7(handle);
    let e = rotvec(&qmul(&q7(target), &qconj(&qh)));
    let scaled = [
        e[0] * s_rot[0].clamp(0.0, 1.0),
        e[1] * s_rot[1].clamp(0.0, 1.0),
        e[2] * s_rot[2].clamp(0.0, 1.0),
    ];
    let q = qnorm(&qmul(&from_rotvec(scaled), &qh));
    for i in 0..4 {
        out[3 + i] = q[i] as f32;
    }
    out
}

/// Margin to a joint limit under which `virtIsInBounds` reports it, rad.
pub const BOUND_MARGIN_RAD: f64 = 0.02;

/// `VIRT_BOUND_*` bits of a joint configuration: an axis within
/// [`BOUND_MARGIN_RAD`] of its limit. Yaw and roll axes (1, 4, 6): LEFT at
/// the upper limit (positive angle), RIGHT at the lower. Pitch axes (2, 3,
/// 5; a positive pitch lowers the link): INF at the upper limit, SUP at the
/// lower.
pub fn bounds(q: &[f64; 6]) -> u32 {
    // (bit at the lower limit, bit at the upper limit) per axis
    const BITS: [(u32, u32); 6] = [
        (0x0002, 0x0001), // axis 1: RIGHT, LEFT
        (0x0004, 0x0008), // axis 2: SUP, INF
        (0x0010, 0x0020), // axis 3: SUP, INF
        (0x0040, 0x0080), // axis 4: RIGHT, LEFT
        (0x0100, 0x0200), // axis 5: SUP, INF
        (0x0800, 0x0400), // axis 6: RIGHT, LEFT
    ];
    let (lo, hi) = limits();
    let mut b = 0;
    for i in 0..6 {
        if q[i] <= lo[i] + BOUND_MARGIN_RAD {
            b |= BITS[i].0;
        }
        if q[i] >= hi[i] - BOUND_MARGIN_RAD {
            b |= BITS[i].1;
        }
    }
    b
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fk(q: &[f64; 6]) -> [f32; 7] {
        let mut qj: Joints = [Fx::ZERO; 6];
        for (d, s) in qj.iter_mut().zip(q.iter()) {
            *d = Fx::from_f64(*s);
        }
        let k = arm::kinematics(&qj);
        let p = k.handle.position.to_f64();
        let o = k.handle.orientation.to_f64();
        [
            p[0] as f32,
            p[1] as f32,
            p[2] as f32,
            o[0] as f32,
            o[1] as f32,
            o[2] as f32,
            o[3] as f32,
        ]
    }

    /// Deterministic pseudo-random joint configurations inside the limits.
    fn samples(n: usize) -> Vec<[f64; 6]> {
        let (lo, hi) = limits();
        let mut s: u64 = 0x9e37_79b9_7f4a_7c15;
        (0..n)
            .map(|_| {
                let mut q = [0.0; 6];
                for i in 0..6 {
                    s = s
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    let u = (s >> 11) as f64 / (1u64 << 53) as f64;
                    // stay 0.05 rad inside the limits and away from q5 = 0
                    q[i] = lo[i] + 0.05 + u * (hi[i] - lo[i] - 0.1);
                }
                if q[4].abs() < 0.05 {
                    q[4] = 0.3;
                }
                q
            })
            .collect()
    }

    #[test]
    fn inverse_kinematics_inverts_the_arm_model() {
        for q in samples(300) {
            let pose = fk(&q);
            let got = inverse_kinematics(&pose, Some(&q)).expect("reachable");
            // Same handle pose (several joint solutions may reach it)...
            let back = fk(&got);
            for i in 0..3 {
                assert!((back[i] - pose[i]).abs() < 1e-4, "{q:?} → {got:?}");
            }
            let dot: f32 = (3..7).map(|i| back[i] * pose[i]).sum();
            assert!(dot.abs() > 1.0 - 1e-5, "{q:?} → {got:?}");
            // ...and with the previous reading as a hint, the same joints.
            for i in 0..6 {
                assert!(wrap(got[i] - q[i]).abs() < 2e-3, "{q:?} → {got:?}");
            }
        }
        // Without a hint: a solution inside the limits for the work pose.
        let mut work = [0.0; 6];
        for (w, a) in work.iter_mut().zip(arm::WORK_Q.iter()) {
            *w = a.to_f64();
        }
        let got = inverse_kinematics(&fk(&work), None).unwrap();
        assert_eq!(excess(&got), 0.0, "{got:?}");
        assert!(inverse_kinematics(&[3.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], None).is_none());
    }

    #[test]
    fn joint_speeds_invert_the_jacobian() {
        for q in samples(50) {
            let qd = [0.1, -0.2, 0.3, 0.05, -0.1, 0.2];
            let mut qj: Joints = [Fx::ZERO; 6];
            for (d, s) in qj.iter_mut().zip(q.iter()) {
                *d = Fx::from_f64(*s);
            }
            let k = arm::kinematics(&qj);
            let mut v = [0f32; 6];
            for (c, col) in k.jacobian().iter().enumerate() {
                let l = col.linear.to_f64();
                let a = col.angular.to_f64();
                for r in 0..3 {
                    v[r] += (l[r] * qd[c]) as f32;
                    v[r + 3] += (a[r] * qd[c]) as f32;
                }
            }
            let got = joint_speeds(&q, &v);
            for i in 0..6 {
                assert!((got[i] - qd[i]).abs() < 2e-2, "{q:?}: {got:?}");
            }
        }
    }

    #[test]
    fn bounds_report_the_limit_reached() {
        let mut q = [0.0; 6];
        assert_eq!(bounds(&q), 0);
        q[0] = arm::Q_MAX[0].to_f64();
        q[1] = arm::Q_MIN[1].to_f64() + 0.01;
        q[5] = arm::Q_MIN[5].to_f64() - 0.1;
        assert_eq!(bounds(&q), 0x0001 | 0x0004 | 0x0800);
    }

    #[test]
    fn matrix_roundtrip() {
        let s = std::f32::consts::FRAC_1_SQRT_2;
        for d in [
            [0.1f32, -0.2, 0.3, 0.0, 0.0, s, s],
            [1.0, 2.0, 3.0, 0.5, 0.5, 0.5, 0.5],
            [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
        ] {
            let m = pose_to_matrix(&d);
            assert_eq!(m[15], 1.0);
            assert_eq!((m[3], m[7], m[11]), (d[0], d[1], d[2]));
            let back = matrix_to_pose(&m);
            let dot: f32 = (3..7).map(|i| back[i] * d[i]).sum();
            assert!(dot.abs() > 1.0 - 1e-6, "{d:?} {back:?}");
        }
        // 90° about z: x axis → y axis (column 0 = (0,1,0)).
        let m = pose_to_matrix(&[0.0, 0.0, 0.0, 0.0, 0.0, s, s]);
        assert!(m[0].abs() < 1e-6 && (m[4] - 1.0).abs() < 1e-6);
    }

    #[test]
    fn force_setpoint_matches_the_coupling_law() {
        let frames = Frames {
            base: [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
            speed_factor: 2.0,
            force_factor: 0.5,
        };
        let h = [0.5, 0.1, 0.3, 0.0, 0.0, 0.0, 1.0];
        let w = [3.0, 0.0, -1.5, 0.0, 0.0, 0.2];
        let t = force_setpoint(&frames, &h, &w, 1500.0, 10.0);
        // arm force = k·(target − handle)/sf, client force = ff·arm force
        let f = (t[0] - h[0]) as f64 / 2.0 * 1500.0 * 0.5;
        assert!((f - 3.0).abs() < 1e-3, "{f}");
        // torque: arm τ = k_rot·error_vector, client τ = ff·sf·arm τ
        let e = qmul(&q7(&t), &qconj(&q7(&h)));
        let tz = 2.0 * e[2] * 10.0 * 0.5 * 2.0;
        assert!((tz - 0.2).abs() < 1e-4, "{tz}");
        let s = saturate(&[30.0, 40.0, 0.0, 0.0, 0.0, 1.0], 10.0, 0.5);
        assert!((s[0] - 6.0).abs() < 1e-5 && (s[1] - 8.0).abs() < 1e-5);
        assert!((s[5] - 0.5).abs() < 1e-6);
    }

    #[test]
    fn rotation_vectors_round_trip() {
        for v in [
            [0.3, -0.2, 0.1],
            [0.0, 0.0, 3.0],
            [1e-9, 0.0, 0.0],
            [0.0; 3],
        ] {
            let back = rotvec(&from_rotvec(v));
            for i in 0..3 {
                assert!((back[i] - v[i]).abs() < 1e-9, "{v:?} -> {back:?}");
            }
        }
    }

    #[test]
    fn an_offset_is_undone_by_its_removal_and_joins_two_poses() {
        let s = std::f32::consts::FRAC_1_SQRT_2;
        let handle = [0.4f32, 0.1, 0.2, 0.0, 0.0, s, s];
        let avatar = [0.5f32, -0.1, 0.3, s, 0.0, 0.0, s];
        let o = Offset::default().between(&avatar, &handle, true);
        let shown = o.apply(&handle);
        for i in 0..7 {
            assert!((shown[i] - avatar[i]).abs() < 1e-6, "{shown:?}");
        }
        let back = o.remove(&shown);
        for i in 0..7 {
            assert!((back[i] - handle[i]).abs() < 1e-6, "{back:?}");
        }
        // Translation only: the rotation of the previous offset stays.
        let t = o.between(&avatar, &[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], false);
        assert_eq!(t.dq, o.dq);
        assert!((t.dp[0] - 0.5).abs() < 1e-6);
        assert_eq!(Offset::default().apply(&handle), handle);
    }

    #[test]
    fn the_quasi_static_setpoint_scales_the_springs_pull() {
        let h = [0.4f32, 0.0, 0.2, 0.0, 0.0, 0.0, 1.0];
        // 0.2 rad about z.
        let qz = from_rotvec([0.0, 0.0, 0.2]);
        let t = [0.5f32, 0.1, 0.2, 0.0, 0.0, qz[2] as f32, qz[3] as f32];
        // x at a quarter of the controller's stiffness, y above it (capped
        // at 1), z 0; rotation about z at half.
        let sp = qsvo_setpoint(&h, &t, [0.25, 3.0, 0.0], [0.0, 0.0, 0.5]);
        assert!((sp[0] - 0.425).abs() < 1e-6, "{sp:?}");
        assert!((sp[1] - 0.1).abs() < 1e-6, "{sp:?}");
        assert!((sp[2] - 0.2).abs() < 1e-6, "{sp:?}");
        let e = rotvec(&[sp[3] as f64, sp[4] as f64, sp[5] as f64, sp[6] as f64]);
        assert!((e[2] - 0.1).abs() < 1e-6 && e[0].abs() < 1e-9, "{e:?}");
        // Full stiffness: the set-point is the target.
        let full = qsvo_setpoint(&h, &t, [1.0; 3], [1.0; 3]);
        for i in 0..7 {
            assert!((full[i] - t[i]).abs() < 1e-6, "{full:?}");
        }
    }
}
