//! Fixed-point scalar and geometric types shared by every component.
//!
//! `Fx` is a signed Q32.32 number in an `i64`: range ±2^31 (±2.1e9), resolution
//! 2^-32 (2.3e-10). Physical quantities use SI units in `Fx` (m, rad, m/s,
//! rad/s, N, N·m, N/m, N·s/m, kg, s) unless a field's doc says otherwise.

/// Signed Q32.32 fixed-point number (SI units unless stated).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Fx(pub i64);

impl Fx {
    /// Number of fractional bits.
    pub const FRAC_BITS: u32 = 32;
    pub const ZERO: Fx = Fx(0);
    pub const ONE: Fx = Fx(1 << 32);
    pub const MAX: Fx = Fx(i64::MAX);
    pub const MIN: Fx = Fx(i64::MIN);

    /// The integer `n` as a fixed-point number (saturating).
    pub const fn from_int(n: i32) -> Fx {
        Fx((n as i64) << 32)
    }

    /// `num / den` as a fixed-point number, for constants (den != 0).
    pub const fn from_ratio(num: i64, den: i64) -> Fx {
        Fx(((num << 16) / den) << 16)
    }
}

/// A 3-vector of `Fx`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Vec3 {
    pub x: Fx,
    pub y: Fx,
    pub z: Fx,
}

/// A unit quaternion (x, y, z, w), scalar last as in Haption's API.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Quat {
    pub x: Fx,
    pub y: Fx,
    pub z: Fx,
    pub w: Fx,
}

impl Default for Quat {
    fn default() -> Self {
        Quat { x: Fx::ZERO, y: Fx::ZERO, z: Fx::ZERO, w: Fx::ONE }
    }
}

/// A rigid pose: position (m) and orientation.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Pose {
    pub position: Vec3,
    pub orientation: Quat,
}

/// A twist: linear velocity (m/s) and angular velocity (rad/s).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Twist {
    pub linear: Vec3,
    pub angular: Vec3,
}

/// A wrench: force (N) and torque (N·m).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Wrench {
    pub force: Vec3,
    pub torque: Vec3,
}
