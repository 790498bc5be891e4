//! Property and oracle tests for crc.rs, xdr.rs and protocol.rs.
//!
//! - every frame type round-trips (proptest), fits in 90 bytes;
//! - decode never panics on random bytes nor on CRC-valid mutations;
//! - each `DecodeError` is produced by a crafted input;
//! - CRC-32C agrees with the `crc` crate (CRC_32_ISCSI);
//! - our XDR bytes equal serde-xdr's (GPL-3.0, dev-dependency only);
//! - float⇄fixed conversions agree with the host's correctly rounded ones.

use hap_core::config::{CommandType, IndexingMode, ServoConfig, VirtualObjectParams};
use hap_core::crc::crc32c;
use hap_core::fixed::{Fx, Pose, Quat, Twist, Vec3, Wrench};
use hap_core::protocol::*;
use hap_core::xdr::{fx_from_f32_bits, fx_to_f32_bits, Decoder, Encoder, XdrError};
use proptest::prelude::*;
use serde::{Deserialize, Serialize};

const TWO32: f64 = 4294967296.0;

// ---------- strategies ----------

/// An f32 that is exactly an `Fx` (in range, and ≥ 2^-32 or 0).
fn arb_f32_val() -> impl Strategy<Value = f32> {
    prop_oneof![
        (-1.0e6f32..1.0e6f32),
        (-10.0f32..10.0f32),
        Just(0.0f32),
        (-2.0e9f32..2.0e9f32),
    ]
}

fn to_fx(v: f32) -> Fx {
    fx_from_f32_bits(v.to_bits()).unwrap()
}

fn arb_fx() -> impl Strategy<Value = Fx> {
    arb_f32_val().prop_map(to_fx)
}

fn arb_pos_fx() -> impl Strategy<Value = Fx> {
    (1.0e-6f32..1.0e4f32).prop_map(to_fx)
}

fn arb_vec3() -> impl Strategy<Value = Vec3> {
    (arb_fx(), arb_fx(), arb_fx()).prop_map(|(x, y, z)| Vec3 { x, y, z })
}

fn arb_quat() -> impl Strategy<Value = Quat> {
    (-1.0f64..1.0, -1.0f64..1.0, -1.0f64..1.0, -1.0f64..1.0)
        .prop_filter("non-degenerate", |(a, b, c, d)| {
            a * a + b * b + c * c + d * d > 0.01
        })
        .prop_map(|(a, b, c, d)| {
            let n = (a * a + b * b + c * c + d * d).sqrt();
            let q = |v: f64| to_fx((v / n) as f32);
            Quat {
                x: q(a),
                y: q(b),
                z: q(c),
                w: q(d),
            }
        })
}

fn arb_pose() -> impl Strategy<Value = Pose> {
    (arb_vec3(), arb_quat()).prop_map(|(position, orientation)| Pose {
        position,
        orientation,
    })
}

fn arb_twist() -> impl Strategy<Value = Twist> {
    (arb_vec3(), arb_vec3()).prop_map(|(linear, angular)| Twist { linear, angular })
}

fn arb_wrench() -> impl Strategy<Value = Wrench> {
    (arb_vec3(), arb_vec3()).prop_map(|(force, torque)| Wrench { force, torque })
}

fn arb_frame() -> impl Strategy<Value = Frame> {
    let ctype = (0u32..3).prop_map(|v| CommandType::from_u32(v).unwrap());
    let imode = (0u32..5).prop_map(|v| IndexingMode::from_u32(v).unwrap());
    let ftype = (0usize..FrameType::ALL.len()).prop_map(|i| FrameType::ALL[i]);
    prop_oneof![
        any::<u32>().prop_map(|client_nonce| Frame::OpenSession { client_nonce }),
        Just(Frame::CloseSession),
        arb_pose().prop_map(Frame::SetBaseFrame),
        arb_pose().prop_map(Frame::SetObservationFrame),
        (arb_pos_fx(), arb_pos_fx()).prop_map(|(force, speed)| Frame::SetFactors { force, speed }),
        (1.0e-6f32..1.0f32).prop_map(|v| Frame::SetTimeStep(to_fx(v))),
        ctype.prop_map(Frame::SetCommandType),
        imode.prop_map(Frame::SetIndexingMode),
        (arb_pos_fx(), 0.0f32..100.0, 0.0f32..100.0, 0.0f32..100.0).prop_map(|(mass, a, b, c)| {
            Frame::AttachVirtualObject(VirtualObjectParams {
                mass,
                inertia: Vec3 {
                    x: to_fx(a),
                    y: to_fx(b),
                    z: to_fx(c),
                },
            })
        }),
        Just(Frame::DetachVirtualObject),
        any::<bool>().prop_map(Frame::PowerRequest),
        (arb_pose(), arb_twist()).prop_map(|(pose, twist)| Frame::VprStream { pose, twist }),
        (arb_pose(), arb_wrench(), any::<[u32; 4]>()).prop_map(
            |(handle_pose, coupling_wrench, w)| {
                Frame::Answer(Answer {
                    handle_pose,
                    coupling_wrench,
                    status: w[0],
                    alarms: w[1],
                    cycle: w[2],
                    vpr_seq: w[3],
                })
            }
        ),
        (arb_twist(), any::<[u32; 5]>()).prop_map(|(handle_twist, w)| {
            Frame::AnswerTwist(AnswerTwist {
                handle_twist,
                status: w[0],
                alarms: w[1],
                cycle: w[2],
                vpr_seq: w[3],
                link_energy: w[4],
            })
        }),
        (any::<u32>(), any::<u32>()).prop_map(|(client_nonce, period_us)| Frame::SessionAck {
            client_nonce,
            period_us
        }),
        (ftype, any::<u32>()).prop_map(|(acked_type, acked_seq)| Frame::Ack {
            acked_type,
            acked_seq
        }),
        (any::<u32>(), any::<u32>()).prop_map(|(reason, rejected_seq)| Frame::Error {
            reason,
            rejected_seq
        }),
    ]
}

fn arb_header() -> impl Strategy<Value = FrameHeader> {
    (0u16..=CTRL_KNOWN, any::<u16>(), any::<u32>(), any::<u32>()).prop_map(
        |(control, session, seq, timestamp_us)| FrameHeader {
            control,
            session,
            seq,
            timestamp_us,
        },
    )
}

fn enc(h: &FrameHeader, f: &Frame) -> Vec<u8> {
    let mut buf = [0u8; MAX_FRAME_LEN];
    let n = encode(h, f, &mut buf);
    buf[..n].to_vec()
}

fn fix_crc(b: &mut [u8]) {
    assert!(seal_crc(b));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn frame_round_trip(h in arb_header(), f in arb_frame()) {
        let b = enc(&h, &f);
        prop_assert!(b.len() <= MAX_FRAME_LEN);
        prop_assert_eq!(b.len(), f.encoded_len());
        prop_assert_eq!(expected_len(&b), Some(b.len()));
        prop_assert_eq!(decode(&b), Ok((h, f)));
    }

    #[test]
    fn random_bytes_never_panic(b in proptest::collection::vec(any::<u8>(), 0..200)) {
        let _ = decode(&b);
        let _ = expected_len(&b);
    }

    #[test]
    fn random_valid_prefix_never_panics(ty in any::<u8>(), len in 0usize..100, fill in any::<u8>(), crc_ok in any::<bool>()) {
        let mut b = vec![fill; len];
        if len >= 4 { b[0] = MAGIC[0]; b[1] = MAGIC[1]; b[2] = VERSION; b[3] = ty; }
        if crc_ok && len >= 4 { fix_crc(&mut b); }
        let r = decode(&b);
        if let Ok((h, f)) = r { prop_assert_eq!(decode(&enc(&h, &f)), Ok((h, f))); }
    }

    /// Mutate a valid frame's header/payload, keep the CRC valid: decode must
    /// not panic, and whatever it accepts must be a fixed point of
    /// decode∘encode.
    #[test]
    fn crc_valid_mutations(h in arb_header(), f in arb_frame(), muts in proptest::collection::vec((any::<usize>(), any::<u8>()), 1..8)) {
        let mut b = enc(&h, &f);
        let n = b.len();
        for (at, v) in muts { b[at % (n - 4)] = v; }
        fix_crc(&mut b);
        if let Ok((h2, f2)) = decode(&b) {
            prop_assert_eq!(decode(&enc(&h2, &f2)), Ok((h2, f2)));
        }
    }

    #[test]
    fn crc_agrees_with_crc_crate(data in proptest::collection::vec(any::<u8>(), 0..512)) {
        let oracle = crc::Crc::<u32>::new(&crc::CRC_32_ISCSI);
        prop_assert_eq!(crc32c(&data), oracle.checksum(&data));
    }

    #[test]
    fn f32_to_fx_within_half_lsb(bits in any::<u32>()) {
        let f = f32::from_bits(bits);
        let r = fx_from_f32_bits(bits);
        if !f.is_finite() {
            prop_assert_eq!(r, Err(XdrError::NotFinite));
        } else {
            // f·2^32 is exact in f64; round half to even is the reference.
            let scaled = (f as f64) * TWO32;
            let want = scaled.round_ties_even();
            if !(-9223372036854775808.0..9223372036854775808.0).contains(&want) {
                prop_assert_eq!(r, Err(XdrError::OutOfRange));
            } else {
                let got = r.unwrap().0;
                prop_assert_eq!(got, want as i64, "bits={:#x}", bits);
                prop_assert!(((got as f64) - scaled).abs() <= 0.5);
            }
        }
    }

    #[test]
    fn fx_to_f32_correctly_rounded(v in any::<i64>()) {
        // `i64 as f32` rounds to nearest even; ·2^-32 is exact.
        let want = (v as f32) * (1.0 / TWO32 as f32);
        prop_assert_eq!(fx_to_f32_bits(Fx(v)), want.to_bits());
    }

    #[test]
    fn f32_fx_f32_is_identity_in_range(v in arb_f32_val()) {
        // Exact wherever the f32's ulp is at least Q32.32's LSB (2^-32), i.e.
        // |v| >= 2^-9; below, f32 has finer steps than Fx and the round trip
        // is within half an Fx LSB (2^-33).
        let x = to_fx(v);
        let back = f32::from_bits(fx_to_f32_bits(x));
        if v.abs() >= 1.0 / 512.0 || v == 0.0 {
            prop_assert_eq!(back, if v == 0.0 { 0.0 } else { v });
        } else {
            prop_assert!(((back as f64) - (v as f64)).abs() <= 1.0 / (TWO32 * 2.0),
                "v={} back={}", v, back);
        }
    }
}

#[test]
fn every_frame_type_fits() {
    for t in FrameType::ALL {
        assert!(t.frame_len() <= MAX_FRAME_LEN, "{t:?}");
        assert_eq!(t.payload_len() % 4, 0);
        assert_eq!(FrameType::from_u8(t as u8), Some(t));
    }
    assert_eq!(FrameType::Answer.frame_len(), 88);
    assert_eq!(FrameType::VprStream.frame_len(), 72);
}

// ---------- each DecodeError from a crafted input ----------

fn valid(f: Frame) -> Vec<u8> {
    enc(
        &FrameHeader {
            control: 0,
            session: 1,
            seq: 2,
            timestamp_us: 3,
        },
        &f,
    )
}

/// Overwrite payload word `i` (0-based, after the header) and fix the CRC.
fn with_word(mut b: Vec<u8>, i: usize, w: u32) -> Vec<u8> {
    let at = HEADER_LEN + 4 * i;
    b[at..at + 4].copy_from_slice(&w.to_be_bytes());
    fix_crc(&mut b);
    b
}

#[test]
fn each_decode_error_is_reachable() {
    use DecodeError::*;
    let base = valid(Frame::SetTimeStep(Fx(1 << 22)));
    let mut cases: Vec<(DecodeError, Vec<u8>)> = Vec::new();
    cases.push((TooShort, base[..MIN_FRAME_LEN - 1].to_vec()));
    cases.push((TooShort, Vec::new()));
    cases.push((TooLong, vec![0u8; MAX_FRAME_LEN + 1]));
    let mut b = base.clone();
    b[0] = b'X';
    cases.push((BadMagic, b));
    let mut b = base.clone();
    b[2] = 2;
    cases.push((BadVersion, b));
    let mut b = base.clone();
    b[20] ^= 1;
    cases.push((BadCrc, b));
    let mut b = base.clone();
    b[3] = 0x7F;
    fix_crc(&mut b);
    cases.push((UnknownType, b));
    let mut b = base.clone();
    b[3] = FrameType::CloseSession as u8; // 24 bytes but CloseSession is 20
    fix_crc(&mut b);
    cases.push((LengthMismatch, b));
    let mut b = base.clone();
    b[4] = 0x80;
    fix_crc(&mut b);
    cases.push((BadFlags, b));
    cases.push((NotFinite, with_word(base.clone(), 0, f32::NAN.to_bits())));
    cases.push((
        NotFinite,
        with_word(base.clone(), 0, f32::INFINITY.to_bits()),
    ));
    cases.push((OutOfRange, with_word(base.clone(), 0, 2.0f32.to_bits()))); // dt > 1 s
    cases.push((OutOfRange, with_word(base.clone(), 0, (-1.0f32).to_bits())));
    cases.push((OutOfRange, with_word(base.clone(), 0, 3.0e9f32.to_bits()))); // beyond Fx
    let pose = valid(Frame::SetBaseFrame(Pose::default()));
    cases.push((OutOfRange, with_word(pose.clone(), 6, 0))); // |q| = 0
    cases.push((NotFinite, with_word(pose, 3, f32::NEG_INFINITY.to_bits())));
    let ct = valid(Frame::SetCommandType(CommandType::Impedance));
    cases.push((BadEnum, with_word(ct.clone(), 0, 3)));
    cases.push((BadEnum, with_word(ct, 0, u32::MAX)));
    let im = valid(Frame::SetIndexingMode(IndexingMode::All));
    cases.push((BadEnum, with_word(im, 0, 5)));
    let ack = valid(Frame::Ack {
        acked_type: FrameType::VprStream,
        acked_seq: 1,
    });
    cases.push((BadEnum, with_word(ack, 0, 0x7F)));
    let pw = valid(Frame::PowerRequest(false));
    cases.push((BadBool, with_word(pw, 0, 2)));
    let vo = valid(Frame::AttachVirtualObject(VirtualObjectParams {
        mass: Fx::ONE,
        inertia: Vec3::default(),
    }));
    cases.push((OutOfRange, with_word(vo.clone(), 0, 0))); // mass 0
    cases.push((OutOfRange, with_word(vo, 2, (-1.0f32).to_bits()))); // negative inertia
    let fac = valid(Frame::SetFactors {
        force: Fx::ONE,
        speed: Fx::ONE,
    });
    cases.push((OutOfRange, with_word(fac, 1, 0)));

    let mut seen = [false; DecodeError::COUNT];
    for (want, bytes) in &cases {
        assert_eq!(decode(bytes), Err(*want), "bytes {bytes:02x?}");
        seen[want.reason_index()] = true;
    }
    for e in DecodeError::ALL {
        assert!(seen[e.reason_index()], "{e:?} not produced");
        assert_eq!(REASON_NAMES[e.reason_index()], e.name());
    }
}

#[test]
fn helpers_for_proto_in() {
    let mut cfg = ServoConfig::default();
    let vo = VirtualObjectParams {
        mass: Fx::from_int(3),
        inertia: Vec3::default(),
    };
    assert!(apply_to_config(&Frame::AttachVirtualObject(vo), &mut cfg));
    assert_eq!(cfg.attached_object, Some(vo));
    assert!(apply_to_config(
        &Frame::SetCommandType(CommandType::VirtMech),
        &mut cfg
    ));
    assert_eq!(cfg.command_type, CommandType::VirtMech);
    assert!(apply_to_config(
        &Frame::SetFactors {
            force: Fx::from_int(2),
            speed: Fx::ONE
        },
        &mut cfg
    ));
    assert_eq!(cfg.force_factor, Fx::from_int(2));
    assert!(apply_to_config(&Frame::DetachVirtualObject, &mut cfg));
    assert_eq!(cfg.attached_object, None);
    let before = cfg;
    assert!(!apply_to_config(&Frame::PowerRequest(true), &mut cfg));
    assert!(!apply_to_config(&Frame::CloseSession, &mut cfg));
    assert_eq!(cfg, before);
    assert_eq!(power_request(&Frame::PowerRequest(true)), Some(true));

    let h = FrameHeader {
        control: 0,
        session: 1,
        seq: 42,
        timestamp_us: 777,
    };
    let f = Frame::VprStream {
        pose: Pose::default(),
        twist: Twist::default(),
    };
    let v = vpr_from(&h, &f, 9).unwrap();
    assert!(v.valid && v.seq == 42 && v.client_time_us == 777 && v.received_cycle == 9);
    assert_eq!(vpr_from(&h, &Frame::CloseSession, 9), None);
    assert!(vpr_accept(&v, 43));
    assert!(!vpr_accept(&v, 42));
    assert!(!vpr_accept(&v, 41));
    assert!(vpr_accept(&Default::default(), 0));
}

// ---------- serde-xdr oracle ----------

#[derive(Serialize, Deserialize, Debug, PartialEq)]
struct XPose {
    x: f32,
    y: f32,
    z: f32,
    qx: f32,
    qy: f32,
    qz: f32,
    qw: f32,
}

#[derive(Serialize, Deserialize, Debug, PartialEq)]
struct XSix {
    a: [f32; 3],
    b: [f32; 3],
}

#[derive(Serialize, Deserialize, Debug, PartialEq)]
struct XVpr {
    pose: XPose,
    twist: XSix,
}

#[derive(Serialize, Deserialize, Debug, PartialEq)]
struct XAnswer {
    pose: XPose,
    wrench: XSix,
    status: u32,
    alarms: u32,
    cycle: u32,
    vpr_seq: u32,
}

#[derive(Serialize, Deserialize, Debug, PartialEq)]
enum XCommandType {
    None,
    Impedance,
    VirtMech,
}

#[derive(Serialize, Deserialize, Debug, PartialEq)]
struct XPrims {
    a: u32,
    b: i32,
    c: u64,
    d: i64,
    e: bool,
    f: f32,
}

fn f(x: Fx) -> f32 {
    f32::from_bits(fx_to_f32_bits(x))
}

fn xpose(p: &Pose) -> XPose {
    XPose {
        x: f(p.position.x),
        y: f(p.position.y),
        z: f(p.position.z),
        qx: f(p.orientation.x),
        qy: f(p.orientation.y),
        qz: f(p.orientation.z),
        qw: f(p.orientation.w),
    }
}

fn xsix(a: &Vec3, b: &Vec3) -> XSix {
    XSix {
        a: [f(a.x), f(a.y), f(a.z)],
        b: [f(b.x), f(b.y), f(b.z)],
    }
}

fn payload(b: &[u8]) -> &[u8] {
    &b[HEADER_LEN..b.len() - CRC_LEN]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(500))]

    #[test]
    fn xdr_primitives_match_serde_xdr(a in any::<u32>(), b in any::<i32>(), c in any::<u64>(), d in any::<i64>(), e in any::<bool>(), fb in any::<u32>()) {
        let fl = f32::from_bits(fb);
        let mut buf = [0u8; 32];
        let mut en = Encoder::new(&mut buf);
        en.put_u32(a).unwrap();
        en.put_i32(b).unwrap();
        en.put_u64(c).unwrap();
        en.put_i64(d).unwrap();
        en.put_bool(e).unwrap();
        en.put_f32_bits(fb).unwrap();
        assert_eq!(en.position(), 32);
        let oracle = serde_xdr::to_bytes(&XPrims { a, b, c, d, e, f: fl }).unwrap();
        prop_assert_eq!(&buf[..], &oracle[..]);
        let mut de = Decoder::new(&oracle);
        prop_assert_eq!(de.get_u32(), Ok(a));
        prop_assert_eq!(de.get_i32(), Ok(b));
        prop_assert_eq!(de.get_u64(), Ok(c));
        prop_assert_eq!(de.get_i64(), Ok(d));
        prop_assert_eq!(de.get_bool(), Ok(e));
        prop_assert_eq!(de.get_f32_bits(), Ok(fb));
        prop_assert_eq!(de.remaining(), 0);
    }

    #[test]
    fn vpr_payload_matches_serde_xdr(pose in arb_pose(), twist in arb_twist()) {
        let b = valid(Frame::VprStream { pose, twist });
        let x = XVpr { pose: xpose(&pose), twist: xsix(&twist.linear, &twist.angular) };
        let oracle = serde_xdr::to_bytes(&x).unwrap();
        prop_assert_eq!(payload(&b), &oracle[..]);
        let back: XVpr = serde_xdr::from_bytes(payload(&b)).unwrap();
        prop_assert_eq!(back, x);
    }

    #[test]
    fn answer_payload_matches_serde_xdr(pose in arb_pose(), w in arb_wrench(), s in any::<[u32; 4]>()) {
        let a = Answer { handle_pose: pose, coupling_wrench: w, status: s[0], alarms: s[1], cycle: s[2], vpr_seq: s[3] };
        let b = valid(Frame::Answer(a));
        let x = XAnswer { pose: xpose(&pose), wrench: xsix(&w.force, &w.torque), status: s[0], alarms: s[1], cycle: s[2], vpr_seq: s[3] };
        prop_assert_eq!(payload(&b), &serde_xdr::to_bytes(&x).unwrap()[..]);
    }

    #[test]
    fn config_payloads_match_serde_xdr(pose in arb_pose(), fa in arb_pos_fx(), fb in arb_pos_fx(), on in any::<bool>(), ct in 0u32..3) {
        let b = valid(Frame::SetBaseFrame(pose));
        prop_assert_eq!(payload(&b), &serde_xdr::to_bytes(&xpose(&pose)).unwrap()[..]);
        let b = valid(Frame::SetFactors { force: fa, speed: fb });
        prop_assert_eq!(payload(&b), &serde_xdr::to_bytes(&(f(fa), f(fb))).unwrap()[..]);
        let b = valid(Frame::PowerRequest(on));
        prop_assert_eq!(payload(&b), &serde_xdr::to_bytes(&on).unwrap()[..]);
        let b = valid(Frame::SetCommandType(CommandType::from_u32(ct).unwrap()));
        let xe = [XCommandType::None, XCommandType::Impedance, XCommandType::VirtMech];
        prop_assert_eq!(payload(&b), &serde_xdr::to_bytes(&xe[ct as usize]).unwrap()[..]);
    }
}
