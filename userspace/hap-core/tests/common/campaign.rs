//! The safety campaign: randomized runs through `ServoCycle::run` with
//! deterministic seeds, every property checked at the torque the motors
//! apply (`MotorLine::applied`, what `simulate_arm` integrates) and on the
//! handle's motion. Shared by `tests/safety.rs` (a small seed set) and
//! `examples/safety_campaign.rs` (the full campaign, `scripts/bench-safety.sh`).
#![allow(dead_code, clippy::needless_range_loop)]

use hap_core::arm;
use hap_core::config::{CommandType, ServoConfig, VirtualObjectParams};
use hap_core::control::{
    brake_gains, BRAKE_START, COUPLING_JOINT_STOP_DEN, COUPLING_JOINT_STOP_NUM, D_CLAMP, MAX_FORCE,
};
use hap_core::cycle::ServoCycle;
use hap_core::effort::EffortSample;
use hap_core::fixed::{Fx, Joints, Pose, Quat, Twist, Vec3, Wrench, JOINTS_ZERO};
use hap_core::io::MotorLine;
use hap_core::mode::Mode;
use hap_core::proto_synchro::LINK_FADE_START_US;
use hap_core::servo::{log_flags, PowerRequest, ServoInputs};
use hap_core::vp::VpReceived;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

/// Strongest user force (N) and torque (N·m) of the campaign.
pub const USER_FORCE_MAX: f64 = 25.0;
pub const USER_TORQUE_MAX: f64 = 0.5;

/// Figures of one or many runs.
#[derive(Clone, Debug, Default)]
pub struct Figures {
    pub runs: u64,
    pub cycles: u64,
    pub coupled_cycles: u64,
    pub passivity_cycles: u64,
    /// Cycles in which the elbow's soft stop pushed.
    pub elbow_stop_cycles: u64,
    /// Lowest energy of the elbow's soft stop at the motors, J: its share
    /// of the elbow's dissipation less the work its torque did on the arm.
    pub worst_elbow_ledger: f64,
    pub link_loss_events: u64,
    pub link_loss_unfaded: u64,
    pub resumes: u64,
    pub worst_resume_excess: f64,
    pub worst_env_step: f64,
    pub mode_switches: u64,
    pub mode_switch_energy: f64,
    pub clamp_cycles: u64,
    pub worst_force_excess: f64,
    pub worst_torque_ratio: f64,
    pub max_speed: f64,
    pub speed_bound: f64,
    pub worst_joint_speed_ratio: f64,
    pub worst_ledger: f64,
    pub worst_observer: f64,
    pub worst_motor_mismatch: f64,
    pub cuts: u64,
    pub cut_nonzero: u64,
}

impl Figures {
    pub fn new() -> Figures {
        Figures {
            worst_ledger: f64::INFINITY,
            worst_observer: f64::INFINITY,
            worst_elbow_ledger: f64::INFINITY,
            ..Default::default()
        }
    }

    pub fn merge(&mut self, o: &Figures) {
        self.runs += o.runs;
        self.cycles += o.cycles;
        self.coupled_cycles += o.coupled_cycles;
        self.passivity_cycles += o.passivity_cycles;
        self.elbow_stop_cycles += o.elbow_stop_cycles;
        self.link_loss_events += o.link_loss_events;
        self.link_loss_unfaded += o.link_loss_unfaded;
        self.resumes += o.resumes;
        self.worst_resume_excess = self.worst_resume_excess.max(o.worst_resume_excess);
        self.worst_env_step = self.worst_env_step.max(o.worst_env_step);
        self.mode_switches += o.mode_switches;
        self.mode_switch_energy += o.mode_switch_energy;
        self.clamp_cycles += o.clamp_cycles;
        self.worst_force_excess = self.worst_force_excess.max(o.worst_force_excess);
        self.worst_torque_ratio = self.worst_torque_ratio.max(o.worst_torque_ratio);
        self.max_speed = self.max_speed.max(o.max_speed);
        self.speed_bound = self.speed_bound.max(o.speed_bound);
        self.worst_joint_speed_ratio = self.worst_joint_speed_ratio.max(o.worst_joint_speed_ratio);
        self.worst_ledger = self.worst_ledger.min(o.worst_ledger);
        self.worst_observer = self.worst_observer.min(o.worst_observer);
        self.worst_elbow_ledger = self.worst_elbow_ledger.min(o.worst_elbow_ledger);
        self.worst_motor_mismatch = self.worst_motor_mismatch.max(o.worst_motor_mismatch);
        self.cuts += o.cuts;
        self.cut_nonzero += o.cut_nonzero;
    }

    pub fn print(&self, label: &str) {
        println!(
            "{label}: {} runs, {} cycles ({} coupled, PASSIVITY active in {} = {:.4} %, the elbow's soft stop pushing in {})",
            self.runs,
            self.cycles,
            self.coupled_cycles,
            self.passivity_cycles,
            100.0 * self.passivity_cycles as f64 / (self.coupled_cycles.max(1) as f64),
            self.elbow_stop_cycles
        );
        println!(
            "  link loss: {} events, {} with motor force above the fade; resumes: {}, worst force above the ramp {:.2e} N; worst envelope step {:.5} (ramp: T/50 ms per cycle)",
            self.link_loss_events, self.link_loss_unfaded, self.resumes, self.worst_resume_excess, self.worst_env_step
        );
        println!(
            "  mode switches: {}, energy from gain changes {:.3e} J; cycles with the torque-vector scaling: {}",
            self.mode_switches, self.mode_switch_energy, self.clamp_cycles
        );
        println!(
            "  worst coupling force above its bound {:.2e} N; worst |τ|/τ_max {:.4}; motor torque vs controller {:.2e} N·m",
            self.worst_force_excess, self.worst_torque_ratio, self.worst_motor_mismatch
        );
        println!(
            "  max handle speed {:.3} m/s (proven bound {:.3} m/s); worst joint speed / its bound {:.3}",
            self.max_speed, self.speed_bound, self.worst_joint_speed_ratio
        );
        println!(
            "  worst coupling energy (motor-side ledger) {:.3e} J, observer {:.3e} J; fail-safe cuts {}, cycles with torque ≠ 0 after a cut {}",
            self.worst_ledger, self.worst_observer, self.cuts, self.cut_nonzero
        );
        println!(
            "  worst energy of the elbow's soft stop at the motors {:.3e} J",
            self.worst_elbow_ledger
        );
    }
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

/// Largest |gravity torque| on each joint over the workspace (lever bounds).
pub fn gravity_bound() -> [f64; 6] {
    let m: Vec<f64> = arm::MASS.iter().map(|x| f(*x)).collect();
    let (l1, l2, l3, h0) = (f(arm::L1), f(arm::L2), f(arm::L3), f(arm::H0));
    let g = f(arm::GRAVITY);
    // Farthest distance of each centre of mass from each joint axis.
    let d = [
        [0.0, 0.0, 0.0], // yaw axis is vertical: gravity has no moment on it
        [l1 / 2.0, l1 + l2 / 2.0, l1 + l2 + l3 / 2.0],
        [0.0, l2 / 2.0, l2 + l3 / 2.0],
        [0.0, 0.0, l3 / 2.0],
        [0.0, 0.0, l3 / 2.0],
        [0.0, 0.0, l3 / 2.0],
    ];
    let _ = h0;
    let mut out = [0.0; 6];
    for i in 0..6 {
        out[i] = g * (0..3).map(|k| m[k] * d[i][k]).sum::<f64>();
    }
    out
}

/// The proven joint speed bound under the campaign's strongest user effort
/// (see Documentation/control.md): per joint, with `τ_u` the largest user
/// torque, `A` the motor torque left after gravity compensation, `B` the
/// brake gain, `b` the damping, `ω_v` the speed beyond which the coupling
/// never drives the joint along its motion (`BRAKE_START`·5/4):
/// `ω ≤ max(ω_v + τ_u/(B + b), (τ_u − A)/b)`.
pub fn joint_speed_bound(period_ns: u32) -> [f64; 6] {
    let brake = brake_gains(Fx::from_ns(period_ns as u64));
    let gb = gravity_bound();
    let mut out = [0.0; 6];
    for i in 0..6 {
        let r = f(arm::LEVER_MAX[i]);
        let tu = USER_FORCE_MAX * r + USER_TORQUE_MAX;
        let a = (f(arm::TAU_MAX[i]) - gb[i]).max(0.0);
        let b = f(arm::DAMPING[i]);
        let bb = f(brake[i]);
        // Beyond `COUPLING_JOINT_STOP` (5/4 of the brake's start) the
        // coupling never drives the joint along its motion.
        let ws =
            f(BRAKE_START[i]) * COUPLING_JOINT_STOP_NUM as f64 / COUPLING_JOINT_STOP_DEN as f64;
        out[i] = (ws + tu / (bb + b)).max((tu - a) / b) + 1e-3;
    }
    out
}

/// The handle speed bound `Σ r_i·ω_i`.
pub fn handle_speed_bound(period_ns: u32) -> f64 {
    let w = joint_speed_bound(period_ns);
    (0..6).map(|i| f(arm::LEVER_MAX[i]) * w[i]).sum()
}

#[derive(Clone, Copy, PartialEq, Debug)]
enum Client {
    /// Steps of the target around the handle.
    Steps,
    /// A target moving at constant speed.
    Ramp,
    /// A stiff wall proxy, delayed by 0–5 cycles.
    Wall,
    /// A free mass behind a penalty wall, driven by the coupling wrench.
    Mass,
}

/// One run: `cycles` cycles at `period_us`, seed `seed`. Panics (with the
/// seed and cycle) on the first violated property.
pub fn run(seed: u64, period_us: u32, cycles: u64) -> Figures {
    let mut rng = StdRng::seed_from_u64(seed ^ (period_us as u64) << 32);
    let period_ns = period_us * 1000;
    let t = period_us as f64 * 1e-6;
    let line = MotorLine::new();
    let mut c = ServoCycle::new(period_us);
    c.servo.init();
    // A random start pose inside the workspace.
    let mut q0 = arm::WORK_Q;
    for i in 0..6 {
        let lo = f(arm::Q_MIN[i]) * 0.6;
        let hi = f(arm::Q_MAX[i]) * 0.6;
        q0[i] = Fx::from_f64(rng.gen_range(lo..hi));
    }
    c.servo.simulator_mut().set_state(&q0, &JOINTS_ZERO);
    let mut cfg = ServoConfig {
        command_type: CommandType::Impedance,
        ..Default::default()
    };
    if rng.gen_bool(0.3) {
        cfg.command_type = CommandType::VirtMech;
        cfg.attached_object = Some(VirtualObjectParams {
            mass: Fx::from_f64(rng.gen_range(0.05..5.0)),
            inertia: Vec3::ZERO,
        });
        cfg.time_step = Fx::from_f64(t);
    }
    let wbound = joint_speed_bound(period_ns);
    let mut figs = Figures {
        runs: 1,
        speed_bound: handle_speed_bound(period_ns),
        worst_ledger: f64::INFINITY,
        worst_observer: f64::INFINITY,
        worst_elbow_ledger: f64::INFINITY,
        ..Default::default()
    };
    let ramp_step = f(c.servo.controller().ramp_step());

    let mut shared = VpReceived::default();
    let mut client = Client::Steps;
    let mut episode_left = 0u64;
    let mut effort_left = 0u64;
    let mut user = EffortSample::NONE;
    let mut drop_left = 0u64;
    let mut drop_busy = false;
    let mut degraded_left = 0u64;
    let mut closed_left = 0u64;
    let mut power_off_left = 0u64;
    let mut mode;
    let mut seq = 0u32;
    // Client state.
    let mut target = Pose::IDENTITY;
    let mut target_v = [0.0f64; 3];
    let mut wall_x = 0.0f64;
    let mut wall_delay = 0usize;
    let mut history: Vec<(Pose, Twist)> = Vec::new();
    let mut mass_p = [0.0f64; 3];
    let mut mass_v = [0.0f64; 3];
    let mut mass_m = 1.0f64;
    let mut last_answer = Wrench::ZERO;
    // Checks' memory.
    let mut prev_env = 0.0f64;
    let mut prev_q: Option<Joints> = None;
    let mut prev_target: Option<Pose> = None;
    let mut prev_hw = Wrench::ZERO;
    let mut prev_fixed_tau = [0.0f64; 6];
    let mut prev_applied = [0.0f64; 6];
    let mut prev_elbow_pushed = false;
    // The elbow soft stop's torque the motors held over the last period,
    // and its ledger (it starts off, storing nothing).
    let mut prev_elbow_tau = 0.0f64;
    let mut elbow_ledger = 0.0f64;
    let mut ledger: Option<f64> = None;
    let mut in_loss = false;
    let mut loss_unfaded = false;
    let mut resume_k: Option<u64> = None;
    let mut prev_mode = Mode::Main;
    let mut prev_gains = c.servo.controller().effective_gains();
    let cut_at = if rng.gen_bool(0.5) {
        Some(cycles.saturating_sub(rng.gen_range(50..400)))
    } else {
        None
    };
    let mut cut = false;
    let mut entered_fast = [true; 6];

    for n in 0..cycles {
        // ---- Scenario.
        let mut power = PowerRequest::None;
        if n == 0 {
            power = PowerRequest::On;
        }
        if power_off_left > 0 {
            power_off_left -= 1;
            if power_off_left == 0 {
                power = PowerRequest::On;
            }
        } else if rng.gen_bool(0.0005) {
            power = PowerRequest::Off;
            power_off_left = rng.gen_range(1..300);
        }
        if effort_left == 0 {
            effort_left = rng.gen_range(20..800);
            let dir = [
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0f64..1.0),
            ];
            let dn = norm(dir).max(1e-9);
            let mag = if rng.gen_bool(0.2) {
                USER_FORCE_MAX
            } else {
                rng.gen_range(0.0..USER_FORCE_MAX)
            };
            let tq = [
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0f64..1.0),
            ];
            let tn = norm(tq).max(1e-9);
            let tm = rng.gen_range(0.0..USER_TORQUE_MAX);
            user = EffortSample {
                wrench: Wrench {
                    force: Vec3::from_f64([
                        dir[0] / dn * mag,
                        dir[1] / dn * mag,
                        dir[2] / dn * mag,
                    ]),
                    torque: Vec3::from_f64([tq[0] / tn * tm, tq[1] / tn * tm, tq[2] / tn * tm]),
                },
                dead_man: rng.gen_bool(0.95),
                buttons: 0,
            };
        }
        effort_left -= 1;
        let handle = c.servo.simulator().q;
        let kin = arm::kinematics(&handle);
        let hp = v3(kin.handle.position);
        if episode_left == 0 {
            episode_left = rng.gen_range(100..3000);
            client = match rng.gen_range(0..4) {
                0 => Client::Steps,
                1 => Client::Ramp,
                2 => Client::Wall,
                _ => Client::Mass,
            };
            target = kin.handle;
            target_v = [
                rng.gen_range(-0.3..0.3),
                rng.gen_range(-0.3..0.3),
                rng.gen_range(-0.3..0.3),
            ];
            wall_x = hp[0] + rng.gen_range(-0.02..0.02);
            wall_delay = rng.gen_range(0..=5);
            history.clear();
            mass_p = hp;
            mass_v = [0.0; 3];
            mass_m = rng.gen_range(0.05..2.0);
        }
        episode_left -= 1;
        let (pose, twist) = match client {
            Client::Steps => {
                if rng.gen_bool(0.005) {
                    let p = [
                        hp[0] + rng.gen_range(-0.05..0.05),
                        hp[1] + rng.gen_range(-0.05..0.05),
                        hp[2] + rng.gen_range(-0.05..0.05),
                    ];
                    target.position = Vec3::from_f64(p);
                    target.orientation = Quat::from_axis_angle(
                        Vec3::from_f64([
                            rng.gen_range(-1.0..1.0),
                            rng.gen_range(-1.0..1.0),
                            rng.gen_range(-1.0..1.0),
                        ]),
                        Fx::from_f64(rng.gen_range(-0.3..0.3)),
                    )
                    .mul(&kin.handle.orientation);
                }
                (target, Twist::ZERO)
            }
            Client::Ramp => {
                let p = v3(target.position);
                target.position = Vec3::from_f64([
                    p[0] + target_v[0] * t,
                    p[1] + target_v[1] * t,
                    p[2] + target_v[2] * t,
                ]);
                (
                    target,
                    Twist {
                        linear: Vec3::from_f64(target_v),
                        angular: Vec3::ZERO,
                    },
                )
            }
            Client::Wall => {
                // God-object proxy: follows the handle, never beyond x_wall.
                let mut p = kin.handle;
                let mut tw = Twist::ZERO;
                if f(p.position.x) > wall_x {
                    p.position.x = Fx::from_f64(wall_x);
                } else {
                    tw = c.servo.vp().handle_twist;
                }
                history.push((p, tw));
                let k = history.len().saturating_sub(1 + wall_delay);
                history[k]
            }
            Client::Mass => {
                // The client's object: m·a = −answer + penalty wall.
                let fa = v3(last_answer.force);
                let pen = if mass_p[2] < hp[2] - 0.03 {
                    3000.0 * (hp[2] - 0.03 - mass_p[2])
                } else {
                    0.0
                };
                for k in 0..3 {
                    let fk = fa[k] + if k == 2 { pen } else { 0.0 } - 2.0 * mass_v[k];
                    mass_v[k] += fk / mass_m * t;
                    mass_p[k] += mass_v[k] * t;
                }
                (
                    Pose {
                        position: Vec3::from_f64(mass_p),
                        orientation: kin.handle.orientation,
                    },
                    Twist {
                        linear: Vec3::from_f64(mass_v),
                        angular: Vec3::ZERO,
                    },
                )
            }
        };
        // Mode switches of the client: command type, attached object.
        if rng.gen_bool(0.0005) {
            cfg.command_type = match rng.gen_range(0..4) {
                0 => CommandType::None,
                1 => CommandType::VirtMech,
                _ => CommandType::Impedance,
            };
            cfg.attached_object = Some(VirtualObjectParams {
                mass: Fx::from_f64(rng.gen_range(0.0001..5.0)),
                inertia: Vec3::ZERO,
            });
            cfg.time_step = Fx::from_f64(t * rng.gen_range(0.5..4.0));
        }
        // Link drops, session close/open, degraded episodes.
        if drop_left == 0 && closed_left == 0 && rng.gen_bool(0.002) {
            drop_left = rng.gen_range(1..=300);
            drop_busy = rng.gen_bool(0.5);
        }
        if closed_left == 0 && drop_left == 0 && rng.gen_bool(0.0003) {
            closed_left = rng.gen_range(1..500);
            c.synchro.reset();
            shared.valid = false;
        }
        if degraded_left == 0 && rng.gen_bool(0.003) {
            degraded_left = rng.gen_range(1..200);
        }
        mode = if degraded_left > 0 {
            degraded_left -= 1;
            if rng.gen_bool(0.2) {
                Mode::Main
            } else {
                Mode::Degraded
            }
        } else {
            Mode::Main
        };
        let now = c.servo.cycle();
        let mut busy = false;
        if closed_left > 0 {
            closed_left -= 1;
        } else if drop_left > 0 {
            drop_left -= 1;
            busy = drop_busy;
        } else {
            seq = seq.wrapping_add(1);
            shared = VpReceived {
                pose,
                twist,
                seq,
                client_time_us: 0,
                received_cycle: now,
                valid: true,
                link_energy: false,
                heard_cycle: now,
            };
        }
        if let Some(k) = cut_at {
            if n == k {
                line.fail_safe_inhibit();
                line.power_off();
                cut = true;
                figs.cuts += 1;
            }
        }

        // ---- One cycle.
        let inputs = ServoInputs {
            power_request: power,
            live_effort: Some(user),
        };
        let r = c.run(
            &line,
            &inputs,
            &cfg,
            if busy { None } else { Some(&shared) },
            mode,
        );
        last_answer = r.vp.coupling_wrench;
        figs.cycles += 1;

        // ---- Checks at the motors.
        let out = *c.servo.control_output();
        let log = *c.servo.log_record();
        let applied = line.applied();
        assert_eq!(
            log.motor_torque, applied,
            "seed {seed} cycle {n}: logged ≠ applied"
        );
        if cut {
            if applied != JOINTS_ZERO || log.motor_torque != JOINTS_ZERO {
                figs.cut_nonzero += 1;
            }
            assert_eq!(
                applied, JOINTS_ZERO,
                "seed {seed} cycle {n}: torque after cut"
            );
            assert!(log.flags & log_flags::LINE_CUT != 0);
        }
        for i in 0..6 {
            let ratio = f(applied[i]).abs() / f(arm::TAU_MAX[i]);
            figs.worst_torque_ratio = figs.worst_torque_ratio.max(ratio);
            assert!(ratio <= 1.0, "seed {seed} cycle {n}: joint {i} torque");
        }
        let enabled = line.motors_enabled();
        // The applied torque is the fixed part plus Jᵀ of the coupling
        // wrench the controller reports: the checks on that wrench are
        // checks at the motors.
        // The controller's kinematics: at the encoder angles.
        let kin_m = arm::kinematics(&log.q);
        let jt = arm::jacobian_transpose_mul(&kin_m.jacobian(), &out.handle_wrench);
        let env = f(out.envelope);
        let hw_force = norm(v3(out.handle_wrench.force));
        if enabled {
            for i in 0..6 {
                let want = (f(out.fixed_torques[i]) + f(jt[i]))
                    .clamp(-f(arm::TAU_MAX[i]), f(arm::TAU_MAX[i]));
                let mis = (f(applied[i]) - want).abs();
                figs.worst_motor_mismatch = figs.worst_motor_mismatch.max(mis);
                assert!(
                    mis < 1e-5,
                    "seed {seed} cycle {n}: joint {i} applied {} vs {want}",
                    f(applied[i])
                );
            }
        }
        // Force bound: |F| ≤ envelope·F_max ≤ link gain·F_max.
        let gain = f(r.link_gain);
        let excess = hw_force - env * f(MAX_FORCE);
        figs.worst_force_excess = figs.worst_force_excess.max(excess);
        assert!(
            excess < 1e-6,
            "seed {seed} cycle {n}: force {hw_force} > env {env}"
        );
        if r.vp.status & hap_core::vp::status::COUPLED != 0 {
            assert!(
                env <= gain + 1e-9,
                "seed {seed} cycle {n}: envelope {env} above link gain {gain}"
            );
        }
        // Envelope slew.
        let step = env - prev_env;
        if step > 0.0 {
            figs.worst_env_step = figs.worst_env_step.max(step);
            assert!(
                step <= ramp_step + 1e-9,
                "seed {seed} cycle {n}: envelope step {step}"
            );
        }
        // Link loss: from age > fade start, the motor force stays under the fade.
        let age_us = now.saturating_sub(c.synchro.last().received_cycle) * period_us as u64;
        let losing = c.synchro.last().valid && age_us > LINK_FADE_START_US;
        if losing && !in_loss {
            figs.link_loss_events += 1;
            loss_unfaded = false;
        }
        if losing && hw_force > gain * f(MAX_FORCE) + 1e-6 && !loss_unfaded {
            loss_unfaded = true;
            figs.link_loss_unfaded += 1;
        }
        if losing && gain == 0.0 {
            // From age 100 ms on, exactly no coupling force at the motors.
            assert_eq!(hw_force, 0.0, "seed {seed} cycle {n}: force at gain 0");
        }
        if in_loss && !losing {
            figs.resumes += 1;
            resume_k = Some(0);
        }
        in_loss = losing;
        if let Some(k) = resume_k {
            let allowed = f(MAX_FORCE) * ((k as f64 + 1.0) * ramp_step + prev_env).min(1.0);
            figs.worst_resume_excess = figs.worst_resume_excess.max(hw_force - allowed);
            assert!(
                hw_force <= allowed + 1e-6,
                "seed {seed} cycle {n}: resume force {hw_force} > {allowed}"
            );
            resume_k = if k > 100 { None } else { Some(k + 1) };
        }
        // Mode switches change no gain: no energy.
        let g_now = c.servo.controller().effective_gains();
        if mode != prev_mode {
            figs.mode_switches += 1;
            let d = v3(c.servo.controller().target().position);
            let dd = norm([d[0] - hp[0], d[1] - hp[1], d[2] - hp[2]]);
            figs.mode_switch_energy +=
                (0.5 * (f(g_now.k_lin) - f(prev_gains.k_lin)) * dd * dd).max(0.0);
        }
        prev_gains = g_now;
        prev_mode = mode;
        if out.torque_scale < Fx::ONE && c.servo.controller().coupled() {
            figs.clamp_cycles += 1;
        }
        // Speed.
        let qd = log.qd;
        let tw = arm::jacobian_mul(&kin.jacobian(), &qd);
        let _ = tw;
        let new_kin = arm::kinematics(&c.servo.simulator().q);
        let v = norm(v3(arm::jacobian_mul(
            &new_kin.jacobian(),
            &c.servo.simulator().qd,
        )
        .linear));
        if enabled {
            figs.max_speed = figs.max_speed.max(v);
        }
        for i in 0..6 {
            let ratio = f(c.servo.simulator().qd[i]).abs() / wbound[i];
            if !enabled {
                // Unpowered, nothing brakes: the bound applies from the
                // first time the powered joint is back under it.
                entered_fast[i] = true;
            } else if ratio <= 1.0 {
                entered_fast[i] = false;
            }
            if enabled && !entered_fast[i] {
                figs.worst_joint_speed_ratio = figs.worst_joint_speed_ratio.max(ratio);
                assert!(
                    ratio <= 1.0,
                    "seed {seed} cycle {n}: joint {i} speed ratio {ratio}"
                );
            }
        }
        // Energy: motor-side ledger of the coupling (exact work of the
        // applied coupling torque over the period, target-port work, the
        // arm's proven viscous dissipation).
        let coupled = c.servo.controller().coupled();
        if coupled {
            figs.coupled_cycles += 1;
            if out.alarms & hap_core::vp::alarm::PASSIVITY != 0 {
                figs.passivity_cycles += 1;
            }
            let tgt = c.servo.controller().target();
            match (ledger, prev_q, prev_target) {
                (Some(l), Some(pq), Some(pt)) => {
                    let qn = log.q;
                    let mut work = 0.0;
                    let mut credit = 0.0;
                    for i in 0..6 {
                        let dq = f(qn[i]) - f(pq[i]);
                        // What the motors applied minus the fixed part = coupling.
                        let tc = prev_applied[i] - prev_fixed_tau[i];
                        work += tc * dq;
                        credit += f(arm::DAMPING[i]) * dq * dq / t;
                    }
                    if prev_elbow_pushed {
                        // The elbow soft stop's share of the elbow's
                        // dissipation (its sampled spring's largest gain).
                        let dq = f(qn[2]) - f(pq[2]);
                        credit -= 0.5 * f(c.servo.controller().elbow_gain()) * dq * dq;
                    }
                    // The client's step as the spring sees it: the change
                    // of its error (bounded to D_CLAMP per component; the
                    // rotation's error vector) at the handle pose now.
                    let hn = arm::kinematics(&qn).handle;
                    let clamp_d =
                        |p: Vec3| v3(p.sub(hn.position)).map(|x| x.clamp(-f(D_CLAMP), f(D_CLAMP)));
                    let (dn, d0) = (clamp_d(tgt.position), clamp_d(pt.position));
                    let dpt: [f64; 3] = std::array::from_fn(|k| dn[k] - d0[k]);
                    let en = v3(tgt.orientation.error_vector(&hn.orientation));
                    let e0 = v3(pt.orientation.error_vector(&hn.orientation));
                    let dth: [f64; 3] = std::array::from_fn(|k| en[k] - e0[k]);
                    // Target port: trapezoid of the wrench before and after
                    // the client's (sampled) step.
                    // (After the step: the spring's force before the motor
                    // scaling, which then slips the spring, a dissipation.)
                    let pf = v3(prev_hw.force.add(out.spring_wrench.force));
                    let pt_ = v3(prev_hw.torque.add(out.spring_wrench.torque));
                    let pf = pf.map(|x| x / 2.0);
                    let pt_ = pt_.map(|x| x / 2.0);
                    let port: f64 = (0..3).map(|k| pf[k] * dpt[k] + pt_[k] * dth[k]).sum();
                    let l2 = l + port - work + credit;
                    if std::env::var_os("HAP_CAMPAIGN_DEBUG").is_some() && l2 - l < -1e-3 {
                        println!(
                            "n {n} client {client:?} mode {mode:?} dL {:.4} port {port:.4} work {work:.4} credit {credit:.4} env {env:.3} scale {:.3} slip {:?} obs {:.4} gain {gain:.3} drop {drop_left} closed {closed_left} pwr {power:?} alarms {:#x}",
                            l2 - l, f(out.torque_scale), c.servo.controller().slip().0.to_f64(), f(out.po_energy), out.alarms
                        );
                    }
                    let l = l2;
                    ledger = Some(l);
                    figs.worst_ledger = figs.worst_ledger.min(l);
                }
                _ => {
                    ledger = Some(f(out.po_energy));
                }
            }
            figs.worst_observer = figs.worst_observer.min(f(out.po_energy));
            prev_target = Some(tgt);
        } else {
            ledger = None;
            prev_target = None;
        }
        // The elbow soft stop at the motors: the work of the torque it added
        // (as held over the period) on the elbow, against the share of the
        // elbow's dissipation it is given (`½K_e Δq₃²` after a push). A
        // spring that only takes energy from the arm keeps this ≥ 0.
        if let Some(pq) = prev_q {
            let dq = f(log.q[2]) - f(pq[2]);
            if prev_elbow_pushed {
                elbow_ledger += 0.5 * f(c.servo.controller().elbow_gain()) * dq * dq;
            }
            elbow_ledger -= prev_elbow_tau * dq;
            figs.worst_elbow_ledger = figs.worst_elbow_ledger.min(elbow_ledger);
        }
        prev_elbow_tau = if enabled {
            f(c.servo.controller().elbow_torque())
        } else {
            0.0
        };
        prev_q = Some(log.q);
        prev_hw = out.handle_wrench;
        prev_elbow_pushed = c.servo.controller().elbow_pushed();
        if prev_elbow_pushed {
            figs.elbow_stop_cycles += 1;
        }
        for i in 0..6 {
            prev_applied[i] = f(applied[i]);
            prev_fixed_tau[i] = if enabled {
                f(out.fixed_torques[i])
            } else {
                0.0
            };
        }
        if !enabled {
            prev_hw = Wrench::ZERO;
        }
        prev_env = env;
    }
    // Per run: the coupling generated no energy beyond rounding, at the
    // motors (ledger) and in the observer the passivity controller uses.
    assert!(
        figs.worst_ledger > -1e-6,
        "seed {seed} at {period_us} µs: coupling energy {:.3e} J",
        figs.worst_ledger
    );
    assert!(
        figs.worst_observer > -1e-6,
        "seed {seed} at {period_us} µs: observer {:.3e} J",
        figs.worst_observer
    );
    assert!(
        figs.worst_elbow_ledger > -1e-6,
        "seed {seed} at {period_us} µs: elbow soft stop energy {:.3e} J",
        figs.worst_elbow_ledger
    );
    figs
}
