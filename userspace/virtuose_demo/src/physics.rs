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
//!
//! [`Bimanual`] is the two-arm scene: two coupled hands, one per arm, and
//! one free object under gravity that they can squeeze and lift between
//! them (hand–object contacts carry Coulomb friction).

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
    /// 1 ms (1138 N/m) this drag tolerates T < 2b/K ≈ 18 ms, less than the
    /// 100 ms horizon after which the demo stops applying an old force (the
    /// controller's own link-fade horizon): over a slower link a plain
    /// client's sphere can gain energy, which `--link-passivity` prevents
    /// (the library then returns only the force the link's energy pays
    /// for). It also sets the sphere's lag behind a handle moving at v:
    /// b·v/K (8.8 ms × v).
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

/// Sub-steps of one [`Bimanual::step`] (see [`Bimanual::grip_c`]).
pub const BIMANUAL_SUBSTEPS: u32 = 10;

/// The two-arm scene: two hands (spheres coupled to the arms, no gravity,
/// viscous drag like sphere A) and one object (a sphere under gravity, in
/// the same box). A hand's contact with the object pushes along the line of
/// centres and grips across it: tangential friction, viscous up to the
/// Coulomb limit `friction` × normal force, so two hands squeezing from
/// both sides can lift the object.
#[derive(Clone, Copy, Debug)]
pub struct Bimanual {
    pub hands: [Sphere; 2],
    pub object: Sphere,
    pub floor_z: f64,
    pub half_width: f64,
    pub gravity: f64,
    pub contact_k: f64,
    pub contact_c: f64,
    /// Coulomb friction coefficient of a hand on the object.
    pub friction: f64,
    /// The grip's tangential damping below the Coulomb limit, N·s/m: the
    /// object slips at force / `grip_c` (1 mm/s under 1 N). Both hands'
    /// together stay below 2 m / dt for the explicit step: `step`
    /// integrates in [`BIMANUAL_SUBSTEPS`] sub-steps (2 000 N·s/m on the
    /// 0.2 kg object at 100 µs: 1 of the limit's 2).
    pub grip_c: f64,
    /// Viscous drag on each hand, N·s/m (see `World::drag_a`).
    pub drag_hand: f64,
    /// Last contact force of each hand on the object (N).
    pub on_object: [V3; 2],
}

impl Bimanual {
    /// Hands at `hands_at`, the object resting on the floor midway between
    /// them.
    pub fn new(hands_at: [V3; 2]) -> Self {
        let w = World::default();
        let hand = |pos| Sphere {
            pos,
            vel: V3::zeros(),
            mass: 0.5,
            radius: 0.03,
        };
        let radius = 0.04;
        let mid = (hands_at[0] + hands_at[1]) / 2.0;
        Bimanual {
            hands: [hand(hands_at[0]), hand(hands_at[1])],
            object: Sphere {
                pos: V3::new(mid.x, mid.y, w.floor_z + radius),
                vel: V3::zeros(),
                mass: 0.2,
                radius,
            },
            floor_z: w.floor_z,
            half_width: w.half_width,
            gravity: w.gravity,
            contact_k: w.contact_k,
            contact_c: w.contact_c,
            friction: 1.0,
            grip_c: 1000.0,
            drag_hand: w.drag_a,
            on_object: [V3::zeros(); 2],
        }
    }

    /// Force of `hand` on the object: normal spring-damper plus friction.
    fn grip(&self, hand: &Sphere) -> V3 {
        let d = self.object.pos - hand.pos;
        let dist = d.norm();
        let pen = hand.radius + self.object.radius - dist;
        if pen <= 0.0 || dist < 1e-9 {
            return V3::zeros();
        }
        let n = d / dist;
        let vrel = self.object.vel - hand.vel;
        let normal = (self.contact_k * pen - self.contact_c * vrel.dot(&n)).max(0.0);
        let vt = vrel - n * vrel.dot(&n);
        let vt_norm = vt.norm();
        let tangential = if vt_norm > 1e-9 {
            // Viscous grip (a stiff damper), capped at the Coulomb limit.
            let mag = (self.grip_c * vt_norm).min(self.friction * normal);
            -vt / vt_norm * mag
        } else {
            V3::zeros()
        };
        n * normal + tangential
    }

    /// Advance by `dt` with each arm's coupling force (N) on its hand
    /// (held over the period's sub-steps).
    pub fn step(&mut self, dt: f64, coupling: [V3; 2]) {
        let h = dt / BIMANUAL_SUBSTEPS as f64;
        for _ in 0..BIMANUAL_SUBSTEPS {
            self.substep(h, coupling);
        }
    }

    fn substep(&mut self, dt: f64, coupling: [V3; 2]) {
        let grips = [self.grip(&self.hands[0]), self.grip(&self.hands[1])];
        let (floor_z, hw, k, c) = (
            self.floor_z,
            self.half_width,
            self.contact_k,
            self.contact_c,
        );
        let mut forces = [V3::zeros(); 3];
        for i in 0..2 {
            let h = &self.hands[i];
            forces[i] =
                coupling[i] - h.vel * self.drag_hand - grips[i] + box_force(h, floor_z, hw, k, c);
        }
        forces[2] = grips[0]
            + grips[1]
            + V3::new(0.0, 0.0, -self.gravity * self.object.mass)
            + box_force(&self.object, floor_z, hw, k, c);
        let [h0, h1] = &mut self.hands;
        for (s, f) in [
            (h0, forces[0]),
            (h1, forces[1]),
            (&mut self.object, forces[2]),
        ] {
            s.vel += f / s.mass * dt;
            if !s.vel.iter().all(|v| v.is_finite()) {
                s.vel = V3::zeros();
            }
            s.vel = s.vel.map(|v| v.clamp(-10.0, 10.0));
            s.pos += s.vel * dt;
            if !s.pos.iter().all(|v| v.is_finite()) {
                s.pos = V3::zeros();
            }
        }
        self.on_object = grips;
    }

    /// Height of the object's bottom above the floor, m.
    pub fn lift(&self) -> f64 {
        self.object.pos.z - self.object.radius - self.floor_z
    }

    /// Both hands touch the object and it is off the floor (by 5 mm).
    pub fn held(&self) -> bool {
        self.on_object.iter().all(|f| f.norm() > 0.0) && self.lift() > 0.005
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

    /// Two hands pressing on the object from both sides and rising lift it
    /// between them; parting, they drop it.
    #[test]
    fn two_hands_lift_the_object_between_them_and_drop_it() {
        let mut w = Bimanual::new([V3::new(-0.09, 0.0, -0.07), V3::new(0.09, 0.0, -0.07)]);
        let spring = |target: V3, s: &Sphere| (target - s.pos) * 300.0 - s.vel * 20.0;
        let mut max_lift: f64 = 0.0;
        let mut held = 0;
        for i in 0..4000 {
            let t = i as f64 / 1000.0;
            // 0-1 s: close in to ±5.5 cm; 1-3 s: rise 6 cm; 3-4 s: part.
            let (x, z) = if t < 1.0 {
                (0.09 - 0.035 * t, -0.07)
            } else if t < 3.0 {
                (0.055, -0.07 + 0.03 * (t - 1.0))
            } else {
                (0.055 + 0.2 * (t - 3.0), -0.01)
            };
            let f = [
                spring(V3::new(-x, 0.0, z), &w.hands[0]),
                spring(V3::new(x, 0.0, z), &w.hands[1]),
            ];
            w.step(0.001, f);
            if (2.5..3.0).contains(&t) {
                max_lift = max_lift.max(w.lift());
                held += usize::from(w.held());
            }
        }
        assert!(max_lift > 0.03, "lifted {max_lift} m");
        assert!(held > 400, "held {held} of 500 cycles");
        assert!(
            w.object.pos.x.abs() < 0.01,
            "between the hands: {}",
            w.object.pos.x
        );
        // Let go: back on the floor.
        assert!(w.lift() < 0.005, "dropped: {}", w.lift());
        assert!(!w.held());
    }
}
