//! The arm's I/O seam (`hap_core::arm_io::ArmIo`) has two implementations:
//! the simulated Virtuose, and here a recorded-trajectory arm that plays
//! back, cycle by cycle, the measures an arm gave. The servo cycle run on
//! the recording answers, commands and logs bit for bit what it did on the
//! simulator: it reaches the arm only through the seam.

use hap_core::arm_io::{ArmIo, Measures};
use hap_core::config::{CommandType, ServoConfig};
use hap_core::cycle::ServoCycle;
use hap_core::effort::EffortSample;
use hap_core::fixed::{Fx, Joints, Pose, Quat, Vec3, Wrench};
use hap_core::io::{Gate, MotorLine};
use hap_core::mode::Mode;
use hap_core::position_log::LogRecord;
use hap_core::servo::{PowerRequest, ServoInputs};
use hap_core::simulator::Simulator;
use hap_core::vp::{VpReceived, VpSent};

/// An arm that records what another arm's I/O gave.
#[derive(Clone, Debug)]
struct Recorder<A> {
    arm: A,
    measures: Vec<Measures>,
}

impl<A: ArmIo> ArmIo for Recorder<A> {
    fn calibrate_at_rest(&mut self, period_ns: u32) {
        self.arm.calibrate_at_rest(period_ns);
    }
    fn set_user_effort(&mut self, effort: &EffortSample) {
        self.arm.set_user_effort(effort);
    }
    fn measures(&mut self, line: &MotorLine) -> Measures {
        let m = self.arm.measures(line);
        self.measures.push(m);
        m
    }
    fn run_period(&mut self, line: &MotorLine) {
        self.arm.run_period(line);
    }
    fn applied_torques(&self) -> Joints {
        self.arm.applied_torques()
    }
    fn line_cut(&self) -> bool {
        self.arm.line_cut()
    }
}

/// A recorded trajectory: each period's measures, played back in order
/// (the last one held after the end); its motors produce what the line
/// gives at the end of each period.
#[derive(Clone, Debug)]
struct RecordedArm {
    measures: Vec<Measures>,
    next: usize,
    applied: Joints,
    line_cut: bool,
    calibrations: u32,
}

impl RecordedArm {
    fn new(measures: Vec<Measures>) -> Self {
        RecordedArm {
            measures,
            next: 0,
            applied: [Fx::ZERO; 6],
            line_cut: false,
            calibrations: 0,
        }
    }
}

impl ArmIo for RecordedArm {
    fn calibrate_at_rest(&mut self, _period_ns: u32) {
        self.next = 0;
        self.applied = [Fx::ZERO; 6];
        self.line_cut = false;
        self.calibrations += 1;
    }
    fn set_user_effort(&mut self, _effort: &EffortSample) {
        // The recording's force sensor already measured the user.
    }
    fn measures(&mut self, _line: &MotorLine) -> Measures {
        let i = self.next.min(self.measures.len() - 1);
        self.next += 1;
        self.measures[i]
    }
    fn run_period(&mut self, line: &MotorLine) {
        self.applied = line.applied();
        self.line_cut = line.gate() == Gate::FailSafe;
    }
    fn applied_torques(&self) -> Joints {
        self.applied
    }
    fn line_cut(&self) -> bool {
        self.line_cut
    }
}

/// What one cycle gave: the answer and the log record's bytes.
type Trace = Vec<(VpSent, [u8; LogRecord::SIZE])>;

/// `cycles` servo cycles of `c` at 1 ms: powered at cycle 0, a user force,
/// a VPr offset from the handle (coupled, impedance); the motor line cut by
/// the fail-safe at `cut_at`.
fn run<A: ArmIo>(c: &mut ServoCycle<A>, cycles: u32, cut_at: u32) -> Trace {
    c.servo.init();
    let line = MotorLine::new();
    let cfg = ServoConfig {
        command_type: CommandType::Impedance,
        ..Default::default()
    };
    let mut vpr = VpReceived {
        valid: true,
        ..Default::default()
    };
    let mut trace = Vec::new();
    for i in 0..cycles {
        if i == cut_at {
            line.fail_safe_inhibit();
            line.power_off();
        }
        let t = Fx::from_ratio(i64::from(i), 1000);
        let (sin, cos) = t.sin_cos();
        let inputs = ServoInputs {
            power_request: if i == 0 {
                PowerRequest::On
            } else {
                PowerRequest::None
            },
            live_effort: Some(EffortSample {
                wrench: Wrench {
                    force: Vec3::new(sin, cos, Fx::from_ratio(1, 2)),
                    torque: Vec3::ZERO,
                },
                dead_man: true,
                buttons: 0,
            }),
        };
        let here = c.servo.vp().handle_pose.position;
        vpr.pose = Pose {
            position: here.add(Vec3::new(
                Fx::from_ratio(1, 100).mul_sat(sin),
                Fx::from_ratio(1, 200).mul_sat(cos),
                Fx::ZERO,
            )),
            orientation: Quat::IDENTITY,
        };
        vpr.seq = i;
        vpr.received_cycle = c.servo.cycle();
        let r = c.run(&line, &inputs, &cfg, Some(&vpr), Mode::Main);
        let mut log = [0u8; LogRecord::SIZE];
        c.servo.log_record().encode(&mut log);
        trace.push((r.vp, log));
    }
    trace
}

const CYCLES: u32 = 3000;
const CUT_AT: u32 = 2500;

#[test]
fn the_servo_on_a_recorded_trajectory_does_what_it_did_on_the_simulator() {
    // The simulator, with its measures recorded.
    let sim = Recorder {
        arm: Simulator::new(1_000_000),
        measures: Vec::new(),
    };
    let mut on_sim = ServoCycle::with_arm(sim, 1000);
    let simulated = run(&mut on_sim, CYCLES, CUT_AT);
    let recorded = on_sim.servo.arm().measures.clone();
    assert_eq!(
        recorded.len(),
        CYCLES as usize,
        "one get_measures per cycle"
    );
    // The arm moved and was pushed by its motors (not a trivial recording).
    assert_ne!(recorded[0].encoders, recorded[CUT_AT as usize - 1].encoders);
    assert!(simulated[..CUT_AT as usize]
        .iter()
        .any(|(_, log)| LogRecord::decode(log).unwrap().motor_torque != [Fx::ZERO; 6]));

    // The same servo cycle on the recording.
    let mut on_rec = ServoCycle::with_arm(RecordedArm::new(recorded), 1000);
    let replayed = run(&mut on_rec, CYCLES, CUT_AT);
    assert_eq!(
        on_rec.servo.arm().calibrations,
        1,
        "calibrated once, by init"
    );
    for (i, (a, b)) in simulated.iter().zip(replayed.iter()).enumerate() {
        assert_eq!(a.0, b.0, "answer of cycle {i}");
        assert_eq!(a.1, b.1, "log record of cycle {i}");
    }
    // After the cut both arms' motors produce 0 and the log says so.
    let last = LogRecord::decode(&replayed.last().unwrap().1).unwrap();
    assert_eq!(last.motor_torque, [Fx::ZERO; 6]);
    assert_ne!(last.flags & hap_core::servo::log_flags::LINE_CUT, 0);
}

#[test]
fn the_log_shows_the_recorded_trajectory() {
    // A trajectory no simulator would produce (a joint stepping by one
    // encoder count per cycle, the others still): the servo's view of the
    // arm is the recording's.
    let base = Simulator::new(1_000_000).measures(&MotorLine::new());
    let recorded: Vec<Measures> = (0..50)
        .map(|i| {
            let mut m = base;
            m.encoders[0] += i;
            m
        })
        .collect();
    let mut c = ServoCycle::with_arm(RecordedArm::new(recorded.clone()), 1000);
    let trace = run(&mut c, 50, u32::MAX);
    let q0 = |log: &[u8; LogRecord::SIZE]| LogRecord::decode(log).unwrap().q[0];
    for w in trace.windows(2) {
        assert!(q0(&w[1].1) > q0(&w[0].1), "q[0] follows the encoder steps");
    }
    let q_first = LogRecord::decode(&trace[0].1).unwrap().q;
    for (k, (_, log)) in trace.iter().enumerate() {
        let r = LogRecord::decode(log).unwrap();
        assert_eq!(
            r.q[1..],
            q_first[1..],
            "the still joints stay still (cycle {k})"
        );
    }
}
