//! Fixed-point math vs libm / nalgebra f64 over randomized inputs.
//!
//! Stated (asserted) error bounds:
//! | op | domain | bound |
//! |---|---|---|
//! | `*` | |a|,|b| ≤ 1e4 (|a·b| < 2^31) | 2 LSB (4.7e-10) + f64 rounding of the reference; exact (floor) vs i128 |
//! | `/` | |a| ≤ 1e4, 1e-3 ≤ |b| ≤ 1e4 | 1 LSB + 2^-52 relative |
//! | `sqrt` | 0 ≤ x ≤ 2e9 | 2^-30 relative + 1 LSB |
//! | `sin`, `cos` | |x| ≤ 1e4 | 4e-9 |
//! | `sin_cos_unit` | |x| ≤ 1e4 | 3e-9, results ≤ 1 with 31 fractional bits |
//! | `mul_unit` | |x| ≤ 1e4, |u| ≤ 2 | bit-identical to `*` for 30-bit factors; else |x|·2^-30 + 2 LSB |
//! | `sqrt` (integer root) | any raw | the exact floor root of the normalised mantissa |
//! | `atan2` | |x|,|y| ≤ 1e4 | 1e-8 rad |
//! | `Quat::rotate`, `to_mat3`, `mul`, `Mat3` ops | unit quats, |v| ≤ 10 | 5e-8 |
//! | `Quat::from_mat3`, `from_axis_angle` | random rotations | 5e-8 |
//! Saturation: products/quotients out of range give MAX/MIN, never panic.
#![allow(clippy::needless_range_loop)]

use hap_core::fixed::{Fx, Mat3, Quat, Vec3};
use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use proptest::prelude::*;
use rand::{Rng, SeedableRng};

const LSB: f64 = 1.0 / 4294967296.0;

fn rng() -> rand::rngs::StdRng {
    rand::rngs::StdRng::seed_from_u64(0x4841_5054)
}

fn rand_quat(r: &mut impl Rng) -> (Quat, UnitQuaternion<f64>) {
    let v: [f64; 4] = [
        r.gen_range(-1.0..1.0),
        r.gen_range(-1.0..1.0),
        r.gen_range(-1.0..1.0),
        r.gen_range(-1.0..1.0),
    ];
    let uq = UnitQuaternion::from_quaternion(Quaternion::new(v[3], v[0], v[1], v[2]));
    let q = Quat::new(
        Fx::from_f64(uq.i),
        Fx::from_f64(uq.j),
        Fx::from_f64(uq.k),
        Fx::from_f64(uq.w),
    );
    (q, uq)
}

#[test]
fn scalar_ops_within_bounds() {
    let mut r = rng();
    let (mut e_mul, mut e_div, mut e_sqrt, mut e_sin, mut e_cos, mut e_atan) =
        (0f64, 0f64, 0f64, 0f64, 0f64, 0f64);
    for _ in 0..200_000 {
        let a = Fx::from_f64(r.gen_range(-1e4..1e4));
        let b = Fx::from_f64(r.gen_range(-1e4..1e4));
        let (af, bf) = (a.to_f64(), b.to_f64());
        let m = (a * b).to_f64();
        if (af * bf).abs() < 2.0e9 {
            let e = (m - af * bf).abs();
            e_mul = e_mul.max(e);
            assert!(
                e <= 2.0 * LSB + (af * bf).abs() * 2f64.powi(-52),
                "{af} * {bf}: {e}"
            );
        }
        let d = Fx::from_f64(r.gen_range(1e-3..1e4) * if r.gen_bool(0.5) { 1.0 } else { -1.0 });
        let df = d.to_f64();
        let q = (a / d).to_f64();
        if (af / df).abs() < 2.0e9 {
            let e = (q - af / df).abs();
            e_div = e_div.max(e);
            assert!(
                e <= LSB + (af / df).abs() * 2f64.powi(-52) * 4.0,
                "{af} / {df}: {e}"
            );
        }
        let x = Fx::from_f64(r.gen_range(0.0..2e9f64).powf(r.gen_range(0.0..1.0)));
        let s = x.sqrt().to_f64();
        let e = (s - x.to_f64().sqrt()).abs();
        e_sqrt = e_sqrt.max(e / x.to_f64().sqrt().max(1.0));
        assert!(
            e <= x.to_f64().sqrt() * 2f64.powi(-30) + LSB,
            "sqrt {}: {e}",
            x.to_f64()
        );
        let ang = Fx::from_f64(r.gen_range(-1e4..1e4) * if r.gen_bool(0.5) { 1e-4 } else { 1.0 });
        let (sn, cs) = ang.sin_cos();
        let es = (sn.to_f64() - libm::sin(ang.to_f64())).abs();
        let ec = (cs.to_f64() - libm::cos(ang.to_f64())).abs();
        e_sin = e_sin.max(es);
        e_cos = e_cos.max(ec);
        assert!(
            es <= 4e-9 && ec <= 4e-9,
            "sin/cos {}: {es} {ec}",
            ang.to_f64()
        );
        let at = Fx::atan2(a, b).to_f64();
        let mut ea = (at - libm::atan2(af, bf)).abs();
        if ea > 3.0 {
            ea = (ea - 2.0 * std::f64::consts::PI).abs();
        }
        e_atan = e_atan.max(ea);
        assert!(ea <= 1e-8, "atan2({af}, {bf}) = {at}: {ea}");
    }
    println!("max abs error: mul {e_mul:.2e}, div {e_div:.2e}, sqrt(rel) {e_sqrt:.2e}, sin {e_sin:.2e}, cos {e_cos:.2e}, atan2 {e_atan:.2e}");
}

#[test]
fn small_and_special_values() {
    assert_eq!(Fx::atan2(Fx::ZERO, Fx::ZERO), Fx::ZERO);
    assert!((Fx::atan2(Fx::ZERO, Fx::from_int(-1)).to_f64() - std::f64::consts::PI).abs() < 1e-8);
    assert!(
        (Fx::atan2(Fx::from_int(1), Fx::ZERO).to_f64() - std::f64::consts::FRAC_PI_2).abs() < 1e-8
    );
    assert!((Fx::atan2(Fx(1), Fx(1)).to_f64() - std::f64::consts::FRAC_PI_4).abs() < 1e-8);
    assert_eq!(Fx::from_int(4).sqrt(), Fx::from_int(2));
    assert_eq!(Fx::from_int(-4).sqrt(), Fx::ZERO);
    assert_eq!(Fx::ONE / Fx::ZERO, Fx::MAX);
    assert_eq!(-Fx::ONE / Fx::ZERO, Fx::MIN);
    assert_eq!(Fx::ZERO / Fx::ZERO, Fx::ZERO);
    assert_eq!(Fx::MAX * Fx::MAX, Fx::MAX);
    assert_eq!(Fx::MIN * Fx::MAX, Fx::MIN);
    assert_eq!(Fx::MIN * Fx::MIN, Fx::MAX);
    assert_eq!(Fx::MAX + Fx::ONE, Fx::MAX);
    assert_eq!(-Fx::MIN, Fx::MAX);
    assert_eq!(Fx::MIN.abs(), Fx::MAX);
    assert_eq!(Fx::MIN / Fx(-1), Fx::MAX);
    assert_eq!(Fx::from_milli(1500), Fx::from_ratio(3, 2));
    assert_eq!(Fx::from_ratio(3, 2).to_milli(), 1500);
    // No division panic: a zero or overflowing divisor gives 0, as `ratio`.
    assert_eq!(Fx::from_ratio(1, 0), Fx::ZERO);
    assert_eq!(Fx::from_ratio(-(1 << 47), -1), Fx::ZERO);
    assert!(
        (Fx::from_f64(7.3).wrap_angle().to_f64() - (7.3 - 2.0 * std::f64::consts::PI)).abs() < 1e-8
    );
}

#[test]
fn quaternions_and_matrices_match_nalgebra() {
    let mut r = rng();
    let mut worst = 0f64;
    for _ in 0..20_000 {
        let (q, uq) = rand_quat(&mut r);
        let (p, up) = rand_quat(&mut r);
        let v = [
            r.gen_range(-10.0..10.0),
            r.gen_range(-10.0..10.0),
            r.gen_range(-10.0..10.0),
        ];
        let rv = q.rotate(Vec3::from_f64(v)).to_f64();
        let rr = uq * Vector3::from(v);
        for i in 0..3 {
            worst = worst.max((rv[i] - rr[i]).abs());
        }
        let pq = q.mul(&p);
        let upq = uq * up;
        let f = pq.to_f64();
        let sign = if (f[3] * upq.w) < 0.0 { -1.0 } else { 1.0 };
        for (a, b) in f.iter().zip([upq.i, upq.j, upq.k, upq.w]) {
            worst = worst.max((a - sign * b).abs());
        }
        let m = q.to_mat3();
        let rm = uq.to_rotation_matrix();
        for i in 0..3 {
            let row = m.r[i].to_f64();
            for j in 0..3 {
                worst = worst.max((row[j] - rm[(i, j)]).abs());
            }
        }
        let back = Quat::from_mat3(&m).to_f64();
        let s = if back[3] * uq.w < 0.0 { -1.0 } else { 1.0 };
        for (a, b) in back.iter().zip([uq.i, uq.j, uq.k, uq.w]) {
            worst = worst.max((a - s * b).abs());
        }
        // Matrix ops.
        let mv = m.mul_vec(Vec3::from_f64(v)).to_f64();
        let tv = m.transpose().mul_vec(Vec3::from_f64(v)).to_f64();
        let tv2 = m.tmul_vec(Vec3::from_f64(v)).to_f64();
        let rtv = rm.transpose() * Vector3::from(v);
        for i in 0..3 {
            worst = worst
                .max((mv[i] - rr[i]).abs())
                .max((tv[i] - rtv[i]).abs())
                .max((tv2[i] - rtv[i]).abs());
        }
        let mm = m.mul(&p.to_mat3());
        let rmm = rm * up.to_rotation_matrix();
        for i in 0..3 {
            let row = mm.r[i].to_f64();
            for j in 0..3 {
                worst = worst.max((row[j] - rmm[(i, j)]).abs());
            }
        }
    }
    println!("quat/mat max abs error {worst:.2e}");
    assert!(worst <= 5e-8, "{worst}");
}

#[test]
fn axis_angle_error_vector_and_normalize() {
    let mut r = rng();
    for _ in 0..5000 {
        let axis = [
            r.gen_range(-1.0..1.0),
            r.gen_range(-1.0..1.0),
            r.gen_range(-1.0..1.0),
        ];
        let ang: f64 = r.gen_range(-3.0..3.0);
        let q = Quat::from_axis_angle(Vec3::from_f64(axis), Fx::from_f64(ang));
        let uq = UnitQuaternion::from_axis_angle(
            &nalgebra::Unit::new_normalize(Vector3::from(axis)),
            ang,
        );
        let f = q.to_f64();
        for (a, b) in f.iter().zip([uq.i, uq.j, uq.k, uq.w]) {
            assert!((a - b).abs() < 5e-8, "{a} {b}");
        }
        // Small-angle error vector: ≈ θ·axis for a small extra rotation.
        let small: f64 = r.gen_range(-0.01..0.01);
        let d = Quat::from_axis_angle(Vec3::from_f64(axis), Fx::from_f64(small));
        let e = d.mul(&q).error_vector(&q).to_f64();
        let n = Vector3::from(axis).normalize() * small;
        for i in 0..3 {
            assert!((e[i] - n[i]).abs() < 1e-6, "{e:?} vs {n:?}");
        }
        // normalize / renormalize.
        let k = r.gen_range(0.5..2.0);
        let scaled = Quat::new(
            q.x * Fx::from_f64(k),
            q.y * Fx::from_f64(k),
            q.z * Fx::from_f64(k),
            q.w * Fx::from_f64(k),
        );
        let nq = scaled.normalize();
        assert!((nq.norm_sq().to_f64() - 1.0).abs() < 1e-8);
        let near = Quat::new(q.x * Fx::from_f64(1.001), q.y, q.z, q.w).renormalize();
        assert!((near.norm_sq().to_f64() - 1.0).abs() < 1e-5);
    }
    // Vec3 helpers.
    let v = Vec3::from_f64([3.0, 4.0, 0.0]);
    assert_eq!(v.norm(), Fx::from_int(5));
    let (c, clamped) = v.clamp_norm(Fx::ONE);
    assert!(clamped && (c.norm().to_f64() - 1.0).abs() < 1e-8);
    let x = Vec3::X.cross(Vec3::Y);
    assert_eq!(x, Vec3::Z);
    assert_eq!(Mat3::IDENTITY.mul(&Mat3::IDENTITY), Mat3::IDENTITY);
}

/// Relative error of `got` against the exact `want` (f64).
fn rel_err(got: f64, want: f64) -> f64 {
    ((got - want) / want).abs()
}

#[test]
fn sqrt_at_the_ends_of_the_range() {
    // The largest input drives the integer square root's partial sums
    // highest; the smallest positive one its lowest bits.
    for raw in [
        i64::MAX,
        i64::MAX - 1,
        1 << 62,
        (1 << 62) - 1,
        1,
        2,
        3,
        1 << 32,
    ] {
        let want = (raw as f64 / 4294967296.0).sqrt();
        let got = Fx(raw).sqrt().to_f64();
        assert!(
            rel_err(got, want) < 1e-9 || (got - want).abs() < 3e-10,
            "sqrt({raw}): {got} vs {want}"
        );
    }
    assert_eq!(Fx::MIN.sqrt(), Fx::ZERO);
}

#[test]
fn atan2_at_the_ends_of_the_range() {
    // MIN and MAX components: the quadrant rotation negates them (after
    // scaling), which must neither overflow nor lose the quadrant.
    let ends = [Fx::MIN, Fx(i64::MIN + 1), Fx(-1), Fx::ZERO, Fx(1), Fx::MAX];
    for y in ends {
        for x in ends {
            let want = if x == Fx::ZERO && y == Fx::ZERO {
                0.0
            } else {
                libm::atan2(y.to_f64(), x.to_f64())
            };
            let got = Fx::atan2(y, x).to_f64();
            // (-π, π]: atan2(-0, -x) is +π here.
            let want = if want <= -std::f64::consts::PI + 1e-9 {
                std::f64::consts::PI
            } else {
                want
            };
            assert!(
                (got - want).abs() < 1e-8,
                "atan2({}, {}): {got} vs {want}",
                y.0,
                x.0
            );
        }
    }
}

#[test]
fn norm_of_large_vectors_saturates_instead_of_the_squares() {
    // Components of 2^14 and more used to give a saturated |v|^2, so a norm
    // near sqrt(MAX) ~ 46341 whatever the vector.
    for v in [
        [1.0e6f64, 0.0, 0.0],
        [3.0e4, -4.0e4, 0.0],
        [1.6384e4, 1.6384e4, 1.6384e4],
        [-1.2e9, 1.0e9, 5.0e8],
        [1.0e4, 2.0e4, -2.0e4],
    ] {
        let want = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        let got = Vec3::from_f64(v).norm().to_f64();
        assert!(rel_err(got, want) < 1e-8, "|{v:?}|: {got} vs {want}");
    }
    // Beyond the range: saturates at MAX, never below the largest component.
    assert_eq!(Vec3::new(Fx::MIN, Fx::MIN, Fx::MIN).norm(), Fx::MAX);
    let n = Vec3::new(Fx::MAX, Fx::ZERO, Fx::ZERO).norm();
    assert!(
        rel_err(n.to_f64(), Fx::MAX.to_f64()) < 1e-8,
        "{}",
        n.to_f64()
    );
}

#[test]
fn clamp_norm_bounds_huge_vectors() {
    // The safety limit on a wrench: whatever comes in, what goes out has a
    // norm of at most `max` (it was 21x `max` for a 1e6 N force).
    let max = Fx::from_int(10);
    for v in [
        [1.0e6f64, 0.0, 0.0],
        [-2.0e9, 2.0e9, -2.0e9],
        [5.0e4, 5.0e4, 0.0],
        [2.0e4, 0.0, -1.0],
    ] {
        let (c, clamped) = Vec3::from_f64(v).clamp_norm(max);
        assert!(clamped, "{v:?}");
        assert!(
            c.norm().to_f64() <= 10.0 + 1e-6,
            "{v:?} clamped to |{:?}| = {}",
            c.to_f64(),
            c.norm().to_f64()
        );
        assert!(
            c.norm().to_f64() > 9.99,
            "{v:?} clamped to {}",
            c.norm().to_f64()
        );
    }
    let huge = Vec3::new(Fx::MIN, Fx::MAX, Fx::MIN);
    let (c, _) = huge.clamp_norm(max);
    assert!(c.norm().to_f64() <= 10.0 + 1e-6, "{}", c.norm().to_f64());
}

#[test]
fn clamp_norm_leaves_a_vector_alone_exactly_when_its_norm_is_within() {
    // The quick exit (largest component, sum of magnitudes) may only skip a
    // norm that would have been ≤ max: compare with `norm()` itself, on
    // vectors and limits of every scale, many within a few raw units.
    let mut r = rng();
    for _ in 0..200_000 {
        let e: u32 = r.gen_range(0..62);
        let span = 1i64 << e;
        let v = Vec3::new(
            Fx(r.gen_range(-span..=span)),
            Fx(r.gen_range(-span..=span)),
            Fx(r.gen_range(-span..=span)),
        );
        let n = v.norm();
        let max = match r.gen_range(0..4) {
            0 => n,
            1 => Fx(n.0.saturating_sub(r.gen_range(0..4))),
            2 => Fx(n.0.saturating_add(r.gen_range(0..4))),
            _ => Fx(r.gen_range(0..=span.saturating_mul(2))),
        };
        let (c, clamped) = v.clamp_norm(max);
        if n.0 <= max.0 || n.0 <= 0 {
            assert!(!clamped && c == v, "{v:?} max {max:?} norm {n:?}");
        } else {
            assert!(clamped, "{v:?} max {max:?} norm {n:?}");
        }
    }
}

proptest! {
    #[test]
    fn arithmetic_never_panics(a in any::<i64>(), b in any::<i64>()) {
        let (x, y) = (Fx(a), Fx(b));
        let _ = (x + y, x - y, x * y, x / y, -x, x.abs(), x.sqrt(), x.sin_cos(), Fx::atan2(x, y), x.recip(), x.wrap_angle(), x.to_milli(), x.round_to_i64());
        let v = Vec3::new(x, y, x);
        let _ = (v.norm(), v.clamp_norm(y), v.cross(v), Quat::new(x, y, x, y).normalize(), Quat::from_axis_angle(v, y));
        let q = Quat::new(x, y, y, x);
        let _ = Quat::from_mat3(&q.to_mat3());
    }

    #[test]
    fn mul_matches_exact_product(a in -(1i64 << 47)..(1i64 << 47), b in -(1i64 << 47)..(1i64 << 47)) {
        // Exact reference with i128 (test only): floor(a*b / 2^32).
        let exact = ((a as i128) * (b as i128)) >> 32;
        let got = (Fx(a) * Fx(b)).0 as i128;
        prop_assert_eq!(got, exact);
    }

    #[test]
    fn by_one_is_identity_as_the_general_paths_compute_it(a in any::<i64>()) {
        // `Vec3::scale(ONE)` and `div_sat(ONE)` return their operand without
        // the arithmetic: the exact floor of a·2^32/2^32 (and of a·2^32/2^32
        // as a quotient), saturated like the general paths.
        let x = Fx(a);
        let v = Vec3::new(x, Fx(a.wrapping_mul(3)), Fx(a.rotate_left(17)));
        prop_assert_eq!(v.scale(Fx::ONE), Vec3::new(v.x.mul_sat(Fx::ONE), v.y.mul_sat(Fx::ONE), v.z.mul_sat(Fx::ONE)));
        prop_assert_eq!(v.scale(Fx::ONE), v);
        let q = ((a as i128) << 32) / (1i128 << 32);
        prop_assert_eq!(x.div_sat(Fx::ONE).0 as i128, q);
        // One raw unit away from 1 takes the general path and differs.
        prop_assert_eq!(x.div_sat(Fx(Fx::ONE.0 + 1)).0 as i128,
            (((a as i128) << 32) / ((1i128 << 32) + 1)).clamp(i64::MIN as i128, i64::MAX as i128));
    }

    #[test]
    fn div_matches_exact_quotient(a in -(1i64 << 50)..(1i64 << 50), b in 1i64..(1i64 << 50)) {
        let exact = ((a as i128) << 32) / (b as i128);
        if exact.abs() < (1i128 << 62) {
            prop_assert_eq!((Fx(a) / Fx(b)).0 as i128, exact);
        }
    }
}

#[test]
fn mul_unit_is_mul_for_q2_30_factors_and_close_otherwise() {
    let mut r = rng();
    let mut worst = 0f64;
    for _ in 0..200_000 {
        let x = Fx::from_f64(r.gen_range(-1e4..1e4));
        let u = Fx::from_f64(r.gen_range(-2.0..2.0));
        // A factor with 30 fractional bits: the very same product as `*`.
        let u30 = Fx(u.0 & !3);
        assert_eq!(x.mul_unit(u30), x * u30, "{x:?} * {u30:?}");
        // Any factor: the dropped bits cost less than |x|·2^-30.
        let e = (x.mul_unit(u).to_f64() - x.to_f64() * u.to_f64()).abs();
        worst = worst.max(e);
        assert!(
            e <= x.to_f64().abs() * 2f64.powi(-30) + 2.0 * LSB,
            "{x:?} * {u:?}: {e}"
        );
    }
    // Extremes: saturation, and a factor beyond 2 is clamped, never wrapped.
    assert_eq!(Fx::MAX.mul_unit(Fx::TWO), Fx::MAX);
    assert_eq!(Fx::MIN.mul_unit(Fx::TWO), Fx::MIN);
    assert_eq!(Fx::MIN.mul_unit(Fx::from_int(-2)), Fx::MAX);
    assert_eq!(
        Fx::from_int(3).mul_unit(Fx::from_int(1000)),
        Fx::from_int(6)
    );
    assert_eq!(Fx::from_int(3).mul_unit(Fx::MIN), Fx::from_int(-6));
    println!("mul_unit max abs error (any factor): {worst:.2e}");
}

#[test]
fn sin_cos_unit_within_bound() {
    let mut r = rng();
    let (mut es, mut ec) = (0f64, 0f64);
    for i in 0..400_000 {
        let x = if i % 2 == 0 {
            r.gen_range(-4.0..4.0)
        } else {
            r.gen_range(-1e4..1e4)
        };
        let a = Fx::from_f64(x);
        let (s, c) = a.sin_cos_unit();
        let xf = a.to_f64();
        es = es.max((s.to_f64() - libm::sin(xf)).abs());
        ec = ec.max((c.to_f64() - libm::cos(xf)).abs());
        assert!(s.abs() <= Fx::ONE && c.abs() <= Fx::ONE, "{x}");
        assert_eq!(s.0 & 1, 0);
        assert_eq!(c.0 & 1, 0);
    }
    println!("sin_cos_unit max abs error: sin {es:.2e}, cos {ec:.2e}");
    assert!(es <= 3e-9 && ec <= 3e-9, "{es} {ec}");
}

#[test]
fn sqrt_is_the_floor_root() {
    let mut r = rng();
    for _ in 0..100_000 {
        let raw: i64 = r.gen_range(1..i64::MAX);
        let s = Fx(raw).sqrt().0 as u128;
        // Fx::sqrt takes the integer root of the mantissa shifted left by
        // an even k ≤ 32, then shifts it back: compare with the exact root.
        let a = raw as u64;
        let k = (a.leading_zeros() & !1).min(32);
        let m = (a << k) as u128;
        let f = (m as f64).sqrt() as u128;
        let mut exact = f;
        while exact * exact > m {
            exact -= 1;
        }
        while (exact + 1) * (exact + 1) <= m {
            exact += 1;
        }
        assert_eq!(s, exact << ((32 - k) / 2), "sqrt raw {raw}");
    }
}

/// `half()` is `mul_sat(Fx::HALF)` for every value: the ends of the range,
/// odd raws of both signs, random raws of every scale.
#[test]
fn half_is_the_product_by_one_half() {
    let mut r = rng();
    let mut vals = vec![
        i64::MIN,
        i64::MIN + 1,
        i64::MAX,
        i64::MAX - 1,
        -1,
        0,
        1,
        3,
        -3,
    ];
    for _ in 0..1_000_000 {
        let sh = r.gen_range(0..64);
        vals.push(r.gen::<i64>() >> sh);
    }
    for v in vals {
        assert_eq!(Fx(v).half(), Fx(v).mul_sat(Fx::HALF), "{v:#x}");
        let w = Vec3::new(Fx(v), Fx(v.wrapping_neg()), Fx(v >> 7));
        assert_eq!(w.half(), w.scale(Fx::HALF));
    }
}
