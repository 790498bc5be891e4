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
            gate: Gate::new(psk, &[0x5e; 32]),
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
    // A new session (the client restarted, on another port).
    rig.src = SocketAddr::from(([192, 0, 2, 1], 40001));
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
    // The recorded open_session, replayed from any address, its own
    // included: nothing (its nonce was answered), nothing forwarded, the
    // session untouched.
    for src in [
        SocketAddr::from(CLIENT),
        SocketAddr::from(([192, 0, 2, 1], 40001)),
        SocketAddr::from(([198, 51, 100, 7], 40000)),
    ] {
        assert_eq!(
            rig.datagram_from(src, open1.bytes()),
            Err(Refusal::HelloReplay)
        );
    }
    assert_eq!(rig.forwarded.len(), n);
    assert_eq!(rig.gate.session_id(), s1);
    // The recorded open_proof, replayed from the same address at once: it
    // opened the live session, so its copy draws that session's
    // session_ack again (68 bytes for 68) and commits nothing.
    assert_eq!(rig.datagram(proof1.bytes()), Ok(Some(ack)));
    assert_eq!(rig.forwarded.len(), n);
    assert_eq!(rig.gate.counters.proofs_reacked, 1);
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
    // After a thousand newer handshakes from another port (the memory
    // holds them all: each is alive as long as its cookie), the proof is
    // not the live session's any more: refused from its own address.
    rig.src = SocketAddr::from(([192, 0, 2, 1], 40002));
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
    rig.src = SocketAddr::from(CLIENT);
    assert_eq!(rig.datagram(proof1.bytes()), Err(Refusal::HandshakeReplay));
    // Once the cookie's lifetime is over: refused on the epoch, and the
    // memory of it may go.
    rig.now += Duration::from_secs(2 * COOKIE_EPOCH_S);
    assert_eq!(rig.datagram(proof1.bytes()), Err(Refusal::BadCookie));
    // A restarted bridge (a new secret) refuses it inside its lifetime too.
    let mut rig2 = Rig::new(Psk::test_key());
    rig2.gate = Gate::new(Psk::test_key(), &[0x6f; 32]);
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
    // One client numbering on (each proof newer than the last).
    for k in 0..PROOF_MEMORY as u32 {
        let mut c = ClientAuth::new(Psk::test_key());
        let mut nc = [0u8; NONCE_LEN];
        nc[..4].copy_from_slice(&k.to_be_bytes());
        let open = c.hello(&hdr(2 * k + 1, 0, 0), nc);
        let cookie = rig.datagram(open.bytes()).unwrap().unwrap();
        c.open(cookie.bytes()).unwrap();
        let p = c.prove(&hdr(2 * k + 2, 0, 0)).unwrap();
        assert!(rig.datagram(p.bytes()).is_ok());
    }
    let n = rig.forwarded.len();
    let mut c = ClientAuth::new(Psk::test_key());
    let next = 2 * PROOF_MEMORY as u32 + 1;
    let (_, proof) = hello_and_proof(&mut rig, &mut c, next, 0xee);
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
    handshake(&mut rig, &mut c, next + 1, 0xef);
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
    // The span counts from the open_proof's number (1): up to 10, excluded.
    for q in 2..=10 {
        let w = c.seal(&hdr(q, s, 0), &vpr(1)).unwrap();
        assert_eq!(rig.datagram(w.bytes()), Ok(None), "{q}");
    }
    assert!(!c.exhausted());
    assert!(c.seal(&hdr(11, s, 0), &vpr(1)).is_none(), "span 10");
    assert!(c.exhausted());
    // The bridge refuses it too (a frame sealed by hand with the keys).
    let keys = c.keys().unwrap().clone();
    let w = seal_request(&keys, &hdr(11, s, 0), &vpr(1)).unwrap();
    assert_eq!(rig.datagram(w.bytes()), Err(Refusal::SeqExhausted));
    // Reordered frames inside the window are still fine; the bridge then
    // ends the session (it does so on the first such refusal).
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

/// The span is the distance between numbers, not a count of frames: a
/// client that jumps its numbering spends them, and an early request can
/// never come round again as "newer".
#[test]
fn the_sequence_span_counts_numbers_not_frames() {
    let mut rig = Rig::new(Psk::test_key());
    let mut c = ClientAuth::new(Psk::test_key());
    let s0 = 7u32;
    let s = handshake(&mut rig, &mut c, s0, 0x31);
    let keys = c.keys().unwrap().clone();
    let seal =
        |seq: u32, control: u16, f: Frame| seal_request(&keys, &hdr(seq, s, control), &f).unwrap();
    // An early power request, acknowledged (and recorded by an onlooker).
    let early = seal(s0 + 1, CTRL_ACK_REQUEST, Frame::PowerRequest(true));
    assert!(rig.datagram(early.bytes()).unwrap().is_some());
    // Jumps of 2^30: the first is fine (span 2^30), the second would make
    // the span 2^31: refused, and the session is to be ended.
    let j1 = seal(s0 + (1 << 30), 0, vpr(1));
    assert_eq!(rig.datagram(j1.bytes()), Ok(None));
    let j2 = seal(s0.wrapping_add(1 << 31), 0, vpr(2));
    assert_eq!(rig.datagram(j2.bytes()), Err(Refusal::SeqExhausted));
    // A stranger's frame that far ahead is refused at its tag: only the key
    // holder can make the bridge end its session.
    let mut forged = j2;
    forged.buf[forged.len - 1] ^= 1;
    assert_eq!(rig.datagram(forged.bytes()), Err(Refusal::BadTag));
    let j3 = seal(s0.wrapping_add(3 << 30), 0, vpr(3));
    assert!(rig.datagram(j3.bytes()).is_err(), "beyond the span");
    // The early request is old, however it is compared: refused, not acked.
    let n = rig.forwarded.len();
    assert_eq!(rig.datagram(early.bytes()), Err(Refusal::TooOld));
    assert_eq!(rig.forwarded.len(), n);
    // The client's side refuses to seal past the span the same way.
    let mut c2 = ClientAuth::new(Psk::test_key());
    rig.src = SocketAddr::from(([192, 0, 2, 1], 40001));
    let s2 = handshake(&mut rig, &mut c2, 100, 0x32);
    assert!(c2.seal(&hdr(100 + (1 << 30), s2, 0), &vpr(1)).is_some());
    assert!(c2
        .seal(&hdr(100u32.wrapping_add(1 << 31), s2, 0), &vpr(1))
        .is_none());
    assert!(c2.exhausted());
}

/// The kernel's direction: its numbers span from the session_ack on.
#[test]
fn the_kernel_direction_ends_at_its_span_too() {
    let mut rig = Rig::new(Psk::test_key());
    rig.gate.set_frame_limit(10);
    let mut c = ClientAuth::new(Psk::test_key());
    let s = handshake(&mut rig, &mut c, 1, 0x33);
    // The session_ack carried the kernel's number 900 (the rig's).
    let answer = |seq: u32| {
        let mut v1 = [0u8; MAX_FRAME_LEN];
        let n = encode(&hdr(seq, s, 0), &Frame::Answer(Answer::default()), &mut v1);
        v1[..n].to_vec()
    };
    for q in 901..=909 {
        assert!(rig.gate.seal_from_kernel(&answer(q)).is_some(), "{q}");
    }
    assert!(!rig.gate.exhausted());
    assert!(rig.gate.seal_from_kernel(&answer(910)).is_none());
    assert!(rig.gate.exhausted(), "the bridge ends it");
    assert!(rig.gate.seal_from_kernel(&answer(911)).is_none());
}

/// A proof commits only forward: from the live session's client address,
/// an attempt older than the one that opened the session is refused; a
/// copy of the opening proof gets the session_ack again.
#[test]
fn a_held_back_proof_never_replaces_the_session_it_was_overtaken_by() {
    let mut rig = Rig::new(Psk::test_key());
    // Attempt 1: its proof is held back (never reaches the bridge now).
    let mut c = ClientAuth::new(Psk::test_key());
    let (_, held) = hello_and_proof(&mut rig, &mut c, 1, 0x50);
    // Attempt 2 of the same client (same address), newer numbers: opens.
    let mut c2 = ClientAuth::new(Psk::test_key());
    let open2 = c2.hello(&hdr(3, 0, 0), [0x51; NONCE_LEN]);
    let cookie2 = rig.datagram(open2.bytes()).unwrap().unwrap();
    c2.open(cookie2.bytes()).unwrap();
    let proof2 = c2.prove(&hdr(4, 0, 0)).unwrap();
    let ack2 = rig.datagram(proof2.bytes()).unwrap().unwrap();
    let (h, _) = c2.open(ack2.bytes()).unwrap();
    let s2 = h.session;
    let n = rig.forwarded.len();
    // The held-back proof of attempt 1 arrives: refused, nothing forwarded,
    // the session stays.
    assert_eq!(rig.datagram(held.bytes()), Err(Refusal::StaleProof));
    assert_eq!(rig.forwarded.len(), n);
    assert_eq!(rig.gate.session_id(), s2);
    assert!(rig.gate.take_replaced().is_none());
    // A copy of attempt 2's proof: the same session_ack, nothing committed.
    assert_eq!(rig.datagram(proof2.bytes()), Ok(Some(ack2)));
    assert_eq!(rig.forwarded.len(), n);
    // Asked again, the client's proof is the same bytes.
    let mut c3 = ClientAuth::new(Psk::test_key());
    let (_, p1) = hello_and_proof(&mut rig, &mut c3, 10, 0x52);
    assert_eq!(c3.pending_proof(), Some(p1));
    assert_eq!(c3.prove(&hdr(99, 0, 0)), Some(p1));
    // From another address (the key holder on another port), an older
    // number is another client's: it takes the session (by design).
    rig.src = SocketAddr::from(([192, 0, 2, 1], 40003));
    let mut c4 = ClientAuth::new(Psk::test_key());
    let s4 = handshake(&mut rig, &mut c4, 1, 0x53);
    assert_ne!(s4, s2);
    assert!(rig.gate.take_replaced().is_some());
}

/// A recorded open_session draws one cookie: its nonce is remembered for
/// HELLO_MEMORY_S, and meanwhile it draws nothing, from any address.
#[test]
fn a_recorded_hello_replayed_from_many_addresses_draws_nothing() {
    let mut rig = Rig::new(Psk::test_key());
    let mut c = ClientAuth::new(Psk::test_key());
    let open = c.hello(&hdr(1, 0, 0), [0x60; NONCE_LEN]);
    assert!(rig.datagram(open.bytes()).unwrap().is_some());
    for k in 0..64u16 {
        let src = SocketAddr::from(([127, 0, 0, 2 + (k % 200) as u8], 5000 + k));
        assert_eq!(
            rig.datagram_from(src, open.bytes()),
            Err(Refusal::HelloReplay)
        );
    }
    assert_eq!(rig.datagram(open.bytes()), Err(Refusal::HelloReplay));
    assert_eq!(rig.gate.counters.cookies, 1);
    // After the memory's time, answered again (one more cookie).
    rig.now += Duration::from_secs(HELLO_MEMORY_S);
    let other = SocketAddr::from(([127, 0, 0, 9], 9));
    assert!(rig.datagram_from(other, open.bytes()).unwrap().is_some());
    // The memory is bounded: the oldest nonce goes first.
    for k in 0..(HELLO_MEMORY as u32 + 10) {
        let mut nc = [0x61; NONCE_LEN];
        nc[..4].copy_from_slice(&k.to_be_bytes());
        let o = seal_open(&Psk::test_key(), &hdr(k, 0, 0), &nc);
        assert!(rig.datagram(o.bytes()).unwrap().is_some());
    }
    assert!(rig.gate.hellos_remembered() <= HELLO_MEMORY);
    let mut first = [0x61; NONCE_LEN];
    first[..4].copy_from_slice(&0u32.to_be_bytes());
    let o = seal_open(&Psk::test_key(), &hdr(0, 0, 0), &first);
    assert!(rig.datagram_from(other, o.bytes()).unwrap().is_some());
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

/// The control word: a reserved bit (3–15) on a verified request is
/// answered `error` 7 `bad_flags` and not forwarded; on the handshake
/// frames the control word has no meaning: whatever it holds, the
/// handshake goes through and the kernel's `open_session` carries 0.
#[test]
fn control_bits_on_requests_and_on_the_handshake() {
    let mut rig = Rig::new(Psk::test_key());
    let mut c = ClientAuth::new(Psk::test_key());
    let open = c.hello(&hdr(1, 0, 0xffff), [0x45; NONCE_LEN]);
    let cookie = rig.datagram(open.bytes()).unwrap().expect("cookie");
    assert_eq!(c.open(cookie.bytes()).unwrap().1, Reply::Cookie);
    let proof = c.prove(&hdr(2, 0, 0xffff)).unwrap();
    let i = rig.gate.inspect(proof.bytes(), rig.src, rig.now).unwrap();
    let Action::Forward(v1) = rig.gate.commit(&i, rig.now) else {
        panic!("not committed")
    };
    let (h, f) = hap_core::protocol::decode(v1.bytes()).unwrap();
    assert_eq!((h.control, h.seq), (0, 2));
    assert!(matches!(f, Frame::OpenSession { .. }));
    let ack = rig.kernel_frame(v1.bytes()).unwrap().unwrap();
    let (hd, _) = c.open(ack.bytes()).unwrap();
    let s = hd.session;
    // A reserved bit on a request: told why, nothing forwarded.
    let n = rig.forwarded.len();
    let w = c.seal(&hdr(3, s, 1 << 5), &vpr(1)).unwrap();
    let reply = rig.datagram(w.bytes()).unwrap().unwrap();
    assert_eq!(
        c.open(reply.bytes()).unwrap().1,
        Reply::Frame(Frame::Error {
            reason: hap_core::protocol::DecodeError::BadFlags.reason_index() as u32,
            rejected_seq: 3
        })
    );
    assert_eq!(rig.forwarded.len(), n);
    // Bits 0–2 are defined: CTRL_LINK_ENERGY (bit 2) on a vpr_stream passes.
    let w = c
        .seal(&hdr(4, s, hap_core::protocol::CTRL_LINK_ENERGY), &vpr(1))
        .unwrap();
    assert_eq!(rig.datagram(w.bytes()), Ok(None));
    assert_eq!(rig.forwarded.len(), n + 1);
}

/// What a client checks in a `cookie`: its length and type, that it
/// echoes the client's Nc, and its tag under K_cookie(Nc). The header's
/// other fields (the bridge sends 0) and the epoch are covered by the tag
/// and not checked against a value; Ns and the epoch go into the proof as
/// they came.
#[test]
fn what_a_client_checks_in_a_cookie() {
    let psk = Psk::test_key();
    let nc = [0x46; NONCE_LEN];
    let ns = [0x47; NONCE_LEN];
    let odd = FrameHeader {
        control: 3,
        session: 9,
        seq: 77,
        timestamp_us: 5,
    };
    let mut c = ClientAuth::new(psk.clone());
    c.hello(&hdr(1, 0, 0), nc);
    // Another nonce echoed, or a tag under another key: ignored.
    assert_eq!(
        c.open(seal_cookie(&psk, &odd, &[0x48; NONCE_LEN], &ns, 3).bytes()),
        Err(Refusal::BadTag)
    );
    assert_eq!(
        c.open(seal_cookie(&other_key(), &odd, &nc, &ns, 3).bytes()),
        Err(Refusal::BadTag)
    );
    let mut short = seal_cookie(&psk, &odd, &nc, &ns, 3);
    short.len -= 1;
    assert_eq!(c.open(short.bytes()), Err(Refusal::LengthMismatch));
    // Other header values, another epoch: taken, as they are.
    assert_eq!(
        c.open(seal_cookie(&psk, &odd, &nc, &ns, 0xdead).bytes())
            .unwrap()
            .1,
        Reply::Cookie
    );
    let p = c.prove(&hdr(2, 0, 0)).unwrap();
    assert_eq!(p, seal_open_proof(&psk, &hdr(2, 0, 0), &nc, &ns, 0xdead));
}

/// A client that sent a second `open_session` (no cookie came in time)
/// still takes the first one's cookie if it comes first; it proves one
/// cookie only, and ignores the other.
#[test]
fn the_first_cookie_to_come_is_proved_and_only_it() {
    let mut rig = Rig::new(Psk::test_key());
    let mut c = ClientAuth::new(Psk::test_key());
    let open1 = c.hello(&hdr(1, 0, 0), [0x49; NONCE_LEN]);
    let open2 = c.hello(&hdr(2, 0, 0), [0x4a; NONCE_LEN]);
    let cookie2 = rig.datagram(open2.bytes()).unwrap().unwrap();
    let cookie1 = rig.datagram(open1.bytes()).unwrap().unwrap();
    assert_eq!(c.open(cookie1.bytes()).unwrap().1, Reply::Cookie);
    assert_eq!(c.open(cookie2.bytes()), Err(Refusal::NoSession));
    let proof = c.prove(&hdr(3, 0, 0)).unwrap();
    assert_eq!(
        &proof.buf[HEADER_LEN..HEADER_LEN + NONCE_LEN],
        &[0x49; NONCE_LEN]
    );
    let ack = rig.datagram(proof.bytes()).unwrap().unwrap();
    assert!(matches!(
        c.open(ack.bytes()).unwrap().1,
        Reply::SessionAck { .. }
    ));
    // Only the last HELLOS_PENDING nonces are heard.
    let mut d = ClientAuth::new(Psk::test_key());
    let first = d.hello(&hdr(10, 0, 0), [0x4b; NONCE_LEN]);
    for k in 0..HELLOS_PENDING as u8 {
        d.hello(&hdr(11 + u32::from(k), 0, 0), [0x50 + k; NONCE_LEN]);
    }
    rig.src = SocketAddr::from(([192, 0, 2, 1], 40005));
    let cookie = rig.datagram(first.bytes()).unwrap().unwrap();
    assert_eq!(d.open(cookie.bytes()), Err(Refusal::BadTag));
}
