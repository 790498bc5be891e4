//! hap_proto_interface: the user-space half of the haptic protocol
//! (spec D9rb.2 §3.3.1.1 and §3.3.1.4).
//!
//! - SERVER thread: receives UDP datagrams from the client application and
//!   writes each whole, valid frame to the kernel's input device
//!   (`/dev/hap_rtf_in`, one frame per `write()`).
//! - CLIENT thread: reads whole answer frames from `/dev/hap_rtf_out` (one
//!   frame per `read()`, 90-byte buffer) and sends them to the session's
//!   client with `sendto()`, from the same UDP socket (so NAT and port
//!   forwards see one flow).
//! - The main thread (see `main.rs`) sleeps until SIGTERM/SIGINT or until a
//!   thread reports that a device went away, prints the counters on SIGUSR1.
//!
//! Authentication (protocol v2, `hap_auth`): the bridge is the trust
//! boundary. Every client datagram is verified (HMAC tag, session, anti-
//! replay window) before anything is written to the kernel's input device;
//! what the kernel reads is the verified frame re-encoded as v1 (same header
//! and payload bytes, CRC-32C). Answers read from the kernel are sealed for
//! the client. Unauthenticated v1 (`--insecure`) forwards the received bytes
//! as they are, after hap-core's decoder accepted them.

pub mod counters;
pub mod frames;
pub mod privdrop;
pub mod ratelimit;
pub mod rtbudget;
pub mod session;

use hap_auth::{Action, EndReason, Ended, Gate, Kind, Psk, Refusal};
use ratelimit::{HandshakeBudget, RateLimit, Served};
use rtbudget::RtBudget;

use std::fs::{File, OpenOptions};
use std::io::{ErrorKind, Read, Write};
use std::net::{SocketAddr, UdpSocket};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use counters::Counters;
use session::{Decision, FrameKind, Session};

/// Largest frame the protocol allows (spec §3.3.1.1: 90 bytes).
pub const MAX_FRAME: usize = frames::MAX_FRAME;

/// Everything the bridge needs; built from the command line in `main.rs`.
#[derive(Clone, Debug)]
pub struct Config {
    pub bind: SocketAddr,
    pub rtf_in: PathBuf,
    pub rtf_out: PathBuf,
    pub stats_file: Option<PathBuf>,
    pub session_timeout: Duration,
    /// How often the stats file is rewritten.
    pub stats_interval: Duration,
    /// The pre-shared key (protocol v2); `None`: unauthenticated v1
    /// (`--insecure`).
    pub key: Option<Psk>,
    /// Refused datagrams per second and source IP before that IP is
    /// dropped unexamined (0: no limit).
    pub refusal_budget: u32,
    /// Cookies per second (answers to verified `open_session`s), all
    /// sources together (bursts of twice that; 0: no limit); IPs that
    /// answered a cookie lately do not wait on it.
    pub handshake_budget: u32,
    /// Cookies per second and source IP (bursts of twice that; 0: no
    /// limit).
    pub handshake_budget_per_ip: u32,
    /// The SCHED_FIFO priority the process was given (`--rt-priority`), so
    /// that the SERVER thread can return to it; `None`: SCHED_OTHER.
    pub rt_priority: Option<i32>,
    /// Share of a CPU, in percent, the SERVER thread may use at its
    /// real-time priority (`rtbudget`); 100: never demoted.
    pub rt_budget_percent: u32,
}

/// State shared by the threads and the main thread.
pub struct Shared {
    pub counters: Counters,
    pub client: Mutex<Option<SocketAddr>>,
    /// The client whose CloseSession was forwarded last: the kernel's ack or
    /// error for it (and nothing else) is still sent there.
    pub closed_by: Mutex<Option<SocketAddr>>,
    pub stop: AtomicBool,
    /// Set by a thread that hit a fatal condition (device gone...).
    pub fatal: Mutex<Option<String>>,
    /// The authenticating gate (v2); `None` in `--insecure` mode.
    pub gate: Option<Mutex<Gate>>,
}

impl Shared {
    pub fn client(&self) -> Option<SocketAddr> {
        self.client.lock().map(|g| *g).unwrap_or(None)
    }

    /// The counters as `key: value` text.
    pub fn render(&self) -> String {
        self.counters.render(self.client())
    }

    fn set_fatal(&self, why: String) {
        if let Ok(mut f) = self.fatal.lock() {
            if f.is_none() {
                *f = Some(why);
            }
        }
        self.stop.store(true, Ordering::SeqCst);
    }
}

/// Run the calling process's threads (this one and those it starts later,
/// which inherit it) under `SCHED_FIFO` at `priority` (1..=99), below the
/// module's kernel tasks (SERVO 80, CLOCK 90) when `priority` < 80: under a
/// heavy userspace load a SCHED_OTHER bridge only gets its fair share of the
/// CPU and the link's latency grows with the load. Needs CAP_SYS_NICE.
pub fn set_fifo_priority(priority: i32) -> std::io::Result<()> {
    if !(1..=99).contains(&priority) {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("SCHED_FIFO priority {priority} is outside 1..=99"),
        ));
    }
    let param = libc::sched_param {
        sched_priority: priority,
    };
    // SAFETY: `param` is a valid, initialised sched_param that outlives the
    // call; pid 0 is the calling thread.
    let rc = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
    if rc == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

/// Write the stats file atomically (temp file + rename).
pub fn write_stats_file(path: &Path, text: &str) -> std::io::Result<()> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    std::fs::write(&tmp, text)?;
    std::fs::rename(&tmp, path)
}

/// Bind the UDP socket (a large receive buffer for bursts). The port is
/// never shared: no `SO_REUSEADDR` or `SO_REUSEPORT`, so a port another
/// process holds (or binds at the same time) is refused with `EADDRINUSE`
/// and a process started later cannot bind it to read the bridge's
/// datagrams.
pub fn bind_socket(addr: SocketAddr) -> std::io::Result<UdpSocket> {
    use socket2::{Domain, Protocol, Socket, Type};
    let sock = Socket::new(Domain::for_address(addr), Type::DGRAM, Some(Protocol::UDP))?;
    sock.set_reuse_address(false)?;
    let _ = sock.set_recv_buffer_size(1 << 20);
    sock.bind(&addr.into()).map_err(|e| {
        if e.kind() == ErrorKind::AddrInUse {
            std::io::Error::new(
                ErrorKind::AddrInUse,
                format!(
                    "udp {addr} is already in use by another process (the bridge never \
                     shares its port: stop the other process or choose another --port)"
                ),
            )
        } else {
            e
        }
    })?;
    let udp: UdpSocket = sock.into();
    udp.set_read_timeout(Some(Duration::from_millis(100)))?;
    Ok(udp)
}

/// Open a device, retrying until it exists (the launch script starts the
/// bridge before it inserts the module) or until `stop` is set.
fn open_device(path: &Path, write: bool, shared: &Shared) -> Option<File> {
    let mut warned = false;
    loop {
        if shared.stop.load(Ordering::SeqCst) {
            return None;
        }
        let r = if write {
            OpenOptions::new().write(true).open(path)
        } else {
            OpenOptions::new().read(true).open(path)
        };
        match r {
            Ok(f) => return Some(f),
            Err(e) => {
                if !warned {
                    eprintln!("proto_interface: waiting for {} ({e})", path.display());
                    warned = true;
                }
                std::thread::sleep(Duration::from_millis(100));
            }
        }
    }
}

/// The running bridge: its two threads and the shared state.
pub struct Bridge {
    pub shared: Arc<Shared>,
    pub local_addr: SocketAddr,
    server: Option<JoinHandle<()>>,
    client: Option<JoinHandle<()>>,
}

impl Bridge {
    /// Bind the socket and start the SERVER and CLIENT threads. `on_fatal`
    /// is called (from a worker thread) when the bridge must stop on its
    /// own, e.g. to wake the main thread's signal loop.
    pub fn start(
        cfg: Config,
        on_fatal: impl Fn() + Send + Sync + 'static,
    ) -> std::io::Result<Bridge> {
        let sock = bind_socket(cfg.bind)?;
        let local_addr = sock.local_addr()?;
        let tx = sock.try_clone()?;
        let shared = Arc::new(Shared {
            counters: Counters::default(),
            client: Mutex::new(None),
            closed_by: Mutex::new(None),
            stop: AtomicBool::new(false),
            fatal: Mutex::new(None),
            gate: match cfg.key.clone() {
                Some(k) => Some(Mutex::new(Gate::with_random_secret(k)?)),
                None => None,
            },
        });
        if shared.gate.is_none() {
            shared.counters.insecure.store(1, Ordering::Relaxed);
        }
        let on_fatal = Arc::new(on_fatal);

        let sh = shared.clone();
        let cfg_s = cfg.clone();
        let fatal_s = on_fatal.clone();
        let server = std::thread::Builder::new()
            .name("SERVER".into())
            .spawn(move || {
                server_loop(&cfg_s, &sock, &sh);
                if sh.fatal.lock().map(|f| f.is_some()).unwrap_or(false) {
                    fatal_s();
                }
            })?;

        let sh = shared.clone();
        let fatal_c = on_fatal;
        let client = std::thread::Builder::new()
            .name("CLIENT".into())
            .spawn(move || {
                client_loop(&cfg, &tx, &sh);
                if sh.fatal.lock().map(|f| f.is_some()).unwrap_or(false) {
                    fatal_c();
                }
            })?;

        Ok(Bridge {
            shared,
            local_addr,
            server: Some(server),
            client: Some(client),
        })
    }

    /// Ask the threads to stop and wait up to a second for them (a thread
    /// blocked in open() or read() of a device is left to die with the
    /// process).
    pub fn stop(&mut self) {
        self.shared.stop.store(true, Ordering::SeqCst);
        let deadline = Instant::now() + Duration::from_secs(1);
        for h in [self.server.take(), self.client.take()]
            .into_iter()
            .flatten()
        {
            while !h.is_finished() && Instant::now() < deadline {
                std::thread::sleep(Duration::from_millis(10));
            }
            if h.is_finished() {
                let _ = h.join();
            }
        }
    }
}

fn server_loop(cfg: &Config, sock: &UdpSocket, shared: &Shared) {
    let mut session = Session::new(cfg.session_timeout);
    // Bigger than any valid frame so that oversized datagrams are seen as
    // such (never truncated into the kernel).
    let mut buf = [0u8; 2048];
    let mut last_stats = Instant::now();
    let mut dev: Option<File> = None;
    let mut stats_warned = false;
    let mut limit = RateLimit::new(cfg.refusal_budget);
    let mut hellos = HandshakeBudget::new(
        cfg.handshake_budget_per_ip,
        cfg.handshake_budget,
        Instant::now(),
    );
    // The gate's clock (cookie epochs): monotonic, from the bridge's start.
    let clock = Instant::now();
    let mut refusal_log = [None; Refusal::COUNT];
    let mut insecure_log: Option<Instant> = None;
    let mut budget = cfg.rt_priority.map(|p| {
        (
            p,
            RtBudget::new(
                cfg.rt_budget_percent,
                Instant::now(),
                rtbudget::thread_cpu_time(),
            ),
        )
    });
    let mut budget_log: Option<Instant> = None;

    loop {
        if shared.stop.load(Ordering::SeqCst) {
            break;
        }
        if dev.is_none() {
            dev = open_device(&cfg.rtf_in, true, shared);
            if dev.is_none() {
                break;
            }
        }
        let now = Instant::now();
        if let Some(path) = &cfg.stats_file {
            if now.duration_since(last_stats) >= cfg.stats_interval {
                last_stats = now;
                if let Err(e) = write_stats_file(path, &shared.render()) {
                    if !stats_warned {
                        eprintln!("proto_interface: cannot write {}: {e}", path.display());
                        stats_warned = true;
                    }
                }
            }
        }
        if let Some((prio, b)) = budget.as_mut() {
            if b.window_ended(now) {
                if let Some(s) = b.end_window(now, rtbudget::thread_cpu_time()) {
                    apply_switch(b, s, *prio, shared, &mut budget_log, now);
                }
            }
        }
        let had = session.client();
        let expired = session.expire(now);
        if let Some(g) = &shared.gate {
            let why = if expired {
                Some(EndReason::Expired)
            } else if lock(g).exhausted() {
                session.end();
                Some(EndReason::SeqExhausted)
            } else {
                None
            };
            if let Some(why) = why {
                let ended = lock(g).end_session(why);
                if let Some(e) = ended {
                    end_in_module(&e, had, sock, dev.as_mut(), shared, cfg);
                }
                Counters::inc(&shared.counters.sessions_ended_by_bridge);
            }
        }
        if expired || had != session.client() {
            publish_session(shared, &session);
        }
        if shared.gate.is_none()
            && insecure_log.is_none_or(|t| now.duration_since(t) >= Duration::from_secs(60))
        {
            insecure_log = Some(now);
            eprintln!(
                "proto_interface: INSECURE: unauthenticated protocol v1, any host that can \
                 reach udp {} can steer the arm ({} v1 frames forwarded so far)",
                cfg.bind,
                shared.counters.insecure_frames.load(Ordering::Relaxed)
            );
        }
        let (n, src) = match sock.recv_from(&mut buf) {
            Ok(x) => x,
            Err(e)
                if matches!(
                    e.kind(),
                    ErrorKind::WouldBlock | ErrorKind::TimedOut | ErrorKind::Interrupted
                ) =>
            {
                continue
            }
            Err(e) => {
                // ICMP errors reported on the socket (ECONNREFUSED from a
                // previous sendto) are not fatal for a UDP server.
                if e.kind() == ErrorKind::ConnectionRefused {
                    continue;
                }
                shared.set_fatal(format!("recvfrom: {e}"));
                break;
            }
        };
        Counters::inc(&shared.counters.received);
        let data = &buf[..n];
        let now = Instant::now();
        // A source whose refusals are over budget is dropped before any
        // HMAC, but for the session's client and for handshake frames (at
        // most one HMAC each: a key holder behind the flooder's IP still
        // opens). Every drop is charged to the source's IP.
        let examined_anyway = shared.gate.is_some() && hap_auth::is_handshake(data);
        if !examined_anyway && !limit.allow(src, session.client(), now) {
            shared.counters.refuse(Refusal::RateLimited);
            limit.charge(src, now);
            continue;
        }
        let step = match &shared.gate {
            Some(gate) => {
                let clock_now = now.saturating_duration_since(clock);
                let mut ctx = Ctx {
                    sock,
                    shared,
                    cfg,
                    hellos: &mut hellos,
                };
                authenticated(gate, &mut session, src, data, &mut ctx, now, clock_now)
            }
            None => insecure(&mut session, src, data, shared, now),
        };
        let frame = match step {
            Step::Refused(r) => {
                shared.counters.refuse(r);
                limit.charge(src, now);
                log_refusal(&mut refusal_log, r, src, now);
                if r == Refusal::SeqExhausted {
                    // The key holder's request would take its session's
                    // numbers to 2^31: the session ends (0x104).
                    if let Some(g) = &shared.gate {
                        let had = session.end();
                        if let Some(e) = lock(g).end_session(EndReason::SeqExhausted) {
                            end_in_module(&e, had, sock, dev.as_mut(), shared, cfg);
                            Counters::inc(&shared.counters.sessions_ended_by_bridge);
                        }
                        publish_session(shared, &session);
                    }
                }
                continue;
            }
            Step::Done => continue,
            Step::Forward(w) => w,
        };
        publish_session(shared, &session);
        let Some(f) = dev.as_mut() else { continue };
        match f.write(frame.bytes()) {
            Ok(w) if w == frame.len => Counters::inc(&shared.counters.forwarded),
            Ok(_) => Counters::inc(&shared.counters.write_errors),
            Err(e) => {
                Counters::inc(&shared.counters.write_errors);
                if is_device_gone(&e) {
                    shared.set_fatal(format!("{}: {e}", cfg.rtf_in.display()));
                    break;
                }
            }
        }
    }
    if let Some(path) = &cfg.stats_file {
        let _ = write_stats_file(path, &shared.render());
    }
}

/// Apply the real-time budget's decision to the calling (SERVER) thread;
/// count it, and log it at most once every 10 s.
fn apply_switch(
    b: &mut RtBudget,
    s: rtbudget::Switch,
    prio: i32,
    shared: &Shared,
    log: &mut Option<Instant>,
    now: Instant,
) {
    match rtbudget::set_policy(s.to, prio) {
        Ok(()) => {
            b.applied(s);
            let demoted = s.to == rtbudget::Policy::Other;
            shared
                .counters
                .server_demoted
                .store(u64::from(demoted), Ordering::Relaxed);
            Counters::inc(if demoted {
                &shared.counters.rt_demotions
            } else {
                &shared.counters.rt_restores
            });
            if log.is_none_or(|t| now.duration_since(t) >= Duration::from_secs(10)) {
                *log = Some(now);
                eprintln!(
                    "proto_interface: SERVER thread used {} us of CPU in {} us; {} \
                     ({} demotions so far)",
                    s.used.as_micros(),
                    s.window.as_micros(),
                    if demoted {
                        "over its real-time budget: SCHED_OTHER until a window within it"
                            .to_string()
                    } else {
                        format!("within its budget again: SCHED_FIFO {prio}")
                    },
                    shared.counters.rt_demotions.load(Ordering::Relaxed)
                );
            }
        }
        Err(e) => {
            Counters::inc(&shared.counters.rt_policy_errors);
            if log.is_none_or(|t| now.duration_since(t) >= Duration::from_secs(10)) {
                *log = Some(now);
                eprintln!(
                    "proto_interface: cannot set the SERVER thread to {:?}: {e}",
                    s.to
                );
            }
        }
    }
}

/// What the SERVER thread does with one datagram.
enum Step {
    /// Write this v1 frame to the kernel.
    Forward(hap_auth::Wire),
    /// Refused, count it.
    Refused(Refusal),
    /// Handled (an authenticated reply was sent), nothing to write.
    Done,
}

fn lock(g: &Mutex<Gate>) -> std::sync::MutexGuard<'_, Gate> {
    match g.lock() {
        Ok(x) => x,
        Err(p) => p.into_inner(),
    }
}

/// What `authenticated` needs of the SERVER thread besides the gate.
struct Ctx<'a> {
    sock: &'a UdpSocket,
    shared: &'a Shared,
    cfg: &'a Config,
    hellos: &'a mut HandshakeBudget,
}

/// Send `w` to `to`, counting a failure.
fn send(sock: &UdpSocket, shared: &Shared, w: &hap_auth::Wire, to: SocketAddr) -> bool {
    let ok = sock.send_to(w.bytes(), to).is_ok();
    if !ok {
        Counters::inc(&shared.counters.send_errors);
    }
    ok
}

/// A session the bridge ended: tell its client why (it was proven, the
/// notice goes to it only), and close the session in the module with the
/// gate's v1 `close_session`, so that PROTO_IN resets the configuration and
/// the VPr as for the client's own close.
fn end_in_module(
    e: &Ended,
    client: Option<SocketAddr>,
    sock: &UdpSocket,
    dev: Option<&mut File>,
    shared: &Shared,
    cfg: &Config,
) {
    if let Some(to) = client {
        if send(sock, shared, &e.notice, to) {
            Counters::inc(&shared.counters.refusals_answered);
        }
    }
    if let (Some(close), Some(f)) = (e.kernel_close, dev) {
        match f.write(close.bytes()) {
            Ok(w) if w == close.len => Counters::inc(&shared.counters.kernel_closes),
            Ok(_) => Counters::inc(&shared.counters.write_errors),
            Err(err) => {
                Counters::inc(&shared.counters.write_errors);
                if is_device_gone(&err) {
                    shared.set_fatal(format!("{}: {err}", cfg.rtf_in.display()));
                }
            }
        }
    }
}

/// Protocol v2: verify, apply the address policy, commit. Until a source
/// has proven the key (a committed `open_proof`), its only answer is the
/// `cookie`, one per `open_session`, at most [`hap_auth::AMPLIFICATION_FACTOR`]
/// times its size.
fn authenticated(
    gate: &Mutex<Gate>,
    session: &mut Session,
    src: SocketAddr,
    data: &[u8],
    ctx: &mut Ctx<'_>,
    now: Instant,
    clock_now: Duration,
) -> Step {
    let shared = ctx.shared;
    let mut g = lock(gate);
    let i = match g.inspect(data, src, clock_now) {
        Ok(i) => i,
        Err(r) => return Step::Refused(r),
    };
    let decision = match i.kind {
        Kind::Hello => match ctx.hellos.allow_hello(src.ip(), now) {
            Err(r) => return Step::Refused(r),
            Ok(Served::First { under_load: true }) => {
                Counters::inc(&shared.counters.cookies_under_load);
                Decision::Forward
            }
            Ok(_) => Decision::Forward,
        },
        Kind::ProofCopy => session.admit(src, FrameKind::Other, now),
        Kind::Proof => {
            let before = session.client();
            session.admit_proven(src, now);
            ctx.hellos.proven(src.ip(), now);
            Counters::inc(&shared.counters.verified);
            let action = g.commit(&i, clock_now);
            if let Some(e) = g.take_replaced() {
                // The kernel's open_session below closes it in the module.
                let e = Ended {
                    kernel_close: None,
                    ..e
                };
                drop(g);
                end_in_module(&e, before, ctx.sock, None, shared, ctx.cfg);
                return finish(action, src, ctx, data.len());
            }
            drop(g);
            return finish(action, src, ctx, data.len());
        }
        Kind::Close => session.admit(src, FrameKind::CloseSession, now),
        Kind::Other => session.admit(src, FrameKind::Other, now),
    };
    if let Decision::Drop(r) = decision {
        return Step::Refused(r);
    }
    if !matches!(i.kind, Kind::Hello | Kind::ProofCopy) {
        Counters::inc(&shared.counters.verified);
    }
    let action = g.commit(&i, clock_now);
    drop(g);
    finish(action, src, ctx, data.len())
}

/// Carry out the gate's decision on a datagram of `received` bytes from `src`.
fn finish(action: Action, src: SocketAddr, ctx: &mut Ctx<'_>, received: usize) -> Step {
    let shared = ctx.shared;
    match action {
        Action::Forward(w) => Step::Forward(w),
        Action::Challenge(w) => {
            // Never true with hap-auth's sizes (68 bytes for 48): the rule
            // is checked where the bytes leave.
            if w.len > hap_auth::AMPLIFICATION_FACTOR * received {
                Counters::inc(&shared.counters.amplification_refused);
                return Step::Done;
            }
            if send(ctx.sock, shared, &w, src) {
                Counters::inc(&shared.counters.cookies_sent);
                shared
                    .counters
                    .cookie_bytes
                    .fetch_add(w.len as u64, Ordering::Relaxed);
            }
            Step::Done
        }
        Action::Reply(w, r) => {
            if r == Refusal::Replay {
                Counters::inc(&shared.counters.retransmits_reacked);
            } else if r == Refusal::HandshakeReplay {
                // A copy of the live session's open_proof: its session_ack.
                Counters::inc(&shared.counters.proofs_reacked);
            } else {
                shared.counters.refuse(r);
                Counters::inc(&shared.counters.refusals_answered);
            }
            send(ctx.sock, shared, &w, src);
            Step::Done
        }
    }
}

/// Unauthenticated v1 (`--insecure`): the received bytes, once hap-core's
/// decoder accepted them and the address policy admits them.
fn insecure(
    session: &mut Session,
    src: SocketAddr,
    data: &[u8],
    shared: &Shared,
    now: Instant,
) -> Step {
    let decision = match frames::classify(data) {
        Err(r) => Decision::Drop(r),
        Ok(kind) => session.admit(src, kind, now),
    };
    match decision {
        Decision::Drop(r) => Step::Refused(r),
        Decision::Forward => {
            Counters::inc(&shared.counters.insecure_frames);
            let mut w = hap_auth::Wire {
                buf: [0u8; MAX_FRAME],
                len: data.len(),
            };
            w.buf[..data.len()].copy_from_slice(data);
            Step::Forward(w)
        }
    }
}

/// One log line per refusal reason per 10 s, with the source.
fn log_refusal(
    last: &mut [Option<Instant>; Refusal::COUNT],
    r: Refusal,
    src: SocketAddr,
    now: Instant,
) {
    let Some(slot) = last.get_mut(r.index()) else {
        return;
    };
    if slot.is_none_or(|t| now.duration_since(t) >= Duration::from_secs(10)) {
        *slot = Some(now);
        eprintln!(
            "proto_interface: refused a datagram from {src}: {} (counted; one line per reason per 10 s)",
            r.name()
        );
    }
}

fn publish_session(shared: &Shared, session: &Session) {
    if let Ok(mut c) = shared.client.lock() {
        *c = session.client();
    }
    if let Ok(mut c) = shared.closed_by.lock() {
        *c = session.closed_by();
    }
    let c = &shared.counters;
    c.sessions_opened.store(session.opened, Ordering::Relaxed);
    c.sessions_closed.store(session.closed, Ordering::Relaxed);
    c.sessions_expired.store(session.expired, Ordering::Relaxed);
}

/// Errors that mean the module is gone (or going): stop the bridge.
fn is_device_gone(e: &std::io::Error) -> bool {
    matches!(
        e.raw_os_error(),
        Some(libc::ENODEV)
            | Some(libc::ENXIO)
            | Some(libc::EPIPE)
            | Some(libc::EBADF)
            | Some(libc::ESHUTDOWN)
    )
}

fn client_loop(cfg: &Config, sock: &UdpSocket, shared: &Shared) {
    let Some(mut dev) = open_device(&cfg.rtf_out, false, shared) else {
        return;
    };
    // Exactly one frame per read; never a smaller buffer (the device may
    // answer EINVAL to a read shorter than a frame).
    let mut buf = [0u8; MAX_FRAME];
    loop {
        if shared.stop.load(Ordering::SeqCst) {
            return;
        }
        match dev.read(&mut buf) {
            Ok(0) => {
                shared.set_fatal(format!(
                    "{}: end of file (module gone)",
                    cfg.rtf_out.display()
                ));
                return;
            }
            Ok(n) => {
                Counters::inc(&shared.counters.answers);
                // Acks and errors of a closing client still reach it.
                let is_reply = buf.get(3).is_some_and(|t| {
                    *t == hap_core::protocol::FrameType::Ack as u8
                        || *t == hap_core::protocol::FrameType::Error as u8
                });
                let closing = || shared.closed_by.lock().ok().and_then(|c| *c);
                let Some(to) = shared.client().or_else(|| closing().filter(|_| is_reply)) else {
                    Counters::inc(&shared.counters.answers_no_client);
                    continue;
                };
                let sealed;
                let out: &[u8] = match &shared.gate {
                    None => &buf[..n],
                    Some(g) => match lock(g).seal_from_kernel(&buf[..n]) {
                        Some(w) => {
                            sealed = w;
                            sealed.bytes()
                        }
                        None => {
                            Counters::inc(&shared.counters.answers_unsealed);
                            continue;
                        }
                    },
                };
                match sock.send_to(out, to) {
                    Ok(_) => Counters::inc(&shared.counters.sent),
                    Err(_) => Counters::inc(&shared.counters.send_errors),
                }
            }
            Err(e) if e.kind() == ErrorKind::Interrupted => continue,
            Err(e) if e.kind() == ErrorKind::WouldBlock => {
                std::thread::sleep(Duration::from_micros(200));
            }
            Err(e) => {
                shared.set_fatal(format!("{}: {e}", cfg.rtf_out.display()));
                return;
            }
        }
    }
}

#[cfg(test)]
mod fifo_tests {
    #[test]
    fn out_of_range_priority_is_refused_without_a_syscall() {
        for p in [0, 100, -1] {
            let e = super::set_fifo_priority(p).unwrap_err();
            assert_eq!(e.kind(), std::io::ErrorKind::InvalidInput, "{p}");
        }
    }
}
