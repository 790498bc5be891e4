//! Protocol v2 test vectors in Documentation/protocol.md §7.11: generated
//! here under the published test key, and the test fails if the document
//! differs by one byte. Regenerate with:
//!
//!   HAP_WRITE_DOC=1 cargo test -p hap-auth --test protocol_v2_doc
//!
//! A second test reads the vectors back from the document and checks every
//! tag with an HMAC-SHA-256 written here from RFC 2104 on top of the plain
//! SHA-256 (not the `hmac` crate the library uses), the keys and the
//! cookie derived as §7.2 says: what an independent implementation would do.

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

/// The bridge's cookie secret of the vectors (a real bridge draws one at
/// start): bytes 0xc0 … 0xdf.
fn secret() -> [u8; 32] {
    core::array::from_fn(|i| 0xc0 + i as u8)
}

/// The client's address of the vectors, and the bridge's clock (100 s
/// after its start: epoch 20).
fn client_addr() -> std::net::SocketAddr {
    std::net::SocketAddr::from(([192, 0, 2, 1], 40000))
}

const NOW: std::time::Duration = std::time::Duration::from_secs(100);

/// A bridge-made header: seq 0, timestamp 0.
fn bridge_h(session: u16) -> FrameHeader {
    FrameHeader {
        control: 0,
        session,
        seq: 0,
        timestamp_us: 0,
    }
}

/// (title, name of the key, frame) for every frame of a session, in the
/// order they are exchanged, as protocol.md §5's samples.
fn vectors() -> Vec<(String, &'static str, Wire)> {
    let psk = Psk::test_key();
    let epoch = epoch_of(NOW);
    let ns = cookie_nonce(&secret(), epoch, &client_addr(), &NC);
    let keys = SessionKeys::derive(&psk, &NC, &ns);
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
    let title = |ty: FrameType| format!("`{}` (0x{:02X})", ty.name(), ty as u8);
    let mut v = vec![
        (
            "`open_session` (0x01), client, handshake round 1".to_string(),
            "K_open",
            seal_open(&psk, &h(1, 0, 0), &NC),
        ),
        (
            "`cookie` (0x90), bridge, answers round 1".to_string(),
            "K_cookie",
            seal_cookie(&psk, &bridge_h(0), &NC, &ns, epoch),
        ),
        (
            "`open_proof` (0x10), client, handshake round 2".to_string(),
            "K_proof",
            seal_open_proof(&psk, &h(2, 0, 0), &NC, &ns, epoch),
        ),
    ];
    let sa = seal_session_ack(&keys, &h(502, 7, 0), &NC, &ns, 1000);
    v.push((
        "`session_ack` (0x83), kernel via the bridge, ends the handshake".to_string(),
        "K_s2c",
        sa,
    ));
    let mut req = |seq: u32, control: u16, f: Frame| {
        let ty = f.frame_type();
        let w = seal_request(&keys, &h(seq, 7, control), &f).unwrap();
        v.push((format!("{}, client", title(ty)), "K_c2s", w));
    };
    req(3, CTRL_ACK_REQUEST, Frame::SetBaseFrame(pose));
    req(4, 0, Frame::SetObservationFrame(Pose::default()));
    req(
        5,
        0,
        Frame::SetFactors {
            force: fx(1.0),
            speed: fx(0.5),
        },
    );
    req(6, 0, Frame::SetTimeStep(fx(1.0 / 1024.0)));
    req(7, 0, Frame::SetCommandType(CommandType::Impedance));
    req(8, 0, Frame::SetIndexingMode(IndexingMode::Trans));
    req(
        9,
        0,
        Frame::AttachVirtualObject(VirtualObjectParams {
            mass: fx(0.5),
            inertia: v3(1.0 / 1024.0, 1.0 / 1024.0, 1.0 / 512.0),
        }),
    );
    req(10, 0, Frame::DetachVirtualObject);
    req(11, 0, Frame::PowerRequest(true));
    req(12, 0, Frame::VprStream { pose, twist });
    req(13, CTRL_ACK_REQUEST, Frame::CloseSession);
    let reply = |seq: u32, session: u16, f: Frame, who: &str| {
        let ty = f.frame_type();
        let mut b = [0u8; MAX_FRAME_LEN];
        let n = encode(&h(seq, session, 0), &f, &mut b);
        (
            format!("{}, {who}", title(ty)),
            "K_s2c",
            seal_reply_from_v1(&keys.s2c, &b[..n]).unwrap(),
        )
    };
    v.push(reply(
        500,
        7,
        Frame::Answer(Answer {
            handle_pose: pose,
            coupling_wrench: wrench,
            status: status::POWER_ON | status::MOTORS_ENABLED | status::DEAD_MAN | status::COUPLED,
            alarms: alarm::TORQUE_SATURATED,
            cycle: 123_456,
            vpr_seq: 12,
        }),
        "kernel via the bridge",
    ));
    v.push(reply(
        501,
        7,
        Frame::AnswerTwist(AnswerTwist {
            handle_twist: twist,
            status: status::POWER_ON,
            alarms: 0,
            cycle: 123_456,
            vpr_seq: 12,
            link_energy: 7 << 19,
        }),
        "kernel via the bridge",
    ));
    v.push(reply(
        503,
        7,
        Frame::Ack {
            acked_type: FrameType::SetBaseFrame,
            acked_seq: 3,
        },
        "kernel via the bridge (the bridge re-sends these bytes for a retransmitted request)",
    ));
    v.push(reply(
        504,
        0,
        Frame::Ack {
            acked_type: FrameType::CloseSession,
            acked_seq: 13,
        },
        "kernel via the bridge, acknowledging `close_session`: session 0",
    ));
    v.push(reply(
        505,
        0,
        Frame::Error {
            reason: ERROR_NO_SESSION,
            rejected_seq: 14,
        },
        "kernel via the bridge, reason 0x100 `no session`: session 0",
    ));
    let mut p = [0u8; 8];
    p[..4].copy_from_slice(&(DecodeError::NotFinite.reason_index() as u32).to_be_bytes());
    p[4..].copy_from_slice(&14u32.to_be_bytes());
    v.push((
        "`error` (0x85), bridge, reason 8 `not_finite` (a verified request that does not decode)"
            .to_string(),
        "K_s2c",
        seal_raw(&keys.s2c, FrameType::Error, &bridge_h(7), &p),
    ));
    // The session-end notice as the gate makes it: after the handshake
    // (newest accepted seq 2, the open_proof's), the session expires.
    let mut gate = Gate::new(psk.clone(), &secret());
    let hello = gate.inspect(v[0].2.bytes(), client_addr(), NOW).unwrap();
    assert_eq!(gate.commit(&hello, NOW), Action::Challenge(v[1].2));
    let proof = gate.inspect(v[2].2.bytes(), client_addr(), NOW).unwrap();
    assert!(matches!(gate.commit(&proof, NOW), Action::Forward(_)));
    let mut b = [0u8; MAX_FRAME_LEN];
    let n = encode(
        &h(502, 7, 0),
        &Frame::SessionAck {
            client_nonce: 1,
            period_us: 1000,
        },
        &mut b,
    );
    assert_eq!(gate.seal_from_kernel(&b[..n]), Some(sa));
    let ended = gate.end_session(EndReason::Expired).unwrap();
    v.push((
        "`error` (0x85), bridge, reason 0x103 `expired`".to_string(),
        "K_s2c",
        ended.notice,
    ));
    v.push((
        "`error` (0x85), bridge, reason 0x101 `refused` (a proven handshake the bridge cannot take)"
            .to_string(),
        "K_refuse",
        seal_refusal(&psk, &NC, &bridge_h(0), 2),
    ));
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
    let epoch = epoch_of(NOW);
    let ns = cookie_nonce(&secret(), epoch, &client_addr(), &NC);
    let keys = SessionKeys::derive(&psk, &NC, &ns);
    let mut s = String::new();
    writeln!(s, "| name | value (hex) |\n|---|---|").unwrap();
    for (n, v) in [
        ("PSK (test key)", hex(psk.as_bytes())),
        ("S (bridge secret)", hex(&secret())),
        (
            "address (192.0.2.1:40000)",
            hex(&address_bytes(&client_addr())),
        ),
        ("epoch (100 s / 5 s)", hex(&epoch.to_be_bytes())),
        ("Nc", hex(&NC)),
        ("Ns", hex(&ns)),
        ("K_open", hex(&open_key(&psk)[..])),
        ("K_cookie", hex(&cookie_key(&psk, &NC)[..])),
        ("K_proof", hex(&proof_key(&psk)[..])),
        ("K_c2s", hex(&keys.c2s)),
        ("K_s2c", hex(&keys.s2c)),
        ("K_refuse", hex(&refuse_key(&psk, &NC)[..])),
    ] {
        writeln!(s, "| {n} | `{v}` |").unwrap();
    }
    writeln!(s).unwrap();
    for (title, key, w) in vectors() {
        let tl = match FrameType::from_u8(w.buf[3]) {
            Some(ty) => tag_len(ty),
            None => TAG_LEN,
        };
        writeln!(
            s,
            "#### {title}; {} bytes, tag {tl} bytes under {key}\n",
            w.len
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

/// The vectors are what the library's two sides make and accept, in the
/// order of a session.
#[test]
fn vectors_verify_on_both_sides() {
    let v = vectors();
    let w = |i: usize| v[i].2;
    let mut c = ClientAuth::new(Psk::test_key());
    assert_eq!(c.hello(&h(1, 0, 0), NC), w(0));
    assert_eq!(c.open(w(1).bytes()).unwrap().1, Reply::Cookie);
    assert_eq!(c.prove(&h(2, 0, 0)), Some(w(2)));
    // The refusal is bound to this handshake's nonce.
    assert_eq!(
        c.open(w(v.len() - 1).bytes()).unwrap().1,
        Reply::HandshakeRefused {
            reason: ERROR_REFUSED
        }
    );
    assert_eq!(
        c.open(w(3).bytes()).unwrap().1,
        Reply::SessionAck { period_us: 1000 }
    );
    // The client's requests are the vectors, byte for byte, and the bridge
    // accepts them (a gate at the vectors' secret, address and time).
    let mut gate = Gate::new(Psk::test_key(), &secret());
    let hello = gate.inspect(w(0).bytes(), client_addr(), NOW).unwrap();
    gate.commit(&hello, NOW);
    let proof = gate.inspect(w(2).bytes(), client_addr(), NOW).unwrap();
    gate.commit(&proof, NOW);
    let mut b = [0u8; MAX_FRAME_LEN];
    let n = encode(
        &h(502, 7, 0),
        &Frame::SessionAck {
            client_nonce: 1,
            period_us: 1000,
        },
        &mut b,
    );
    assert_eq!(gate.seal_from_kernel(&b[..n]), Some(w(3)));
    for (title, _, req) in &v[4..15] {
        let f = hap_core::protocol::decode(&{
            // The v1 form of the request, to seal it again on the client.
            let i2 = gate.inspect(req.bytes(), client_addr(), NOW).unwrap();
            match gate.commit(&i2, NOW) {
                Action::Forward(v1) => v1.bytes().to_vec(),
                a => panic!("{a:?}"),
            }
        })
        .unwrap();
        assert_eq!(c.seal(&f.0, &f.1).as_ref(), Some(req), "{title}");
    }
    // The controller's frames verify on the client (each on a copy of it:
    // the kernel's 0x100 and the bridge's notice end the session there).
    for (title, _, reply) in &v[15..v.len() - 1] {
        let mut copy = c.clone();
        assert!(copy.open(reply.bytes()).is_ok(), "{title}");
        let ends = title.contains("0x100") || title.contains("0x103");
        assert_eq!(copy.established(), !ends, "{title}");
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
    let (secret, addr, epoch) = (
        val("S (bridge secret)"),
        val("address (192.0.2.1:40000)"),
        val("epoch (100 s / 5 s)"),
    );
    assert_eq!(
        addr,
        [
            &[0u8; 10][..],
            &[0xff, 0xff, 192, 0, 2, 1],
            &40000u16.to_be_bytes()
        ]
        .concat()
    );
    assert_eq!(epoch, 20u32.to_be_bytes());
    let cat = |parts: &[&[u8]]| parts.concat();
    let ns_full = rfc2104(&secret, &cat(&[b"hapticctrl v2 ns", &epoch, &addr, &nc]));
    assert_eq!(ns, ns_full[..16]);
    let k_open = rfc2104(&psk, b"hapticctrl v2 open");
    let k_cookie = rfc2104(&psk, &cat(&[b"hapticctrl v2 cookie", &nc]));
    let k_proof = rfc2104(&psk, b"hapticctrl v2 proof");
    let k_c2s = rfc2104(&psk, &cat(&[b"hapticctrl v2 c2s", &nc, &ns]));
    let k_s2c = rfc2104(&psk, &cat(&[b"hapticctrl v2 s2c", &nc, &ns]));
    let k_refuse = rfc2104(&psk, &cat(&[b"hapticctrl v2 refuse", &nc]));
    assert_eq!(val("K_open"), k_open);
    assert_eq!(val("K_cookie"), k_cookie);
    assert_eq!(val("K_proof"), k_proof);
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
            "K_cookie" => k_cookie,
            "K_proof" => k_proof,
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
    assert_eq!(frames, 23);
}
