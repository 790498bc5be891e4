//! The cycle handshake between the cycle timer, SERVO and CLOCK's
//! supervisor: which cycle is current, whether SERVO finished it, and which
//! path SERVO runs. Atomics only, no lock.
//!
//! # Protocol
//!
//! State: `tick` (cycles started, written by the timer), `working` (SERVO is
//! inside a cycle), `done_tick` (the tick of SERVO's last finished cycle),
//! `mode` (written by the supervisor), `waiting` (SERVO is at the barrier).
//!
//! 1. Timer, at the top of cycle `n` ([`CycleHandshake::top`]): `tick ← n`
//!    (Release). It then posts SERVO's cycle start only if
//!    [`CycleHandshake::servo_waiting`]: a SERVO still busy gets no cycle
//!    queued behind the current one.
//! 2. SERVO, woken ([`CycleHandshake::servo_begin`]): `working ← true`
//!    (SeqCst), then reads `tick` (SeqCst) and `mode`: this cycle is `tick`.
//! 3. SERVO, done ([`CycleHandshake::servo_end`]): `done_tick ← tick`, then
//!    `working ← false` (both Release, in that order). A SERVO that finds
//!    the mode `FailSafe` runs nothing and leaves ([`CycleHandshake::servo_leave`]:
//!    `working ← false`, the cycle is not marked done).
//! 4. Supervisor, at 3/4 of the period ([`CycleHandshake::check`]): reads
//!    `tick`, then `working` (Acquire), then `done_tick` (Acquire). SERVO
//!    finished the current cycle iff `!working && done_tick == tick`.
//!
//! Why this is sound: `done_tick == tick` alone could be a finished cycle
//! whose end has not been published in order; reading `working` first with
//! Acquire, after SERVO's Release of `working = false` that follows its
//! `done_tick` store, guarantees the `done_tick` read is at least that
//! cycle's. A SERVO that has not started the current cycle (late wake-up)
//! still shows the previous `done_tick`: a miss, as it should be. A SERVO
//! inside a cycle shows `working`: a miss. No outcome depends on a lock.
//!
//! The mode is a [`Mode`] end to end; it crosses the atomic as its `u8`
//! (`Mode::as_u8` / `Mode::from_u8`, unknown values read as `FailSafe`).

use core::sync::atomic::{AtomicBool, AtomicU64, AtomicU8, Ordering};

use super::mode::Mode;

/// The mode stored in the atomic as `v`; a byte no mode has reads as
/// `FailSafe` (the safe side).
const fn mode_of(v: u8) -> Mode {
    match Mode::from_u8(v) {
        Some(m) => m,
        None => Mode::FailSafe,
    }
}

/// The handshake state (see the module doc).
#[derive(Debug)]
pub struct CycleHandshake {
    tick: AtomicU64,
    working: AtomicBool,
    waiting: AtomicBool,
    done_tick: AtomicU64,
    mode: AtomicU8,
}

impl Default for CycleHandshake {
    fn default() -> Self {
        Self::new()
    }
}

/// What SERVO runs this cycle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CycleStart {
    pub tick: u64,
    pub mode: Mode,
}

/// The supervisor's view at its check.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CycleCheck {
    pub tick: u64,
    /// SERVO finished cycle `tick`.
    pub finished: bool,
    /// SERVO is inside a cycle now (for diagnostics).
    pub working: bool,
    pub done_tick: u64,
}

impl CycleHandshake {
    pub const fn new() -> Self {
        CycleHandshake {
            tick: AtomicU64::new(0),
            working: AtomicBool::new(false),
            waiting: AtomicBool::new(false),
            done_tick: AtomicU64::new(0),
            mode: AtomicU8::new(Mode::Main.as_u8()),
        }
    }

    /// Timer: a new cycle starts; its tick.
    pub fn top(&self) -> u64 {
        self.tick.fetch_add(1, Ordering::SeqCst).wrapping_add(1)
    }

    /// Timer: may the cycle start be posted (SERVO waits at the barrier)?
    pub fn servo_waiting(&self) -> bool {
        self.waiting.load(Ordering::SeqCst)
    }

    /// SERVO: at the barrier (`true`) or leaving it (`false`).
    pub fn set_servo_waiting(&self, w: bool) {
        self.waiting.store(w, Ordering::SeqCst);
    }

    /// SERVO: entering a cycle; which one, and in which mode.
    pub fn servo_begin(&self) -> CycleStart {
        self.working.store(true, Ordering::SeqCst);
        CycleStart {
            tick: self.tick.load(Ordering::SeqCst),
            mode: mode_of(self.mode.load(Ordering::Acquire)),
        }
    }

    /// SERVO: cycle `tick` is finished.
    pub fn servo_end(&self, tick: u64) {
        self.done_tick.store(tick, Ordering::Release);
        self.working.store(false, Ordering::Release);
    }

    /// SERVO: leaving without running the cycle it entered (the mode was
    /// `FailSafe`): no longer working, and that cycle is not marked done.
    pub fn servo_leave(&self) {
        self.working.store(false, Ordering::Release);
    }

    /// SERVO is inside a cycle now.
    pub fn servo_working(&self) -> bool {
        self.working.load(Ordering::Acquire)
    }

    /// Supervisor: did SERVO finish the current cycle?
    pub fn check(&self) -> CycleCheck {
        let tick = self.tick.load(Ordering::SeqCst);
        let working = self.working.load(Ordering::Acquire);
        let done_tick = self.done_tick.load(Ordering::Acquire);
        CycleCheck {
            tick,
            finished: !working && done_tick == tick,
            working,
            done_tick,
        }
    }

    /// Current tick.
    pub fn tick(&self) -> u64 {
        self.tick.load(Ordering::Acquire)
    }

    /// SERVO's last finished tick.
    pub fn done_tick(&self) -> u64 {
        self.done_tick.load(Ordering::Acquire)
    }

    /// Supervisor: the mode SERVO runs from its next cycle on.
    pub fn set_mode(&self, m: Mode) {
        self.mode.store(m.as_u8(), Ordering::Release);
    }

    pub fn mode(&self) -> Mode {
        mode_of(self.mode.load(Ordering::Acquire))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_finished_cycle_is_seen_finished() {
        let h = CycleHandshake::new();
        let t = h.top();
        let s = h.servo_begin();
        assert_eq!(s.tick, t);
        assert!(!h.check().finished, "inside the cycle");
        h.servo_end(s.tick);
        let c = h.check();
        assert!(c.finished && !c.working && c.done_tick == t);
    }

    #[test]
    fn a_late_or_overrunning_servo_is_a_miss() {
        let h = CycleHandshake::new();
        let t1 = h.top();
        let s = h.servo_begin();
        h.servo_end(s.tick);
        // Next cycle: SERVO has not woken yet at the check.
        let _t2 = h.top();
        assert!(!h.check().finished);
        // SERVO wakes late, overruns into the next check.
        let s2 = h.servo_begin();
        assert_eq!(s2.tick, t1 + 1);
        let _t3 = h.top();
        let c = h.check();
        assert!(!c.finished && c.working);
        // It finishes cycle 2 during cycle 3: still not cycle 3.
        h.servo_end(s2.tick);
        assert!(!h.check().finished);
    }

    #[test]
    fn modes_round_trip_and_fail_safe_is_not_degraded() {
        let h = CycleHandshake::new();
        assert_eq!(h.mode(), Mode::Main);
        for m in [Mode::Main, Mode::Degraded, Mode::FailSafe] {
            h.set_mode(m);
            assert_eq!(h.servo_begin().mode, m);
            assert_eq!(mode_of(m.as_u8()), m);
        }
        assert_eq!(mode_of(200), Mode::FailSafe);
    }

    #[test]
    fn leaving_is_not_finishing() {
        let h = CycleHandshake::new();
        let _ = h.top();
        let _ = h.servo_begin();
        h.servo_leave();
        let c = h.check();
        assert!(!c.working && !c.finished);
    }

    #[test]
    fn waiting_flag() {
        let h = CycleHandshake::new();
        assert!(!h.servo_waiting());
        h.set_servo_waiting(true);
        assert!(h.servo_waiting());
    }
}
