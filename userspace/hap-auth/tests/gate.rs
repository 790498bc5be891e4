//! The bridge's gate against hostile input, with hap-core's PROTO_IN as the
//! kernel: every refused datagram is refused for the documented reason and
//! nothing but verified frames reaches PROTO_IN.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::time::Duration;

use hap_auth::*;
use hap_core::config::CommandType;
use hap_core::fixed::{Fx, Pose, Twist};
use hap_core::proto_in::ProtoIn;
use hap_core::protocol::{
    encode, Answer, Frame, FrameHeader, FrameType, CTRL_ACK_REQUEST, CTRL_RETRANSMIT,
    ERROR_REFUSED, HEADER_LEN, MAX_FRAME_LEN,
};

/// Bridge + kernel in one: the gate in front of PROTO_IN, counting refusals
/// by reason, recording what reached the kernel.
struct Rig {
    gate: Gate,
    kernel: ProtoIn,
    forwarded: Vec<Vec<u8>>,
    refused: HashMap<Refusal, u64>,
    /// The client's address and the bridge's clock.
    src: SocketAddr,
    now: Duration,
}

const CLIENT: ([u8; 4], u16) = ([192, 0, 2, 1], 40000);

impl Rig {
    fn new(psk: Psk) -> Rig {
        Rig {
            gate: Gate::new(psk, [0x5e; 32]),
            kernel: ProtoIn::new(),
            forwarded: Vec::new(),
            refused: HashMap::new(),
            src: SocketAddr::from(CLIENT),
            now: Duration::from_secs(100),
        }
    }

    /// One client datagram through the gate and, if forwarded, PROTO_IN;
    /// returns what goes back to the client (sealed by the gate).
    fn datagram(&mut self, b: &[u8]) -> Result<Option<Wire>, Refusal> {
        self.datagram_from(self.src, b)
    }

    fn datagram_from(&mut self, src: SocketAddr, b: &[u8]) -> Result<Option<Wire>, Refusal> {
        let i = match self.gate.inspect(b, src, self.now) {
            Ok(i) => i,
            Err(r) => {
                *self.refused.entry(r).or_default() += 1;
                return Err(r);
            }
        };
        match self.gate.commit(&i, self.now) {
            Action::Challenge(w) => {
                assert!(w.len <= AMPLIFICATION_FACTOR * b.len());
                Ok(Some(w))
            }
            Action::Reply(w, r) => {
                *self.refused.entry(r).or_default() += 1;
                Ok(Some(w))
            }
            Action::Forward(v1) => self.kernel_frame(v1.bytes()),
        }
    }

    /// A v1 frame into PROTO_IN; its reply as the gate seals it.
    fn kernel_frame(&mut self, v1: &[u8]) -> Result<Option<Wire>, Refusal> {
        self.forwarded.push(v1.to_vec());
        let o = self.kernel.handle(v1, 1, 1000);
        let Some(reply) = o.reply else {
            return Ok(None);
        };
        let h = FrameHeader {
            control: 0,
            session: self.kernel.session(),
            seq: 900,
            timestamp_us: 5,
        };
        let mut out = [0u8; MAX_FRAME_LEN];
        let n = encode(&h, &reply, &mut out);
        Ok(self.gate.seal_from_kernel(&out[..n]))
    }

    fn refusals(&self) -> u64 {
        self.refused.values().sum()
    }
}

fn hdr(seq: u32, session: u16, control: u16) -> FrameHeader {
    FrameHeader {
        control,
        session,
        seq,
        timestamp_us: seq.wrapping_mul(1000),
    }
}

fn vpr(x: i64) -> Frame {
    let mut pose = Pose::default();
    pose.position.x = Fx::from_ratio(x, 100);
    Frame::VprStream {
        pose,
        twist: Twist::default(),
    }
}

fn other_key() -> Psk {
    let mut k = *Psk::test_key().as_bytes();
    k[31] ^= 0x80;
    Psk::from_bytes(k)
}

/// The first round of a handshake: `open_session` in, the `cookie` out,
/// read by the client; returns the `open_session` and the `open_proof`.
fn hello_and_proof(rig: &mut Rig, client: &mut ClientAuth, seq: u32, nc: u8) -> (Wire, Wire) {
    let open = client.hello(&hdr(seq, 0, 0), [nc; NONCE_LEN]);
    let cookie = rig.datagram(open.bytes()).unwrap().expect("cookie");
    assert_eq!(cookie.len, PROOF_FRAME_LEN);
    assert_eq!(client.open(cookie.bytes()).unwrap().1, Reply::Cookie);
    let proof = client.prove(&hdr(seq, 0, 0)).expect("open_proof");
    (open, proof)
}

/// Handshake `client` through `rig`; returns the session id.
fn handshake(rig: &mut Rig, client: &mut ClientAuth, seq: u32, nc: u8) -> u16 {
    let (_, proof) = hello_and_proof(rig, client, seq, nc);
    let ack = rig.datagram(proof.bytes()).unwrap().expect("session_ack");
    let (h, r) = client.open(ack.bytes()).unwrap();
    assert_eq!(r, Reply::SessionAck { period_us: 1000 });
    assert!(client.established());
    assert_eq!(h.session, rig.kernel.session());
    h.session
}

#[test]
fn authenticated_session_end_to_end() {
    let mut rig = Rig::new(Psk::test_key());
    let mut c = ClientAuth::new(Psk::test_key());
    let s = handshake(&mut rig, &mut c, 1, 0x11);
    assert_eq!(rig.gate.session_id(), s);
    let w = c
        .seal(
            &hdr(2, s, CTRL_ACK_REQUEST),
            &Frame::SetCommandType(CommandType::Impedance),
        )
        .unwrap();
    let ack = rig.datagram(w.bytes()).unwrap().expect("ack");
    assert_eq!(
        c.open(ack.bytes()).unwrap().1,
        Reply::Frame(Frame::Ack {
            acked_type: FrameType::SetCommandType,
            acked_seq: 2
        })
    );
    assert_eq!(rig.kernel.config().command_type, CommandType::Impedance);
    let w = c.seal(&hdr(3, s, 0), &vpr(5)).unwrap();
    assert_eq!(w.len, 84);
    assert_eq!(rig.datagram(w.bytes()), Ok(None));
    assert!(rig.kernel.vpr().valid);
    // An answer from the kernel reaches the client intact (cycle in the header).
    let a = Answer {
        handle_pose: Pose::default(),
        status: 0x3ff,
        alarms: 0x3f,
        cycle: 0xdead_beef,
        vpr_seq: 3,
        ..Answer::default()
    };
    let mut v1 = [0u8; MAX_FRAME_LEN];
    let n = encode(&hdr(901, s, 0), &Frame::Answer(a), &mut v1);
    let w = rig.gate.seal_from_kernel(&v1[..n]).unwrap();
    assert_eq!(w.len, 88);
    assert_eq!(c.open(w.bytes()).unwrap().1, Reply::Frame(Frame::Answer(a)));
    // A forged answer (one bit) is refused by the client.
    let mut bad = w;
    bad.buf[20] ^= 1;
    assert_eq!(c.open(bad.bytes()), Err(Refusal::BadTag));
    assert_eq!(rig.refusals(), 0);
}

#[test]
fn a_client_with_the_wrong_key_gets_nothing_through() {
    let mut rig = Rig::new(Psk::test_key());
    let mut wrong = ClientAuth::new(other_key());
    let open = wrong.hello(&hdr(1, 0, 0), [7; NONCE_LEN]);
    assert_eq!(rig.datagram(open.bytes()), Err(Refusal::BadTag));
    assert_eq!(rig.kernel.session(), 0);
    // Even after the real client opened, the wrong key's frames fail.
    let mut c = ClientAuth::new(Psk::test_key());
    let s = handshake(&mut rig, &mut c, 1, 0x22);
    let keys = SessionKeys::derive(&other_key(), &[0x22; NONCE_LEN], &[1; NONCE_LEN]);
    let forged = seal_request(&keys, &hdr(2, s, 0), &vpr(9)).unwrap();
    assert_eq!(rig.datagram(forged.bytes()), Err(Refusal::BadTag));
    assert_eq!(
        rig.forwarded.len(),
        1,
        "only the real open reached PROTO_IN"
    );
    assert!(!rig.kernel.vpr().valid);
    assert_eq!(rig.refused[&Refusal::BadTag], 2);
}

#[test]
fn every_flipped_bit_of_every_request_is_refused() {
    let mut rig = Rig::new(Psk::test_key());
    let mut c = ClientAuth::new(Psk::test_key());
    let s = handshake(&mut rig, &mut c, 1, 0x33);
    let mut other = ClientAuth::new(Psk::test_key());
    let (_, proof) = hello_and_proof(&mut rig, &mut other, 40, 0x45);
    let before = rig.forwarded.len();
    let mut frames = vec![
        proof,
        seal_open(&Psk::test_key(), &hdr(50, 0, 0), &[0x44; NONCE_LEN]),
        c.seal(&hdr(2, s, 0), &vpr(1)).unwrap(),
        c.seal(&hdr(3, s, CTRL_ACK_REQUEST), &Frame::PowerRequest(true))
            .unwrap(),
        c.seal(&hdr(4, s, 0), &Frame::CloseSession).unwrap(),
    ];
    frames.push(
        c.seal(
            &hdr(5, s, 0),
            &Frame::SetFactors {
                force: Fx::ONE,
                speed: Fx::ONE,
            },
        )
        .unwrap(),
    );
    let mut tried = 0u64;
    for w in &frames {
        for byte in 0..w.len {
            for bit in 0..8 {
                let mut m = *w;
                m.buf[byte] ^= 1 << bit;
                let r = rig.datagram(m.bytes());
                assert!(r.is_err(), "byte {byte} bit {bit} of {:?} passed", w);
                tried += 1;
            }
        }
    }
    assert_eq!(rig.forwarded.len(), before);
    assert_eq!(rig.refusals(), tried);
    assert!(rig.refused[&Refusal::BadTag] > 0);
    assert!(rig.refused[&Refusal::BadMagic] > 0);
    assert!(rig.refused[&Refusal::BadCookie] > 0);
    // The untouched frames still pass afterwards: the refusals changed nothing.
    assert!(rig.datagram(frames[2].bytes()).is_ok());
}

#[test]
fn truncated_or_extended_tags_are_refused() {
    let mut rig = Rig::new(Psk::test_key());
    let mut c = ClientAuth::new(Psk::test_key());
    let s = handshake(&mut rig, &mut c, 1, 0x55);
    let w = c.seal(&hdr(2, s, 0), &vpr(1)).unwrap();
    for cut in 1..=TAG_LEN {
        let r = rig.datagram(&w.bytes()[..w.len - cut]);
        assert_eq!(r, Err(Refusal::LengthMismatch), "cut {cut}");
    }
    // The tag of a shorter type does not make a shorter frame valid: a
    // v2 vpr_stream cut to a 12-byte tag is still the wrong length.
    let mut long = w.bytes().to_vec();
    long.push(0);
    assert_eq!(rig.datagram(&long), Err(Refusal::LengthMismatch));
    assert_eq!(rig.refused[&Refusal::LengthMismatch], TAG_LEN as u64 + 1);
    assert!(rig.datagram(w.bytes()).is_ok());
}

#[test]
fn replayed_and_reordered_frames() {
    let mut rig = Rig::new(Psk::test_key());
    let mut c = ClientAuth::new(Psk::test_key());
    let s = handshake(&mut rig, &mut c, 1, 0x66);
    let f: Vec<Wire> = (2..=200)
        .map(|q| c.seal(&hdr(q, s, 0), &vpr(i64::from(q))).unwrap())
        .collect();
    assert!(rig.datagram(f[10].bytes()).is_ok()); // seq 12
    assert!(rig.datagram(f[5].bytes()).is_ok()); // seq 7: reordered, inside the window
    assert_eq!(rig.datagram(f[5].bytes()), Err(Refusal::Replay));
    assert_eq!(rig.datagram(f[10].bytes()), Err(Refusal::Replay));
    assert!(rig.datagram(f[198].bytes()).is_ok()); // seq 200
    assert_eq!(rig.datagram(f[100].bytes()), Err(Refusal::TooOld)); // seq 102 < 200-63
    assert_eq!(rig.forwarded.len(), 4);
    assert_eq!(
        rig.kernel.vpr().pose.position.x,
        Fx::from_ratio(200, 100),
        "the newest VPr holds"
    );
    assert_eq!(rig.refused[&Refusal::Replay], 2);
    assert_eq!(rig.refused[&Refusal::TooOld], 1);
}

#[test]
fn a_retransmitted_request_gets_the_same_ack_without_reaching_the_kernel() {
    let mut rig = Rig::new(Psk::test_key());
    let mut c = ClientAuth::new(Psk::test_key());
    let s = handshake(&mut rig, &mut c, 1, 0x77);
    let w = c
        .seal(&hdr(2, s, CTRL_ACK_REQUEST), &Frame::PowerRequest(true))
        .unwrap();
    let ack1 = rig.datagram(w.bytes()).unwrap().unwrap();
    let n = rig.forwarded.len();
    let ack2 = rig.datagram(w.bytes()).unwrap().unwrap();
    assert_eq!(ack1, ack2);
    assert_eq!(rig.forwarded.len(), n);
    assert_eq!(rig.gate.counters.reacked, 1);
    // The client's retransmission with CTRL_RETRANSMIT set (another tag, the
    // same sequence number and type): the same ack again.
    let w2 = c
        .seal(
            &hdr(2, s, CTRL_ACK_REQUEST | CTRL_RETRANSMIT),
            &Frame::PowerRequest(true),
        )
        .unwrap();
    assert_eq!(rig.datagram(w2.bytes()), Ok(Some(ack1)));
    assert_eq!(rig.forwarded.len(), n);
    // A duplicate of a frame that asked for no ack is a replay.
    let v = c.seal(&hdr(3, s, 0), &vpr(1)).unwrap();
    assert_eq!(rig.datagram(v.bytes()), Ok(None));
    assert_eq!(rig.datagram(v.bytes()), Err(Refusal::Replay));
}

#[test]
fn old_session_frames_are_refused() {
    let mut rig = Rig::new(Psk::test_key());
    let mut c = ClientAuth::new(Psk::test_key());
    let s1 = handshake(&mut rig, &mut c, 1, 0x01);
    let old_vpr = c.seal(&hdr(2, s1, 0), &vpr(1)).unwrap();
    assert!(rig.datagram(old_vpr.bytes()).is_ok());
    // A new session (the client restarted).
    let mut c2 = ClientAuth::new(Psk::test_key());
    let s2 = handshake(&mut rig, &mut c2, 1, 0x02);
    assert_ne!(s1, s2);
    // Frames of the old session (old keys, old id): refused on the id,
    // before any tag is computed.
    let old_vpr3 = c.seal(&hdr(3, s1, 0), &vpr(3)).unwrap();
    assert_eq!(rig.datagram(old_vpr3.bytes()), Err(Refusal::WrongSession));
    // The old keys under the new session id: refused at the tag.
    let old_keys = c.seal(&hdr(3, s2, 0), &vpr(3)).unwrap();
    assert_eq!(rig.datagram(old_keys.bytes()), Err(Refusal::BadTag));
    // The new key with the old session id: refused.
    let wrong_id = c2.seal(&hdr(2, s1, 0), &vpr(3)).unwrap();
    assert_eq!(rig.datagram(wrong_id.bytes()), Err(Refusal::WrongSession));
    assert_eq!(rig.refused[&Refusal::BadTag], 1);
    assert_eq!(rig.refused[&Refusal::WrongSession], 2);
}

#[test]
fn a_replayed_hello_commits_nothing_and_a_replayed_proof_is_refused_everywhere() {
    let mut rig = Rig::new(Psk::test_key());
    let mut c = ClientAuth::new(Psk::test_key());
    let (open1, proof1) = hello_and_proof(&mut rig, &mut c, 1, 0x01);
    let ack = rig.datagram(proof1.bytes()).unwrap().unwrap();
    c.open(ack.bytes()).unwrap();
    let s1 = rig.kernel.session();
    let n = rig.forwarded.len();
    // The recorded open_session, replayed: a cookie (68 bytes for 48), no
    // state, nothing forwarded, the session untouched.
    let cookie = rig.datagram(open1.bytes()).unwrap().unwrap();
    assert!(cookie.len <= 3 * open1.len);
    assert_eq!(rig.forwarded.len(), n);
    assert_eq!(rig.gate.session_id(), s1);
    // The recorded open_proof, replayed from the same address at once:
    // refused (the proof is remembered for its cookie's lifetime).
    assert_eq!(rig.datagram(proof1.bytes()), Err(Refusal::HandshakeReplay));
    // From another address, or another port: the cookie is not theirs.
    for src in [
        SocketAddr::from(([192, 0, 2, 1], 40001)),
        SocketAddr::from(([198, 51, 100, 7], 40000)),
    ] {
        assert_eq!(
            rig.datagram_from(src, proof1.bytes()),
            Err(Refusal::BadCookie)
        );
    }
    // After a thousand newer handshakes (the memory holds them all: each
    // is alive as long as its cookie).
    for k in 0..1000u32 {
        let mut ck = ClientAuth::new(Psk::test_key());
        let nc = [
            (k >> 8) as u8,
            k as u8,
            0xc0,
            0xc1,
            0,
            0,
            0,
            0,
            0,
            0,
            0,
            0,
            0,
            0,
            0,
            0,
        ];
        let open = ck.hello(&hdr(10 + k, 0, 0), nc);
        let cookie = rig.datagram(open.bytes()).unwrap().unwrap();
        ck.open(cookie.bytes()).unwrap();
        let proof = ck.prove(&hdr(10 + k, 0, 0)).unwrap();
        rig.datagram(proof.bytes()).unwrap();
    }
    assert_eq!(rig.datagram(proof1.bytes()), Err(Refusal::HandshakeReplay));
    // Once the cookie's lifetime is over: refused on the epoch, and the
    // memory of it may go.
    rig.now += Duration::from_secs(2 * COOKIE_EPOCH_S);
    assert_eq!(rig.datagram(proof1.bytes()), Err(Refusal::BadCookie));
    // A restarted bridge (a new secret) refuses it inside its lifetime too.
    let mut rig2 = Rig::new(Psk::test_key());
    rig2.gate = Gate::new(Psk::test_key(), [0x6f; 32]);
    assert_eq!(rig2.datagram(proof1.bytes()), Err(Refusal::BadCookie));
    assert!(rig2.forwarded.is_empty());
    // The handshake frames carry session 0: another id is refused unhashed.
    let bad_open = seal_open(&Psk::test_key(), &hdr(1, 5, 0), &[0x04; NONCE_LEN]);
    assert_eq!(rig.datagram(bad_open.bytes()), Err(Refusal::WrongSession));
    // A cookie forged without the bridge's secret is refused before the tag.
    let mut forged = proof1;
    forged.buf[HEADER_LEN + NONCE_LEN] ^= 1;
    assert_eq!(rig.datagram(forged.bytes()), Err(Refusal::BadCookie));
    // A recorded session_ack does not fool a client of another handshake.
    let mut c3 = ClientAuth::new(Psk::test_key());
    c3.hello(&hdr(1, 0, 0), [0x03; NONCE_LEN]);
    assert_eq!(c3.open(ack.bytes()), Err(Refusal::NoSession));
}

#[test]
fn a_proven_handshake_replaces_the_session_and_its_client_is_told() {
    let mut rig = Rig::new(Psk::test_key());
    let mut old = ClientAuth::new(Psk::test_key());
    let s1 = handshake(&mut rig, &mut old, 1, 0x10);
    // The key holder restarted on another port: a proven handshake from
    // there takes the session (no lockout until expiry).
    rig.src = SocketAddr::from(([192, 0, 2, 1], 40002));
    let mut new = ClientAuth::new(Psk::test_key());
    let (_, proof) = hello_and_proof(&mut rig, &mut new, 1, 0x11);
    let ack = rig.datagram(proof.bytes()).unwrap().unwrap();
    let (h, _) = new.open(ack.bytes()).unwrap();
    assert_ne!(h.session, s1);
    // The old session's client gets `error` 0x102 under its keys.
    let ended = rig.gate.take_replaced().unwrap();
    assert!(rig.gate.take_replaced().is_none());
    assert_eq!(
        old.open(ended.notice.bytes()).unwrap().1,
        Reply::Frame(Frame::Error {
            reason: ERROR_REPLACED,
            rejected_seq: 1
        })
    );
    assert!(!old.established(), "the client forgets an ended session");
    assert_eq!(rig.gate.counters.ended_replaced, 1);
}

#[test]
fn a_full_proof_memory_refuses_new_handshakes_and_says_so() {
    let mut rig = Rig::new(Psk::test_key());
    for k in 0..PROOF_MEMORY as u32 {
        let mut c = ClientAuth::new(Psk::test_key());
        let mut nc = [0u8; NONCE_LEN];
        nc[..4].copy_from_slice(&k.to_be_bytes());
        let open = c.hello(&hdr(1, 0, 0), nc);
        let cookie = rig.datagram(open.bytes()).unwrap().unwrap();
        c.open(cookie.bytes()).unwrap();
        let p = c.prove(&hdr(2, 0, 0)).unwrap();
        assert!(rig.datagram(p.bytes()).is_ok());
    }
    let n = rig.forwarded.len();
    let mut c = ClientAuth::new(Psk::test_key());
    let (_, proof) = hello_and_proof(&mut rig, &mut c, 1, 0xee);
    let r = rig.datagram(proof.bytes()).unwrap().unwrap();
    assert_eq!(
        c.open(r.bytes()).unwrap().1,
        Reply::HandshakeRefused {
            reason: ERROR_REFUSED
        }
    );
    assert_eq!(rig.forwarded.len(), n, "nothing committed");
    assert_eq!(rig.refused[&Refusal::HandshakeBusy], 1);
    // The memory is never cleared wholesale: once the proofs' cookies are
    // dead, a new handshake passes.
    rig.now += Duration::from_secs(2 * COOKIE_EPOCH_S);
    handshake(&mut rig, &mut c, 3, 0xef);
}

#[test]
fn expiry_closes_the_session_in_proto_in_and_tells_the_client() {
    let mut rig = Rig::new(Psk::test_key());
    let mut c = ClientAuth::new(Psk::test_key());
    let s = handshake(&mut rig, &mut c, 1, 0x20);
    let w = c.seal(&hdr(2, s, 0), &vpr(4)).unwrap();
    rig.datagram(w.bytes()).unwrap();
    assert!(rig.kernel.vpr().valid);
    let ended = rig.gate.end_session(EndReason::Expired).unwrap();
    let close = ended.kernel_close.expect("a close for the kernel");
    assert_eq!(rig.kernel_frame(close.bytes()), Ok(None), "no ack asked");
    assert_eq!(rig.kernel.session(), 0, "PROTO_IN closed the session");
    assert!(!rig.kernel.vpr().valid);
    assert_eq!(
        c.open(ended.notice.bytes()).unwrap().1,
        Reply::Frame(Frame::Error {
            reason: ERROR_EXPIRED,
            rejected_seq: 2
        })
    );
    assert!(rig.gate.end_session(EndReason::Expired).is_none());
    // The ended session's frames are refused, and nothing is sealed for it.
    let mut c2 = ClientAuth::new(Psk::test_key());
    let s2 = handshake(&mut rig, &mut c2, 1, 0x21);
    let _ = s2;
}

#[test]
fn a_session_ends_before_its_sequence_numbers_can_wrap() {
    let mut rig = Rig::new(Psk::test_key());
    rig.gate.set_frame_limit(10);
    let mut c = ClientAuth::new(Psk::test_key());
    c.set_frame_limit(10);
    let s = handshake(&mut rig, &mut c, 1, 0x30);
    // The open_proof counted one; nine more frames fit.
    for q in 2..=10 {
        assert!(!rig.gate.exhausted());
        let w = c.seal(&hdr(q, s, 0), &vpr(1)).unwrap();
        rig.datagram(w.bytes()).unwrap();
    }
    assert!(rig.gate.exhausted());
    let w = c.seal(&hdr(11, s, 0), &vpr(1));
    assert!(w.is_some(), "the client sealed 9 of its 10");
    assert_eq!(rig.datagram(w.unwrap().bytes()), Err(Refusal::NoSession));
    c.seal(&hdr(12, s, 0), &vpr(1));
    assert!(c.exhausted());
    assert!(c.seal(&hdr(13, s, 0), &vpr(1)).is_none());
    let ended = rig.gate.end_session(EndReason::SeqExhausted).unwrap();
    assert!(ended.kernel_close.is_some());
    assert_eq!(
        c.open(ended.notice.bytes()).unwrap().1,
        Reply::Frame(Frame::Error {
            reason: ERROR_SEQ_EXHAUSTED,
            rejected_seq: 10
        })
    );
}

#[test]
fn only_frames_of_the_open_session_are_sealed() {
    let mut rig = Rig::new(Psk::test_key());
    let mut c = ClientAuth::new(Psk::test_key());
    let s = handshake(&mut rig, &mut c, 1, 0x40);
    let answer = |session: u16| {
        let mut v1 = [0u8; MAX_FRAME_LEN];
        let n = encode(
            &hdr(901, session, 0),
            &Frame::Answer(Answer::default()),
            &mut v1,
        );
        v1[..n].to_vec()
    };
    assert!(rig.gate.seal_from_kernel(&answer(s)).is_some());
    assert!(rig.gate.seal_from_kernel(&answer(s + 1)).is_none());
    assert!(rig.gate.seal_from_kernel(&answer(0)).is_none());
    // The client closes: the kernel's ack of it (session 0) is sealed, and
    // after it nothing.
    let w = c
        .seal(&hdr(2, s, CTRL_ACK_REQUEST), &Frame::CloseSession)
        .unwrap();
    let ack = rig.datagram(w.bytes()).unwrap().expect("the close's ack");
    assert_eq!(
        c.open(ack.bytes()).unwrap().1,
        Reply::Frame(Frame::Ack {
            acked_type: FrameType::CloseSession,
            acked_seq: 2
        })
    );
    assert!(rig.gate.seal_from_kernel(&answer(s)).is_none());
    assert!(rig.gate.seal_from_kernel(&answer(0)).is_none());
    assert!(rig.gate.counters.replies_unsealed >= 4);
}

#[test]
fn strangers_and_v1_frames_are_refused_silently() {
    let mut rig = Rig::new(Psk::test_key());
    // v1 frames: unauthenticated.
    let mut v1 = [0u8; MAX_FRAME_LEN];
    let n = encode(
        &hdr(1, 0, 0),
        &Frame::OpenSession { client_nonce: 1 },
        &mut v1,
    );
    assert_eq!(rig.datagram(&v1[..n]), Err(Refusal::Unauthenticated));
    // No session: a request is refused before any key is tried.
    let keys = SessionKeys::derive(&Psk::test_key(), &[0; 16], &[0; 16]);
    let w = seal_request(&keys, &hdr(2, 1, 0), &vpr(1)).unwrap();
    assert_eq!(rig.datagram(w.bytes()), Err(Refusal::NoSession));
    assert_eq!(rig.datagram(&[0u8; 91]), Err(Refusal::Oversize));
    assert_eq!(rig.datagram(&[0u8; 5]), Err(Refusal::Undersize));
    assert!(rig.forwarded.is_empty());
    assert_eq!(rig.refusals(), 4);
}

#[test]
fn an_authenticated_malformed_request_is_told_why() {
    let mut rig = Rig::new(Psk::test_key());
    let mut c = ClientAuth::new(Psk::test_key());
    let s = handshake(&mut rig, &mut c, 1, 0x44);
    // A NaN in the pose, properly sealed.
    let keys = c.keys().unwrap().clone();
    let mut p = [0u8; 52];
    p[0..4].copy_from_slice(&f32::NAN.to_bits().to_be_bytes());
    p[24..28].copy_from_slice(&1f32.to_bits().to_be_bytes());
    let w = seal_raw(&keys.c2s, FrameType::VprStream, &hdr(2, s, 0), &p);
    let reply = rig.datagram(w.bytes()).unwrap().unwrap();
    assert_eq!(
        c.open(reply.bytes()).unwrap().1,
        Reply::Frame(Frame::Error {
            reason: hap_core::protocol::DecodeError::NotFinite.reason_index() as u32,
            rejected_seq: 2
        })
    );
    assert_eq!(rig.forwarded.len(), 1);
    assert_eq!(rig.refused[&Refusal::Malformed], 1);
}
