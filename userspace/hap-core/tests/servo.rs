//! The servo step: power gating, degraded mode, fail-safe hooks, determinism,
//! log records.
#![allow(clippy::needless_range_loop)]

use hap_core::arm;
use hap_core::config::{CommandType, ServoConfig};
use hap_core::effort::EffortSample;
use hap_core::fixed::{Fx, Pose, Quat, Vec3, Wrench, JOINTS_ZERO};
use hap_core::io::MotorLine;
use hap_core::mode::Mode;
use hap_core::position_log::{LogDecodeError, LogRecord};
use hap_core::servo::{PowerRequest, Servo, ServoInputs, StandaloneServo};
use hap_core::simulator::Simulator;
use hap_core::vp::{alarm, status, VpReceived};

const PERIOD_NS: u32 = 1_000_000;

const SCRIPT: &[u8] = b"# push around, release the dead-man at the end\n\
0    0  0  0   0 0 0    1\n\
400  4  1 -2   0 0.05 0 1\n\
900 -3  2  1   0.02 0 0 1 1\n\
1400 0  0  0   0 0 0    1\n\
1800 0  0  0   0 0 0    0\n";

fn impedance_cfg() -> ServoConfig {
    ServoConfig {
        command_type: CommandType::Impedance,
        ..Default::default()
    }
}

fn far_vpr() -> VpReceived {
    VpReceived {
        pose: Pose {
            position: Vec3::from_f64([0.5, 0.3, 0.2]),
            orientation: Quat::IDENTITY,
        },
        valid: true,
        ..Default::default()
    }
}

#[test]
fn servo_is_small_and_const_constructible() {
    static _S: Servo = Servo::new(PERIOD_NS);
    let size = core::mem::size_of::<Servo>();
    println!("size_of::<Servo>() = {size} bytes");
    assert!(size < 8 * 1024, "{size}");
}

#[test]
fn power_off_the_arm_moves_only_under_gravity_and_the_user() {
    // Servo never powered, commanded hard toward a far object...
    let mut s = StandaloneServo::new(PERIOD_NS);
    s.init();
    s.load_effort_text(SCRIPT).unwrap();
    // ...and a bare unpowered simulator under the same effort.
    let mut bare = Simulator::new(PERIOD_NS);
    bare.calibrate();
    let mut player = hap_core::effort::EffortPlayer::new();
    player.load_text(SCRIPT).unwrap();
    let cfg = impedance_cfg();
    let vpr = far_vpr();
    for n in 0..2000u64 {
        let vp = *s.step(&ServoInputs::default(), &cfg, &vpr, Mode::Main);
        assert_eq!(
            vp.status & (status::POWER_ON | status::MOTORS_ENABLED | status::COUPLED),
            0
        );
        assert_eq!(s.log_record().motor_torque, JOINTS_ZERO);
        let e = player.sample(n * 1000);
        bare.set_user_effort(&e);
        bare.simulate_arm(&MotorLine::new());
        assert_eq!(s.simulator().q, bare.q, "cycle {n}");
    }
    // The user moved it.
    let moved = s
        .simulator()
        .q
        .iter()
        .zip(arm::REST_Q.iter())
        .any(|(a, b)| (a.to_f64() - b.to_f64()).abs() > 0.01);
    assert!(moved);

    // Left alone, the unpowered arm stays at rest (shoulder on its stop).
    let mut s = StandaloneServo::new(PERIOD_NS);
    for _ in 0..2000 {
        s.step(&ServoInputs::default(), &cfg, &vpr, Mode::Main);
    }
    for (a, b) in s.simulator().q.iter().zip(arm::REST_Q.iter()) {
        assert!(
            (a.to_f64() - b.to_f64()).abs() < 0.02,
            "{:?}",
            s.simulator().q
        );
    }
}

#[test]
fn power_on_enables_commands_and_power_off_inhibits_them() {
    let mut s = StandaloneServo::new(PERIOD_NS);
    let cfg = ServoConfig::default();
    let vpr = VpReceived::default();
    let vp = *s.step(&ServoInputs::default(), &cfg, &vpr, Mode::Main);
    assert_eq!(vp.status & status::MOTORS_ENABLED, 0);
    let vp = *s.step(
        &ServoInputs {
            power_request: PowerRequest::On,
            live_effort: None,
        },
        &cfg,
        &vpr,
        Mode::Main,
    );
    assert_ne!(vp.status & status::POWER_ON, 0);
    assert_ne!(vp.status & status::MOTORS_ENABLED, 0);
    // Gravity compensation is being commanded.
    assert!(s.log_record().motor_torque[1].abs() > Fx::ONE);
    let vp = *s.step(
        &ServoInputs {
            power_request: PowerRequest::Off,
            live_effort: None,
        },
        &cfg,
        &vpr,
        Mode::Main,
    );
    assert_eq!(vp.status & (status::POWER_ON | status::MOTORS_ENABLED), 0);
    assert_eq!(s.log_record().motor_torque, JOINTS_ZERO);
    assert_eq!(s.line.applied(), JOINTS_ZERO);
}

#[test]
fn fail_safe_inhibits_for_good() {
    let mut s = StandaloneServo::new(PERIOD_NS);
    let cfg = impedance_cfg();
    let vpr = far_vpr();
    s.step(
        &ServoInputs {
            power_request: PowerRequest::On,
            live_effort: None,
        },
        &cfg,
        &vpr,
        Mode::Main,
    );
    assert_ne!(s.line.applied(), JOINTS_ZERO);
    s.line.fail_safe_inhibit();
    assert_eq!(s.line.applied(), JOINTS_ZERO);
    s.line.power_off();
    assert!(!s.line.supply_on());
    let vp = *s.step(
        &ServoInputs {
            power_request: PowerRequest::On,
            live_effort: None,
        },
        &cfg,
        &vpr,
        Mode::Main,
    );
    assert_eq!(vp.status & (status::POWER_ON | status::MOTORS_ENABLED), 0);
    assert_ne!(vp.alarms & alarm::FAIL_SAFE, 0);
    // A module reload (new line, servo init) clears it.
    s.line.reset();
    s.init();
    let vp = *s.step(
        &ServoInputs {
            power_request: PowerRequest::On,
            live_effort: None,
        },
        &cfg,
        &vpr,
        Mode::Main,
    );
    assert_ne!(vp.status & status::MOTORS_ENABLED, 0);
}

#[test]
fn degraded_mode_couples_with_the_same_gains_and_is_flagged() {
    let mut s = StandaloneServo::new(PERIOD_NS);
    s.init();
    s.simulator_mut().set_state(&arm::WORK_Q, &JOINTS_ZERO);
    let cfg = impedance_cfg();
    let vpr = far_vpr();
    let held = Some(EffortSample {
        wrench: Wrench::ZERO,
        dead_man: true,
        buttons: 0,
    });
    let on = ServoInputs {
        power_request: PowerRequest::On,
        live_effort: held,
    };
    let vp = *s.step(&on, &cfg, &vpr, Mode::Main);
    assert_ne!(vp.status & status::COUPLED, 0);
    let mut inputs = on;
    inputs.power_request = PowerRequest::None;
    // The degraded path keeps force feedback with the same gains (they are
    // scheduled for an effective period of 2T): the same spring deflection
    // gives the same force, so switching path injects no energy.
    // (a target 3 mm from the handle: below the 20 N saturation)
    let mut near = vpr;
    near.pose = vp.handle_pose;
    near.pose.position.x = near.pose.position.x.add_sat(Fx::from_ratio(3, 1000));
    let mut main = s.clone();
    let vp_main = *main.step(&inputs, &cfg, &near, Mode::Main);
    let vp_deg = *s.step(&inputs, &cfg, &near, Mode::Degraded);
    assert_ne!(vp_deg.status & status::DEGRADED, 0);
    assert_ne!(vp_deg.status & status::COUPLED, 0);
    let f = |w: Wrench| {
        Vec3::to_f64(w.force)
            .iter()
            .map(|x| x * x)
            .sum::<f64>()
            .sqrt()
    };
    let (fm, fd) = (f(vp_main.coupling_wrench), f(vp_deg.coupling_wrench));
    assert!(fm > 0.1, "main path couples ({fm} N)");
    assert_eq!(vp_main.coupling_wrench, vp_deg.coupling_wrench);
    assert!(fd > 0.1);
    for _ in 0..500 {
        let vp = *s.step(&inputs, &cfg, &vpr, Mode::Degraded);
        assert_ne!(vp.status & status::DEGRADED, 0);
        assert_ne!(vp.status & status::COUPLED, 0);
    }
}

fn scripted_run() -> Vec<[u8; LogRecord::SIZE]> {
    let mut s = StandaloneServo::new(PERIOD_NS);
    s.init();
    s.load_effort_text(SCRIPT).unwrap();
    let cfg = impedance_cfg();
    let mut out = Vec::new();
    for n in 0..3000u32 {
        let t = Fx::from_ratio(n as i64, 1000);
        let vpr = VpReceived {
            pose: Pose {
                position: Vec3::new(
                    Fx::from_ratio(33, 100),
                    Fx::from_ratio(5, 100).mul_sat(t.sin()),
                    Fx::from_ratio(-50, 100),
                ),
                orientation: Quat::IDENTITY,
            },
            valid: n > 200,
            seq: n,
            ..Default::default()
        };
        let power = if n == 100 {
            PowerRequest::On
        } else {
            PowerRequest::None
        };
        let mode = if n % 500 == 499 {
            Mode::Degraded
        } else {
            Mode::Main
        };
        s.step(
            &ServoInputs {
                power_request: power,
                live_effort: None,
            },
            &cfg,
            &vpr,
            mode,
        );
        let mut b = [0u8; LogRecord::SIZE];
        s.log_record().encode(&mut b);
        out.push(b);
    }
    out
}

#[test]
fn two_runs_of_the_same_script_give_identical_log_records() {
    let a = scripted_run();
    let b = scripted_run();
    assert_eq!(a.len(), b.len());
    assert!(a == b);
    // And the run did something.
    let first = LogRecord::decode(&a[0]).unwrap();
    let last = LogRecord::decode(a.last().unwrap()).unwrap();
    assert_ne!(first.q, last.q);
    assert_eq!(last.cycle, 2999);
}

#[test]
fn log_record_round_trip_and_errors() {
    let mut s = StandaloneServo::new(PERIOD_NS);
    s.load_effort_text(SCRIPT).unwrap();
    for _ in 0..500 {
        s.step(
            &ServoInputs {
                power_request: PowerRequest::On,
                live_effort: None,
            },
            &impedance_cfg(),
            &far_vpr(),
            Mode::Main,
        );
    }
    let r = *s.log_record();
    let mut b = [0u8; LogRecord::SIZE];
    r.encode(&mut b);
    assert_eq!(&b[0..4], b"HAPL");
    assert_eq!(LogRecord::decode(&b), Ok(r));
    let mut bad = b;
    bad[0] = b'X';
    assert_eq!(LogRecord::decode(&bad), Err(LogDecodeError::BadMagic));
    let mut bad = b;
    bad[4] = 9;
    assert_eq!(LogRecord::decode(&bad), Err(LogDecodeError::BadVersion));
}

/// Every field at its documented offset (simulator.md), each distinct, and
/// back; a bad mode byte is refused.
#[test]
fn log_record_v2_layout_matches_its_documentation() {
    use hap_core::position_log::LogTiming;
    let f = |k: i64| Fx(k.wrapping_mul(0x0101_0101_0101) ^ 0x5a);
    let v3 = |k: i64| Vec3::new(f(k), f(k + 1), f(k + 2));
    let j6 = |k: i64| [f(k), f(k + 1), f(k + 2), f(k + 3), f(k + 4), f(k + 5)];
    let r = LogRecord {
        flags: 0x7f,
        cycle: 0x0102_0304_0506_0708,
        time_us: 0x1112_1314_1516_1718,
        mode: Mode::FailSafe,
        fail_safe_step: 4,
        vpr_age_cycles: 0x2122_2324,
        q: j6(10),
        qd: j6(20),
        handle_position: v3(30),
        handle_orientation: [f(40), f(41), f(42), f(43)],
        handle_velocity: v3(50),
        handle_angular_velocity: v3(60),
        torque_command: j6(70),
        motor_torque: j6(80),
        coupling_force: v3(90),
        coupling_torque: v3(100),
        user_wrench: j6(110),
        vpr_position: v3(120),
        vpr_orientation: [f(130), f(131), f(132), f(133)],
        handle_position_client: v3(140),
        status: 0x3132_3334,
        alarms: 0x4142_4344,
        po_energy: f(150),
        link_gain: f(151),
        timing: LogTiming {
            tick: 0x5152_5354_5556_5758,
            start_ns: 0x6162_6364_6566_6768,
            wakeup_ns: 0x7172_7374,
            exec_ns: 0x8182_8384,
            session: 0x9192,
        },
    };
    let mut b = [0u8; LogRecord::SIZE];
    r.encode(&mut b);
    let u64_at = |o: usize| u64::from_le_bytes(b[o..o + 8].try_into().unwrap());
    let u32_at = |o: usize| u32::from_le_bytes(b[o..o + 4].try_into().unwrap());
    let fx_at = |o: usize| Fx(u64_at(o) as i64);
    assert_eq!(&b[0..4], b"HAPL");
    assert_eq!(u16::from_le_bytes([b[4], b[5]]), 2);
    assert_eq!(u16::from_le_bytes([b[6], b[7]]), 0x7f);
    assert_eq!(u64_at(8), r.cycle);
    assert_eq!(u64_at(16), r.time_us);
    assert_eq!((b[24], b[25], b[26], b[27]), (2, 4, 0, 0));
    assert_eq!(u32_at(28), r.vpr_age_cycles);
    assert_eq!(fx_at(32), r.q[0]);
    assert_eq!(fx_at(80), r.qd[0]);
    assert_eq!(fx_at(128), r.handle_position.x);
    assert_eq!(fx_at(152), r.handle_orientation[0]);
    assert_eq!(fx_at(184), r.handle_velocity.x);
    assert_eq!(fx_at(208), r.handle_angular_velocity.x);
    assert_eq!(fx_at(232), r.torque_command[0]);
    assert_eq!(fx_at(280), r.motor_torque[0]);
    assert_eq!(fx_at(328), r.coupling_force.x);
    assert_eq!(fx_at(352), r.coupling_torque.x);
    assert_eq!(fx_at(376), r.user_wrench[0]);
    assert_eq!(fx_at(424), r.vpr_position.x);
    assert_eq!(fx_at(448), r.vpr_orientation[0]);
    assert_eq!(fx_at(480), r.handle_position_client.x);
    assert_eq!(u32_at(504), r.status);
    assert_eq!(u32_at(508), r.alarms);
    assert_eq!(fx_at(512), r.po_energy);
    assert_eq!(fx_at(520), r.link_gain);
    assert_eq!(LogRecord::TIMING, 528..560);
    assert_eq!(u64_at(528), r.timing.tick);
    assert_eq!(u64_at(536), r.timing.start_ns);
    assert_eq!(u32_at(544), r.timing.wakeup_ns);
    assert_eq!(u32_at(548), r.timing.exec_ns);
    assert_eq!(u16::from_le_bytes([b[552], b[553]]), 0x9192);
    assert_eq!(&b[554..560], &[0u8; 6]);
    assert_eq!(LogRecord::decode(&b), Ok(r));
    let mut bad = b;
    bad[24] = 3;
    assert_eq!(LogRecord::decode(&bad), Err(LogDecodeError::BadMode));
}

/// The log carries what the motors produced (the simulator's torques,
/// within the motor limits), the VPr in use, the servo time and the mode.
#[test]
fn log_record_carries_command_applied_vpr_and_mode() {
    let mut s = StandaloneServo::new(PERIOD_NS);
    s.load_effort_text(SCRIPT).unwrap();
    let vpr = far_vpr();
    for n in 0..400 {
        let mode = if n == 399 { Mode::Degraded } else { Mode::Main };
        s.step(
            &ServoInputs {
                power_request: if n == 0 {
                    PowerRequest::On
                } else {
                    PowerRequest::None
                },
                live_effort: None,
            },
            &impedance_cfg(),
            &vpr,
            mode,
        );
    }
    let r = *s.log_record();
    assert_eq!(r.mode, hap_core::mode::Mode::Degraded);
    assert_eq!(r.cycle, 399);
    assert_eq!(r.time_us, 399 * u64::from(PERIOD_NS / 1000));
    assert_eq!(r.vpr_position, vpr.pose.position);
    assert_eq!(r.motor_torque, s.simulator().applied_torques());
    for (a, l) in r.motor_torque.iter().zip(hap_core::arm::TAU_MAX.iter()) {
        assert!(a.abs() <= *l);
    }
    assert!(r.coupling_force.norm() > Fx::ZERO);
}

/// A step asked in `Mode::FailSafe` (the supervisor never starts one) runs
/// the degraded path: the same record, answer and state as a degraded step.
#[test]
fn a_step_in_fail_safe_runs_the_degraded_path() {
    let run = |last: Mode| {
        let mut s = StandaloneServo::new(PERIOD_NS);
        s.load_effort_text(SCRIPT).unwrap();
        let vpr = far_vpr();
        for n in 0..300 {
            let mode = if n >= 290 { last } else { Mode::Main };
            let power_request = if n == 0 {
                PowerRequest::On
            } else {
                PowerRequest::None
            };
            let inputs = ServoInputs {
                power_request,
                live_effort: None,
            };
            s.step(&inputs, &impedance_cfg(), &vpr, mode);
        }
        (*s.log_record(), *s.vp(), format!("{:?}", *s))
    };
    let (degraded, fail_safe) = (run(Mode::Degraded), run(Mode::FailSafe));
    assert_eq!(fail_safe.0.mode, Mode::Degraded);
    assert_eq!(fail_safe.0, degraded.0);
    assert_eq!(fail_safe.1, degraded.1);
    assert_eq!(fail_safe.2, degraded.2);
    assert_ne!(run(Mode::Main).0, degraded.0, "the paths differ");
}
