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

/// The sample values of protocol.md §5.
fn samples() -> (Pose, Twist, Wrench) {
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
    (pose, twist, wrench)
}

/// A kernel frame (v1) as the bridge reads it.
fn kernel(seq: u32, session: u16, f: &Frame) -> Vec<u8> {
    let mut b = [0u8; MAX_FRAME_LEN];
    let n = encode(&h(seq, session, 0), f, &mut b);
    b[..n].to_vec()
}

/// The `set_time_step` of seq 13 with a NaN: verified, does not decode.
fn nan_time_step(keys: &SessionKeys) -> Wire {
    seal_raw(
        &keys.c2s,
        FrameType::SetTimeStep,
        &h(13, 7, 0),
        &[0x7f, 0xc0, 0x00, 0x00],
    )
}

/// The vectors' bridge after the main line of the session (the handshake,
/// the requests 3 … 13, the kernel's frames 500 … 503), and the frames it
/// made or sealed on the way, in order.
fn main_line(c: &mut ClientAuth) -> (Gate, Vec<(String, &'static str, Wire)>) {
    main_line_to(c, 13)
}

/// [`main_line`] up to the client's request `last` (12 or 13).
fn main_line_to(c: &mut ClientAuth, last: u32) -> (Gate, Vec<(String, &'static str, Wire)>) {
    let psk = Psk::test_key();
    let (pose, twist, wrench) = samples();
    let mut gate = Gate::new(psk.clone(), &secret());
    let mut v: Vec<(String, &'static str, Wire)> = Vec::new();
    let title = |ty: FrameType| format!("`{}` (0x{:02X})", ty.name(), ty as u8);
    let client = |gate: &mut Gate, w: &Wire| -> Action {
        let i = gate.inspect(w.bytes(), client_addr(), NOW).unwrap();
        gate.commit(&i, NOW)
    };
    // The handshake.
    let open = c.hello(&h(1, 0, 0), NC);
    v.push((
        "`open_session` (0x01), client, handshake round 1".into(),
        "K_open",
        open,
    ));
    let Action::Challenge(cookie) = client(&mut gate, &open) else {
        panic!("no cookie")
    };
    v.push((
        "`cookie` (0x90), bridge, answers round 1".into(),
        "K_cookie",
        cookie,
    ));
    assert_eq!(c.open(cookie.bytes()).unwrap().1, Reply::Cookie);
    let proof = c.prove(&h(2, 0, 0)).unwrap();
    v.push((
        "`open_proof` (0x10), client, handshake round 2".into(),
        "K_proof",
        proof,
    ));
    assert!(matches!(client(&mut gate, &proof), Action::Forward(_)));
    let sa = gate
        .seal_from_kernel(&kernel(
            500,
            7,
            &Frame::SessionAck {
                client_nonce: 1,
                period_us: 1000,
            },
        ))
        .unwrap();
    v.push((
        "`session_ack` (0x83), kernel via the bridge, ends the handshake (the bridge re-sends \
         these bytes for a copy of the `open_proof`)"
            .into(),
        "K_s2c",
        sa,
    ));
    assert_eq!(
        c.open(sa.bytes()).unwrap().1,
        Reply::SessionAck { period_us: 1000 }
    );
    // The requests, each through the bridge.
    let req = |gate: &mut Gate, c: &mut ClientAuth, seq: u32, control: u16, f: Frame| {
        let ty = f.frame_type();
        let w = c.seal(&h(seq, 7, control), &f).unwrap();
        assert!(matches!(client(gate, &w), Action::Forward(_)));
        (format!("{}, client", title(ty)), "K_c2s", w)
    };
    v.push(req(
        &mut gate,
        c,
        3,
        CTRL_ACK_REQUEST,
        Frame::SetBaseFrame(pose),
    ));
    let ack = gate
        .seal_from_kernel(&kernel(
            501,
            7,
            &Frame::Ack {
                acked_type: FrameType::SetBaseFrame,
                acked_seq: 3,
            },
        ))
        .unwrap();
    v.push((
        "`ack` (0x84), kernel via the bridge, of `set_base_frame` seq 3 (the bridge re-sends \
         these bytes for a retransmission of it)"
            .into(),
        "K_s2c",
        ack,
    ));
    for (seq, f) in [
        (4, Frame::SetObservationFrame(Pose::default())),
        (
            5,
            Frame::SetFactors {
                force: fx(1.0),
                speed: fx(0.5),
            },
        ),
        (6, Frame::SetTimeStep(fx(1.0 / 1024.0))),
        (7, Frame::SetCommandType(CommandType::Impedance)),
        (8, Frame::SetIndexingMode(IndexingMode::Trans)),
        (
            9,
            Frame::AttachVirtualObject(VirtualObjectParams {
                mass: fx(0.5),
                inertia: v3(1.0 / 1024.0, 1.0 / 1024.0, 1.0 / 512.0),
            }),
        ),
        (10, Frame::DetachVirtualObject),
        (11, Frame::PowerRequest(true)),
        (12, Frame::VprStream { pose, twist }),
    ] {
        v.push(req(&mut gate, c, seq, 0, f));
    }
    v.push((
        "`answer` (0x81), kernel via the bridge, using the VPr of seq 12".into(),
        "K_s2c",
        gate.seal_from_kernel(&kernel(
            502,
            7,
            &Frame::Answer(Answer {
                handle_pose: pose,
                coupling_wrench: wrench,
                status: status::POWER_ON
                    | status::MOTORS_ENABLED
                    | status::DEAD_MAN
                    | status::COUPLED,
                alarms: alarm::TORQUE_SATURATED,
                cycle: 123_456,
                vpr_seq: 12,
            }),
        ))
        .unwrap(),
    ));
    v.push((
        "`answer_twist` (0x82), kernel via the bridge".into(),
        "K_s2c",
        gate.seal_from_kernel(&kernel(
            503,
            7,
            &Frame::AnswerTwist(AnswerTwist {
                handle_twist: twist,
                status: status::POWER_ON,
                alarms: 0,
                cycle: 123_456,
                vpr_seq: 12,
                link_energy: 7 << 19,
            }),
        ))
        .unwrap(),
    ));
    if last < 13 {
        return (gate, v);
    }
    // A verified request that does not decode: the bridge answers it.
    let keys = c.keys().unwrap().clone();
    let nan = nan_time_step(&keys);
    v.push((
        "`set_time_step` (0x06), client, seq 13, a NaN (verified; does not decode)".into(),
        "K_c2s",
        nan,
    ));
    let Action::Reply(err, Refusal::Malformed) = client(&mut gate, &nan) else {
        panic!("no error")
    };
    v.push((
        "`error` (0x85), bridge, reason 8 `not_finite`, of seq 13".into(),
        "K_s2c",
        err,
    ));
    (gate, v)
}

/// (title, name of the key, frame) for every frame of a session, in the
/// order they are exchanged: the main line, then each way it can end (each
/// continuing from the main line, the kernel's next number 504), then the
/// handshake the bridge cannot take. Every bridge frame is the gate's own.
fn vectors() -> Vec<(String, &'static str, Wire)> {
    let psk = Psk::test_key();
    let mut c = ClientAuth::new(psk.clone());
    let (_, mut v) = main_line(&mut c);
    let keys = c.keys().unwrap().clone();
    // The other refusals a verified request can draw, each instead of
    // request 13: a reserved control bit, a value out of range, an unknown
    // enum value, a bool other than 0 or 1.
    for (what, ty, control, payload) in [
        (
            "a reserved control bit (bit 5)",
            FrameType::SetTimeStep,
            1u16 << 5,
            [0x3a, 0x80, 0x00, 0x00],
        ),
        (
            "2 s (out of range)",
            FrameType::SetTimeStep,
            0,
            [0x40, 0x00, 0x00, 0x00],
        ),
        (
            "command type 7 (unknown)",
            FrameType::SetCommandType,
            0,
            [0, 0, 0, 7],
        ),
        ("the bool 2", FrameType::PowerRequest, 0, [0, 0, 0, 2]),
    ] {
        let (mut gate, _) = main_line_to(&mut ClientAuth::new(psk.clone()), 12);
        let w = seal_raw(&keys.c2s, ty, &h(13, 7, control), &payload);
        let i = gate.inspect(w.bytes(), client_addr(), NOW).unwrap();
        let Action::Reply(err, Refusal::Malformed) = gate.commit(&i, NOW) else {
            panic!("{what}: no error")
        };
        let reason = u32::from_be_bytes([
            err.buf[HEADER_LEN],
            err.buf[HEADER_LEN + 1],
            err.buf[HEADER_LEN + 2],
            err.buf[HEADER_LEN + 3],
        ]);
        let name = DecodeError::from_index(reason as usize).unwrap().name();
        v.push((
            format!(
                "`{}` (0x{:02X}), client, seq 13 instead, {what} (verified; does not decode)",
                ty.name(),
                ty as u8
            ),
            "K_c2s",
            w,
        ));
        v.push((
            format!("`error` (0x85), bridge, reason {reason} `{name}`, of seq 13"),
            "K_s2c",
            err,
        ));
    }
    // A. The client closes.
    {
        let (mut gate, _) = main_line(&mut ClientAuth::new(psk.clone()));
        let w = seal_request(&keys, &h(14, 7, CTRL_ACK_REQUEST), &Frame::CloseSession).unwrap();
        let i = gate.inspect(w.bytes(), client_addr(), NOW).unwrap();
        assert!(matches!(gate.commit(&i, NOW), Action::Forward(_)));
        v.push((
            "`close_session` (0x02), client, seq 14 (end A: the client closes)".into(),
            "K_c2s",
            w,
        ));
        v.push((
            "`ack` (0x84), kernel via the bridge, of `close_session` seq 14: session 0".into(),
            "K_s2c",
            gate.seal_from_kernel(&kernel(
                504,
                0,
                &Frame::Ack {
                    acked_type: FrameType::CloseSession,
                    acked_seq: 14,
                },
            ))
            .unwrap(),
        ));
    }
    // B. The kernel has no session any more (a fail-safe closed it).
    {
        let (mut gate, _) = main_line(&mut ClientAuth::new(psk.clone()));
        let w = seal_request(
            &keys,
            &h(14, 7, CTRL_ACK_REQUEST),
            &Frame::PowerRequest(true),
        )
        .unwrap();
        let i = gate.inspect(w.bytes(), client_addr(), NOW).unwrap();
        assert!(matches!(gate.commit(&i, NOW), Action::Forward(_)));
        v.push((
            "`power_request` (0x0B), client, seq 14 (end B: the kernel closed the session)".into(),
            "K_c2s",
            w,
        ));
        v.push((
            "`error` (0x85), kernel via the bridge, reason 0x100 `no session`, of seq 14: session 0"
                .into(),
            "K_s2c",
            gate.seal_from_kernel(&kernel(
                504,
                0,
                &Frame::Error {
                    reason: ERROR_NO_SESSION,
                    rejected_seq: 14,
                },
            ))
            .unwrap(),
        ));
    }
    // C, D. The bridge ends it: silence, another key holder's handshake.
    for (why, title) in [
        (
            EndReason::Expired,
            "`error` (0x85), bridge, reason 0x103 `expired` (end C: the client was silent), \
             newest seq 13",
        ),
        (
            EndReason::Replaced,
            "`error` (0x85), bridge, reason 0x102 `replaced` (end D: another key holder's \
             handshake), newest seq 13",
        ),
    ] {
        let (mut gate, _) = main_line(&mut ClientAuth::new(psk.clone()));
        v.push((title.into(), "K_s2c", gate.end_session(why).unwrap().notice));
    }
    // E. A request whose number would take the span to 2^31.
    {
        let (mut gate, _) = main_line(&mut ClientAuth::new(psk.clone()));
        let (pose, twist, _) = samples();
        let far = 2u32.wrapping_add(1 << 31);
        let w = seal_request(&keys, &h(far, 7, 0), &Frame::VprStream { pose, twist }).unwrap();
        assert_eq!(
            gate.inspect(w.bytes(), client_addr(), NOW).map(|i| i.kind),
            Err(Refusal::SeqExhausted)
        );
        v.push((
            "`vpr_stream` (0x0C), client, seq 0x80000002: 2^31 past the `open_proof` (end E)"
                .into(),
            "K_c2s",
            w,
        ));
        v.push((
            "`error` (0x85), bridge, reason 0x104 `seq_exhausted`, newest seq 13".into(),
            "K_s2c",
            gate.end_session(EndReason::SeqExhausted).unwrap().notice,
        ));
    }
    // F. A proven handshake the bridge cannot remember (instead of the
    // session_ack).
    v.push((
        "`error` (0x85), bridge, reason 0x101 `refused`, of the `open_proof` seq 2 (instead of \
         the `session_ack`)"
            .into(),
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
/// order of a session; each follows from the rules: the client numbers on
/// from 1, the kernel from 500; a notice names the newest number the
/// bridge accepted (13); every request shown is the one its reply names.
#[test]
fn vectors_verify_on_both_sides() {
    let v = vectors();
    let find = |t: &str| {
        v.iter()
            .find(|(title, _, _)| title.contains(t))
            .unwrap_or_else(|| panic!("no vector {t}"))
            .2
    };
    // The client's side: a fresh client makes the same bytes.
    let mut c = ClientAuth::new(Psk::test_key());
    assert_eq!(c.hello(&h(1, 0, 0), NC), find("`open_session`"));
    assert_eq!(c.open(find("`cookie`").bytes()).unwrap().1, Reply::Cookie);
    assert_eq!(c.prove(&h(2, 0, 0)), Some(find("`open_proof`")));
    // The refusal is bound to this handshake's nonce.
    assert_eq!(
        c.open(find("0x101").bytes()).unwrap().1,
        Reply::HandshakeRefused {
            reason: ERROR_REFUSED
        }
    );
    assert_eq!(
        c.open(find("`session_ack`").bytes()).unwrap().1,
        Reply::SessionAck { period_us: 1000 }
    );
    // The numbers follow from the rules: the client's +1 a frame from 1
    // (each end continuing at 14; end E's 2^31 past the open_proof), the
    // kernel's +1 a frame from 500 (each end continuing at 504), the
    // bridge's own frames 0.
    let seq = |w: &Wire| u32::from_be_bytes([w.buf[8], w.buf[9], w.buf[10], w.buf[11]]);
    let who = |t: &str| {
        if t.contains("kernel via the bridge") {
            "kernel"
        } else if t.contains(", bridge,") {
            "bridge"
        } else {
            "client"
        }
    };
    let numbers = |w: &str| -> Vec<u32> {
        v.iter()
            .filter(|(t, _, _)| who(t) == w)
            .map(|(_, _, x)| seq(x))
            .collect()
    };
    let mut client: Vec<u32> = (1..=13).collect();
    client.extend([13, 13, 13, 13, 14, 14, 0x8000_0002]);
    assert_eq!(numbers("client"), client);
    assert_eq!(numbers("kernel"), [500, 501, 502, 503, 504, 504]);
    assert!(numbers("bridge").iter().all(|q| *q == 0));
    // Every error: its reason and the number it names (the request it
    // answers, shown before it; or, for the bridge's notices, the newest
    // number it accepted, 13).
    let errors: Vec<(u32, u32)> = v
        .iter()
        .filter(|(_, _, w)| w.buf[3] == FrameType::Error as u8)
        .map(|(_, _, w)| {
            let b = &w.buf[HEADER_LEN..];
            (
                u32::from_be_bytes([b[0], b[1], b[2], b[3]]),
                u32::from_be_bytes([b[4], b[5], b[6], b[7]]),
            )
        })
        .collect();
    assert_eq!(
        errors,
        [
            (8, 13),
            (7, 13),
            (9, 13),
            (10, 13),
            (11, 13),
            (0x100, 14),
            (0x103, 13),
            (0x102, 13),
            (0x104, 13),
            (0x101, 2)
        ]
    );
    // Every kernel and bridge frame of the session verifies on the client
    // (each on a copy: the ends forget the keys, and only they).
    for (title, key, w) in &v {
        // (The handshake's frames were verified above, in order.)
        if who(title) == "client"
            || *key == "K_refuse"
            || title.contains("`cookie`")
            || title.contains("`session_ack`")
        {
            continue;
        }
        let mut copy = c.clone();
        let (_, r) = copy
            .open(w.bytes())
            .unwrap_or_else(|e| panic!("{title}: {e:?}"));
        let ends = matches!(
            r,
            Reply::Frame(Frame::Error {
                reason: 0x100 | 0x102..=0x104,
                ..
            })
        );
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
    assert_eq!(frames, vectors().len());
}
