//! Control: coupling convergence, a stiff virtual wall at the passivity
//! bound, and saturation over 10^6 randomized cycles.
#![allow(clippy::needless_range_loop)]

use hap_core::arm;
use hap_core::config::{CommandType, IndexingMode, ServoConfig, VirtualObjectParams};
use hap_core::control::{Gains, MAX_FORCE, MAX_TORQUE};
use hap_core::effort::EffortSample;
use hap_core::fixed::{Fx, Pose, Quat, Twist, Vec3, Wrench, JOINTS_ZERO};
use hap_core::mode::Mode;
use hap_core::servo::{PowerRequest, ServoInputs, StandaloneServo};
use hap_core::vp::{alarm, status, VpReceived};
use rand::{Rng, SeedableRng};

const PERIOD_NS: u32 = 1_000_000;

fn held(force: [f64; 3]) -> Option<EffortSample> {
    Some(EffortSample {
        wrench: Wrench {
            force: Vec3::from_f64(force),
            torque: Vec3::ZERO,
        },
        dead_man: true,
        buttons: 0,
    })
}

fn powered_servo_at_work() -> StandaloneServo {
    let mut s = StandaloneServo::new(PERIOD_NS);
    s.init();
    s.simulator_mut().set_state(&arm::WORK_Q, &JOINTS_ZERO);
    let cfg = ServoConfig::default();
    s.step(
        &ServoInputs {
            power_request: PowerRequest::On,
            live_effort: held([0.0; 3]),
        },
        &cfg,
        &VpReceived::default(),
        Mode::Main,
    );
    s
}

#[test]
fn coupling_to_a_static_object_converges() {
    let mut s = powered_servo_at_work();
    let cfg = ServoConfig {
        command_type: CommandType::Impedance,
        ..Default::default()
    };
    let start = s.vp().handle_pose;
    let target = Pose {
        position: start.position.add(Vec3::from_f64([-0.05, 0.02, -0.03])),
        orientation: Quat::from_axis_angle(Vec3::Z, Fx::from_f64(0.1)).mul(&start.orientation),
    };
    let vpr = VpReceived {
        pose: target,
        valid: true,
        seq: 1,
        ..Default::default()
    };
    let inputs = ServoInputs {
        power_request: PowerRequest::None,
        live_effort: held([0.0; 3]),
    };
    let mut first_force = 0.0;
    for n in 0..3000 {
        let vp = s.step(&inputs, &cfg, &vpr, Mode::Main);
        assert!(vp.status & status::COUPLED != 0);
        if n == 0 {
            // Soft start: the first cycle carries at most one ramp step.
            let f0 = vp.coupling_wrench.force.norm().to_f64();
            assert!(f0 <= MAX_FORCE.to_f64() * 0.02 + 1e-6, "{f0}");
        }
        if n == 50 {
            first_force = Vec3::to_f64(vp.coupling_wrench.force)
                .iter()
                .map(|f| f * f)
                .sum::<f64>()
                .sqrt();
        }
    }
    let h = s.vp().handle_pose;
    let d = h.position.sub(target.position).norm().to_f64();
    let e = target
        .orientation
        .error_vector(&h.orientation)
        .norm()
        .to_f64();
    let f = s.vp().coupling_wrench.force.norm().to_f64();
    println!("coupling: force after the 50 ms ramp {first_force:.2} N, after 3 s: distance {d:.2e} m, angle {e:.2e} rad, force {f:.2e} N");
    assert!(first_force > 5.0, "{first_force}");
    assert!(d < 1e-3, "{d}");
    // K_r = 1.6 N·m/rad at 1 ms (1/16 of the joint-space budget goes to
    // the rotational spring): slower in rotation.
    assert!(e < 5e-2, "{e}");
    assert!(f < 1.0);
}

/// A client-side virtual wall (god-object proxy): the object follows the
/// handle but cannot go beyond `x_wall` along +x.
fn wall_run(gains: Gains, push: f64, seconds: usize) -> (Vec<f64>, f64, u32, StandaloneServo) {
    let mut s = powered_servo_at_work();
    s.controller_mut().gains = gains;
    let cfg = ServoConfig {
        command_type: CommandType::Impedance,
        ..Default::default()
    };
    let x_wall = s.vp().handle_pose.position.x.to_f64() + 0.01;
    let mut xs = Vec::new();
    let mut min_energy = f64::MAX;
    let mut alarms = 0;
    for n in 0..seconds * 1000 {
        let prev = *s.vp();
        let mut pose = prev.handle_pose;
        let mut twist = prev.handle_twist;
        if pose.position.x.to_f64() > x_wall {
            pose.position.x = Fx::from_f64(x_wall);
            twist = Twist::ZERO;
        }
        let vpr = VpReceived {
            pose,
            twist,
            valid: true,
            seq: n as u32,
            ..Default::default()
        };
        let f = if n < 3000 { push } else { push * 2.0 };
        let inputs = ServoInputs {
            power_request: PowerRequest::None,
            live_effort: held([f, 0.0, 0.0]),
        };
        s.step(&inputs, &cfg, &vpr, Mode::Main);
        xs.push(s.vp().handle_pose.position.x.to_f64() - x_wall);
        let e = s.controller().po_energy().to_f64();
        if s.controller().coupled() {
            min_energy = min_energy.min(e);
        }
        alarms |= s.vp().alarms;
    }
    (xs, min_energy, alarms, s)
}

fn amplitude(x: &[f64]) -> f64 {
    let (lo, hi) = x
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
    hi - lo
}

#[test]
fn stiff_wall_at_the_bound_is_stable_and_passive() {
    let period = Fx::from_ns(PERIOD_NS as u64);
    let g = Gains::at_bound(period);
    let nominal = Gains::for_period(period);
    let (xs, min_energy, alarms, s) = wall_run(g, 2.0, 6);
    let pen1 = xs[2500];
    let pen2 = *xs.last().unwrap();
    let early = amplitude(&xs[3200..3700]);
    let late = amplitude(&xs[5500..6000]);
    let k = g.k_lin.to_f64();
    // No force was refused: the spring did not slip (beyond rounding).
    assert!(s.controller().slip().0.norm().to_f64() < 1e-6);
    println!(
        "wall K = {k:.0} N/m (nominal {:.0}): penetration {:.2} mm @2 N, {:.2} mm @4 N (expected {:.2}/{:.2}); \
         oscillation p-p after step {:.3e} m, last 0.5 s {:.3e} m; min PO energy {:.3e} J; alarms {alarms:#x}",
        nominal.k_lin.to_f64(), pen1 * 1e3, pen2 * 1e3, 2.0 / k * 1e3, 4.0 / k * 1e3, early, late, min_energy
    );
    // The stiffest gains offered at 1 ms (joint-space bound at 2T, margin 0.95).
    assert!(k > 240.0 && k > nominal.k_lin.to_f64());
    // Steady penetration close to F/K (the proxy lags one cycle).
    // (2 N and 4 N keep the soft wall's penetration inside the reach; 10 N
    // would push the arm to full extension, where x is singular.)
    // The soft wall (ζ ≈ 0.1) still rings slightly when sampled.
    assert!((pen1 - 2.0 / k).abs() < 0.15 * 2.0 / k, "{pen1}");
    assert!((pen2 - 4.0 / k).abs() < 0.15 * 4.0 / k, "{pen2}");
    // No growing oscillation; it dies out.
    assert!(late <= early + 1e-9, "{late} vs {early}");
    assert!(late < 0.1 * early, "{late} vs {early}");
    // The passivity observer's energy never goes negative, i.e. the
    // coupling never generated energy.
    assert!(min_energy >= -1e-6, "{min_energy}");
    // ...and the passivity controller never had to act.
    assert_eq!(alarms & alarm::PASSIVITY, 0, "{alarms:#x}");
}

#[test]
fn saturation_never_exceeded_over_1e6_randomized_cycles() {
    let mut rng = rand::rngs::StdRng::seed_from_u64(42);
    let mut s = StandaloneServo::new(PERIOD_NS);
    s.init();
    let mut cfg = ServoConfig {
        command_type: CommandType::Impedance,
        ..Default::default()
    };
    let mut vpr = VpReceived {
        valid: true,
        ..Default::default()
    };
    let mut inputs = ServoInputs {
        power_request: PowerRequest::On,
        live_effort: held([0.0; 3]),
    };
    let mut mode = Mode::Main;
    let mut sat_seen = 0u64;
    let mut coupled = 0u64;
    let tau_max = arm::TAU_MAX;
    for n in 0..1_000_000u64 {
        if n % 97 == 0 {
            let r = |rng: &mut rand::rngs::StdRng, a: f64| rng.gen_range(-a..a);
            vpr.pose.position =
                Vec3::from_f64([r(&mut rng, 1.0), r(&mut rng, 1.0), r(&mut rng, 1.0)]);
            vpr.pose.orientation = Quat::from_axis_angle(
                Vec3::from_f64([r(&mut rng, 1.0), r(&mut rng, 1.0), r(&mut rng, 1.0)]),
                Fx::from_f64(r(&mut rng, 3.0)),
            );
            vpr.twist.linear =
                Vec3::from_f64([r(&mut rng, 5.0), r(&mut rng, 5.0), r(&mut rng, 5.0)]);
            vpr.twist.angular =
                Vec3::from_f64([r(&mut rng, 20.0), r(&mut rng, 20.0), r(&mut rng, 20.0)]);
            let ff = Fx::from_f64(rng.gen_range(0.1..10.0));
            cfg.force_factor = ff;
            cfg.speed_factor = Fx::from_f64(rng.gen_range(0.1..10.0));
            cfg.command_type = [
                CommandType::None,
                CommandType::Impedance,
                CommandType::VirtMech,
            ][rng.gen_range(0..3)];
            cfg.indexing_mode = IndexingMode::from_u32(rng.gen_range(0..5)).unwrap();
            cfg.attached_object = if rng.gen_bool(0.5) {
                Some(VirtualObjectParams {
                    mass: Fx::from_f64(rng.gen_range(0.01..5.0)),
                    inertia: Vec3::ZERO,
                })
            } else {
                None
            };
            cfg.base_frame.orientation =
                Quat::from_axis_angle(Vec3::Z, Fx::from_f64(r(&mut rng, 3.0)));
            inputs.live_effort = Some(EffortSample {
                wrench: Wrench {
                    force: Vec3::from_f64([
                        r(&mut rng, 40.0),
                        r(&mut rng, 40.0),
                        r(&mut rng, 40.0),
                    ]),
                    torque: Vec3::from_f64([r(&mut rng, 1.0), r(&mut rng, 1.0), r(&mut rng, 1.0)]),
                },
                dead_man: rng.gen_bool(0.9),
                buttons: rng.gen_range(0..4),
            });
            mode = if rng.gen_bool(0.1) {
                Mode::Degraded
            } else {
                Mode::Main
            };
            inputs.power_request = match rng.gen_range(0..20) {
                0 => PowerRequest::Off,
                1..=3 => PowerRequest::On,
                _ => PowerRequest::None,
            };
        } else {
            inputs.power_request = PowerRequest::None;
        }
        let vp = *s.step(&inputs, &cfg, &vpr, mode);
        let applied = s.log_record().motor_torque;
        for (t, l) in applied.iter().zip(tau_max.iter()) {
            assert!(t.abs() <= *l, "cycle {n}: torque {t:?} > {l:?}");
        }
        let st = s.line.applied();
        for (t, l) in st.iter().zip(tau_max.iter()) {
            assert!(t.abs() <= *l);
        }
        let f = s.log_record().coupling_force.norm();
        assert!(f <= MAX_FORCE + Fx(16), "cycle {n}: coupling force {f:?}");
        if vp.status & status::COUPLED != 0 {
            coupled += 1;
        }
        if vp.alarms & alarm::TORQUE_SATURATED != 0 {
            sat_seen += 1;
        }
        if n % 50_000 == 0 {
            // Keep the arm inside its workspace most of the time.
            s.simulator_mut().set_state(&arm::WORK_Q, &JOINTS_ZERO);
        }
    }
    println!("1e6 randomized cycles: {coupled} coupled, {sat_seen} with the saturation alarm latched; limits held (|F| ≤ {} N, |T| ≤ {} N·m at the handle)", MAX_FORCE.to_f64(), MAX_TORQUE.to_f64());
    assert!(coupled > 10_000);
}
