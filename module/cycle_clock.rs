// SPDX-License-Identifier: GPL-2.0

//! The synchronous cycle between CLOCK and SERVO (the spec's `bar_clock`
//! and `servo_working`), and the cycle's time stamps.
//!
//! Protocol (one writer per field):
//! - `cycle_start`: posted by the cycle timer (hard IRQ) when SERVO waits
//!   at the barrier; SERVO waits on it. `check_due`: posted by the check
//!   timer at 3/4 of the period; the CLOCK thread waits on it.
//! - `handshake` (hap-core's `CycleHandshake`, its own orderings): the tick
//!   is advanced by the cycle timer, SERVO's working/done/waiting by SERVO,
//!   the mode by the CLOCK thread.
//! - `expiry_ns` (Release) and `tick_ns` (Relaxed, read only for the
//!   statistics): written by the cycle timer before it posts the cycle;
//!   `ticks_not_posted`: counted by the cycle timer.
//! - `servo_start_ns` / `servo_end_ns`: written by SERVO (Release) at the
//!   start and end of its cycle; read by the CLOCK thread (Acquire) for the
//!   statistics.

use crate::{completion::Completion, hap_core::handshake::CycleHandshake};
use kernel::{
    prelude::*,
    sync::atomic::{Acquire, Atomic, Relaxed, Release},
};

#[pin_data]
pub(crate) struct CycleClock {
    /// Cycle start (the spec's `bar_clock`): cycle timer → SERVO.
    #[pin]
    pub(crate) cycle_start: Completion,
    /// Three quarters of the period: check timer → CLOCK thread.
    #[pin]
    pub(crate) check_due: Completion,
    /// The cycle handshake (tick, SERVO working / done tick / waiting, mode).
    pub(crate) handshake: CycleHandshake,
    /// Ticks at which SERVO was still busy, so the cycle start was not posted.
    ticks_not_posted: Atomic<u64>,
    /// ns since the epoch: the current cycle's timer expiry, the timer
    /// callback's actual run time, SERVO's start and end of its last cycle.
    expiry_ns: Atomic<i64>,
    tick_ns: Atomic<i64>,
    servo_start_ns: Atomic<i64>,
    servo_end_ns: Atomic<i64>,
}

/// The time stamps of the last cycle, as CLOCK records them.
pub(crate) struct CycleStamps {
    pub(crate) expiry_ns: i64,
    pub(crate) tick_ns: i64,
    pub(crate) servo_start_ns: i64,
    pub(crate) servo_end_ns: i64,
}

impl CycleClock {
    pub(crate) fn new() -> impl PinInit<Self> {
        pin_init!(Self {
            cycle_start <- Completion::new(),
            check_due <- Completion::new(),
            handshake: CycleHandshake::new(),
            ticks_not_posted: Atomic::new(0),
            expiry_ns: Atomic::new(0),
            tick_ns: Atomic::new(0),
            servo_start_ns: Atomic::new(0),
            servo_end_ns: Atomic::new(0),
        })
    }

    /// The cycle timer: stamp the cycle about to be posted.
    pub(crate) fn stamp_tick(&self, expiry_ns: i64, now_ns: i64) {
        self.expiry_ns.store(expiry_ns, Release);
        self.tick_ns.store(now_ns, Relaxed);
    }

    /// The cycle timer: SERVO was busy, the cycle start was not posted.
    pub(crate) fn count_not_posted(&self) {
        self.ticks_not_posted.add(1, Relaxed);
    }

    pub(crate) fn ticks_not_posted(&self) -> u64 {
        self.ticks_not_posted.load(Relaxed)
    }

    /// The current cycle's timer expiry (ns since the epoch).
    pub(crate) fn expiry_ns(&self) -> i64 {
        self.expiry_ns.load(Acquire)
    }

    /// How late the cycle timer's callback ran, ns.
    pub(crate) fn timer_late_ns(&self) -> i64 {
        self.tick_ns
            .load(Relaxed)
            .saturating_sub(self.expiry_ns.load(Relaxed))
    }

    /// SERVO: its cycle starts / ends (ns since the epoch).
    pub(crate) fn stamp_servo_start(&self, ns: i64) {
        self.servo_start_ns.store(ns, Release);
    }

    pub(crate) fn stamp_servo_end(&self, ns: i64) {
        self.servo_end_ns.store(ns, Release);
    }

    /// CLOCK: the stamps of the last cycle.
    pub(crate) fn stamps(&self) -> CycleStamps {
        CycleStamps {
            expiry_ns: self.expiry_ns.load(Acquire),
            tick_ns: self.tick_ns.load(Relaxed),
            servo_start_ns: self.servo_start_ns.load(Acquire),
            servo_end_ns: self.servo_end_ns.load(Acquire),
        }
    }
}
