// SPDX-License-Identifier: GPL-2.0

//! SERVO (the spec's hap_servo): waits for the cycle start, runs one servo
//! step, and loops.

use crate::{completion::Wait, kthread, shared::Shared};
use kernel::sync::atomic::{Acquire, Relaxed};

/// SERVO's thread body.
pub(crate) fn servo_main(shared: &Shared) {
    while !kthread::should_stop() && !shared.is_stopping() {
        if shared.cycle_start.wait_timeout(100) == Wait::TimedOut {
            continue;
        }
        if shared.is_stopping() {
            break;
        }
        let latency = shared.now_ns() - shared.cycle_expiry_ns.load(Acquire);
        shared.last_latency_ns.store(latency, Relaxed);
        if latency > shared.max_latency_ns.load(Relaxed) {
            shared.max_latency_ns.store(latency, Relaxed);
        }
        shared.servo_cycles.add(1, Relaxed);
    }
}
