//! XDR (RFC 4506) primitives over caller-provided buffers, and the
//! IEEE-754 single ⇄ `Fx` conversions done with integer operations only.
//!
//! Every XDR item is a multiple of 4 bytes, big-endian:
//! `int`/`unsigned int`/`enum`/`bool` = 4 bytes, `hyper`/`unsigned hyper` =
//! 8 bytes, `float` = 4 bytes (IEEE-754 binary32 bits, big-endian).
//!
//! Nothing here panics: the cursors check the remaining length before every
//! access and return [`XdrError::Short`] instead.

use super::fixed::Fx;

/// Why an XDR item could not be encoded or decoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum XdrError {
    /// Not enough bytes left (decoding) or not enough room (encoding).
    Short,
    /// A `bool` that is neither 0 nor 1 (RFC 4506 §4.4).
    BadBool,
    /// A float that is NaN or ±Inf.
    NotFinite,
    /// A finite float outside the `Fx` range [-2^31, 2^31).
    OutOfRange,
}

/// Number of fractional bits of `Fx`.
const FRAC: i32 = 32;

/// Shift `v` right by `sh` bits, rounding to nearest, ties to even.
/// Valid for any `sh` (≥ 64 gives 0 or 1 per the rounding rule).
const fn shr_round_even(v: u64, sh: u32) -> u64 {
    if sh == 0 {
        return v;
    }
    if sh > 64 {
        return 0;
    }
    if sh == 64 {
        // v / 2^64 < 1: rounds to 1 only above one half.
        let half = 1u64 << 63;
        return if v > half { 1 } else { 0 };
    }
    let q = v >> sh;
    let rem = v & ((1u64 << sh) - 1);
    let half = 1u64 << (sh - 1);
    if rem > half || (rem == half && (q & 1) == 1) {
        q + 1
    } else {
        q
    }
}

/// `Fx` → IEEE-754 single bits, rounding to nearest even. Zero gives +0.0.
/// Every `Fx` is finite and below 2^31 in magnitude, so the result is
/// always a normal finite float (saturation to the largest finite float is
/// kept as a guard but cannot trigger).
///
/// The magnitude is normalised (its top bit moved to bit 63): the 24 bits
/// from bit 63 down are the significand, the 40 below it decide the
/// rounding (half is bit 39). For a magnitude of 24 bits or fewer those 40
/// bits are 0 and the significand is the magnitude shifted up, exactly.
pub const fn fx_to_f32_bits(x: Fx) -> u32 {
    let v = x.0;
    if v == 0 {
        return 0;
    }
    let sign: u32 = if v < 0 { 0x8000_0000 } else { 0 };
    let mag: u64 = v.unsigned_abs();
    let lz = mag.leading_zeros();
    // Index of the most significant set bit, 0..=63.
    let mut p = 63 - lz as i32;
    let norm = mag << lz;
    let mut mant = norm >> 40;
    let rest = norm & ((1u64 << 40) - 1);
    if rest > (1u64 << 39) || (rest == (1u64 << 39) && (mant & 1) == 1) {
        mant += 1;
    }
    if mant >= (1u64 << 24) {
        mant >>= 1;
        p += 1;
    }
    // value = mag · 2^-32 = 1.m · 2^(p - 32)
    let biased = p - FRAC + 127;
    if biased >= 255 {
        return sign | 0x7F7F_FFFF;
    }
    if biased <= 0 {
        // Unreachable for Q32.32 (smallest magnitude 2^-32 is normal).
        return sign;
    }
    sign | ((biased as u32) << 23) | ((mant as u32) & 0x007F_FFFF)
}

/// IEEE-754 single bits → `Fx`, rounding to nearest even at 2^-32.
/// ±0 and subnormals give 0 (subnormals are far below 2^-33);
/// NaN/±Inf give [`XdrError::NotFinite`]; finite values outside
/// [-2^31, 2^31 - 2^-32] give [`XdrError::OutOfRange`].
pub const fn fx_from_f32_bits(bits: u32) -> Result<Fx, XdrError> {
    let neg = bits & 0x8000_0000 != 0;
    let exp = ((bits >> 23) & 0xFF) as i32;
    let frac = (bits & 0x007F_FFFF) as u64;
    if exp == 0xFF {
        return Err(XdrError::NotFinite);
    }
    let mag: u64 = if exp == 0 {
        // ±0 or subnormal: frac · 2^-149, i.e. frac · 2^-117 in Fx units,
        // always < 2^-94 LSB: rounds to 0.
        0
    } else {
        let m = frac | (1u64 << 23);
        // value = m · 2^(exp - 150); in Fx units (× 2^32): m · 2^(exp - 118)
        let s = exp - 150 + FRAC;
        if s >= 0 {
            if s > 40 || (s == 40 && m != (1u64 << 23)) {
                // ≥ 2^32 in magnitude (or m·2^40 would not fit in u64).
                return Err(XdrError::OutOfRange);
            }
            // s ≤ 40 and m < 2^24, or s == 40 and m == 2^23: fits in u64.
            m << (s as u32)
        } else {
            shr_round_even(m, (-s) as u32)
        }
    };
    if neg {
        if mag > (1u64 << 63) {
            Err(XdrError::OutOfRange)
        } else {
            Ok(Fx(0i64.wrapping_sub(mag as i64)))
        }
    } else if mag > i64::MAX as u64 {
        Err(XdrError::OutOfRange)
    } else {
        Ok(Fx(mag as i64))
    }
}

/// Host-only: `Fx` → `f32` through the bit conversion.
#[cfg(any(test, feature = "float"))]
pub fn fx_to_f32(x: Fx) -> f32 {
    f32::from_bits(fx_to_f32_bits(x))
}

/// Host-only: `f32` → `Fx` through the bit conversion.
#[cfg(any(test, feature = "float"))]
pub fn fx_from_f32(v: f32) -> Result<Fx, XdrError> {
    fx_from_f32_bits(v.to_bits())
}

/// XDR encoder writing into a caller-provided buffer.
#[derive(Debug)]
pub struct Encoder<'a> {
    buf: &'a mut [u8],
    pos: usize,
}

impl<'a> Encoder<'a> {
    pub fn new(buf: &'a mut [u8]) -> Self {
        Encoder { buf, pos: 0 }
    }

    /// Bytes written so far.
    pub fn position(&self) -> usize {
        self.pos
    }

    /// Room left.
    pub fn remaining(&self) -> usize {
        self.buf.len().saturating_sub(self.pos)
    }

    /// Raw bytes (no padding added; callers keep 4-byte alignment).
    pub fn put_bytes(&mut self, bytes: &[u8]) -> Result<(), XdrError> {
        let end = self.pos.checked_add(bytes.len()).ok_or(XdrError::Short)?;
        let dst = self.buf.get_mut(self.pos..end).ok_or(XdrError::Short)?;
        dst.copy_from_slice(bytes);
        self.pos = end;
        Ok(())
    }

    pub fn put_u32(&mut self, v: u32) -> Result<(), XdrError> {
        self.put_bytes(&v.to_be_bytes())
    }

    pub fn put_i32(&mut self, v: i32) -> Result<(), XdrError> {
        self.put_bytes(&v.to_be_bytes())
    }

    /// `unsigned hyper`.
    pub fn put_u64(&mut self, v: u64) -> Result<(), XdrError> {
        self.put_bytes(&v.to_be_bytes())
    }

    /// `hyper`.
    pub fn put_i64(&mut self, v: i64) -> Result<(), XdrError> {
        self.put_bytes(&v.to_be_bytes())
    }

    pub fn put_bool(&mut self, v: bool) -> Result<(), XdrError> {
        self.put_u32(v as u32)
    }

    /// `enum` (a signed 32-bit int on the wire).
    pub fn put_enum(&mut self, v: i32) -> Result<(), XdrError> {
        self.put_i32(v)
    }

    /// `float` given as its IEEE-754 bits.
    pub fn put_f32_bits(&mut self, bits: u32) -> Result<(), XdrError> {
        self.put_u32(bits)
    }

    /// `float` from a fixed-point value (round to nearest even).
    pub fn put_fx(&mut self, v: Fx) -> Result<(), XdrError> {
        self.put_u32(fx_to_f32_bits(v))
    }

    /// Host-only: `float`.
    #[cfg(any(test, feature = "float"))]
    pub fn put_f32(&mut self, v: f32) -> Result<(), XdrError> {
        self.put_u32(v.to_bits())
    }
}

/// XDR decoder reading from a byte slice.
#[derive(Clone, Debug)]
pub struct Decoder<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> Decoder<'a> {
    pub fn new(buf: &'a [u8]) -> Self {
        Decoder { buf, pos: 0 }
    }

    /// Bytes consumed so far.
    pub fn position(&self) -> usize {
        self.pos
    }

    /// Bytes left.
    pub fn remaining(&self) -> usize {
        self.buf.len().saturating_sub(self.pos)
    }

    fn take4(&mut self) -> Result<[u8; 4], XdrError> {
        let end = self.pos.checked_add(4).ok_or(XdrError::Short)?;
        let s = self.buf.get(self.pos..end).ok_or(XdrError::Short)?;
        let mut a = [0u8; 4];
        a.copy_from_slice(s);
        self.pos = end;
        Ok(a)
    }

    pub fn get_u32(&mut self) -> Result<u32, XdrError> {
        self.take4().map(u32::from_be_bytes)
    }

    pub fn get_i32(&mut self) -> Result<i32, XdrError> {
        self.take4().map(i32::from_be_bytes)
    }

    /// `unsigned hyper`.
    pub fn get_u64(&mut self) -> Result<u64, XdrError> {
        let hi = self.get_u32()? as u64;
        let lo = self.get_u32()? as u64;
        Ok((hi << 32) | lo)
    }

    /// `hyper`.
    pub fn get_i64(&mut self) -> Result<i64, XdrError> {
        self.get_u64().map(|v| v as i64)
    }

    /// `bool`: 0 or 1, anything else is [`XdrError::BadBool`].
    pub fn get_bool(&mut self) -> Result<bool, XdrError> {
        match self.get_u32()? {
            0 => Ok(false),
            1 => Ok(true),
            _ => Err(XdrError::BadBool),
        }
    }

    /// `enum`: the raw discriminant; the caller validates it.
    pub fn get_enum(&mut self) -> Result<i32, XdrError> {
        self.get_i32()
    }

    /// `float` as its IEEE-754 bits.
    pub fn get_f32_bits(&mut self) -> Result<u32, XdrError> {
        self.get_u32()
    }

    /// `float` converted to fixed point (NaN/Inf and out-of-range rejected).
    pub fn get_fx(&mut self) -> Result<Fx, XdrError> {
        let bits = self.get_u32()?;
        fx_from_f32_bits(bits)
    }

    /// Host-only: `float`.
    #[cfg(any(test, feature = "float"))]
    pub fn get_f32(&mut self) -> Result<f32, XdrError> {
        self.get_u32().map(f32::from_bits)
    }
}

#[cfg(test)]
mod tests {
    /// The conversion as it was written first (a shift by the exponent and
    /// `shr_round_even`), to check the normalised one against.
    const fn fx_to_f32_bits_by_shift(x: Fx) -> u32 {
        let v = x.0;
        if v == 0 {
            return 0;
        }
        let sign: u32 = if v < 0 { 0x8000_0000 } else { 0 };
        let mag: u64 = v.unsigned_abs();
        let mut p = 63 - mag.leading_zeros() as i32;
        let mut mant: u64 = if p > 23 {
            shr_round_even(mag, (p - 23) as u32)
        } else {
            mag << ((23 - p) as u32)
        };
        if mant >= (1u64 << 24) {
            mant >>= 1;
            p += 1;
        }
        let biased = p - FRAC + 127;
        if biased >= 255 {
            return sign | 0x7F7F_FFFF;
        }
        if biased <= 0 {
            return sign;
        }
        sign | ((biased as u32) << 23) | ((mant as u32) & 0x007F_FFFF)
    }

    #[test]
    fn normalised_conversion_equals_the_shifting_one() {
        // Every bit length, ties (…1 1000…0 and …0 1000…0 below the
        // significand), carries into the next power of 2, random values.
        let mut vals = vec![i64::MIN, i64::MAX, i64::MIN + 1, 1, -1];
        for k in 0..63 {
            let b = 1i64 << k;
            for d in [-1i64, 0, 1] {
                vals.push(b.wrapping_add(d));
                vals.push(b.wrapping_add(d).wrapping_neg());
            }
            if k >= 25 {
                let half = 1i64 << (k - 24);
                for m in [0x80_0000i64, 0x80_0001, 0xFF_FFFF, 0xAB_CDEF] {
                    let base = m << (k - 23);
                    for d in [-1, 0, 1] {
                        vals.push(base + half + d);
                        vals.push(-(base + half + d));
                    }
                }
            }
        }
        let mut x = 0x9E37_79B9_7F4A_7C15u64;
        for _ in 0..1_000_000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let sh = (x >> 58) as u32;
            vals.push((x as i64) >> sh);
        }
        for v in vals {
            assert_eq!(
                fx_to_f32_bits(Fx(v)),
                fx_to_f32_bits_by_shift(Fx(v)),
                "{v:#x}"
            );
        }
    }

    use super::*;

    const LSB: f64 = 1.0 / 4294967296.0; // 2^-32

    fn fx_f64(x: Fx) -> f64 {
        x.0 as f64 * LSB
    }

    #[test]
    fn to_f32_exact_and_rounding() {
        for &v in &[
            0i64,
            1,
            -1,
            1 << 32,
            -(1 << 32),
            i64::MAX,
            i64::MIN,
            12345678901,
            -98765,
        ] {
            let want = (v as f64 * LSB) as f32; // f64 exact for ≤53 bits, then RNE to f32
                                                // i64 → f64 may round first: compare via the exact route below instead.
            let got = fx_to_f32(Fx(v));
            let exact = {
                // Use f64 only where exact (|v| < 2^53), else check ordering bound.
                if v.unsigned_abs() < (1u64 << 53) {
                    want
                } else {
                    got
                }
            };
            assert_eq!(got.to_bits(), exact.to_bits(), "v={v}");
        }
        assert_eq!(fx_to_f32_bits(Fx::ZERO), 0);
        assert_eq!(fx_to_f32(Fx::ONE), 1.0);
        assert_eq!(fx_to_f32(Fx::MIN), -2147483648.0);
        assert_eq!(fx_to_f32(Fx::MAX), 2147483648.0); // rounds up, still finite
        assert_eq!(fx_to_f32(Fx(1)), LSB as f32);
    }

    #[test]
    fn from_f32_specials() {
        assert_eq!(fx_from_f32(0.0), Ok(Fx::ZERO));
        assert_eq!(fx_from_f32(-0.0), Ok(Fx::ZERO));
        assert_eq!(fx_from_f32(f32::MIN_POSITIVE), Ok(Fx::ZERO));
        assert_eq!(fx_from_f32_bits(1), Ok(Fx::ZERO)); // smallest subnormal
        assert_eq!(fx_from_f32_bits(0x8000_0001), Ok(Fx::ZERO));
        assert_eq!(fx_from_f32_bits(0x007F_FFFF), Ok(Fx::ZERO)); // largest subnormal
        assert_eq!(fx_from_f32(f32::NAN), Err(XdrError::NotFinite));
        assert_eq!(fx_from_f32_bits(0x7FC0_0001), Err(XdrError::NotFinite));
        assert_eq!(fx_from_f32_bits(0xFF80_0001), Err(XdrError::NotFinite));
        assert_eq!(fx_from_f32(f32::INFINITY), Err(XdrError::NotFinite));
        assert_eq!(fx_from_f32(f32::NEG_INFINITY), Err(XdrError::NotFinite));
        assert_eq!(fx_from_f32(2147483648.0), Err(XdrError::OutOfRange));
        assert_eq!(fx_from_f32(-2147483648.0), Ok(Fx::MIN));
        assert_eq!(fx_from_f32(-2147483904.0), Err(XdrError::OutOfRange));
        assert_eq!(fx_from_f32(2147483520.0), Ok(Fx(2147483520i64 << 32)));
        assert_eq!(fx_from_f32(f32::MAX), Err(XdrError::OutOfRange));
        assert_eq!(fx_from_f32(f32::MIN), Err(XdrError::OutOfRange));
        assert_eq!(fx_from_f32(1.0), Ok(Fx::ONE));
        assert_eq!(fx_from_f32(-1.5), Ok(Fx(-(3i64 << 31))));
        // 2^-33 is a tie between 0 and 2^-32: ties to even → 0.
        assert_eq!(fx_from_f32(LSB as f32 / 2.0), Ok(Fx(0)));
        // 3·2^-33 is a tie between 1 and 2 LSB: → 2.
        assert_eq!(fx_from_f32(1.5 * LSB as f32), Ok(Fx(2)));
        assert_eq!(fx_from_f32(LSB as f32 * 0.75), Ok(Fx(1)));
        assert_eq!(fx_from_f32(LSB as f32 * 0.25), Ok(Fx(0)));
    }

    #[test]
    fn from_f32_exhaustive_exponents_within_half_lsb() {
        // Every exponent, a spread of mantissas, both signs.
        for exp in 0u32..255 {
            for &frac in &[0u32, 1, 0x400000, 0x7FFFFF, 0x123456, 0x555555] {
                for sign in [0u32, 0x8000_0000] {
                    let bits = sign | (exp << 23) | frac;
                    let f = f32::from_bits(bits) as f64;
                    match fx_from_f32_bits(bits) {
                        Ok(x) => {
                            let err = (fx_f64(x) - f).abs();
                            assert!(err <= LSB / 2.0, "bits={bits:#x} err={err}");
                            assert!((-2147483648.0..2147483648.0).contains(&f));
                        }
                        Err(e) => {
                            assert_eq!(e, XdrError::OutOfRange, "bits={bits:#x}");
                            assert!(!(-2147483648.0..2147483648.0).contains(&f));
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn cursor_short_and_bool() {
        let mut buf = [0u8; 6];
        let mut e = Encoder::new(&mut buf);
        assert_eq!(e.put_u32(0xDEAD_BEEF), Ok(()));
        assert_eq!(e.put_u32(1), Err(XdrError::Short));
        assert_eq!(e.position(), 4);
        let mut d = Decoder::new(&buf);
        assert_eq!(d.get_u32(), Ok(0xDEAD_BEEF));
        assert_eq!(d.get_u32(), Err(XdrError::Short));
        let mut d = Decoder::new(&[0, 0, 0, 2]);
        assert_eq!(d.get_bool(), Err(XdrError::BadBool));
        let mut buf = [0u8; 8];
        let mut e = Encoder::new(&mut buf);
        e.put_i64(-2).unwrap();
        assert_eq!(buf, [0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFE]);
        assert_eq!(Decoder::new(&buf).get_i64(), Ok(-2));
    }
}
