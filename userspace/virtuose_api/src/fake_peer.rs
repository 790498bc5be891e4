//! A fake controller speaking hap-core frames over UDP, for tests and for
//! running the demo without the kernel module (`virtuose_demo --server fake`).
//!
//! It grants one session (other source addresses are ignored, like the
//! bridge does), acknowledges configuration requests, and answers every
//! VprStream with an Answer (or, with `answer_every_period`, answers every
//! period while the session is open, like the controller): the handle
//! follows a scripted sinusoid of the fake's own time (one period per
//! answer, whatever the host's clock), and the coupling wrench is a spring-damper
//! between the handle and the streamed virtual object (only while a virtual
//! object is attached and power is on).

use std::collections::BTreeMap;
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use hap_core::fixed::{Pose, Twist, Vec3, Wrench};
use hap_core::protocol::{
    decode, encode, Answer, AnswerTwist, Frame, FrameHeader, CTRL_ACK_REQUEST, CTRL_LINK_ENERGY,
    ERROR_NO_SESSION, MAX_FRAME_LEN,
};
use hap_core::vp::status;

/// Behaviour of the fake controller.
#[derive(Clone, Debug)]
pub struct FakePeerConfig {
    pub bind: SocketAddr,
    pub period_us: u32,
    /// Coupling spring (N/m) and damper (N·s/m).
    pub stiffness: f64,
    pub damping: f64,
    /// Handle position = center + amplitude · sin(2π·freq·t).
    pub center: [f64; 3],
    pub amplitude: [f64; 3],
    pub freq_hz: f64,
    /// Drop every Nth answer (0: never), to exercise loss accounting.
    pub drop_every: u32,
    /// Send every Nth answer twice (0: never), to exercise duplicate drops.
    pub duplicate_every: u32,
    /// Send an AnswerTwist after every Nth answer (0: never).
    pub twist_every: u32,
    /// Start with the arm powered.
    pub powered: bool,
    /// Answer every `period_us` while a session is open, like the
    /// controller (true), instead of once per VprStream (false).
    pub answer_every_period: bool,
    /// `hap_core::vp::status` bits added to every answer (buttons,
    /// emergency stop...).
    pub extra_status: u32,
    /// `hap_core::vp::alarm` bits reported in every answer.
    pub alarms: u32,
    /// Neither apply nor acknowledge power requests (a controller that
    /// does not answer a request: the client's retries time out).
    pub ignore_power_requests: bool,
    /// Answers that still report the previous power state after a power
    /// request was applied and acknowledged (a controller whose status
    /// lags its acknowledgement).
    pub power_lag_answers: u32,
}

impl Default for FakePeerConfig {
    fn default() -> Self {
        FakePeerConfig {
            bind: SocketAddr::from(([127, 0, 0, 1], 0)),
            period_us: 1000,
            stiffness: 300.0,
            damping: 4.0,
            center: [0.0, 0.0, 0.0],
            amplitude: [0.05, 0.0, 0.02],
            freq_hz: 0.5,
            drop_every: 0,
            duplicate_every: 0,
            twist_every: 10,
            powered: false,
            answer_every_period: false,
            extra_status: 0,
            alarms: 0,
            ignore_power_requests: false,
            power_lag_answers: 0,
        }
    }
}

/// What the fake controller saw.
#[derive(Clone, Debug, Default)]
pub struct FakePeerStats {
    /// Frames received, by frame-type name.
    pub frames: BTreeMap<&'static str, u64>,
    /// Datagrams that did not decode.
    pub garbage: u64,
    /// Frames from a source other than the session's client, ignored.
    pub stray: u64,
    pub answers_sent: u64,
    pub powered: bool,
    pub attached: bool,
    /// Last virtual-object position streamed.
    pub last_vo_position: [f64; 3],
    /// Last virtual-object pose streamed, `[x,y,z,qx,qy,qz,qw]`.
    pub last_vo_pose: [f64; 7],
    /// Handle position of the last answer sent.
    pub last_handle_position: [f64; 3],
    /// Last command type set (wire value).
    pub command_type: Option<u32>,
    /// Largest distance between a streamed virtual-object position and the
    /// handle position of the last answer sent before it, m.
    pub max_vo_offset: f64,
    /// VprStream frames that carried `CTRL_LINK_ENERGY` (a client keeping
    /// the link passive).
    pub link_energy_frames: u64,
    pub client: Option<SocketAddr>,
}

/// A running fake controller; stops when dropped.
pub struct FakePeer {
    pub addr: SocketAddr,
    stop: Arc<AtomicBool>,
    stats: Arc<Mutex<FakePeerStats>>,
    thread: Option<JoinHandle<()>>,
}

impl FakePeer {
    pub fn start(cfg: FakePeerConfig) -> std::io::Result<FakePeer> {
        let sock = UdpSocket::bind(cfg.bind)?;
        sock.set_read_timeout(Some(Duration::from_millis(50)))?;
        let addr = sock.local_addr()?;
        let stop = Arc::new(AtomicBool::new(false));
        let stats = Arc::new(Mutex::new(FakePeerStats {
            powered: cfg.powered,
            ..Default::default()
        }));
        let (s2, st2) = (stop.clone(), stats.clone());
        let thread = std::thread::Builder::new()
            .name("fake_peer".into())
            .spawn(move || run(cfg, sock, s2, st2))?;
        Ok(FakePeer {
            addr,
            stop,
            stats,
            thread: Some(thread),
        })
    }

    /// `"127.0.0.1#port"`, ready for `VirtContext::open`.
    pub fn address(&self) -> String {
        format!("{}#{}", self.addr.ip(), self.addr.port())
    }

    pub fn stats(&self) -> FakePeerStats {
        self.stats.lock().map(|s| s.clone()).unwrap_or_default()
    }

    pub fn stop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for FakePeer {
    fn drop(&mut self) {
        self.stop();
    }
}

fn v3(a: [f64; 3]) -> Vec3 {
    Vec3::from_f64(a)
}

fn run(
    cfg: FakePeerConfig,
    sock: UdpSocket,
    stop: Arc<AtomicBool>,
    stats: Arc<Mutex<FakePeerStats>>,
) {
    let t0 = Instant::now();
    let mut buf = [0u8; 2048];
    let mut out = [0u8; MAX_FRAME_LEN];
    let mut client: Option<SocketAddr> = None;
    let mut session: u16 = 0;
    let mut seq: u32 = 0;
    let mut cycle: u32 = 0;
    let mut powered = cfg.powered;
    // The power state the answers report, and the answers left before they
    // report `powered`.
    let mut reported_power = cfg.powered;
    let mut lag_left: u32 = 0;
    let mut attached = false;
    let mut n_answers: u64 = 0;
    let w = 2.0 * std::f64::consts::PI * cfg.freq_hz;

    let send =
        |f: &Frame, seq: &mut u32, session: u16, to: SocketAddr, out: &mut [u8; MAX_FRAME_LEN]| {
            *seq = seq.wrapping_add(1);
            let h = FrameHeader {
                control: 0,
                session,
                seq: *seq,
                timestamp_us: t0.elapsed().as_micros() as u32,
            };
            let n = encode(&h, f, out);
            let _ = sock.send_to(&out[..n], to);
            n
        };

    let mut last_vpr: Option<(Pose, Twist, u32)> = None;
    let mut next_answer = Instant::now();
    let period = Duration::from_micros(cfg.period_us.max(100) as u64);
    let mut answer = |seq: &mut u32,
                      session: u16,
                      src: SocketAddr,
                      out: &mut [u8; MAX_FRAME_LEN],
                      vpr: &Option<(Pose, Twist, u32)>,
                      powered: bool,
                      attached: bool| {
        // The handle moves on the controller's clock: one period per
        // answer (a client that is late sees the handle where the
        // controller's time puts it, not where the host's clock would).
        let t = f64::from(cycle) * f64::from(cfg.period_us) * 1e-6;
        let mut hp = [0.0; 3];
        let mut hv = [0.0; 3];
        for i in 0..3 {
            hp[i] = cfg.center[i] + cfg.amplitude[i] * (w * t).sin();
            hv[i] = cfg.amplitude[i] * w * (w * t).cos();
        }
        let (vo, vv, vpr_seq) = match vpr {
            Some((p, tw, s)) => (p.position.to_f64(), tw.linear.to_f64(), *s),
            None => (hp, hv, 0),
        };
        let mut f = [0.0; 3];
        if attached && powered && vpr.is_some() {
            for i in 0..3 {
                f[i] = cfg.stiffness * (hp[i] - vo[i]) + cfg.damping * (hv[i] - vv[i]);
            }
        }
        cycle = cycle.wrapping_add(1);
        let mut st = status::DEAD_MAN | cfg.extra_status;
        if powered {
            st |= status::POWER_ON | status::MOTORS_ENABLED;
        }
        if attached {
            st |= status::COUPLED;
        }
        let a = Answer {
            handle_pose: Pose {
                position: v3(hp),
                orientation: Default::default(),
            },
            coupling_wrench: Wrench {
                force: v3(f),
                torque: Vec3::default(),
            },
            status: st,
            alarms: cfg.alarms,
            cycle,
            vpr_seq,
        };
        n_answers += 1;
        let drop_it = cfg.drop_every > 0 && n_answers % cfg.drop_every as u64 == 0;
        if drop_it {
            *seq = seq.wrapping_add(1); // a lost datagram leaves a gap
        } else {
            let len = send(&Frame::Answer(a), seq, session, src, out);
            if cfg.duplicate_every > 0 && n_answers % cfg.duplicate_every as u64 == 0 {
                let _ = sock.send_to(&out[..len], src);
            }
        }
        if cfg.twist_every > 0 && n_answers % cfg.twist_every as u64 == 0 {
            let tw = AnswerTwist {
                handle_twist: Twist {
                    linear: v3(hv),
                    angular: Vec3::default(),
                },
                status: st,
                alarms: cfg.alarms,
                cycle,
                vpr_seq,
                link_energy: 0,
            };
            send(&Frame::AnswerTwist(tw), seq, session, src, out);
        }
        if let Ok(mut s) = stats.lock() {
            s.answers_sent = n_answers;
            s.last_handle_position = hp;
        }
    };

    // Answering every period with a session open, like the controller's
    // cycle: the socket is non-blocking, the frames that arrived are
    // handled, then the thread sleeps until the next answer (a sleep is
    // precise; a socket's receive timeout is rounded up to the kernel's
    // tick, which would answer every few ms instead).
    let mut nonblocking = false;
    while !stop.load(Ordering::SeqCst) {
        let periodic = cfg.answer_every_period && client.is_some();
        if periodic != nonblocking {
            let _ = sock.set_nonblocking(periodic);
            nonblocking = periodic;
        }
        if periodic {
            if let Some(c) = client {
                let now = Instant::now();
                if now >= next_answer {
                    let shown = if lag_left > 0 {
                        lag_left -= 1;
                        reported_power
                    } else {
                        reported_power = powered;
                        powered
                    };
                    answer(&mut seq, session, c, &mut out, &last_vpr, shown, attached);
                    next_answer += period;
                    if next_answer < now {
                        next_answer = now + period;
                    }
                }
            }
        }
        let (n, src) = match sock.recv_from(&mut buf) {
            Ok(x) => x,
            Err(e) if periodic && e.kind() == std::io::ErrorKind::WouldBlock => {
                std::thread::sleep(next_answer.saturating_duration_since(Instant::now()));
                continue;
            }
            Err(_) => continue,
        };
        let Ok((h, frame)) = decode(&buf[..n]) else {
            if let Ok(mut s) = stats.lock() {
                s.garbage += 1;
            }
            continue;
        };
        if let Ok(mut s) = stats.lock() {
            *s.frames.entry(frame.frame_type().name()).or_insert(0) += 1;
        }
        if let Some(c) = client {
            if c != src {
                if let Ok(mut s) = stats.lock() {
                    s.stray += 1;
                }
                continue;
            }
        }
        // The reply (and its session id) is sent once the new state is
        // published in `stats`: a client that got its ack sees the state.
        let mut reply: Option<(Frame, u16)> = None;
        let ack = |session: u16| {
            (h.control & CTRL_ACK_REQUEST != 0).then_some((
                Frame::Ack {
                    acked_type: frame.frame_type(),
                    acked_seq: h.seq,
                },
                session,
            ))
        };
        match frame {
            Frame::OpenSession { client_nonce } => {
                if client.is_none() {
                    session = session.wrapping_add(1).max(1);
                    seq = 0;
                }
                client = Some(src);
                reply = Some((
                    Frame::SessionAck {
                        client_nonce,
                        period_us: cfg.period_us,
                    },
                    session,
                ));
            }
            _ if client.is_none() => {
                reply = Some((
                    Frame::Error {
                        reason: ERROR_NO_SESSION,
                        rejected_seq: h.seq,
                    },
                    0,
                ));
            }
            Frame::CloseSession => {
                reply = ack(session);
                client = None;
                attached = false;
                last_vpr = None;
            }
            Frame::PowerRequest(_) if cfg.ignore_power_requests => {}
            Frame::PowerRequest(on) => {
                if on != powered {
                    reported_power = powered;
                    lag_left = cfg.power_lag_answers;
                }
                powered = on;
                reply = ack(session);
            }
            Frame::AttachVirtualObject(_) => {
                attached = true;
                reply = ack(session);
            }
            Frame::DetachVirtualObject => {
                attached = false;
                reply = ack(session);
            }
            Frame::VprStream { pose, twist } => {
                last_vpr = Some((pose, twist, h.seq));
                if let Ok(mut s) = stats.lock() {
                    if h.control & CTRL_LINK_ENERGY != 0 {
                        s.link_energy_frames += 1;
                    }
                    s.last_vo_position = pose.position.to_f64();
                    let o = pose.orientation.to_f64();
                    let p = s.last_vo_position;
                    s.last_vo_pose = [p[0], p[1], p[2], o[0], o[1], o[2], o[3]];
                    if s.answers_sent > 0 {
                        let h = s.last_handle_position;
                        let d =
                            ((p[0] - h[0]).powi(2) + (p[1] - h[1]).powi(2) + (p[2] - h[2]).powi(2))
                                .sqrt();
                        if d > s.max_vo_offset {
                            s.max_vo_offset = d;
                        }
                    }
                }
                if !cfg.answer_every_period {
                    let shown = if lag_left > 0 {
                        lag_left -= 1;
                        reported_power
                    } else {
                        reported_power = powered;
                        powered
                    };
                    answer(&mut seq, session, src, &mut out, &last_vpr, shown, attached);
                }
            }
            Frame::SetCommandType(t) => {
                if let Ok(mut s) = stats.lock() {
                    s.command_type = Some(t as u32);
                }
                reply = ack(session);
            }
            _ => reply = ack(session),
        }
        if let Ok(mut s) = stats.lock() {
            s.powered = powered;
            s.attached = attached;
            s.client = client;
        }
        if let Some((f, sess)) = reply {
            send(&f, &mut seq, sess, src, &mut out);
        }
    }
}
