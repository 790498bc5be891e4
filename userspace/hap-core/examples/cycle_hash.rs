//! Fingerprint of the servo cycle's output, to check that a change to the
//! arithmetic leaves the cycle bit for bit the same.
//!
//! `cycle_hash PERIOD_US TARGET_SCALE FORCE_SCALE CYCLES` runs CYCLES full
//! SERVO cycles (`hap_core::cycle::ServoCycle`, the script of the
//! `servo_steps` example: a scripted user force and a VPr coupled to the
//! arm's own VP) at PERIOD_US, with the VPr's offset from the handle scaled
//! by TARGET_SCALE (0: no target motion) and the user force by FORCE_SCALE
//! (0: no force), and prints one 64-bit FNV-1a hash of every answer frame,
//! every log record and, every 100 cycles, the whole servo state (its
//! `Debug` text). Run it before and after a change: equal hashes for every
//! script mean the same output (up to hash collisions).

use hap_core::config::{CommandType, ServoConfig};
use hap_core::cycle::ServoCycle;
use hap_core::effort::EffortSample;
use hap_core::fixed::{Fx, Pose, Quat, Vec3, Wrench};
use hap_core::io::MotorLine;
use hap_core::mode::Mode;
use hap_core::position_log::LogRecord;
use hap_core::protocol::MAX_FRAME_LEN;
use hap_core::servo::{PowerRequest, ServoInputs};

struct Fnv(u64);

impl Fnv {
    fn feed(&mut self, bytes: &[u8]) {
        for b in bytes {
            self.0 ^= u64::from(*b);
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let arg = |i: usize, d: i64| -> i64 { args.get(i).and_then(|a| a.parse().ok()).unwrap_or(d) };
    let period_us = arg(1, 1000) as u32;
    let target_scale = arg(2, 1) as i32;
    let force_scale = arg(3, 1) as i32;
    let cycles = arg(4, 30_000) as u32;

    let mut cycle = ServoCycle::new(period_us);
    cycle.servo.init();
    let line = MotorLine::new();
    let cfg = ServoConfig {
        command_type: CommandType::Impedance,
        ..Default::default()
    };
    let mut vpr = hap_core::vp::VpReceived {
        valid: true,
        ..Default::default()
    };
    let mut frames = [[0u8; MAX_FRAME_LEN]; 2];
    let mut lens = [0usize; 2];
    let mut log = [0u8; LogRecord::SIZE];
    let mut seq = 0u32;
    let mut h = Fnv(0xcbf2_9ce4_8422_2325);
    for i in 0..cycles {
        let t = Fx::from_ratio(i64::from(i % 6283), 1000);
        let (sin, cos) = t.sin_cos();
        let fs = Fx::from_int(force_scale);
        let effort = EffortSample {
            wrench: Wrench {
                force: Vec3::new(sin, cos, Fx::from_ratio(1, 2)).scale(fs),
                torque: Vec3::ZERO,
            },
            dead_man: true,
            buttons: 0,
        };
        let inputs = ServoInputs {
            power_request: if i == 0 {
                PowerRequest::On
            } else {
                PowerRequest::None
            },
            live_effort: Some(effort),
        };
        let here = cycle.servo.vp().handle_pose.position;
        let ts = Fx::from_int(target_scale);
        vpr.pose = Pose {
            position: here.add(
                Vec3::new(
                    Fx::from_ratio(1, 100).mul_sat(sin),
                    Fx::from_ratio(1, 200).mul_sat(cos),
                    Fx::ZERO,
                )
                .scale(ts),
            ),
            orientation: Quat::IDENTITY,
        };
        vpr.seq = i;
        vpr.received_cycle = cycle.servo.cycle();
        let r = cycle.run(&line, &inputs, &cfg, Some(&vpr), Mode::Main);
        let n = ServoCycle::encode_answers(
            &r.vp,
            1,
            i,
            || {
                seq = seq.wrapping_add(1);
                seq
            },
            &mut frames,
            &mut lens,
        );
        for (f, l) in frames.iter().zip(lens.iter()).take(n) {
            h.feed(f.get(..*l).unwrap_or(&[]));
        }
        cycle.servo.log_record().encode(&mut log);
        h.feed(&log);
        if i % 100 == 99 {
            h.feed(format!("{:?}", cycle.servo).as_bytes());
        }
    }
    h.feed(format!("{:?}", cycle.servo).as_bytes());
    println!(
        "period {period_us} us, target x{target_scale}, force x{force_scale}, {cycles} cycles: {:016x}",
        h.0
    );
}
