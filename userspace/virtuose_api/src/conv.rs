//! Float arrays (Haption's conventions) ⇄ hap-core fixed-point types.
//!
//! Pose: `[x, y, z, qx, qy, qz, qw]` (m, unit quaternion, scalar last).
//! Twist: `[vx, vy, vz, wx, wy, wz]` (m/s, rad/s).
//! Wrench: `[fx, fy, fz, tx, ty, tz]` (N, N·m).

use hap_core::fixed::{Fx, Pose, Quat, Twist, Vec3, Wrench};

use crate::VirtError;

fn finite(name: &str, v: &[f32]) -> Result<(), VirtError> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(VirtError::InvalidArgument(format!(
            "{name}: NaN or infinite value"
        )))
    }
}

fn v3(a: f32, b: f32, c: f32) -> Vec3 {
    Vec3::from_f64([a as f64, b as f64, c as f64])
}

fn f3(v: Vec3) -> [f32; 3] {
    let a = v.to_f64();
    [a[0] as f32, a[1] as f32, a[2] as f32]
}

/// A pose from `[x,y,z,qx,qy,qz,qw]`; the quaternion is normalised (an
/// all-zero quaternion is refused).
pub fn pose_from(name: &str, p: &[f32; 7]) -> Result<Pose, VirtError> {
    finite(name, p)?;
    let n = (p[3] as f64)
        .hypot(p[4] as f64)
        .hypot((p[5] as f64).hypot(p[6] as f64));
    if n < 1e-6 {
        return Err(VirtError::InvalidArgument(format!(
            "{name}: zero quaternion"
        )));
    }
    let q = |i: usize| Fx::from_f64(p[i] as f64 / n);
    Ok(Pose {
        position: v3(p[0], p[1], p[2]),
        orientation: Quat::new(q(3), q(4), q(5), q(6)),
    })
}

pub fn pose_to(p: &Pose) -> [f32; 7] {
    let a = f3(p.position);
    let q = &p.orientation;
    [
        a[0],
        a[1],
        a[2],
        q.x.to_f64() as f32,
        q.y.to_f64() as f32,
        q.z.to_f64() as f32,
        q.w.to_f64() as f32,
    ]
}

pub fn twist_from(name: &str, t: &[f32; 6]) -> Result<Twist, VirtError> {
    finite(name, t)?;
    Ok(Twist {
        linear: v3(t[0], t[1], t[2]),
        angular: v3(t[3], t[4], t[5]),
    })
}

pub fn twist_to(t: &Twist) -> [f32; 6] {
    let (a, b) = (f3(t.linear), f3(t.angular));
    [a[0], a[1], a[2], b[0], b[1], b[2]]
}

pub fn wrench_to(w: &Wrench) -> [f32; 6] {
    let (a, b) = (f3(w.force), f3(w.torque));
    [a[0], a[1], a[2], b[0], b[1], b[2]]
}

pub fn wrench_from(w: &[f32; 6]) -> Wrench {
    Wrench {
        force: v3(w[0], w[1], w[2]),
        torque: v3(w[3], w[4], w[5]),
    }
}

pub fn fx(name: &str, v: f32) -> Result<Fx, VirtError> {
    if v.is_finite() {
        Ok(Fx::from_f64(v as f64))
    } else {
        Err(VirtError::InvalidArgument(format!(
            "{name}: NaN or infinite value"
        )))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pose_roundtrip_and_normalisation() {
        let p = pose_from("p", &[0.1, -0.2, 0.3, 0.0, 0.0, 0.0, 2.0]).unwrap();
        let a = pose_to(&p);
        assert!((a[0] - 0.1).abs() < 1e-6 && (a[6] - 1.0).abs() < 1e-6);
        assert!(pose_from("p", &[0.0; 7]).is_err());
        assert!(pose_from("p", &[f32::NAN, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]).is_err());
        assert!(twist_from("t", &[0.0, 0.0, f32::INFINITY, 0.0, 0.0, 0.0]).is_err());
    }
}
