//! Hostile-input campaign (`hapdev hostile`): malformed and hostile frames,
//! all built with hap-core (encoder, CRC-32C, frame table: no second copy of
//! the layout), each with the counter it must land in.
//!
//! Two targets:
//! - `net`: UDP datagrams to the bridge (proto_interface) from a fresh
//!   socket, i.e. a source other than the session's client. Expected
//!   bridge counters: `rejected_oversize` (> 90 bytes), `rejected_undersize`
//!   (< 20), `rejected_malformed` (does not decode, or a controller-only
//!   type), `rejected_stray_source` (decodes as a request: wrong session,
//!   replayed sequence number, a second OpenSession...). Nothing reaches the
//!   module.
//! - `dev`: frames written straight to `/dev/hap_rtf_in` (what a broken or
//!   compromised bridge could write), next to the live session `--session`.
//!   Expected module counters: `rtf_in.bad_length` (the device refuses a
//!   length that is not the type's), `rejected.<decode reason>`,
//!   `rejected.not_a_request`, `rejected.no_session` (valid CRC, another
//!   session id), `rejected.stale_seq` (the live session id with a replayed,
//!   old sequence number). Frames that would be *accepted* (an OpenSession,
//!   or the live session with a new sequence number) are never generated:
//!   they are not hostile input but a second client, which the bridge's
//!   session pinning refuses.

use std::collections::BTreeMap;
use std::io::Write;
use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

use hap_core::{
    config::{CommandType, VirtualObjectParams},
    fixed::{Fx, Pose, Quat, Twist, Vec3, Wrench},
    protocol::{
        decode, encode, expected_len, seal_crc, Answer, DecodeError, Frame, FrameHeader, FrameType,
        CRC_LEN, HEADER_LEN, MAX_FRAME_LEN, MIN_FRAME_LEN,
    },
};

/// Where the frames go.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Target {
    Net,
    Dev { session: u16 },
}

/// Deterministic generator (xorshift64).
pub struct Gen {
    x: u64,
    target: Target,
}

/// Kinds of hostile input, in rotation.
pub const KINDS: [&str; 12] = [
    "random_bytes",
    "truncated",
    "oversized",
    "bad_crc",
    "wrong_session",
    "replayed_seq",
    "nan_inf_float",
    "bad_value",
    "controller_type",
    "second_open",
    "bit_flip",
    "wrong_length",
];

fn enc(h: &FrameHeader, f: &Frame) -> Vec<u8> {
    let mut buf = [0u8; MAX_FRAME_LEN];
    let n = encode(h, f, &mut buf);
    buf[..n].to_vec()
}

/// Recompute the trailing CRC-32C (hap-core's) after a mutation.
fn fix_crc(b: &mut [u8]) {
    if b.len() >= MIN_FRAME_LEN {
        seal_crc(b);
    }
}

impl Gen {
    pub fn new(seed: u64, target: Target) -> Gen {
        Gen {
            x: seed | 1,
            target,
        }
    }

    fn next(&mut self) -> u64 {
        self.x ^= self.x << 13;
        self.x ^= self.x >> 7;
        self.x ^= self.x << 17;
        self.x
    }

    fn below(&mut self, n: u64) -> u64 {
        self.next() % n.max(1)
    }

    fn bytes(&mut self, n: usize) -> Vec<u8> {
        (0..n).map(|_| self.next() as u8).collect()
    }

    fn fx(&mut self, range_mm: i64) -> Fx {
        Fx::from_f64((self.below(2 * range_mm as u64 + 1) as i64 - range_mm) as f64 / 1000.0)
    }

    /// A valid request of a random type (never an OpenSession).
    fn request(&mut self) -> Frame {
        let pose = Pose {
            position: Vec3 {
                x: self.fx(200),
                y: self.fx(200),
                z: self.fx(200),
            },
            orientation: Quat::default(),
        };
        match self.below(6) {
            0 => Frame::VprStream {
                pose,
                twist: Twist::default(),
            },
            1 => Frame::PowerRequest(self.below(2) == 0),
            2 => Frame::SetCommandType(CommandType::Impedance),
            3 => Frame::SetFactors {
                force: Fx::from_f64(1.0),
                speed: Fx::from_f64(1.0),
            },
            4 => Frame::AttachVirtualObject(VirtualObjectParams {
                mass: Fx::from_f64(0.5),
                inertia: Vec3 {
                    x: Fx::from_f64(0.001),
                    y: Fx::from_f64(0.001),
                    z: Fx::from_f64(0.001),
                },
            }),
            _ => Frame::CloseSession,
        }
    }

    /// A session id that is not the live one (and not 0 for `dev`, where 0
    /// is "no session" and also refused: either is fine).
    fn other_session(&mut self) -> u16 {
        let live = match self.target {
            Target::Dev { session } => session,
            Target::Net => 0,
        };
        loop {
            let s = self.next() as u16;
            if s != live {
                return s;
            }
        }
    }

    /// The header of a frame that must not be accepted: another session,
    /// or (dev) the live one with an old, replayed sequence number.
    fn header(&mut self, replay: bool) -> FrameHeader {
        match (self.target, replay) {
            (Target::Dev { session }, true) => FrameHeader {
                control: 0,
                session,
                seq: 1 + self.below(16) as u32,
                timestamp_us: 0,
            },
            (_, replay) => FrameHeader {
                control: 0,
                session: self.other_session(),
                seq: if replay {
                    1 + self.below(16) as u32
                } else {
                    self.next() as u32
                },
                timestamp_us: self.next() as u32,
            },
        }
    }

    /// A VprStream with one float replaced by NaN, +Inf or -Inf, CRC valid.
    fn nan_frame(&mut self) -> Vec<u8> {
        let replay = self.below(2) == 0;
        let h = self.header(replay);
        let mut b = enc(
            &h,
            &Frame::VprStream {
                pose: Pose::default(),
                twist: Twist::default(),
            },
        );
        // Every payload word of a VprStream is an XDR float (pose, twist).
        let words = FrameType::VprStream.payload_len() / 4;
        let w = self.below(words as u64) as usize;
        let bits: u32 = match self.below(4) {
            0 => f32::NAN.to_bits(),
            1 => 0xFFC0_0001, // a negative quiet NaN with payload
            2 => f32::INFINITY.to_bits(),
            _ => f32::NEG_INFINITY.to_bits(),
        };
        let at = HEADER_LEN + 4 * w;
        b[at..at + 4].copy_from_slice(&bits.to_be_bytes());
        fix_crc(&mut b);
        b
    }

    /// A frame with a bad value (out-of-range float, bad enum, bad bool,
    /// reserved control bit), CRC valid.
    fn bad_value_frame(&mut self) -> Vec<u8> {
        let replay = self.below(2) == 0;
        let h = self.header(replay);
        match self.below(4) {
            0 => {
                let mut b = enc(
                    &h,
                    &Frame::VprStream {
                        pose: Pose::default(),
                        twist: Twist::default(),
                    },
                );
                let w = self.below(3) as usize; // a position coordinate
                let at = HEADER_LEN + 4 * w;
                b[at..at + 4].copy_from_slice(&3.0e10f32.to_bits().to_be_bytes());
                fix_crc(&mut b);
                b
            }
            1 => {
                let mut b = enc(&h, &Frame::SetCommandType(CommandType::None));
                b[HEADER_LEN..HEADER_LEN + 4]
                    .copy_from_slice(&(7 + self.below(100) as u32).to_be_bytes());
                fix_crc(&mut b);
                b
            }
            2 => {
                let mut b = enc(&h, &Frame::PowerRequest(false));
                b[HEADER_LEN..HEADER_LEN + 4]
                    .copy_from_slice(&(2 + self.below(100) as u32).to_be_bytes());
                fix_crc(&mut b);
                b
            }
            _ => {
                let f = self.request();
                let mut h = h;
                h.control = 1 << (3 + self.below(13)); // bits 3–15 are reserved
                let mut b = enc(&FrameHeader { control: 0, ..h }, &f);
                b[4..6].copy_from_slice(&h.control.to_be_bytes());
                fix_crc(&mut b);
                b
            }
        }
    }

    /// Datagram number `i` and its kind.
    pub fn make(&mut self, i: u64) -> (Vec<u8>, &'static str) {
        let kind = KINDS[(i % KINDS.len() as u64) as usize];
        let b = match kind {
            "random_bytes" => {
                let n = self.below(200) as usize;
                self.bytes(n)
            }
            "truncated" => {
                let h = self.header(false);
                let f = self.request();
                let b = enc(&h, &f);
                let n = self.below(b.len() as u64) as usize;
                b[..n].to_vec()
            }
            "oversized" => {
                let h = self.header(false);
                let f = self.request();
                let mut b = enc(&h, &f);
                let n = MAX_FRAME_LEN + 1 + self.below(1400) as usize;
                let pad = self.bytes(n - b.len());
                b.extend(pad);
                b
            }
            "bad_crc" => {
                let h = self.header(false);
                let f = self.request();
                let mut b = enc(&h, &f);
                let last = b.len() - 1 - self.below(CRC_LEN as u64) as usize;
                b[last] ^= 1 + self.below(255) as u8;
                b
            }
            "wrong_session" => {
                let h = self.header(false);
                let f = self.request();
                enc(&h, &f)
            }
            "replayed_seq" => {
                let h = self.header(true);
                let f = self.request();
                enc(&h, &f)
            }
            "nan_inf_float" => self.nan_frame(),
            "bad_value" => self.bad_value_frame(),
            "controller_type" => {
                let h = self.header(false);
                let f = match self.below(3) {
                    0 => Frame::Answer(Answer {
                        coupling_wrench: Wrench::default(),
                        cycle: self.next() as u32,
                        ..Answer::default()
                    }),
                    1 => Frame::SessionAck {
                        client_nonce: self.next() as u32,
                        period_us: 1000,
                    },
                    _ => Frame::Error {
                        reason: 0x100,
                        rejected_seq: self.next() as u32,
                    },
                };
                enc(&h, &f)
            }
            "second_open" => match self.target {
                // A second client opening a session from another source.
                Target::Net => enc(
                    &self.header(false),
                    &Frame::OpenSession {
                        client_nonce: self.next() as u32,
                    },
                ),
                // On the device an OpenSession would be obeyed (the bridge is
                // what pins the client): send a CloseSession replay instead.
                Target::Dev { .. } => enc(&self.header(true), &Frame::CloseSession),
            },
            "bit_flip" => {
                let h = self.header(false);
                let f = self.request();
                let mut b = enc(&h, &f);
                // Any byte but the type byte (which would change the length).
                let mut at = self.below(b.len() as u64) as usize;
                if at == 3 {
                    at = 4;
                }
                b[at] ^= 1 << self.below(8);
                b
            }
            _ => {
                // "wrong_length": a valid header and CRC, a length that is not
                // the type's (but within 20..=90).
                let h = self.header(false);
                let f = self.request();
                let mut b = enc(&h, &f);
                let want = b.len();
                let mut n =
                    MIN_FRAME_LEN + self.below((MAX_FRAME_LEN - MIN_FRAME_LEN + 1) as u64) as usize;
                if n == want {
                    n = if want > MIN_FRAME_LEN {
                        want - 4
                    } else {
                        want + 4
                    };
                }
                b.resize(n, 0);
                fix_crc(&mut b);
                b
            }
        };
        (b, kind)
    }
}

/// The bridge counter a datagram from a stray source must land in.
pub fn bridge_counter(b: &[u8]) -> &'static str {
    if b.len() > MAX_FRAME_LEN {
        return "rejected_oversize";
    }
    if b.len() < MIN_FRAME_LEN {
        return "rejected_undersize";
    }
    match decode(b) {
        Err(DecodeError::TooLong) => "rejected_oversize",
        Err(DecodeError::TooShort) => "rejected_undersize",
        Err(_) => "rejected_malformed",
        Ok((_, f)) if !f.frame_type().is_request() => "rejected_malformed",
        Ok(_) => "rejected_stray_source",
    }
}

/// The module counter a frame written to rtf_in must land in, next to the
/// live session `session`, whose sequence numbers are past 16 + 64 (seq
/// 1..=16 is then older than PROTO_IN's anti-replay window: stale).
pub fn module_counter(b: &[u8], session: u16) -> String {
    if b.len() < MIN_FRAME_LEN || b.len() > MAX_FRAME_LEN || expected_len(b) != Some(b.len()) {
        return "rtf_in.bad_length".into();
    }
    match decode(b) {
        Err(e) => format!("rejected.{}", e.name()),
        Ok((_, f)) if !f.frame_type().is_request() => "rejected.not_a_request".into(),
        Ok((_, Frame::OpenSession { .. })) => "ACCEPTED(open_session)".into(),
        Ok((h, _)) if h.session != session => "rejected.no_session".into(),
        Ok((h, _)) if h.seq <= 16 => "rejected.stale_seq".into(),
        Ok(_) => "ACCEPTED".into(),
    }
}

/// What a run did and what the counters must show.
#[derive(Default)]
pub struct Report {
    pub sent: u64,
    pub kinds: BTreeMap<&'static str, u64>,
    pub expect: BTreeMap<String, u64>,
    /// Device writes retried because rtf_in was full (dev).
    pub retries_full: u64,
    /// Device writes refused (EINVAL) (dev).
    pub refused: u64,
    pub seconds: f64,
    /// Why the run stopped early (the counts above are what was sent).
    pub error: Option<String>,
}

impl Report {
    pub fn render(&self) -> String {
        let mut s = format!("sent: {}\nseconds: {:.2}\n", self.sent, self.seconds);
        for (k, v) in &self.kinds {
            s += &format!("kind.{k}: {v}\n");
        }
        for (k, v) in &self.expect {
            s += &format!("expect.{k}: {v}\n");
        }
        s += &format!(
            "retries_full: {}\nrefused: {}\n",
            self.retries_full, self.refused
        );
        if let Some(e) = &self.error {
            s += &format!("error: {e}\n");
        }
        s
    }
}

/// Paces the frames at one per `interval` on average; after a stall (the
/// sender descheduled) it catches up by at most 8 frames back to back, so
/// no burst overflows a queue on the way.
struct Pacer {
    next: Instant,
    interval: Duration,
}

impl Pacer {
    fn new(interval: Duration) -> Pacer {
        Pacer {
            next: Instant::now() + interval,
            interval,
        }
    }

    fn wait(&mut self) {
        let now = Instant::now();
        if self.next > now {
            std::thread::sleep(self.next - now);
        } else if now - self.next > self.interval * 8 {
            self.next = now;
        }
        self.next += self.interval;
    }
}

/// Send `count` hostile datagrams to `to` (loopback only).
pub fn run_net(
    to: SocketAddr,
    count: u64,
    interval: Duration,
    seed: u64,
) -> Result<Report, String> {
    if !to.ip().is_loopback() {
        return Err(format!("{to}: loopback addresses only"));
    }
    let sock = UdpSocket::bind("127.0.0.1:0").map_err(|e| format!("bind: {e}"))?;
    let mut g = Gen::new(seed, Target::Net);
    let mut r = Report::default();
    let t0 = Instant::now();
    let mut pacer = Pacer::new(interval);
    for i in 0..count {
        let (b, kind) = g.make(i);
        // ECONNREFUSED from an ICMP error of an earlier datagram: retry once.
        if sock.send_to(&b, to).is_err() {
            if let Err(e) = sock.send_to(&b, to) {
                r.error = Some(format!("send to {to}: datagram {i}: {e}"));
                break;
            }
        }
        *r.kinds.entry(kind).or_default() += 1;
        *r.expect.entry(bridge_counter(&b).into()).or_default() += 1;
        r.sent += 1;
        pacer.wait();
    }
    r.seconds = t0.elapsed().as_secs_f64();
    Ok(r)
}

/// Write `count` hostile frames to the rtf_in device next to `session`.
pub fn run_dev(
    dev: &str,
    session: u16,
    count: u64,
    interval: Duration,
    seed: u64,
) -> Result<Report, String> {
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .open(dev)
        .map_err(|e| format!("{dev}: {e}"))?;
    let mut g = Gen::new(seed, Target::Dev { session });
    let mut r = Report::default();
    let t0 = Instant::now();
    let mut pacer = Pacer::new(interval);
    for i in 0..count {
        let (b, kind) = g.make(i);
        let c = module_counter(&b, session);
        if c.starts_with("ACCEPTED") {
            return Err(format!(
                "generator bug: frame {i} ({kind}) would be accepted: {c}"
            ));
        }
        let res = loop {
            match f.write(&b) {
                Ok(_) => break Ok(()),
                Err(e) if e.raw_os_error() == Some(libc::EINVAL) => {
                    r.refused += 1;
                    break Ok(());
                }
                Err(e) if e.raw_os_error() == Some(libc::EAGAIN) => {
                    r.retries_full += 1;
                    std::thread::sleep(Duration::from_millis(1));
                }
                Err(e) => break Err(format!("{dev}: frame {i}: {e}")),
            }
        };
        if let Err(e) = res {
            // The module went away (fail-safe, rmmod): report what was sent.
            r.error = Some(e);
            break;
        }
        *r.kinds.entry(kind).or_default() += 1;
        *r.expect.entry(c).or_default() += 1;
        r.sent += 1;
        pacer.wait();
    }
    let _ = f.flush();
    r.seconds = t0.elapsed().as_secs_f64();
    Ok(r)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn net_datagrams_never_forward() {
        let mut g = Gen::new(42, Target::Net);
        let mut seen = BTreeMap::new();
        for i in 0..24_000 {
            let (b, kind) = g.make(i);
            let c = bridge_counter(&b);
            *seen.entry((kind, c)).or_insert(0u32) += 1;
            match kind {
                "oversized" => assert_eq!(c, "rejected_oversize"),
                "nan_inf_float" => assert_eq!(decode(&b).err(), Some(DecodeError::NotFinite)),
                "wrong_session" | "replayed_seq" | "second_open" => {
                    assert_eq!(c, "rejected_stray_source")
                }
                "controller_type" | "bad_crc" | "bad_value" | "wrong_length" => {
                    assert_eq!(c, "rejected_malformed", "{kind}: {:?}", decode(&b))
                }
                _ => {}
            }
        }
        // Every counter is exercised.
        for c in [
            "rejected_oversize",
            "rejected_undersize",
            "rejected_malformed",
            "rejected_stray_source",
        ] {
            assert!(
                seen.keys().any(|(_, cc)| *cc == c),
                "{c} never hit: {seen:?}"
            );
        }
    }

    #[test]
    fn dev_frames_are_never_accepted_and_hit_every_reason() {
        let session = 3;
        let mut g = Gen::new(7, Target::Dev { session });
        let mut seen = BTreeMap::new();
        for i in 0..24_000 {
            let (b, _) = g.make(i);
            let c = module_counter(&b, session);
            assert!(!c.starts_with("ACCEPTED"), "frame {i}: {c}");
            *seen.entry(c).or_insert(0u32) += 1;
        }
        for c in [
            "rtf_in.bad_length",
            "rejected.bad_crc",
            "rejected.not_finite",
            "rejected.out_of_range",
            "rejected.bad_enum",
            "rejected.bad_bool",
            "rejected.bad_flags",
            "rejected.not_a_request",
            "rejected.no_session",
            "rejected.stale_seq",
        ] {
            assert!(seen.contains_key(c), "{c} never hit: {seen:?}");
        }
    }
}
