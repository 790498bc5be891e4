//! Fixed-point arm vs the f64 nalgebra reference of the same model, and the
//! gravity behaviour of the free arm.
//!
//! Stated bounds (asserted): over 10 s of scripted effort with gravity
//! compensation, |q_fx − q_f64| ≤ 1e-5 rad per joint and the handle position
//! differs by ≤ 1e-5 m; the kinematics (FK, Jacobian, gravity, inertia) agree
//! within 1e-7 over random configurations.
#![allow(clippy::needless_range_loop)]

mod reference;

use hap_core::arm;
use hap_core::config::ServoConfig;
use hap_core::effort::EffortSample;
use hap_core::fixed::{Fx, Vec3, Wrench, JOINTS_ZERO};
use hap_core::io::MotorLine;
use hap_core::mode::Mode;
use hap_core::servo::{PowerRequest, ServoInputs, StandaloneServo};
use hap_core::simulator::Simulator;
use hap_core::vp::VpReceived;
use nalgebra::Vector3;
use rand::{Rng, SeedableRng};

/// Scripted user effort at time t (s): slow pushes in every direction.
fn scripted(t: f64) -> ([f64; 3], [f64; 3]) {
    (
        [
            3.0 * (0.7 * t).sin(),
            2.0 * (1.1 * t + 0.3).sin(),
            1.5 * (0.5 * t).cos() - 0.5,
        ],
        [
            0.05 * (0.9 * t).sin(),
            0.04 * (1.3 * t).cos(),
            0.03 * (0.6 * t).sin(),
        ],
    )
}

#[test]
fn kinematics_match_reference() {
    let mut rng = rand::rngs::StdRng::seed_from_u64(7);
    let mut worst = [0.0f64; 4];
    for _ in 0..2000 {
        let mut q = [0.0; 6];
        for (i, v) in q.iter_mut().enumerate() {
            *v = rng.gen_range(arm::Q_MIN[i].to_f64()..arm::Q_MAX[i].to_f64());
        }
        let kf = arm::kinematics(&q.map(Fx::from_f64));
        let kr = reference::kinematics(&q);
        let hp = kf.handle.position.to_f64();
        let e = (Vector3::from(hp) - kr.handle).abs().max();
        worst[0] = worst[0].max(e);
        for i in 0..6 {
            let l = Vector3::from(kf.jacobian()[i].linear.to_f64()) - kr.jac[i].0;
            let a = Vector3::from(kf.jacobian()[i].angular.to_f64()) - kr.jac[i].1;
            worst[1] = worst[1].max(l.abs().max()).max(a.abs().max());
            worst[2] = worst[2].max((kf.gravity[i].to_f64() - kr.gravity[i]).abs());
            worst[3] = worst[3].max((kf.inertia[i].to_f64() - kr.inertia[i]).abs());
        }
        // Quaternion ↔ matrix consistency.
        let m = kf.handle.orientation.to_mat3();
        for r in 0..3 {
            let row = m.r[r].to_f64();
            for c in 0..3 {
                assert!((row[c] - kr.rot[(r, c)]).abs() < 1e-7);
            }
        }
    }
    println!("kinematics max |err|: handle {:.2e} m, jacobian {:.2e}, gravity {:.2e} N·m, inertia {:.2e} kg·m²", worst[0], worst[1], worst[2], worst[3]);
    assert!(worst.iter().all(|&w| w < 1e-7), "{worst:?}");
}

/// The products the cycle takes from a kinematics evaluation (its own Q2.30
/// entries, no clamp) are exactly the general `mul_unit` products of the
/// `Fx` Jacobian and rotation, over the whole joint range and beyond it,
/// for factors of every scale (clamped ones included).
#[test]
fn kinematics_products_equal_the_general_ones() {
    let mut rng = rand::rngs::StdRng::seed_from_u64(11);
    let factor = |rng: &mut rand::rngs::StdRng| {
        let scale = rng.gen_range(-40..30);
        let raw: i64 = rng.gen_range(-(1i64 << 40)..(1i64 << 40));
        Fx(if scale >= 0 {
            raw.saturating_mul(1 << scale.min(62))
        } else {
            raw >> (-scale).min(63)
        })
    };
    for n in 0..20_000 {
        let mut q = [Fx::ZERO; 6];
        for (i, v) in q.iter_mut().enumerate() {
            // Inside the limits, and up to 10 rad outside them.
            let (lo, hi) = if n % 4 == 0 {
                (-10.0, 10.0)
            } else {
                (arm::Q_MIN[i].to_f64(), arm::Q_MAX[i].to_f64())
            };
            *v = Fx::from_f64(rng.gen_range(lo..hi));
        }
        let parts = if n % 2 == 0 {
            arm::Parts::SIMULATOR
        } else {
            arm::Parts::STATE_MODEL
        };
        let k = arm::kinematics_with(&q, parts);
        let w = Wrench {
            force: Vec3::new(factor(&mut rng), factor(&mut rng), factor(&mut rng)),
            torque: Vec3::new(factor(&mut rng), factor(&mut rng), factor(&mut rng)),
        };
        let qd = [(); 6].map(|_| factor(&mut rng));
        let (j, r) = (k.jacobian(), k.handle_rot());
        assert_eq!(
            k.jacobian_transpose_mul(&w),
            arm::jacobian_transpose_mul(&j, &w)
        );
        assert_eq!(k.jacobian_mul(&qd), arm::jacobian_mul(&j, &qd));
        assert_eq!(k.rot_mul(w.force), r.mul_vec_unit(w.force));
        assert_eq!(k.rot_tmul(w.torque), r.tmul_vec_unit(w.torque));
        for c in j
            .iter()
            .flat_map(|t| t.to_array())
            .chain(r.r.iter().flat_map(|v| v.to_array()))
        {
            assert!(c.abs() < Fx::TWO, "entry {c:?} at {q:?}");
        }
    }
}

#[test]
fn ten_seconds_of_scripted_effort_match_reference() {
    scripted_effort_matches_reference(1_000_000, 10_000);
}

/// The same at the module's shortest period (one sub-step a period) and at
/// 10 ms (20 sub-steps), 2 s each.
#[test]
fn scripted_effort_matches_reference_at_100us_and_10ms() {
    scripted_effort_matches_reference(100_000, 20_000);
    scripted_effort_matches_reference(10_000_000, 200);
}

#[test]
fn substeps_are_at_most_half_a_millisecond() {
    use hap_core::simulator::{substeps, MAX_SUBSTEPS, MAX_SUBSTEP_NS};
    assert_eq!(substeps(0), 1);
    assert_eq!(substeps(100_000), 1);
    assert_eq!(substeps(500_000), 1);
    assert_eq!(substeps(500_001), 2);
    assert_eq!(substeps(1_000_000), 2);
    assert_eq!(substeps(10_000_000), 20);
    assert_eq!(substeps(u32::MAX), MAX_SUBSTEPS);
    for p in (50_000u32..=32_000_000).step_by(12_345) {
        let n = substeps(p);
        assert!(p.div_ceil(n) <= MAX_SUBSTEP_NS, "{p} ns in {n} sub-steps");
        assert!(
            n == 1 || p.div_ceil(n - 1) > MAX_SUBSTEP_NS,
            "{p} ns: {n} is not the fewest"
        );
    }
}

fn scripted_effort_matches_reference(period_ns: u32, steps: u32) {
    let period = f64::from(period_ns) * 1e-9;
    let mut sim = Simulator::new(period_ns);
    let line = MotorLine::new();
    assert!(line.power_on());
    sim.set_state(&arm::WORK_Q, &JOINTS_ZERO);
    let mut rf = reference::RefSim {
        q: arm::WORK_Q.map(|v| v.to_f64()),
        qd: [0.0; 6],
        period,
    };
    let mut worst_q = 0.0f64;
    let mut worst_p = 0.0f64;
    let mut travel = 0.0f64;
    let start = reference::kinematics(&rf.q).handle;
    for n in 0..steps {
        let t = f64::from(n) * period;
        let (f, tq) = scripted(t);
        // Fixed side: gravity compensation computed in fixed point.
        let kin = arm::kinematics(&sim.q);
        let comp = kin.gravity.map(|g| -g);
        line.write_command(&comp);
        let w = Wrench {
            force: Vec3::from_f64(f),
            torque: Vec3::from_f64(tq),
        };
        sim.set_user_effort(&EffortSample {
            wrench: w,
            dead_man: true,
            buttons: 0,
        });
        sim.simulate_arm(&line);
        // Reference side.
        let kr = reference::kinematics(&rf.q);
        let comp_r = kr.gravity.map(|g| -g);
        rf.step(&comp_r, &Vector3::from(f), &Vector3::from(tq));
        for i in 0..6 {
            worst_q = worst_q.max((sim.q[i].to_f64() - rf.q[i]).abs());
        }
        let hf = Vector3::from(arm::kinematics(&sim.q).handle.position.to_f64());
        let hr = reference::kinematics(&rf.q).handle;
        worst_p = worst_p.max((hf - hr).norm());
        travel = travel.max((hr - start).norm());
    }
    println!("{} s scripted effort at {period_ns} ns: max |q_fx - q_f64| = {worst_q:.3e} rad, handle {worst_p:.3e} m (handle travelled up to {travel:.3} m)", f64::from(steps) * period);
    assert!(travel > 0.05, "the script should move the arm");
    assert!(worst_q <= 1e-5, "{worst_q}");
    assert!(worst_p <= 1e-5, "{worst_p}");
}

fn run_free(gravity_compensation: bool) -> (f64, f64) {
    let mut s = StandaloneServo::new(1_000_000);
    s.init();
    s.controller_mut().gravity_compensation = gravity_compensation;
    s.simulator_mut().set_state(&arm::WORK_Q, &JOINTS_ZERO);
    let cfg = ServoConfig::default();
    let vpr = VpReceived::default();
    let start = arm::kinematics(&arm::WORK_Q).handle.position;
    let on = ServoInputs {
        power_request: PowerRequest::On,
        live_effort: None,
    };
    s.step(&on, &cfg, &vpr, Mode::Main);
    for _ in 0..1000 {
        s.step(&ServoInputs::default(), &cfg, &vpr, Mode::Main);
    }
    let q = s.simulator().q;
    let dq = q
        .iter()
        .zip(arm::WORK_Q.iter())
        .map(|(a, b)| (a.to_f64() - b.to_f64()).abs())
        .fold(0.0, f64::max);
    let h = arm::kinematics(&q).handle.position;
    (dq, (h.z.to_f64() - start.z.to_f64()))
}

#[test]
fn free_arm_falls_without_compensation_and_holds_with_it() {
    let (dq_free, dz_free) = run_free(false);
    let (dq_comp, dz_comp) = run_free(true);
    println!("1 s without compensation: max |dq| {dq_free:.3} rad, handle dz {dz_free:.3} m; with: {dq_comp:.2e} rad, {dz_comp:.2e} m");
    assert!(
        dz_free < -0.1,
        "the uncompensated arm must fall: dz = {dz_free}"
    );
    assert!(dq_comp < 1e-4, "the compensated arm must hold: {dq_comp}");
    assert!(dz_comp.abs() < 1e-4);
}
