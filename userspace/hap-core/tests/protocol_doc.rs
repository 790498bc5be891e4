//! The hex dumps in Documentation/protocol.md are generated here and must
//! match the document. Regenerate them with:
//!
//!   HAP_WRITE_DOC=1 cargo test -p hap-core --test protocol_doc

use std::fmt::Write;

use hap_core::config::{CommandType, IndexingMode, VirtualObjectParams};
use hap_core::fixed::{Fx, Pose, Quat, Twist, Vec3, Wrench};
use hap_core::protocol::*;
use hap_core::vp::{alarm, status};

const BEGIN: &str = "<!-- BEGIN GENERATED DUMPS (tests/protocol_doc.rs) -->\n";
const END: &str = "<!-- END GENERATED DUMPS -->";

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

fn samples() -> Vec<(FrameHeader, Frame)> {
    let h = |seq: u32, session: u16| FrameHeader {
        control: 0,
        session,
        seq,
        timestamp_us: 1_000_000 + seq,
    };
    let pose = Pose {
        position: v3(0.1, -0.05, 0.3),
        // 90° about z: (0, 0, sin 45°, cos 45°)
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
    vec![
        (
            FrameHeader {
                control: CTRL_ACK_REQUEST,
                ..h(1, 0)
            },
            Frame::OpenSession {
                client_nonce: 0x1234_5678,
            },
        ),
        (h(2, 7), Frame::CloseSession),
        (
            FrameHeader {
                control: CTRL_ACK_REQUEST,
                ..h(3, 7)
            },
            Frame::SetBaseFrame(pose),
        ),
        (h(4, 7), Frame::SetObservationFrame(Pose::default())),
        (
            h(5, 7),
            Frame::SetFactors {
                force: fx(1.0),
                speed: fx(0.5),
            },
        ),
        (h(6, 7), Frame::SetTimeStep(fx(1.0 / 1024.0))),
        (h(7, 7), Frame::SetCommandType(CommandType::Impedance)),
        (h(8, 7), Frame::SetIndexingMode(IndexingMode::Trans)),
        (
            h(9, 7),
            Frame::AttachVirtualObject(VirtualObjectParams {
                mass: fx(0.5),
                inertia: v3(1.0 / 1024.0, 1.0 / 1024.0, 1.0 / 512.0),
            }),
        ),
        (h(10, 7), Frame::DetachVirtualObject),
        (h(11, 7), Frame::PowerRequest(true)),
        (h(12, 7), Frame::VprStream { pose, twist }),
        (
            // A client that keeps the link passive: its energy grants,
            // 2.5 J (2.5·2^20 units), in the timestamp field.
            FrameHeader {
                control: CTRL_LINK_ENERGY,
                timestamp_us: 0x0028_0000,
                ..h(14, 7)
            },
            Frame::VprStream { pose, twist },
        ),
        (
            h(500, 7),
            Frame::Answer(Answer {
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
        ),
        (
            h(501, 7),
            Frame::AnswerTwist(AnswerTwist {
                handle_twist: twist,
                status: status::POWER_ON,
                alarms: 0,
                cycle: 123_456,
                vpr_seq: 12,
                // 3.5 J put into the channel (2^-20 J units).
                link_energy: 7 << 19,
            }),
        ),
        (
            h(502, 7),
            Frame::SessionAck {
                client_nonce: 0x1234_5678,
                period_us: 1000,
            },
        ),
        (
            h(503, 7),
            Frame::Ack {
                acked_type: FrameType::SetBaseFrame,
                acked_seq: 3,
            },
        ),
        (
            h(504, 7),
            Frame::Error {
                reason: DecodeError::BadCrc.reason_index() as u32,
                rejected_seq: 13,
            },
        ),
    ]
}

fn dumps() -> String {
    let mut s = String::new();
    for (h, f) in samples() {
        let mut buf = [0u8; MAX_FRAME_LEN];
        let n = encode(&h, &f, &mut buf);
        assert_eq!(decode(&buf[..n]).map(|(h2, _)| h2), Ok(h));
        let t = f.frame_type();
        let note = if h.control & CTRL_LINK_ENERGY != 0 {
            ", control `CTRL_LINK_ENERGY`"
        } else {
            ""
        };
        writeln!(
            s,
            "#### `{}` (0x{:02X}){note}, {} bytes\n",
            t.name(),
            t as u8,
            n
        )
        .unwrap();
        writeln!(s, "```text").unwrap();
        for (i, chunk) in buf[..n].chunks(16).enumerate() {
            let hex: Vec<String> = chunk.iter().map(|b| format!("{b:02x}")).collect();
            let (a, b) = hex.split_at(hex.len().min(8));
            let line = format!("{:04x}  {:<23}  {}", i * 16, a.join(" "), b.join(" "));
            writeln!(s, "{}", line.trim_end()).unwrap();
        }
        writeln!(s, "```\n").unwrap();
    }
    s
}

#[test]
fn documentation_dumps_are_current() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../Documentation/protocol.md"
    );
    let doc = std::fs::read_to_string(path).expect("Documentation/protocol.md");
    let start = doc.find(BEGIN).expect("begin marker") + BEGIN.len();
    let end = doc.find(END).expect("end marker");
    let generated = dumps();
    if std::env::var_os("HAP_WRITE_DOC").is_some() {
        let new = format!("{}{}{}", &doc[..start], generated, &doc[end..]);
        std::fs::write(path, new).unwrap();
        return;
    }
    assert_eq!(
        &doc[start..end],
        generated,
        "regenerate with HAP_WRITE_DOC=1"
    );
}

/// The keys of protocol.md's table of the protocol counters in
/// /dev/hap_stats.
fn documented_stats_keys(doc: &str) -> Vec<String> {
    let begin = "<!-- BEGIN STATS COUNTERS -->";
    let end = "<!-- END STATS COUNTERS -->";
    let start = doc.find(begin).expect("stats counters begin marker") + begin.len();
    let stop = doc.find(end).expect("stats counters end marker");
    doc[start..stop]
        .lines()
        .filter_map(|l| l.strip_prefix("| `"))
        .filter_map(|l| l.split_once('`').map(|(k, _)| k.to_string()))
        .collect()
}

fn rendered_keys(text: &str) -> Vec<String> {
    text.lines()
        .filter(|l| !l.starts_with('#'))
        .filter_map(|l| l.split_once(": ").map(|(k, _)| k.to_string()))
        .collect()
}

#[test]
fn stats_counters_match_the_documentation() {
    use hap_core::proto_in::{ProtoCounters, ProtoPublication};
    use hap_core::stats::{render_summary, HapStats};
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../Documentation/protocol.md"
    );
    let doc = std::fs::read_to_string(path).expect("Documentation/protocol.md");
    let documented = documented_stats_keys(&doc);
    assert!(documented.len() >= 20, "{documented:?}");
    // Every line PROTO_IN's publication renders is documented, with the
    // value of its own counter.
    let p = ProtoPublication {
        counters: ProtoCounters {
            retransmits_reacked: 11,
            superseded: 12,
            ..ProtoCounters::default()
        },
        session: 3,
    };
    let mut proto = String::new();
    p.render(&mut proto).unwrap();
    let proto_keys = rendered_keys(&proto);
    for k in &proto_keys {
        assert!(
            documented.contains(k),
            "`{k}` is rendered but not in protocol.md's table"
        );
    }
    assert!(proto.contains("retransmits_reacked: 11\n"), "{proto}");
    assert!(proto.contains("superseded: 12\n"), "{proto}");
    // The documented keys PROTO_IN does not render are the summary's.
    let st = HapStats::new(1000);
    let mut buf = vec![0u8; 16384];
    let n = render_summary(&st.summary(), &mut buf).len;
    let summary = String::from_utf8(buf[..n].to_vec()).unwrap();
    let summary_keys = rendered_keys(&summary);
    let others: Vec<&String> = documented
        .iter()
        .filter(|k| !proto_keys.contains(k) && !summary_keys.contains(k))
        .collect();
    // SERVO's answer counters are rendered by the module itself (checked
    // in the guest by tests/qemu/03-phase2-coupling.sh).
    assert_eq!(
        others,
        ["answers_sent", "answers_skipped_latch_busy"],
        "documented keys rendered nowhere in hap-core"
    );
}

/// The link energy fields: where they travel and what the receiving end
/// makes of them (`Documentation/protocol.md`, "Link energy").
#[test]
fn link_energy_fields_cross_as_documented() {
    let twist = Twist::default();
    let pose = Pose::IDENTITY;
    let h = FrameHeader {
        control: CTRL_LINK_ENERGY,
        session: 7,
        seq: 14,
        timestamp_us: 0x0028_0000,
    };
    let mut buf = [0u8; MAX_FRAME_LEN];
    let n = encode(&h, &Frame::VprStream { pose, twist }, &mut buf);
    assert_eq!(n, 72);
    assert_eq!(buf[4..6], [0x00, 0x04]);
    assert_eq!(buf[12..16], [0x00, 0x28, 0x00, 0x00]);
    let (h2, f) = decode(&buf[..n]).unwrap();
    let v = vpr_from(&h2, &f, 99).unwrap();
    assert!(v.link_energy);
    assert_eq!(v.client_time_us, 0x0028_0000);
    assert_eq!(v.heard_cycle, 99);
    let mut credit = hap_core::link::PeerTotal::new();
    assert_eq!(credit.receive(v.client_time_us), Fx::from_ratio(5, 2));
    // Without the bit the field is the client's clock.
    let plain = FrameHeader { control: 0, ..h };
    let n = encode(&plain, &Frame::VprStream { pose, twist }, &mut buf);
    let (h3, f3) = decode(&buf[..n]).unwrap();
    assert!(!vpr_from(&h3, &f3, 0).unwrap().link_energy);
    // answer_twist: the controller's grants, the last payload word.
    let a = AnswerTwist {
        link_energy: 0xFFFF_FFFF,
        ..AnswerTwist::default()
    };
    let n = encode(&FrameHeader::default(), &Frame::AnswerTwist(a), &mut buf);
    assert_eq!(n, 64);
    assert_eq!(buf[56..60], [0xFF; 4]);
    match decode(&buf[..n]).unwrap().1 {
        Frame::AnswerTwist(b) => assert_eq!(b.link_energy, 0xFFFF_FFFF),
        other => panic!("{other:?}"),
    }
    // Wrap: a total of 4096.5 J reads 0.5 J on the wire; a receiver that
    // had 4095 J credits 1.5 J.
    let mut r = hap_core::link::PeerTotal::new();
    for j in [2000, 4000, 4095] {
        r.receive(hap_core::link::energy_to_wire(Fx::from_int(j)));
    }
    let w = hap_core::link::energy_to_wire(Fx::from_ratio(8193, 2));
    assert_eq!(w, 1 << 19);
    assert_eq!(r.receive(w), Fx::from_ratio(3, 2));
}
