//! Checks joint states received over DDS against the pose received with the
//! same stamp: the arm's forward kinematics (`hap_core::arm::kinematics`, the
//! controller's own model) of each sample's joint angles must give its pose.
//!
//!   joint_check SAMPLES_FILE
//!
//! SAMPLES_FILE: one line per sample, "stamp x y z qx qy qz qw fx fy fz q1 .. q6"
//! (tests/ros2/peer.py --samples). Prints the number of samples and the
//! largest position (m) and orientation (quaternion distance) differences as
//! `key: value` lines; exits 2 on a malformed file.

use hap_core::arm;
use hap_core::fixed::Fx;

fn main() {
    let Some(path) = std::env::args().nth(1) else {
        eprintln!("usage: joint_check SAMPLES_FILE");
        std::process::exit(2)
    };
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| {
        eprintln!("joint_check: {path}: {e}");
        std::process::exit(2)
    });
    let (mut n, mut max_pos, mut max_rot) = (0u64, 0f64, 0f64);
    for (i, line) in text.lines().enumerate() {
        let v: Vec<f64> = match line
            .split_whitespace()
            .skip(1)
            .map(str::parse::<f64>)
            .collect::<Result<Vec<f64>, _>>()
        {
            Ok(v) if v.len() == 16 && v.iter().all(|x| x.is_finite()) => v,
            _ => {
                eprintln!(
                    "joint_check: {path}:{}: expected a stamp and 16 numbers",
                    i + 1
                );
                std::process::exit(2)
            }
        };
        let mut q = [Fx::ZERO; 6];
        for (d, s) in q.iter_mut().zip(&v[10..16]) {
            *d = Fx::from_f64(*s);
        }
        let k = arm::kinematics(&q);
        let p = k.handle.position.to_f64();
        let o = k.handle.orientation.to_f64();
        let dp = (0..3).map(|j| (p[j] - v[j]).powi(2)).sum::<f64>().sqrt();
        // q and -q are the same rotation.
        let dq = |s: f64| {
            (0..4)
                .map(|j| (s * o[j] - v[3 + j]).powi(2))
                .sum::<f64>()
                .sqrt()
        };
        max_pos = max_pos.max(dp);
        max_rot = max_rot.max(dq(1.0).min(dq(-1.0)));
        n += 1;
    }
    println!("joint_samples: {n}");
    println!("max_position_error_m: {max_pos:.3e}");
    println!("max_orientation_error: {max_rot:.3e}");
}
