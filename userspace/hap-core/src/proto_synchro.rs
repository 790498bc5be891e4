//! The protocol synchronizer (spec §3.3.1.3), run by SERVO every cycle.
//!
//! `receive_vp`: SERVO reads the VPr latch (the session and VPr PROTO_IN
//! publishes, without any lock). With a read it copies the VPr; when every
//! read attempt overlapped a publication it keeps the copy it has. Either
//! way it then computes the *best estimate* of VPr at this
//! cycle: the client's pose extrapolated with the client's twist over the
//! age of the data, **bounded** by [`EXTRAPOLATION_HORIZON_US`] (20 ms):
//! past the horizon the estimate holds the pose reached at the horizon and
//! reports a zero twist.
//!
//! The link watchdog fades the coupling to zero when the client goes
//! silent: with `age` = time since the VPr in use was received, the gain
//! is 1 up to [`LINK_FADE_START_US`] (50 ms), decreases linearly to 0 at
//! [`LINK_FADE_END_US`] (100 ms), and stays 0 after (and before the first
//! VPr of a session). SERVO bounds the coupling envelope by it
//! (`control::Controller::set_link_gain`): the force the motors apply is at
//! most `gain · MAX_FORCE`, and the answer's wrench is its reaction.
//!
//! `send_vp`: [`answer_frame`] builds the per-cycle `Answer` from `VpSent`,
//! [`answer_twist_frame`] the `AnswerTwist` sent every [`TWIST_EVERY`]
//! cycles (the handle twist does not fit in the 90-byte answer).

use super::fixed::{Fx, Pose, Quat, Twist, Vec3, Wrench};
use super::protocol::{Answer, AnswerTwist, Frame, FrameHeader};
use super::vp::{status, VpReceived, VpSent};

/// Longest extrapolation of VPr, µs; beyond it the estimate holds.
pub const EXTRAPOLATION_HORIZON_US: u64 = 20_000;
/// Age of VPr at which the link watchdog starts fading the coupling, µs.
pub const LINK_FADE_START_US: u64 = 50_000;
/// Age of VPr at which the coupling is zero, µs.
pub const LINK_FADE_END_US: u64 = 100_000;
/// An `AnswerTwist` frame is due every `TWIST_EVERY` cycles.
pub const TWIST_EVERY: u64 = 4;
/// Largest rotation (rad, per axis) applied by one extrapolation: keeps the
/// first-order quaternion step well conditioned.
const MAX_ROT_STEP: Fx = Fx::ONE;

/// Saturating Q32.32 product without i128 (rounded to nearest).
fn mul(a: Fx, b: Fx) -> Fx {
    let neg = (a.0 < 0) != (b.0 < 0);
    let (x, y) = (a.0.unsigned_abs(), b.0.unsigned_abs());
    let (xh, xl) = (x >> 32, x & 0xFFFF_FFFF);
    let (yh, yl) = (y >> 32, y & 0xFFFF_FFFF);
    // x·y / 2^32 = xh·yh·2^32 + xh·yl + xl·yh + xl·yl / 2^32
    let hh = xh.saturating_mul(yh);
    let hh = if hh >= (1u64 << 32) {
        u64::MAX
    } else {
        hh << 32
    };
    let low = xl.saturating_mul(yl).saturating_add(1 << 31) >> 32;
    let mag = hh
        .saturating_add(xh.saturating_mul(yl))
        .saturating_add(xl.saturating_mul(yh))
        .saturating_add(low);
    if neg {
        if mag >= 1u64 << 63 {
            Fx::MIN
        } else {
            Fx(-(mag as i64))
        }
    } else if mag > i64::MAX as u64 {
        Fx::MAX
    } else {
        Fx(mag as i64)
    }
}

fn add(a: Fx, b: Fx) -> Fx {
    Fx(a.0.saturating_add(b.0))
}

fn sub(a: Fx, b: Fx) -> Fx {
    Fx(a.0.saturating_sub(b.0))
}

fn clamp(a: Fx, lim: Fx) -> Fx {
    Fx(a.0.clamp(lim.0.saturating_neg(), lim.0))
}

/// Microseconds as seconds in `Fx` (saturating above ~2^31 s).
fn us_to_fx(us: u64) -> Fx {
    // us < 2^31·10^6 keeps (us << 32) within u64 only below 2^32 µs; split.
    let s = us / 1_000_000;
    let r = us % 1_000_000; // < 2^20, so r << 32 < 2^52
    if s >= (1u64 << 31) {
        return Fx::MAX;
    }
    Fx(((s << 32) | ((r << 32) / 1_000_000)) as i64)
}

/// q / |q| for |q|² in [0.25, 4] (Newton on 1/√n², 6 steps from 1);
/// returns `None` outside that range.
fn normalize(q: Quat) -> Option<Quat> {
    let n2 = add(
        add(mul(q.x, q.x), mul(q.y, q.y)),
        add(mul(q.z, q.z), mul(q.w, q.w)),
    );
    if n2.0 < (1i64 << 30) || n2.0 > (4i64 << 32) {
        return None;
    }
    // r ← r·(3 − n²·r²)/2 converges to 1/√n² for n² < 3 from r = 1; start
    // from 1/2 above that.
    let mut r = if n2.0 > (3i64 << 32) {
        Fx(1 << 31)
    } else {
        Fx::ONE
    };
    let three = Fx::from_int(3);
    for _ in 0..6 {
        let t = sub(three, mul(n2, mul(r, r)));
        r = Fx(mul(r, t).0 >> 1);
    }
    Some(Quat {
        x: mul(q.x, r),
        y: mul(q.y, r),
        z: mul(q.z, r),
        w: mul(q.w, r),
    })
}

/// Pose after moving with `twist` for `dt` seconds (world-frame twist:
/// ṗ = v, q̇ = ½ (ω, 0) ⊗ q), first-order step then renormalised.
pub fn extrapolate_pose(pose: &Pose, twist: &Twist, dt: Fx) -> Pose {
    let p = &pose.position;
    let v = &twist.linear;
    let position = Vec3 {
        x: add(p.x, mul(v.x, dt)),
        y: add(p.y, mul(v.y, dt)),
        z: add(p.z, mul(v.z, dt)),
    };
    // Half rotation vector h = ω·dt/2, each component bounded.
    let half = |w: Fx| Fx(clamp(mul(w, dt), MAX_ROT_STEP).0 >> 1);
    let (hx, hy, hz) = (
        half(twist.angular.x),
        half(twist.angular.y),
        half(twist.angular.z),
    );
    let q = &pose.orientation;
    // (h, 0) ⊗ (qv, qw) = (qw·h + h × qv, −h·qv)
    let dq = Quat {
        x: add(mul(q.w, hx), sub(mul(hy, q.z), mul(hz, q.y))),
        y: add(mul(q.w, hy), sub(mul(hz, q.x), mul(hx, q.z))),
        z: add(mul(q.w, hz), sub(mul(hx, q.y), mul(hy, q.x))),
        w: Fx(0i64.saturating_sub(add(add(mul(hx, q.x), mul(hy, q.y)), mul(hz, q.z)).0)),
    };
    let stepped = Quat {
        x: add(q.x, dq.x),
        y: add(q.y, dq.y),
        z: add(q.z, dq.z),
        w: add(q.w, dq.w),
    };
    let orientation = normalize(stepped).unwrap_or(*q);
    Pose {
        position,
        orientation,
    }
}

/// Age of `vpr` at `now_cycle`, µs (saturating; 0 if stamped in the future).
pub fn vpr_age_us(vpr: &VpReceived, now_cycle: u64, period_us: u32) -> u64 {
    now_cycle
        .saturating_sub(vpr.received_cycle)
        .saturating_mul(u64::from(period_us))
}

/// The link watchdog's age at `now_cycle`, µs: the VPr's age
/// ([`vpr_age_us`]), or, for a client that keeps the link passive
/// (`link_energy`), the time since the last frame of the session arrived
/// (`heard_cycle`): a slow link is a live one as long as frames arrive.
pub fn link_age_us(vpr: &VpReceived, now_cycle: u64, period_us: u32) -> u64 {
    if vpr.link_energy {
        now_cycle
            .saturating_sub(vpr.heard_cycle)
            .saturating_mul(u64::from(period_us))
    } else {
        vpr_age_us(vpr, now_cycle, period_us)
    }
}

/// Link watchdog gain for data `age_us` old: 1 up to `LINK_FADE_START_US`,
/// linear to 0 at `LINK_FADE_END_US`, then 0.
pub fn link_gain(age_us: u64) -> Fx {
    if age_us <= LINK_FADE_START_US {
        Fx::ONE
    } else if age_us >= LINK_FADE_END_US {
        Fx::ZERO
    } else {
        let left = LINK_FADE_END_US - age_us; // < 50_000
        Fx(((left << 32) / (LINK_FADE_END_US - LINK_FADE_START_US)) as i64)
    }
}

/// `w · gain` (gain in [0, 1]).
pub fn fade_wrench(w: &Wrench, gain: Fx) -> Wrench {
    let s = |v: &Vec3| Vec3 {
        x: mul(v.x, gain),
        y: mul(v.y, gain),
        z: mul(v.z, gain),
    };
    Wrench {
        force: s(&w.force),
        torque: s(&w.torque),
    }
}

/// What `receive_vp` gives SERVO.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct VprEstimate {
    /// VPr with pose/twist estimated at this cycle (other fields copied).
    pub vpr: VpReceived,
    /// Age of the data the estimate comes from, µs.
    pub age_us: u64,
    /// The lock was busy or the data is more than one period old.
    pub extrapolated: bool,
    /// Link watchdog gain for the coupling wrench, [0, 1].
    pub link_gain: Fx,
    /// `status::VPR_EXTRAPOLATED` / `status::LINK_FADING` bits to OR into
    /// the answer's status.
    pub status: u32,
}

/// The best estimate of `last` at `now_cycle` (bounded extrapolation).
pub fn estimate_vpr(last: &VpReceived, now_cycle: u64, period_us: u32) -> VprEstimate {
    let age_us = vpr_age_us(last, now_cycle, period_us);
    if !last.valid {
        return VprEstimate {
            vpr: *last,
            age_us,
            extrapolated: false,
            link_gain: Fx::ZERO,
            status: status::LINK_FADING,
        };
    }
    let mut vpr = *last;
    if age_us > 0 {
        let dt = us_to_fx(age_us.min(EXTRAPOLATION_HORIZON_US));
        vpr.pose = extrapolate_pose(&last.pose, &last.twist, dt);
        if age_us > EXTRAPOLATION_HORIZON_US {
            vpr.twist = Twist::default(); // holding
        }
    }
    let extrapolated = age_us > u64::from(period_us);
    let link_gain = link_gain(link_age_us(last, now_cycle, period_us));
    let mut st = 0;
    if extrapolated {
        st |= status::VPR_EXTRAPOLATED;
    }
    if link_gain != Fx::ONE {
        st |= status::LINK_FADING;
    }
    VprEstimate {
        vpr,
        age_us,
        extrapolated,
        link_gain,
        status: st,
    }
}

/// SERVO's synchronizer state: its own copy of VPr.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Synchro {
    copy: VpReceived,
    /// Cycles on which the VPr latch was being written on every read
    /// attempt (the field's name is part of the state's `Debug` text, which
    /// `examples/cycle_hash.rs` fingerprints).
    busy_count: u64,
}

impl Synchro {
    pub const fn new() -> Self {
        Synchro {
            copy: VpReceived {
                pose: Pose {
                    position: Vec3 {
                        x: Fx::ZERO,
                        y: Fx::ZERO,
                        z: Fx::ZERO,
                    },
                    orientation: Quat {
                        x: Fx::ZERO,
                        y: Fx::ZERO,
                        z: Fx::ZERO,
                        w: Fx::ONE,
                    },
                },
                twist: Twist {
                    linear: Vec3 {
                        x: Fx::ZERO,
                        y: Fx::ZERO,
                        z: Fx::ZERO,
                    },
                    angular: Vec3 {
                        x: Fx::ZERO,
                        y: Fx::ZERO,
                        z: Fx::ZERO,
                    },
                },
                seq: 0,
                client_time_us: 0,
                received_cycle: 0,
                valid: false,
                link_energy: false,
                heard_cycle: 0,
            },
            busy_count: 0,
        }
    }

    /// `receive_vp()`: `latest` is the VPr read from the VPr latch, `None`
    /// when every read attempt overlapped PROTO_IN's publication.
    pub fn receive_vp(
        &mut self,
        latest: Option<&VpReceived>,
        now_cycle: u64,
        period_us: u32,
    ) -> VprEstimate {
        let busy = match latest {
            Some(v) => {
                self.copy = *v;
                false
            }
            None => {
                self.busy_count = self.busy_count.saturating_add(1);
                true
            }
        };
        let mut e = estimate_vpr(&self.copy, now_cycle, period_us);
        if busy && self.copy.valid {
            e.extrapolated = true;
            e.status |= status::VPR_EXTRAPOLATED;
        }
        e
    }

    /// The last VPr copied from the latch.
    pub const fn last(&self) -> &VpReceived {
        &self.copy
    }

    /// Cycles on which the VPr latch was being written on every read attempt.
    pub const fn latch_busy_cycles(&self) -> u64 {
        self.busy_count
    }

    /// Forget the VPr (session closed): the coupling fades out at once.
    pub fn reset(&mut self) {
        *self = Self::new();
    }
}

fn header(session: u16, seq: u32, time_us: u32) -> FrameHeader {
    FrameHeader {
        control: 0,
        session,
        seq,
        timestamp_us: time_us,
    }
}

/// The per-cycle `Answer` frame for `vp` (header: no flags, `session`,
/// `seq`, controller time `time_us`).
pub fn answer_frame(vp: &VpSent, session: u16, seq: u32, time_us: u32) -> (FrameHeader, Frame) {
    (
        header(session, seq, time_us),
        Frame::Answer(Answer {
            handle_pose: vp.handle_pose,
            coupling_wrench: vp.coupling_wrench,
            status: vp.status,
            alarms: vp.alarms,
            cycle: vp.cycle as u32, // low 32 bits by design
            vpr_seq: vp.vpr_seq,
        }),
    )
}

/// The `AnswerTwist` frame for `vp`.
pub fn answer_twist_frame(
    vp: &VpSent,
    session: u16,
    seq: u32,
    time_us: u32,
) -> (FrameHeader, Frame) {
    (
        header(session, seq, time_us),
        Frame::AnswerTwist(AnswerTwist {
            handle_twist: vp.handle_twist,
            status: vp.status,
            alarms: vp.alarms,
            cycle: vp.cycle as u32,
            vpr_seq: vp.vpr_seq,
            link_energy: vp.link_energy,
        }),
    )
}

/// Is an `AnswerTwist` due at `cycle` (in addition to the `Answer`)?
pub const fn twist_due(cycle: u64) -> bool {
    cycle % TWIST_EVERY == 0
}

#[cfg(test)]
mod tests {
    use super::*;

    fn f(x: Fx) -> f64 {
        x.0 as f64 / 4294967296.0
    }

    fn fx(v: f64) -> Fx {
        Fx((v * 4294967296.0).round() as i64)
    }

    #[test]
    fn mul_matches_float() {
        let mut seed = 0x9E37_79B9_7F4A_7C15u64;
        for _ in 0..10_000 {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            let a = Fx((seed as i64) >> (seed % 40));
            let b = Fx(((seed.rotate_left(17)) as i64) >> (seed % 37 + 10));
            let want = f(a) * f(b);
            let got = mul(a, b);
            if want.abs() < 2147483647.0 {
                assert!(
                    (f(got) - want).abs() <= 1e-9 * want.abs().max(1.0),
                    "{a:?} {b:?}"
                );
            } else {
                assert!(got == Fx::MAX || got == Fx::MIN);
            }
        }
        assert_eq!(mul(Fx::MIN, Fx::MIN), Fx::MAX);
        assert_eq!(mul(Fx::MIN, Fx::ONE), Fx::MIN);
        assert_eq!(mul(Fx::MAX, Fx(-(1 << 33))), Fx::MIN);
    }

    fn vpr(received_cycle: u64) -> VpReceived {
        VpReceived {
            pose: Pose::default(),
            twist: Twist {
                linear: Vec3 {
                    x: Fx::ONE,
                    y: Fx::ZERO,
                    z: Fx(-(1 << 31)),
                },
                angular: Vec3 {
                    x: Fx::ZERO,
                    y: Fx::ZERO,
                    z: Fx::from_int(2),
                },
            },
            seq: 5,
            client_time_us: 0,
            received_cycle,
            valid: true,
            link_energy: false,
            heard_cycle: received_cycle,
        }
    }

    #[test]
    fn extrapolation_is_bounded_then_holds() {
        let v = vpr(100);
        let e = estimate_vpr(&v, 100, 1000);
        assert_eq!(e.vpr.pose, v.pose);
        assert!(!e.extrapolated);
        assert_eq!(e.link_gain, Fx::ONE);
        assert_eq!(e.status, 0);
        let e = estimate_vpr(&v, 110, 1000); // 10 ms
        assert!(e.extrapolated);
        assert!((f(e.vpr.pose.position.x) - 0.010).abs() < 1e-8);
        assert!((f(e.vpr.pose.position.z) + 0.005).abs() < 1e-8);
        // yaw 2 rad/s · 10 ms = 0.02 rad → q = (0, 0, sin .01, cos .01)
        assert!((f(e.vpr.pose.orientation.z) - 0.01f64.sin()).abs() < 1e-4);
        assert!((f(e.vpr.pose.orientation.w) - 0.01f64.cos()).abs() < 1e-4);
        let e20 = estimate_vpr(&v, 120, 1000);
        let e40 = estimate_vpr(&v, 140, 1000);
        assert!((f(e20.vpr.pose.position.x) - 0.020).abs() < 1e-8);
        assert_eq!(e40.vpr.pose, e20.vpr.pose); // held past the horizon
        assert_eq!(e40.vpr.twist, Twist::default());
        assert_eq!(e20.vpr.twist, v.twist);
    }

    #[test]
    fn normalized_after_extrapolation() {
        let mut v = vpr(0);
        v.twist.angular = Vec3 {
            x: Fx::from_int(30),
            y: Fx::from_int(-40),
            z: Fx::from_int(50),
        };
        let e = estimate_vpr(&v, 20, 1000);
        let q = e.vpr.pose.orientation;
        let n = f(q.x).powi(2) + f(q.y).powi(2) + f(q.z).powi(2) + f(q.w).powi(2);
        assert!((n - 1.0).abs() < 1e-7, "{n}");
    }

    #[test]
    fn watchdog_fades_linearly() {
        assert_eq!(link_gain(0), Fx::ONE);
        assert_eq!(link_gain(LINK_FADE_START_US), Fx::ONE);
        assert_eq!(link_gain(75_000), Fx(1 << 31));
        assert_eq!(link_gain(LINK_FADE_END_US), Fx::ZERO);
        assert_eq!(link_gain(u64::MAX), Fx::ZERO);
        let mut prev = Fx::ONE;
        for age in (50_000..=100_000).step_by(1000) {
            let g = link_gain(age);
            assert!(g <= prev);
            prev = g;
        }
        let w = Wrench {
            force: Vec3 {
                x: fx(10.0),
                y: fx(-4.0),
                z: Fx::ZERO,
            },
            torque: Vec3::default(),
        };
        let half = fade_wrench(&w, link_gain(75_000));
        assert_eq!(half.force.x, fx(5.0));
        assert_eq!(half.force.y, fx(-2.0));
        let v = vpr(0);
        let e = estimate_vpr(&v, 80, 1000);
        assert_eq!(e.status, status::VPR_EXTRAPOLATED | status::LINK_FADING);
        assert!((f(e.link_gain) - 0.4).abs() < 1e-9);
    }

    #[test]
    fn synchro_busy_lock_uses_copy() {
        let mut s = Synchro::new();
        let e = s.receive_vp(None, 0, 1000);
        assert_eq!(e.link_gain, Fx::ZERO); // nothing received yet
        let v = vpr(10);
        let e = s.receive_vp(Some(&v), 10, 1000);
        assert!(!e.extrapolated);
        let e = s.receive_vp(None, 11, 1000);
        assert!(e.extrapolated);
        assert_eq!(e.vpr.seq, 5);
        assert_eq!(s.latch_busy_cycles(), 2);
        s.reset();
        assert!(!s.last().valid);
    }

    #[test]
    fn answer_frames() {
        let vp = VpSent {
            status: 3,
            alarms: 1,
            cycle: 0x1_0000_0007,
            vpr_seq: 9,
            ..Default::default()
        };
        let (h, fr) = answer_frame(&vp, 4, 100, 12345);
        assert_eq!(
            h,
            FrameHeader {
                control: 0,
                session: 4,
                seq: 100,
                timestamp_us: 12345
            }
        );
        match fr {
            Frame::Answer(a) => {
                assert_eq!((a.status, a.alarms, a.cycle, a.vpr_seq), (3, 1, 7, 9));
            }
            _ => panic!(),
        }
        assert!(matches!(
            answer_twist_frame(&vp, 4, 101, 0).1,
            Frame::AnswerTwist(_)
        ));
        assert!(twist_due(0) && twist_due(8) && !twist_due(3));
    }
}
