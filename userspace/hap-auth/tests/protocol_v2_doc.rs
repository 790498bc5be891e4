//! Protocol v2 test vectors in Documentation/protocol.md §7.6: generated
//! here under the published test key, and the test fails if the document
//! differs by one byte. Regenerate with:
//!
//!   HAP_WRITE_DOC=1 cargo test -p hap-auth --test protocol_v2_doc
//!
//! A second test reads the vectors back from the document and checks every
//! tag with an HMAC-SHA-256 written here from RFC 2104 on top of the plain
//! SHA-256 (not the `hmac` crate the library uses), the keys derived as §7.2
//! says: what an independent implementation would do.

use std::fmt::Write;

use hap_auth::*;
use hap_core::config::{CommandType, IndexingMode, VirtualObjectParams};
use hap_core::fixed::{Fx, Pose, Quat, Twist, Vec3, Wrench};
use hap_core::protocol::*;
use hap_core::vp::{alarm, status};
use sha2::{Digest, Sha256};

const BEGIN: &str = "<!-- BEGIN V2 TEST VECTORS (hap-auth/tests/protocol_v2_doc.rs) -->\n";
const END: &str = "<!-- END V2 TEST VECTORS -->";

const NC: [u8; NONCE_LEN] = [
    0xa0, 0xa1, 0xa2, 0xa3, 0xa4, 0xa5, 0xa6, 0xa7, 0xa8, 0xa9, 0xaa, 0xab, 0xac, 0xad, 0xae, 0xaf,
];
const NS: [u8; NONCE_LEN] = [
    0xb0, 0xb1, 0xb2, 0xb3, 0xb4, 0xb5, 0xb6, 0xb7, 0xb8, 0xb9, 0xba, 0xbb, 0xbc, 0xbd, 0xbe, 0xbf,
];

fn fx(v: f64) -> Fx {
    Fx((v * 4294967296.0).round() as i64)
}

fn v3(x: f64, y: f64, z: f64) -> Vec3 {
    Vec3 {
        x: fx(x),
        y: fx(y),
        z: fx(z),
    }
}

fn h(seq: u32, session: u16, control: u16) -> FrameHeader {
    FrameHeader {
        control,
        session,
        seq,
        timestamp_us: 1_000_000 + seq,
    }
}

/// (name of the key, frame) for every type, as protocol.md §5's samples.
fn vectors() -> Vec<(&'static str, Wire)> {
    let psk = Psk::test_key();
    let keys = SessionKeys::derive(&psk, &NC, &NS);
    let pose = Pose {
        position: v3(0.1, -0.05, 0.3),
        orientation: Quat {
            x: Fx::ZERO,
            y: Fx::ZERO,
            z: fx(0.5f64.sqrt()),
            w: fx(0.5f64.sqrt()),
        },
    };
    let twist = Twist {
        linear: v3(0.01, 0.0, -0.02),
        angular: v3(0.0, 0.0, 0.5),
    };
    let wrench = Wrench {
        force: v3(1.5, -2.0, 0.25),
        torque: v3(0.0, 0.125, 0.0),
    };
    let req = |seq: u32, control: u16, f: Frame| {
        (
            "K_c2s",
            seal_request(&keys, &h(seq, 7, control), &f).unwrap(),
        )
    };
    let mut v = vec![("K_open", seal_open(&psk, &h(1, 0, CTRL_ACK_REQUEST), &NC))];
    v.push(req(2, 0, Frame::CloseSession));
    v.push(req(3, CTRL_ACK_REQUEST, Frame::SetBaseFrame(pose)));
    v.push(req(4, 0, Frame::SetObservationFrame(Pose::default())));
    v.push(req(
        5,
        0,
        Frame::SetFactors {
            force: fx(1.0),
            speed: fx(0.5),
        },
    ));
    v.push(req(6, 0, Frame::SetTimeStep(fx(1.0 / 1024.0))));
    v.push(req(7, 0, Frame::SetCommandType(CommandType::Impedance)));
    v.push(req(8, 0, Frame::SetIndexingMode(IndexingMode::Trans)));
    v.push(req(
        9,
        0,
        Frame::AttachVirtualObject(VirtualObjectParams {
            mass: fx(0.5),
            inertia: v3(1.0 / 1024.0, 1.0 / 1024.0, 1.0 / 512.0),
        }),
    ));
    v.push(req(10, 0, Frame::DetachVirtualObject));
    v.push(req(11, 0, Frame::PowerRequest(true)));
    v.push(req(12, 0, Frame::VprStream { pose, twist }));
    let reply = |seq: u32, f: Frame| {
        let mut b = [0u8; MAX_FRAME_LEN];
        let n = encode(&h(seq, 7, 0), &f, &mut b);
        ("K_s2c", seal_reply_from_v1(&keys.s2c, &b[..n]).unwrap())
    };
    v.push(reply(
        500,
        Frame::Answer(Answer {
            handle_pose: pose,
            coupling_wrench: wrench,
            status: status::POWER_ON | status::MOTORS_ENABLED | status::DEAD_MAN | status::COUPLED,
            alarms: alarm::TORQUE_SATURATED,
            cycle: 123_456,
            vpr_seq: 12,
        }),
    ));
    v.push(reply(
        501,
        Frame::AnswerTwist(AnswerTwist {
            handle_twist: twist,
            status: status::POWER_ON,
            alarms: 0,
            cycle: 123_456,
            vpr_seq: 12,
        }),
    ));
    v.push((
        "K_s2c",
        seal_session_ack(&keys, &h(502, 7, 0), &NC, &NS, 1000),
    ));
    v.push(reply(
        503,
        Frame::Ack {
            acked_type: FrameType::SetBaseFrame,
            acked_seq: 3,
        },
    ));
    v.push(reply(
        504,
        Frame::Error {
            reason: DecodeError::NotFinite.reason_index() as u32,
            rejected_seq: 13,
        },
    ));
    v.push(("K_refuse", seal_refusal(&psk, &NC, &h(505, 0, 0), 1)));
    v
}

fn dump(s: &mut String, b: &[u8]) {
    writeln!(s, "```text").unwrap();
    for (i, chunk) in b.chunks(16).enumerate() {
        let hx: Vec<String> = chunk.iter().map(|b| format!("{b:02x}")).collect();
        let (a, b) = hx.split_at(hx.len().min(8));
        let line = format!("{:04x}  {:<23}  {}", i * 16, a.join(" "), b.join(" "));
        writeln!(s, "{}", line.trim_end()).unwrap();
    }
    writeln!(s, "```\n").unwrap();
}

fn generated() -> String {
    let psk = Psk::test_key();
    let keys = SessionKeys::derive(&psk, &NC, &NS);
    let mut s = String::new();
    writeln!(s, "| name | value (hex) |\n|---|---|").unwrap();
    for (n, v) in [
        ("PSK (test key)", hex(psk.as_bytes())),
        ("Nc", hex(&NC)),
        ("Ns", hex(&NS)),
        ("K_open", hex(&open_key(&psk))),
        ("K_c2s", hex(&keys.c2s)),
        ("K_s2c", hex(&keys.s2c)),
        ("K_refuse", hex(&refuse_key(&psk, &NC))),
    ] {
        writeln!(s, "| {n} | `{v}` |").unwrap();
    }
    writeln!(s).unwrap();
    for (i, (key, w)) in vectors().iter().enumerate() {
        let ty = FrameType::from_u8(w.buf[3]).unwrap();
        let what = if i + 1 == vectors().len() {
            "`error` 0x101 refusing the handshake".to_string()
        } else {
            format!("`{}` (0x{:02X})", ty.name(), ty as u8)
        };
        writeln!(
            s,
            "#### {what}, {} bytes, tag {} bytes under {key}\n",
            w.len,
            tag_len(ty)
        )
        .unwrap();
        dump(&mut s, w.bytes());
    }
    s
}

fn doc_path() -> String {
    concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../Documentation/protocol.md"
    )
    .to_string()
}

#[test]
fn documentation_vectors_are_current() {
    let path = doc_path();
    let doc = std::fs::read_to_string(&path).expect("Documentation/protocol.md");
    let start = doc.find(BEGIN).expect("begin marker") + BEGIN.len();
    let end = doc.find(END).expect("end marker");
    let g = generated();
    if std::env::var_os("HAP_WRITE_DOC").is_some() {
        std::fs::write(&path, format!("{}{}{}", &doc[..start], g, &doc[end..])).unwrap();
        return;
    }
    assert_eq!(&doc[start..end], g, "regenerate with HAP_WRITE_DOC=1");
}

/// The vectors are accepted by the library's own two sides.
#[test]
fn vectors_verify_on_both_sides() {
    let v = vectors();
    let mut gate = Gate::new(Psk::test_key());
    let open = gate.inspect(v[0].1.bytes()).unwrap();
    assert!(matches!(gate.commit(&open, NS), Action::Forward(_)));
    // The kernel's session_ack (kernel nonce 1) makes the gate's session 7.
    let mut b = [0u8; MAX_FRAME_LEN];
    let n = encode(
        &h(502, 7, 0),
        &Frame::SessionAck {
            client_nonce: 1,
            period_us: 1000,
        },
        &mut b,
    );
    assert_eq!(gate.seal_from_kernel(&b[..n]).unwrap(), v[14].1);
    for (_, w) in &v[1..12] {
        assert!(gate.inspect(w.bytes()).is_ok(), "{w:?}");
    }
    let mut c = ClientAuth::new(Psk::test_key());
    c.hello(&h(1, 0, 0), NC);
    let refusal = &v[17].1;
    assert!(matches!(
        c.open(refusal.bytes()),
        Ok((_, Reply::HandshakeRefused { reason: 0x101 }))
    ));
    assert!(c.open(v[14].1.bytes()).is_ok());
    for i in [12, 13, 15, 16] {
        let w = &v[i].1;
        assert!(c.open(w.bytes()).is_ok(), "{w:?}");
    }
}

/// RFC 2104 over plain SHA-256.
fn rfc2104(key: &[u8], msg: &[u8]) -> [u8; 32] {
    let mut k = [0u8; 64];
    if key.len() > 64 {
        k[..32].copy_from_slice(&Sha256::digest(key));
    } else {
        k[..key.len()].copy_from_slice(key);
    }
    let ipad: Vec<u8> = k.iter().map(|b| b ^ 0x36).collect();
    let opad: Vec<u8> = k.iter().map(|b| b ^ 0x5c).collect();
    let inner = Sha256::new()
        .chain_update(&ipad)
        .chain_update(msg)
        .finalize();
    Sha256::new()
        .chain_update(&opad)
        .chain_update(inner)
        .finalize()
        .into()
}

fn unhex(s: &str) -> Vec<u8> {
    (0..s.len() / 2)
        .map(|i| u8::from_str_radix(&s[2 * i..2 * i + 2], 16).unwrap())
        .collect()
}

#[test]
fn an_independent_hmac_reproduces_the_document() {
    let doc = std::fs::read_to_string(doc_path()).unwrap();
    let sec = &doc[doc.find(BEGIN).unwrap()..doc.find(END).unwrap()];
    let val = |name: &str| -> Vec<u8> {
        let l = sec
            .lines()
            .find(|l| l.starts_with(&format!("| {name} |")))
            .unwrap();
        unhex(l.split('`').nth(1).unwrap())
    };
    let (psk, nc, ns) = (val("PSK (test key)"), val("Nc"), val("Ns"));
    let cat = |parts: &[&[u8]]| parts.concat();
    let k_open = rfc2104(&psk, b"hapticctrl v2 open");
    let k_c2s = rfc2104(&psk, &cat(&[b"hapticctrl v2 c2s", &nc, &ns]));
    let k_s2c = rfc2104(&psk, &cat(&[b"hapticctrl v2 s2c", &nc, &ns]));
    let k_refuse = rfc2104(&psk, &cat(&[b"hapticctrl v2 refuse", &nc]));
    assert_eq!(val("K_open"), k_open);
    assert_eq!(val("K_c2s"), k_c2s);
    assert_eq!(val("K_s2c"), k_s2c);
    assert_eq!(val("K_refuse"), k_refuse);
    let mut frames = 0;
    let mut lines = sec.lines();
    while let Some(l) = lines.next() {
        let Some(rest) = l.strip_prefix("#### ") else {
            continue;
        };
        let key = match rest.rsplit("under ").next().unwrap() {
            "K_open" => k_open,
            "K_c2s" => k_c2s,
            "K_s2c" => k_s2c,
            "K_refuse" => k_refuse,
            k => panic!("unknown key {k}"),
        };
        let tlen: usize = rest
            .split("tag ")
            .nth(1)
            .unwrap()
            .split(' ')
            .next()
            .unwrap()
            .parse()
            .unwrap();
        let mut bytes = Vec::new();
        for l in lines.by_ref() {
            if l == "```" && !bytes.is_empty() {
                break;
            }
            if l.starts_with("```") {
                continue;
            }
            for hx in l.split_whitespace().skip(1) {
                bytes.push(u8::from_str_radix(hx, 16).unwrap());
            }
        }
        assert!(bytes.len() <= 90);
        assert_eq!(&bytes[0..3], &[0x48, 0x43, 0x02]);
        let (body, tag) = bytes.split_at(bytes.len() - tlen);
        assert_eq!(tag, &rfc2104(&key, body)[..tlen], "{rest}");
        frames += 1;
    }
    assert_eq!(frames, 18);
}
