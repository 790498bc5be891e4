//! virtuose_api: client library for the hapticctrl haptic controller,
//! modelled on Haption's VirtuoseAPI (spec D9rb.2 §3.1).
//!
//! ```no_run
//! use virtuose_api::{VirtContext, CommandType};
//! let mut vc = VirtContext::open("127.0.0.1#5000")?;
//! vc.set_time_step(0.001)?;
//! vc.set_command_type(CommandType::VirtMech)?;
//! vc.attach_vo(0.5, [0.001, 0.001, 0.001])?;
//! vc.set_power_on(true)?;
//! loop {
//!     let handle = vc.get_position()?;      // [x,y,z,qx,qy,qz,qw]
//!     let wrench = vc.get_force()?;         // force on the virtual object
//!     // ... integrate the virtual object with `wrench` ...
//!     vc.set_speed(&[0.0; 6])?;
//!     vc.set_position(&handle)?;            // streams one VprStream frame
//! #   break;
//! }
//! vc.close()?;
//! # Ok::<(), virtuose_api::VirtError>(())
//! ```
//!
//! Every frame is encoded and decoded by `hap_core::protocol` (the one
//! source of truth). A background thread receives the controller's answers:
//! duplicates and stale answers (sequence number not newer than the last
//! one) are dropped, gaps are counted as losses, and the round-trip time is
//! measured from the `vpr_seq` the controller echoes. [`VirtContext::link_stats`]
//! reports rate, loss and RTT.
//!
//! Authentication (protocol v2, `hap_auth`): with a pre-shared key the
//! session opens with a challenge–response handshake and every frame
//! carries an HMAC tag (Documentation/protocol.md §7). The key comes from
//! [`Options::key`], else from the address (`"host#port?key=/path/to/key"`,
//! which also works through the C `virtOpen`; `&link=passive` there turns on
//! [`Options::link_passivity`]), else from the file named by
//! the environment variable [`KEY_ENV`]. Without a key the library speaks
//! unauthenticated v1, which a bridge refuses unless it runs `--insecure`.

pub mod conv;
pub mod fake_peer;
pub mod ffi;
pub mod kin;

use std::collections::HashMap;
use std::net::{SocketAddr, ToSocketAddrs, UdpSocket};
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use hap_core::config::VirtualObjectParams;
pub use hap_core::config::{CommandType, IndexingMode};
use hap_core::fixed::{Fx, Pose, Twist, Wrench};
use hap_core::link::ClientLink;
use hap_core::protocol::{
    decode, encode, seq_newer, Answer, DecodeError, Frame, FrameHeader, FrameType,
    CTRL_ACK_REQUEST, CTRL_LINK_ENERGY, ERROR_NO_SESSION, ERROR_REFUSED, MAX_FRAME_LEN,
};
use hap_core::vp::status;

/// Default UDP port of proto_interface.
pub const DEFAULT_PORT: u16 = 5000;
/// Environment variable naming the key file when neither the options nor
/// the address give one.
pub const KEY_ENV: &str = "HAP_KEY_FILE";

pub use hap_auth::Psk;
use hap_auth::{ClientAuth, Reply as AuthReply};

/// Every error the API can return. `code()` is the integer the C ABI returns
/// through `virtGetErrorCode`.
#[derive(Debug, Clone, PartialEq)]
pub enum VirtError {
    /// The address string could not be parsed or resolved.
    InvalidAddress(String),
    /// A socket operation failed.
    Io(String),
    /// No reply to a request within the configured timeout and retries.
    Timeout(&'static str),
    /// The controller refused a request (reason code and name).
    Refused {
        request: &'static str,
        reason: u32,
        name: String,
    },
    /// A parameter is invalid (NaN, out of range...).
    InvalidArgument(String),
    /// No answer frame has been received yet (get_* before the first answer).
    NoData,
    /// The context was closed.
    Closed,
    /// A null pointer or invalid handle was passed to the C ABI.
    NullPointer,
    /// The controller ended the session (protocol v2: `error` 0x100 no
    /// session, 0x102 replaced, 0x103 expired, 0x104 sequence numbers
    /// spent): every call but `close` fails with it; open a new context.
    SessionEnded { reason: u32, name: String },
}

impl VirtError {
    /// Stable integer code of this crate (the C ABI reports VirtuoseAPI's
    /// `VIRT_E_*` codes instead, see `ffi`).
    pub fn code(&self) -> i32 {
        match self {
            VirtError::InvalidAddress(_) => 1,
            VirtError::Io(_) => 2,
            VirtError::Timeout(_) => 3,
            VirtError::Refused { .. } => 4,
            VirtError::InvalidArgument(_) => 5,
            VirtError::NoData => 6,
            VirtError::Closed => 7,
            VirtError::NullPointer => 8,
            VirtError::SessionEnded { .. } => 9,
        }
    }

    /// Generic message of a code (C ABI, when no detailed message is kept).
    pub fn code_message(code: i32) -> &'static str {
        match code {
            0 => "no error",
            1 => "invalid address (expected \"host#port\" or \"host\")",
            2 => "socket error",
            3 => "timeout: no reply from the controller",
            4 => "request refused by the controller",
            5 => "invalid argument",
            6 => "no data received from the controller yet",
            7 => "context closed",
            8 => "null pointer or invalid context",
            9 => "the controller ended the session",
            _ => "unknown error code",
        }
    }
}

impl std::fmt::Display for VirtError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            VirtError::InvalidAddress(s) => write!(f, "invalid address: {s}"),
            VirtError::Io(s) => write!(f, "socket error: {s}"),
            VirtError::Timeout(op) => write!(f, "timeout: no reply from the controller to {op}"),
            VirtError::Refused {
                request,
                reason,
                name,
            } => {
                write!(
                    f,
                    "{request} refused by the controller: {name} ({reason:#x})"
                )
            }
            VirtError::InvalidArgument(s) => write!(f, "invalid argument: {s}"),
            VirtError::NoData => write!(f, "no answer received from the controller yet"),
            VirtError::Closed => write!(f, "context closed"),
            VirtError::NullPointer => write!(f, "null pointer or invalid context"),
            VirtError::SessionEnded { reason, name } => write!(
                f,
                "the controller ended the session: {name} ({reason:#x}); open a new session"
            ),
        }
    }
}

impl std::error::Error for VirtError {}

impl From<std::io::Error> for VirtError {
    fn from(e: std::io::Error) -> Self {
        VirtError::Io(e.to_string())
    }
}

pub type Result<T> = std::result::Result<T, VirtError>;

/// Timeouts, retries and the key.
#[derive(Clone, Debug)]
pub struct Options {
    /// How long to wait for the Ack of one attempt, and for the SessionAck
    /// of the first OpenSession (each further one waits twice as long).
    pub reply_timeout: Duration,
    /// Attempts for each acknowledged request (open, configuration, power).
    pub attempts: u32,
    /// Pre-shared key (protocol v2). `None`: the address's `?key=` or
    /// [`KEY_ENV`], else unauthenticated v1.
    pub key: Option<Psk>,
    /// Keep the link passive (`hap_core::link`): `get_force` returns the
    /// coupling wrench less what the controller's energy grants do not
    /// cover, `set_position` records the step and sends this end's grants
    /// (`CTRL_LINK_ENERGY`); the controller then does the same at the
    /// handle and keeps the coupling on over a slow link. Off by default;
    /// also on with `link=passive` in the address (`"host#port?link=passive"`,
    /// [`split_options`]), which is how C's `virtOpen` turns it on.
    pub link_passivity: bool,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            reply_timeout: Duration::from_millis(250),
            attempts: 4,
            key: None,
            link_passivity: false,
        }
    }
}

/// Link quality as measured by the receiver thread.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LinkStats {
    /// Frames sent (all types).
    pub sent: u64,
    /// VprStream frames sent.
    pub vpr_sent: u64,
    /// Answer frames accepted.
    pub answers: u64,
    /// Controller frames missing (gaps in its sequence numbers).
    pub lost: u64,
    /// Duplicates (same sequence number as the last accepted) dropped.
    pub duplicates: u64,
    /// Stale frames (older than the last accepted) dropped.
    pub stale: u64,
    /// Datagrams that did not decode.
    pub decode_errors: u64,
    /// Answers per second over the last measurement window (~0.5 s); before
    /// the first window closes, over the answers seen so far (0: none yet).
    pub rate_hz: f64,
    /// lost / (received + lost) over the whole session.
    pub loss_ratio: f64,
    /// Round-trip time of the last VprStream → Answer pair, ms.
    pub rtt_ms_last: f64,
    /// Mean RTT over the session, ms.
    pub rtt_ms_mean: f64,
    /// Maximum RTT over the session, ms.
    pub rtt_ms_max: f64,
    /// Controller servo period announced in the SessionAck, µs.
    pub period_us: u32,
}

/// A reply to an acknowledged request.
#[derive(Clone, Copy, Debug)]
enum Reply {
    Ack,
    Error(u32),
}

const RTT_RING: usize = 4096;

/// One VprStream → Answer round trip, recorded when
/// [`VirtContext::record_rtt`] is on (for benchmarks: per-sample export).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RttSample {
    /// Sequence number of the VprStream the answer echoed.
    pub vpr_seq: u32,
    /// Time from sending that VprStream to receiving the first answer that
    /// used it, µs (saturated at `u32::MAX`).
    pub rtt_us: u32,
    /// The answer's servo cycle counter (low 32 bits): controller time.
    pub cycle: u32,
}

/// Samples kept between two [`VirtContext::drain_rtt`] calls; more are
/// counted in [`VirtContext::rtt_overflow`] and dropped.
pub const RTT_LOG_MAX: usize = 1 << 20;

struct State {
    /// The bridge refused the authenticated handshake (reason).
    handshake_refused: Option<u32>,
    /// Why the controller ended the session (`error` 0x100, 0x102–0x104).
    session_ended: Option<u32>,
    /// When the handshake's cookie came (protocol v2): its proof is valid
    /// at the bridge for at most two cookie epochs from then.
    cookie_at: Option<Instant>,
    /// Handshake rounds the open took (each a new `open_session`, or the
    /// pending `open_proof` again).
    open_attempts: u32,
    session: u16,
    session_nonce: u32,
    session_ack: Option<(u16, u32)>,
    replies: HashMap<u32, Reply>,
    answer: Option<Answer>,
    twist: Twist,
    last_seq: Option<u32>,
    stats: LinkStats,
    rtt_sum: f64,
    rtt_n: u64,
    last_vpr_seq_seen: Option<u32>,
    sent_at: Vec<(u32, Option<Instant>)>,
    window_start: Instant,
    window_count: u64,
    /// Bumped on every accepted answer (for `wait_answer`).
    answer_gen: u64,
    /// Per-sample round trips, when recording (`record_rtt`).
    rtt_log: Option<Vec<RttSample>>,
    rtt_overflow: u64,
    /// This end of the link's passivity (`Options::link_passivity`), in the
    /// controller's units.
    link: ClientLink,
    /// The time step given to `set_time_step`, s (the controller's default
    /// until then).
    time_step: Fx,
}

struct Inner {
    /// Protocol v2 state; `None`: unauthenticated v1.
    auth: Option<Mutex<ClientAuth>>,
    sock: UdpSocket,
    state: Mutex<State>,
    cond: Condvar,
    stop: AtomicBool,
    seq: AtomicU32,
    t0: Instant,
}

impl Inner {
    fn lock(&self) -> MutexGuard<'_, State> {
        match self.state.lock() {
            Ok(g) => g,
            Err(p) => p.into_inner(),
        }
    }

    fn next_seq(&self) -> u32 {
        self.seq.fetch_add(1, Ordering::Relaxed).wrapping_add(1)
    }

    fn now_us(&self) -> u32 {
        self.t0.elapsed().as_micros() as u32
    }

    /// Encode with hap-core and send; returns the sequence number used.
    fn send(&self, frame: &Frame, control: u16) -> Result<u32> {
        self.send_stamped(frame, control, self.now_us())
    }

    /// Why nothing more can be sent in this session: the controller ended
    /// it (the reason it gave), or its sequence numbers are spent (`spent`).
    fn ended_error(&self, spent: bool) -> VirtError {
        match self.lock().session_ended {
            Some(r) => session_ended_error(r),
            None if spent => session_ended_error(hap_auth::ERROR_SEQ_EXHAUSTED),
            None => VirtError::Closed,
        }
    }

    /// Send bytes already sealed (the pending `open_proof` again).
    fn send_raw(&self, b: &[u8]) -> Result<()> {
        self.sock.send(b)?;
        self.lock().stats.sent += 1;
        Ok(())
    }

    /// [`Inner::send`] with the header's timestamp field given.
    fn send_stamped(&self, frame: &Frame, control: u16, timestamp_us: u32) -> Result<u32> {
        let seq = self.next_seq();
        let session = self.lock().session;
        let h = FrameHeader {
            control,
            session,
            seq,
            timestamp_us,
        };
        let mut buf = [0u8; MAX_FRAME_LEN];
        let n = match &self.auth {
            None => encode(&h, frame, &mut buf),
            Some(a) => {
                let mut a = match a.lock() {
                    Ok(g) => g,
                    Err(p) => p.into_inner(),
                };
                let w = if let Frame::OpenSession { .. } = frame {
                    // A fresh nonce for every attempt: the first round of the
                    // handshake (the receiver answers the cookie).
                    Some(a.hello(&h, hap_auth::fresh_nonce()?))
                } else if a.exhausted() || !a.established() {
                    // Spent, or ended by the controller (`session_ended`).
                    let spent = a.exhausted();
                    drop(a);
                    return Err(self.ended_error(spent));
                } else {
                    a.seal(&h, frame)
                };
                match w {
                    Some(w) => {
                        buf[..w.len].copy_from_slice(w.bytes());
                        w.len
                    }
                    None => 0,
                }
            }
        };
        if n == 0 {
            return Err(VirtError::InvalidArgument("frame does not encode".into()));
        }
        if let Frame::VprStream { .. } = frame {
            let mut st = self.lock();
            st.sent_at[seq as usize % RTT_RING] = (seq, Some(Instant::now()));
            st.stats.vpr_sent += 1;
        }
        self.sock.send(&buf[..n])?;
        self.lock().stats.sent += 1;
        Ok(seq)
    }
}

/// A connection to a hapticctrl controller (VirtuoseAPI `VirtContext`).
pub struct VirtContext {
    inner: Arc<Inner>,
    rx: Option<JoinHandle<()>>,
    opts: Options,
    peer: SocketAddr,
    force_factor: f32,
    speed_factor: f32,
    /// The virtual object's twist, sent with the next set_position.
    speed: Mutex<Twist>,
    /// The last power state acknowledged by the controller, until its
    /// answers report it (read-your-writes for `get_power_on`).
    power_set: Mutex<PowerSet>,
    closed: bool,
}

/// What `get_power_on` reports after a `set_power_on` the controller
/// acknowledged.
#[derive(Clone, Copy, Debug, PartialEq)]
enum PowerSet {
    /// Nothing pending: the answers' power bit.
    Reported,
    /// `on` was acknowledged at `at`; the answers do not show it yet.
    Pending { on: bool, at: Instant },
}

/// Waits for the controller's answers ([`VirtContext::answer_waiter`]).
#[derive(Clone)]
pub struct AnswerWaiter {
    inner: Arc<Inner>,
}

impl AnswerWaiter {
    /// The answer generation (bumped on every accepted answer) and the last
    /// answer's servo cycle, if any answer has arrived.
    pub fn current(&self) -> (u64, Option<u32>) {
        let st = self.inner.lock();
        (st.answer_gen, st.answer.map(|a| a.cycle))
    }

    /// Wait until an answer newer than generation `gen` has arrived (at once
    /// if it already has), up to `timeout`: its generation and servo cycle,
    /// or `None` on timeout.
    pub fn wait_newer(&self, gen: u64, timeout: Duration) -> Option<(u64, u32)> {
        let deadline = Instant::now() + timeout;
        let mut st = self.inner.lock();
        loop {
            if st.answer_gen != gen {
                if let Some(a) = st.answer {
                    return Some((st.answer_gen, a.cycle));
                }
            }
            let now = Instant::now();
            if now >= deadline {
                return None;
            }
            st = match self.inner.cond.wait_timeout(st, deadline - now) {
                Ok((g, _)) => g,
                Err(p) => p.into_inner().0,
            };
        }
    }
}

/// The options an address string may carry after `?`, `&`-separated:
/// `key=/path/to/key` (the pre-shared key's file) and `link=passive`
/// ([`Options::link_passivity`]), so that a C application's `virtOpen`
/// reaches both.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct AddressOptions<'a> {
    pub key: Option<&'a str>,
    pub link_passivity: bool,
}

/// Split `"address?key=/path&link=passive"` into the address and its
/// options; an address without `?` has none. An unknown option, an empty
/// key path or a `link=` other than `passive` is refused.
pub fn split_options(s: &str) -> Result<(&str, AddressOptions<'_>)> {
    let mut o = AddressOptions::default();
    let Some((addr, opts)) = s.split_once('?') else {
        return Ok((s, o));
    };
    for kv in opts.split('&').filter(|kv| !kv.is_empty()) {
        match kv.split_once('=') {
            Some(("key", path)) if !path.is_empty() => o.key = Some(path),
            Some(("link", "passive")) => o.link_passivity = true,
            _ => {
                return Err(VirtError::InvalidAddress(format!(
                    "{s}: unknown option '{kv}' (expected key=/path/to/key or link=passive)"
                )))
            }
        }
    }
    Ok((addr, o))
}

fn load_key(path: &str) -> Result<Psk> {
    Psk::load(std::path::Path::new(path))
        .map_err(|e| VirtError::InvalidArgument(format!("key {path}: {e}")))
}

/// Parse `"host#port"` (VirtuoseAPI style) or `"host"` (port 5000); also
/// accepts `"host:port"`. A `?key=...` suffix is ignored here
/// ([`split_options`]).
pub fn parse_address(s: &str) -> Result<SocketAddr> {
    let s = split_options(s.trim())?.0.trim();
    if s.is_empty() {
        return Err(VirtError::InvalidAddress("empty address".into()));
    }
    let (host, port) = match s.rsplit_once('#') {
        Some((h, p)) => {
            let port: u16 = p
                .parse()
                .map_err(|_| VirtError::InvalidAddress(format!("{s}: bad port '{p}'")))?;
            (h.to_string(), port)
        }
        None => {
            // "host:port" (not for bare IPv6 addresses).
            match s.rsplit_once(':') {
                Some((h, p)) if !h.contains(':') => {
                    let port: u16 = p
                        .parse()
                        .map_err(|_| VirtError::InvalidAddress(format!("{s}: bad port '{p}'")))?;
                    (h.to_string(), port)
                }
                _ => (s.to_string(), DEFAULT_PORT),
            }
        }
    };
    if host.is_empty() {
        return Err(VirtError::InvalidAddress(format!("{s}: empty host")));
    }
    if port == 0 {
        return Err(VirtError::InvalidAddress(format!("{s}: port 0")));
    }
    let host = host.trim_start_matches('[').trim_end_matches(']');
    // A name with several addresses ("localhost": ::1 and 127.0.0.1): the
    // IPv4 one first, as VirtuoseAPI clients expect.
    let addrs: Vec<SocketAddr> = (host, port)
        .to_socket_addrs()
        .map_err(|e| VirtError::InvalidAddress(format!("{s}: {e}")))?
        .collect();
    addrs
        .iter()
        .find(|a| a.is_ipv4())
        .or(addrs.first())
        .copied()
        .ok_or_else(|| VirtError::InvalidAddress(format!("{s}: no address")))
}

impl VirtContext {
    /// Open a session with the controller at `"host#port"` (default port 5000).
    pub fn open(addr: &str) -> Result<VirtContext> {
        VirtContext::open_with(addr, Options::default())
    }

    /// Open with explicit timeouts.
    pub fn open_with(addr: &str, mut opts: Options) -> Result<VirtContext> {
        let peer = parse_address(addr)?;
        let from_addr = split_options(addr.trim())?.1;
        opts.link_passivity |= from_addr.link_passivity;
        let key = match (opts.key.clone(), from_addr.key) {
            (Some(k), _) => Some(k),
            (None, Some(path)) => Some(load_key(path)?),
            (None, None) => match std::env::var(KEY_ENV) {
                Ok(path) if !path.is_empty() => Some(load_key(&path)?),
                _ => None,
            },
        };
        let bind: SocketAddr = if peer.is_ipv4() {
            "0.0.0.0:0"
                .parse()
                .map_err(|_| VirtError::Io("bind".into()))?
        } else {
            "[::]:0".parse().map_err(|_| VirtError::Io("bind".into()))?
        };
        let sock = UdpSocket::bind(bind)?;
        sock.connect(peer)?;
        sock.set_read_timeout(Some(Duration::from_millis(50)))?;
        let rx_sock = sock.try_clone()?;
        let t0 = Instant::now();
        let nonce = (t0.elapsed().as_nanos() as u32)
            ^ std::process::id().rotate_left(16)
            ^ (sock.local_addr().map(|a| a.port()).unwrap_or(0) as u32);
        let inner = Arc::new(Inner {
            sock,
            auth: key.map(|k| Mutex::new(ClientAuth::new(k))),
            state: Mutex::new(State {
                handshake_refused: None,
                session_ended: None,
                cookie_at: None,
                open_attempts: 0,
                session: 0,
                session_nonce: nonce,
                session_ack: None,
                replies: HashMap::new(),
                answer: None,
                twist: Twist::default(),
                last_seq: None,
                stats: LinkStats::default(),
                rtt_sum: 0.0,
                rtt_n: 0,
                last_vpr_seq_seen: None,
                sent_at: vec![(0, None); RTT_RING],
                window_start: Instant::now(),
                window_count: 0,
                answer_gen: 0,
                rtt_log: None,
                rtt_overflow: 0,
                link: ClientLink::new(),
                time_step: Fx::from_ratio(1, 1000),
            }),
            cond: Condvar::new(),
            stop: AtomicBool::new(false),
            seq: AtomicU32::new(0),
            t0,
        });
        let rx_inner = inner.clone();
        let rx = std::thread::Builder::new()
            .name("virtuose_rx".into())
            .spawn(move || receiver(rx_inner, rx_sock))?;
        let mut vc = VirtContext {
            inner,
            rx: Some(rx),
            opts: opts.clone(),
            peer,
            force_factor: 1.0,
            speed_factor: 1.0,
            speed: Mutex::new(Twist::default()),
            power_set: Mutex::new(PowerSet::Reported),
            closed: false,
        };
        // OpenSession, retried until the SessionAck; each attempt waits
        // twice as long as the one before (a controller that is slow to
        // answer its first handshake, e.g. on a loaded or emulated machine,
        // is not asked again and again, each retry opening a new session).
        //
        // Protocol v2: once the cookie came and the proof went, the attempt
        // is never abandoned while that proof could still open a session at
        // the bridge: each further attempt sends the same proof again (the
        // bridge answers a copy with the same session_ack), beyond
        // `attempts` if need be, until the cookie is dead. A new
        // open_session (a new nonce) goes only when no cookie came.
        let mut ok = false;
        let mut wait = opts.reply_timeout;
        let mut round = 0u32;
        loop {
            let proof = vc
                .inner
                .auth
                .as_ref()
                .and_then(|a| lock_poisoned(a).pending_proof());
            let cookie_dies = vc.inner.lock().cookie_at.map(|t| t + COOKIE_LIFE);
            // (The receiver notes the cookie's time under the same lock as
            // the proof: a proof without it cannot be seen.)
            let proof_alive = proof.is_some() && cookie_dies.is_none_or(|d| Instant::now() < d);
            if round >= opts.attempts.max(1) && !proof_alive {
                break;
            }
            round += 1;
            vc.inner.lock().open_attempts = round;
            match proof {
                Some(w) if proof_alive => vc.inner.send_raw(w.bytes())?,
                _ => {
                    vc.inner.lock().cookie_at = None;
                    vc.inner.send(
                        &Frame::OpenSession {
                            client_nonce: nonce,
                        },
                        0,
                    )?;
                }
            }
            let mut deadline = Instant::now() + wait;
            if round > opts.attempts.max(1) {
                // Past the attempts: only until the cookie is dead.
                if let Some(d) = cookie_dies {
                    deadline = deadline.min(d);
                }
            }
            wait = wait.saturating_mul(2);
            let mut st = vc.inner.lock();
            loop {
                if let Some(reason) = st.handshake_refused {
                    drop(st);
                    vc.shutdown();
                    return Err(VirtError::Refused {
                        request: "open_session",
                        reason,
                        name: reason_name(reason),
                    });
                }
                if let Some((session, period)) = st.session_ack {
                    st.session = session;
                    st.stats.period_us = period;
                    ok = true;
                    break;
                }
                let now = Instant::now();
                if now >= deadline {
                    break;
                }
                st = match vc.inner.cond.wait_timeout(st, deadline - now) {
                    Ok((g, _)) => g,
                    Err(p) => p.into_inner().0,
                };
            }
            if ok {
                break;
            }
        }
        if !ok {
            vc.shutdown();
            return Err(VirtError::Timeout("open_session"));
        }
        Ok(vc)
    }

    /// Handshake rounds the open took: 1 when the first `open_session` was
    /// answered in time; each further round sent a new `open_session` (no
    /// cookie came) or the pending `open_proof` again.
    pub fn open_attempts(&self) -> u32 {
        self.inner.lock().open_attempts
    }

    /// `Ok` while the session lasts; once the controller ended it,
    /// [`VirtError::SessionEnded`] with its reason (every call but
    /// [`close`](Self::close) then fails with it).
    pub fn check_session(&self) -> Result<()> {
        match self.inner.lock().session_ended {
            Some(r) => Err(session_ended_error(r)),
            None => Ok(()),
        }
    }

    /// True when the session is authenticated (protocol v2).
    pub fn authenticated(&self) -> bool {
        self.inner.auth.is_some()
    }

    /// The controller's address.
    pub fn peer(&self) -> SocketAddr {
        self.peer
    }

    /// Why the controller ended the session, if it did (protocol v2: the
    /// `error` reason, `ERROR_NO_SESSION` or `hap_auth::ERROR_REPLACED`,
    /// `ERROR_EXPIRED`, `ERROR_SEQ_EXHAUSTED`); requests then fail with
    /// `VirtError::Closed`: open a new context.
    pub fn session_ended(&self) -> Option<u32> {
        self.inner.lock().session_ended
    }

    /// Session id granted by the controller.
    pub fn session_id(&self) -> u16 {
        self.inner.lock().session
    }

    /// Change timeouts and retries.
    pub fn set_options(&mut self, opts: Options) {
        self.opts = opts;
    }

    /// Timeouts and retries in use.
    pub fn options(&self) -> Options {
        self.opts.clone()
    }

    fn check_open(&self) -> Result<()> {
        if self.closed {
            Err(VirtError::Closed)
        } else {
            self.check_session()
        }
    }

    /// Send `frame` with an ACK request; wait for its Ack (retrying).
    fn request(&self, frame: Frame) -> Result<()> {
        self.check_open()?;
        let name = frame.frame_type().name();
        for _ in 0..self.opts.attempts.max(1) {
            let seq = self.inner.send(&frame, CTRL_ACK_REQUEST)?;
            let deadline = Instant::now() + self.opts.reply_timeout;
            let mut st = self.inner.lock();
            loop {
                if let Some(r) = st.replies.remove(&seq) {
                    return match r {
                        Reply::Ack => Ok(()),
                        // The error that ended the session (the notice names
                        // the newest request the bridge accepted).
                        Reply::Error(reason) if st.session_ended == Some(reason) => {
                            Err(session_ended_error(reason))
                        }
                        Reply::Error(reason) => Err(VirtError::Refused {
                            request: name,
                            reason,
                            name: reason_name(reason),
                        }),
                    };
                }
                let now = Instant::now();
                if now >= deadline {
                    break;
                }
                st = match self.inner.cond.wait_timeout(st, deadline - now) {
                    Ok((g, _)) => g,
                    Err(p) => p.into_inner().0,
                };
            }
        }
        Err(VirtError::Timeout(name))
    }

    /// The client's simulation time step, s (`virtSetTimeStep`).
    pub fn set_time_step(&self, dt: f32) -> Result<()> {
        if !(dt > 0.0 && dt <= 1.0) {
            return Err(VirtError::InvalidArgument(format!(
                "time step {dt} not in (0, 1] s"
            )));
        }
        let step = conv::fx("time step", dt)?;
        self.request(Frame::SetTimeStep(step))?;
        self.inner.lock().time_step = step;
        Ok(())
    }

    pub fn set_indexing_mode(&self, mode: IndexingMode) -> Result<()> {
        self.request(Frame::SetIndexingMode(mode))
    }

    pub fn set_command_type(&self, ty: CommandType) -> Result<()> {
        self.request(Frame::SetCommandType(ty))
    }

    /// Scale from arm forces to client forces (> 0).
    pub fn set_force_factor(&mut self, k: f32) -> Result<()> {
        if !(k > 0.0 && k.is_finite()) {
            return Err(VirtError::InvalidArgument(format!(
                "force factor {k} must be > 0"
            )));
        }
        self.request(Frame::SetFactors {
            force: conv::fx("force factor", k)?,
            speed: conv::fx("speed factor", self.speed_factor)?,
        })?;
        self.force_factor = k;
        Ok(())
    }

    /// Scale from arm displacements to client displacements (> 0).
    pub fn set_speed_factor(&mut self, k: f32) -> Result<()> {
        if !(k > 0.0 && k.is_finite()) {
            return Err(VirtError::InvalidArgument(format!(
                "speed factor {k} must be > 0"
            )));
        }
        self.request(Frame::SetFactors {
            force: conv::fx("force factor", self.force_factor)?,
            speed: conv::fx("speed factor", k)?,
        })?;
        self.speed_factor = k;
        Ok(())
    }

    /// World → arm base, `[x,y,z,qx,qy,qz,qw]`.
    pub fn set_base_frame(&self, pose: &[f32; 7]) -> Result<()> {
        self.request(Frame::SetBaseFrame(conv::pose_from("base frame", pose)?))
    }

    /// World → observer, `[x,y,z,qx,qy,qz,qw]`.
    pub fn set_observation_frame(&self, pose: &[f32; 7]) -> Result<()> {
        self.request(Frame::SetObservationFrame(conv::pose_from(
            "observation frame",
            pose,
        )?))
    }

    /// Attach a virtual object of `mass` kg and principal inertia (kg·m²).
    pub fn attach_vo(&self, mass: f32, inertia: [f32; 3]) -> Result<()> {
        if !(mass > 0.0 && mass.is_finite()) {
            return Err(VirtError::InvalidArgument(format!(
                "mass {mass} must be > 0"
            )));
        }
        if inertia.iter().any(|i| !(i.is_finite() && *i >= 0.0)) {
            return Err(VirtError::InvalidArgument(
                "inertia must be finite and >= 0".into(),
            ));
        }
        let p = VirtualObjectParams {
            mass: conv::fx("mass", mass)?,
            inertia: hap_core::fixed::Vec3::from_f64([
                inertia[0] as f64,
                inertia[1] as f64,
                inertia[2] as f64,
            ]),
        };
        self.request(Frame::AttachVirtualObject(p))
    }

    pub fn detach_vo(&self) -> Result<()> {
        self.request(Frame::DetachVirtualObject)
    }

    /// Arm supply power request (`virtSetPowerOn`). Once the controller
    /// acknowledged it, [`get_power_on`](Self::get_power_on) reads `on`
    /// (see there).
    pub fn set_power_on(&self, on: bool) -> Result<()> {
        self.request(Frame::PowerRequest(on))?;
        *lock_poisoned(&self.power_set) = PowerSet::Pending {
            on,
            at: Instant::now(),
        };
        Ok(())
    }

    /// How long a power state acknowledged by the controller is reported
    /// while its answers still show the other one: the time a request may
    /// take (reply timeout × attempts).
    fn power_settle(&self) -> Duration {
        self.opts
            .reply_timeout
            .saturating_mul(self.opts.attempts.max(1))
    }

    /// Twist of the virtual object, `[vx,vy,vz,wx,wy,wz]`; sent with the
    /// next [`set_position`](Self::set_position) (call it first).
    pub fn set_speed(&self, twist: &[f32; 6]) -> Result<()> {
        self.check_open()?;
        let t = conv::twist_from("speed", twist)?;
        *match self.speed.lock() {
            Ok(g) => g,
            Err(p) => p.into_inner(),
        } = t;
        Ok(())
    }

    /// Pose of the virtual object, `[x,y,z,qx,qy,qz,qw]`: streams one
    /// VprStream frame (pose + the last speed given). Not acknowledged.
    ///
    /// With [`Options::link_passivity`], the step that the last
    /// [`get_force`](Self::get_force) began is recorded, and the frame
    /// carries this end's energy grants (`CTRL_LINK_ENERGY`).
    pub fn set_position(&self, pose: &[f32; 7]) -> Result<()> {
        self.check_open()?;
        let pose: Pose = conv::pose_from("position", pose)?;
        let frame = Frame::VprStream {
            pose,
            twist: *match self.speed.lock() {
                Ok(g) => g,
                Err(p) => p.into_inner(),
            },
        };
        if self.opts.link_passivity {
            let granted = {
                let mut st = self.inner.lock();
                st.link.commit();
                st.link.wire_granted()
            };
            self.inner.send_stamped(&frame, CTRL_LINK_ENERGY, granted)?;
        } else {
            self.inner.send(&frame, 0)?;
        }
        Ok(())
    }

    fn with_answer<T>(&self, f: impl FnOnce(&Answer, &State) -> T) -> Result<T> {
        self.check_open()?;
        let st = self.inner.lock();
        match &st.answer {
            Some(a) => Ok(f(a, &st)),
            None => Err(VirtError::NoData),
        }
    }

    /// Handle pose `[x,y,z,qx,qy,qz,qw]` in the client's world frame.
    pub fn get_position(&self) -> Result<[f32; 7]> {
        self.with_answer(|a, _| conv::pose_to(&a.handle_pose))
    }

    /// Handle twist `[vx,vy,vz,wx,wy,wz]` (last AnswerTwist received).
    pub fn get_speed(&self) -> Result<[f32; 6]> {
        self.with_answer(|_, st| conv::twist_to(&st.twist))
    }

    /// Wrench to apply to the virtual object `[fx,fy,fz,tx,ty,tz]`.
    ///
    /// With [`Options::link_passivity`]: the coupling wrench less the push
    /// along the object's motion (the speed last given to
    /// [`set_speed`](Self::set_speed)) that the controller's energy grants
    /// do not cover over one time step ([`set_time_step`](Self::set_time_step)),
    /// to apply until the next [`set_position`](Self::set_position).
    pub fn get_force(&self) -> Result<[f32; 6]> {
        if !self.opts.link_passivity {
            return self.with_answer(|a, _| conv::wrench_to(&a.coupling_wrench));
        }
        self.check_open()?;
        let twist = *match self.speed.lock() {
            Ok(g) => g,
            Err(p) => p.into_inner(),
        };
        let mut st = self.inner.lock();
        let Some(a) = st.answer else {
            return Err(VirtError::NoData);
        };
        // In the controller's units (the grants' unit): client force =
        // force factor × arm force, client length = speed factor × arm
        // length, client torque = both factors × arm torque.
        let (kf, ks) = (self.force_factor, self.speed_factor);
        let w = conv::wrench_to(&a.coupling_wrench);
        let t = conv::twist_to(&twist);
        let arm_w = conv::wrench_from(&[
            w[0] / kf,
            w[1] / kf,
            w[2] / kf,
            w[3] / (kf * ks),
            w[4] / (kf * ks),
            w[5] / (kf * ks),
        ]);
        let arm_t = conv::twist_from(
            "speed",
            &[t[0] / ks, t[1] / ks, t[2] / ks, t[3], t[4], t[5]],
        )?;
        let dt = st.time_step;
        let out: Wrench = st.link.force(&arm_w, &arm_t, dt);
        let o = conv::wrench_to(&out);
        Ok([
            o[0] * kf,
            o[1] * kf,
            o[2] * kf,
            o[3] * kf * ks,
            o[4] * kf * ks,
            o[5] * kf * ks,
        ])
    }

    /// This end's link ledger (`Options::link_passivity`): its port's
    /// energy in and out, its grants and the controller's, J (controller
    /// units).
    pub fn link_ledger(&self) -> hap_core::link::PortLedger {
        self.inner.lock().link.ledger
    }

    /// Raw `hap_core::vp::status` bits of the last answer.
    pub fn get_status(&self) -> Result<u32> {
        self.with_answer(|a, _| a.status)
    }

    /// The arm's power. Read-your-writes: after a [`set_power_on`](Self::set_power_on)
    /// the controller acknowledged, the value set until an answer reports
    /// it (answers sent before the request took effect still show the old
    /// state); from then on, or if no answer reports it within the time a
    /// request may take (the power did not come on, e.g. the fail-safe
    /// refused it), the answers' power bit.
    pub fn get_power_on(&self) -> Result<bool> {
        let reported = self.with_answer(|a, _| a.status & status::POWER_ON != 0)?;
        let mut set = lock_poisoned(&self.power_set);
        Ok(match *set {
            PowerSet::Pending { on, at }
                if on != reported && at.elapsed() < self.power_settle() =>
            {
                on
            }
            PowerSet::Pending { .. } => {
                *set = PowerSet::Reported;
                reported
            }
            PowerSet::Reported => reported,
        })
    }

    pub fn get_dead_man(&self) -> Result<bool> {
        self.with_answer(|a, _| a.status & status::DEAD_MAN != 0)
    }

    pub fn get_emergency_stop(&self) -> Result<bool> {
        self.with_answer(|a, _| a.status & status::EMERGENCY_STOP != 0)
    }

    /// `hap_core::vp::alarm` bits.
    pub fn get_alarm(&self) -> Result<u32> {
        self.with_answer(|a, _| a.alarms)
    }

    /// The last answer's servo cycle counter.
    pub fn get_cycle(&self) -> Result<u32> {
        self.with_answer(|a, _| a.cycle)
    }

    /// Block until an answer newer than the current one arrives, or timeout.
    /// Returns true if one arrived.
    pub fn wait_answer(&self, timeout: Duration) -> bool {
        let deadline = Instant::now() + timeout;
        let mut st = self.inner.lock();
        let gen = st.answer_gen;
        while st.answer_gen == gen {
            let now = Instant::now();
            if now >= deadline {
                return false;
            }
            st = match self.inner.cond.wait_timeout(st, deadline - now) {
                Ok((g, _)) => g,
                Err(p) => p.into_inner().0,
            };
        }
        true
    }

    /// A handle that waits for the controller's answers without holding
    /// this context (another thread may use the context meanwhile).
    pub fn answer_waiter(&self) -> AnswerWaiter {
        AnswerWaiter {
            inner: self.inner.clone(),
        }
    }

    /// Rate, loss and round-trip time measured so far.
    pub fn link_stats(&self) -> LinkStats {
        let st = self.inner.lock();
        let mut s = st.stats;
        let total = s.answers + s.lost;
        s.loss_ratio = if total > 0 {
            s.lost as f64 / total as f64
        } else {
            0.0
        };
        s.rtt_ms_mean = if st.rtt_n > 0 {
            st.rtt_sum / st.rtt_n as f64
        } else {
            0.0
        };
        // Before the first window closes: the rate over what was seen so far
        // (a session that ran its answers in less than a window has one).
        let el = st.window_start.elapsed().as_secs_f64();
        if s.rate_hz == 0.0 && st.window_count > 0 && el > 0.0 {
            s.rate_hz = st.window_count as f64 / el;
        }
        s
    }

    /// Start (true) or stop (false) recording every round trip as an
    /// [`RttSample`]; collect them with [`drain_rtt`](Self::drain_rtt).
    pub fn record_rtt(&self, on: bool) {
        let mut st = self.inner.lock();
        match (on, st.rtt_log.is_some()) {
            (true, false) => st.rtt_log = Some(Vec::with_capacity(4096)),
            (false, true) => st.rtt_log = None,
            _ => {}
        }
    }

    /// Move the round trips recorded since the last call to `out`.
    pub fn drain_rtt(&self, out: &mut Vec<RttSample>) {
        if let Some(log) = self.inner.lock().rtt_log.as_mut() {
            out.append(log);
        }
    }

    /// Round trips not recorded because more than [`RTT_LOG_MAX`] were
    /// waiting to be drained.
    pub fn rtt_overflow(&self) -> u64 {
        self.inner.lock().rtt_overflow
    }

    /// Close the session (CloseSession, acknowledged if the controller
    /// answers in time) and stop the receiver thread. Idempotent.
    pub fn close(&mut self) -> Result<()> {
        if self.closed {
            return Ok(());
        }
        let r = self.request(Frame::CloseSession);
        self.shutdown();
        match r {
            // Nothing to close: the controller ended the session already.
            Err(VirtError::Timeout(_)) | Err(VirtError::SessionEnded { .. }) | Ok(()) => Ok(()),
            Err(e) => Err(e),
        }
    }

    fn shutdown(&mut self) {
        self.closed = true;
        self.inner.stop.store(true, Ordering::SeqCst);
        if let Some(h) = self.rx.take() {
            let _ = h.join();
        }
    }
}

impl Drop for VirtContext {
    fn drop(&mut self) {
        if !self.closed {
            // Best effort: tell the controller, do not wait.
            let _ = self.inner.send(&Frame::CloseSession, 0);
            self.shutdown();
        }
    }
}

/// How long a cookie keeps its `open_proof` valid at the bridge, at most
/// (two cookie epochs from when the bridge made it, before it came).
const COOKIE_LIFE: Duration = Duration::from_secs(2 * hap_auth::COOKIE_EPOCH_S);

fn session_ended_error(reason: u32) -> VirtError {
    VirtError::SessionEnded {
        reason,
        name: reason_name(reason),
    }
}

fn reason_name(reason: u32) -> String {
    match reason {
        ERROR_NO_SESSION => "no session".into(),
        ERROR_REFUSED => "refused: the controller cannot take a handshake now".into(),
        hap_auth::ERROR_REPLACED => "session replaced by a newer handshake with this key".into(),
        hap_auth::ERROR_EXPIRED => "session expired (the client was silent too long)".into(),
        hap_auth::ERROR_SEQ_EXHAUSTED => {
            "session ended: its sequence numbers are spent (open a new one)".into()
        }
        r => match DecodeError::from_index(r as usize) {
            Some(e) => e.name().into(),
            None => format!("reason {r}"),
        },
    }
}

fn receiver(inner: Arc<Inner>, sock: UdpSocket) {
    let mut buf = [0u8; 2048];
    while !inner.stop.load(Ordering::SeqCst) {
        let n = match sock.recv(&mut buf) {
            Ok(n) => n,
            Err(_) => continue, // timeout, ICMP unreachable...: keep going
        };
        let decoded = match &inner.auth {
            None => decode(&buf[..n]).ok(),
            Some(a) => {
                let mut g = lock_poisoned(a);
                let r = g.open(&buf[..n]);
                if let Ok((_, AuthReply::Cookie)) = r {
                    // The bridge's cookie: prove the key over it, under the
                    // same lock (the open loop sends this proof again, never
                    // a second one for the attempt). The open_proof's
                    // sequence number starts the session.
                    let h = FrameHeader {
                        control: 0,
                        session: 0,
                        seq: inner.next_seq(),
                        timestamp_us: inner.now_us(),
                    };
                    let proof = g.prove(&h);
                    // Noted before the auth lock goes (lock order: auth,
                    // then state, everywhere both are held).
                    inner.lock().cookie_at = Some(Instant::now());
                    drop(g);
                    if let Some(w) = proof {
                        if inner.sock.send(w.bytes()).is_ok() {
                            inner.lock().stats.sent += 1;
                        }
                    }
                    continue;
                }
                drop(g);
                match r {
                    Ok((_, AuthReply::Cookie)) => continue,
                    Ok((h, AuthReply::Frame(f))) => Some((h, f)),
                    Ok((h, AuthReply::SessionAck { period_us })) => {
                        // Verified against this handshake's nonce: the v1
                        // path below matches on the v1 nonce.
                        let client_nonce = inner.lock().session_nonce;
                        Some((
                            h,
                            Frame::SessionAck {
                                client_nonce,
                                period_us,
                            },
                        ))
                    }
                    Ok((_, AuthReply::HandshakeRefused { reason })) => {
                        inner.lock().handshake_refused = Some(reason);
                        inner.cond.notify_all();
                        continue;
                    }
                    // A controller frame before our session_ack (the servo
                    // may answer the new session first): no keys yet,
                    // ignored as v1 ignores answers before the ack.
                    Err(hap_auth::Refusal::NoSession) => continue,
                    Err(_) => None,
                }
            }
        };
        let Some((h, frame)) = decoded else {
            inner.lock().stats.decode_errors += 1;
            continue;
        };
        let mut st = inner.lock();
        match frame {
            Frame::SessionAck {
                client_nonce,
                period_us,
            } => {
                if client_nonce == st.session_nonce {
                    st.session_ack = Some((h.session, period_us));
                    // A new session: controller sequence numbers restart,
                    // and both ends' energy totals.
                    st.last_seq = None;
                    st.link.reset();
                }
            }
            Frame::Ack { acked_seq, .. } => {
                if st.session_ack.is_some() {
                    account_seq(&mut st, h.seq);
                }
                if st.replies.len() > 1024 {
                    st.replies.clear();
                }
                st.replies.insert(acked_seq, Reply::Ack);
            }
            Frame::Error {
                reason,
                rejected_seq,
            } => {
                if st.session_ack.is_some() {
                    account_seq(&mut st, h.seq);
                }
                let ends = matches!(
                    reason,
                    ERROR_NO_SESSION
                        | hap_auth::ERROR_REPLACED
                        | hap_auth::ERROR_EXPIRED
                        | hap_auth::ERROR_SEQ_EXHAUSTED
                );
                if inner.auth.is_some() && ends {
                    st.session_ended = Some(reason);
                }
                if st.replies.len() > 1024 {
                    st.replies.clear();
                }
                st.replies.insert(rejected_seq, Reply::Error(reason));
            }
            Frame::Answer(_) | Frame::AnswerTwist(_) => {
                if st.session_ack.is_none() {
                    continue;
                }
                if !account_seq(&mut st, h.seq) {
                    continue;
                }
                match frame {
                    Frame::Answer(a) => {
                        on_answer(&mut st, a);
                    }
                    Frame::AnswerTwist(t) => {
                        st.link.on_peer_total(t.link_energy);
                        st.twist = t.handle_twist;
                        if let Some(a) = st.answer.as_mut() {
                            a.status = t.status;
                            a.alarms = t.alarms;
                        }
                    }
                    _ => {}
                }
            }
            // Requests coming back to us: ignore.
            _ => continue,
        }
        drop(st);
        inner.cond.notify_all();
    }
}

/// Duplicate / stale / loss accounting on the controller's sequence numbers:
/// one counter for all its frames (answers, answer twists, acks, errors), so
/// replies are accounted too, else each would look like a lost answer.
/// Returns false for a duplicate or stale frame.
fn account_seq(st: &mut State, seq: u32) -> bool {
    if let Some(last) = st.last_seq {
        if seq == last {
            st.stats.duplicates += 1;
            return false;
        }
        if !seq_newer(seq, last) {
            st.stats.stale += 1;
            return false;
        }
        let gap = seq.wrapping_sub(last) as u64;
        if gap > 1 && gap < 1_000_000 {
            st.stats.lost += gap - 1;
        }
    }
    st.last_seq = Some(seq);
    true
}

fn on_answer(st: &mut State, a: Answer) {
    st.stats.answers += 1;
    st.answer_gen += 1;
    st.window_count += 1;
    let el = st.window_start.elapsed();
    if el >= Duration::from_millis(500) {
        st.stats.rate_hz = st.window_count as f64 / el.as_secs_f64();
        st.window_count = 0;
        st.window_start = Instant::now();
    }
    if st.last_vpr_seq_seen != Some(a.vpr_seq) {
        st.last_vpr_seq_seen = Some(a.vpr_seq);
        let slot = st.sent_at[a.vpr_seq as usize % RTT_RING];
        if slot.0 == a.vpr_seq {
            if let Some(t) = slot.1 {
                let el = t.elapsed();
                let rtt = el.as_secs_f64() * 1e3;
                let sample = RttSample {
                    vpr_seq: a.vpr_seq,
                    rtt_us: u32::try_from(el.as_micros()).unwrap_or(u32::MAX),
                    cycle: a.cycle,
                };
                let mut overflow = false;
                if let Some(log) = st.rtt_log.as_mut() {
                    if log.len() < RTT_LOG_MAX {
                        log.push(sample);
                    } else {
                        overflow = true;
                    }
                }
                if overflow {
                    st.rtt_overflow += 1;
                }
                st.stats.rtt_ms_last = rtt;
                st.rtt_sum += rtt;
                st.rtt_n += 1;
                if rtt > st.stats.rtt_ms_max {
                    st.stats.rtt_ms_max = rtt;
                }
                st.sent_at[a.vpr_seq as usize % RTT_RING].1 = None;
            }
        }
    }
    st.answer = Some(a);
}

fn lock_poisoned<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    match m.lock() {
        Ok(g) => g,
        Err(p) => p.into_inner(),
    }
}

/// Names of the frame types (for logs).
pub fn frame_type_name(t: FrameType) -> &'static str {
    t.name()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn addresses() {
        assert_eq!(parse_address("127.0.0.1#5001").unwrap().port(), 5001);
        assert_eq!(parse_address("127.0.0.1").unwrap().port(), 5000);
        assert_eq!(parse_address("127.0.0.1:6000").unwrap().port(), 6000);
        assert_eq!(parse_address("localhost#7").unwrap().port(), 7);
        assert!(parse_address("localhost#7").unwrap().is_ipv4());
        assert!(parse_address("").is_err());
        assert!(parse_address("127.0.0.1#x").is_err());
        assert!(parse_address("127.0.0.1#70000").is_err());
        assert!(parse_address("#5000").is_err());
        assert!(parse_address("127.0.0.1#0").is_err());
        assert_eq!(parse_address("127.0.0.1#5001?key=/k").unwrap().port(), 5001);
        let key = |k| AddressOptions {
            key: Some(k),
            link_passivity: false,
        };
        assert_eq!(
            split_options("h#1?key=/etc/hap.key").unwrap(),
            ("h#1", key("/etc/hap.key"))
        );
        assert_eq!(
            split_options("h#1").unwrap(),
            ("h#1", AddressOptions::default())
        );
        assert_eq!(
            split_options("h#1?key=/k&link=passive").unwrap(),
            (
                "h#1",
                AddressOptions {
                    key: Some("/k"),
                    link_passivity: true
                }
            )
        );
        assert!(split_options("h#1?link=passive").unwrap().1.link_passivity);
        assert!(split_options("h#1?kex=/x").is_err());
        assert!(split_options("h#1?key=").is_err());
        assert!(split_options("h#1?link=active").is_err());
        assert!(split_options("h#1?link").is_err());
    }

    #[test]
    fn error_codes_are_distinct() {
        let all = [
            VirtError::InvalidAddress(String::new()),
            VirtError::Io(String::new()),
            VirtError::Timeout("x"),
            VirtError::Refused {
                request: "x",
                reason: 0,
                name: String::new(),
            },
            VirtError::InvalidArgument(String::new()),
            VirtError::NoData,
            VirtError::Closed,
            VirtError::NullPointer,
        ];
        let mut codes: Vec<i32> = all.iter().map(|e| e.code()).collect();
        codes.sort();
        codes.dedup();
        assert_eq!(codes.len(), all.len());
        for e in &all {
            assert_ne!(VirtError::code_message(e.code()), "unknown error code");
            assert!(!e.to_string().is_empty());
        }
    }
}
