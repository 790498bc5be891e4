//! Time-domain passivity across the network link: the two-port approach
//! with energy grants.
//!
//! The network between the user's hand and the client's virtual object is
//! the coupling spring and the channel. Its two ports are the **handle**
//! (the coupling's wrench on it, its twist) at the controller and the
//! **object** (the coupling wrench it receives, its twist) at the client.
//! Delay, jitter, loss and reordering make this network a source of
//! energy. Each end observes its port with Ryu's sampled power `F·v·T`
//! ([`PortLedger::record`]: `energy_in` what its side put in, `energy_out`
//! what the link gave it, both non-decreasing) and keeps a reservoir
//!
//! `R = energy_in + grants received − energy_out − grants given`
//!
//! ([`PortLedger::reservoir`]). An end hands energy to the other end by
//! *granting* it: the grants are a non-decreasing running total sent with
//! its frames. Its passivity controller keeps `R ≥ 0` (the push along the
//! motion that `R` does not cover is taken off before the step). Then,
//! whatever the delays, the network's energy
//! `E_in,S + E_in,C − E_out,S − E_out,C = R_S + R_C + (grants in flight)`
//! stays ≥ 0. Because grants are running totals, a lost frame loses no
//! energy (the next one carries it) and a reordered older frame changes
//! nothing (the receiver keeps the largest total it has seen).
//!
//! On the wire a total is a `u32` in units of 2⁻²⁰ J (about 0.95 µJ),
//! rounded down by the sender (a receiver never credits more than was
//! granted), and wraps modulo 2³²; the receiver takes `wire − last` as a
//! signed 32-bit difference and credits it only when positive. The sender
//! must not grant 2³¹ units (2048 J) between two frames the receiver
//! accepts; a larger jump would be taken for an older frame and ignored
//! (which can only withhold energy). See `Documentation/protocol.md` §2
//! ("Link energy") and `Documentation/control.md` ("Passivity across the
//! link").

use super::control::along;
#[cfg(test)]
use super::fixed::Vec3;
use super::fixed::{Fx, Twist, Wrench};

/// Fractional bits of `Fx` dropped on the wire: a wire unit is 2⁻²⁰ J.
pub const ENERGY_WIRE_SHIFT: u32 = 12;

/// A running total (J, ≥ 0) as its wire value: rounded down to 2⁻²⁰ J,
/// modulo 2³².
pub const fn energy_to_wire(total: Fx) -> u32 {
    let t = if total.0 < 0 { 0 } else { total.0 };
    ((t as u64) >> ENERGY_WIRE_SHIFT) as u32
}

/// The other end's running total, rebuilt from its wire values.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PeerTotal {
    last_wire: u32,
    total: Fx,
}

impl PeerTotal {
    pub const fn new() -> PeerTotal {
        PeerTotal {
            last_wire: 0,
            total: Fx::ZERO,
        }
    }

    /// Take a received wire total; returns the energy credited (J, ≥ 0).
    /// An older (smaller) value, or the same one again, credits nothing.
    pub fn receive(&mut self, wire: u32) -> Fx {
        let delta = wire.wrapping_sub(self.last_wire) as i32;
        if delta <= 0 {
            return Fx::ZERO;
        }
        self.last_wire = wire;
        let credit = Fx(i64::from(delta) << ENERGY_WIRE_SHIFT);
        self.total = self.total.add_sat(credit);
        credit
    }

    /// The other end's total as far as received, J.
    pub const fn total(&self) -> Fx {
        self.total
    }
}

/// One end's ledger: its port on the link, what it granted the other end
/// and what the other end granted it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PortLedger {
    /// Energy this end's port put into the link, J (non-decreasing).
    pub energy_in: Fx,
    /// Energy the link gave this end's port, J (non-decreasing).
    pub energy_out: Fx,
    /// Energy granted to the other end, J (non-decreasing; sent on the
    /// wire as [`PortLedger::wire_granted`]).
    pub granted: Fx,
    /// The other end's grants, as received.
    pub peer: PeerTotal,
}

impl PortLedger {
    pub const fn new() -> PortLedger {
        PortLedger {
            energy_in: Fx::ZERO,
            energy_out: Fx::ZERO,
            granted: Fx::ZERO,
            peer: PeerTotal::new(),
        }
    }

    /// This end's reservoir, J: what its port put in and the other end
    /// granted it, less what its port took and it granted away. Its
    /// passivity controller keeps it ≥ 0; it is also what the port may
    /// still take out.
    pub const fn reservoir(&self) -> Fx {
        self.energy_in
            .add_sat(self.peer.total())
            .sub_sat(self.energy_out)
            .sub_sat(self.granted)
    }

    /// Record one step's energy at the port: `e > 0` the link gave `e` to
    /// this end, `e < 0` this end put `−e` into the link.
    pub fn record(&mut self, e: Fx) {
        if e.0 > 0 {
            self.energy_out = self.energy_out.add_sat(e);
        } else {
            self.energy_in = self.energy_in.add_sat(e.neg_sat());
        }
    }

    /// Grant the other end what the reservoir holds beyond `keep` (J).
    pub fn grant_beyond(&mut self, keep: Fx) {
        let surplus = self.reservoir().sub_sat(keep.max(Fx::ZERO));
        if surplus.0 > 0 {
            self.granted = self.granted.add_sat(surplus);
        }
    }

    /// The grants' total as sent on the wire (rounded down: the other end
    /// never receives more than was granted).
    pub const fn wire_granted(&self) -> u32 {
        energy_to_wire(self.granted)
    }
}

/// The client's end: its passivity observer on the object's port and the
/// passivity controller on the force the object receives.
///
/// Per client step: [`ClientLink::on_peer_total`] with the controller's
/// total of every `answer_twist` received; [`ClientLink::force`] turns the
/// coupling wrench received into the wrench to apply to the object over the
/// step that starts, the object moving with `twist`; [`ClientLink::commit`]
/// when the step is done (before its `vpr_stream`), which records the
/// step's energy; [`ClientLink::wire_in`] goes into that `vpr_stream`.
///
/// The observer's power sample is `F·v·dt` (and `τ·ω·dt`), `v` the twist
/// the step starts with. The controller takes off the part of the wrench's
/// push along the motion that would exceed the budget (`F − c·v̂`,
/// `0 ≤ c ≤ F·v̂`: never more than the force's own push, so no active
/// damping), so the observer's output stays within the received input.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ClientLink {
    pub ledger: PortLedger,
    /// The step handed out last and not yet committed: wrench, twist, dt.
    pending: Option<(Wrench, Twist, Fx)>,
    /// Steps on which the controller took force off.
    pub limited_steps: u64,
}

impl ClientLink {
    pub const fn new() -> ClientLink {
        ClientLink {
            ledger: PortLedger::new(),
            pending: None,
            limited_steps: 0,
        }
    }

    /// The controller's `energy_in` total of an `answer_twist`.
    pub fn on_peer_total(&mut self, wire: u32) {
        self.ledger.peer.receive(wire);
    }

    /// The wrench to apply to the object for the step of `dt` seconds that
    /// starts now, the object moving with `twist`: `received` less the push
    /// along the motion that the budget does not cover. Calling it again
    /// before [`ClientLink::commit`] replaces the step.
    pub fn force(&mut self, received: &Wrench, twist: &Twist, dt: Fx) -> Wrench {
        let mut w = *received;
        let p_f = w.force.dot(twist.linear).mul_sat(dt).max(Fx::ZERO);
        let p_t = w.torque.dot(twist.angular).mul_sat(dt).max(Fx::ZERO);
        let mut over = p_f
            .add_sat(p_t)
            .sub_sat(self.ledger.reservoir().max(Fx::ZERO));
        if over.0 > 0 {
            self.limited_steps = self.limited_steps.saturating_add(1);
            // A hair more than the excess, for the rounding of the products.
            over = over.add_sat(Fx(over.0 >> 10)).add_sat(Fx(16));
            let take_f = over.min(p_f);
            w.force = w.force.sub(along(twist.linear, take_f, dt));
            let take_t = over.sub_sat(take_f).min(p_t);
            w.torque = w.torque.sub(along(twist.angular, take_t, dt));
        }
        self.pending = Some((w, *twist, dt));
        w
    }

    /// The wrench to apply unchanged (the controller off): the observer
    /// still records the step at [`ClientLink::commit`].
    pub fn observe_only(&mut self, received: &Wrench, twist: &Twist, dt: Fx) -> Wrench {
        self.pending = Some((*received, *twist, dt));
        *received
    }

    /// The step handed out is done: record its energy (> 0: the link gave
    /// it to the object), then grant the controller all the reservoir holds
    /// (the client keeps nothing back: its object stores its own energy).
    pub fn commit(&mut self) {
        if let Some((w, twist, dt)) = self.pending.take() {
            let e = w
                .force
                .dot(twist.linear)
                .add_sat(w.torque.dot(twist.angular))
                .mul_sat(dt);
            self.ledger.record(e);
        }
        self.ledger.grant_beyond(Fx::ZERO);
    }

    /// This end's grants' total for the next `vpr_stream`.
    pub const fn wire_granted(&self) -> u32 {
        self.ledger.wire_granted()
    }

    /// Forget everything (a new session: both ends start at 0).
    pub fn reset(&mut self) {
        *self = ClientLink::new();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wire_rounds_down_and_wraps() {
        assert_eq!(energy_to_wire(Fx::ZERO), 0);
        assert_eq!(energy_to_wire(Fx(-5)), 0);
        assert_eq!(energy_to_wire(Fx((1 << 12) - 1)), 0);
        assert_eq!(energy_to_wire(Fx::ONE), 1 << 20);
        // 4096 J is 2^32 units: wraps to 0.
        assert_eq!(energy_to_wire(Fx::from_int(4096)), 0);
        assert_eq!(energy_to_wire(Fx::from_int(4097)), 1 << 20);
    }

    #[test]
    fn peer_total_is_monotone_across_loss_reordering_and_wrap() {
        let mut p = PeerTotal::new();
        assert_eq!(p.receive(1 << 20), Fx::ONE);
        // An older frame arriving late credits nothing.
        assert_eq!(p.receive(1 << 19), Fx::ZERO);
        assert_eq!(p.receive(1 << 20), Fx::ZERO);
        assert_eq!(p.total(), Fx::ONE);
        // Frames lost in between: the next total carries their energy.
        p.receive(5 << 20);
        assert_eq!(p.total(), Fx::from_int(5));
        // Across the wrap: 2000 J, 4000 J, then 4097 J (wire 1 J).
        let mut q = PeerTotal::new();
        for j in [2000, 4000, 4097] {
            q.receive(energy_to_wire(Fx::from_int(j)));
        }
        assert_eq!(energy_to_wire(Fx::from_int(4097)), 1 << 20);
        assert_eq!(q.total(), Fx::from_int(4097));
        // A jump of 2^31 units or more is taken for an older frame.
        let mut r = PeerTotal::new();
        assert_eq!(r.receive(1 << 31), Fx::ZERO);
        assert_eq!(r.total(), Fx::ZERO);
    }

    #[test]
    fn ledger_sorts_energy_by_direction_and_grants_its_surplus() {
        let mut l = PortLedger::new();
        l.record(Fx::from_int(-3));
        l.record(Fx::from_int(2));
        assert_eq!(l.energy_out, Fx::from_int(2));
        assert_eq!(l.energy_in, Fx::from_int(3));
        assert_eq!(l.reservoir(), Fx::ONE);
        l.peer.receive(energy_to_wire(Fx::from_int(5)));
        assert_eq!(l.reservoir(), Fx::from_int(6));
        l.grant_beyond(Fx::from_int(4));
        assert_eq!(l.granted, Fx::from_int(2));
        assert_eq!(l.reservoir(), Fx::from_int(4));
        // Nothing beyond what it keeps: no grant, never a negative one.
        l.grant_beyond(Fx::from_int(10));
        assert_eq!(l.granted, Fx::from_int(2));
        assert_eq!(l.wire_granted(), 2 << 20);
    }

    fn fx(v: f64) -> Fx {
        Fx::from_f64(v)
    }

    #[test]
    fn client_controller_keeps_the_work_within_the_budget() {
        let mut c = ClientLink::new();
        c.on_peer_total(energy_to_wire(fx(0.001)));
        let dt = fx(0.001);
        let twist = Twist {
            linear: Vec3::new(fx(1.0), Fx::ZERO, Fx::ZERO),
            angular: Vec3::ZERO,
        };
        // 10 N along a 1 m/s motion for 1 ms: 10 mJ, 1 mJ allowed.
        let f = Wrench {
            force: Vec3::new(fx(10.0), fx(3.0), Fx::ZERO),
            torque: Vec3::ZERO,
        };
        let w = c.force(&f, &twist, dt);
        assert!((w.force.x.to_f64() - 1.0).abs() < 1e-2, "{:?}", w.force);
        // The part across the motion does no work and is kept.
        assert_eq!(w.force.y, fx(3.0));
        assert_eq!(c.limited_steps, 1);
        c.commit();
        let b = c.ledger.reservoir().to_f64();
        assert!((-1e-9..1e-5).contains(&b), "{b}");
        // A second commit records nothing.
        c.commit();
        assert_eq!(c.ledger.reservoir().to_f64(), b);
        // No budget left: the push along the motion goes, nothing reverses.
        let w = c.force(&f, &twist, dt);
        assert!((0.0..0.01).contains(&w.force.x.to_f64()), "{:?}", w.force);
        c.commit();
        // A force against the motion is not touched and puts energy in.
        let back = Wrench {
            force: Vec3::new(fx(-4.0), Fx::ZERO, Fx::ZERO),
            torque: Vec3::ZERO,
        };
        assert_eq!(c.force(&back, &twist, dt), back);
        c.commit();
        assert!((c.ledger.energy_in.to_f64() - 0.004).abs() < 1e-6);
        // ...which the client grants the controller at once.
        assert_eq!(c.ledger.reservoir(), Fx::ZERO);
        assert_eq!(c.wire_granted(), energy_to_wire(c.ledger.granted));
        assert!(c.ledger.energy_out <= c.ledger.peer.total());
    }
}
