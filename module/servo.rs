// SPDX-License-Identifier: GPL-2.0

//! SERVO (the spec's hap_servo): waits at the cycle barrier, then runs one
//! servo cycle under `mtx_data`: hap-core's `ServoCycle::run` (get_measures →
//! logical/physical state → cartesian_control → send_commands → simulate_arm)
//! between the synchronizer's `receive_vp` and `send_vp`, then logs the
//! simulator's position. The main and the auxiliary (degraded) path are the
//! same code (spec §3.5); CLOCK's supervisor picks the mode.
//! No allocation and no printk inside the cycle. Motor commands go through
//! hap_io's motor line (`Shared::motor_line`), which is outside every lock:
//! the fail-safe cuts it whatever SERVO is doing.

use crate::{
    completion::Wait,
    hap_core::servo::{PowerRequest, ServoInputs, ServoMode},
    kthread, proto_synchro,
    shared::{ServoData, Shared},
};
use kernel::sync::atomic::{Acquire, Relaxed, Release};

/// SERVO's thread body.
pub(crate) fn servo_main(sh: &Shared) {
    while !kthread::should_stop() && !sh.is_stopping() {
        sh.servo_waiting.store(true, Release);
        let w = sh.cycle_start.wait_timeout(100);
        sh.servo_waiting.store(false, Release);
        if sh.is_stopping() {
            break;
        }
        if w == Wait::TimedOut {
            continue;
        }
        // The spec's servo_working = TRUE.
        sh.servo_working.store(true, Release);
        let tick = sh.tick.load(Acquire);
        sh.servo_start_ns.store(sh.now_ns(), Release);

        let mut data = sh.data.lock();
        if inject_fault(sh) == Injected::Hung {
            // The hung SERVO is released only by rmmod: it never finishes.
            break;
        }
        servo_cycle(sh, &mut data);
        drop(data);

        sh.servo_end_ns.store(sh.now_ns(), Release);
        sh.servo_done_tick.store(tick, Release);
        sh.servo_working.store(false, Release);
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
    servo_cycle(sh, &mut data);
}

fn servo_cycle(sh: &Shared, data: &mut ServoData) {
    // Configuration: a fresh copy unless PROTO_IN is writing it.
    match sh.config.try_read() {
        Some(cfg) => data.config = *cfg,
        None => {
            sh.config_busy.add(1, Relaxed);
        }
    }
    let power_request = match sh.power_request.xchg(0, Relaxed) {
        // After a fail-safe the motor line refuses a power-on by itself.
        1 => PowerRequest::On,
        2 => PowerRequest::Off,
        _ => PowerRequest::None,
    };
    if power_request == PowerRequest::On {
        sh.power_on_cycle.store(data.cycle.servo.cycle(), Relaxed);
    }
    let inputs = ServoInputs {
        power_request,
        live_effort: None,
    };
    let mode = if sh.mode.load(Acquire) == 0 {
        ServoMode::Main
    } else {
        ServoMode::Degraded
    };

    let result = proto_synchro::run_cycle(sh, data, &sh.motor_line, &inputs, mode);
    sh.last_status.store(result.vp.status, Relaxed);
    if result.extrapolated {
        sh.vpr_extrapolated.add(1, Relaxed);
    }
    // The simulator's position log.
    let mut rec = [0u8; crate::hap_core::simulator::LogRecord::SIZE];
    data.cycle.servo.log_record().encode(&mut rec);
    sh.simlog.push_overwrite(&rec);
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
fn inject_fault(sh: &Shared) -> Injected {
    if sh.fault_hang.load(Acquire) {
        while !kthread::should_stop() {
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
