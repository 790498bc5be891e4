// SPDX-License-Identifier: GPL-2.0

//! SERVO (the spec's hap_servo): waits at the cycle barrier, then runs one
//! servo cycle under `mtx_data`: takes the effort commands handed over since
//! its last cycle, then hap-core's `ServoCycle::run` (get_measures →
//! logical/physical state → cartesian_control → send_commands →
//! simulate_arm) between the synchronizer's `receive_vp` and `send_vp`; after
//! `mtx_data` is released it logs the simulator's position with the cycle's
//! timing. The main and the auxiliary (degraded) path
//! are the same code (spec §3.5); CLOCK's supervisor picks the mode through
//! the cycle handshake (`hap_core::handshake`); in `FailSafe` SERVO runs
//! nothing and leaves.
//!
//! Locks inside the cycle: `mtx_data` (SERVO's; module init takes it before
//! the tasks start, the fail-safe only try-locks it) and a try-read of the
//! configuration rwsem (PROTO_IN writes it). VPr and the session come from
//! the VPr latch, a seqcount read without any lock: SERVO never takes
//! `mtx_proto`. No lock a system call can hold: rtf_out, the position log
//! and the effort handoff are lock-free rings, a reader being stopped or
//! preempted cannot delay SERVO; SERVO rings their doorbells (a completion:
//! a raw spinlock held for a bounded wake-up) only when a reader sleeps. No
//! allocation and no printk inside the cycle. Motor commands go through
//! hap_io's motor line (`Shared::motor_line`), which is outside every lock:
//! the fail-safe cuts it whatever SERVO is doing.

use crate::{
    completion::Wait,
    hap_core::{
        clock::Mode,
        servo::{PowerRequest, ServoInputs, ServoMode},
        simulator::{LogRecord, LogTiming},
    },
    kthread::CurrentKThread,
    proto_synchro,
    shared::{ServoData, Shared},
    simulator::take_effort,
};
use kernel::sync::atomic::{Acquire, Relaxed, Release};

/// SERVO's thread body.
pub(crate) fn servo_main(kt: &CurrentKThread, sh: &Shared) {
    // The protocol session, for the log (kept when the latch is being written).
    let mut session = 0u16;
    while !kt.should_stop() && !sh.is_stopping() {
        sh.cycle.set_servo_waiting(true);
        let w = sh.cycle_start.wait_timeout(100);
        sh.cycle.set_servo_waiting(false);
        if sh.is_stopping() {
            break;
        }
        if w == Wait::TimedOut {
            continue;
        }
        // The spec's servo_working = TRUE.
        let start = sh.cycle.servo_begin();
        let mode = match start.mode {
            Mode::Normal => ServoMode::Main,
            Mode::Degraded => ServoMode::Degraded,
            Mode::FailSafe => {
                sh.cycle.servo_leave();
                break;
            }
        };
        let start_ns = sh.now_ns();
        let expiry_ns = sh.expiry_ns.load(Acquire);
        sh.servo_start_ns.store(start_ns, Release);

        let mut data = sh.data.lock();
        if inject_fault(kt, sh) == Injected::Hung {
            // The hung SERVO is released only by rmmod: it never finishes.
            break;
        }
        take_effort(sh, &mut data);
        servo_cycle(sh, &mut data, mode);
        let mut rec = *data.cycle.servo.log_record();
        drop(data);

        if let Some((s, _)) = sh.latest_vpr() {
            session = s;
        }
        let end_ns = sh.now_ns();
        sh.servo_end_ns.store(end_ns, Release);
        // The position log, with this cycle's timing (pushed after the
        // cycle so that the execution time includes everything SERVO did).
        rec.timing = LogTiming {
            tick: start.tick,
            start_ns: u64::try_from(start_ns).unwrap_or(0),
            wakeup_ns: ns_u32(start_ns.saturating_sub(expiry_ns)),
            exec_ns: ns_u32(end_ns.saturating_sub(start_ns)),
            session,
        };
        push_log(sh, &rec);
        sh.cycle.servo_end(start.tick);
    }
}

/// The initial calibration (spec §3.2), at insmod before the tasks start:
/// one servo cycle with the arm at rest and no client. It takes every lock
/// of the cycle once, so first-use costs (lockdep registering its classes on
/// the debug kernel: milliseconds) are not paid inside the first real-time
/// cycle. Its inputs are those of every cycle before a client or a user acts,
/// so the host replay starts from the same state.
pub(crate) fn calibrate(sh: &Shared) {
    let mut data = sh.data.lock();
    servo_cycle(sh, &mut data, ServoMode::Main);
    let rec = *data.cycle.servo.log_record();
    drop(data);
    push_log(sh, &rec);
}

/// Append one record to the position log: refused (counted in
/// `simlog.dropped`) when the log is full or CLOCK's fail-safe is pushing
/// its step record at that moment; never waits.
pub(crate) fn push_log(sh: &Shared, rec: &LogRecord) {
    let mut buf = [0u8; LogRecord::SIZE];
    rec.encode(&mut buf);
    let _ = sh.simlog.try_push_exclusive(&buf);
}

fn ns_u32(ns: i64) -> u32 {
    u32::try_from(ns.max(0)).unwrap_or(u32::MAX)
}

fn servo_cycle(sh: &Shared, data: &mut ServoData, mode: ServoMode) {
    // Configuration: a fresh copy unless PROTO_IN is writing it.
    match sh.config.try_read() {
        Some(cfg) => data.config = *cfg,
        None => {
            sh.config_busy.add(1, Relaxed);
        }
    }
    // After a fail-safe the motor line refuses a power-on by itself.
    let power_request = sh.take_power_request();
    if power_request == PowerRequest::On {
        sh.power_on_cycle.store(data.cycle.servo.cycle(), Relaxed);
    }
    let inputs = ServoInputs {
        power_request,
        live_effort: None,
    };

    let result = proto_synchro::run_cycle(sh, data, &sh.motor_line, &inputs, mode);
    sh.last_status.store(result.vp.status, Relaxed);
    if result.extrapolated {
        sh.vpr_extrapolated.add(1, Relaxed);
    }
}

/// What the fault injection did to this cycle.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Injected {
    Nothing,
    /// Stayed busy past the 3/4 check, then let the cycle run (late).
    Overrun,
    /// Hung until the module is removed.
    Hung,
}

/// Fault injection (`/dev/hap_fault`), called with `mtx_data` held, before
/// the cycle's work: the real fault is a cycle that takes too long (or never
/// ends) while holding SERVO's data, with the last motor command still on
/// the line. `overrun N`: stay busy past the 3/4 check, then run the cycle
/// late; `hang`: never finish, blocked (as in a deadlock) until rmmod stops
/// the thread.
fn inject_fault(kt: &CurrentKThread, sh: &Shared) -> Injected {
    if sh.fault_hang.load(Acquire) {
        while !kt.should_stop() {
            kernel::time::delay::fsleep(kernel::time::Delta::from_millis(1));
        }
        return Injected::Hung;
    }
    let left = sh.fault_overruns.load(Acquire);
    if left == 0 {
        return Injected::Nothing;
    }
    sh.fault_overruns.store(left.saturating_sub(1), Release);
    let until = sh
        .expiry_ns
        .load(Acquire)
        .saturating_add(sh.period_ns() / 8 * 7);
    while sh.now_ns() < until && !sh.is_stopping() {
        kernel::time::delay::udelay(kernel::time::Delta::from_micros(5));
    }
    Injected::Overrun
}
