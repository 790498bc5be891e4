//! ns per full servo step (measures → state → control → commands → simulate
//! → VP + log record encode). Run: `cargo bench -p hap-core --bench servo_step`.

use hap_core::arm;
use hap_core::config::{CommandType, ServoConfig};
use hap_core::effort::EffortSample;
use hap_core::fixed::{Fx, Pose, Quat, Vec3, Wrench, JOINTS_ZERO};
use hap_core::mode::Mode;
use hap_core::position_log::LogRecord;
use hap_core::servo::{PowerRequest, ServoInputs, StandaloneServo};
use hap_core::vp::VpReceived;
use std::hint::black_box;
use std::time::Instant;

fn main() {
    let mut s = StandaloneServo::new(1_000_000);
    s.init();
    s.simulator_mut().set_state(&arm::WORK_Q, &JOINTS_ZERO);
    let cfg = ServoConfig {
        command_type: CommandType::Impedance,
        ..Default::default()
    };
    let held = Some(EffortSample {
        wrench: Wrench {
            force: Vec3::new(Fx::ONE, Fx::ZERO, Fx::ZERO),
            torque: Vec3::ZERO,
        },
        dead_man: true,
        buttons: 0,
    });
    let on = ServoInputs {
        power_request: PowerRequest::On,
        live_effort: held,
    };
    let run = ServoInputs {
        power_request: PowerRequest::None,
        live_effort: held,
    };
    let mut vpr = VpReceived {
        valid: true,
        ..Default::default()
    };
    s.step(&on, &cfg, &vpr, Mode::Main);
    let base = s.vp().handle_pose.position;
    let mut buf = [0u8; LogRecord::SIZE];
    for (label, mode) in [("main", Mode::Main), ("degraded", Mode::Degraded)] {
        let n = 200_000u32;
        let mut best = f64::MAX;
        for _round in 0..5 {
            let t0 = Instant::now();
            for i in 0..n {
                let t = Fx::from_ratio((i % 6283) as i64, 1000);
                vpr.pose = Pose {
                    position: base.add(Vec3::new(
                        Fx::from_ratio(2, 100).mul_sat(t.sin()),
                        Fx::ZERO,
                        Fx::ZERO,
                    )),
                    orientation: Quat::IDENTITY,
                };
                vpr.seq = i;
                black_box(s.step(black_box(&run), &cfg, &vpr, mode));
                s.log_record().encode(&mut buf);
                black_box(&buf);
            }
            let ns = t0.elapsed().as_nanos() as f64 / n as f64;
            best = best.min(ns);
        }
        println!("servo step ({label}): {best:.0} ns/step (best of 5 x 200000 steps, incl. LogRecord encode)");
    }
}
