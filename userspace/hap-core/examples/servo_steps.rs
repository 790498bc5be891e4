//! Driver for the per-step cost figures of `scripts/bench-step.sh`.
//!
//! * `servo_steps K [PERIOD_US]` runs K full SERVO cycles
//!   (`hap_core::cycle::ServoCycle`: synchronizer, servo step, answer
//!   encoding, log record) at a servo period of PERIOD_US (default 1000)
//!   with a scripted effort and a VPr coupled to the arm's own VP. Run it
//!   under `valgrind --tool=callgrind` for K = 1000 and 2000: the Ir
//!   difference divided by 1000 is the instruction count of one cycle (setup
//!   cancels). The period matters: the simulated arm integrates in
//!   sub-steps of at most 500 µs (`simulator::substeps`).
//!   `servo_steps K PERIOD_US ARMS` (ARMS 1 or 2) steps that many arms in
//!   each cycle, one after the other as the module's SERVO does, each with
//!   its own cycle state, motor line and script (arm 1's effort runs a
//!   phase ahead of arm 0's): the Ir difference between ARMS = 2 and
//!   ARMS = 1 is what the second arm adds to a cycle.
//!   With `HAP_STEP_LINK` set, the VPr is a link-passive client's
//!   (`CTRL_LINK_ENERGY`, about 1 W of grants): the cost of that path.
//! * `servo_steps rt SECONDS PERIOD_US` runs the same cycle in a periodic
//!   loop (absolute `clock_nanosleep` on CLOCK_MONOTONIC) and prints the
//!   wake-up latency and the cycle time, like cyclictest. Start it under
//!   `chrt -f 80` for a SCHED_FIFO figure. `servo_steps rt S P DIR` also
//!   writes the 1 µs histograms `DIR/host_loop_{wakeup,cycle}.csv`.

use hap_core::config::{CommandType, ServoConfig};
use hap_core::cycle::ServoCycle;
use hap_core::effort::EffortSample;
use hap_core::fixed::{Fx, Pose, Quat, Vec3, Wrench};
use hap_core::io::MotorLine;
use hap_core::mode::Mode;
use hap_core::position_log::LogRecord;
use hap_core::protocol::MAX_FRAME_LEN;
use hap_core::servo::{PowerRequest, ServoInputs};
use std::hint::black_box;

/// The scripted world: effort, VPr and the output buffers of one cycle.
struct Script {
    cycle: ServoCycle,
    line: MotorLine,
    cfg: ServoConfig,
    vpr: hap_core::vp::VpReceived,
    frames: [[u8; MAX_FRAME_LEN]; 2],
    lens: [usize; 2],
    log: [u8; LogRecord::SIZE],
    seq: u32,
    i: u32,
    /// `HAP_STEP_LINK` set: the VPr carries `link_energy` (the link
    /// passivity path, `hap_core::link`).
    link: bool,
}

impl Script {
    fn new(period_us: u32) -> Script {
        Script::with_phase(period_us, 0)
    }

    /// A script whose effort starts `phase` cycles in.
    fn with_phase(period_us: u32, phase: u32) -> Script {
        let mut cycle = ServoCycle::new(period_us);
        cycle.servo.init();
        let cfg = ServoConfig {
            command_type: CommandType::Impedance,
            ..Default::default()
        };
        let link = std::env::var_os("HAP_STEP_LINK").is_some();
        let vpr = hap_core::vp::VpReceived {
            valid: true,
            link_energy: link,
            ..Default::default()
        };
        let mut s = Script {
            cycle,
            line: MotorLine::new(),
            cfg,
            vpr,
            frames: [[0u8; MAX_FRAME_LEN]; 2],
            lens: [0; 2],
            log: [0u8; LogRecord::SIZE],
            seq: 0,
            i: phase,
            link,
        };
        s.step(PowerRequest::On);
        s
    }

    /// One SERVO cycle: scripted effort, VPr = the last VP's pose plus a
    /// small sinusoidal offset (a coupled virtual object), answers and log
    /// record encoded as the kernel does.
    fn step(&mut self, power: PowerRequest) {
        let i = self.i;
        self.i = i.wrapping_add(1);
        let t = Fx::from_ratio((i % 6283) as i64, 1000);
        let (sin, cos) = t.sin_cos();
        let effort = EffortSample {
            wrench: Wrench {
                force: Vec3::new(sin, cos, Fx::from_ratio(1, 2)),
                torque: Vec3::ZERO,
            },
            dead_man: true,
            buttons: 0,
        };
        let inputs = ServoInputs {
            power_request: power,
            live_effort: Some(effort),
        };
        let here = self.cycle.servo.vp().handle_pose.position;
        self.vpr.pose = Pose {
            position: here.add(Vec3::new(
                Fx::from_ratio(1, 100).mul_sat(sin),
                Fx::from_ratio(1, 200).mul_sat(cos),
                Fx::ZERO,
            )),
            orientation: Quat::IDENTITY,
        };
        self.vpr.seq = i;
        self.vpr.received_cycle = self.cycle.servo.cycle();
        if self.link {
            // A client that keeps the link passive, granting about 1 W
            // (2^10 units of 2^-20 J per cycle).
            self.vpr.heard_cycle = self.vpr.received_cycle;
            self.vpr.client_time_us = i.wrapping_mul(1 << 10);
        }
        let r = self.cycle.run(
            &self.line,
            black_box(&inputs),
            &self.cfg,
            Some(&self.vpr),
            Mode::Main,
        );
        let seq = &mut self.seq;
        let n = ServoCycle::encode_answers(
            &r.vp,
            1,
            i,
            || {
                *seq = seq.wrapping_add(1);
                *seq
            },
            &mut self.frames,
            &mut self.lens,
        );
        self.cycle.servo.log_record().encode(&mut self.log);
        black_box((n, &self.frames, &self.log));
    }
}

#[repr(C)]
struct Timespec {
    tv_sec: i64,
    tv_nsec: i64,
}

extern "C" {
    fn clock_gettime(clk: i32, ts: *mut Timespec) -> i32;
    fn clock_nanosleep(clk: i32, flags: i32, req: *const Timespec, rem: *mut Timespec) -> i32;
}

const CLOCK_MONOTONIC: i32 = 1;
const TIMER_ABSTIME: i32 = 1;

fn now_ns() -> i64 {
    let mut ts = Timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec for the call's duration.
    unsafe { clock_gettime(CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec * 1_000_000_000 + ts.tv_nsec
}

fn sleep_until_ns(t: i64) {
    let ts = Timespec {
        tv_sec: t / 1_000_000_000,
        tv_nsec: t % 1_000_000_000,
    };
    loop {
        // SAFETY: `ts` is a valid timespec; a null `rem` is allowed with TIMER_ABSTIME.
        let rc =
            unsafe { clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, std::ptr::null_mut()) };
        // Non-zero only when a signal interrupted the sleep: sleep again.
        if rc == 0 {
            break;
        }
    }
}

/// min / avg / p99 / p99.9 / max of `v` in µs (sorts it).
fn summary(v: &mut [i64]) -> String {
    v.sort_unstable();
    let n = v.len();
    let q = |p: f64| v[((n as f64 * p).ceil() as usize).clamp(1, n) - 1];
    let avg = v.iter().sum::<i64>() as f64 / n as f64;
    format!(
        "min {:.1} avg {:.1} p99 {:.1} p99.9 {:.1} max {:.1}",
        v[0] as f64 / 1e3,
        avg / 1e3,
        q(0.99) as f64 / 1e3,
        q(0.999) as f64 / 1e3,
        v[n - 1] as f64 / 1e3
    )
}

/// `us,count` lines of a 1 µs histogram of `v` (ns), non-zero buckets only.
fn hist_csv(v: &[i64]) -> String {
    let mut h = std::collections::BTreeMap::<i64, u64>::new();
    for x in v {
        *h.entry(x.max(&0) / 1000).or_default() += 1;
    }
    let mut out = String::from("us,count\n");
    for (us, n) in h {
        out.push_str(&format!("{us},{n}\n"));
    }
    out
}

fn rt_loop(seconds: u32, period_us: u32, hist_dir: Option<&str>) {
    let mut s = Script::new(period_us);
    let period = i64::from(period_us) * 1000;
    let n = (u64::from(seconds) * 1_000_000 / u64::from(period_us)) as usize;
    let mut wake = Vec::with_capacity(n);
    let mut exec = Vec::with_capacity(n);
    let mut misses = 0u32;
    let mut next = now_ns() + period;
    for _ in 0..n {
        sleep_until_ns(next);
        let t0 = now_ns();
        s.step(PowerRequest::None);
        let t1 = now_ns();
        wake.push(t0 - next);
        exec.push(t1 - t0);
        next += period;
        if t1 > next - period / 4 {
            misses += 1;
        }
    }
    if let Some(dir) = hist_dir {
        for (name, v) in [("wakeup", &wake), ("cycle", &exec)] {
            let p = format!("{dir}/host_loop_{name}.csv");
            if let Err(e) = std::fs::write(&p, hist_csv(v)) {
                eprintln!("{p}: {e}");
            }
        }
    }
    println!("host rt loop: {n} cycles at {period_us} us");
    println!("wakeup_us: {}", summary(&mut wake));
    println!("cycle_us: {}", summary(&mut exec));
    println!("misses_3/4_period: {misses}");
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    match args.get(1).map(String::as_str) {
        Some("rt") => {
            let secs = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(10);
            let period = args.get(3).and_then(|a| a.parse().ok()).unwrap_or(1000);
            rt_loop(secs, period, args.get(4).map(String::as_str));
        }
        other => {
            let k: u32 = other.and_then(|a| a.parse().ok()).unwrap_or(1000);
            let period = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(1000);
            let arms: u32 = args.get(3).and_then(|a| a.parse().ok()).unwrap_or(1);
            if !(1..=2).contains(&arms) {
                eprintln!("servo_steps: ARMS is 1 or 2, not {arms}");
                std::process::exit(2);
            }
            let mut scripts: Vec<Script> = (0..arms)
                .map(|a| Script::with_phase(period, a * 1000))
                .collect();
            for _ in 0..k {
                for s in scripts.iter_mut() {
                    s.step(PowerRequest::None);
                }
            }
            for (a, s) in scripts.iter().enumerate() {
                println!(
                    "{k} servo cycles, arm {a}: final handle position {:?}",
                    s.cycle.servo.vp().handle_pose.position
                );
            }
        }
    }
}
