//! f64 nalgebra reference of the simulated arm model (same equations,
//! same discretisation as `arm.rs` / `simulator.rs`), for host tests.
#![allow(dead_code, clippy::needless_range_loop)]

use hap_core::arm;
use nalgebra::{Matrix3, Rotation3, Vector3};

pub fn p(v: hap_core::fixed::Fx) -> f64 {
    v.to_f64()
}

pub struct RefKin {
    pub handle: Vector3<f64>,
    pub rot: Matrix3<f64>,
    /// columns: (linear, angular)
    pub jac: [(Vector3<f64>, Vector3<f64>); 6],
    pub gravity: [f64; 6],
    pub inertia: [f64; 6],
}

fn ry(a: f64) -> Matrix3<f64> {
    *Rotation3::from_axis_angle(&Vector3::y_axis(), a).matrix()
}
fn rx(a: f64) -> Matrix3<f64> {
    *Rotation3::from_axis_angle(&Vector3::x_axis(), a).matrix()
}
fn rz(a: f64) -> Matrix3<f64> {
    *Rotation3::from_axis_angle(&Vector3::z_axis(), a).matrix()
}

pub fn kinematics(q: &[f64; 6]) -> RefKin {
    let (h0, l1, l2, l3) = (p(arm::H0), p(arm::L1), p(arm::L2), p(arm::L3));
    let r1 = rz(q[0]);
    let r12 = r1 * ry(q[1]);
    let r123 = r12 * ry(q[2]);
    let r1234 = r123 * rx(q[3]);
    let r5 = r1234 * ry(q[4]);
    let r6 = r5 * rx(q[5]);
    let ps = Vector3::new(0.0, 0.0, h0);
    let x12: Vector3<f64> = r12.column(0).into();
    let x123: Vector3<f64> = r123.column(0).into();
    let x5: Vector3<f64> = r5.column(0).into();
    let pe = ps + x12 * l1;
    let pw = pe + x123 * l2;
    let ph = pw + x5 * l3;
    let z: [Vector3<f64>; 6] = [
        Vector3::z(),
        r1.column(1).into(),
        r1.column(1).into(),
        x123,
        r1234.column(1).into(),
        r6.column(0).into(),
    ];
    let pts = [Vector3::zeros(), ps, pe, pw, pw, pw];
    let mut jac = [(Vector3::zeros(), Vector3::zeros()); 6];
    for i in 0..6 {
        jac[i] = (z[i].cross(&(ph - pts[i])), z[i]);
    }
    let com = [
        ps + x12 * (l1 / 2.0),
        pe + x123 * (l2 / 2.0),
        pw + x5 * (l3 / 2.0),
    ];
    let last = [1usize, 2, 5];
    let g = p(arm::GRAVITY);
    let mut gravity = [0.0; 6];
    let mut inertia = arm::ROTOR_INERTIA.map(p);
    for i in 0..6 {
        for k in 0..3 {
            if i <= last[k] {
                let m = p(arm::MASS[k]);
                let f = Vector3::new(0.0, 0.0, -m * g);
                let r = com[k] - pts[i];
                gravity[i] += z[i].dot(&r.cross(&f));
                let a = r.dot(&z[i]);
                inertia[i] += m * (r.norm_squared() - a * a).max(0.0);
            }
        }
    }
    RefKin {
        handle: ph,
        rot: r6,
        jac,
        gravity,
        inertia,
    }
}

pub fn jt_mul(k: &RefKin, f: &Vector3<f64>, t: &Vector3<f64>) -> [f64; 6] {
    let mut tau = [0.0; 6];
    for i in 0..6 {
        tau[i] = k.jac[i].0.dot(f) + k.jac[i].1.dot(t);
    }
    tau
}

/// The simulator's integration of one period, in f64.
pub struct RefSim {
    pub q: [f64; 6],
    pub qd: [f64; 6],
    pub period: f64,
}

impl RefSim {
    pub fn step(&mut self, motor: &[f64; 6], force: &Vector3<f64>, torque: &Vector3<f64>) {
        let k = kinematics(&self.q);
        let ut = jt_mul(&k, force, torque);
        let sub = hap_core::simulator::substeps((self.period * 1e9).round() as u32) as usize;
        let dt = self.period / sub as f64;
        let tau_max = arm::TAU_MAX.map(p);
        let mut base = [0.0; 6];
        for i in 0..6 {
            base[i] = motor[i].clamp(-tau_max[i], tau_max[i]) + ut[i] + k.gravity[i];
        }
        let (qmin, qmax) = (arm::Q_MIN.map(p), arm::Q_MAX.map(p));
        for _ in 0..sub {
            for i in 0..6 {
                let (q, qd) = (self.q[i], self.qd[i]);
                let mut tau = base[i]
                    - p(arm::DAMPING[i]) * qd
                    - p(arm::COULOMB[i]) * (qd * 100.0).clamp(-1.0, 1.0);
                if q > qmax[i] {
                    let t =
                        p(arm::STOP_STIFFNESS[i]) * (q - qmax[i]) + p(arm::STOP_DAMPING[i]) * qd;
                    tau -= t.max(0.0);
                } else if q < qmin[i] {
                    let t =
                        p(arm::STOP_STIFFNESS[i]) * (q - qmin[i]) + p(arm::STOP_DAMPING[i]) * qd;
                    tau -= t.min(0.0);
                }
                let qd = qd + tau * dt / k.inertia[i];
                self.qd[i] = qd;
                self.q[i] = q + qd * dt;
            }
        }
    }
}
