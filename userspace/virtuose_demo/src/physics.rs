//! A tiny physics engine for the test client: two spheres in a box.
//!
//! - Sphere A is the virtual object coupled to the arm: no gravity (the
//!   coupling carries it); forces = coupling wrench from the controller +
//!   contact with sphere B + walls/floor.
//! - Sphere B is free: gravity, floor and wall contacts with restitution
//!   and rolling friction, contact with A.
//!
//! Contacts are penalty springs with damping (N/m, N·s/m); integration is
//! semi-implicit Euler at the client's time step. Units: m, kg, s, N. The
//! world frame is z up.

use nalgebra::Vector3;

pub type V3 = Vector3<f64>;

#[derive(Clone, Copy, Debug)]
pub struct Sphere {
    pub pos: V3,
    pub vel: V3,
    pub mass: f64,
    pub radius: f64,
}

/// Box the spheres live in: floor at `floor_z`, walls at ±`half_width` in x and y.
#[derive(Clone, Copy, Debug)]
pub struct World {
    pub a: Sphere,
    pub b: Sphere,
    pub floor_z: f64,
    pub half_width: f64,
    pub gravity: f64,
    pub contact_k: f64,
    pub contact_c: f64,
    /// Viscous drag on the coupled sphere A, N·s/m. The coupling reaches the
    /// client late (network + answer period); a spring K delayed by T stays
    /// passive only with damping b > K·T/2: with the controller's K_t at
    /// 1 ms (203 N/m) this drag tolerates T < 2b/K ≈ 98 ms (the client
    /// paces its stream so that queues cannot build such a delay). It also
    /// sets the sphere's lag behind a handle moving at v: b·v/K (0.05 s × v).
    pub drag_a: f64,
    /// Last contact force applied on A by B (N), for display.
    pub contact_on_a: V3,
    /// Last force of the box's walls and floor on A (N).
    pub wall_on_a: V3,
}

impl Default for World {
    fn default() -> Self {
        World {
            a: Sphere {
                pos: V3::zeros(),
                vel: V3::zeros(),
                mass: 0.5,
                radius: 0.03,
            },
            b: Sphere {
                pos: V3::new(0.09, 0.0, -0.06),
                vel: V3::zeros(),
                mass: 0.3,
                radius: 0.04,
            },
            floor_z: -0.10,
            half_width: 0.20,
            gravity: 9.81,
            contact_k: 2000.0,
            contact_c: 10.0,
            drag_a: 10.0,
            contact_on_a: V3::zeros(),
            wall_on_a: V3::zeros(),
        }
    }
}

/// Penalty force pushing a sphere out of the box walls and floor.
fn box_force(s: &Sphere, floor_z: f64, hw: f64, k: f64, c: f64) -> V3 {
    let mut f = V3::zeros();
    let pen = floor_z + s.radius - s.pos.z;
    if pen > 0.0 {
        f.z += k * pen - c * s.vel.z.min(0.0);
        // rolling/sliding friction on the floor
        f.x -= 0.5 * s.vel.x;
        f.y -= 0.5 * s.vel.y;
    }
    for i in 0..2 {
        let lo = -hw + s.radius - s.pos[i];
        if lo > 0.0 {
            f[i] += k * lo - c * s.vel[i].min(0.0);
        }
        let hi = s.pos[i] + s.radius - hw;
        if hi > 0.0 {
            f[i] -= k * hi + c * s.vel[i].max(0.0);
        }
    }
    f
}

impl World {
    /// Contact force on A from B (B gets the opposite).
    fn sphere_contact(&self) -> V3 {
        let d = self.a.pos - self.b.pos;
        let dist = d.norm();
        let pen = self.a.radius + self.b.radius - dist;
        if pen <= 0.0 || dist < 1e-9 {
            return V3::zeros();
        }
        let n = d / dist;
        let vrel = (self.a.vel - self.b.vel).dot(&n);
        let mag = (self.contact_k * pen - self.contact_c * vrel).max(0.0);
        n * mag
    }

    /// Advance by `dt` with `coupling` (N) applied to A. Returns the
    /// contact force on A.
    pub fn step(&mut self, dt: f64, coupling: V3) -> V3 {
        let fc = self.sphere_contact();
        let fw = box_force(
            &self.a,
            self.floor_z,
            self.half_width,
            self.contact_k,
            self.contact_c,
        );
        let fa = coupling - self.a.vel * self.drag_a + fc + fw;
        let fb = -fc
            + V3::new(0.0, 0.0, -self.gravity * self.b.mass)
            + box_force(
                &self.b,
                self.floor_z,
                self.half_width,
                self.contact_k,
                self.contact_c,
            );
        for (s, f) in [(&mut self.a, fa), (&mut self.b, fb)] {
            s.vel += f / s.mass * dt;
            // Sanitise: never let a NaN or a blow-up escape to the controller.
            if !s.vel.iter().all(|v| v.is_finite()) {
                s.vel = V3::zeros();
            }
            s.vel = s.vel.map(|v| v.clamp(-10.0, 10.0));
            s.pos += s.vel * dt;
            if !s.pos.iter().all(|v| v.is_finite()) {
                s.pos = V3::zeros();
            }
        }
        self.contact_on_a = fc;
        self.wall_on_a = fw;
        fc
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn free_sphere_falls_and_rests_on_the_floor() {
        let mut w = World::default();
        for _ in 0..3000 {
            w.step(0.001, V3::zeros());
        }
        let rest = w.floor_z + w.b.radius;
        assert!((w.b.pos.z - rest).abs() < 0.005, "{}", w.b.pos.z);
        assert!(w.b.vel.norm() < 0.05);
    }

    #[test]
    fn coupled_sphere_pushes_the_free_one() {
        let mut w = World::default();
        let x0 = w.b.pos.x;
        // drag A towards +x with a spring to a moving target
        for i in 0..3000 {
            let target = V3::new(0.15 * (i as f64 / 3000.0), 0.0, -0.06);
            let f = (target - w.a.pos) * 300.0 - w.a.vel * 20.0;
            w.step(0.001, f);
        }
        assert!(w.b.pos.x > x0 + 0.01, "B did not move: {}", w.b.pos.x);
    }
}
