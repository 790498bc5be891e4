//! One SERVO cycle (spec §3.5) as a single function: the synchronizer's
//! `receive_vp` (copy VPr when the read of the VPr latch succeeded, else the
//! best estimate), the servo step with the link watchdog's gain bounding the
//! coupling force at the motors (and so the answer, its reaction), and the
//! answer frames of `send_vp`.
//!
//! The kernel's SERVO thread only takes the locks and moves bytes around this
//! call; the host replay (`hap_replay`) calls the very same function, so a
//! scripted run gives the same position log bit for bit in both places.

use super::arm_io::ArmIo;
use super::config::ServoConfig;
use super::fixed::Fx;
use super::io::MotorLine;
use super::mode::Mode;
use super::proto_synchro::{answer_frame, answer_twist_frame, twist_due, Synchro};
use super::protocol::{encode, FrameHeader, MAX_FRAME_LEN};
use super::servo::{Servo, ServoInputs};
use super::simulator::Simulator;
use super::vp::{VpReceived, VpSent};

/// What one cycle produced.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CycleResult {
    /// The answer (VP): its coupling wrench is the reaction of the force the
    /// motors apply, already faded by the link watchdog.
    pub vp: VpSent,
    /// The VPr estimate was extrapolated (lock busy or frame late).
    pub extrapolated: bool,
    /// The link watchdog gain, [0, 1]: the coupling envelope at the motors
    /// stays at or below it.
    pub link_gain: Fx,
}

/// SERVO's whole state: the servo (the arm behind the I/O seam, the
/// controller, effort) and the synchronizer's VPr copy.
pub struct ServoCycle<A: ArmIo = Simulator> {
    pub servo: Servo<A>,
    pub synchro: Synchro,
    period_us: u32,
}

impl ServoCycle<Simulator> {
    /// A servo cycle of the simulated arm for `period_us` (100..=10000, see
    /// `clock::validate_period_us`).
    pub const fn new(period_us: u32) -> ServoCycle {
        ServoCycle::with_arm(Simulator::new(period_us.saturating_mul(1000)), period_us)
    }
}

impl<A: ArmIo> ServoCycle<A> {
    /// A servo cycle of `arm` for `period_us`.
    pub const fn with_arm(arm: A, period_us: u32) -> ServoCycle<A> {
        ServoCycle {
            servo: Servo::with_arm(arm, period_us.saturating_mul(1000)),
            synchro: Synchro::new(),
            period_us,
        }
    }

    pub const fn period_us(&self) -> u32 {
        self.period_us
    }

    /// Run one cycle. `line` is hap_io's motor line (outside every lock, see
    /// `io`). `vpr_latest` is the VPr read from the VPr latch, `None` when
    /// every read attempt overlapped PROTO_IN's publication.
    pub fn run(
        &mut self,
        line: &MotorLine,
        inputs: &ServoInputs,
        config: &ServoConfig,
        vpr_latest: Option<&VpReceived>,
        mode: Mode,
    ) -> CycleResult {
        let now_cycle = self.servo.cycle();
        let est = self
            .synchro
            .receive_vp(vpr_latest, now_cycle, self.period_us);
        // A VPr the watchdog has faded to nothing no longer couples the arm.
        let mut vpr = est.vpr;
        if est.link_gain == Fx::ZERO {
            vpr.valid = false;
        }
        // The watchdog's gain bounds the coupling envelope, so the force the
        // motors apply and the answer's wrench (its reaction) are both faded.
        // A closed session (no VPr copy) is not a silent link: the
        // coupling then ramps down on its own (control.md).
        let gain = if self.synchro.last().valid {
            est.link_gain
        } else {
            Fx::ONE
        };
        self.servo.set_link_gain(gain);
        let mut vp = *self.servo.step(line, inputs, config, &vpr, mode);
        self.servo.log_link(&est, gain);
        vp.status |= est.status;
        CycleResult {
            vp,
            extrapolated: est.extrapolated,
            link_gain: est.link_gain,
        }
    }
}

/// `send_vp`'s encoding does not depend on the arm.
impl ServoCycle {
    /// Encode the answer frames for `vp` (`send_vp`): always an `Answer`,
    /// plus an `AnswerTwist` every `TWIST_EVERY` cycles. `next_seq` gives the
    /// sequence number of each frame. Returns the number of frames written.
    pub fn encode_answers(
        vp: &VpSent,
        session: u16,
        time_us: u32,
        mut next_seq: impl FnMut() -> u32,
        out: &mut [[u8; MAX_FRAME_LEN]; 2],
        lens: &mut [usize; 2],
    ) -> usize {
        let (h, f): (FrameHeader, _) = answer_frame(vp, session, next_seq(), time_us);
        let [first, second] = out;
        lens[0] = encode(&h, &f, first);
        if twist_due(vp.cycle) {
            let (h, f) = answer_twist_frame(vp, session, next_seq(), time_us);
            lens[1] = encode(&h, &f, second);
            2
        } else {
            lens[1] = 0;
            1
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::fixed::Pose;
    use super::super::protocol::{decode, Frame};
    use super::super::servo::PowerRequest;
    use super::*;

    #[test]
    fn silent_link_fades_to_no_coupling_and_answers_decode() {
        let line = MotorLine::new();
        let mut c = ServoCycle::new(1000);
        let cfg = ServoConfig::default();
        let vpr = VpReceived {
            pose: Pose::default(),
            valid: true,
            ..VpReceived::default()
        };
        let on = ServoInputs {
            power_request: PowerRequest::On,
            live_effort: None,
        };
        let r = c.run(&line, &on, &cfg, Some(&vpr), Mode::Main);
        assert_eq!(r.link_gain, Fx::ONE);
        // Lock busy for a long time: the estimate ages, the gain reaches 0.
        let none = ServoInputs {
            power_request: PowerRequest::None,
            live_effort: None,
        };
        let mut last = r;
        for _ in 0..200 {
            last = c.run(&line, &none, &cfg, None, Mode::Main);
        }
        assert!(last.extrapolated);
        assert_eq!(last.link_gain, Fx::ZERO);
        assert_eq!(last.vp.coupling_wrench, Default::default());
        let mut out = [[0u8; MAX_FRAME_LEN]; 2];
        let mut lens = [0usize; 2];
        let mut seq = 10;
        let n = ServoCycle::encode_answers(
            &last.vp,
            3,
            1234,
            || {
                seq += 1;
                seq
            },
            &mut out,
            &mut lens,
        );
        assert!(n >= 1);
        let (h, f) = decode(&out[0][..lens[0]]).expect("answer decodes");
        assert_eq!(h.session, 3);
        assert_eq!(h.seq, 11);
        assert!(matches!(f, Frame::Answer(_)));
    }

    #[test]
    fn same_inputs_same_results() {
        let cfg = ServoConfig::default();
        let mut a = ServoCycle::new(1000);
        let mut b = ServoCycle::new(1000);
        let (la, lb) = (MotorLine::new(), MotorLine::new());
        let inp = ServoInputs {
            power_request: PowerRequest::None,
            live_effort: None,
        };
        for _ in 0..500 {
            let ra = a.run(&la, &inp, &cfg, None, Mode::Main);
            let rb = b.run(&lb, &inp, &cfg, None, Mode::Main);
            assert_eq!(ra, rb);
        }
    }
}
