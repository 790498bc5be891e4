//! Fixed-point scalar and geometric types shared by every component.
//!
//! # Formats
//!
//! `Fx` is a signed Q32.32 number in an `i64`: range ±2^31 (±2.1e9), resolution
//! 2^-32 (2.3e-10). Physical quantities use SI units in `Fx` (m, rad, m/s,
//! rad/s, N, N·m, N/m, N·s/m, kg, s) unless a field's doc says otherwise.
//!
//! | quantity | unit | working range | resolution |
//! |---|---|---|---|
//! | length / position | m | ±10 m (arm ≤ 1 m) | 2.3e-10 m |
//! | angle | rad | ±π after reduction, any `Fx` accepted | 2.3e-10 rad |
//! | velocity | m/s, rad/s | ±100 | 2.3e-10 |
//! | force / torque | N, N·m | ±1e4 | 2.3e-10 |
//! | stiffness | N/m, N·m/rad | ≤ 1e6 | 2.3e-10 |
//! | damping | N·s/m, N·m·s/rad | ≤ 1e4 | 2.3e-10 |
//! | mass / inertia | kg, kg·m² | ≤ 1e3 | 2.3e-10 |
//! | time | s (servo period 1e-3 s) | ≤ 2^31 s | 2.3e-10 s (0.23 ns) |
//! | quaternion / rotation matrix entries | 1 | [-1, 1] | 2.3e-10 |
//!
//! Products of two quantities that fit the working ranges never come near the
//! ±2^31 limit; every operation nevertheless saturates instead of overflowing.
//!
//! # Arithmetic (no `i128`, no float)
//!
//! * `+ - neg`: saturating.
//! * `*`: four 32-bit partial products, truncated toward −∞ (error < 1 LSB),
//!   saturating.
//! * `/`: unsigned long division (one hardware `u64` division in the common
//!   case, a 32-step restoring loop otherwise), truncated toward zero, saturating;
//!   `x / 0` saturates to `MAX`/`MIN` (`0 / 0 = 0`).
//! * `mul_unit` (`x · u`, `|u| ≤ 2`): `u` in Q2.30, two partial products;
//!   the same result as `*` when `u` has ≤ 30 fractional bits, else an
//!   extra error < |x|·2^-30.
//! * `sqrt`: integer square root (Newton, hardware divisions) of the
//!   normalised mantissa; relative error < 2^-30; negative input gives 0.
//! * `sin`/`cos`: Cody–Waite reduction by π/2 (π/2 held to 64 fractional bits),
//!   then Taylor polynomials of degree 11/12 on [-π/4, π/4];
//!   absolute error ≤ 4e-9 for |x| ≤ 1e4 (tested against `libm`).
//!   `sin_cos_unit`: the same polynomials in Q1.31 with single 64-bit
//!   products; absolute error ≤ 3e-9.
//!
//! # Formats inside the arm's kinematics
//!
//! [`super::arm`] computes forward kinematics, Jacobian, gravity and inertia
//! in Q2.30 (an `i64` with 30 fractional bits, resolution 9.3e-10): every
//! quantity there is below 2.3 in magnitude (rotation and axis entries ≤ 1,
//! positions and lever arms ≤ 1.13 m, differences of two points ≤ 2.26 m),
//! so a product of two is below 2^63 and costs one 64-bit multiply. Its
//! results leave as `Fx` with two zero low bits, which makes every later
//! `mul_unit` by them exact. Error bounds: see `arm`.
//! * `atan2`: 32-iteration CORDIC in vectoring mode after a quadrant rotation;
//!   absolute error ≤ 1e-8 rad (tested against `libm`).

use core::ops::{Add, AddAssign, Div, Mul, Neg, Sub, SubAssign};

/// Signed Q32.32 fixed-point number (SI units unless stated).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Fx(pub i64);

const HALF_PI_RAW: i64 = 6_746_518_852;
/// The bits of π/2 below 2^-32, scaled by 2^32 (Cody–Waite second part).
const HALF_PI_LO: i64 = 1_121_027_178;
const FRAC_2_PI_RAW: i64 = 2_734_261_102;

/// atan(2^-i) in Q32.32, i = 0..32.
const CORDIC_ATAN: [i64; 32] = [
    3373259426, 1991351318, 1052175346, 534100635, 268086748, 134174063, 67103403, 33553749,
    16777131, 8388597, 4194303, 2097152, 1048576, 524288, 262144, 131072, 65536, 32768, 16384,
    8192, 4096, 2048, 1024, 512, 256, 128, 64, 32, 16, 8, 4, 2,
];

impl Fx {
    /// Number of fractional bits.
    pub const FRAC_BITS: u32 = 32;
    pub const ZERO: Fx = Fx(0);
    pub const ONE: Fx = Fx(1 << 32);
    pub const HALF: Fx = Fx(1 << 31);
    pub const TWO: Fx = Fx(2 << 32);
    pub const MAX: Fx = Fx(i64::MAX);
    pub const MIN: Fx = Fx(i64::MIN);
    /// Smallest positive value, 2^-32.
    pub const EPSILON: Fx = Fx(1);
    pub const PI: Fx = Fx(13_493_037_705);
    pub const HALF_PI: Fx = Fx(HALF_PI_RAW);
    pub const TWO_PI: Fx = Fx(26_986_075_409);

    /// The integer `n` as a fixed-point number (exact: every `i32` fits).
    pub const fn from_int(n: i32) -> Fx {
        Fx((n as i64) << 32)
    }

    /// `num / den` as a fixed-point number, for constants (|num| < 2^47;
    /// `den == 0` gives 0, as [`Fx::ratio`]).
    pub const fn from_ratio(num: i64, den: i64) -> Fx {
        match (num << 16).checked_div(den) {
            Some(q) => Fx(q << 16),
            None => Fx::ZERO,
        }
    }

    /// `num / den` with full precision and saturation; `den == 0` gives 0.
    pub const fn ratio(num: i64, den: i64) -> Fx {
        if den == 0 {
            return Fx::ZERO;
        }
        let neg = (num < 0) != (den < 0);
        let r = udiv_q32(num.unsigned_abs(), den.unsigned_abs());
        apply_sign(r, neg)
    }

    /// `m / 1000` (milli-units → units), full precision.
    pub const fn from_milli(m: i64) -> Fx {
        Fx::ratio(m, 1000)
    }

    /// Value in milli-units, rounded to nearest (saturating).
    pub const fn to_milli(self) -> i64 {
        let t = self.mul_int(1000).0;
        (t >> 32).saturating_add((t >> 31) & 1)
    }

    /// A time in nanoseconds, as seconds.
    pub const fn from_ns(ns: u64) -> Fx {
        let ns = if ns > i64::MAX as u64 {
            i64::MAX
        } else {
            ns as i64
        };
        Fx::ratio(ns, 1_000_000_000)
    }

    /// Nearest integer (ties away from zero... toward +∞), saturating to i64.
    pub const fn round_to_i64(self) -> i64 {
        self.0.saturating_add(1 << 31) >> 32
    }

    /// Integer part toward −∞.
    pub const fn floor_to_i64(self) -> i64 {
        self.0 >> 32
    }

    pub const fn add_sat(self, o: Fx) -> Fx {
        Fx(self.0.saturating_add(o.0))
    }

    pub const fn sub_sat(self, o: Fx) -> Fx {
        Fx(self.0.saturating_sub(o.0))
    }

    pub const fn neg_sat(self) -> Fx {
        Fx(self.0.saturating_neg())
    }

    pub const fn abs(self) -> Fx {
        Fx(self.0.saturating_abs())
    }

    pub const fn is_negative(self) -> bool {
        self.0 < 0
    }

    pub const fn min(self, o: Fx) -> Fx {
        if self.0 < o.0 {
            self
        } else {
            o
        }
    }

    pub const fn max(self, o: Fx) -> Fx {
        if self.0 > o.0 {
            self
        } else {
            o
        }
    }

    /// Clamp into `[lo, hi]` (if `lo > hi`, `hi` wins).
    pub const fn clamp(self, lo: Fx, hi: Fx) -> Fx {
        self.max(lo).min(hi)
    }

    /// Clamp into `[-lim, lim]` (`lim` taken as its absolute value).
    pub const fn clamp_abs(self, lim: Fx) -> Fx {
        let l = lim.abs();
        self.clamp(l.neg_sat(), l)
    }

    /// Multiply by an integer (saturating).
    pub const fn mul_int(self, n: i64) -> Fx {
        Fx(self.0.saturating_mul(n))
    }

    /// `self / 2` toward −∞: exactly `self.mul_sat(Fx::HALF)` (one partial
    /// product, `⌊x·2^31 / 2^32⌋`, which never saturates) as one shift.
    pub const fn half(self) -> Fx {
        Fx(self.0 >> 1)
    }

    /// Fixed-point product, saturating, truncated toward −∞.
    pub const fn mul_sat(self, o: Fx) -> Fx {
        let a = self.0;
        let b = o.0;
        // Both below 2^15 in magnitude (raw below 2^47), as every force,
        // length, speed and gain of the controller: |ah·bh| < 2^30, the
        // middle products < 2^47, so the sum below is the exact floor and
        // cannot overflow: no saturation checks (the same result as the
        // general path).
        if (a.wrapping_add(1 << 47) as u64) < (1 << 48)
            && (b.wrapping_add(1 << 47) as u64) < (1 << 48)
        {
            return Fx(mul_fast(a, b));
        }
        let ah = a >> 32;
        let al = a & 0xFFFF_FFFF;
        let bh = b >> 32;
        let bl = b & 0xFFFF_FFFF;
        // |ah|, |bh| <= 2^31 so hh fits; shifting it by 32 may not.
        let hh = ah * bh;
        let hi = if hh > (i64::MAX >> 32) {
            return Fx::MAX;
        } else if hh < (i64::MIN >> 32) {
            return Fx::MIN;
        } else {
            hh << 32
        };
        // |ah| <= 2^31, bl < 2^32: |ah*bl| < 2^63.
        let m1 = ah * bl;
        let m2 = al * bh;
        let lo = (((al as u64) * (bl as u64)) >> 32) as i64;
        Fx(hi.saturating_add(m1).saturating_add(m2).saturating_add(lo))
    }

    /// `self · u` for a factor `|u| ≤ 2`: sines, cosines, rotation-matrix
    /// and unit-axis entries, the arm's Jacobian entries (≤ 1.13), constants
    /// below 2. `u` is taken in Q2.30 (its two lowest raw bits dropped), so
    /// the product needs two 32×64-bit partial products instead of four;
    /// truncated toward −∞, saturating. **Exactly `mul_sat`** when `u` has at
    /// most 30 fractional bits (every Q2.30 quantity of [`super::arm`], every
    /// `from_ratio`/`from_int` constant); otherwise the dropped bits add an
    /// error below `|self|·2^-30`. A `|u| > 2` is clamped to ±2 (a wrong
    /// factor, never a panic or a wrapped product).
    pub const fn mul_unit(self, u: Fx) -> Fx {
        let mut u30 = u.0 >> 2;
        if u30 > (1 << 31) {
            u30 = 1 << 31;
        } else if u30 < -(1 << 31) {
            u30 = -(1 << 31);
        }
        // |u30| ≤ 2^31, |xh| ≤ 2^31, xl < 2^32: |hi| ≤ 2^62, |lo| ≤ 2^63 − 2^31.
        let xh = self.0 >> 32;
        let xl = self.0 & 0xFFFF_FFFF;
        let hi = u30.wrapping_mul(xh);
        let lo = u30.wrapping_mul(xl);
        // floor(x·u30 / 2^30) = 4·hi + floor(lo / 2^30), exactly.
        Fx(hi.saturating_mul(4).saturating_add(lo >> 30))
    }

    /// Fixed-point quotient, saturating, truncated toward zero. `x/0`
    /// saturates to `MAX` or `MIN` by the sign of `x` (`0/0 = 0`).
    pub const fn div_sat(self, o: Fx) -> Fx {
        if o.0 == 0 {
            return if self.0 > 0 {
                Fx::MAX
            } else if self.0 < 0 {
                Fx::MIN
            } else {
                Fx::ZERO
            };
        }
        if o.0 == Fx::ONE.0 {
            // What the division gives (`MIN / 1` saturates to `MIN`).
            return self;
        }
        let neg = (self.0 < 0) != (o.0 < 0);
        let r = udiv_q32(self.0.unsigned_abs(), o.0.unsigned_abs());
        apply_sign(r, neg)
    }

    /// Reciprocal `1/x` (saturating).
    pub const fn recip(self) -> Fx {
        Fx::ONE.div_sat(self)
    }

    /// Square root; 0 for negative input. Relative error < 2^-30.
    pub const fn sqrt(self) -> Fx {
        if self.0 <= 0 {
            return Fx::ZERO;
        }
        let a = self.0 as u64;
        let lz = a.leading_zeros();
        let mut k = lz & !1;
        if k > 32 {
            k = 32;
        }
        // Below k = 32 the shifted value's top bit is bit 62 or 63: the
        // root's start needs no normalisation of its own.
        let s = if k < 32 {
            isqrt_newton(a << k, 0)
        } else {
            isqrt_u64(a << k)
        };
        Fx((s << ((32 - k) / 2)) as i64)
    }

    /// Sine and cosine together.
    pub const fn sin_cos(self) -> (Fx, Fx) {
        let t = self.mul_sat(Fx(FRAC_2_PI_RAW));
        let n = t.0.saturating_add(1 << 31) >> 32;
        // Wrapping is exact here: the true remainder is small.
        let r = self
            .0
            .wrapping_sub(n.wrapping_mul(HALF_PI_RAW))
            .wrapping_sub(n.wrapping_mul(HALF_PI_LO) >> 32);
        let (s, c) = sin_cos_poly(Fx(r));
        match n & 3 {
            0 => (s, c),
            1 => (c, s.neg_sat()),
            2 => (s.neg_sat(), c.neg_sat()),
            _ => (c.neg_sat(), s),
        }
    }

    /// Sine and cosine with 31 fractional bits (the lowest raw bit is 0):
    /// the same Cody–Waite reduction as [`Fx::sin_cos`] (quadrant from a
    /// [`Fx::mul_unit`] product, remainder exact), then the same Taylor
    /// polynomials evaluated in Q1.31 with single 64-bit products (every
    /// operand ≤ 1 in magnitude, so no product exceeds 2^62). Absolute error
    /// ≤ 3e-9 for |x| ≤ 1e4 (tested against `libm`); `|sin|, |cos| ≤ 1`.
    /// This is the kinematics' sine: its results are Q2.30-exact inputs
    /// for [`Fx::mul_unit`] after dropping one more bit.
    pub const fn sin_cos_unit(self) -> (Fx, Fx) {
        let t = self.mul_unit(Fx(FRAC_2_PI_RAW));
        let n = t.0.saturating_add(1 << 31) >> 32;
        let r = self
            .0
            .wrapping_sub(n.wrapping_mul(HALF_PI_RAW))
            .wrapping_sub(n.wrapping_mul(HALF_PI_LO) >> 32);
        let (s, c) = sin_cos_poly_q31(r >> 1);
        let (s, c) = (Fx(s << 1), Fx(c << 1));
        match n & 3 {
            0 => (s, c),
            1 => (c, s.neg_sat()),
            2 => (s.neg_sat(), c.neg_sat()),
            _ => (c.neg_sat(), s),
        }
    }

    pub const fn sin(self) -> Fx {
        self.sin_cos().0
    }

    pub const fn cos(self) -> Fx {
        self.sin_cos().1
    }

    /// Four-quadrant arctangent of `y/x` in (-π, π]; `atan2(0, 0) = 0`.
    pub const fn atan2(y: Fx, x: Fx) -> Fx {
        let mut x = x.0;
        let mut y = y.0;
        if x == 0 && y == 0 {
            return Fx::ZERO;
        }
        // Bring magnitudes to at most 2^60 (headroom for the CORDIC gain 1.65)
        // and at least 2^59 for precision.
        let m = if x.unsigned_abs() > y.unsigned_abs() {
            x.unsigned_abs()
        } else {
            y.unsigned_abs()
        };
        let lz = m.leading_zeros();
        if lz < 4 {
            let sh = 4 - lz;
            x >>= sh;
            y >>= sh;
        } else {
            let sh = lz - 4;
            x <<= sh;
            y <<= sh;
        }
        let mut z: i64 = 0;
        // After scaling |x|, |y| <= 2^60: negating never saturates.
        if x < 0 {
            if y >= 0 {
                let t = x;
                x = y;
                y = t.saturating_neg();
                z = HALF_PI_RAW;
            } else {
                let t = x;
                x = y.saturating_neg();
                y = t;
                z = -HALF_PI_RAW;
            }
        }
        let mut i = 0;
        while i < 32 {
            let xs = x >> i;
            let ys = y >> i;
            if y > 0 {
                x = x.saturating_add(ys);
                y = y.saturating_sub(xs);
                z = z.saturating_add(CORDIC_ATAN[i]);
            } else {
                x = x.saturating_sub(ys);
                y = y.saturating_add(xs);
                z = z.saturating_sub(CORDIC_ATAN[i]);
            }
            i += 1;
        }
        // Map -π to π so the range is (-π, π].
        if z < -Fx::PI.0 + 8 {
            z = Fx::PI.0;
        }
        Fx(z)
    }

    /// Wrap an angle into [-π, π).
    pub const fn wrap_angle(self) -> Fx {
        // n = round(x / 2π), then x - n·2π with π held to 64 fractional bits.
        let t = self.mul_sat(Fx(FRAC_2_PI_RAW / 4 + 1));
        let n = t.0.saturating_add(1 << 31) >> 32;
        let r = self
            .0
            .wrapping_sub(n.wrapping_mul(4 * HALF_PI_RAW))
            .wrapping_sub(n.wrapping_mul(4 * HALF_PI_LO) >> 32);
        Fx(r)
    }

    #[cfg(any(test, feature = "float"))]
    pub fn from_f64(v: f64) -> Fx {
        let s = v * 4294967296.0;
        if s.is_nan() {
            Fx::ZERO
        } else if s >= 9.223_372_036_854_776e18 {
            Fx::MAX
        } else if s <= -9.223_372_036_854_776e18 {
            Fx::MIN
        } else {
            // round half away from zero (`f64::round` is not in `core`)
            Fx(if s >= 0.0 {
                (s + 0.5) as i64
            } else {
                (s - 0.5) as i64
            })
        }
    }

    #[cfg(any(test, feature = "float"))]
    pub fn to_f64(self) -> f64 {
        self.0 as f64 / 4294967296.0
    }
}

const fn apply_sign(r: u64, neg: bool) -> Fx {
    if neg {
        if r > (1u64 << 63) {
            Fx::MIN
        } else {
            Fx((r as i64).wrapping_neg())
        }
    } else if r > i64::MAX as u64 {
        Fx::MAX
    } else {
        Fx(r as i64)
    }
}

/// `(a · 2^32) / b` (unsigned), i.e. `a/b` in Q32.32 whether `a`, `b` are
/// plain integers or both Q32.32 raws; `u64::MAX` when the integer part
/// needs more than 31 bits. `b != 0`.
const fn udiv_q32(a: u64, b: u64) -> u64 {
    if b == 0 {
        return u64::MAX;
    }
    if a < (1u64 << 32) {
        // One division: a·2^32 fits, and its quotient is (q << 32) | frac
        // below; q ≥ 2^31 exactly when it reaches 2^63.
        let f = (a << 32) / b;
        return if f >= (1u64 << 63) { u64::MAX } else { f };
    }
    let q = a / b;
    let r = a % b;
    if q >= (1u64 << 31) {
        return u64::MAX;
    }
    let frac = if r < (1u64 << 32) {
        (r << 32) / b
    } else {
        frac_q32_wide(r, b)
    };
    (q << 32) | frac
}

/// `floor(r · 2^32 / b)` for `2^32 ≤ r < b ≤ 2^63`, without 128-bit arithmetic:
/// one step of Knuth's long division (TAOCP 4.3.1, algorithm D) in 32-bit
/// digits. With `b` normalised (top bit set) the estimate from the top
/// digit of the divisor is at most 2 above the quotient, and with a
/// two-digit divisor the test against its low digit is exact, so the loop
/// ends on the floor. The same result as a 32-step restoring division (the
/// reference in the tests), in about a tenth of the instructions.
const fn frac_q32_wide(r: u64, b: u64) -> u64 {
    const DIGIT: u64 = 1 << 32;
    // b > r ≥ 2^32: s < 32, and r < b keeps r << s below 2^64 (the
    // wrapping shifts take s as it is: no shift-overflow panic path).
    let s = b.leading_zeros();
    let v = b.wrapping_shl(s);
    let u = r.wrapping_shl(s);
    let v1 = v >> 32;
    let v0 = v & 0xFFFF_FFFF;
    // v1 ≥ 2^31: the fallbacks are never taken (no panic path).
    let mut qhat = match u.checked_div(v1) {
        Some(x) => x,
        None => return u64::MAX,
    };
    let mut rhat = match u.checked_rem(v1) {
        Some(x) => x,
        None => return u64::MAX,
    };
    // qhat ≤ 2^32 + 2 and rhat < 2^32 on entry. qhat·v > r·2^s·2^32
    // exactly when qhat ≥ 2^32 or qhat·v0 > rhat·2^32 (qhat < 2^32 there:
    // the product fits); once rhat ≥ 2^32 the quotient is reached.
    while rhat < DIGIT && (qhat >= DIGIT || qhat.wrapping_mul(v0) > (rhat << 32)) {
        qhat = qhat.wrapping_sub(1);
        rhat = rhat.wrapping_add(v1);
    }
    qhat
}

/// The 32-step restoring division that [`frac_q32_wide`] replaces.
#[cfg(test)]
const fn frac_q32_bitwise(mut r: u64, b: u64) -> u64 {
    let mut f: u64 = 0;
    let mut i = 0;
    while i < 32 {
        // r < b <= 2^63, so r << 1 fits in u64.
        r <<= 1;
        f <<= 1;
        if r >= b {
            r -= b;
            f |= 1;
        }
        i += 1;
    }
    f
}

/// `floor(sqrt(n))`: Newton's iteration `x ← ⌊(x + ⌊n/x⌋)/2⌋` from a
/// start at or above the root, taken from [`SQRT_START`] by the top bits
/// of `n` (within 0.8 % of it); every step stays at or above the floor of
/// the root and falls strictly while `x² > n`, so the first `x` with
/// `x² ≤ n` is the floor. Three divisions or so, where the former start
/// (a power of two) took five to six, and the same result.
const fn isqrt_u64(n: u64) -> u64 {
    if n < 2 {
        return n;
    }
    isqrt_newton(n, n.leading_zeros() / 2)
}

/// [`isqrt_u64`] for `n ≥ 2` with `e` = half its leading zeros, rounded
/// down (so that `n·4^e` is in [2^62, 2^64)).
#[inline(always)]
const fn isqrt_newton(n: u64, e: u32) -> u64 {
    // n·4^e in [2^62, 2^64): its top byte t in [64, 255], and
    // √n ≤ √((t+1)·2^56) / 2^e ≤ (SQRT_START[t − 64] + 1) / 2^e.
    let t = (n << (2 * e)) >> 56;
    let tab = SQRT_START.len() as u64;
    let i = t.wrapping_sub(64);
    let s0 = if i < tab {
        SQRT_START[i as usize] as u64
    } else {
        u32::MAX as u64
    };
    // ⌊s0 / 2^e⌋ + 1 ≥ (s0 + 1) / 2^e; the floor of the root is below
    // 2^32, so the start may be capped there, and x·x never overflows.
    let mut x = (s0 >> e).wrapping_add(1);
    if x > u32::MAX as u64 {
        x = u32::MAX as u64;
    }
    while x.wrapping_mul(x) > n {
        // x > √n ≥ 1: the fallback is never taken (no panic path).
        let q = match n.checked_div(x) {
            Some(q) => q,
            None => return 0,
        };
        // x < 2^32 and q < √n < 2^32: the sum fits.
        x = x.wrapping_add(q) >> 1;
    }
    x
}

/// `⌈√((t+1)·2^56)⌉ − 1` for t in [64, 255] (the last is 2^32 − 1): the
/// start of [`isqrt_u64`] for an `n` normalised to [2^62, 2^64) by an even
/// shift, whose top byte is t, at most 1/(2t) above its root.
const SQRT_START: [u32; 192] = {
    let mut tab = [0u32; 192];
    let mut i = 0;
    while i < 192 {
        let m = ((i as u64) + 65) << 56;
        tab[i] = if i == 191 {
            u32::MAX
        } else {
            let r = isqrt_bitwise(m);
            // ⌈√m⌉ − 1: r − 1 when m is a square, else r.
            if r * r == m {
                (r - 1) as u32
            } else {
                r as u32
            }
        };
        i += 1;
    }
    tab
};

/// `floor(sqrt(n))` digit by digit (compile time only: [`SQRT_START`], and
/// the reference in the tests).
const fn isqrt_bitwise(n: u64) -> u64 {
    let mut rem = n;
    let mut root = 0u64;
    let mut bit = 1u64 << 62;
    while bit > rem {
        bit >>= 2;
    }
    while bit != 0 {
        if rem >= root + bit {
            rem -= root + bit;
            root = (root >> 1) + bit;
        } else {
            root >>= 1;
        }
        bit >>= 2;
    }
    root
}

/// sin and cos of |x| <= π/4 (slightly more is fine).
// Taylor coefficients (evaluated at compile time).
const C_N39916800: Fx = Fx::ratio(-1, 39_916_800);
const C_P362880: Fx = Fx::ratio(1, 362_880);
const C_N5040: Fx = Fx::ratio(-1, 5_040);
const C_P120: Fx = Fx::ratio(1, 120);
const C_N6: Fx = Fx::ratio(-1, 6);
const C_P479001600: Fx = Fx::ratio(1, 479_001_600);
const C_N3628800: Fx = Fx::ratio(-1, 3_628_800);
const C_P40320: Fx = Fx::ratio(1, 40_320);
const C_N720: Fx = Fx::ratio(-1, 720);
const C_P24: Fx = Fx::ratio(1, 24);
const C_N2: Fx = Fx::ratio(-1, 2);

const fn sin_cos_poly(x: Fx) -> (Fx, Fx) {
    let x2 = x.mul_sat(x);
    // sin: x·(1 - x²/6 + x⁴/120 - x⁶/5040 + x⁸/362880 - x¹⁰/39916800)
    let mut s = C_N39916800;
    s = C_P362880.add_sat(x2.mul_sat(s));
    s = C_N5040.add_sat(x2.mul_sat(s));
    s = C_P120.add_sat(x2.mul_sat(s));
    s = C_N6.add_sat(x2.mul_sat(s));
    s = Fx::ONE.add_sat(x2.mul_sat(s));
    let s = x.mul_sat(s);
    // cos: 1 - x²/2 + x⁴/24 - x⁶/720 + x⁸/40320 - x¹⁰/3628800 + x¹²/479001600
    let mut c = C_P479001600;
    c = C_N3628800.add_sat(x2.mul_sat(c));
    c = C_P40320.add_sat(x2.mul_sat(c));
    c = C_N720.add_sat(x2.mul_sat(c));
    c = C_P24.add_sat(x2.mul_sat(c));
    c = C_N2.add_sat(x2.mul_sat(c));
    c = Fx::ONE.add_sat(x2.mul_sat(c));
    (s, c)
}

/// Q1.31 Taylor coefficients (raw, the Q32.32 constants above shifted by 1).
const Q31_S: [i64; 6] = [
    C_N39916800.0 >> 1,
    C_P362880.0 >> 1,
    C_N5040.0 >> 1,
    C_P120.0 >> 1,
    C_N6.0 >> 1,
    1 << 31,
];
const Q31_C: [i64; 7] = [
    C_P479001600.0 >> 1,
    C_N3628800.0 >> 1,
    C_P40320.0 >> 1,
    C_N720.0 >> 1,
    C_P24.0 >> 1,
    C_N2.0 >> 1,
    1 << 31,
];

/// sin and cos (Q1.31 raw) of `x` (Q1.31 raw, |x| ≤ π/4 + 1e-8). Every
/// Horner value stays in [-1, 1] (raw ≤ 2^31), so each product is below
/// 2^62 and one 64-bit multiply; each step truncates by < 2^-31.
const fn sin_cos_poly_q31(x: i64) -> (i64, i64) {
    let x2 = x.wrapping_mul(x) >> 31;
    let mut s = Q31_S[0];
    let mut i = 1;
    while i < Q31_S.len() {
        s = (x2.wrapping_mul(s) >> 31).wrapping_add(Q31_S[i]);
        i += 1;
    }
    let s = x.wrapping_mul(s) >> 31;
    let mut c = Q31_C[0];
    let mut i = 1;
    while i < Q31_C.len() {
        c = (x2.wrapping_mul(c) >> 31).wrapping_add(Q31_C[i]);
        i += 1;
    }
    (s, c)
}

impl Add for Fx {
    type Output = Fx;
    #[inline]
    fn add(self, o: Fx) -> Fx {
        self.add_sat(o)
    }
}
impl Sub for Fx {
    type Output = Fx;
    #[inline]
    fn sub(self, o: Fx) -> Fx {
        self.sub_sat(o)
    }
}
impl Mul for Fx {
    type Output = Fx;
    #[inline]
    fn mul(self, o: Fx) -> Fx {
        self.mul_sat(o)
    }
}
impl Div for Fx {
    type Output = Fx;
    #[inline]
    fn div(self, o: Fx) -> Fx {
        self.div_sat(o)
    }
}
impl Neg for Fx {
    type Output = Fx;
    #[inline]
    fn neg(self) -> Fx {
        self.neg_sat()
    }
}
impl AddAssign for Fx {
    #[inline]
    fn add_assign(&mut self, o: Fx) {
        *self = self.add_sat(o);
    }
}
impl SubAssign for Fx {
    #[inline]
    fn sub_assign(&mut self, o: Fx) {
        *self = self.sub_sat(o);
    }
}

/// A factor prepared for several products by factors `|u| ≤ 2` (rotation
/// entries, this arm's Jacobian), as in [`Fx::mul_unit`]: its magnitude
/// clamped to 2^27 (1.3e8, far beyond any force, torque or speed of the
/// arm), split into its high and low 32 bits once. Each product is then
/// two multiplies and no saturation check: `|u30·h| ≤ 2^58`, a product is
/// below 2^60 and a sum of up to eight cannot overflow. Below the clamp a
/// product is exactly `mul_unit`'s (so `mul_sat`'s for 30-bit factors).
#[derive(Clone, Copy)]
pub(crate) struct UnitFactor {
    h: i64,
    l: i64,
}

impl UnitFactor {
    const LIM: i64 = 1 << 59;

    pub(crate) const fn new(x: Fx) -> UnitFactor {
        let x = if x.0 > Self::LIM {
            Self::LIM
        } else if x.0 < -Self::LIM {
            -Self::LIM
        } else {
            x.0
        };
        UnitFactor {
            h: x >> 32,
            l: x & 0xFFFF_FFFF,
        }
    }

    /// Raw Q32.32 of `x · u`; `u` as in [`Fx::mul_unit`] (Q2.30, clamped to ±2).
    pub(crate) const fn mul(self, u: Fx) -> i64 {
        self.mul30(unit30(u))
    }

    /// [`UnitFactor::mul`] with the factor already taken by [`unit30`]
    /// (`|u30| ≤ 2^31`): the same value.
    pub(crate) const fn mul30(self, u30: i64) -> i64 {
        (u30.wrapping_mul(self.h) << 2).wrapping_add(u30.wrapping_mul(self.l) >> 30)
    }
}

/// `u` as [`Fx::mul_unit`] and [`UnitFactor::mul`] take it: Q2.30 (the two
/// lowest raw bits dropped), clamped to ±2^31 (±2).
pub(crate) const fn unit30(u: Fx) -> i64 {
    let u30 = u.0 >> 2;
    if u30 > (1 << 31) {
        1 << 31
    } else if u30 < -(1 << 31) {
        -(1 << 31)
    } else {
        u30
    }
}

/// Whether all four raws are in [−2^47, 2^47), the range of
/// [`Fx::mul_sat`]'s fast path (for both factors).
#[inline(always)]
const fn in_fast_range(a: i64, b: i64, c: i64, d: i64) -> bool {
    const R: i64 = 1 << 47;
    ((a.wrapping_add(R) | b.wrapping_add(R) | c.wrapping_add(R) | d.wrapping_add(R)) as u64)
        < (1 << 48)
}

/// [`Fx::mul_sat`]'s fast path: the exact floor of a·b/2^32 for a, b in
/// [−2^47, 2^47) (see there), below 2^62 in magnitude.
#[inline(always)]
const fn mul_fast(a: i64, b: i64) -> i64 {
    let (ah, al) = (a >> 32, a & 0xFFFF_FFFF);
    let (bh, bl) = (b >> 32, b & 0xFFFF_FFFF);
    let lo = (((al as u64).wrapping_mul(bl as u64)) >> 32) as i64;
    (ah.wrapping_mul(bh) << 32)
        .wrapping_add(ah.wrapping_mul(bl))
        .wrapping_add(al.wrapping_mul(bh))
        .wrapping_add(lo)
}

/// `⌊x²/2^32⌋` for `|x| < 2^47` raw: exactly `Fx(x).mul_sat(Fx(x))` (its
/// fast path is that exact floor, and x² = |x|²), as an unsigned value
/// below 2^62 + 2^49: `h² < 2^30` shifted by 32, `2·h·l < 2^48`.
#[inline(always)]
const fn sq_small(x: i64) -> u64 {
    let u = x.unsigned_abs();
    let (h, l) = (u >> 32, u & 0xFFFF_FFFF);
    (h.wrapping_mul(h) << 32)
        .wrapping_add(h.wrapping_mul(l) << 1)
        .wrapping_add(l.wrapping_mul(l) >> 32)
}

/// A 3-vector of `Fx`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Vec3 {
    pub x: Fx,
    pub y: Fx,
    pub z: Fx,
}

impl Vec3 {
    pub const ZERO: Vec3 = Vec3 {
        x: Fx::ZERO,
        y: Fx::ZERO,
        z: Fx::ZERO,
    };
    pub const X: Vec3 = Vec3 {
        x: Fx::ONE,
        y: Fx::ZERO,
        z: Fx::ZERO,
    };
    pub const Y: Vec3 = Vec3 {
        x: Fx::ZERO,
        y: Fx::ONE,
        z: Fx::ZERO,
    };
    pub const Z: Vec3 = Vec3 {
        x: Fx::ZERO,
        y: Fx::ZERO,
        z: Fx::ONE,
    };

    pub const fn new(x: Fx, y: Fx, z: Fx) -> Vec3 {
        Vec3 { x, y, z }
    }

    pub const fn add(self, o: Vec3) -> Vec3 {
        Vec3::new(
            self.x.add_sat(o.x),
            self.y.add_sat(o.y),
            self.z.add_sat(o.z),
        )
    }

    pub const fn sub(self, o: Vec3) -> Vec3 {
        Vec3::new(
            self.x.sub_sat(o.x),
            self.y.sub_sat(o.y),
            self.z.sub_sat(o.z),
        )
    }

    pub const fn neg(self) -> Vec3 {
        Vec3::new(self.x.neg_sat(), self.y.neg_sat(), self.z.neg_sat())
    }

    /// The test is inlined at the caller, the products are not.
    #[inline(always)]
    pub const fn scale(self, k: Fx) -> Vec3 {
        // `x.mul_sat(ONE)` is `x` for every x (one partial product, exact):
        // the speed, force and envelope factors are mostly 1.
        if k.0 == Fx::ONE.0 {
            return self;
        }
        self.scale_products(k)
    }

    #[inline(never)]
    const fn scale_products(self, k: Fx) -> Vec3 {
        // All four in mul_sat's fast range (one test for the four): its
        // fast products, without the saturating path's registers.
        if in_fast_range(k.0, self.x.0, self.y.0, self.z.0) {
            return Vec3::new(
                Fx(mul_fast(self.x.0, k.0)),
                Fx(mul_fast(self.y.0, k.0)),
                Fx(mul_fast(self.z.0, k.0)),
            );
        }
        self.scale_products_wide(k)
    }

    #[cold]
    #[inline(never)]
    const fn scale_products_wide(self, k: Fx) -> Vec3 {
        Vec3::new(self.x.mul_sat(k), self.y.mul_sat(k), self.z.mul_sat(k))
    }

    /// `self.scale(k).add(o.scale(c))` in one pass: the same value (a
    /// factor 1 gives the same product as `scale`'s shortcut), with one
    /// range test for the eight factors of the fast products.
    #[inline(never)]
    pub const fn scale_add(self, k: Fx, o: Vec3, c: Fx) -> Vec3 {
        if in_fast_range(k.0, self.x.0, self.y.0, self.z.0)
            && in_fast_range(c.0, o.x.0, o.y.0, o.z.0)
        {
            return Vec3::new(
                Fx(mul_fast(self.x.0, k.0)).add_sat(Fx(mul_fast(o.x.0, c.0))),
                Fx(mul_fast(self.y.0, k.0)).add_sat(Fx(mul_fast(o.y.0, c.0))),
                Fx(mul_fast(self.z.0, k.0)).add_sat(Fx(mul_fast(o.z.0, c.0))),
            );
        }
        self.scale(k).add(o.scale(c))
    }

    /// Every component doubled: exactly `self.scale(Fx::TWO)` (`mul_sat` by
    /// 2 is the doubling, saturating at `MAX`/`MIN`), without the products.
    pub const fn twice(self) -> Vec3 {
        Vec3::new(self.x.mul_int(2), self.y.mul_int(2), self.z.mul_int(2))
    }

    /// Every component halved: exactly `self.scale(Fx::HALF)`.
    pub const fn half(self) -> Vec3 {
        Vec3::new(self.x.half(), self.y.half(), self.z.half())
    }

    pub const fn dot(self, o: Vec3) -> Fx {
        // All six in mul_sat's fast range (two tests for the six): its
        // fast products; the sum still saturates (each is below 2^62).
        if in_fast_range(self.x.0, self.y.0, self.z.0, 0) && in_fast_range(o.x.0, o.y.0, o.z.0, 0) {
            return Fx(mul_fast(self.x.0, o.x.0))
                .add_sat(Fx(mul_fast(self.y.0, o.y.0)))
                .add_sat(Fx(mul_fast(self.z.0, o.z.0)));
        }
        self.dot_wide(o)
    }

    #[cold]
    #[inline(never)]
    const fn dot_wide(self, o: Vec3) -> Fx {
        self.x
            .mul_sat(o.x)
            .add_sat(self.y.mul_sat(o.y))
            .add_sat(self.z.mul_sat(o.z))
    }

    /// `self · o` where every component of `self` is ≤ 2 (a unit axis, a
    /// Jacobian column of the arm): [`Fx::mul_unit`] products.
    pub const fn dot_unit(self, o: Vec3) -> Fx {
        o.x.mul_unit(self.x)
            .add_sat(o.y.mul_unit(self.y))
            .add_sat(o.z.mul_unit(self.z))
    }

    pub const fn cross(self, o: Vec3) -> Vec3 {
        Vec3::new(
            self.y.mul_sat(o.z).sub_sat(self.z.mul_sat(o.y)),
            self.z.mul_sat(o.x).sub_sat(self.x.mul_sat(o.z)),
            self.x.mul_sat(o.y).sub_sat(self.y.mul_sat(o.x)),
        )
    }

    pub const fn norm_sq(self) -> Fx {
        self.dot(self)
    }

    /// Euclidean norm. Small vectors are scaled up by up to 2^16 before
    /// squaring so that norms down to ~1e-9 keep their precision; vectors with
    /// a component of 2^14 or more are scaled down first, so that the norm
    /// never comes from a saturated square (it saturates at `MAX` itself).
    pub const fn norm(self) -> Fx {
        let m = self.max_abs_raw();
        if m == 0 {
            return Fx::ZERO;
        }
        let lz = m.leading_zeros();
        if lz <= 17 {
            // |component| >= 2^14: the squares could saturate (the norm would
            // come out near sqrt(MAX) ~ 46341 whatever the vector). Scale down
            // to at most 2^46 raw first, then back up, saturating at MAX.
            let d = 18 - lz;
            let v = Vec3::new(Fx(self.x.0 >> d), Fx(self.y.0 >> d), Fx(self.z.0 >> d));
            let n = Fx(v.sum_sq_small() as i64).sqrt().0;
            return if n > (i64::MAX >> d) {
                Fx::MAX
            } else {
                Fx(n << d)
            };
        }
        let k = Vec3::small_shift(lz);
        Fx(Fx(self.shifted_sum_sq(k) as i64).sqrt().0 >> k)
    }

    /// `Some(self.norm())` when `self.norm_sq() > t2`, else `None`: the
    /// norm only where the squared test passes, and from the same sum of
    /// squares where that is the root's (components of 2^30 to 2^46 raw:
    /// the norm takes the root of `norm_sq` unshifted, and it cannot
    /// saturate).
    pub const fn norm_where_sq_above(self, t2: Fx) -> Option<Fx> {
        let m = self.max_abs_raw();
        if m >= (1 << 30) && m < (1 << 46) {
            // small_shift(leading zeros) = 0 here.
            let s = Fx(self.sum_sq_small() as i64);
            return if s.0 > t2.0 { Some(s.sqrt()) } else { None };
        }
        if self.norm_sq().0 > t2.0 {
            Some(self.norm())
        } else {
            None
        }
    }

    /// How far [`Vec3::norm`] shifts a vector whose largest component is
    /// below 2^46 raw (`lz`, its leading zeros, ≥ 18) before squaring: so
    /// that the largest component stays below 2^30 raw (0.25), by at most
    /// 16 bits.
    #[inline(always)]
    const fn small_shift(lz: u32) -> u32 {
        let k = lz.saturating_sub(34);
        if k > 16 {
            16
        } else {
            k
        }
    }

    /// The sum of squares [`Vec3::norm`] takes the root of, for a vector
    /// whose components are below 2^46 raw, shifted up by
    /// `k = small_shift(..)` (then below 2^30 raw when `k > 0`).
    #[inline(always)]
    const fn shifted_sum_sq(self, k: u32) -> u64 {
        Vec3::new(Fx(self.x.0 << k), Fx(self.y.0 << k), Fx(self.z.0 << k)).sum_sq_small()
    }

    /// Raw `norm_sq()` for components of at most 2^46 raw: each square is
    /// `x.mul_sat(x)` (the exact floor of x²/2^32, its fast path, taken on
    /// |x|) below 2^60, their sum below 2^62, so `add_sat` never saturates
    /// and plain sums give the same value, without the range checks.
    #[inline(always)]
    /// The largest component's magnitude, raw.
    const fn max_abs_raw(self) -> u64 {
        let ax = self.x.0.unsigned_abs();
        let ay = self.y.0.unsigned_abs();
        let az = self.z.0.unsigned_abs();
        let mut m = ax;
        if ay > m {
            m = ay;
        }
        if az > m {
            m = az;
        }
        m
    }

    const fn sum_sq_small(self) -> u64 {
        sq_small(self.x.0)
            .wrapping_add(sq_small(self.y.0))
            .wrapping_add(sq_small(self.z.0))
    }

    /// Scale down so that the norm is at most `max`; returns the vector and
    /// whether it was clamped.
    pub const fn clamp_norm(self, max: Fx) -> (Vec3, bool) {
        let ax = self.x.0.unsigned_abs();
        let ay = self.y.0.unsigned_abs();
        let az = self.z.0.unsigned_abs();
        if max.0 >= 0 && ax < (1 << 46) && ay < (1 << 46) && az < (1 << 46) {
            // Quick exit, the same result as computing the norm: below 2^46
            // raw `norm()` is exact shifts, floor products and a floor root,
            // so it is at most the true norm, itself at most √3 < 2 times the
            // largest component and at most the sum of the components'
            // magnitudes.
            let mut m = ax;
            if ay > m {
                m = ay;
            }
            if az > m {
                m = az;
            }
            let l1 = ax.wrapping_add(ay).wrapping_add(az);
            let bound = if l1 < (m << 1) { l1 } else { m << 1 };
            if bound <= max.0 as u64 {
                return (self, false);
            }
            // `norm()` of such a vector (m > max ≥ 0 here) is
            // `√(s) >> k`, with s its shifted sum of squares and `√` the
            // floor root `Fx::sqrt`, at most √(s·2^32) raw. Before the
            // root: with M = max·2^k, s ≤ ⌊M²/2^32⌋ gives √ ≤ M and a norm
            // at most `max`, so no clamp, as the norm would decide; s is
            // below 2^62, so any M ≥ 2^47 passes too.
            let k = Vec3::small_shift(m.leading_zeros());
            let s = self.shifted_sum_sq(k);
            let mu = max.0 as u64;
            if mu >= (1u64 << 47) >> k || s <= sq_small((mu << k) as i64) {
                return (self, false);
            }
            let n = Fx(Fx(s as i64).sqrt().0 >> k);
            if n.0 <= max.0 || n.0 <= 0 {
                return (self, false);
            }
            // 0 ≤ max < n: `max.div_sat(n)` is this quotient (both
            // positive), below 1 (raw below 2^32), and with components
            // below 2^46 raw `scale` takes mul_sat's fast products.
            let c = udiv_q32(max.0 as u64, n.0 as u64) as i64;
            return (
                Vec3::new(
                    Fx(mul_fast(self.x.0, c)),
                    Fx(mul_fast(self.y.0, c)),
                    Fx(mul_fast(self.z.0, c)),
                ),
                true,
            );
        }
        let n = self.norm();
        if n.0 <= max.0 || n.0 <= 0 {
            return (self, false);
        }
        if n.0 == i64::MAX {
            // The norm saturated (up to sqrt(3)·2^31): a quarter of the
            // vector has a representable one, and the same direction.
            // Direction first (each component over the norm, full precision),
            // then the length: `max / n` alone would be a few raw units.
            let v = Vec3::new(Fx(self.x.0 >> 2), Fx(self.y.0 >> 2), Fx(self.z.0 >> 2));
            let n = v.norm();
            let m = max.abs();
            let u = Vec3::new(v.x.div_sat(n), v.y.div_sat(n), v.z.div_sat(n));
            return (u.scale(m), true);
        }
        (self.scale(max.abs().div_sat(n)), true)
    }

    /// Element-wise product.
    pub const fn mul_elem(self, o: Vec3) -> Vec3 {
        Vec3::new(
            self.x.mul_sat(o.x),
            self.y.mul_sat(o.y),
            self.z.mul_sat(o.z),
        )
    }

    pub const fn to_array(self) -> [Fx; 3] {
        [self.x, self.y, self.z]
    }

    pub const fn from_array(a: [Fx; 3]) -> Vec3 {
        Vec3::new(a[0], a[1], a[2])
    }

    #[cfg(any(test, feature = "float"))]
    pub fn from_f64(v: [f64; 3]) -> Vec3 {
        Vec3::new(Fx::from_f64(v[0]), Fx::from_f64(v[1]), Fx::from_f64(v[2]))
    }

    #[cfg(any(test, feature = "float"))]
    pub fn to_f64(self) -> [f64; 3] {
        [self.x.to_f64(), self.y.to_f64(), self.z.to_f64()]
    }
}

impl Add for Vec3 {
    type Output = Vec3;
    fn add(self, o: Vec3) -> Vec3 {
        Vec3::add(self, o)
    }
}
impl Sub for Vec3 {
    type Output = Vec3;
    fn sub(self, o: Vec3) -> Vec3 {
        Vec3::sub(self, o)
    }
}
impl Neg for Vec3 {
    type Output = Vec3;
    fn neg(self) -> Vec3 {
        Vec3::neg(self)
    }
}
impl Mul<Fx> for Vec3 {
    type Output = Vec3;
    fn mul(self, k: Fx) -> Vec3 {
        self.scale(k)
    }
}

/// A 3×3 matrix, row-major (`r[row]`), used for rotations.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Mat3 {
    pub r: [Vec3; 3],
}

impl Default for Mat3 {
    fn default() -> Self {
        Mat3::IDENTITY
    }
}

impl Mat3 {
    pub const IDENTITY: Mat3 = Mat3 {
        r: [Vec3::X, Vec3::Y, Vec3::Z],
    };

    pub const fn from_rows(a: Vec3, b: Vec3, c: Vec3) -> Mat3 {
        Mat3 { r: [a, b, c] }
    }

    pub const fn from_cols(a: Vec3, b: Vec3, c: Vec3) -> Mat3 {
        Mat3::from_rows(a, b, c).transpose()
    }

    pub const fn col(&self, i: usize) -> Vec3 {
        let [a, b, c] = self.r;
        match i {
            0 => Vec3::new(a.x, b.x, c.x),
            1 => Vec3::new(a.y, b.y, c.y),
            _ => Vec3::new(a.z, b.z, c.z),
        }
    }

    pub const fn transpose(&self) -> Mat3 {
        Mat3 {
            r: [self.col(0), self.col(1), self.col(2)],
        }
    }

    pub const fn mul_vec(&self, v: Vec3) -> Vec3 {
        let [a, b, c] = self.r;
        Vec3::new(a.dot(v), b.dot(v), c.dot(v))
    }

    /// `self · v` for a matrix with entries ≤ 2 (a rotation): [`Fx::mul_unit`]
    /// products (exactly `mul_vec` for Q2.30 entries).
    pub fn mul_vec_unit(&self, v: Vec3) -> Vec3 {
        let [a, b, c] = self.r;
        let (x, y, z) = (
            UnitFactor::new(v.x),
            UnitFactor::new(v.y),
            UnitFactor::new(v.z),
        );
        let row = |r: Vec3| Fx(x.mul(r.x).wrapping_add(y.mul(r.y)).wrapping_add(z.mul(r.z)));
        Vec3::new(row(a), row(b), row(c))
    }

    /// `selfᵀ · v` for a matrix with entries ≤ 2, like [`Mat3::mul_vec_unit`].
    pub fn tmul_vec_unit(&self, v: Vec3) -> Vec3 {
        let [a, b, c] = self.r;
        let (x, y, z) = (
            UnitFactor::new(v.x),
            UnitFactor::new(v.y),
            UnitFactor::new(v.z),
        );
        let col = |a: Fx, b: Fx, c: Fx| Fx(x.mul(a).wrapping_add(y.mul(b)).wrapping_add(z.mul(c)));
        Vec3::new(col(a.x, b.x, c.x), col(a.y, b.y, c.y), col(a.z, b.z, c.z))
    }

    /// `selfᵀ · v` without building the transpose.
    pub const fn tmul_vec(&self, v: Vec3) -> Vec3 {
        let [a, b, c] = self.r;
        a.scale(v.x).add(b.scale(v.y)).add(c.scale(v.z))
    }

    pub const fn mul(&self, o: &Mat3) -> Mat3 {
        let t = o.transpose();
        let [a, b, c] = self.r;
        let [p, q, s] = t.r;
        Mat3 {
            r: [
                Vec3::new(a.dot(p), a.dot(q), a.dot(s)),
                Vec3::new(b.dot(p), b.dot(q), b.dot(s)),
                Vec3::new(c.dot(p), c.dot(q), c.dot(s)),
            ],
        }
    }

    /// Rotation about x by an angle given by its (sin, cos).
    pub const fn rot_x(s: Fx, c: Fx) -> Mat3 {
        Mat3::from_rows(
            Vec3::X,
            Vec3::new(Fx::ZERO, c, s.neg_sat()),
            Vec3::new(Fx::ZERO, s, c),
        )
    }

    pub const fn rot_y(s: Fx, c: Fx) -> Mat3 {
        Mat3::from_rows(
            Vec3::new(c, Fx::ZERO, s),
            Vec3::Y,
            Vec3::new(s.neg_sat(), Fx::ZERO, c),
        )
    }

    pub const fn rot_z(s: Fx, c: Fx) -> Mat3 {
        Mat3::from_rows(
            Vec3::new(c, s.neg_sat(), Fx::ZERO),
            Vec3::new(s, c, Fx::ZERO),
            Vec3::Z,
        )
    }
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
        Quat {
            x: Fx::ZERO,
            y: Fx::ZERO,
            z: Fx::ZERO,
            w: Fx::ONE,
        }
    }
}

impl Quat {
    pub const IDENTITY: Quat = Quat {
        x: Fx::ZERO,
        y: Fx::ZERO,
        z: Fx::ZERO,
        w: Fx::ONE,
    };

    pub const fn new(x: Fx, y: Fx, z: Fx, w: Fx) -> Quat {
        Quat { x, y, z, w }
    }

    pub const fn vec(&self) -> Vec3 {
        Vec3::new(self.x, self.y, self.z)
    }

    pub const fn conjugate(&self) -> Quat {
        Quat::new(self.x.neg_sat(), self.y.neg_sat(), self.z.neg_sat(), self.w)
    }

    /// Hamilton product `self ⊗ o`.
    /// The tests are inlined at the caller, the products are not.
    #[inline(always)]
    pub const fn mul(&self, o: &Quat) -> Quat {
        // The identity on either side: the product below gives the other
        // factor bit for bit; skip its 16 products (the base frame and the
        // indexing offset are the identity unless a client sets them).
        if self.is_identity() {
            return *o;
        }
        if o.is_identity() {
            return *self;
        }
        self.mul_products(o)
    }

    #[inline(never)]
    const fn mul_products(&self, o: &Quat) -> Quat {
        let a = self.vec();
        let b = o.vec();
        let w = self.w.mul_sat(o.w).sub_sat(a.dot(b));
        let v = b.scale(self.w).add(a.scale(o.w)).add(a.cross(b));
        Quat::new(v.x, v.y, v.z, w)
    }

    /// Exactly (0, 0, 0, 1).
    pub const fn is_identity(&self) -> bool {
        self.x.0 == 0 && self.y.0 == 0 && self.z.0 == 0 && self.w.0 == Fx::ONE.0
    }

    pub const fn norm_sq(&self) -> Fx {
        self.vec().dot(self.vec()).add_sat(self.w.mul_sat(self.w))
    }

    /// Exact normalisation (sqrt + division); identity for a zero quaternion.
    pub const fn normalize(&self) -> Quat {
        const R: i64 = 1 << 46;
        let (x, y, z, w) = (self.x.0, self.y.0, self.z.0, self.w.0);
        let n = if ((x.wrapping_add(R) | y.wrapping_add(R) | z.wrapping_add(R) | w.wrapping_add(R))
            as u64)
            < (1 << 47)
        {
            // Components in [−2^46, 2^46) raw: `norm_sq`'s squares are
            // these exact floors, at most 2^60, and their sum (at most
            // 2^62) does not saturate.
            Fx((sq_small(self.x.0)
                .wrapping_add(sq_small(self.y.0))
                .wrapping_add(sq_small(self.z.0))
                .wrapping_add(sq_small(self.w.0))) as i64)
        } else {
            self.norm_sq()
        }
        .sqrt();
        if n.0 <= 0 {
            return Quat::IDENTITY;
        }
        let k = n.recip();
        Quat::new(
            self.x.mul_sat(k),
            self.y.mul_sat(k),
            self.z.mul_sat(k),
            self.w.mul_sat(k),
        )
    }

    /// Cheap renormalisation for a nearly-unit quaternion (one Newton step of
    /// 1/sqrt): `q·(3 − |q|²)/2`.
    pub const fn renormalize(&self) -> Quat {
        let k = Fx::from_int(3).sub_sat(self.norm_sq()).mul_sat(Fx::HALF);
        Quat::new(
            self.x.mul_sat(k),
            self.y.mul_sat(k),
            self.z.mul_sat(k),
            self.w.mul_sat(k),
        )
    }

    /// Rotate a vector: `q v q*` (Rodrigues form, 2 cross products).
    /// The test is inlined at the caller, the products are not.
    #[inline(always)]
    pub const fn rotate(&self, v: Vec3) -> Vec3 {
        // No vector part: the products below are 0 and `v` comes out bit
        // for bit, whatever `w`; skip them.
        if self.x.0 == 0 && self.y.0 == 0 && self.z.0 == 0 {
            return v;
        }
        self.rotate_products(v)
    }

    #[inline(never)]
    const fn rotate_products(&self, v: Vec3) -> Vec3 {
        let u = self.vec();
        let t = u.cross(v).twice();
        v.add(t.scale(self.w)).add(u.cross(t))
    }

    /// Rotation by `angle` about `axis` (normalised here; zero axis → identity).
    pub const fn from_axis_angle(axis: Vec3, angle: Fx) -> Quat {
        let n = axis.norm();
        if n.0 <= 0 {
            return Quat::IDENTITY;
        }
        let (s, c) = angle.mul_sat(Fx::HALF).sin_cos();
        let a = axis.scale(s.div_sat(n));
        Quat::new(a.x, a.y, a.z, c)
    }

    pub const fn to_mat3(&self) -> Mat3 {
        let (x, y, z, w) = (self.x, self.y, self.z, self.w);
        let two = Fx::TWO;
        let xx = x.mul_sat(x);
        let yy = y.mul_sat(y);
        let zz = z.mul_sat(z);
        let xy = x.mul_sat(y);
        let xz = x.mul_sat(z);
        let yz = y.mul_sat(z);
        let wx = w.mul_sat(x);
        let wy = w.mul_sat(y);
        let wz = w.mul_sat(z);
        Mat3::from_rows(
            Vec3::new(
                Fx::ONE.sub_sat(two.mul_sat(yy.add_sat(zz))),
                two.mul_sat(xy.sub_sat(wz)),
                two.mul_sat(xz.add_sat(wy)),
            ),
            Vec3::new(
                two.mul_sat(xy.add_sat(wz)),
                Fx::ONE.sub_sat(two.mul_sat(xx.add_sat(zz))),
                two.mul_sat(yz.sub_sat(wx)),
            ),
            Vec3::new(
                two.mul_sat(xz.sub_sat(wy)),
                two.mul_sat(yz.add_sat(wx)),
                Fx::ONE.sub_sat(two.mul_sat(xx.add_sat(yy))),
            ),
        )
    }

    /// From a rotation matrix (Shepperd's method), normalised, `w >= 0`.
    pub const fn from_mat3(m: &Mat3) -> Quat {
        let [r0, r1, r2] = m.r;
        let (m00, m01, m02) = (r0.x, r0.y, r0.z);
        let (m10, m11, m12) = (r1.x, r1.y, r1.z);
        let (m20, m21, m22) = (r2.x, r2.y, r2.z);
        let tr = m00.add_sat(m11).add_sat(m22);
        let q = if tr.0 > 0 {
            let s = tr.add_sat(Fx::ONE).sqrt().mul_sat(Fx::TWO); // 4w
            let k = s.recip();
            Quat::new(
                m21.sub_sat(m12).mul_sat(k),
                m02.sub_sat(m20).mul_sat(k),
                m10.sub_sat(m01).mul_sat(k),
                s.mul_sat(Fx::from_ratio(1, 4)),
            )
        } else if m00.0 > m11.0 && m00.0 > m22.0 {
            let s = Fx::ONE
                .add_sat(m00)
                .sub_sat(m11)
                .sub_sat(m22)
                .sqrt()
                .mul_sat(Fx::TWO);
            let k = s.recip();
            Quat::new(
                s.mul_sat(Fx::from_ratio(1, 4)),
                m01.add_sat(m10).mul_sat(k),
                m02.add_sat(m20).mul_sat(k),
                m21.sub_sat(m12).mul_sat(k),
            )
        } else if m11.0 > m22.0 {
            let s = Fx::ONE
                .add_sat(m11)
                .sub_sat(m00)
                .sub_sat(m22)
                .sqrt()
                .mul_sat(Fx::TWO);
            let k = s.recip();
            Quat::new(
                m01.add_sat(m10).mul_sat(k),
                s.mul_sat(Fx::from_ratio(1, 4)),
                m12.add_sat(m21).mul_sat(k),
                m02.sub_sat(m20).mul_sat(k),
            )
        } else {
            let s = Fx::ONE
                .add_sat(m22)
                .sub_sat(m00)
                .sub_sat(m11)
                .sqrt()
                .mul_sat(Fx::TWO);
            let k = s.recip();
            Quat::new(
                m02.add_sat(m20).mul_sat(k),
                m12.add_sat(m21).mul_sat(k),
                s.mul_sat(Fx::from_ratio(1, 4)),
                m10.sub_sat(m01).mul_sat(k),
            )
        };
        let q = q.normalize();
        if q.w.0 < 0 {
            Quat::new(q.x.neg_sat(), q.y.neg_sat(), q.z.neg_sat(), q.w.neg_sat())
        } else {
            q
        }
    }

    /// Rotation vector (world frame) taking `b` to `self`, small-angle form:
    /// `2·sign(w)·vec(self ⊗ b*)`. Equals `θ·axis` to first order; its norm is
    /// `2·sin(θ/2)` (≤ 2), the gradient of the potential `4(1 − cos(θ/2))`.
    pub const fn error_vector(&self, b: &Quat) -> Vec3 {
        let e = self.mul(&b.conjugate());
        let v = e.vec().twice();
        if e.w.0 < 0 {
            v.neg()
        } else {
            v
        }
    }

    #[cfg(any(test, feature = "float"))]
    pub fn to_f64(self) -> [f64; 4] {
        [
            self.x.to_f64(),
            self.y.to_f64(),
            self.z.to_f64(),
            self.w.to_f64(),
        ]
    }
}

/// A rigid pose: position (m) and orientation.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Pose {
    pub position: Vec3,
    pub orientation: Quat,
}

impl Pose {
    pub const IDENTITY: Pose = Pose {
        position: Vec3::ZERO,
        orientation: Quat::IDENTITY,
    };

    /// `self ∘ p`: the pose `p` (given in self's frame) expressed in the parent frame.
    #[inline]
    pub const fn compose(&self, p: &Pose) -> Pose {
        Pose {
            position: self.orientation.rotate(p.position).add(self.position),
            orientation: self.orientation.mul(&p.orientation),
        }
    }

    pub const fn inverse(&self) -> Pose {
        let qi = self.orientation.conjugate();
        Pose {
            position: qi.rotate(self.position).neg(),
            orientation: qi,
        }
    }

    pub const fn transform_point(&self, v: Vec3) -> Vec3 {
        self.orientation.rotate(v).add(self.position)
    }
}

/// A twist: linear velocity (m/s) and angular velocity (rad/s).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Twist {
    pub linear: Vec3,
    pub angular: Vec3,
}

impl Twist {
    pub const ZERO: Twist = Twist {
        linear: Vec3::ZERO,
        angular: Vec3::ZERO,
    };

    pub const fn add(&self, o: &Twist) -> Twist {
        Twist {
            linear: self.linear.add(o.linear),
            angular: self.angular.add(o.angular),
        }
    }

    pub const fn scale(&self, k: Fx) -> Twist {
        Twist {
            linear: self.linear.scale(k),
            angular: self.angular.scale(k),
        }
    }

    /// Rotate both parts.
    pub const fn rotate(&self, q: &Quat) -> Twist {
        Twist {
            linear: q.rotate(self.linear),
            angular: q.rotate(self.angular),
        }
    }

    /// Power `wrench · twist` (W).
    pub const fn power(&self, w: &Wrench) -> Fx {
        self.linear.dot(w.force).add_sat(self.angular.dot(w.torque))
    }

    pub const fn to_array(&self) -> [Fx; 6] {
        let (l, a) = (self.linear, self.angular);
        [l.x, l.y, l.z, a.x, a.y, a.z]
    }

    pub const fn from_array(v: [Fx; 6]) -> Twist {
        Twist {
            linear: Vec3::new(v[0], v[1], v[2]),
            angular: Vec3::new(v[3], v[4], v[5]),
        }
    }
}

/// A wrench: force (N) and torque (N·m).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Wrench {
    pub force: Vec3,
    pub torque: Vec3,
}

impl Wrench {
    pub const ZERO: Wrench = Wrench {
        force: Vec3::ZERO,
        torque: Vec3::ZERO,
    };

    pub const fn add(&self, o: &Wrench) -> Wrench {
        Wrench {
            force: self.force.add(o.force),
            torque: self.torque.add(o.torque),
        }
    }

    pub const fn neg(&self) -> Wrench {
        Wrench {
            force: self.force.neg(),
            torque: self.torque.neg(),
        }
    }

    pub const fn scale(&self, k: Fx) -> Wrench {
        Wrench {
            force: self.force.scale(k),
            torque: self.torque.scale(k),
        }
    }

    pub const fn rotate(&self, q: &Quat) -> Wrench {
        Wrench {
            force: q.rotate(self.force),
            torque: q.rotate(self.torque),
        }
    }

    /// Saturate force and torque norms separately (Haption's
    /// `virtSaturateTorque(forceThreshold, momentThreshold)`); returns whether
    /// either was clamped.
    pub const fn saturate(&self, max_force: Fx, max_torque: Fx) -> (Wrench, bool) {
        let (f, a) = self.force.clamp_norm(max_force);
        let (t, b) = self.torque.clamp_norm(max_torque);
        (
            Wrench {
                force: f,
                torque: t,
            },
            a || b,
        )
    }

    pub const fn to_array(&self) -> [Fx; 6] {
        let (f, t) = (self.force, self.torque);
        [f.x, f.y, f.z, t.x, t.y, t.z]
    }

    pub const fn from_array(v: [Fx; 6]) -> Wrench {
        Wrench {
            force: Vec3::new(v[0], v[1], v[2]),
            torque: Vec3::new(v[3], v[4], v[5]),
        }
    }
}

/// A joint-space 6-vector (rad, rad/s, N·m... per joint).
pub type Joints = [Fx; 6];

/// Zero joint vector.
pub const JOINTS_ZERO: Joints = [Fx::ZERO; 6];

#[cfg(test)]
mod tests {
    use super::{frac_q32_bitwise, frac_q32_wide, isqrt_bitwise, isqrt_u64, udiv_q32, Fx, Vec3};

    /// `Vec3::norm` as it was: the squares through `norm_sq` (`mul_sat`,
    /// `add_sat`).
    fn norm_reference(v: Vec3) -> Fx {
        let m =
            v.x.0
                .unsigned_abs()
                .max(v.y.0.unsigned_abs())
                .max(v.z.0.unsigned_abs());
        if m == 0 {
            return Fx::ZERO;
        }
        let lz = m.leading_zeros();
        if lz <= 17 {
            let d = 18 - lz;
            let w = Vec3::new(Fx(v.x.0 >> d), Fx(v.y.0 >> d), Fx(v.z.0 >> d));
            let n = w.norm_sq().sqrt().0;
            return if n > (i64::MAX >> d) {
                Fx::MAX
            } else {
                Fx(n << d)
            };
        }
        let k = lz.saturating_sub(34).min(16);
        let w = Vec3::new(Fx(v.x.0 << k), Fx(v.y.0 << k), Fx(v.z.0 << k));
        Fx(w.norm_sq().sqrt().0 >> k)
    }

    /// `Vec3::clamp_norm` as it was: the root first, then the comparison.
    fn clamp_norm_reference(v: Vec3, max: Fx) -> (Vec3, bool) {
        let n = norm_reference(v);
        if n.0 <= max.0 || n.0 <= 0 {
            return (v, false);
        }
        if n.0 == i64::MAX {
            let w = Vec3::new(Fx(v.x.0 >> 2), Fx(v.y.0 >> 2), Fx(v.z.0 >> 2));
            let n = norm_reference(w);
            let u = Vec3::new(w.x.div_sat(n), w.y.div_sat(n), w.z.div_sat(n));
            return (u.scale(max.abs()), true);
        }
        (v.scale(max.abs().div_sat(n)), true)
    }

    #[test]
    fn norm_and_clamp_are_the_root_first_ones() {
        let mut x: u64 = 0x2545_F491_4F6C_DD1D;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        // Components of every width and sign; limits near the norm (the
        // test before the root decides at its edge) and anywhere.
        for i in 0..1_000_000u32 {
            let mut c = [0i64; 3];
            for v in &mut c {
                let r = next();
                *v = (r >> (r % 64)) as i64;
                if r & (1 << 7) != 0 {
                    *v = v.wrapping_neg();
                }
            }
            let v = Vec3::new(Fx(c[0]), Fx(c[1]), Fx(c[2]));
            let n = norm_reference(v);
            assert_eq!(v.norm(), n, "{v:?}");
            let r = next();
            let max = match i % 4 {
                0 => Fx(n.0.wrapping_add((r % 9) as i64 - 4)),
                1 => Fx(n.0 >> 1).add_sat(Fx((r % 7) as i64 - 3)),
                2 => Fx((r >> (r % 64)) as i64),
                _ => Fx(n.0.wrapping_mul(3) / 2).neg_sat(),
            };
            assert_eq!(
                v.clamp_norm(max),
                clamp_norm_reference(v, max),
                "{v:?} {max:?}"
            );
        }
        // Limits at and around the square's edge for small forces.
        for raw in [1i64, 3, 1 << 20, 1 << 31, 20 << 32, (20 << 32) + 1, 1 << 46] {
            let v = Vec3::new(Fx(raw), Fx(-raw), Fx(raw / 3));
            let n = norm_reference(v);
            for d in -8..=8 {
                let max = Fx(n.0 + d);
                assert_eq!(
                    v.clamp_norm(max),
                    clamp_norm_reference(v, max),
                    "{v:?} {max:?}"
                );
            }
        }
    }

    /// `udiv_q32` without its one-division path for small numerators.
    fn udiv_q32_two_step(a: u64, b: u64) -> u64 {
        let (q, r) = (a / b, a % b);
        if q >= (1u64 << 31) {
            return u64::MAX;
        }
        let frac = if r < (1u64 << 32) {
            (r << 32) / b
        } else {
            frac_q32_wide(r, b)
        };
        (q << 32) | frac
    }

    #[test]
    fn small_numerator_division_is_the_two_step_one() {
        let mut x: u64 = 0x6A09_E667_F3BC_C909;
        let mut cases = vec![
            (0u64, 1u64),
            (1, 1),
            ((1 << 31) - 1, 1),
            (1 << 31, 1),
            ((1 << 32) - 1, 1),
            ((1 << 32) - 1, 2),
            (1 << 32, 2),
            ((1 << 32) - 1, u64::MAX),
            (12345, 429_497),
        ];
        for _ in 0..1_000_000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let a = (x >> 32) >> (x % 32);
            let b = (x.rotate_left(17) >> (x % 63)).max(1);
            cases.push((a, b));
        }
        for (a, b) in cases {
            assert_eq!(udiv_q32(a, b), udiv_q32_two_step(a, b), "a {a:#x} b {b:#x}");
        }
    }

    #[test]
    fn newton_root_is_the_digit_by_digit_root() {
        let mut cases = vec![0u64, 1, 2, 3, 4, u64::MAX, u64::MAX - 1, 1 << 62, 1 << 63];
        // Around every square r² (r < 2^32 at every bit length and at the
        // table's bucket edges) and every power of two.
        let mut roots: Vec<u64> = (0..32).flat_map(|b| [1u64 << b, (1u64 << b) + 1]).collect();
        roots.extend((1..32).map(|b| (1u64 << b) - 1));
        roots.push(u64::from(u32::MAX));
        roots.extend((64u64..256).map(|t| isqrt_bitwise((t << 56) - 1) + 1));
        for r in roots {
            let sq = r.wrapping_mul(r);
            cases.extend([sq.wrapping_sub(1), sq, sq.wrapping_add(1)]);
        }
        for b in 0..64 {
            cases.extend([1u64 << b, (1u64 << b).wrapping_sub(1), (1u64 << b) + 1]);
        }
        for t in 64u64..256 {
            for e in 0..32 {
                let n = (t << 56) >> (2 * e);
                cases.extend([
                    n,
                    n.wrapping_sub(1),
                    ((t + 1) << 56).wrapping_sub(1) >> (2 * e),
                ]);
            }
        }
        let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
        for _ in 0..2_000_000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            cases.push(x >> (x % 64));
        }
        for n in cases {
            assert_eq!(isqrt_u64(n), isqrt_bitwise(n), "n {n:#x}");
        }
    }

    #[test]
    fn wide_fraction_is_the_restoring_division() {
        // Edge divisors (normalised top digits at 2^31 and 2^32 − 1, low
        // digits at 0 and 2^32 − 1: the estimate's worst cases), edge
        // remainders, then pseudo-random pairs of every width.
        let mut cases = Vec::new();
        // The domain: `b` is the magnitude of an i64, at most 2^63.
        for b in [
            (1u64 << 32) + 1,
            (1u64 << 33) - 1,
            1u64 << 63,
            (1u64 << 63) - 1,
            0x4000_0000_FFFF_FFFF,
            0x7FFF_FFFF_0000_0000,
            0x4000_0001_0000_0000,
            0x1_0000_FFFF_FFFF,
        ] {
            for r in [
                1u64 << 32,
                b - 1,
                b / 2,
                b - (1 << 32),
                (b >> 1) | (1 << 32),
            ] {
                if r >= (1 << 32) && r < b {
                    cases.push((r, b));
                }
            }
        }
        let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        for _ in 0..2_000_000 {
            let wb = 33 + (next() % 31) as u32; // 33..=63 bits
            let b = (next() >> (64 - wb)) | (1 << (wb - 1));
            let wr = 33 + (next() % u64::from(wb - 32)) as u32;
            let r = next() >> (64 - wr);
            let r = if r >= b { r - b } else { r };
            let r = if r < (1 << 32) { r | (1 << 32) } else { r };
            if r < b {
                cases.push((r, b));
            }
        }
        for (r, b) in cases {
            assert_eq!(
                frac_q32_wide(r, b),
                frac_q32_bitwise(r, b),
                "r {r:#x} b {b:#x}"
            );
        }
        // Through the quotient: 1 / 2.5 and a divisor near the top.
        assert_eq!(udiv_q32(1 << 32, 5 << 31), 0x6666_6666);
        assert_eq!(udiv_q32(3, u64::MAX), 0);
    }
}
