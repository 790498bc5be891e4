// SPDX-License-Identifier: GPL-2.0

//! The inter-task channels and shared state of the running controller (the
//! spec's ITCs), created once at insmod and shared by CLOCK, SERVO, PROTO_IN
//! and the char devices through an `Arc`.

use crate::completion::Completion;
use kernel::{
    prelude::*,
    sync::atomic::{Atomic, Relaxed},
    time::{Delta, Instant, Monotonic},
};

#[pin_data]
pub(crate) struct Shared {
    /// Cycle start: posted by the CLOCK timer, waited on by SERVO.
    #[pin]
    pub(crate) cycle_start: Completion,
    /// Time origin for every nanosecond stamp below.
    epoch: Instant<Monotonic>,
    /// Servo period, ns (module parameter `period_us`).
    pub(crate) period_ns: i64,
    /// Expiry time of the current cycle's timer, ns since `epoch`.
    pub(crate) cycle_expiry_ns: Atomic<i64>,
    /// Cycles started by the timer.
    pub(crate) timer_ticks: Atomic<u64>,
    /// Cycles completed by SERVO.
    pub(crate) servo_cycles: Atomic<u64>,
    /// Last and worst SERVO wake-up latency after the timer expiry, ns.
    pub(crate) last_latency_ns: Atomic<i64>,
    pub(crate) max_latency_ns: Atomic<i64>,
    /// Bytes and writes accepted by /dev/hap_rtf_in, and the CRC-32C of the last write.
    pub(crate) rtf_in_writes: Atomic<u64>,
    pub(crate) rtf_in_last_crc: Atomic<u32>,
    /// Set at teardown: every thread leaves its loop.
    pub(crate) stopping: Atomic<bool>,
}

impl Shared {
    pub(crate) fn new(period_ns: i64) -> impl PinInit<Self> {
        pin_init!(Self {
            cycle_start <- Completion::new(),
            epoch: Instant::now(),
            period_ns,
            cycle_expiry_ns: Atomic::new(0),
            timer_ticks: Atomic::new(0),
            servo_cycles: Atomic::new(0),
            last_latency_ns: Atomic::new(0),
            max_latency_ns: Atomic::new(0),
            rtf_in_writes: Atomic::new(0),
            rtf_in_last_crc: Atomic::new(0),
            stopping: Atomic::new(false),
        })
    }

    /// Nanoseconds since `epoch` of an instant.
    pub(crate) fn ns_of(&self, t: Instant<Monotonic>) -> i64 {
        (t - self.epoch).as_nanos()
    }

    /// Nanoseconds since `epoch`, now.
    pub(crate) fn now_ns(&self) -> i64 {
        self.ns_of(Instant::now())
    }

    pub(crate) fn period(&self) -> Delta {
        Delta::from_nanos(self.period_ns)
    }

    pub(crate) fn is_stopping(&self) -> bool {
        self.stopping.load(Relaxed)
    }
}
