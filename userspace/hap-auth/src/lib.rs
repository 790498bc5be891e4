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
//! - Handshake (protocol.md §7.4): `open_session` → `cookie` (the bridge's
//!   nonce, an HMAC under its per-process secret of the client's address,
//!   a 5 s epoch and the client's nonce: no state kept) → `open_proof` (the
//!   client's proof of the key over it) → `session_ack`. Nothing is
//!   committed before the proof; accepted proofs are remembered for the
//!   cookie's lifetime, answered `open_session` nonces for
//!   [`HELLO_MEMORY_S`], and a proof commits only forward: from the live
//!   session's client address, only a newer one than the session's own.
//! - [`Gate`]: the bridge's side. Every client datagram is checked (length,
//!   tag, cookie, session, anti-replay window) before the bridge turns it
//!   into the v1 frame the kernel reads; every refusal has a [`Refusal`]
//!   reason. The budgets that ration what verified handshakes may cost live
//!   in the bridge (`proto_interface`'s `ratelimit`).
//! - [`ClientAuth`]: the client's side (handshake, sealing requests,
//!   verifying replies).
//!
//! The kernel never sees v2: the bridge forwards only frames it verified,
//! re-encoded as v1 (same header fields, same payload bytes, CRC-32C).

use std::io::Read;
use std::net::{IpAddr, SocketAddr};
use std::path::Path;
use std::time::Duration;

use hap_core::protocol::{
    decode, read_header, seal_crc, seq_newer, write_header, DecodeError, Frame, FrameHeader,
    FrameType, SeqCheck, SeqWindow, CTRL_ACK_REQUEST, ERROR_NO_SESSION, ERROR_REFUSED, HEADER_LEN,
    MAGIC, MAX_FRAME_LEN,
};
use hmac::{Hmac, KeyInit, Mac};
use sha2::Sha256;
use zeroize::{Zeroize, ZeroizeOnDrop, Zeroizing};

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
/// Frame type of the bridge's `cookie` (v2 only; the answer to `open_session`).
pub const TYPE_COOKIE: u8 = 0x90;
/// Frame type of the client's `open_proof` (v2 only; the answer to `cookie`).
pub const TYPE_OPEN_PROOF: u8 = 0x10;
/// Payload of `cookie` and `open_proof`: Nc, Ns, epoch (u32).
pub const PROOF_PAYLOAD_LEN: usize = 2 * NONCE_LEN + 4;
/// Whole length of `cookie` and `open_proof`.
pub const PROOF_FRAME_LEN: usize = HEADER_LEN + PROOF_PAYLOAD_LEN + TAG_LEN;
/// Length of a cookie epoch, seconds. A cookie is accepted in its own epoch
/// and the next one: for at least one and at most two epochs.
pub const COOKIE_EPOCH_S: u64 = 5;
/// Accepted proofs the bridge remembers (each for the lifetime of its
/// cookie, at most two epochs: 16384 in 10 s is about 1600 proven
/// handshakes a second, three times the default `--handshake-budget`); a
/// proof beyond that is refused (`handshake_busy`), nothing is forgotten
/// early. About 0.7 MB when full.
pub const PROOF_MEMORY: usize = 16384;
/// How long the bridge remembers the client nonce (`Nc`) of every
/// `open_session` it answered with a cookie, seconds: a copy of that
/// `open_session`, from any address, draws nothing in that time
/// (`hello_replay`). A client whose cookie went missing starts a new
/// attempt with a new nonce.
pub const HELLO_MEMORY_S: u64 = 600;
/// Answered `open_session` nonces the bridge remembers at most (about
/// 1 MB when full; beyond, the oldest is forgotten first).
pub const HELLO_MEMORY: usize = 16384;
/// The sequence span one direction of a session may cover: half the
/// sequence-number space, so that serial-number comparison stays
/// meaningful for the whole session. The span is counted from the first
/// number of the session (the client's `open_proof`, the kernel's
/// `session_ack`) to the newest, whatever the steps between them: a sender
/// that skips numbers spends them. The bridge ends a session whose
/// direction would reach it (`ERROR_SEQ_EXHAUSTED`); the client opens a new
/// one.
pub const SESSION_SEQ_SPAN: u64 = 1 << 31;
/// The bridge's largest answer to a source not yet proven, as a multiple
/// of the bytes received from it (QUIC's anti-amplification rule).
pub const AMPLIFICATION_FACTOR: usize = 3;

/// `error` reason: the session was replaced by a newer proven handshake.
pub const ERROR_REPLACED: u32 = 0x102;
/// `error` reason: the session expired (the client was silent too long).
pub const ERROR_EXPIRED: u32 = 0x103;
/// `error` reason: a direction reached [`SESSION_SEQ_SPAN`]; open anew.
pub const ERROR_SEQ_EXHAUSTED: u32 = 0x104;

/// KDF labels (ASCII, no terminator).
pub const LABEL_OPEN: &[u8] = b"hapticctrl v2 open";
pub const LABEL_COOKIE: &[u8] = b"hapticctrl v2 cookie";
pub const LABEL_PROOF: &[u8] = b"hapticctrl v2 proof";
pub const LABEL_NS: &[u8] = b"hapticctrl v2 ns";
pub const LABEL_C2S: &[u8] = b"hapticctrl v2 c2s";
pub const LABEL_S2C: &[u8] = b"hapticctrl v2 s2c";
pub const LABEL_REFUSE: &[u8] = b"hapticctrl v2 refuse";

type HmacSha256 = Hmac<Sha256>;

/// A 32-byte MAC or derivation key.
pub type Key = [u8; 32];

/// HMAC-SHA-256 of the concatenation of `parts` under `key` (wiped when
/// dropped: most are keys).
pub fn hmac(key: &[u8], parts: &[&[u8]]) -> Zeroizing<Key> {
    prf(&keyed(key), parts)
}

/// HMAC-SHA-256 of the concatenation of `parts` under an already keyed
/// state, which is kept for the next call (the clone used here is wiped
/// when dropped, as every HMAC state is: `hmac`'s `zeroize` feature).
fn prf(mac: &HmacSha256, parts: &[&[u8]]) -> Zeroizing<Key> {
    let mut m = mac.clone();
    for p in parts {
        m.update(p);
    }
    let mut key = Zeroizing::new([0u8; 32]);
    let out: &mut hmac::digest::Output<HmacSha256> = (&mut *key).into();
    hmac::digest::FixedOutput::finalize_into(m, out);
    key
}

/// The pre-shared key: not `Copy`, wiped from memory when dropped, never
/// printed by `Debug`.
#[derive(Clone, PartialEq, Eq, Zeroize, ZeroizeOnDrop)]
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
    /// Not a regular file (a directory, a device, a FIFO, a socket).
    NotAFile(&'static str),
    /// Group or others may read or write the file.
    Permissions(u32),
    /// Not exactly one line of 64 lowercase hexadecimal digits: what is
    /// wrong with it.
    Format(String),
    /// A well-formed key that must not be used.
    Weak(&'static str),
}

impl std::fmt::Display for KeyError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            KeyError::Io(e) => write!(f, "{e}"),
            KeyError::NotAFile(what) => write!(
                f,
                "{what}, not a key file (a key file is a regular file of one line; \
                 hapctl keygen FILE writes one)"
            ),
            KeyError::Permissions(m) => write!(
                f,
                "mode {m:04o}: a key file must not be accessible to group or others (chmod 600)"
            ),
            KeyError::Format(why) => write!(
                f,
                "not a key file: {why}; expected exactly {} lowercase hexadecimal digits \
                 [0-9a-f] and one newline (hapctl keygen writes one)",
                PSK_LEN * 2
            ),
            KeyError::Weak(why) => write!(
                f,
                "weak key refused: {why}; generate a new one with hapctl keygen"
            ),
        }
    }
}

impl std::error::Error for KeyError {}

/// Bytes a key file may hold at most (64 digits and a newline).
pub const KEY_FILE_LEN: usize = PSK_LEN * 2 + 1;

/// Distinct byte values, and distinct differences between successive bytes,
/// a key must have at least. 32 random bytes have about 30 of each; fewer
/// than 16 of either happens by chance with a probability below 10⁻¹⁵
/// (a birthday bound), and catches constant, repeated, counting and
/// hand-typed patterns.
pub const KEY_MIN_DISTINCT: usize = 16;

impl Psk {
    /// A key from its bytes, unchecked (tests and vectors; files go through
    /// [`Psk::load`], which refuses weak keys).
    pub const fn from_bytes(b: [u8; PSK_LEN]) -> Psk {
        Psk(b)
    }

    pub const fn as_bytes(&self) -> &[u8; PSK_LEN] {
        &self.0
    }

    /// The published test key of protocol.md §7.6: bytes 0x00, 0x01, … 0x1f.
    /// [`Psk::load`] and [`Psk::check_strength`] refuse it.
    pub fn test_key() -> Psk {
        let mut k = [0u8; PSK_LEN];
        for (i, b) in k.iter_mut().enumerate() {
            *b = i as u8;
        }
        Psk(k)
    }

    /// A fresh random key (from the kernel's CSPRNG), drawn until it passes
    /// [`Psk::check_strength`] (the first draw does but with a negligible
    /// probability).
    pub fn generate() -> std::io::Result<Psk> {
        loop {
            let mut k = Psk([0u8; PSK_LEN]);
            fill_random(&mut k.0)?;
            if k.check_strength().is_ok() {
                return Ok(k);
            }
        }
    }

    /// 64 lowercase hex digits.
    pub fn to_hex(&self) -> String {
        hex(&self.0)
    }

    /// Refuse keys that are not random: all zero, the published test key,
    /// fewer than [`KEY_MIN_DISTINCT`] distinct bytes or distinct successive
    /// differences (each difference `key[i] - key[i-1]` taken modulo 256).
    pub fn check_strength(&self) -> Result<(), KeyError> {
        if self.0.iter().all(|b| *b == 0) {
            return Err(KeyError::Weak("all zero"));
        }
        if *self == Psk::test_key() {
            return Err(KeyError::Weak(
                "the published test key of Documentation/protocol.md",
            ));
        }
        let mut seen = [false; 256];
        let mut deltas = [false; 256];
        for (i, b) in self.0.iter().enumerate() {
            seen[usize::from(*b)] = true;
            if let Some(prev) = i.checked_sub(1).and_then(|j| self.0.get(j)) {
                deltas[usize::from(b.wrapping_sub(*prev))] = true;
            }
        }
        let distinct = seen.iter().filter(|s| **s).count();
        let distinct_deltas = deltas.iter().filter(|s| **s).count();
        seen.zeroize();
        deltas.zeroize();
        if distinct < KEY_MIN_DISTINCT {
            return Err(KeyError::Weak("too few distinct bytes (low entropy)"));
        }
        if distinct_deltas < KEY_MIN_DISTINCT {
            return Err(KeyError::Weak(
                "a regular pattern (too few distinct steps between bytes)",
            ));
        }
        Ok(())
    }

    /// Parse a key file's content: exactly 64 lowercase hex digits, then
    /// one `\n` (or nothing). No white space, sign, prefix or upper case.
    /// Weak keys are refused. The error names the first fault: the first
    /// character that is not a digit (and where), else the number of
    /// digits.
    pub fn parse_file(s: &[u8]) -> Result<Psk, KeyError> {
        let digits = s.strip_suffix(b"\n").unwrap_or(s);
        let nibble = |c: u8| match c {
            b'0'..=b'9' => Some(c - b'0'),
            b'a'..=b'f' => Some(c - b'a' + 10),
            _ => None,
        };
        if let Some((at, c)) = digits
            .iter()
            .enumerate()
            .find(|(_, c)| nibble(**c).is_none())
        {
            let what = match *c {
                b'\n' => "a second line".to_string(),
                b'\r' => "a carriage return (a DOS line end?)".to_string(),
                b' ' | b'\t' => "white space".to_string(),
                b'A'..=b'F' => format!("an upper-case digit '{}'", *c as char),
                c if c.is_ascii_graphic() => format!("'{}'", c as char),
                c => format!("the byte 0x{c:02x}"),
            };
            return Err(KeyError::Format(format!(
                "{what} at character {}, where only 0-9 a-f may be",
                at + 1
            )));
        }
        if digits.len() != PSK_LEN * 2 {
            let why = if digits.is_empty() {
                "empty".to_string()
            } else if digits.len() < PSK_LEN * 2 {
                format!("too short: {} hexadecimal digits", digits.len())
            } else {
                format!("too long: {} hexadecimal digits", digits.len())
            };
            return Err(KeyError::Format(why));
        }
        let mut k = Psk([0u8; PSK_LEN]);
        for (i, b) in k.0.iter_mut().enumerate() {
            let (Some(hi), Some(lo)) = (nibble(digits[2 * i]), nibble(digits[2 * i + 1])) else {
                return Err(KeyError::Format("not hexadecimal".to_string()));
            };
            *b = (hi << 4) | lo;
        }
        k.check_strength()?;
        Ok(k)
    }

    /// Read a key file ([`Psk::parse_file`]), and on Unix a mode without any
    /// group or other permission (like ssh's private keys). The buffer that
    /// held the digits is wiped.
    pub fn load(path: &Path) -> Result<Psk, KeyError> {
        // What the path is, before opening it (opening a FIFO would wait
        // for a writer), and again once open (it may have changed).
        let kind = |m: &std::fs::Metadata| -> Result<(), KeyError> {
            if m.is_dir() {
                Err(KeyError::NotAFile("a directory"))
            } else if !m.is_file() {
                Err(KeyError::NotAFile("a device, FIFO or socket"))
            } else {
                Ok(())
            }
        };
        kind(&std::fs::metadata(path).map_err(KeyError::Io)?)?;
        let mut f = std::fs::File::open(path).map_err(KeyError::Io)?;
        let meta = f.metadata().map_err(KeyError::Io)?;
        kind(&meta)?;
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = meta.permissions().mode() & 0o7777;
            if mode & 0o077 != 0 {
                return Err(KeyError::Permissions(mode));
            }
        }
        // Room for one more byte than a key and a newline, to tell a file
        // of 65 characters from a longer one without reading it all.
        let mut buf = Zeroizing::new([0u8; KEY_FILE_LEN + 2]);
        let mut n = 0;
        while n < buf.len() {
            match f.read(&mut buf[n..]) {
                Ok(0) => break,
                Ok(k) => n += k,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(KeyError::Io(e)),
            }
        }
        if n == buf.len() && !buf.contains(&b'\n') {
            let mut more = [0u8; 1];
            if f.read(&mut more).map_err(KeyError::Io)? > 0 {
                return Err(KeyError::Format(format!(
                    "too long: more than {} characters",
                    buf.len()
                )));
            }
        }
        Psk::parse_file(&buf[..n])
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
        let mut line = Zeroizing::new(self.to_hex().into_bytes());
        line.push(b'\n');
        f.write_all(&line)?;
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
pub fn open_key(psk: &Psk) -> Zeroizing<Key> {
    hmac(&psk.0, &[LABEL_OPEN])
}

/// Key of the bridge's `cookie` answering the `open_session` with nonce Nc:
/// HMAC(PSK, "hapticctrl v2 cookie" ‖ Nc).
pub fn cookie_key(psk: &Psk, nc: &[u8; NONCE_LEN]) -> Zeroizing<Key> {
    hmac(&psk.0, &[LABEL_COOKIE, nc])
}

/// Key of the client's `open_proof`: HMAC(PSK, "hapticctrl v2 proof").
pub fn proof_key(psk: &Psk) -> Zeroizing<Key> {
    hmac(&psk.0, &[LABEL_PROOF])
}

/// Key of the bridge's refusal of a handshake (bound to its nonce):
/// HMAC(PSK, "hapticctrl v2 refuse" ‖ Nc).
pub fn refuse_key(psk: &Psk, nc: &[u8; NONCE_LEN]) -> Zeroizing<Key> {
    hmac(&psk.0, &[LABEL_REFUSE, nc])
}

/// The 18 bytes of a source address the cookie is bound to: the IPv6
/// address (an IPv4 one mapped, `::ffff:a.b.c.d`) and the port, big-endian.
pub fn address_bytes(a: &SocketAddr) -> [u8; 18] {
    let ip = match a.ip() {
        IpAddr::V4(v4) => v4.to_ipv6_mapped(),
        IpAddr::V6(v6) => v6,
    };
    let mut out = [0u8; 18];
    out[..16].copy_from_slice(&ip.octets());
    out[16..].copy_from_slice(&a.port().to_be_bytes());
    out
}

/// The bridge's nonce for a handshake, which is also its cookie:
/// the first 16 bytes of HMAC(S, "hapticctrl v2 ns" ‖ epoch ‖ address ‖ Nc)
/// under the bridge's secret S (random, drawn at start, never stored).
/// Only the bridge can compute it; it binds the client's address, a coarse
/// time and the client's nonce.
pub fn cookie_nonce(
    secret: &[u8; 32],
    epoch: u32,
    src: &SocketAddr,
    nc: &[u8; NONCE_LEN],
) -> [u8; NONCE_LEN] {
    cookie_nonce_with(&keyed(secret), epoch, src, nc)
}

/// [`cookie_nonce`] under the secret's keyed state.
fn cookie_nonce_with(
    secret: &HmacSha256,
    epoch: u32,
    src: &SocketAddr,
    nc: &[u8; NONCE_LEN],
) -> [u8; NONCE_LEN] {
    let full = prf(
        secret,
        &[LABEL_NS, &epoch.to_be_bytes(), &address_bytes(src), nc],
    );
    let mut ns = [0u8; NONCE_LEN];
    ns.copy_from_slice(&full[..NONCE_LEN]);
    ns
}

/// The cookie epoch of a time `now` on the bridge's monotonic clock.
pub fn epoch_of(now: Duration) -> u32 {
    (now.as_secs() / COOKIE_EPOCH_S) as u32
}

/// An HMAC-SHA-256 instance already keyed (its inner and outer pads
/// hashed once), cloned for each frame. Its state, and every clone's, is
/// wiped when dropped (`hmac`'s `zeroize` feature).
fn keyed(key: &[u8]) -> HmacSha256 {
    <HmacSha256 as KeyInit>::new_from_slice(key).expect("HMAC takes any key length")
}

/// The two directional keys of one session and their keyed HMAC states:
/// all four are wiped when dropped (a clone too).
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

impl Drop for SessionKeys {
    fn drop(&mut self) {
        self.c2s.zeroize();
        self.s2c.zeroize();
    }
}

impl SessionKeys {
    pub fn derive(psk: &Psk, nc: &[u8; NONCE_LEN], ns: &[u8; NONCE_LEN]) -> SessionKeys {
        SessionKeys::derive_with(&keyed(&psk.0), nc, ns)
    }

    /// [`SessionKeys::derive`] under the PSK's keyed state.
    fn derive_with(psk: &HmacSha256, nc: &[u8; NONCE_LEN], ns: &[u8; NONCE_LEN]) -> SessionKeys {
        let c2s = prf(psk, &[LABEL_C2S, nc, ns]);
        let s2c = prf(psk, &[LABEL_S2C, nc, ns]);
        SessionKeys {
            c2s_mac: keyed(&c2s[..]),
            s2c_mac: keyed(&s2c[..]),
            c2s: *c2s,
            s2c: *s2c,
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
        // twist, state word, VPr seq, link energy total
        FrameType::AnswerTwist => 24 + 12,
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
    /// Fewer than 20 bytes (a header and a CRC: no frame of either version).
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
    /// No live session: a request other than the handshake's without one
    /// (or after its frame limit).
    NoSession,
    /// The tag does not verify (wrong key, forged or corrupted frame).
    BadTag,
    /// An `open_proof` whose proof was already accepted (a replay inside
    /// its cookie's lifetime).
    HandshakeReplay,
    /// An `open_proof` whose cookie is not the bridge's for this source
    /// address and nonce, or whose epoch is over (older than its lifetime,
    /// or from before the bridge started).
    BadCookie,
    /// A proven `open_proof` the bridge cannot remember (its proof memory
    /// is full of proofs still alive): answered with `error` 0x101.
    HandshakeBusy,
    /// A verified `open_session` from a source IP that has not proven the
    /// key lately, dropped: the global budget of cookies per second is spent
    /// (the bridge is under load: only IPs that answered a cookie lately
    /// are served; protocol.md §7.10).
    HandshakeBudget,
    /// A frame carrying another session id than the open session's
    /// (refused before its tag is computed).
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
    /// A proven `open_proof` from the live session's client address that is
    /// not newer (serial order) than the `open_proof` that opened that
    /// session: an abandoned, held-back or late attempt of the same client.
    StaleProof,
    /// A verified `open_session` whose nonce the bridge already answered
    /// (a recorded one, replayed, from any address).
    HelloReplay,
    /// A verified `open_session` beyond its source IP's handshake budget.
    HandshakeIpBudget,
    /// A request whose sequence number would take the session's span to
    /// [`SESSION_SEQ_SPAN`]: the bridge ends the session (0x104).
    SeqExhausted,
}

impl Refusal {
    pub const COUNT: usize = 24;
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
        Refusal::BadCookie,
        Refusal::HandshakeBusy,
        Refusal::HandshakeBudget,
        Refusal::WrongSession,
        Refusal::Replay,
        Refusal::TooOld,
        Refusal::Malformed,
        Refusal::StraySource,
        Refusal::RateLimited,
        Refusal::StaleProof,
        Refusal::HelloReplay,
        Refusal::HandshakeIpBudget,
        Refusal::SeqExhausted,
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
            Refusal::BadCookie => "bad_cookie",
            Refusal::HandshakeBusy => "handshake_busy",
            Refusal::HandshakeBudget => "handshake_budget",
            Refusal::WrongSession => "wrong_session",
            Refusal::Replay => "replay",
            Refusal::TooOld => "too_old",
            Refusal::Malformed => "malformed",
            Refusal::StraySource => "stray_source",
            Refusal::RateLimited => "rate_limited",
            Refusal::StaleProof => "stale_proof",
            Refusal::HelloReplay => "hello_replay",
            Refusal::HandshakeIpBudget => "handshake_ip_budget",
            Refusal::SeqExhausted => "seq_exhausted",
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

/// A handshake frame of a v2-only type (`cookie`, `open_proof`): the
/// header with `type_byte`, Nc, Ns, the epoch, a 16-byte tag under `key`.
fn seal_proof_frame(
    key: &Key,
    type_byte: u8,
    h: &FrameHeader,
    nc: &[u8; NONCE_LEN],
    ns: &[u8; NONCE_LEN],
    epoch: u32,
) -> Wire {
    let mut w = Wire {
        buf: [0u8; MAX_FRAME_LEN],
        len: PROOF_FRAME_LEN,
    };
    // The header layout of every frame; byte 3 is then this v2-only type.
    write_header(&mut w.buf, VERSION, FrameType::OpenSession, h);
    w.buf[3] = type_byte;
    w.buf[HEADER_LEN..HEADER_LEN + NONCE_LEN].copy_from_slice(nc);
    w.buf[HEADER_LEN + NONCE_LEN..HEADER_LEN + 2 * NONCE_LEN].copy_from_slice(ns);
    let body = HEADER_LEN + PROOF_PAYLOAD_LEN;
    w.buf[body - 4..body].copy_from_slice(&epoch.to_be_bytes());
    let t = tag(&keyed(key), &w.buf[..body], TAG_LEN);
    w.buf[body..body + TAG_LEN].copy_from_slice(&t);
    w
}

/// The bridge's `cookie` (session 0, seq 0, timestamp 0): Nc echoed, its
/// nonce Ns (the cookie), the epoch; under [`cookie_key`].
pub fn seal_cookie(
    psk: &Psk,
    h: &FrameHeader,
    nc: &[u8; NONCE_LEN],
    ns: &[u8; NONCE_LEN],
    epoch: u32,
) -> Wire {
    seal_proof_frame(&cookie_key(psk, nc), TYPE_COOKIE, h, nc, ns, epoch)
}

/// The client's `open_proof` (session 0): Nc, the cookie's Ns and epoch;
/// under [`proof_key`].
pub fn seal_open_proof(
    psk: &Psk,
    h: &FrameHeader,
    nc: &[u8; NONCE_LEN],
    ns: &[u8; NONCE_LEN],
    epoch: u32,
) -> Wire {
    seal_proof_frame(&proof_key(psk), TYPE_OPEN_PROOF, h, nc, ns, epoch)
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

/// The bridge's `error` 0x101 refusing a proven handshake it cannot
/// remember (`handshake_busy`), under [`refuse_key`].
pub fn seal_refusal(psk: &Psk, nc: &[u8; NONCE_LEN], h: &FrameHeader, rejected_seq: u32) -> Wire {
    let mut p = [0u8; 8];
    p[..4].copy_from_slice(&ERROR_REFUSED.to_be_bytes());
    p[4..].copy_from_slice(&rejected_seq.to_be_bytes());
    seal_raw(&refuse_key(psk, nc), FrameType::Error, h, &p)
}

/// Is `b` shaped as a v2 handshake datagram of the client (`open_session`
/// or `open_proof`: magic, version 2, type and exact length)? The bridge
/// examines these even from a source whose refusal budget is spent: each
/// costs at most one HMAC to refute, and a key holder sharing an IP with a
/// flooder must still be able to open.
pub fn is_handshake(b: &[u8]) -> bool {
    matches!(
        precheck(b),
        Ok(WireType::OpenProof | WireType::Frame(FrameType::OpenSession))
    )
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
            let mut p = [0u8; 36];
            p[..24].copy_from_slice(v1.get(16..40)?);
            p[24..28].copy_from_slice(&state(a.status, a.alarms).to_be_bytes());
            p[28..32].copy_from_slice(&a.vpr_seq.to_be_bytes());
            p[32..36].copy_from_slice(&a.link_energy.to_be_bytes());
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

/// The type of a v2 datagram: one of hap-core's, or a v2-only handshake type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum WireType {
    Frame(FrameType),
    Cookie,
    OpenProof,
}

/// First checks common to both sides: size, magic, version, type, length.
fn precheck(b: &[u8]) -> Result<WireType, Refusal> {
    if b.len() > MAX_FRAME_LEN {
        return Err(Refusal::Oversize);
    }
    // Shorter than a v1 header and CRC: no frame of either version. (The
    // smallest v2 frame is 32 bytes; a shorter v2 datagram is refused as
    // `length_mismatch` below, a v1 frame as `unauthenticated_v1`.)
    if b.len() < HEADER_LEN + 4 {
        return Err(Refusal::Undersize);
    }
    if b[0..2] != MAGIC {
        return Err(Refusal::BadMagic);
    }
    if b[2] == hap_core::protocol::VERSION {
        return Err(Refusal::Unauthenticated);
    }
    if b[2] != VERSION {
        return Err(Refusal::BadVersion);
    }
    let (ty, len) = match b[3] {
        TYPE_COOKIE => (WireType::Cookie, PROOF_FRAME_LEN),
        TYPE_OPEN_PROOF => (WireType::OpenProof, PROOF_FRAME_LEN),
        t => {
            let ty = FrameType::from_u8(t).ok_or(Refusal::UnknownType)?;
            (WireType::Frame(ty), frame_len(ty))
        }
    };
    if b.len() != len {
        return Err(Refusal::LengthMismatch);
    }
    Ok(ty)
}

fn nonce_at(b: &[u8], at: usize) -> [u8; NONCE_LEN] {
    let mut n = [0u8; NONCE_LEN];
    n.copy_from_slice(&b[at..at + NONCE_LEN]);
    n
}

/// Constant-time equality of two nonces.
fn same_nonce(a: &[u8; NONCE_LEN], b: &[u8; NONCE_LEN]) -> bool {
    a.iter()
        .zip(b.iter())
        .fold(0u8, |acc, (x, y)| acc | (x ^ y))
        == 0
}

/// What kind of client datagram passed the gate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// `open_session`: answered with a `cookie`, nothing committed.
    Hello,
    /// `open_proof` with a valid cookie and tag, not seen before: commits a
    /// session.
    Proof,
    /// A copy of the `open_proof` that opened the live session, from its
    /// client's address (a retransmission after a lost `session_ack`):
    /// answered with the session's `session_ack` again, nothing committed.
    ProofCopy,
    /// `close_session` of the open session.
    Close,
    /// Any other request of the open session.
    Other,
}

/// A client datagram that passed every check of [`Gate::inspect`]; hand it
/// back to [`Gate::commit`] once the bridge's address policy admits it.
#[derive(Clone, Copy, Debug)]
pub struct Inspected {
    pub kind: Kind,
    pub header: FrameHeader,
    pub src: SocketAddr,
    ty: FrameType,
    nc: [u8; NONCE_LEN],
    ns: [u8; NONCE_LEN],
    epoch: u32,
    wire: Wire,
}

/// What the bridge does with a committed datagram.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Action {
    /// Write this v1 frame to the kernel's input device.
    Forward(Wire),
    /// Send this v2 frame back to the source, write nothing: the `cookie`
    /// answering an `open_session` (no state kept but its nonce; never
    /// larger than [`AMPLIFICATION_FACTOR`] times the datagram).
    Challenge(Wire),
    /// Send this v2 frame back to the client, write nothing (a replayed
    /// acknowledged request: its ack again, [`Refusal::Replay`]; a copy of
    /// the live session's `open_proof`: its `session_ack` again,
    /// [`Refusal::HandshakeReplay`]; an authenticated but malformed
    /// request: `error` with the decode reason; a proven handshake the
    /// bridge cannot remember: `error` 0x101).
    Reply(Wire, Refusal),
}

/// Why the bridge ended a session on its own.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EndReason {
    /// A newer proven handshake took the session ([`ERROR_REPLACED`]).
    Replaced,
    /// The client was silent longer than the session timeout ([`ERROR_EXPIRED`]).
    Expired,
    /// A direction reached [`SESSION_SEQ_SPAN`] ([`ERROR_SEQ_EXHAUSTED`]).
    SeqExhausted,
}

impl EndReason {
    /// The `error` reason the client is told.
    pub const fn error_reason(self) -> u32 {
        match self {
            EndReason::Replaced => ERROR_REPLACED,
            EndReason::Expired => ERROR_EXPIRED,
            EndReason::SeqExhausted => ERROR_SEQ_EXHAUSTED,
        }
    }
}

/// What the bridge sends when it ends a session itself.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Ended {
    /// `error` with the reason, under the ended session's s2c key, for its
    /// client (session id the ended one's, seq 0, timestamp 0).
    pub notice: Wire,
    /// A v1 `close_session` for the kernel (the session's id, the next
    /// sequence number after the newest accepted, no ack request), so that
    /// PROTO_IN closes the session too; `None` if the kernel had not
    /// granted it yet.
    pub kernel_close: Option<Wire>,
}

/// Counters of the gate (the bridge renders them).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct GateCounters {
    pub verified: u64,
    /// Proven handshakes committed.
    pub handshakes: u64,
    /// `cookie` answers sent (one per authenticated `open_session`).
    pub cookies: u64,
    /// Replayed acknowledged requests answered with their ack again.
    pub reacked: u64,
    /// Copies of the live session's `open_proof` answered with its
    /// `session_ack` again.
    pub proofs_reacked: u64,
    /// Replies the kernel sent that were not sealed (no session, another
    /// session's id, or the session ended).
    pub replies_unsealed: u64,
    /// Sessions the bridge ended itself, by reason.
    pub ended_replaced: u64,
    pub ended_expired: u64,
    pub ended_seq_exhausted: u64,
}

/// Where a session is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum SessionState {
    /// Proven and forwarded; the kernel's `session_ack` not yet seen.
    Granting,
    /// The kernel granted it (id known).
    Open,
    /// The client closed it (`close_session` forwarded, with this sequence
    /// number): only the kernel's ack of that close is still sealed.
    Closing(u32),
    /// Ended (closed and acknowledged, or ended by the bridge): nothing is
    /// sealed any more.
    Ended,
}

#[derive(Clone, Debug)]
struct GateSession {
    nc: [u8; NONCE_LEN],
    ns: [u8; NONCE_LEN],
    keys: SessionKeys,
    /// The address that proved the key (the session's client).
    client: SocketAddr,
    /// The sequence number of the `open_proof` that opened the session:
    /// the start of the client's span, and what a later proof from the
    /// same address must be newer than.
    open_seq: u32,
    /// Granted by the kernel (0 until its session_ack).
    id: u16,
    kernel_nonce: u32,
    window: SeqWindow,
    state: SessionState,
    /// The sealed `session_ack` (sent again for a copy of the proof).
    ack: Option<Wire>,
    /// The kernel's sequence number in that `session_ack`: the start of
    /// the controller's span.
    s2c_first: u32,
    s2c_newest: u32,
    /// The kernel's frames reached [`SESSION_SEQ_SPAN`]: nothing more is
    /// sealed, the bridge ends the session.
    s2c_spent: bool,
    /// Sealed acks of the last acknowledged requests: (seq, type, bytes).
    acks: [Option<(u32, FrameType, Wire)>; ACK_MEMORY],
    acks_next: usize,
}

/// One accepted proof, remembered until its cookie's epoch is over.
#[derive(Clone, Copy, Debug)]
struct SeenProof {
    nc: [u8; NONCE_LEN],
    ns: [u8; NONCE_LEN],
    epoch: u32,
}

/// The `open_session` nonces answered with a cookie in the last
/// [`HELLO_MEMORY_S`] seconds (at most [`HELLO_MEMORY`]).
#[derive(Debug, Default)]
struct HelloMemory {
    /// Nonce → the second it was answered.
    by_nonce: std::collections::HashMap<[u8; NONCE_LEN], u64>,
    /// (nonce, second answered), oldest first.
    order: std::collections::VecDeque<([u8; NONCE_LEN], u64)>,
}

impl HelloMemory {
    /// Was `nc` answered in the last [`HELLO_MEMORY_S`] before `now_s`?
    fn answered(&self, nc: &[u8; NONCE_LEN], now_s: u64) -> bool {
        self.by_nonce
            .get(nc)
            .is_some_and(|t| now_s.saturating_sub(*t) < HELLO_MEMORY_S)
    }

    fn remember(&mut self, nc: [u8; NONCE_LEN], now_s: u64) {
        while let Some((old, t)) = self.order.front().copied() {
            let dead = now_s.saturating_sub(t) >= HELLO_MEMORY_S;
            if !dead && self.order.len() < HELLO_MEMORY {
                break;
            }
            self.order.pop_front();
            // The nonce may have been answered again since (its entry then
            // carries a later time): forget only this answer.
            if self.by_nonce.get(&old) == Some(&t) {
                self.by_nonce.remove(&old);
            }
        }
        self.by_nonce.insert(nc, now_s);
        self.order.push_back((nc, now_s));
    }

    fn len(&self) -> usize {
        self.by_nonce.len()
    }
}

/// The bridge's authenticator: one session (the kernel has one), the PSK,
/// the bridge's cookie secret, the proofs accepted in the cookies' lifetime
/// and the nonces of the `open_session`s it answered.
pub struct Gate {
    /// Keyed states: the PSK (to derive the per-nonce and session keys),
    /// `K_open`, `K_proof`, and the cookie secret S (which is kept only in
    /// this form). Each is wiped when dropped.
    psk_mac: HmacSha256,
    k_open: HmacSha256,
    k_proof: HmacSha256,
    secret_mac: HmacSha256,
    session: Option<GateSession>,
    /// Accepted proofs in the order they came (to forget them when their
    /// cookie dies) and as a set (to look one up).
    proofs: std::collections::VecDeque<SeenProof>,
    proof_set: std::collections::HashSet<([u8; NONCE_LEN], [u8; NONCE_LEN])>,
    hellos: HelloMemory,
    kernel_nonce: u32,
    span_limit: u64,
    /// The session a proven handshake replaced, until the bridge takes it.
    replaced: Option<Ended>,
    pub counters: GateCounters,
}

impl std::fmt::Debug for Gate {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Gate")
            .field("session", &self.session.as_ref().map(|s| s.id))
            .finish()
    }
}

/// Is a cookie of `epoch` alive at epoch `now`? Its own epoch and the next.
fn epoch_alive(epoch: u32, now: u32) -> bool {
    epoch == now || epoch.checked_add(1) == Some(now)
}

const BRIDGE_HEADER: FrameHeader = FrameHeader {
    control: 0,
    session: 0,
    seq: 0,
    timestamp_us: 0,
};

impl Gate {
    /// A gate with the cookie secret `secret` (tests and vectors; the bridge
    /// uses [`Gate::with_random_secret`]). Only its keyed HMAC state is
    /// kept; the caller wipes its copy.
    pub fn new(psk: Psk, secret: &[u8; 32]) -> Gate {
        Gate {
            psk_mac: keyed(&psk.0),
            k_open: keyed(&open_key(&psk)[..]),
            k_proof: keyed(&proof_key(&psk)[..]),
            secret_mac: keyed(secret),
            session: None,
            proofs: std::collections::VecDeque::new(),
            proof_set: std::collections::HashSet::new(),
            hellos: HelloMemory::default(),
            kernel_nonce: 0,
            span_limit: SESSION_SEQ_SPAN,
            replaced: None,
            counters: GateCounters::default(),
        }
    }

    /// A gate with a fresh random cookie secret: every cookie of an earlier
    /// process is refused. The secret is drawn into memory that is wiped
    /// once the gate has keyed its HMAC state with it.
    pub fn with_random_secret(psk: Psk) -> std::io::Result<Gate> {
        let mut s = Zeroizing::new([0u8; 32]);
        fill_random(&mut s[..])?;
        Ok(Gate::new(psk, &s))
    }

    /// Lower the sequence span a session may cover per direction (tests of
    /// the session end at [`SESSION_SEQ_SPAN`]).
    pub fn set_frame_limit(&mut self, span: u64) {
        self.span_limit = span.clamp(1, SESSION_SEQ_SPAN);
    }

    fn live(&self) -> Option<&GateSession> {
        self.session
            .as_ref()
            .filter(|s| matches!(s.state, SessionState::Granting | SessionState::Open))
    }

    /// The session id the kernel granted (0: none or not yet).
    pub fn session_id(&self) -> u16 {
        self.live().map_or(0, |s| s.id)
    }

    /// `open_session` nonces remembered now.
    pub fn hellos_remembered(&self) -> usize {
        self.hellos.len()
    }

    /// End the session on the bridge's decision: the client's notice and
    /// the kernel's `close_session`. `None` if no session is live.
    pub fn end_session(&mut self, why: EndReason) -> Option<Ended> {
        let s = self
            .session
            .as_mut()
            .filter(|s| matches!(s.state, SessionState::Granting | SessionState::Open))?;
        s.state = SessionState::Ended;
        let c = &mut self.counters;
        match why {
            EndReason::Replaced => c.ended_replaced = c.ended_replaced.saturating_add(1),
            EndReason::Expired => c.ended_expired = c.ended_expired.saturating_add(1),
            EndReason::SeqExhausted => {
                c.ended_seq_exhausted = c.ended_seq_exhausted.saturating_add(1)
            }
        }
        let h = FrameHeader {
            session: s.id,
            ..BRIDGE_HEADER
        };
        let newest = s.window.newest().unwrap_or(s.open_seq);
        let mut p = [0u8; 8];
        p[..4].copy_from_slice(&why.error_reason().to_be_bytes());
        p[4..].copy_from_slice(&newest.to_be_bytes());
        let notice = seal_with(&s.keys.s2c_mac, FrameType::Error, &h, &p);
        let kernel_close = (s.id != 0)
            .then(|| {
                let h = FrameHeader {
                    control: 0,
                    session: s.id,
                    seq: newest.wrapping_add(1),
                    timestamp_us: 0,
                };
                v1_from_payload(FrameType::CloseSession, &h, &[])
            })
            .flatten();
        Some(Ended {
            notice,
            kernel_close,
        })
    }

    /// The session the last committed handshake replaced (its client's
    /// notice; the kernel's new `open_session` closes it there).
    pub fn take_replaced(&mut self) -> Option<Ended> {
        self.replaced.take()
    }

    /// Forget the proofs whose cookie is dead at epoch `now`.
    fn prune_proofs(&mut self, now: u32) {
        while self
            .proofs
            .front()
            .is_some_and(|p| !epoch_alive(p.epoch, now))
        {
            if let Some(p) = self.proofs.pop_front() {
                self.proof_set.remove(&(p.nc, p.ns));
            }
        }
    }

    /// Check a client datagram from `src` at `now` (the bridge's monotonic
    /// clock) without changing anything: size, version, type; for
    /// `open_session` the tag and the memory of answered nonces; for
    /// `open_proof` the epoch, the cookie, the tag, that it is newer than
    /// the live session's if it comes from that session's client, and that
    /// the proof is new; for a request the session id, the anti-replay
    /// window and the sequence span, then the tag (constant time).
    pub fn inspect(&self, b: &[u8], src: SocketAddr, now: Duration) -> Result<Inspected, Refusal> {
        let wt = precheck(b)?;
        let header = read_header(b).ok_or(Refusal::Undersize)?;
        let mut wire = Wire {
            buf: [0u8; MAX_FRAME_LEN],
            len: b.len(),
        };
        wire.buf[..b.len()].copy_from_slice(b);
        let mut i = Inspected {
            kind: Kind::Other,
            header,
            src,
            ty: FrameType::OpenSession,
            nc: [0u8; NONCE_LEN],
            ns: [0u8; NONCE_LEN],
            epoch: 0,
            wire,
        };
        let handshake = matches!(
            wt,
            WireType::OpenProof | WireType::Frame(FrameType::OpenSession)
        );
        if handshake && header.session != 0 {
            // The handshake frames carry session 0 (the session is not
            // granted yet); refused before any HMAC.
            return Err(Refusal::WrongSession);
        }
        let ty = match wt {
            WireType::Cookie => return Err(Refusal::NotARequest),
            WireType::OpenProof => return self.inspect_proof(b, i, now),
            WireType::Frame(ty) => ty,
        };
        if !ty.is_request() {
            return Err(Refusal::NotARequest);
        }
        i.ty = ty;
        if ty == FrameType::OpenSession {
            if !verify(&self.k_open, b, TAG_LEN) {
                return Err(Refusal::BadTag);
            }
            i.nc = nonce_at(b, HEADER_LEN);
            // A recorded open_session, replayed from any address, draws
            // nothing while its nonce is remembered.
            if self.hellos.answered(&i.nc, now.as_secs()) {
                return Err(Refusal::HelloReplay);
            }
            i.epoch = epoch_of(now);
            i.kind = Kind::Hello;
            return Ok(i);
        }
        let Some(s) = self.live() else {
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
            SeqCheck::Newer => {
                // The span from the session's first number (the open_proof)
                // to this one, whatever the steps: the newest is less than
                // the limit past the first and this one less than 2^31 past
                // the newest, so the 32-bit difference is the exact span.
                // Refused only once the tag verified: the bridge ends the
                // session on it, which a stranger must not be able to ask.
                let span = u64::from(header.seq.wrapping_sub(s.open_seq));
                if span >= self.span_limit {
                    if !verify(&s.keys.c2s_mac, b, TAG_LEN) {
                        return Err(Refusal::BadTag);
                    }
                    return Err(Refusal::SeqExhausted);
                }
            }
            SeqCheck::InWindow => {}
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
        i.kind = if ty == FrameType::CloseSession {
            Kind::Close
        } else {
            Kind::Other
        };
        Ok(i)
    }

    fn inspect_proof(
        &self,
        b: &[u8],
        mut i: Inspected,
        now: Duration,
    ) -> Result<Inspected, Refusal> {
        // Cheapest first: the epoch (no hash), the cookie (one HMAC under
        // the bridge's secret), the tag (under the PSK), then the live
        // session and the memory of accepted proofs.
        let now_epoch = epoch_of(now);
        let epoch = be32(b, HEADER_LEN + 2 * NONCE_LEN);
        if !epoch_alive(epoch, now_epoch) {
            return Err(Refusal::BadCookie);
        }
        i.nc = nonce_at(b, HEADER_LEN);
        i.ns = nonce_at(b, HEADER_LEN + NONCE_LEN);
        i.epoch = epoch;
        let expect = cookie_nonce_with(&self.secret_mac, epoch, &i.src, &i.nc);
        if !same_nonce(&expect, &i.ns) {
            return Err(Refusal::BadCookie);
        }
        if !verify(&self.k_proof, b, TAG_LEN) {
            return Err(Refusal::BadTag);
        }
        if let Some(s) = self.live().filter(|s| s.client == i.src) {
            if same_nonce(&s.nc, &i.nc) && same_nonce(&s.ns, &i.ns) {
                // The proof that opened the live session, again from its
                // client: its session_ack went missing. Answered once the
                // kernel granted the session; before, dropped.
                if s.state == SessionState::Open && s.ack.is_some() {
                    i.kind = Kind::ProofCopy;
                    return Ok(i);
                }
                return Err(Refusal::HandshakeReplay);
            }
            // A proof commits only forward: from the client of the live
            // session, an attempt sent before the one that opened it (held
            // back, late, or abandoned by the client) is refused.
            if !seq_newer(i.header.seq, s.open_seq) {
                return Err(Refusal::StaleProof);
            }
        }
        // A remembered proof is alive: its epoch is this one's (Ns binds
        // the epoch), which was just checked.
        if self.proof_set.contains(&(i.nc, i.ns)) {
            return Err(Refusal::HandshakeReplay);
        }
        i.kind = Kind::Proof;
        Ok(i)
    }

    /// Commit an inspected datagram. `open_session`: the `cookie` to send
    /// back, its nonce remembered. `open_proof`: remember the proof, derive
    /// the session keys from Nc and the cookie's Ns, replace the session,
    /// and forward a v1 `open_session`. A copy of the live session's proof:
    /// its `session_ack` again. A request: advance the window, forward its
    /// v1 frame (or reply).
    pub fn commit(&mut self, i: &Inspected, now: Duration) -> Action {
        self.counters.verified = self.counters.verified.saturating_add(1);
        let b = i.wire.bytes();
        match i.kind {
            Kind::Hello => {
                let ns = cookie_nonce_with(&self.secret_mac, i.epoch, &i.src, &i.nc);
                self.hellos.remember(i.nc, now.as_secs());
                self.counters.cookies = self.counters.cookies.saturating_add(1);
                let key = prf(&self.psk_mac, &[LABEL_COOKIE, &i.nc]);
                return Action::Challenge(seal_proof_frame(
                    &key,
                    TYPE_COOKIE,
                    &BRIDGE_HEADER,
                    &i.nc,
                    &ns,
                    i.epoch,
                ));
            }
            Kind::Proof => return self.commit_proof(i, now),
            Kind::ProofCopy => {
                if let Some(ack) = self.live().and_then(|s| s.ack) {
                    self.counters.proofs_reacked = self.counters.proofs_reacked.saturating_add(1);
                    return Action::Reply(ack, Refusal::HandshakeReplay);
                }
                // inspect() saw the ack; commit() right after cannot miss it.
                return self.malformed_reply(i, DecodeError::TooShort);
            }
            Kind::Close | Kind::Other => {}
        }
        let Some(s) = self
            .session
            .as_mut()
            .filter(|s| matches!(s.state, SessionState::Granting | SessionState::Open))
        else {
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
        if i.kind == Kind::Close {
            s.state = SessionState::Closing(i.header.seq);
        }
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

    fn commit_proof(&mut self, i: &Inspected, now: Duration) -> Action {
        let now_epoch = epoch_of(now);
        self.prune_proofs(now_epoch);
        if self.proofs.len() >= PROOF_MEMORY {
            let key = prf(&self.psk_mac, &[LABEL_REFUSE, &i.nc]);
            let mut p = [0u8; 8];
            p[..4].copy_from_slice(&ERROR_REFUSED.to_be_bytes());
            p[4..].copy_from_slice(&i.header.seq.to_be_bytes());
            return Action::Reply(
                seal_raw(&key, FrameType::Error, &BRIDGE_HEADER, &p),
                Refusal::HandshakeBusy,
            );
        }
        if self.live().is_some() {
            self.replaced = self.end_session(EndReason::Replaced);
        }
        self.proofs.push_back(SeenProof {
            nc: i.nc,
            ns: i.ns,
            epoch: i.epoch,
        });
        self.proof_set.insert((i.nc, i.ns));
        self.kernel_nonce = self.kernel_nonce.wrapping_add(1);
        let mut window = SeqWindow::new();
        window.reset(i.header.seq);
        self.session = Some(GateSession {
            nc: i.nc,
            ns: i.ns,
            keys: SessionKeys::derive_with(&self.psk_mac, &i.nc, &i.ns),
            client: i.src,
            open_seq: i.header.seq,
            id: 0,
            kernel_nonce: self.kernel_nonce,
            window,
            state: SessionState::Granting,
            ack: None,
            s2c_first: 0,
            s2c_newest: 0,
            s2c_spent: false,
            acks: [None; ACK_MEMORY],
            acks_next: 0,
        });
        self.counters.handshakes = self.counters.handshakes.saturating_add(1);
        // The kernel's open_session: the proof's seq and timestamp; control
        // 0 (the control word of a handshake frame has no meaning).
        let h = FrameHeader {
            control: 0,
            session: 0,
            ..i.header
        };
        match v1_from_payload(FrameType::OpenSession, &h, &self.kernel_nonce.to_be_bytes()) {
            Some(w) => Action::Forward(w),
            None => self.malformed_reply(i, DecodeError::LengthMismatch),
        }
    }

    fn malformed_reply(&mut self, i: &Inspected, e: DecodeError) -> Action {
        let h = FrameHeader {
            session: i.header.session,
            ..BRIDGE_HEADER
        };
        let mut p = [0u8; 8];
        p[..4].copy_from_slice(&(e.reason_index() as u32).to_be_bytes());
        p[4..].copy_from_slice(&i.header.seq.to_be_bytes());
        let w = match self.session.as_ref() {
            Some(s) if !matches!(i.kind, Kind::Proof | Kind::ProofCopy) => {
                seal_with(&s.keys.s2c_mac, FrameType::Error, &h, &p)
            }
            _ => {
                let key = prf(&self.psk_mac, &[LABEL_REFUSE, &i.nc]);
                seal_raw(&key, FrameType::Error, &h, &p)
            }
        };
        Action::Reply(w, Refusal::Malformed)
    }

    /// Has the kernel's direction of the live session reached the sequence
    /// span? The bridge then ends it ([`EndReason::SeqExhausted`]); the
    /// client's direction is refused frame by frame
    /// ([`Refusal::SeqExhausted`]) and the bridge ends the session on the
    /// first such refusal.
    pub fn exhausted(&self) -> bool {
        self.live().is_some_and(|s| s.s2c_spent)
    }

    /// Seal a v1 frame the kernel wrote on its output device for the client.
    /// The kernel's `session_ack` of the pending handshake becomes the v2
    /// `session_ack` (and fixes the session id). Answers, acks and errors
    /// are sealed under the session's s2c key only if they carry its id
    /// (or, for the kernel's `error` 0x100, id 0: the kernel closed the
    /// session); after the client's `close_session`, only the kernel's ack
    /// of it (which carries id 0). `None`: nothing to send.
    pub fn seal_from_kernel(&mut self, v1: &[u8]) -> Option<Wire> {
        let limit = self.span_limit;
        let sealed = self.seal_kernel_frame(v1, limit);
        if sealed.is_none() {
            self.counters.replies_unsealed = self.counters.replies_unsealed.saturating_add(1);
        }
        sealed
    }

    fn seal_kernel_frame(&mut self, v1: &[u8], limit: u64) -> Option<Wire> {
        let (h, f) = decode(v1).ok()?;
        let s = self.session.as_mut()?;
        if let Frame::SessionAck {
            client_nonce,
            period_us,
        } = f
        {
            if client_nonce != s.kernel_nonce || s.state != SessionState::Granting {
                return None; // the ack of an earlier handshake
            }
            s.id = h.session;
            s.state = SessionState::Open;
            s.s2c_first = h.seq;
            s.s2c_newest = h.seq;
            let w = seal_session_ack(&s.keys, &h, &s.nc, &s.ns, period_us);
            s.ack = Some(w);
            return Some(w);
        }
        let ok = match (s.state, f) {
            (SessionState::Open, Frame::Error { reason, .. })
                if reason == ERROR_NO_SESSION && h.session == 0 =>
            {
                true
            }
            (SessionState::Open, _) => h.session == s.id && s.id != 0,
            (
                SessionState::Closing(seq),
                Frame::Ack {
                    acked_type: FrameType::CloseSession,
                    acked_seq,
                },
            ) => acked_seq == seq,
            _ => false,
        };
        if !ok || s.s2c_spent {
            return None;
        }
        // The kernel numbers its frames +1 each, for all sessions: the span
        // from this session's session_ack to its newest frame (exact in 32
        // bits: the newest is less than the limit past the first, a newer
        // frame less than 2^31 past the newest).
        if seq_newer(h.seq, s.s2c_newest) {
            if u64::from(h.seq.wrapping_sub(s.s2c_first)) >= limit {
                s.s2c_spent = true;
                return None;
            }
            s.s2c_newest = h.seq;
        }
        let w = seal_reply_with(&s.keys.s2c_mac, v1)?;
        match f {
            Frame::Ack {
                acked_type: FrameType::CloseSession,
                ..
            } if matches!(s.state, SessionState::Closing(_)) => {
                s.state = SessionState::Ended;
            }
            Frame::Ack {
                acked_type,
                acked_seq,
            } => {
                if let Some(slot) = s.acks.get_mut(s.acks_next) {
                    *slot = Some((acked_seq, acked_type, w));
                }
                s.acks_next = (s.acks_next + 1) % ACK_MEMORY;
            }
            _ => {}
        }
        Some(w)
    }
}

/// A reply the client verified.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reply {
    /// The bridge's cookie: send [`ClientAuth::prove`] next.
    Cookie,
    /// The handshake completed: the session id is in the header.
    SessionAck { period_us: u32 },
    /// Any other controller frame, as hap-core decodes its v1 form
    /// (answers carry the cycle from the header's timestamp field).
    Frame(Frame),
    /// The bridge refused the handshake (`error` under the refusal key).
    HandshakeRefused { reason: u32 },
}

/// Where the client's handshake is.
#[derive(Clone, Debug)]
enum ClientState {
    Idle,
    /// `open_session`s sent with these nonces (the newest last, at most
    /// [`HELLOS_PENDING`]): the first cookie to come for any of them is
    /// proved, the others are then ignored.
    Hello(Vec<[u8; NONCE_LEN]>),
    /// `cookie` received; `open_proof` to send, or sent (then kept, to be
    /// sent again as it is until the `session_ack` comes: a new attempt
    /// would leave this proof valid at the bridge for its cookie's life).
    Proving {
        nc: [u8; NONCE_LEN],
        ns: [u8; NONCE_LEN],
        epoch: u32,
        proof: Option<Wire>,
    },
}

/// `open_session`s of one open whose cookie the client still takes (a
/// bridge slow to answer the first one is not left unheard when the client
/// sends another).
pub const HELLOS_PENDING: usize = 8;

/// The client's side: the PSK, the pending handshake and the session keys.
#[derive(Clone, Debug)]
pub struct ClientAuth {
    psk: Psk,
    pending: ClientState,
    keys: Option<SessionKeys>,
    /// The sequence number of the `open_proof` of the session (the start
    /// of its span) and the newest number sealed in it.
    first_seq: u32,
    newest_seq: u32,
    /// The session's span reached the limit: nothing more is sealed.
    spent: bool,
    span_limit: u64,
}

impl ClientAuth {
    pub fn new(psk: Psk) -> ClientAuth {
        ClientAuth {
            psk,
            pending: ClientState::Idle,
            keys: None,
            first_seq: 0,
            newest_seq: 0,
            spent: false,
            span_limit: SESSION_SEQ_SPAN,
        }
    }

    /// Lower the sequence span a session may cover (tests).
    pub fn set_frame_limit(&mut self, span: u64) {
        self.span_limit = span.clamp(1, SESSION_SEQ_SPAN);
    }

    /// Send an `open_session` with the nonce `nc` (fresh for every
    /// attempt). Returns it. While no cookie came, the cookie of an earlier
    /// `open_session` (one of the last [`HELLOS_PENDING`]) is still taken.
    pub fn hello(&mut self, h: &FrameHeader, nc: [u8; NONCE_LEN]) -> Wire {
        match &mut self.pending {
            ClientState::Hello(ncs) => {
                if ncs.len() >= HELLOS_PENDING {
                    ncs.remove(0);
                }
                ncs.push(nc);
            }
            _ => self.pending = ClientState::Hello(vec![nc]),
        }
        let h = FrameHeader { session: 0, ..*h };
        seal_open(&self.psk, &h, &nc)
    }

    /// The `open_proof` answering the cookie received (`None` before one).
    /// Its header's sequence number starts the session's numbering. Asked
    /// again in the same attempt, the same proof, byte for byte (`h` is
    /// then ignored): a copy is harmless at the bridge (it re-sends the
    /// `session_ack` of the session the proof opened), a second proof of
    /// the same attempt would not be.
    pub fn prove(&mut self, h: &FrameHeader) -> Option<Wire> {
        let ClientState::Proving {
            nc,
            ns,
            epoch,
            proof,
        } = &mut self.pending
        else {
            return None;
        };
        if let Some(w) = proof {
            return Some(*w);
        }
        let h = FrameHeader { session: 0, ..*h };
        let w = seal_open_proof(&self.psk, &h, nc, ns, *epoch);
        *proof = Some(w);
        Some(w)
    }

    /// The `open_proof` sent in the pending attempt, to send again if its
    /// `session_ack` does not come (`None`: no cookie came yet, or the
    /// session is established).
    pub fn pending_proof(&self) -> Option<Wire> {
        match &self.pending {
            ClientState::Proving { proof, .. } => *proof,
            _ => None,
        }
    }

    pub fn established(&self) -> bool {
        self.keys.is_some()
    }

    /// The session's keys, once established.
    pub fn keys(&self) -> Option<&SessionKeys> {
        self.keys.as_ref()
    }

    /// True once the session sealed [`SESSION_SEQ_SPAN`] frames: open a
    /// new session.
    pub fn exhausted(&self) -> bool {
        self.keys.is_some() && self.spent
    }

    /// Forget the session (the controller ended it, or the client closed it).
    pub fn end(&mut self) {
        self.keys = None;
        self.pending = ClientState::Idle;
    }

    /// Seal a request (not `open_session`) under the session key; `None`
    /// without a session, or when `h`'s sequence number would take the
    /// session's span to [`SESSION_SEQ_SPAN`] (the session is then
    /// [`ClientAuth::exhausted`]).
    pub fn seal(&mut self, h: &FrameHeader, f: &Frame) -> Option<Wire> {
        if self.exhausted() {
            return None;
        }
        let keys = self.keys.as_ref()?;
        if seq_newer(h.seq, self.newest_seq) {
            if u64::from(h.seq.wrapping_sub(self.first_seq)) >= self.span_limit {
                self.spent = true;
                return None;
            }
            self.newest_seq = h.seq;
        }
        seal_request(keys, h, f)
    }

    /// Verify and decode a datagram from the controller.
    pub fn open(&mut self, b: &[u8]) -> Result<(FrameHeader, Reply), Refusal> {
        let wt = precheck(b)?;
        let h = read_header(b).ok_or(Refusal::Undersize)?;
        let ty = match wt {
            WireType::OpenProof => return Err(Refusal::NotARequest),
            WireType::Cookie => {
                let ClientState::Hello(ncs) = &self.pending else {
                    return Err(Refusal::NoSession);
                };
                let echoed = nonce_at(b, HEADER_LEN);
                let Some(nc) = ncs.iter().copied().find(|n| same_nonce(n, &echoed)) else {
                    return Err(Refusal::BadTag);
                };
                if !verify(&keyed(&cookie_key(&self.psk, &nc)[..]), b, TAG_LEN) {
                    return Err(Refusal::BadTag);
                }
                self.pending = ClientState::Proving {
                    nc,
                    ns: nonce_at(b, HEADER_LEN + NONCE_LEN),
                    epoch: be32(b, HEADER_LEN + 2 * NONCE_LEN),
                    proof: None,
                };
                return Ok((h, Reply::Cookie));
            }
            WireType::Frame(ty) => ty,
        };
        if ty.is_request() {
            return Err(Refusal::NotARequest);
        }
        let tl = tag_len(ty);
        if ty == FrameType::SessionAck {
            let ClientState::Proving { nc, ns, proof, .. } = &self.pending else {
                return Err(Refusal::NoSession);
            };
            let (nc, ns, proof) = (*nc, *ns, *proof);
            if nonce_at(b, HEADER_LEN) != nc || nonce_at(b, HEADER_LEN + NONCE_LEN) != ns {
                return Err(Refusal::BadTag);
            }
            let keys = SessionKeys::derive(&self.psk, &nc, &ns);
            if !verify(&keys.s2c_mac, b, tl) {
                return Err(Refusal::BadTag);
            }
            let period_us = be32(b, HEADER_LEN + 2 * NONCE_LEN);
            self.keys = Some(keys);
            // The proof's number starts the session's span.
            let first = proof.map_or(0, |w| be32(w.bytes(), 8));
            self.first_seq = first;
            self.newest_seq = first;
            self.spent = false;
            self.pending = ClientState::Idle;
            return Ok((h, Reply::SessionAck { period_us }));
        }
        if ty == FrameType::Error && h.session == 0 {
            let ncs: Vec<[u8; NONCE_LEN]> = match &self.pending {
                ClientState::Hello(ncs) => ncs.clone(),
                ClientState::Proving { nc, .. } => vec![*nc],
                ClientState::Idle => Vec::new(),
            };
            for nc in ncs {
                if verify(&keyed(&refuse_key(&self.psk, &nc)[..]), b, tl) {
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
                // answer_twist: the link energy total follows, as in v1.
                let tail = if ty == FrameType::AnswerTwist {
                    let at = state_at + 8;
                    p[keep + 16..keep + 20].copy_from_slice(&be32(b, at).to_be_bytes());
                    4
                } else {
                    0
                };
                hv1.timestamp_us = h.timestamp_us;
                let w =
                    v1_from_payload(ty, &hv1, &p[..keep + 16 + tail]).ok_or(Refusal::Malformed)?;
                v1[..n].copy_from_slice(w.bytes());
            }
            _ => {
                let w =
                    v1_from_payload(ty, &hv1, &b[HEADER_LEN..body]).ok_or(Refusal::Malformed)?;
                v1[..n].copy_from_slice(w.bytes());
            }
        }
        let (_, f) = decode(&v1[..n]).map_err(|_| Refusal::Malformed)?;
        if let Frame::Error { reason, .. } = f {
            if matches!(
                reason,
                ERROR_NO_SESSION | ERROR_REPLACED | ERROR_EXPIRED | ERROR_SEQ_EXHAUSTED
            ) {
                // The bridge or the kernel ended the session: no further
                // frame of it.
                self.keys = None;
            }
        }
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
    fn every_handshake_frame_fits_and_the_cookie_is_under_three_times_the_hello() {
        assert_eq!(frame_len(FrameType::OpenSession), 48);
        assert_eq!(PROOF_FRAME_LEN, 68);
        const {
            assert!(PROOF_FRAME_LEN <= AMPLIFICATION_FACTOR * frame_len(FrameType::OpenSession));
            assert!(PROOF_FRAME_LEN <= MAX_FRAME_LEN);
        }
    }

    /// A key that passes: 32 bytes of a fixed pseudo-random sequence.
    fn good_key() -> Psk {
        let mut k = [0u8; PSK_LEN];
        let mut x: u32 = 0x9e37_79b9;
        for b in k.iter_mut() {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            *b = (x >> 11) as u8;
        }
        Psk::from_bytes(k)
    }

    #[test]
    fn a_key_file_is_exactly_one_line_of_64_lowercase_hex_digits() {
        let k = good_key();
        let line = format!("{}\n", k.to_hex());
        assert_eq!(Psk::parse_file(line.as_bytes()).unwrap(), k);
        assert_eq!(Psk::parse_file(&line.as_bytes()[..64]).unwrap(), k);
        let bad: Vec<String> = vec![
            format!(" {}", &line[..64]),
            format!("{}\n\n", &line[..64]),
            format!("{}\r\n", &line[..64]),
            format!("{} \n", &line[..64]),
            line[..64].to_uppercase(),
            format!("+{}", &line[1..64]),
            format!("0x{}", &line[2..64]),
            line[..62].to_string(),
            String::new(),
            format!("{}\n{}", &line[..32], &line[32..64]),
        ];
        for b in &bad {
            assert!(
                matches!(Psk::parse_file(b.as_bytes()), Err(KeyError::Format(_))),
                "{b:?}"
            );
        }
    }

    /// Each malformed key file is told its own fault.
    #[test]
    fn a_key_file_refusal_names_the_fault() {
        let line = format!("{}\n", good_key().to_hex());
        let msg = |b: &str| match Psk::parse_file(b.as_bytes()) {
            Err(e @ KeyError::Format(_)) => e.to_string(),
            r => panic!("{b:?}: {r:?}"),
        };
        let cases: Vec<(String, &str)> = vec![
            (
                format!("{}\n", &line[..63]),
                "too short: 63 hexadecimal digits",
            ),
            (line[..63].to_string(), "too short: 63 hexadecimal digits"),
            (
                format!("{}0\n", &line[..64]),
                "too long: 65 hexadecimal digits",
            ),
            (
                format!("{}00\n", &line[..64]),
                "too long: 66 hexadecimal digits",
            ),
            (String::new(), "empty"),
            ("\n".to_string(), "empty"),
            (
                format!("{}\r\n", &line[..64]),
                "a carriage return (a DOS line end?) at character 65",
            ),
            (
                format!("{}\n\n", &line[..64]),
                "a second line at character 65",
            ),
            (format!(" {}", &line[..64]), "white space at character 1"),
            (line[..64].to_uppercase(), "an upper-case digit"),
            (format!("0x{}", &line[2..64]), "'x' at character 2"),
            (
                format!("{}\u{e9}", &line[..63]),
                "the byte 0xc3 at character 64",
            ),
        ];
        for (input, want) in &cases {
            let m = msg(input);
            assert!(m.contains(want), "{input:?}: {m}");
            assert!(m.starts_with("not a key file: "), "{m}");
        }
    }

    #[test]
    fn a_directory_or_a_fifo_is_not_a_key_file() {
        let dir = std::env::temp_dir().join(format!("hap_auth_keydir_{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let e = Psk::load(&dir).unwrap_err();
        assert!(matches!(e, KeyError::NotAFile(_)), "{e:?}");
        assert!(
            e.to_string().starts_with("a directory, not a key file"),
            "{e}"
        );
        assert!(!e.to_string().contains("chmod"), "{e}");
        // A FIFO is refused before it is opened (an open would wait).
        let fifo = dir.join("fifo");
        let st = std::process::Command::new("mkfifo").arg(&fifo).status();
        if st.is_ok_and(|s| s.success()) {
            let e = Psk::load(&fifo).unwrap_err();
            assert!(e.to_string().starts_with("a device, FIFO or socket"), "{e}");
        }
        // A good file still loads; a missing one is the system's error.
        let f = dir.join("key");
        good_key().write_new(&f).unwrap();
        assert_eq!(Psk::load(&f).unwrap(), good_key());
        let e = Psk::load(&dir.join("none")).unwrap_err();
        assert!(matches!(e, KeyError::Io(_)), "{e:?}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn weak_keys_are_refused() {
        assert!(good_key().check_strength().is_ok());
        let weak = [
            Psk::from_bytes([0; PSK_LEN]),
            Psk::test_key(),
            Psk::from_bytes([0x5a; PSK_LEN]),
            Psk::from_bytes(*b"passwordpasswordpasswordpassword"),
            Psk::from_bytes(core::array::from_fn(|i| (7 * i + 3) as u8)),
            Psk::from_bytes(core::array::from_fn(
                |i| if i % 2 == 0 { 0xde } else { 0xad },
            )),
        ];
        for k in &weak {
            assert!(
                matches!(k.check_strength(), Err(KeyError::Weak(_))),
                "{:?}",
                k.as_bytes()
            );
            let line = format!("{}\n", k.to_hex());
            let e = Psk::parse_file(line.as_bytes()).unwrap_err();
            assert!(e.to_string().starts_with("weak key refused"), "{e}");
        }
        // Generated keys always pass.
        for _ in 0..64 {
            assert!(Psk::generate().unwrap().check_strength().is_ok());
        }
        assert_eq!(format!("{:?}", good_key()), "Psk(..)");
    }

    /// What protocol.md §7.1 says is wiped: the keyed HMAC states (the
    /// hash cores that hold the inner and outer pads' state, and the block
    /// buffer) wipe themselves when dropped with the `zeroize` features this
    /// crate enables; the PSK and the session keys are wiped by their own
    /// `Drop`. (A compile-time check: the test fails to build if a feature
    /// goes.)
    #[test]
    fn the_keyed_hmac_states_are_wiped_when_dropped() {
        fn wiped<T: zeroize::ZeroizeOnDrop>() {}
        wiped::<<Sha256 as hmac::EagerHash>::Core>();
        wiped::<hmac::digest::block_api::Buffer<hmac::block_api::HmacCore<Sha256>>>();
        wiped::<Sha256>();
        wiped::<Psk>();
        // A key derived here is handed out in a wiping box.
        let k: Zeroizing<Key> = open_key(&good_key());
        assert_ne!(*k, [0u8; 32]);
    }

    #[test]
    fn hmac_matches_rfc4231_case_2() {
        // RFC 4231 test case 2: key "Jefe", data "what do ya want for nothing?".
        let t = hmac(b"Jefe", &[b"what do ya want ", b"for nothing?"]);
        assert_eq!(
            hex(&t[..]),
            "5bdcc146bf60754e6a042426089575c75a003f089d2739839dec58b964ec3843"
        );
    }
}
