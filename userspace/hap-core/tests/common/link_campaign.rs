//! The link passivity campaign: the controller (`ProtoIn` + `ServoCycle`,
//! the simulated arm) and a client (`link::ClientLink`, a point-mass object,
//! free or behind a stiff penalty wall) talk through an in-process channel
//! that delays, jitters, drops and reorders the encoded frames. Every frame
//! crosses as bytes (`protocol::encode` / `decode`, `ProtoIn::handle`).
//! Shared by `tests/link_passivity.rs` (a small seed set) and
//! `examples/link_passivity.rs` (the full campaign,
//! `scripts/bench-link-passivity.sh`).
#![allow(dead_code, clippy::needless_range_loop)]

use hap_core::config::{CommandType, VirtualObjectParams};
use hap_core::control::MAX_FORCE;
use hap_core::cycle::ServoCycle;
use hap_core::effort::EffortSample;
use hap_core::fixed::{Fx, Pose, Twist, Vec3, Wrench};
use hap_core::io::MotorLine;
use hap_core::link::ClientLink;
use hap_core::mode::Mode;
use hap_core::proto_in::ProtoIn;
use hap_core::protocol::{
    decode, encode, seq_newer, Frame, FrameHeader, CTRL_LINK_ENERGY, MAX_FRAME_LEN,
};
use hap_core::servo::{PowerRequest, ServoInputs};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

/// Servo period, µs (the module's default), and the client's step.
pub const PERIOD_US: u32 = 1000;
const DT: f64 = 0.001;
/// The client's object: mass (kg), the wall's stiffness (N/m) and where it
/// stands from the object's start along +x (m).
pub const OBJECT_MASS: f64 = 0.5;
pub const WALL_STIFFNESS: f64 = 20_000.0;
pub const WALL_OFFSET: f64 = 0.01;
/// Strongest user force of the random efforts, N (as the safety campaign).
pub const USER_FORCE_MAX: f64 = 25.0;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Object {
    FreeMass,
    Wall,
}

/// One run's link and client.
#[derive(Clone, Copy, Debug)]
pub struct Link {
    /// Round-trip delay, ms (half each way).
    pub rtt_ms: f64,
    /// Jitter, fraction of each one-way delay (uniform ±).
    pub jitter: f64,
    /// Loss probability of each frame, both ways.
    pub loss: f64,
    /// Both ends' passivity controllers on (the client sets `CTRL_LINK_ENERGY`).
    pub passivity: bool,
    pub object: Object,
}

/// Figures of a run.
#[derive(Clone, Debug, Default)]
pub struct LinkFigures {
    pub cycles: u64,
    pub coupled_cycles: u64,
    /// Cycles with the watchdog's gain below 1 once the stream is
    /// established (one round trip after the first VPr).
    pub faded_cycles: u64,
    /// The channel's energy `E_in,S + E_in,C − E_out,S − E_out,C`, J:
    /// lowest over the run and at its end.
    pub channel_min: f64,
    pub channel_end: f64,
    /// The totals at the end, J.
    pub e_in_s: f64,
    pub e_out_s: f64,
    pub e_in_c: f64,
    pub e_out_c: f64,
    /// Largest coupling force at the handle, N; largest handle speed, m/s.
    pub max_force: f64,
    pub max_speed: f64,
    /// Cycles the controller's / steps the client's passivity controller acted.
    pub limited_server: u64,
    pub limited_client: u64,
    /// Frames sent / lost / delivered out of order (client → controller).
    pub frames: u64,
    pub lost: u64,
    pub reordered: u64,
    pub stale_rejects: u64,
    /// Oscillation energy (J) of object and handle after the user lets go:
    /// largest over the first 200 ms of the release, over the release
    /// before its last 200 ms, and over its last 200 ms. The link stores
    /// energy (the spring, the reservoirs, grants in flight) that may come
    /// out after the release; a growing oscillation is one whose last
    /// window holds more than any before it.
    pub release_start: f64,
    pub release_peak: f64,
    pub release_end: f64,
    /// Largest |handle − object| (client frame) at the end, m.
    pub drift: f64,
}

fn f(x: Fx) -> f64 {
    x.to_f64()
}

fn v3(v: Vec3) -> [f64; 3] {
    v.to_f64()
}

fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

/// Frames in flight, delivered in arrival order (so a jitter larger than
/// the spacing of frames reorders them).
struct Channel {
    flight: Vec<(u64, u64, [u8; MAX_FRAME_LEN], usize)>,
    sent: u64,
    lost: u64,
    delivered_max: u64,
    reordered: u64,
}

impl Channel {
    fn new() -> Channel {
        Channel {
            flight: Vec::new(),
            sent: 0,
            lost: 0,
            delivered_max: 0,
            reordered: 0,
        }
    }

    fn send(&mut self, rng: &mut StdRng, link: &Link, now: u64, b: &[u8; MAX_FRAME_LEN], n: usize) {
        self.sent += 1;
        if link.loss > 0.0 && rng.gen_bool(link.loss) {
            self.lost += 1;
            return;
        }
        let one_way = link.rtt_ms * 0.5;
        let j = if link.jitter > 0.0 {
            rng.gen_range(-link.jitter..link.jitter)
        } else {
            0.0
        };
        let delay_cycles = (one_way * (1.0 + j)).max(0.0).round() as u64;
        self.flight.push((now + delay_cycles, self.sent, *b, n));
    }

    /// The frames that arrive at `now`, in arrival order.
    fn arrive(&mut self, now: u64, out: &mut Vec<([u8; MAX_FRAME_LEN], usize)>) {
        out.clear();
        let mut due: Vec<_> = Vec::new();
        self.flight.retain(|e| {
            if e.0 <= now {
                due.push(*e);
                false
            } else {
                true
            }
        });
        due.sort_by_key(|e| (e.0, e.1));
        for (_, id, b, n) in due {
            if id < self.delivered_max {
                self.reordered += 1;
            }
            self.delivered_max = self.delivered_max.max(id);
            out.push((b, n));
        }
    }
}

/// The user's hand at the handle: a random intent force (piecewise
/// constant, up to `USER_FORCE_MAX`) plus a soft hold around where it took
/// the handle; `None` after `release_at`: the hand stays on the handle
/// (dead-man held) and pushes no more.
struct Hand {
    intent: [f64; 3],
    left: u64,
    home: Option<[f64; 3]>,
}

impl Hand {
    fn force(&mut self, rng: &mut StdRng, object: Object, p: [f64; 3], v: [f64; 3]) -> [f64; 3] {
        let home = *self.home.get_or_insert(p);
        if self.left == 0 {
            self.left = rng.gen_range(200..1500);
            let mut d = [
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0f64..1.0),
            ];
            if object == Object::Wall && rng.gen_bool(0.5) {
                d = [1.0, d[1] * 0.2, d[2] * 0.2]; // into the wall
            }
            let dn = norm(d).max(1e-9);
            let mag = rng.gen_range(0.0..USER_FORCE_MAX * 0.6);
            self.intent = [d[0] / dn * mag, d[1] / dn * mag, d[2] / dn * mag];
        }
        self.left -= 1;
        let mut out = [0.0; 3];
        for i in 0..3 {
            out[i] = self.intent[i] - 300.0 * (p[i] - home[i]) - 5.0 * v[i];
        }
        let n = norm(out);
        if n > USER_FORCE_MAX {
            for x in &mut out {
                *x *= USER_FORCE_MAX / n;
            }
        }
        out
    }
}

fn frame_bytes(h: &FrameHeader, fr: &Frame) -> ([u8; MAX_FRAME_LEN], usize) {
    let mut b = [0u8; MAX_FRAME_LEN];
    let n = encode(h, fr, &mut b);
    (b, n)
}

/// The client's view of the object and the controller.
struct Client {
    link: ClientLink,
    p: [f64; 3],
    v: [f64; 3],
    started: bool,
    orientation: hap_core::fixed::Quat,
    wall_x: f64,
    force: Wrench,
    handle: [f64; 3],
    newest_answer: Option<u32>,
    seq: u32,
}

/// The probe's force along +x, N, at cycle `n`, its phases `k` times
/// longer than the base script: 0 → 5 N over 1 s, hold 2 s, → 10 N over
/// 1 s, hold 2 s, → 0 over 1 s, then nothing for 3 s.
fn push_force(n: u64, k: f64) -> f64 {
    let t = n as f64 * DT / k;
    match t {
        t if t < 1.0 => 5.0 * t,
        t if t < 3.0 => 5.0,
        t if t < 4.0 => 5.0 + 5.0 * (t - 3.0),
        t if t < 6.0 => 10.0,
        t if t < 7.0 => 10.0 * (7.0 - t),
        _ => 0.0,
    }
}

/// Cycles of the wall probe's base script (10 s).
pub const PROBE_CYCLES: u64 = 10_000;

/// The probe's time scale for a round trip: its phases last at least four
/// round trips (1 at up to 250 ms).
pub fn probe_scale(rtt_ms: f64) -> f64 {
    (rtt_ms / 250.0).max(1.0)
}

/// The probe's figures: the felt stiffness of the wall (N/m, the force
/// step 5 → 10 N over the handle's move between the two plateaus), and
/// the handle–object drift at rest after the push (m).
#[derive(Clone, Copy, Debug, Default)]
pub struct Probe {
    pub stiffness: f64,
    pub drift: f64,
    pub penetration_10n: f64,
    pub channel_min: f64,
}

struct Sim {
    rng: StdRng,
    link: Link,
    line: MotorLine,
    servo: ServoCycle,
    proto: ProtoIn,
    up: Channel,
    down: Channel,
    client: Client,
    server_seq: u32,
    hand: Hand,
    figs: LinkFigures,
    first_vpr: Option<u64>,
    arrivals: Vec<([u8; MAX_FRAME_LEN], usize)>,
}

impl Sim {
    fn new(seed: u64, link: Link) -> Sim {
        let mut s = Sim {
            rng: StdRng::seed_from_u64(seed),
            link,
            line: MotorLine::new(),
            servo: ServoCycle::new(PERIOD_US),
            proto: ProtoIn::new(),
            up: Channel::new(),
            down: Channel::new(),
            client: Client {
                link: ClientLink::new(),
                p: [0.0; 3],
                v: [0.0; 3],
                started: false,
                orientation: hap_core::fixed::Quat::IDENTITY,
                wall_x: 0.0,
                force: Wrench::ZERO,
                handle: [0.0; 3],
                newest_answer: None,
                seq: 0,
            },
            server_seq: 0,
            hand: Hand {
                intent: [0.0; 3],
                left: 0,
                home: None,
            },
            figs: LinkFigures {
                channel_min: f64::INFINITY,
                ..Default::default()
            },
            first_vpr: None,
            arrivals: Vec::new(),
        };
        s.servo.servo.init();
        // The session is set up before the link degrades (no delay, no loss).
        let setup = [
            Frame::OpenSession { client_nonce: 7 },
            Frame::SetCommandType(CommandType::VirtMech),
            Frame::SetTimeStep(Fx::from_f64(DT)),
            Frame::AttachVirtualObject(VirtualObjectParams {
                mass: Fx::from_f64(OBJECT_MASS),
                inertia: Vec3::new(Fx::from_f64(1e-4), Fx::from_f64(1e-4), Fx::from_f64(1e-4)),
            }),
            Frame::PowerRequest(true),
        ];
        for fr in setup {
            let seq = s.client.seq;
            s.client.seq += 1;
            let h = FrameHeader {
                control: 0,
                session: s.proto.session(),
                seq,
                timestamp_us: 0,
            };
            let (b, n) = frame_bytes(&h, &fr);
            let out = s.proto.handle(&b[..n], 0, PERIOD_US);
            assert!(out.accepted, "setup frame {fr:?} refused: {out:?}");
        }
        s
    }

    /// One servo cycle and one client step at cycle `n`; `user` the force
    /// the hand applies (base frame).
    fn step(&mut self, n: u64, user: [f64; 3]) {
        // ---- Controller: the frames that arrive, then the cycle.
        self.up.arrive(n, &mut self.arrivals);
        for (b, len) in &self.arrivals {
            let out = self.proto.handle(&b[..*len], n, PERIOD_US);
            if out.rejected.is_some() {
                self.figs.stale_rejects += 1;
            }
        }
        let power = if n == 0 {
            PowerRequest::On
        } else {
            PowerRequest::None
        };
        let inputs = ServoInputs {
            power_request: power,
            live_effort: Some(EffortSample {
                wrench: Wrench {
                    force: Vec3::from_f64(user),
                    torque: Vec3::ZERO,
                },
                dead_man: true,
                buttons: 0,
            }),
        };
        let vpr = *self.proto.vpr();
        let cfg = *self.proto.config();
        let r = self
            .servo
            .run(&self.line, &inputs, &cfg, Some(&vpr), Mode::Main);
        if vpr.valid && self.first_vpr.is_none() {
            self.first_vpr = Some(n);
        }
        // Once the stream is established (one round trip after the first
        // VPr: before, arrivals thin out toward the shortest delays).
        let warm = self
            .first_vpr
            .is_some_and(|k| n > k + self.link.rtt_ms as u64 + 1);
        if warm && r.link_gain != Fx::ONE {
            self.figs.faded_cycles += 1;
        }
        let out = *self.servo.servo.control_output();
        if out.envelope.0 > 0 {
            self.figs.coupled_cycles += 1;
        }
        self.figs.max_force = self.figs.max_force.max(norm(v3(out.handle_wrench.force)));
        self.figs.max_speed =
            self.figs
                .max_speed
                .max(norm(v3(self.servo.servo.vp().handle_twist.linear)));
        let mut frames = [[0u8; MAX_FRAME_LEN]; 2];
        let mut lens = [0usize; 2];
        let mut seq = self.server_seq;
        let k = ServoCycle::encode_answers(
            &r.vp,
            self.proto.session(),
            n as u32,
            || {
                seq = seq.wrapping_add(1);
                seq
            },
            &mut frames,
            &mut lens,
        );
        self.server_seq = seq;
        for i in 0..k {
            self.down
                .send(&mut self.rng, &self.link, n, &frames[i], lens[i]);
        }

        // ---- Client: the answers that arrive, then its step.
        self.down.arrive(n, &mut self.arrivals);
        let c = &mut self.client;
        for (b, len) in &self.arrivals {
            let Ok((h, fr)) = decode(&b[..*len]) else {
                panic!("an answer does not decode");
            };
            match fr {
                Frame::Answer(a) if c.newest_answer.is_none_or(|s| seq_newer(h.seq, s)) => {
                    c.newest_answer = Some(h.seq);
                    c.force = a.coupling_wrench;
                    c.handle = v3(a.handle_pose.position);
                    if !c.started {
                        c.started = true;
                        c.p = c.handle;
                        c.orientation = a.handle_pose.orientation;
                        c.wall_x = c.p[0] + WALL_OFFSET;
                    }
                }
                Frame::AnswerTwist(t) => c.link.on_peer_total(t.link_energy),
                _ => {}
            }
        }
        if !c.started {
            return;
        }
        let twist = Twist {
            linear: Vec3::from_f64(c.v),
            angular: Vec3::ZERO,
        };
        let dt = Fx::from_f64(DT);
        let applied = if self.link.passivity {
            c.link.force(&c.force, &twist, dt)
        } else {
            // Observed all the same: the force applied is the one received.
            c.link.observe_only(&c.force, &twist, dt)
        };
        let fa = v3(applied.force);
        let mut fw = [0.0; 3];
        if self.link.object == Object::Wall && c.p[0] > c.wall_x {
            fw[0] = -WALL_STIFFNESS * (c.p[0] - c.wall_x);
        }
        for i in 0..3 {
            c.v[i] += (fa[i] + fw[i]) / OBJECT_MASS * DT;
            c.p[i] += c.v[i] * DT;
        }
        let pose = Pose {
            position: Vec3::from_f64(c.p),
            orientation: c.orientation,
        };
        c.link.commit();
        let h = FrameHeader {
            control: if self.link.passivity {
                CTRL_LINK_ENERGY
            } else {
                0
            },
            session: self.proto.session(),
            seq: c.seq,
            timestamp_us: if self.link.passivity {
                c.link.wire_granted()
            } else {
                n as u32
            },
        };
        c.seq = c.seq.wrapping_add(1);
        let fr = Frame::VprStream {
            pose,
            twist: Twist {
                linear: Vec3::from_f64(c.v),
                angular: Vec3::ZERO,
            },
        };
        let (b, len) = frame_bytes(&h, &fr);
        self.up.send(&mut self.rng, &self.link, n, &b, len);

        // ---- The channel's ledger.
        let s = self.servo.servo.controller().link();
        let cl = &self.client.link.ledger;
        let h = f(s.energy_in) + f(cl.energy_in) - f(s.energy_out) - f(cl.energy_out);
        self.figs.channel_min = self.figs.channel_min.min(h);
        self.figs.channel_end = h;
    }

    fn oscillation_energy(&self) -> f64 {
        let v = norm(self.client.v);
        let vh = norm(v3(self.servo.servo.vp().handle_twist.linear));
        0.5 * OBJECT_MASS * v * v + 0.5 * vh * vh
    }

    fn finish(mut self) -> LinkFigures {
        let s = *self.servo.servo.controller().link();
        let cl = self.client.link.ledger;
        self.figs.e_in_s = f(s.energy_in);
        self.figs.e_out_s = f(s.energy_out);
        self.figs.e_in_c = f(cl.energy_in);
        self.figs.e_out_c = f(cl.energy_out);
        self.figs.limited_server = self.servo.servo.controller().link_limited_cycles();
        self.figs.limited_client = self.client.link.limited_steps;
        self.figs.frames = self.up.sent;
        self.figs.lost = self.up.lost;
        self.figs.reordered = self.up.reordered;
        self.figs
    }

    fn handle_state(&self) -> ([f64; 3], [f64; 3]) {
        let vp = self.servo.servo.vp();
        (v3(vp.handle_pose.position), v3(vp.handle_twist.linear))
    }
}

/// One run of `cycles` cycles: random efforts for 70 % of it, then the
/// user lets go (dead-man held, no force).
pub fn run(seed: u64, link: Link, cycles: u64) -> LinkFigures {
    let mut sim = Sim::new(seed, link);
    let release_at = cycles * 7 / 10;
    let window = 200u64.min((cycles - release_at) / 2);
    for n in 0..cycles {
        let (p, v) = sim.handle_state();
        // (The first answer is the cycle's output: from cycle 1 on.)
        let user = if n > 0 && n < release_at {
            let obj = sim.link.object;
            sim.hand.force(&mut sim.rng, obj, p, v)
        } else {
            [0.0; 3]
        };
        sim.step(n, user);
        if n >= release_at {
            let e = sim.oscillation_energy();
            if n < release_at + window {
                sim.figs.release_start = sim.figs.release_start.max(e);
            }
            if n >= cycles - window {
                sim.figs.release_end = sim.figs.release_end.max(e);
            } else {
                sim.figs.release_peak = sim.figs.release_peak.max(e);
            }
        }
        sim.figs.cycles += 1;
    }
    let (p, _) = sim.handle_state();
    sim.figs.drift = norm([
        p[0] - sim.client.p[0],
        p[1] - sim.client.p[1],
        p[2] - sim.client.p[2],
    ]);
    sim.finish()
}

/// The wall probe: the object starts against nothing, the wall 1 cm
/// ahead; the user pushes the handle along +x (`push_force`): the felt
/// stiffness between the 5 N and the 10 N plateaus, the penetration at 10
/// N (handle beyond the wall), and the drift after the release.
pub fn probe_wall(rtt_ms: f64, jitter: f64, loss: f64, passivity: bool, seed: u64) -> Probe {
    let link = Link {
        rtt_ms,
        jitter,
        loss,
        passivity,
        object: Object::Wall,
    };
    let mut sim = Sim::new(seed, link);
    let (mut x5, mut x10, mut k5, mut k10) = (0.0, 0.0, 0u32, 0u32);
    let mut handle_at_start: Option<[f64; 3]> = None;
    let k = probe_scale(rtt_ms);
    let cycles = (PROBE_CYCLES as f64 * k) as u64;
    for n in 0..cycles {
        let (p, v) = sim.handle_state();
        // (The first answer is the cycle's output: from cycle 1 on.)
        let home = if n == 0 {
            p
        } else {
            *handle_at_start.get_or_insert(p)
        };
        // The hand holds the handle's y and z (a soft hold), pushes along x.
        let user = [
            push_force(n, k),
            -300.0 * (p[1] - home[1]) - 5.0 * v[1],
            -300.0 * (p[2] - home[2]) - 5.0 * v[2],
        ];
        sim.step(n, user);
        if std::env::var_os("HAP_PROBE_TRACE").is_some() && n % 250 == 0 {
            let o = sim.servo.servo.control_output();
            println!(
                "t {:.2} user {:.1} handle {:.4} object {:.4} wall {:.4} f_handle {:.2} f_obj {:.2} env {:.2} res_s {:.4} res_c {:.4}",
                n as f64 * DT,
                user[0],
                p[0],
                sim.client.p[0],
                sim.client.wall_x,
                f(o.handle_wrench.force.x),
                f(sim.client.force.force.x),
                f(o.envelope),
                f(sim.servo.servo.controller().link().reservoir()),
                f(sim.client.link.ledger.reservoir()),
            );
        }
        let t = n as f64 * DT / k;
        if (2.5..3.0).contains(&t) {
            x5 += p[0];
            k5 += 1;
        }
        if (5.5..6.0).contains(&t) {
            x10 += p[0];
            k10 += 1;
        }
    }
    let x5 = x5 / f64::from(k5.max(1));
    let x10 = x10 / f64::from(k10.max(1));
    let (p, _) = sim.handle_state();
    Probe {
        stiffness: 5.0 / (x10 - x5).max(1e-9),
        drift: norm([
            p[0] - sim.client.p[0],
            p[1] - sim.client.p[1],
            p[2] - sim.client.p[2],
        ]),
        penetration_10n: x10 - sim.client.wall_x,
        channel_min: sim.figs.channel_min,
    }
}

/// The largest coupling force the controller may apply, N.
pub fn force_bound() -> f64 {
    f(MAX_FORCE)
}
