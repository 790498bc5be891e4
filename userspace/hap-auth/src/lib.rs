//! hapticctrl protocol v2: the authenticated envelope around hap-core's
//! frames (`Documentation/protocol.md` §7), shared by the bridge
//! (`proto_interface`) and the client library (`virtuose_api`).
//!
//! - [`Psk`]: the 32-byte pre-shared key, read from a mode-0600 file.
//! - Key derivation: HMAC-SHA-256 as a PRF over a label and the two
//!   handshake nonces ([`open_key`], [`SessionKeys::derive`]).
//! - Envelope: the v1 header with version 2, the payload, and an
//!   HMAC-SHA-256 tag truncated to 16 bytes (12 for `answer`) in place of
//!   the CRC-32C. Tags are compared in constant time (`hmac`'s
//!   `verify_truncated_left`).
//! - [`Gate`]: the bridge's side. Every client datagram is checked (length,
//!   tag, session, anti-replay window) before the bridge turns it into the
//!   v1 frame the kernel reads; every refusal has a [`Refusal`] reason.
//! - [`ClientAuth`]: the client's side (handshake, sealing requests,
//!   verifying replies).
//!
//! The kernel never sees v2: the bridge forwards only frames it verified,
//! re-encoded as v1 (same header fields, same payload bytes, CRC-32C).

use std::io::Read;
use std::path::Path;

use hap_core::protocol::{
    decode, read_header, seal_crc, write_header, DecodeError, Frame, FrameHeader, FrameType,
    SeqCheck, SeqWindow, CTRL_ACK_REQUEST, ERROR_REFUSED, HEADER_LEN, MAGIC, MAX_FRAME_LEN,
};
use hmac::{Hmac, Mac};
use sha2::Sha256;

/// Wire version of the authenticated protocol (byte 2).
pub const VERSION: u8 = 2;
/// Pre-shared key length, bytes.
pub const PSK_LEN: usize = 32;
/// Handshake nonce length, bytes (each side contributes one).
pub const NONCE_LEN: usize = 16;
/// Tag length of every v2 frame but `answer`.
pub const TAG_LEN: usize = 16;
/// Tag length of `answer` (the 90-byte limit; protocol.md §7.4).
pub const ANSWER_TAG_LEN: usize = 12;
/// Acknowledged requests whose ack the bridge keeps to answer a replayed copy.
pub const ACK_MEMORY: usize = 8;
/// Client nonces remembered to refuse a replayed `open_session`.
pub const NONCE_MEMORY: usize = 4096;

/// KDF labels (ASCII, no terminator).
pub const LABEL_OPEN: &[u8] = b"hapticctrl v2 open";
pub const LABEL_C2S: &[u8] = b"hapticctrl v2 c2s";
pub const LABEL_S2C: &[u8] = b"hapticctrl v2 s2c";
pub const LABEL_REFUSE: &[u8] = b"hapticctrl v2 refuse";

type HmacSha256 = Hmac<Sha256>;

/// A 32-byte MAC or derivation key.
pub type Key = [u8; 32];

/// HMAC-SHA-256 of the concatenation of `parts` under `key`.
pub fn hmac(key: &[u8], parts: &[&[u8]]) -> Key {
    let mut m = <HmacSha256 as Mac>::new_from_slice(key).expect("HMAC takes any key length");
    for p in parts {
        m.update(p);
    }
    m.finalize().into_bytes().into()
}

/// The pre-shared key. `Debug` does not print it.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Psk([u8; PSK_LEN]);

impl std::fmt::Debug for Psk {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Psk(..)")
    }
}

/// Why a key could not be loaded.
#[derive(Debug)]
pub enum KeyError {
    Io(std::io::Error),
    /// Group or others may read or write the file.
    Permissions(u32),
    /// Not 64 hexadecimal digits.
    Format,
}

impl std::fmt::Display for KeyError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            KeyError::Io(e) => write!(f, "{e}"),
            KeyError::Permissions(m) => write!(
                f,
                "mode {m:04o}: a key file must not be accessible to group or others (chmod 600)"
            ),
            KeyError::Format => write!(
                f,
                "not a key: expected {} hexadecimal digits (hapctl keygen)",
                PSK_LEN * 2
            ),
        }
    }
}

impl std::error::Error for KeyError {}

impl Psk {
    pub const fn from_bytes(b: [u8; PSK_LEN]) -> Psk {
        Psk(b)
    }

    pub const fn as_bytes(&self) -> &[u8; PSK_LEN] {
        &self.0
    }

    /// The published test key of protocol.md §7.6: bytes 0x00, 0x01, … 0x1f.
    pub fn test_key() -> Psk {
        let mut k = [0u8; PSK_LEN];
        for (i, b) in k.iter_mut().enumerate() {
            *b = i as u8;
        }
        Psk(k)
    }

    /// A fresh random key (from the kernel's CSPRNG).
    pub fn generate() -> std::io::Result<Psk> {
        let mut k = [0u8; PSK_LEN];
        fill_random(&mut k)?;
        Ok(Psk(k))
    }

    /// 64 lowercase hex digits.
    pub fn to_hex(&self) -> String {
        hex(&self.0)
    }

    /// Parse 64 hex digits (surrounding white space ignored).
    pub fn parse_hex(s: &str) -> Result<Psk, KeyError> {
        let s = s.trim();
        if s.len() != PSK_LEN * 2 || !s.is_ascii() {
            return Err(KeyError::Format);
        }
        let mut k = [0u8; PSK_LEN];
        for (i, b) in k.iter_mut().enumerate() {
            let d = s.get(2 * i..2 * i + 2).ok_or(KeyError::Format)?;
            *b = u8::from_str_radix(d, 16).map_err(|_| KeyError::Format)?;
        }
        Ok(Psk(k))
    }

    /// Read a key file: 64 hex digits, and on Unix a mode without any group
    /// or other permission (like ssh's private keys).
    pub fn load(path: &Path) -> Result<Psk, KeyError> {
        let mut f = std::fs::File::open(path).map_err(KeyError::Io)?;
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = f.metadata().map_err(KeyError::Io)?.permissions().mode() & 0o7777;
            if mode & 0o077 != 0 {
                return Err(KeyError::Permissions(mode));
            }
        }
        let mut s = String::new();
        f.by_ref()
            .take(256)
            .read_to_string(&mut s)
            .map_err(|_| KeyError::Format)?;
        Psk::parse_hex(&s)
    }

    /// Write a new key file with mode 0600; fails if `path` exists.
    pub fn write_new(&self, path: &Path) -> std::io::Result<()> {
        use std::io::Write;
        let mut o = std::fs::OpenOptions::new();
        o.write(true).create_new(true);
        #[cfg(unix)]
        {
            use std::os::unix::fs::OpenOptionsExt;
            o.mode(0o600);
        }
        let mut f = o.open(path)?;
        writeln!(f, "{}", self.to_hex())?;
        f.sync_all()
    }
}

/// Lowercase hex of `b`.
pub fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

/// Fill `out` from the kernel's CSPRNG (`/dev/urandom`).
pub fn fill_random(out: &mut [u8]) -> std::io::Result<()> {
    std::fs::File::open("/dev/urandom")?.read_exact(out)
}

/// A fresh handshake nonce.
pub fn fresh_nonce() -> std::io::Result<[u8; NONCE_LEN]> {
    let mut n = [0u8; NONCE_LEN];
    fill_random(&mut n)?;
    Ok(n)
}

/// Key of the client's `open_session`: HMAC(PSK, "hapticctrl v2 open").
pub fn open_key(psk: &Psk) -> Key {
    hmac(&psk.0, &[LABEL_OPEN])
}

/// Key of the bridge's refusal of an `open_session` (bound to its nonce):
/// HMAC(PSK, "hapticctrl v2 refuse" ‖ Nc).
pub fn refuse_key(psk: &Psk, nc: &[u8; NONCE_LEN]) -> Key {
    hmac(&psk.0, &[LABEL_REFUSE, nc])
}

/// An HMAC-SHA-256 instance already keyed (its inner and outer pads
/// hashed once), cloned for each frame.
fn keyed(key: &[u8]) -> HmacSha256 {
    <HmacSha256 as Mac>::new_from_slice(key).expect("HMAC takes any key length")
}

/// The two directional keys of one session.
#[derive(Clone)]
pub struct SessionKeys {
    /// Client → controller: HMAC(PSK, "hapticctrl v2 c2s" ‖ Nc ‖ Ns).
    pub c2s: Key,
    /// Controller → client: HMAC(PSK, "hapticctrl v2 s2c" ‖ Nc ‖ Ns).
    pub s2c: Key,
    c2s_mac: HmacSha256,
    s2c_mac: HmacSha256,
}

impl PartialEq for SessionKeys {
    fn eq(&self, o: &Self) -> bool {
        self.c2s == o.c2s && self.s2c == o.s2c
    }
}

impl Eq for SessionKeys {}

impl std::fmt::Debug for SessionKeys {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("SessionKeys(..)")
    }
}

impl SessionKeys {
    pub fn derive(psk: &Psk, nc: &[u8; NONCE_LEN], ns: &[u8; NONCE_LEN]) -> SessionKeys {
        let c2s = hmac(&psk.0, &[LABEL_C2S, nc, ns]);
        let s2c = hmac(&psk.0, &[LABEL_S2C, nc, ns]);
        SessionKeys {
            c2s_mac: keyed(&c2s),
            s2c_mac: keyed(&s2c),
            c2s,
            s2c,
        }
    }
}

/// Tag length of a v2 frame of type `ty`.
pub const fn tag_len(ty: FrameType) -> usize {
    match ty {
        FrameType::Answer => ANSWER_TAG_LEN,
        _ => TAG_LEN,
    }
}

/// Payload length of a v2 frame of type `ty`.
pub const fn payload_len(ty: FrameType) -> usize {
    match ty {
        FrameType::OpenSession => NONCE_LEN,
        FrameType::SessionAck => 2 * NONCE_LEN + 4,
        // pose, wrench, state word, VPr seq (the cycle is in the header)
        FrameType::Answer => 28 + 24 + 8,
        // twist, state word, VPr seq
        FrameType::AnswerTwist => 24 + 8,
        t => t.payload_len(),
    }
}

/// Whole length of a v2 frame of type `ty` (≤ 90 for every type).
pub const fn frame_len(ty: FrameType) -> usize {
    HEADER_LEN + payload_len(ty) + tag_len(ty)
}

/// Why a datagram was refused. Every refusal is counted by reason.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Refusal {
    /// More than 90 bytes.
    Oversize,
    /// Fewer than the smallest frame.
    Undersize,
    /// Not "HC".
    BadMagic,
    /// A version-1 (unauthenticated) frame and the bridge is not `--insecure`.
    Unauthenticated,
    /// Another version.
    BadVersion,
    /// Unknown frame type.
    UnknownType,
    /// A controller-only frame type.
    NotARequest,
    /// Length ≠ the type's v2 length.
    LengthMismatch,
    /// No session: a request other than `open_session` without a handshake.
    NoSession,
    /// The tag does not verify (wrong key, forged or corrupted frame).
    BadTag,
    /// An `open_session` whose nonce was already used.
    HandshakeReplay,
    /// A verified frame carrying another session's id.
    WrongSession,
    /// A sequence number already accepted in this session.
    Replay,
    /// A sequence number older than the anti-replay window.
    TooOld,
    /// Verified, but the payload does not decode (answered with `error`).
    Malformed,
    /// From an address other than the session's client (bridge policy).
    StraySource,
    /// Dropped unverified: the source sent too many refused datagrams.
    RateLimited,
}

impl Refusal {
    pub const COUNT: usize = 17;
    pub const ALL: [Refusal; Refusal::COUNT] = [
        Refusal::Oversize,
        Refusal::Undersize,
        Refusal::BadMagic,
        Refusal::Unauthenticated,
        Refusal::BadVersion,
        Refusal::UnknownType,
        Refusal::NotARequest,
        Refusal::LengthMismatch,
        Refusal::NoSession,
        Refusal::BadTag,
        Refusal::HandshakeReplay,
        Refusal::WrongSession,
        Refusal::Replay,
        Refusal::TooOld,
        Refusal::Malformed,
        Refusal::StraySource,
        Refusal::RateLimited,
    ];

    pub const fn index(self) -> usize {
        self as usize
    }

    /// Counter name (`rejected_<name>` in the bridge's stats).
    pub const fn name(self) -> &'static str {
        match self {
            Refusal::Oversize => "oversize",
            Refusal::Undersize => "undersize",
            Refusal::BadMagic => "bad_magic",
            Refusal::Unauthenticated => "unauthenticated_v1",
            Refusal::BadVersion => "bad_version",
            Refusal::UnknownType => "unknown_type",
            Refusal::NotARequest => "not_a_request",
            Refusal::LengthMismatch => "length_mismatch",
            Refusal::NoSession => "no_session",
            Refusal::BadTag => "bad_tag",
            Refusal::HandshakeReplay => "handshake_replay",
            Refusal::WrongSession => "wrong_session",
            Refusal::Replay => "replay",
            Refusal::TooOld => "too_old",
            Refusal::Malformed => "malformed",
            Refusal::StraySource => "stray_source",
            Refusal::RateLimited => "rate_limited",
        }
    }
}

fn tag(mac: &HmacSha256, body: &[u8], len: usize) -> [u8; TAG_LEN] {
    let mut m = mac.clone();
    m.update(body);
    let full: Key = m.finalize().into_bytes().into();
    let mut t = [0u8; TAG_LEN];
    for (d, s) in t.iter_mut().zip(full.iter()).take(len) {
        *d = *s;
    }
    t
}

/// Verify the tag at the end of `frame` (its length already checked) in
/// constant time.
fn verify(mac: &HmacSha256, frame: &[u8], tlen: usize) -> bool {
    let Some(body_len) = frame.len().checked_sub(tlen) else {
        return false;
    };
    let (body, t) = frame.split_at(body_len);
    let mut m = mac.clone();
    m.update(body);
    m.verify_truncated_left(t).is_ok()
}

/// A v2 frame under construction or received: at most 90 bytes.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Wire {
    pub buf: [u8; MAX_FRAME_LEN],
    pub len: usize,
}

impl std::fmt::Debug for Wire {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Wire({})", hex(self.bytes()))
    }
}

impl Wire {
    pub fn bytes(&self) -> &[u8] {
        &self.buf[..self.len]
    }
}

fn be32(b: &[u8], at: usize) -> u32 {
    u32::from_be_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

/// Seal `header ‖ payload` of type `ty` under `key`.
pub fn seal_raw(key: &Key, ty: FrameType, h: &FrameHeader, payload: &[u8]) -> Wire {
    seal_with(&keyed(key), ty, h, payload)
}

fn seal_with(mac: &HmacSha256, ty: FrameType, h: &FrameHeader, payload: &[u8]) -> Wire {
    let mut w = Wire {
        buf: [0u8; MAX_FRAME_LEN],
        len: frame_len(ty),
    };
    debug_assert_eq!(payload.len(), payload_len(ty));
    write_header(&mut w.buf, VERSION, ty, h);
    let body = HEADER_LEN + payload.len();
    w.buf[HEADER_LEN..body].copy_from_slice(payload);
    let t = tag(mac, &w.buf[..body], tag_len(ty));
    let tl = tag_len(ty);
    w.buf[body..body + tl].copy_from_slice(&t[..tl]);
    w.len = body + tl;
    w
}

/// The client's `open_session` (session 0, payload Nc) under [`open_key`].
pub fn seal_open(psk: &Psk, h: &FrameHeader, nc: &[u8; NONCE_LEN]) -> Wire {
    seal_raw(&open_key(psk), FrameType::OpenSession, h, nc)
}

/// A client request other than `open_session`, under the session's c2s key:
/// the same header and payload bytes as hap-core's v1 encoding.
pub fn seal_request(keys: &SessionKeys, h: &FrameHeader, frame: &Frame) -> Option<Wire> {
    let ty = frame.frame_type();
    if !ty.is_request() || ty == FrameType::OpenSession {
        return None;
    }
    let mut v1 = [0u8; MAX_FRAME_LEN];
    let n = hap_core::protocol::encode(h, frame, &mut v1);
    let payload = v1.get(HEADER_LEN..n.checked_sub(4)?)?;
    Some(seal_with(&keys.c2s_mac, ty, h, payload))
}

/// The controller's `session_ack` for Nc/Ns under the session's s2c key.
pub fn seal_session_ack(
    keys: &SessionKeys,
    h: &FrameHeader,
    nc: &[u8; NONCE_LEN],
    ns: &[u8; NONCE_LEN],
    period_us: u32,
) -> Wire {
    let mut p = [0u8; 2 * NONCE_LEN + 4];
    p[..NONCE_LEN].copy_from_slice(nc);
    p[NONCE_LEN..2 * NONCE_LEN].copy_from_slice(ns);
    p[2 * NONCE_LEN..].copy_from_slice(&period_us.to_be_bytes());
    seal_with(&keys.s2c_mac, FrameType::SessionAck, h, &p)
}

/// The bridge's `error` refusing an authenticated `open_session` (reason
/// `ERROR_REFUSED`: another client holds the session), under [`refuse_key`].
pub fn seal_refusal(psk: &Psk, nc: &[u8; NONCE_LEN], h: &FrameHeader, rejected_seq: u32) -> Wire {
    let mut p = [0u8; 8];
    p[..4].copy_from_slice(&ERROR_REFUSED.to_be_bytes());
    p[4..].copy_from_slice(&rejected_seq.to_be_bytes());
    seal_raw(&refuse_key(psk, nc), FrameType::Error, h, &p)
}

/// Turn a v1 controller frame read from the kernel (answer, answer twist,
/// ack, error) into its v2 form under `s2c`. `None` for anything else
/// (a session_ack is built with [`seal_session_ack`]).
pub fn seal_reply_from_v1(s2c: &Key, v1: &[u8]) -> Option<Wire> {
    seal_reply_with(&keyed(s2c), v1)
}

fn seal_reply_with(s2c: &HmacSha256, v1: &[u8]) -> Option<Wire> {
    let (h, f) = decode(v1).ok()?;
    let ty = f.frame_type();
    let state = |status: u32, alarms: u32| ((alarms & 0xFFFF) << 16) | (status & 0xFFFF);
    match f {
        Frame::Answer(a) => {
            // v1 payload: pose 16..44, wrench 44..68, status, alarms, cycle, vpr_seq.
            let mut p = [0u8; 60];
            p[..52].copy_from_slice(v1.get(16..68)?);
            p[52..56].copy_from_slice(&state(a.status, a.alarms).to_be_bytes());
            p[56..60].copy_from_slice(&a.vpr_seq.to_be_bytes());
            let h2 = FrameHeader {
                timestamp_us: a.cycle,
                ..h
            };
            Some(seal_with(s2c, ty, &h2, &p))
        }
        Frame::AnswerTwist(a) => {
            let mut p = [0u8; 32];
            p[..24].copy_from_slice(v1.get(16..40)?);
            p[24..28].copy_from_slice(&state(a.status, a.alarms).to_be_bytes());
            p[28..32].copy_from_slice(&a.vpr_seq.to_be_bytes());
            let h2 = FrameHeader {
                timestamp_us: a.cycle,
                ..h
            };
            Some(seal_with(s2c, ty, &h2, &p))
        }
        Frame::Ack { .. } | Frame::Error { .. } => {
            let end = v1.len().checked_sub(4)?;
            Some(seal_with(s2c, ty, &h, v1.get(HEADER_LEN..end)?))
        }
        _ => None,
    }
}

/// The v1 frame (what the kernel reads) carrying the same header and
/// payload as a verified v2 request; `timestamp`/`nonce` as given.
fn v1_from_payload(ty: FrameType, h: &FrameHeader, payload: &[u8]) -> Option<Wire> {
    let len = ty.frame_len();
    let mut w = Wire {
        buf: [0u8; MAX_FRAME_LEN],
        len,
    };
    write_header(&mut w.buf, hap_core::protocol::VERSION, ty, h);
    w.buf
        .get_mut(HEADER_LEN..HEADER_LEN + payload.len())?
        .copy_from_slice(payload);
    if !seal_crc(w.buf.get_mut(..len)?) {
        return None;
    }
    Some(w)
}

/// First checks common to both sides: size, magic, version, type, length.
/// Returns the type.
fn precheck(b: &[u8], insecure_v1_ok: bool) -> Result<FrameType, Refusal> {
    if b.len() > MAX_FRAME_LEN {
        return Err(Refusal::Oversize);
    }
    if b.len() < HEADER_LEN + 4 {
        return Err(Refusal::Undersize);
    }
    if b[0..2] != MAGIC {
        return Err(Refusal::BadMagic);
    }
    if b[2] == hap_core::protocol::VERSION && !insecure_v1_ok {
        return Err(Refusal::Unauthenticated);
    }
    if b[2] != VERSION {
        return Err(Refusal::BadVersion);
    }
    let ty = FrameType::from_u8(b[3]).ok_or(Refusal::UnknownType)?;
    if b.len() != frame_len(ty) {
        return Err(Refusal::LengthMismatch);
    }
    Ok(ty)
}

/// What kind of request a verified datagram is (for the bridge's session
/// pinning).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    Open,
    Close,
    Other,
}

/// A client datagram that passed every check of [`Gate::inspect`]; hand it
/// back to [`Gate::commit`] once the bridge's address policy admits it.
#[derive(Clone, Copy, Debug)]
pub struct Inspected {
    pub kind: Kind,
    pub header: FrameHeader,
    ty: FrameType,
    nc: [u8; NONCE_LEN],
    wire: Wire,
}

/// What the bridge does with a committed datagram.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Action {
    /// Write this v1 frame to the kernel's input device.
    Forward(Wire),
    /// Send this v2 frame back to the client, write nothing (a replayed
    /// acknowledged request: its ack again; an authenticated but malformed
    /// request: `error` with the decode reason).
    Reply(Wire, Refusal),
}

/// Counters of the gate (the bridge renders them).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct GateCounters {
    pub verified: u64,
    pub handshakes: u64,
    /// Replayed acknowledged requests answered with their ack again.
    pub reacked: u64,
    /// Replies the kernel sent that could not be sealed (no session keys).
    pub replies_unsealed: u64,
}

#[derive(Clone, Debug)]
struct GateSession {
    nc: [u8; NONCE_LEN],
    ns: [u8; NONCE_LEN],
    keys: SessionKeys,
    /// Granted by the kernel (0 until its session_ack).
    id: u16,
    kernel_nonce: u32,
    window: SeqWindow,
    closed: bool,
    /// Sealed acks of the last acknowledged requests: (seq, type, bytes).
    acks: [Option<(u32, FrameType, Wire)>; ACK_MEMORY],
    acks_next: usize,
}

/// The bridge's authenticator: one session (the kernel has one), the PSK,
/// the nonces already used.
pub struct Gate {
    psk: Psk,
    k_open: HmacSha256,
    session: Option<GateSession>,
    nonces: Vec<[u8; NONCE_LEN]>,
    nonces_next: usize,
    kernel_nonce: u32,
    pub counters: GateCounters,
}

impl std::fmt::Debug for Gate {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Gate")
            .field("session", &self.session.as_ref().map(|s| s.id))
            .finish()
    }
}

impl Gate {
    pub fn new(psk: Psk) -> Gate {
        Gate {
            k_open: keyed(&open_key(&psk)),
            psk,
            session: None,
            nonces: Vec::new(),
            nonces_next: 0,
            kernel_nonce: 0,
            counters: GateCounters::default(),
        }
    }

    /// The session id the kernel granted (0: none or not yet).
    pub fn session_id(&self) -> u16 {
        self.session
            .as_ref()
            .filter(|s| !s.closed)
            .map_or(0, |s| s.id)
    }

    /// Forget the session (the bridge's session expired).
    pub fn end_session(&mut self) {
        if let Some(s) = self.session.as_mut() {
            s.closed = true;
        }
    }

    /// Check a client datagram without changing anything: size, version,
    /// type, session id, anti-replay window, then the tag (constant time). The
    /// handshake nonce is checked against the nonces already used.
    pub fn inspect(&self, b: &[u8]) -> Result<Inspected, Refusal> {
        let ty = precheck(b, false)?;
        if !ty.is_request() {
            return Err(Refusal::NotARequest);
        }
        let header = read_header(b).ok_or(Refusal::Undersize)?;
        let mut wire = Wire {
            buf: [0u8; MAX_FRAME_LEN],
            len: b.len(),
        };
        wire.buf[..b.len()].copy_from_slice(b);
        if ty == FrameType::OpenSession {
            if !verify(&self.k_open, b, TAG_LEN) {
                return Err(Refusal::BadTag);
            }
            let mut nc = [0u8; NONCE_LEN];
            nc.copy_from_slice(&b[HEADER_LEN..HEADER_LEN + NONCE_LEN]);
            if self.nonces.contains(&nc) {
                return Err(Refusal::HandshakeReplay);
            }
            return Ok(Inspected {
                kind: Kind::Open,
                header,
                ty,
                nc,
                wire,
            });
        }
        let Some(s) = self.session.as_ref().filter(|s| !s.closed) else {
            return Err(Refusal::NoSession);
        };
        // The session id and the sequence number are sent in clear: what
        // they refuse is refused before the tag is computed (a datagram for
        // another session or behind the window costs no HMAC), and the
        // refusal tells an onlooker nothing the header did not.
        if header.session != s.id || s.id == 0 {
            return Err(Refusal::WrongSession);
        }
        match s.window.check(header.seq) {
            SeqCheck::Newer | SeqCheck::InWindow => {}
            SeqCheck::Duplicate => {
                let reack = header.control & CTRL_ACK_REQUEST != 0
                    && s.acks
                        .iter()
                        .flatten()
                        .any(|(q, t, _)| *q == header.seq && *t == ty);
                if !reack {
                    return Err(Refusal::Replay);
                }
            }
            SeqCheck::TooOld => return Err(Refusal::TooOld),
        }
        if !verify(&s.keys.c2s_mac, b, TAG_LEN) {
            return Err(Refusal::BadTag);
        }
        Ok(Inspected {
            kind: if ty == FrameType::CloseSession {
                Kind::Close
            } else {
                Kind::Other
            },
            header,
            ty,
            nc: [0u8; NONCE_LEN],
            wire,
        })
    }

    /// Commit an inspected datagram: for `open_session`, remember its nonce,
    /// draw the server nonce `ns` and derive the session keys; for a request,
    /// advance the window. Returns the v1 frame to forward, or the reply.
    pub fn commit(&mut self, i: &Inspected, ns: [u8; NONCE_LEN]) -> Action {
        self.counters.verified = self.counters.verified.saturating_add(1);
        let b = i.wire.bytes();
        if i.kind == Kind::Open {
            if self.nonces.len() < NONCE_MEMORY {
                self.nonces.push(i.nc);
            } else if let Some(slot) = self.nonces.get_mut(self.nonces_next) {
                *slot = i.nc;
            }
            self.nonces_next = (self.nonces_next + 1) % NONCE_MEMORY;
            self.kernel_nonce = self.kernel_nonce.wrapping_add(1);
            let mut window = SeqWindow::new();
            window.reset(i.header.seq);
            self.session = Some(GateSession {
                nc: i.nc,
                ns,
                keys: SessionKeys::derive(&self.psk, &i.nc, &ns),
                id: 0,
                kernel_nonce: self.kernel_nonce,
                window,
                closed: false,
                acks: [None; ACK_MEMORY],
                acks_next: 0,
            });
            self.counters.handshakes = self.counters.handshakes.saturating_add(1);
            let h = FrameHeader {
                session: 0,
                ..i.header
            };
            let v1 = v1_from_payload(FrameType::OpenSession, &h, &self.kernel_nonce.to_be_bytes());
            return match v1 {
                Some(w) => Action::Forward(w),
                None => self.malformed_reply(i, DecodeError::LengthMismatch),
            };
        }
        let Some(s) = self.session.as_mut() else {
            // inspect() saw a session; commit() right after cannot miss it.
            return self.malformed_reply(i, DecodeError::TooShort);
        };
        if s.window.check(i.header.seq) == SeqCheck::Duplicate {
            if let Some((_, _, w)) = s
                .acks
                .iter()
                .flatten()
                .find(|(q, t, _)| *q == i.header.seq && *t == i.ty)
            {
                let w = *w;
                self.counters.reacked = self.counters.reacked.saturating_add(1);
                return Action::Reply(w, Refusal::Replay);
            }
        }
        s.window.accept(i.header.seq);
        let end = b.len().saturating_sub(TAG_LEN);
        let v1 = v1_from_payload(i.ty, &i.header, b.get(HEADER_LEN..end).unwrap_or(&[]));
        let Some(v1) = v1 else {
            return self.malformed_reply(i, DecodeError::LengthMismatch);
        };
        match decode(v1.bytes()) {
            Ok(_) => Action::Forward(v1),
            Err(e) => self.malformed_reply(i, e),
        }
    }

    fn malformed_reply(&mut self, i: &Inspected, e: DecodeError) -> Action {
        let h = FrameHeader {
            control: 0,
            session: i.header.session,
            seq: 0,
            timestamp_us: 0,
        };
        let mut p = [0u8; 8];
        p[..4].copy_from_slice(&(e.reason_index() as u32).to_be_bytes());
        p[4..].copy_from_slice(&i.header.seq.to_be_bytes());
        let key = match self.session.as_ref() {
            Some(s) if i.kind != Kind::Open => s.keys.s2c,
            _ => refuse_key(&self.psk, &i.nc),
        };
        Action::Reply(seal_raw(&key, FrameType::Error, &h, &p), Refusal::Malformed)
    }

    /// The reply refusing an authenticated `open_session` (another client
    /// holds the session): `error` `ERROR_REFUSED`, sealed with the key bound
    /// to its nonce. `seq`/`timestamp_us` are the bridge's.
    pub fn refusal(&self, i: &Inspected, seq: u32, timestamp_us: u32) -> Option<Wire> {
        if i.kind != Kind::Open {
            return None;
        }
        let h = FrameHeader {
            control: 0,
            session: 0,
            seq,
            timestamp_us,
        };
        Some(seal_refusal(&self.psk, &i.nc, &h, i.header.seq))
    }

    /// Seal a v1 frame the kernel wrote on its output device for the client.
    /// The kernel's `session_ack` for the pending handshake becomes the v2
    /// `session_ack` (and fixes the session id); answers, acks and errors are
    /// sealed under the session's s2c key. `None`: nothing to send.
    pub fn seal_from_kernel(&mut self, v1: &[u8]) -> Option<Wire> {
        let Ok((h, f)) = decode(v1) else {
            self.counters.replies_unsealed = self.counters.replies_unsealed.saturating_add(1);
            return None;
        };
        let Some(s) = self.session.as_mut() else {
            self.counters.replies_unsealed = self.counters.replies_unsealed.saturating_add(1);
            return None;
        };
        if let Frame::SessionAck {
            client_nonce,
            period_us,
        } = f
        {
            if client_nonce != s.kernel_nonce {
                return None; // the ack of an earlier handshake
            }
            s.id = h.session;
            return Some(seal_session_ack(&s.keys, &h, &s.nc, &s.ns, period_us));
        }
        let w = seal_reply_with(&s.keys.s2c_mac, v1)?;
        if let Frame::Ack {
            acked_type,
            acked_seq,
        } = f
        {
            if let Some(slot) = s.acks.get_mut(s.acks_next) {
                *slot = Some((acked_seq, acked_type, w));
            }
            s.acks_next = (s.acks_next + 1) % ACK_MEMORY;
        }
        Some(w)
    }
}

/// A reply the client verified.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reply {
    /// The handshake completed: the session id is in the header.
    SessionAck { period_us: u32 },
    /// Any other controller frame, as hap-core decodes its v1 form
    /// (answers carry the cycle from the header's timestamp field).
    Frame(Frame),
    /// The bridge refused the handshake (`error` under the refusal key).
    HandshakeRefused { reason: u32 },
}

/// The client's side: the PSK, the pending handshake and the session keys.
#[derive(Clone, Debug)]
pub struct ClientAuth {
    psk: Psk,
    pending: Option<[u8; NONCE_LEN]>,
    keys: Option<SessionKeys>,
}

impl ClientAuth {
    pub fn new(psk: Psk) -> ClientAuth {
        ClientAuth {
            psk,
            pending: None,
            keys: None,
        }
    }

    /// Start a handshake with the nonce `nc` (fresh for every attempt: the
    /// bridge refuses a nonce it has seen). Returns the `open_session`.
    pub fn hello(&mut self, h: &FrameHeader, nc: [u8; NONCE_LEN]) -> Wire {
        self.pending = Some(nc);
        let h = FrameHeader { session: 0, ..*h };
        seal_open(&self.psk, &h, &nc)
    }

    pub fn established(&self) -> bool {
        self.keys.is_some()
    }

    /// Seal a request (not `open_session`) under the session key.
    pub fn seal(&self, h: &FrameHeader, f: &Frame) -> Option<Wire> {
        seal_request(self.keys.as_ref()?, h, f)
    }

    /// Verify and decode a datagram from the controller.
    pub fn open(&mut self, b: &[u8]) -> Result<(FrameHeader, Reply), Refusal> {
        let ty = precheck(b, false)?;
        if ty.is_request() {
            return Err(Refusal::NotARequest);
        }
        let h = read_header(b).ok_or(Refusal::Undersize)?;
        let tl = tag_len(ty);
        if ty == FrameType::SessionAck {
            let nc = self.pending.ok_or(Refusal::NoSession)?;
            if b[HEADER_LEN..HEADER_LEN + NONCE_LEN] != nc {
                return Err(Refusal::BadTag);
            }
            let mut ns = [0u8; NONCE_LEN];
            ns.copy_from_slice(&b[HEADER_LEN + NONCE_LEN..HEADER_LEN + 2 * NONCE_LEN]);
            let keys = SessionKeys::derive(&self.psk, &nc, &ns);
            if !verify(&keys.s2c_mac, b, tl) {
                return Err(Refusal::BadTag);
            }
            let period_us = be32(b, HEADER_LEN + 2 * NONCE_LEN);
            self.keys = Some(keys);
            self.pending = None;
            return Ok((h, Reply::SessionAck { period_us }));
        }
        if ty == FrameType::Error && h.session == 0 {
            if let Some(nc) = self.pending {
                if verify(&keyed(&refuse_key(&self.psk, &nc)), b, tl) {
                    return Ok((
                        h,
                        Reply::HandshakeRefused {
                            reason: be32(b, HEADER_LEN),
                        },
                    ));
                }
            }
        }
        let keys = self.keys.as_ref().ok_or(Refusal::NoSession)?;
        if !verify(&keys.s2c_mac, b, tl) {
            return Err(Refusal::BadTag);
        }
        // Back to the v1 layout, then hap-core's decoder checks the payload.
        let body = b.len() - tl;
        let mut v1 = [0u8; MAX_FRAME_LEN];
        let n = ty.frame_len();
        let mut hv1 = h;
        match ty {
            FrameType::Answer | FrameType::AnswerTwist => {
                let (keep, state_at) = if ty == FrameType::Answer {
                    (52, HEADER_LEN + 52)
                } else {
                    (24, HEADER_LEN + 24)
                };
                let state = be32(b, state_at);
                let vpr_seq = be32(b, state_at + 4);
                let mut p = [0u8; 68];
                p[..keep].copy_from_slice(&b[HEADER_LEN..HEADER_LEN + keep]);
                p[keep..keep + 4].copy_from_slice(&(state & 0xFFFF).to_be_bytes());
                p[keep + 4..keep + 8].copy_from_slice(&(state >> 16).to_be_bytes());
                p[keep + 8..keep + 12].copy_from_slice(&h.timestamp_us.to_be_bytes());
                p[keep + 12..keep + 16].copy_from_slice(&vpr_seq.to_be_bytes());
                hv1.timestamp_us = h.timestamp_us;
                let w = v1_from_payload(ty, &hv1, &p[..keep + 16]).ok_or(Refusal::Malformed)?;
                v1[..n].copy_from_slice(w.bytes());
            }
            _ => {
                let w =
                    v1_from_payload(ty, &hv1, &b[HEADER_LEN..body]).ok_or(Refusal::Malformed)?;
                v1[..n].copy_from_slice(w.bytes());
            }
        }
        let (_, f) = decode(&v1[..n]).map_err(|_| Refusal::Malformed)?;
        Ok((h, Reply::Frame(f)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_v2_frame_fits_in_90_bytes() {
        for ty in FrameType::ALL {
            assert!(frame_len(ty) <= MAX_FRAME_LEN, "{ty:?} {}", frame_len(ty));
            assert_eq!(payload_len(ty) % 4, 0);
        }
        assert_eq!(frame_len(FrameType::VprStream), 84);
        assert_eq!(frame_len(FrameType::Answer), 88);
    }

    #[test]
    fn refusal_indices_and_names() {
        let mut names = std::collections::HashSet::new();
        for (i, r) in Refusal::ALL.iter().enumerate() {
            assert_eq!(r.index(), i);
            assert!(names.insert(r.name()), "{}", r.name());
        }
    }

    #[test]
    fn hex_round_trip_and_bad_keys() {
        let k = Psk::test_key();
        assert_eq!(Psk::parse_hex(&k.to_hex()).unwrap(), k);
        assert!(Psk::parse_hex("00").is_err());
        assert!(Psk::parse_hex(&"zz".repeat(32)).is_err());
        assert_eq!(format!("{k:?}"), "Psk(..)");
    }

    #[test]
    fn hmac_matches_rfc4231_case_2() {
        // RFC 4231 test case 2: key "Jefe", data "what do ya want for nothing?".
        let t = hmac(b"Jefe", &[b"what do ya want ", b"for nothing?"]);
        assert_eq!(
            hex(&t),
            "5bdcc146bf60754e6a042426089575c75a003f089d2739839dec58b964ec3843"
        );
    }
}
