//! What the hand feels, through hap-core's public API (`ServoCycle::run`
//! with a `MotorLine`, the simulated arm): felt stiffness of a rigid wall,
//! the penetration curve, the force capacity of the motors per pose and
//! direction, the wall's return after a push beyond it, the drag of free
//! motion, the largest handle speed under a 25 N push, the largest force
//! step per cause, and the passive stiffness × damping region per period.
//! Host native, deterministic. `scripts/bench-fidelity.sh` runs it.
//!
//!   cargo run --release -p hap-core --example fidelity [-- --svg DIR]
#![allow(clippy::needless_range_loop)]

use hap_core::arm;
use hap_core::config::{CommandType, ServoConfig};
use hap_core::control::{self, Gains, LIN_MOBILITY_MAX};
use hap_core::cycle::ServoCycle;
use hap_core::effort::EffortSample;
use hap_core::fixed::{Fx, Joints, Pose, Vec3, Wrench, JOINTS_ZERO};
use hap_core::io::MotorLine;
use hap_core::mode::Mode;
use hap_core::servo::{PowerRequest, ServoInputs};
use hap_core::vp::VpReceived;

const PERIODS_US: [u32; 4] = [100, 250, 1000, 10_000];

fn f(x: Fx) -> f64 {
    x.to_f64()
}

fn v3(v: Vec3) -> [f64; 3] {
    v.to_f64()
}

fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

fn poses() -> [(&'static str, Joints); 3] {
    let q = |a: [f64; 6]| a.map(Fx::from_f64);
    [
        ("WORK_Q (reach 0.88 m)", arm::WORK_Q),
        ("centre (0.55 m)", q([0.0, -0.3, 1.3, 0.0, 0.2, 0.0])),
        ("side (yaw 0.6)", q([0.6, -0.1, 0.9, 0.3, -0.3, 0.2])),
    ]
}

const AXES: [(&str, [f64; 3]); 3] = [
    ("x", [1.0, 0.0, 0.0]),
    ("y", [0.0, 1.0, 0.0]),
    ("z", [0.0, 0.0, -1.0]),
];

/// A powered, coupled servo at `q`, its virtual object held still at the
/// handle's pose (a rigid wall in every direction).
struct Rig {
    c: ServoCycle,
    line: MotorLine,
    cfg: ServoConfig,
    vpr: VpReceived,
    wall: Pose,
    period_s: f64,
    /// `Some(k)`: a client whose object follows the handle, one frame
    /// (pose and twist) every `k` cycles, the controller extrapolating in
    /// between; `None`: the object held still, a fresh frame every cycle.
    follow: Option<usize>,
    n: usize,
}

fn hand(force: [f64; 3]) -> ServoInputs {
    ServoInputs {
        power_request: PowerRequest::None,
        live_effort: Some(EffortSample {
            wrench: Wrench {
                force: Vec3::from_f64(force),
                torque: Vec3::ZERO,
            },
            dead_man: true,
            buttons: 0,
        }),
    }
}

impl Rig {
    fn new(period_us: u32, q: &Joints, coupled: bool) -> Rig {
        let line = MotorLine::new();
        let mut c = ServoCycle::new(period_us);
        c.servo.init();
        c.servo.simulator_mut().set_state(q, &JOINTS_ZERO);
        let cfg = ServoConfig {
            command_type: if coupled {
                CommandType::Impedance
            } else {
                CommandType::None
            },
            ..Default::default()
        };
        let mut inp = hand([0.0; 3]);
        inp.power_request = PowerRequest::On;
        let r = c.run(&line, &inp, &cfg, None, Mode::Main);
        let wall = r.vp.handle_pose;
        let vpr = VpReceived {
            pose: wall,
            valid: true,
            seq: 1,
            ..Default::default()
        };
        let mut rig = Rig {
            c,
            line,
            cfg,
            vpr,
            wall,
            period_s: period_us as f64 * 1e-6,
            follow: None,
            n: 0,
        };
        // Settle on the wall with no push.
        rig.run_for(0.3, [0.0; 3]);
        rig
    }

    fn cycles(&self, seconds: f64) -> usize {
        (seconds / self.period_s).round() as usize
    }

    /// One cycle with the hand's force; returns (handle position, speed,
    /// motor force on the handle).
    fn step(&mut self, force: [f64; 3]) -> ([f64; 3], [f64; 3], [f64; 3]) {
        match self.follow {
            None => {
                self.vpr.seq = self.vpr.seq.wrapping_add(1);
                self.vpr.received_cycle = self.c.servo.cycle();
            }
            Some(k) => {
                if self.n % k == 0 {
                    let vp = self.c.servo.vp();
                    self.vpr.pose = vp.handle_pose;
                    self.vpr.twist = vp.handle_twist;
                    self.vpr.seq = self.vpr.seq.wrapping_add(1);
                    self.vpr.received_cycle = self.c.servo.cycle();
                }
            }
        }
        self.n += 1;
        let r = self.c.run(
            &self.line,
            &hand(force),
            &self.cfg,
            Some(&self.vpr),
            Mode::Main,
        );
        (
            v3(r.vp.handle_pose.position),
            v3(r.vp.handle_twist.linear),
            v3(self.c.servo.control_output().handle_wrench.force),
        )
    }

    fn run_for(&mut self, seconds: f64, force: [f64; 3]) -> ([f64; 3], [f64; 3], [f64; 3]) {
        let mut last = ([0.0; 3], [0.0; 3], [0.0; 3]);
        for _ in 0..self.cycles(seconds) {
            last = self.step(force);
        }
        last
    }

    /// Mean penetration along `u` over the last 0.3 s of a 1.2 s push.
    fn penetration(&mut self, u: [f64; 3], push: f64) -> f64 {
        let force = u.map(|x| x * push);
        self.run_for(0.9, force);
        let n = self.cycles(0.3);
        let w = v3(self.wall.position);
        let mut acc = 0.0;
        for _ in 0..n {
            let (p, _, _) = self.step(force);
            acc += (0..3).map(|i| (p[i] - w[i]) * u[i]).sum::<f64>();
        }
        acc / n as f64
    }
}

/// The largest force the motors can give against a push along `u` at `q`
/// (the allocation's force-first scale, gravity compensation taking its
/// share of each motor), N.
fn capacity(q: &Joints, u: [f64; 3]) -> f64 {
    let kin = arm::kinematics(q);
    let tau = kin.jacobian_transpose_mul(&Wrench {
        force: Vec3::from_f64(u.map(|x| -x)),
        torque: Vec3::ZERO,
    });
    let mut cap = f64::INFINITY;
    for i in 0..6 {
        let t = f(tau[i]);
        let g = -f(kin.gravity[i]);
        let lim = f(arm::TAU_MAX[i]);
        if t.abs() > 1e-9 {
            let room = if t > 0.0 { lim - g } else { lim + g };
            cap = cap.min(room.max(0.0) / t.abs());
        }
    }
    cap
}

fn stiffness_table(svg: &mut Vec<(u32, Vec<(f64, f64)>)>) {
    println!("## Felt stiffness of a rigid wall (the client's object held still), N/mm = push / penetration");
    println!("(host native; steady push by the hand along each axis, mean over the last 0.3 s of 1.2 s; z is downward)");
    println!();
    println!(
        "| period | K_t (N/m) | pose | axis | capacity (N) | 5 N | 10 N | 25 N | pen. 10 N / 5 N |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    let mut worst = Vec::new();
    for &us in &PERIODS_US {
        let k = control::Gains::for_period(Fx::from_ns(us as u64 * 1000)).k_lin;
        let mut w5 = f64::INFINITY;
        let mut worst_ratio: f64 = 0.0;
        for (pname, q) in poses() {
            for (aname, u) in AXES {
                let cap = capacity(&q, u);
                let mut cells = Vec::new();
                let mut pens = Vec::new();
                for push in [5.0, 10.0, 25.0] {
                    let mut rig = Rig::new(us, &q, true);
                    let pen = rig.penetration(u, push);
                    pens.push(pen);
                    cells.push(format!(
                        "{:.2} ({:.1} mm)",
                        push / (pen * 1000.0),
                        pen * 1000.0
                    ));
                }
                let ratio = pens[1] / pens[0];
                w5 = w5.min(5.0 / (pens[0] * 1000.0));
                if cap >= 10.0 {
                    worst_ratio = worst_ratio.max(ratio);
                }
                println!(
                    "| {us} µs | {:.0} | {pname} | {aname} | {cap:.1} | {} | {} | {} | {ratio:.2}{} |",
                    f(k),
                    cells[0],
                    cells[1],
                    cells[2],
                    if cap < 10.0 { " (beyond capacity)" } else { "" }
                );
            }
        }
        worst.push((us, w5, worst_ratio));
    }
    println!();
    for (us, w5, r) in &worst {
        println!("period {us} µs: smallest felt stiffness at 5 N {w5:.2} N/mm; largest penetration ratio 10 N / 5 N where the motors give 10 N: {r:.2}");
    }
    println!();
    // Penetration curve at WORK_Q, downward.
    println!("## Penetration curve (WORK_Q, downward push)");
    println!();
    println!("| push (N) | 100 µs (mm) | 250 µs (mm) | 1 ms (mm) | 10 ms (mm) |");
    println!("|---|---|---|---|---|");
    let pushes = [1.0, 2.0, 4.0, 6.0, 8.0, 10.0, 15.0, 20.0, 25.0];
    let mut rows = vec![Vec::new(); pushes.len()];
    for &us in &PERIODS_US {
        let mut curve = Vec::new();
        for (i, &push) in pushes.iter().enumerate() {
            let mut rig = Rig::new(us, &arm::WORK_Q, true);
            let pen = rig.penetration(AXES[2].1, push) * 1000.0;
            rows[i].push(pen);
            curve.push((pen, push));
        }
        svg.push((us, curve));
    }
    for (i, push) in pushes.iter().enumerate() {
        println!(
            "| {push} | {} |",
            rows[i]
                .iter()
                .map(|p| format!("{p:.2}"))
                .collect::<Vec<_>>()
                .join(" | ")
        );
    }
    println!();
}

/// The joints at (or beyond) a position limit, as `q3 = -0.30` (joints
/// numbered from 1), or "none".
fn at_stops(q: &Joints) -> String {
    let mut out = Vec::new();
    for i in 0..6 {
        let (lo, hi) = (f(arm::Q_MIN[i]), f(arm::Q_MAX[i]));
        let x = f(q[i]);
        // Within 0.01 rad of the limit: the stop springs give a little.
        if x <= lo + 0.01 || x >= hi - 0.01 {
            out.push(format!("q{} = {x:.2}", i + 1));
        }
    }
    if out.is_empty() {
        "none".into()
    } else {
        out.join(", ")
    }
}

/// After a push beyond the capacity, how long until the wall is back
/// (penetration within 1 mm of where a 2 N touch holds it, or through that
/// depth within one cycle). The push is
/// 25 % above the motors' capacity for 0.3 s; a second table rams the arm
/// with 25 N for 0.5 s wherever that is beyond the capacity.
fn recovery() {
    for (title, over, secs) in [
        ("a push 25 % beyond the capacity for 0.3 s", None, 0.3),
        ("25 N for 0.5 s where the motors give less", Some(25.0), 0.5),
    ] {
        println!("## The wall after {title}, then a 2 N touch");
        println!();
        println!("| period | pose | axis | capacity (N) | push (N) | penetration at the push (mm) | 2 N touch before (mm) | back within 1 mm after (ms) | joints at a stop 2 s after |");
        println!("|---|---|---|---|---|---|---|---|---|");
        let mut worst: f64 = 0.0;
        for &us in &PERIODS_US {
            for (pname, q) in poses() {
                for (aname, u) in AXES {
                    let cap = capacity(&q, u);
                    let push = over.unwrap_or(cap * 1.25);
                    if push <= cap {
                        continue;
                    }
                    let mut rig = Rig::new(us, &q, true);
                    let before = rig.penetration(u, 2.0);
                    let mut rig = Rig::new(us, &q, true);
                    let w = v3(rig.wall.position);
                    let (p, _, _) = rig.run_for(secs, u.map(|x| x * push));
                    let deep = (0..3).map(|i| (p[i] - w[i]) * u[i]).sum::<f64>();
                    let mut back = None;
                    let mut prev = deep - before;
                    for n in 0..rig.cycles(2.0) {
                        let (p, _, _) = rig.step(u.map(|x| x * 2.0));
                        let pen = (0..3).map(|i| (p[i] - w[i]) * u[i]).sum::<f64>();
                        // Within 1 mm, or through it within one cycle (at
                        // 10 ms the handle moves several mm a cycle).
                        let off = pen - before;
                        if back.is_none() && (off.abs() < 1e-3 || off * prev < 0.0) {
                            back = Some(n as f64 * rig.period_s * 1000.0);
                        }
                        prev = off;
                    }
                    if us != 10_000 {
                        worst = worst.max(back.unwrap_or(f64::INFINITY));
                    }
                    println!(
                        "| {us} µs | {pname} | {aname} | {cap:.1} | {push:.1} | {:.1} | {:.1} | {} | {} |",
                        deep * 1000.0,
                        before * 1000.0,
                        back.map(|ms| format!("{ms:.0}")).unwrap_or_else(|| "not within 2 s".into()),
                        at_stops(&rig.c.servo.simulator().q)
                    );
                }
            }
        }
        println!();
        println!(
            "slowest return at 100 µs–1 ms: {}",
            if worst.is_finite() {
                format!("{worst:.0} ms")
            } else {
                "not within 2 s".into()
            }
        );
        println!();
    }
}

/// The arm's own viscous drag along `u` at `speed` at the pose `q`, N: the
/// force a hand holding only the handle's position (no torque) pushes to
/// move it at that speed through the joint dampers alone,
/// `speed · uᵀ (J_v D⁻¹ J_vᵀ)⁻¹ u` (f64).
fn viscous_drag(q: &Joints, u: [f64; 3], speed: f64) -> f64 {
    let j = arm::kinematics(q).jacobian();
    let mut m = [[0.0f64; 3]; 3];
    for (col, b) in j.iter().zip(arm::DAMPING.iter()) {
        let c = v3(col.linear);
        for r in 0..3 {
            for k in 0..3 {
                m[r][k] += c[r] * c[k] / f(*b);
            }
        }
    }
    let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    let mut x = 0.0;
    for r in 0..3 {
        for k in 0..3 {
            // (M⁻¹)[r][k] = cofactor[k][r] / det.
            let (k1, k2, r1, r2) = ((k + 1) % 3, (k + 2) % 3, (r + 1) % 3, (r + 2) % 3);
            let inv = (m[k1][r1] * m[k2][r2] - m[k1][r2] * m[k2][r1]) / det;
            x += u[r] * inv * u[k];
        }
    }
    speed * x
}

/// What the hand felt while driving the handle at a constant speed.
struct Drag {
    /// Mean force along the motion the hand pushed, N.
    push: f64,
    /// Of it, what the arm's joint dampers took: their mean power
    /// `Σ b_i q̇_i²` over the speed, N.
    dampers: f64,
    /// Of it, the change of the arm's kinetic energy `½Σ I_i q̇_i²` over
    /// the measured travel, N.
    kinetic: f64,
    /// Alarms raised meanwhile.
    alarms: u32,
}

/// The simulated arm's kinetic energy `½Σ I_i(q) q̇_i²`, J.
fn kinetic_energy(rig: &Rig) -> f64 {
    let s = rig.c.servo.simulator();
    let inertia = arm::kinematics(&s.q).inertia;
    (0..6)
        .map(|i| 0.5 * f(inertia[i]) * f(s.qd[i]) * f(s.qd[i]))
        .sum()
}

/// The hand drives the handle at a constant speed (a stiff hand:
/// 3000 N/m, 60 N·s/m around a point moving at `speed`); the mean force
/// along the motion the hand pushes while moving (after 60 mm), and the
/// share of it the arm's joint dampers dissipate.
fn drag(us: u32, q: &Joints, u: [f64; 3], speed: f64, coupled: bool) -> Drag {
    let mut rig = Rig::new(us, q, coupled);
    rig.follow = Some(((3e-3 / rig.period_s).round() as usize).max(1));
    let (mut p, mut v, _) = rig.step([0.0; 3]);
    let p0 = p;
    let (kh, bh) = (3000.0, 60.0);
    let mut acc = 0.0;
    let mut damp = 0.0;
    let (mut ke0, mut x0) = (0.0, 0.0);
    let mut n_acc = 0usize;
    let mut alarms = 0u32;
    let travel = 0.12;
    let n_total = (travel / speed / rig.period_s) as usize;
    for n in 0..n_total {
        let t = n as f64 * rig.period_s;
        let ph = [
            p0[0] + u[0] * speed * t,
            p0[1] + u[1] * speed * t,
            p0[2] + u[2] * speed * t,
        ];
        let mut fh = [0.0; 3];
        for i in 0..3 {
            fh[i] = kh * (ph[i] - p[i]) + bh * (u[i] * speed - v[i]);
        }
        let r = rig.step(fh);
        p = r.0;
        v = r.1;
        let along = (0..3).map(|i| fh[i] * u[i]).sum::<f64>();
        if speed * t > 0.06 {
            if n_acc == 0 {
                ke0 = kinetic_energy(&rig);
                x0 = speed * t;
            }
            acc += along;
            n_acc += 1;
            alarms |= rig.c.servo.vp().alarms;
            let qd = rig.c.servo.simulator().qd;
            damp += (0..6)
                .map(|i| f(arm::DAMPING[i]) * f(qd[i]) * f(qd[i]))
                .sum::<f64>()
                / speed;
        }
    }
    let n = n_acc.max(1) as f64;
    let travelled = (travel - x0).max(1e-9);
    Drag {
        push: acc / n,
        dampers: damp / n,
        kinetic: (kinetic_energy(&rig) - ke0) / travelled,
        alarms,
    }
}

/// Directions with free travel from each pose: toward the base (radial
/// inward), sideways (tangential), down.
fn free_axes(q: &Joints) -> [(&'static str, [f64; 3]); 3] {
    let (s, c) = (f(q[0]).sin(), f(q[0]).cos());
    [
        ("toward base", [-c, -s, 0.0]),
        ("sideways", [-s, c, 0.0]),
        ("down", [0.0, 0.0, -1.0]),
    ]
}

fn drag_table() {
    println!(
        "## Drag of free motion: the force the hand pushes to move the handle at a constant speed"
    );
    println!("(the client's object follows the handle every 3 ms; \"off\": coupling off, gravity compensation and brakes only; mean over the last half of 0.12 m)");
    println!();
    println!("(coupling off, what the arm itself takes of the push: its joint dampers, their power Σ b_i q̇_i² over the speed, and the change of its kinetic energy ½Σ I_i q̇_i² over the travel; no coupling adds these)");
    println!();
    println!("| period | pose | axis | 0.1 m/s (N) | 0.5 m/s (N) | 1 m/s (N) | 0.5 m/s, coupling off (N) | of which the arm's dampers (N) | of which its kinetic energy (N) | brakes or stops acting at 0.5 m/s |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    let mut worst05: f64 = 0.0;
    // The bench's hand (3000 N/m, 60 N·s/m) is sampled at the servo
    // period: at 10 ms it is not a stable hand, so 10 ms is left out.
    for &us in &PERIODS_US[..3] {
        for (pname, q) in poses() {
            for (aname, u) in free_axes(&q) {
                let a = drag(us, &q, u, 0.1, true).push;
                let on = drag(us, &q, u, 0.5, true);
                let c = drag(us, &q, u, 1.0, true).push;
                let off = drag(us, &q, u, 0.5, false);
                let (b, d) = (on.push, off.push);
                worst05 = worst05.max(b.abs()).max(d.abs());
                let al = on.alarms | off.alarms;
                let mut why = Vec::new();
                if al & hap_core::vp::alarm::VELOCITY_LIMIT != 0 {
                    why.push("velocity brake");
                }
                if al & hap_core::vp::alarm::JOINT_LIMIT != 0 {
                    why.push("joint stop");
                }
                let why = if why.is_empty() {
                    "none".to_string()
                } else {
                    why.join(", ")
                };
                println!(
                    "| {us} µs | {pname} | {aname} | {a:.2} | {b:.2} | {c:.2} | {d:.2} | {:.2} | {:.2} | {why} |",
                    off.dampers, off.kinetic
                );
            }
        }
    }
    println!();
    println!("largest push at 0.5 m/s: {worst05:.2} N");
    println!();
}

/// Largest powered handle speed under a constant 25 N push, coupling off
/// and on (object following every 3 ms), until a joint stop ends the push.
fn speed_table() {
    println!(
        "## Largest powered handle speed under a constant 25 N push (2 s or until a joint stop)"
    );
    println!();
    println!("(where the handle first passes 2 m/s with the coupling on: the push's component along the motion, and the most the arm could oppose the motion there, the motors' capacity against it plus the arm's own viscous drag at 2 m/s along it, 2·v̂ᵀ(J_v D⁻¹ J_vᵀ)⁻¹v̂; where the push is the larger, no controller keeps the handle under 2 m/s)");
    println!();
    println!("| period | pose | axis | capacity at the start (N) | at 2 m/s: push along the motion (N) | at 2 m/s: most the arm can oppose (N) | coupling off (m/s) | coupling on, object following (m/s) |");
    println!("|---|---|---|---|---|---|---|---|");
    let mut worst: f64 = 0.0;
    for &us in &PERIODS_US {
        for (pname, q) in poses() {
            for (aname, u) in free_axes(&q) {
                let mut cells = Vec::new();
                // Coupling on, where the handle first passes 2 m/s: the
                // push along the motion there and the most the arm could
                // oppose it (the motors' capacity against the motion plus
                // the arm's own viscous drag at 2 m/s along it).
                let mut at_2 = None;
                for coupled in [false, true] {
                    let mut rig = Rig::new(us, &q, coupled);
                    rig.follow = Some(((3e-3 / rig.period_s).round() as usize).max(1));
                    let mut vmax: f64 = 0.0;
                    for _ in 0..rig.cycles(2.0) {
                        let (_, v, _) = rig.step(u.map(|x| x * 25.0));
                        let speed = norm(v);
                        vmax = vmax.max(speed);
                        if coupled && at_2.is_none() && speed > 2.0 {
                            let qq = rig.c.servo.simulator().q;
                            let vh = v.map(|x| x / speed);
                            let push = 25.0 * (0..3).map(|i| u[i] * vh[i]).sum::<f64>();
                            at_2 = Some((push, capacity(&qq, vh) + viscous_drag(&qq, vh, 2.0)));
                        }
                    }
                    worst = worst.max(vmax);
                    cells.push(vmax);
                }
                let (push, hold) = at_2
                    .map(|(p, h)| (format!("{p:.1}"), format!("{h:.1}")))
                    .unwrap_or_else(|| ("—".into(), "—".into()));
                println!(
                    "| {us} µs | {pname} | {aname} | {:.1} | {push} | {hold} | {:.2} | {:.2} |",
                    capacity(&q, u),
                    cells[0],
                    cells[1]
                );
            }
        }
    }
    println!();
    println!("largest powered handle speed under 25 N: {worst:.2} m/s");
    println!();
}

/// The Cartesian force the motors give the handle this cycle beyond gravity
/// compensation: the coupling's and the Cartesian brake's.
fn motor_force(rig: &Rig) -> [f64; 3] {
    let o = rig.c.servo.control_output();
    v3(o.handle_wrench.force.add(o.brake_force))
}

/// A scripted hand: the force for cycle `k`, free to change the rig.
type Script = Box<dyn FnMut(&mut Rig, usize) -> [f64; 3]>;

/// The largest change of the motors' force on the handle in one cycle, per
/// cause, at `us`.
fn force_steps(us: u32) -> Vec<(&'static str, f64)> {
    let mut out = Vec::new();
    let q = arm::WORK_Q;
    let max_step = |rig: &mut Rig, n: usize, mut script: Script| {
        let mut prev = motor_force(rig);
        let mut worst: f64 = 0.0;
        for k in 0..n {
            let fh = script(rig, k);
            rig.step(fh);
            let fm = motor_force(rig);
            let d = [fm[0] - prev[0], fm[1] - prev[1], fm[2] - prev[2]];
            worst = worst.max(norm(d));
            prev = fm;
        }
        worst
    };
    // Link drop with the object moved 5 cm meanwhile, then resume.
    {
        let mut rig = Rig::new(us, &q, true);
        rig.run_for(0.2, [0.0; 3]);
        let moved = rig.wall.position.add(Vec3::from_f64([0.0, 0.05, 0.0]));
        let n = rig.cycles(0.6);
        let drop = rig.cycles(0.15);
        let w = max_step(
            &mut rig,
            n,
            Box::new(move |r: &mut Rig, k| {
                if k == 10 {
                    r.vpr.pose.position = moved;
                }
                if (10..10 + drop).contains(&k) {
                    // Silent link: the latch keeps the last frame, its age grows.
                    r.vpr.seq = r.vpr.seq.wrapping_sub(1);
                    r.vpr.received_cycle = r.c.servo.cycle().saturating_sub(k as u64 - 9);
                }
                [0.0; 3]
            }),
        );
        out.push(("link drop 150 ms, object moved 5 cm, resume", w));
    }
    // A client alternating its target by ±2 cm every cycle.
    {
        let mut rig = Rig::new(us, &q, true);
        let base = rig.wall.position;
        let n = rig.cycles(0.3);
        let w = max_step(
            &mut rig,
            n,
            Box::new(move |r: &mut Rig, k| {
                let s = if k % 2 == 0 { 0.02 } else { -0.02 };
                r.vpr.pose.position = base.add(Vec3::from_f64([0.0, s, 0.0]));
                [0.0; 3]
            }),
        );
        out.push(("client target alternating ±2 cm every cycle", w));
    }
    // A client target jump of 10 cm.
    {
        let mut rig = Rig::new(us, &q, true);
        let jump = rig.wall.position.add(Vec3::from_f64([0.1, 0.0, 0.0]));
        let n = rig.cycles(0.3);
        let w = max_step(
            &mut rig,
            n,
            Box::new(move |r: &mut Rig, k| {
                if k == 5 {
                    r.vpr.pose.position = jump;
                }
                [0.0; 3]
            }),
        );
        out.push(("client target jump 10 cm", w));
    }
    // Session close (VPr invalid) and reopen with the object 3 cm away.
    {
        let mut rig = Rig::new(us, &q, true);
        let away = rig.wall.position.add(Vec3::from_f64([0.0, 0.0, 0.03]));
        let n = rig.cycles(0.5);
        let w = max_step(
            &mut rig,
            n,
            Box::new(move |r: &mut Rig, k| {
                let close = r.cycles(0.1);
                if k == 5 {
                    r.vpr.pose.position = away;
                }
                r.vpr.valid = !(5 + 1..5 + close).contains(&k);
                [0.0; 3]
            }),
        );
        out.push(("session close and reopen 3 cm away", w));
    }
    // Power off and on while the object is 3 cm away.
    {
        let mut rig = Rig::new(us, &q, true);
        rig.vpr.pose.position = rig.wall.position.add(Vec3::from_f64([0.0, 0.0, 0.03]));
        rig.run_for(0.2, [0.0; 3]);
        let mut prev = motor_force(&rig);
        let mut worst: f64 = 0.0;
        for k in 0..rig.cycles(0.4) {
            let mut inp = hand([0.0; 3]);
            inp.power_request = if k == 0 {
                PowerRequest::Off
            } else if k == rig.cycles(0.1) {
                PowerRequest::On
            } else {
                PowerRequest::None
            };
            rig.vpr.seq = rig.vpr.seq.wrapping_add(1);
            rig.vpr.received_cycle = rig.c.servo.cycle();
            rig.c
                .run(&rig.line, &inp, &rig.cfg, Some(&rig.vpr), Mode::Main);
            let fm = motor_force(&rig);
            // The switch-off itself is a cut (0 at once, by design): only
            // the power-on ramp counts here.
            if k > 0 {
                worst = worst.max(norm([fm[0] - prev[0], fm[1] - prev[1], fm[2] - prev[2]]));
            }
            prev = fm;
        }
        out.push(("power on with the object 3 cm away", worst));
    }
    // Brake onset: the hand throws the handle at 2 m/s with the object
    // dragging behind (following every 3 ms).
    {
        let mut rig = Rig::new(us, &q, true);
        let n = rig.cycles(0.4);
        rig.follow = Some(((3e-3 / rig.period_s).round() as usize).max(1));
        let w = max_step(
            &mut rig,
            n,
            Box::new(move |_r: &mut Rig, _k| [0.0, 25.0, 0.0]),
        );
        out.push(("hand throws the handle (25 N), brakes engage", w));
    }
    // Saturation: a 25 N push into the wall beyond the capacity, then release.
    {
        let mut rig = Rig::new(us, &q, true);
        let n = rig.cycles(1.0);
        let w = max_step(
            &mut rig,
            n,
            Box::new(move |_r: &mut Rig, k| {
                let t = k as f64 / n as f64;
                // A hand that presses in and lets go over 0.1 s each.
                let push = if t < 0.4 {
                    (t / 0.1).min(1.0) * 25.0
                } else {
                    ((0.5 - t) / 0.1).clamp(0.0, 1.0) * 25.0
                };
                [0.0, 0.0, -push]
            }),
        );
        out.push(("25 N press into the wall and release (saturation)", w));
    }
    // Degraded episodes (main ↔ degraded every 7 cycles) under a 5 N push.
    {
        let mut rig = Rig::new(us, &q, true);
        let mut prev = motor_force(&rig);
        let mut worst: f64 = 0.0;
        for k in 0..rig.cycles(0.3) {
            let mode = if (k / 7) % 2 == 0 {
                Mode::Main
            } else {
                Mode::Degraded
            };
            rig.vpr.seq = rig.vpr.seq.wrapping_add(1);
            rig.vpr.received_cycle = rig.c.servo.cycle();
            rig.c.run(
                &rig.line,
                &hand([0.0, 0.0, -5.0]),
                &rig.cfg,
                Some(&rig.vpr),
                mode,
            );
            let fm = motor_force(&rig);
            if k > 300 {
                worst = worst.max(norm([fm[0] - prev[0], fm[1] - prev[1], fm[2] - prev[2]]));
            }
            prev = fm;
        }
        out.push(("main ↔ degraded every 7 cycles, 5 N push", worst));
    }
    out
}

fn zwidth(svg_dir: Option<&str>) {
    println!("## Passive region (Z-width) per period: largest K for a damping B, joint-space condition at T");
    println!("(K_max(B) = 2(1/a − B)/T for the translational spring alone, a = λ_max(J_v D⁻¹ J_vᵀ) = {:.3} over the workspace; the point is the law's (K_t, B_t))", f(LIN_MOBILITY_MAX));
    println!();
    println!("| period | K_max at B = 0 (N/m) | at B = 0.2 | at B = 0.5 | law: K_t (N/m), B_t (N·s/m) | K_t / K_max(B_t) |");
    println!("|---|---|---|---|---|---|");
    let a = f(LIN_MOBILITY_MAX);
    let mut lines = Vec::new();
    for &us in &PERIODS_US {
        let t = us as f64 * 1e-6;
        let g = Gains::for_period(Fx::from_ns(us as u64 * 1000));
        let kmax = |b: f64| (2.0 * (1.0 / a - b) / t).max(0.0);
        println!(
            "| {us} µs | {:.0} | {:.0} | {:.0} | {:.0}, {:.3} | {:.2} |",
            kmax(0.0),
            kmax(0.2),
            kmax(0.5),
            f(g.k_lin),
            f(g.b_lin),
            f(g.k_lin) / kmax(f(g.b_lin))
        );
        lines.push((us, kmax(0.0), f(g.k_lin), f(g.b_lin)));
    }
    println!();
    if let Some(dir) = svg_dir {
        // One small SVG: K_max(B) per period (log K), the law's points.
        let (w, h) = (640.0, 420.0);
        let (x0, y0, x1, y1) = (70.0, 20.0, 620.0, 370.0);
        let bmax = 1.0 / a;
        let ky = |k: f64| y1 - (k.max(10.0).log10() - 1.0) / 4.0 * (y1 - y0);
        let bx = |b: f64| x0 + b / bmax * (x1 - x0);
        let mut s = format!("<svg xmlns='http://www.w3.org/2000/svg' width='{w}' height='{h}' font-family='sans-serif' font-size='12'>\n<rect width='100%' height='100%' fill='white'/>\n");
        s += &format!("<line x1='{x0}' y1='{y1}' x2='{x1}' y2='{y1}' stroke='black'/><line x1='{x0}' y1='{y0}' x2='{x0}' y2='{y1}' stroke='black'/>\n");
        for e in 1..=5 {
            let y = ky(10f64.powi(e));
            s += &format!("<text x='{}' y='{}' text-anchor='end'>1e{e}</text><line x1='{x0}' y1='{y}' x2='{x1}' y2='{y}' stroke='#ddd'/>\n", x0 - 5.0, y + 4.0);
        }
        for i in 0..=5 {
            let b = bmax * i as f64 / 5.0;
            s += &format!(
                "<text x='{}' y='{}' text-anchor='middle'>{b:.2}</text>\n",
                bx(b),
                y1 + 16.0
            );
        }
        s += &format!(
            "<text x='{}' y='{}' text-anchor='middle'>coupling damping B (N·s/m)</text>\n",
            (x0 + x1) / 2.0,
            h - 10.0
        );
        s += &format!("<text x='15' y='{}' transform='rotate(-90 15 {})' text-anchor='middle'>stiffness K (N/m), passive below the line</text>\n", (y0 + y1) / 2.0, (y0 + y1) / 2.0);
        let colours = ["#1f77b4", "#2ca02c", "#d62728", "#9467bd"];
        for (i, (us, k0, kt, bt)) in lines.iter().enumerate() {
            let c = colours[i % 4];
            s += &format!(
                "<line x1='{}' y1='{}' x2='{}' y2='{}' stroke='{c}' stroke-width='2'/>\n",
                bx(0.0),
                ky(*k0),
                bx(bmax * 0.999),
                ky(k0 * 0.001)
            );
            s += &format!("<circle cx='{}' cy='{}' r='4' fill='{c}'/><text x='{}' y='{}' fill='{c}'>{us} µs: K_t {kt:.0}</text>\n", bx(*bt), ky(*kt), bx(*bt) + 8.0, ky(*kt) - 6.0);
        }
        s += "</svg>\n";
        let path = format!("{dir}/zwidth.svg");
        std::fs::write(&path, s).expect("write the Z-width plot");
        println!("Z-width plot: {path}");
        println!();
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let svg_dir = args
        .iter()
        .position(|a| a == "--svg")
        .and_then(|i| args.get(i + 1))
        .cloned();
    let only = args
        .iter()
        .position(|a| a == "--only")
        .and_then(|i| args.get(i + 1))
        .cloned();
    let want = |name: &str| only.as_deref().map(|o| o == name).unwrap_or(true);
    println!("# hapticctrl fidelity bench (host native, deterministic; simulated Virtuose arm through ServoCycle::run)");
    println!();
    let mut curves = Vec::new();
    if want("stiffness") {
        stiffness_table(&mut curves);
    }
    if want("recovery") {
        recovery();
    }
    if want("drag") {
        drag_table();
    }
    if want("speed") {
        speed_table();
    }
    if want("steps") {
        println!(
            "## Largest change of the motors' force on the handle in one cycle, per cause (WORK_Q)"
        );
        println!("(the coupling's force and the Cartesian brake's, as the allocation gave them to the motors)");
        println!();
        println!("| cause | 100 µs (N) | 250 µs (N) | 1 ms (N) | 10 ms (N) |");
        println!("|---|---|---|---|---|");
        let cols: Vec<Vec<(&str, f64)>> = PERIODS_US.iter().map(|&us| force_steps(us)).collect();
        for (i, (name, _)) in cols[0].iter().enumerate() {
            println!(
                "| {name} | {} |",
                cols.iter()
                    .map(|c| format!("{:.3}", c[i].1))
                    .collect::<Vec<_>>()
                    .join(" | ")
            );
        }
        let worst_1ms = cols[2].iter().map(|c| c.1).fold(0.0, f64::max);
        println!();
        println!("largest force step in one 1 ms cycle: {worst_1ms:.3} N");
        println!();
    }
    if want("zwidth") {
        zwidth(svg_dir.as_deref());
    }
}
