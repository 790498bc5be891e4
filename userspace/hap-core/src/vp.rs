//! The two records exchanged between the protocol and the servo loop
//! (the spec's shared memories): `VpReceived` (VPr, the client's virtual
//! object as PROTO_IN decoded it) and `VpSent` (VP, what SERVO answers).

use super::fixed::{Pose, Twist, Wrench};
use super::words::WordWalk;

/// VPr: the client's virtual object, as last received.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct VpReceived {
    /// Pose of the virtual object in the client's world frame.
    pub pose: Pose,
    /// Twist of the virtual object (used to extrapolate when a frame is late).
    pub twist: Twist,
    /// Sequence number of the frame it came from.
    pub seq: u32,
    /// The client's timestamp of that frame, µs (wraps).
    pub client_time_us: u32,
    /// Controller time (servo cycle counter) at which it was decoded.
    pub received_cycle: u64,
    /// False until the first valid VPr frame of the session.
    pub valid: bool,
    /// The frame carried `CTRL_LINK_ENERGY`: `client_time_us` is the
    /// client's link energy grants (2⁻²⁰ J, wrapping), and the controller
    /// keeps the link passive (`link`).
    pub link_energy: bool,
    /// Controller time (servo cycle counter) at which the last frame of the
    /// session arrived, this VPr's or any later one, in order or not (the
    /// link watchdog's clock when `link_energy`).
    pub heard_cycle: u64,
}

/// Words of a published [`VpReceived`] ([`VpReceived::visit_words`]).
pub const VPR_WORDS: usize = 19;

impl VpReceived {
    /// Visit the words of a publication of the VPr (`VPR_WORDS` of them,
    /// word `i` handed to `f` as `(i, &mut value)`): reading `*value`
    /// encodes, writing it decodes. One walk for both directions, so that
    /// they cannot disagree; `Fx` values cross as their bits. The kernel's
    /// VPr latch (PROTO_IN → SERVO) is these words under a seqcount.
    pub fn visit_words(&mut self, f: impl FnMut(usize, &mut u64)) {
        self.visit_words_from(0, f);
    }

    /// [`VpReceived::visit_words`] with the first word numbered `first`
    /// (a record that embeds the VPr after words of its own).
    pub fn visit_words_from(&mut self, first: usize, f: impl FnMut(usize, &mut u64)) {
        let mut k = WordWalk::new(first, f);
        let (p, o) = (&mut self.pose.position, &mut self.pose.orientation);
        for x in [
            &mut p.x, &mut p.y, &mut p.z, &mut o.x, &mut o.y, &mut o.z, &mut o.w,
        ] {
            k.fx(x);
        }
        let (l, a) = (&mut self.twist.linear, &mut self.twist.angular);
        for x in [&mut l.x, &mut l.y, &mut l.z, &mut a.x, &mut a.y, &mut a.z] {
            k.fx(x);
        }
        k.u32(&mut self.seq);
        k.u32(&mut self.client_time_us);
        k.word(&mut self.received_cycle);
        k.bool(&mut self.valid);
        k.bool(&mut self.link_energy);
        k.word(&mut self.heard_cycle);
    }
}

/// The VPr latch's record (PROTO_IN → SERVO): the protocol's session and
/// its VPr, published together whenever either changes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct VprLatchRecord {
    /// The open session (0: none).
    pub session: u16,
    pub vpr: VpReceived,
}

/// Words of a [`VprLatchRecord`]: the session, then the VPr's.
pub const VPR_LATCH_WORDS: usize = 1 + VPR_WORDS;

impl VprLatchRecord {
    /// The record's words (see [`VpReceived::visit_words`]): word 0 is the
    /// session, then the VPr's `VPR_WORDS`.
    pub fn visit_words(&mut self, f: impl FnMut(usize, &mut u64)) {
        let mut k = WordWalk::new(0, f);
        k.u16(&mut self.session);
        let mut f = k.into_inner();
        self.vpr.visit_words_from(1, &mut f);
    }
}

/// Status bits of the arm, sent in every answer (VirtuoseAPI `virtGetPowerOn`,
/// `virtGetDeadMan`, `virtGetEmergencyStop`, buttons...).
pub mod status {
    /// Arm supply powered.
    pub const POWER_ON: u32 = 1 << 0;
    /// Motor commands enabled (power on and not inhibited).
    pub const MOTORS_ENABLED: u32 = 1 << 1;
    /// The user holds the handle (dead-man switch).
    pub const DEAD_MAN: u32 = 1 << 2;
    /// Emergency stop pressed.
    pub const EMERGENCY_STOP: u32 = 1 << 3;
    /// Handle button 1 (indexing) pressed.
    pub const BUTTON_1: u32 = 1 << 4;
    /// Handle button 2 pressed.
    pub const BUTTON_2: u32 = 1 << 5;
    /// SERVO ran its auxiliary (degraded) path this cycle.
    pub const DEGRADED: u32 = 1 << 6;
    /// A virtual object is attached and coupled.
    pub const COUPLED: u32 = 1 << 7;
    /// The link watchdog is fading the coupling (client silent).
    pub const LINK_FADING: u32 = 1 << 8;
    /// VPr was extrapolated this cycle (protocol lock busy or frame late).
    pub const VPR_EXTRAPOLATED: u32 = 1 << 9;
}

/// Alarm bits (latched until cleared by a power cycle).
pub mod alarm {
    /// A joint reached its position limit.
    pub const JOINT_LIMIT: u32 = 1 << 0;
    /// A motor torque was saturated.
    pub const TORQUE_SATURATED: u32 = 1 << 1;
    /// The handle speed exceeded the velocity limit.
    pub const VELOCITY_LIMIT: u32 = 1 << 2;
    /// The passivity observer had to dissipate energy.
    pub const PASSIVITY: u32 = 1 << 3;
    /// A deadline was missed (see the cycle supervisor).
    pub const DEADLINE_MISS: u32 = 1 << 4;
    /// Fail-safe engaged.
    pub const FAIL_SAFE: u32 = 1 << 5;
}

/// VP: SERVO's answer to the client for one cycle.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct VpSent {
    /// Handle pose in the client's world frame (after base frame and factors).
    pub handle_pose: Pose,
    /// Handle twist in the client's world frame.
    pub handle_twist: Twist,
    /// Wrench to apply to the coupled virtual object (client units).
    pub coupling_wrench: Wrench,
    /// `status::*` bits.
    pub status: u32,
    /// `alarm::*` bits.
    pub alarms: u32,
    /// Servo cycle counter.
    pub cycle: u64,
    /// Sequence number of the last VPr used.
    pub vpr_seq: u32,
    /// The controller's link energy grants (`AnswerTwist::link_energy`).
    pub link_energy: u32,
}

#[cfg(test)]
mod tests {
    use super::*;

    use super::super::fixed::{Fx, Quat, Vec3};

    fn words_of(v: &VpReceived) -> [u64; VPR_WORDS] {
        let mut out = [0u64; VPR_WORDS];
        let mut v = *v;
        let mut seen = 0;
        v.visit_words(|i, w| {
            assert_eq!(i, seen, "words visited in order");
            out[i] = *w;
            seen += 1;
        });
        assert_eq!(seen, VPR_WORDS);
        out
    }

    fn from_words(words: &[u64; VPR_WORDS]) -> VpReceived {
        let mut v = VpReceived::default();
        v.visit_words(|i, w| *w = words[i]);
        v
    }

    #[test]
    fn words_round_trip_every_field() {
        // Every field distinct, extremes included: a field dropped, swapped
        // or truncated on the way changes the decoded value.
        let v3 = |a: i64, b: i64, c: i64| Vec3 {
            x: Fx(a),
            y: Fx(b),
            z: Fx(c),
        };
        let samples = [
            VpReceived::default(),
            VpReceived {
                pose: Pose {
                    position: v3(1, -2, i64::MAX),
                    orientation: Quat {
                        x: Fx(i64::MIN),
                        y: Fx(5),
                        z: Fx(-6),
                        w: Fx::ONE,
                    },
                },
                twist: Twist {
                    linear: v3(7, 8, -9),
                    angular: v3(10, -11, 12),
                },
                seq: u32::MAX,
                client_time_us: 0x8000_0001,
                received_cycle: u64::MAX - 1,
                valid: true,
                link_energy: true,
                heard_cycle: u64::MAX - 3,
            },
        ];
        for v in samples {
            assert_eq!(from_words(&words_of(&v)), v);
        }
        // Each word reaches its own field: flipping one word changes the value.
        let base = samples[1];
        let w = words_of(&base);
        for i in 0..VPR_WORDS {
            let mut w2 = w;
            w2[i] ^= 1;
            assert_ne!(from_words(&w2), base, "word {i} is not decoded");
        }
    }

    fn latch_words(r: &VprLatchRecord) -> [u64; VPR_LATCH_WORDS] {
        let mut r = *r;
        super::super::words::check::to_words(|f| r.visit_words(f))
    }

    fn latch_from(words: &[u64; VPR_LATCH_WORDS]) -> VprLatchRecord {
        let mut r = VprLatchRecord::default();
        r.visit_words(|i, w| *w = words[i]);
        r
    }

    #[test]
    fn latch_record_round_trips_session_and_vpr() {
        let vpr = VpReceived {
            seq: 77,
            client_time_us: 5,
            received_cycle: 9,
            valid: true,
            ..VpReceived::default()
        };
        for session in [0u16, 1, 0xbeef, u16::MAX] {
            let r = VprLatchRecord { session, vpr };
            let w = latch_words(&r);
            assert_eq!(w[0], u64::from(session), "the session is word 0");
            assert_eq!(latch_from(&w), r);
            // The VPr part is exactly the VPr's own layout.
            let own = words_of(&vpr);
            assert_eq!(&w[1..], &own[..]);
        }
        // A session word out of u16 range reads as no session (never a
        // truncated, wrong session id).
        let mut w = latch_words(&VprLatchRecord { session: 3, vpr });
        w[0] = 0x1_0003;
        assert_eq!(latch_from(&w).session, 0);
    }
}
