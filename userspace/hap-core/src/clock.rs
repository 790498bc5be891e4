//! CLOCK's decision logic (spec §3.4, §3.5) as a pure state machine.
//!
//! Each period the kernel's CLOCK task wakes SERVO, sleeps until
//! [`check_offset_ns`] (3/4 of the period) and calls
//! [`Supervisor::check`] with whether SERVO (main or auxiliary) had not
//! finished that tick's cycle by then (the cycle handshake's check): a
//! missed deadline.
//!
//! - A miss increments the consecutive-miss counter and puts SERVO in
//!   [`Mode::Degraded`] (its auxiliary path) from the next cycle.
//! - A good cycle resets the counter. Degraded mode is left after
//!   [`DEGRADED_EXIT_GOOD_CYCLES`] consecutive good cycles.
//! - Exactly the [`MISS_LIMIT`]-th (5th) consecutive miss, or a stop request
//!   (`servo_stop`), gives [`Verdict::FailSafe`]: the kernel then executes
//!   [`FAIL_SAFE_SEQUENCE`] in order. Fail-safe is latched.

use super::mode::Mode;

/// Consecutive misses that trigger fail-safe (spec §3.4: "miss_count less
/// than 5" keeps looping).
pub const MISS_LIMIT: u32 = 5;

/// Consecutive good cycles after the last miss before SERVO leaves its
/// auxiliary (degraded) path: 100 cycles = 100 ms at the default 1 kHz.
pub const DEGRADED_EXIT_GOOD_CYCLES: u32 = 100;

/// Shortest accepted servo period, µs (10 kHz).
pub const PERIOD_MIN_US: u32 = 100;
/// Longest accepted servo period, µs (100 Hz).
pub const PERIOD_MAX_US: u32 = 10_000;
/// The spec's period, µs (1 kHz).
pub const DEFAULT_PERIOD_US: u32 = 1_000;

/// Why a period parameter was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PeriodError {
    /// Below `PERIOD_MIN_US`.
    TooShort,
    /// Above `PERIOD_MAX_US`.
    TooLong,
}

/// Accept a servo period in `PERIOD_MIN_US..=PERIOD_MAX_US` µs.
pub const fn validate_period_us(period_us: u32) -> Result<u32, PeriodError> {
    if period_us < PERIOD_MIN_US {
        Err(PeriodError::TooShort)
    } else if period_us > PERIOD_MAX_US {
        Err(PeriodError::TooLong)
    } else {
        Ok(period_us)
    }
}

/// Period in ns (exact; saturating for absurd inputs).
pub const fn period_ns(period_us: u32) -> u64 {
    (period_us as u64).saturating_mul(1_000)
}

/// Offset of the deadline check after the period start: 3/4 of the
/// period, in ns (exact: `period_us · 750`).
pub const fn check_offset_ns(period_us: u32) -> u64 {
    (period_us as u64).saturating_mul(750)
}

/// The same offset in µs, rounded down (750 µs for 1 ms).
pub const fn check_offset_us(period_us: u32) -> u32 {
    ((period_us as u64).saturating_mul(3) / 4) as u32
}

/// Why fail-safe was engaged.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FailSafeCause {
    /// `MISS_LIMIT` consecutive deadline misses.
    MissLimit,
    /// Termination requested (`servo_stop`).
    StopRequested,
}

impl FailSafeCause {
    pub const fn name(self) -> &'static str {
        match self {
            FailSafeCause::MissLimit => "miss_limit",
            FailSafeCause::StopRequested => "stop_requested",
        }
    }
}

/// Result of one check.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    /// SERVO finished in time; `mode` is the path for the next cycle.
    Good { mode: Mode },
    /// SERVO was still working at 3/4 period; `consecutive` (1..MISS_LIMIT)
    /// misses in a row so far. The next cycle runs degraded.
    Miss { consecutive: u32 },
    /// Execute `FAIL_SAFE_SEQUENCE` (returned again on every later check).
    FailSafe(FailSafeCause),
}

/// One step of the fail-safe shutdown, in `FAIL_SAFE_SEQUENCE` order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FailSafeAction {
    /// Zero and inhibit motor commands.
    InhibitMotorCommands,
    /// Power off the (simulated) arm supply.
    PowerOffArm,
    /// Close the protocol (no more frames in or out).
    CloseProtocol,
    /// Stop SERVO, PROTO_IN and CLOCK.
    StopTasks,
    /// Release FIFOs, buffers, devices.
    ReleaseResources,
}

impl FailSafeAction {
    /// Name for dmesg.
    pub const fn name(self) -> &'static str {
        match self {
            FailSafeAction::InhibitMotorCommands => "inhibit_motor_commands",
            FailSafeAction::PowerOffArm => "power_off_arm",
            FailSafeAction::CloseProtocol => "close_protocol",
            FailSafeAction::StopTasks => "stop_tasks",
            FailSafeAction::ReleaseResources => "release_resources",
        }
    }
}

/// The fail-safe actions, in the order the kernel must execute them
/// (spec §3.4: inhibit motor commands, power off the robot supply, then
/// the termination function).
pub const FAIL_SAFE_SEQUENCE: [FailSafeAction; 5] = [
    FailSafeAction::InhibitMotorCommands,
    FailSafeAction::PowerOffArm,
    FailSafeAction::CloseProtocol,
    FailSafeAction::StopTasks,
    FailSafeAction::ReleaseResources,
];

/// CLOCK's supervisor state.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Supervisor {
    miss_count: u32,
    good_streak: u32,
    mode: Mode,
    stop_requested: bool,
    cause: Option<FailSafeCause>,
    max_consecutive: u32,
    total_misses: u64,
    degraded_cycles: u64,
    checks: u64,
}

impl Supervisor {
    pub const fn new() -> Self {
        Supervisor {
            miss_count: 0,
            good_streak: 0,
            mode: Mode::Main,
            stop_requested: false,
            cause: None,
            max_consecutive: 0,
            total_misses: 0,
            degraded_cycles: 0,
            checks: 0,
        }
    }

    /// `servo_stop` was set: the next check returns fail-safe.
    pub fn request_stop(&mut self) {
        self.stop_requested = true;
    }

    /// The 3/4-period check. `missed`: SERVO had not finished this tick's
    /// cycle at the check (`CycleHandshake::check`'s `finished` is false).
    pub fn check(&mut self, missed: bool) -> Verdict {
        if let Some(cause) = self.cause {
            return Verdict::FailSafe(cause);
        }
        self.checks = self.checks.saturating_add(1);
        if self.mode == Mode::Degraded {
            self.degraded_cycles = self.degraded_cycles.saturating_add(1);
        }
        let verdict = if missed {
            self.miss_count = self.miss_count.saturating_add(1);
            self.total_misses = self.total_misses.saturating_add(1);
            if self.miss_count > self.max_consecutive {
                self.max_consecutive = self.miss_count;
            }
            self.good_streak = 0;
            self.mode = Mode::Degraded;
            if self.miss_count >= MISS_LIMIT {
                return self.engage(FailSafeCause::MissLimit);
            }
            Verdict::Miss {
                consecutive: self.miss_count,
            }
        } else {
            self.miss_count = 0;
            if self.mode == Mode::Degraded {
                self.good_streak = self.good_streak.saturating_add(1);
                if self.good_streak >= DEGRADED_EXIT_GOOD_CYCLES {
                    self.mode = Mode::Main;
                    self.good_streak = 0;
                }
            }
            Verdict::Good { mode: self.mode }
        };
        if self.stop_requested {
            return self.engage(FailSafeCause::StopRequested);
        }
        verdict
    }

    fn engage(&mut self, cause: FailSafeCause) -> Verdict {
        self.cause = Some(cause);
        self.mode = Mode::FailSafe;
        Verdict::FailSafe(cause)
    }

    /// The SERVO path for the current cycle.
    pub const fn mode(&self) -> Mode {
        self.mode
    }

    /// Misses in a row right now.
    pub const fn consecutive_misses(&self) -> u32 {
        self.miss_count
    }

    /// Longest run of consecutive misses seen.
    pub const fn max_consecutive_misses(&self) -> u32 {
        self.max_consecutive
    }

    /// All misses seen.
    pub const fn total_misses(&self) -> u64 {
        self.total_misses
    }

    /// Checks made while in degraded mode.
    pub const fn degraded_cycles(&self) -> u64 {
        self.degraded_cycles
    }

    /// Checks made (before fail-safe).
    pub const fn checks(&self) -> u64 {
        self.checks
    }

    /// `Some` once fail-safe is engaged.
    pub const fn fail_safe_cause(&self) -> Option<FailSafeCause> {
        self.cause
    }

    pub const fn stop_requested(&self) -> bool {
        self.stop_requested
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn four_misses_then_hit_recovers() {
        let mut s = Supervisor::new();
        for i in 1..=4 {
            assert_eq!(s.check(true), Verdict::Miss { consecutive: i });
        }
        assert_eq!(
            s.check(false),
            Verdict::Good {
                mode: Mode::Degraded
            }
        );
        assert_eq!(s.consecutive_misses(), 0);
        // Another 4 misses still do not trip it.
        for i in 1..=4 {
            assert_eq!(s.check(true), Verdict::Miss { consecutive: i });
        }
        assert_eq!(
            s.check(false),
            Verdict::Good {
                mode: Mode::Degraded
            }
        );
        assert_eq!(s.fail_safe_cause(), None);
        assert_eq!(s.max_consecutive_misses(), 4);
    }

    #[test]
    fn exactly_fifth_miss_fails_safe_and_latches() {
        let mut s = Supervisor::new();
        for _ in 0..10 {
            assert!(matches!(s.check(false), Verdict::Good { .. }));
        }
        for i in 1..MISS_LIMIT {
            assert_eq!(s.check(true), Verdict::Miss { consecutive: i });
        }
        assert_eq!(s.check(true), Verdict::FailSafe(FailSafeCause::MissLimit));
        assert_eq!(s.mode(), Mode::FailSafe);
        assert_eq!(s.check(false), Verdict::FailSafe(FailSafeCause::MissLimit));
        assert_eq!(MISS_LIMIT, 5);
    }

    #[test]
    fn stop_request() {
        let mut s = Supervisor::new();
        s.check(false);
        s.request_stop();
        assert_eq!(
            s.check(false),
            Verdict::FailSafe(FailSafeCause::StopRequested)
        );
        assert_eq!(
            s.check(true),
            Verdict::FailSafe(FailSafeCause::StopRequested)
        );
    }

    #[test]
    fn degraded_entry_and_exit() {
        let mut s = Supervisor::new();
        assert_eq!(s.mode(), Mode::Main);
        s.check(true);
        assert_eq!(s.mode(), Mode::Degraded);
        for _ in 0..DEGRADED_EXIT_GOOD_CYCLES - 1 {
            assert_eq!(
                s.check(false),
                Verdict::Good {
                    mode: Mode::Degraded
                }
            );
        }
        assert_eq!(s.check(false), Verdict::Good { mode: Mode::Main });
        // A miss in the middle of recovery restarts the count.
        s.check(true);
        for _ in 0..50 {
            s.check(false);
        }
        s.check(true);
        for _ in 0..DEGRADED_EXIT_GOOD_CYCLES - 1 {
            s.check(false);
        }
        assert_eq!(s.mode(), Mode::Degraded);
        s.check(false);
        assert_eq!(s.mode(), Mode::Main);
    }

    #[test]
    fn sequence_order_and_names() {
        let names: [&str; 5] = FAIL_SAFE_SEQUENCE.map(FailSafeAction::name);
        assert_eq!(
            names,
            [
                "inhibit_motor_commands",
                "power_off_arm",
                "close_protocol",
                "stop_tasks",
                "release_resources"
            ]
        );
    }

    #[test]
    fn period_validation_and_offset() {
        assert_eq!(validate_period_us(99), Err(PeriodError::TooShort));
        assert_eq!(validate_period_us(100), Ok(100));
        assert_eq!(validate_period_us(250), Ok(250));
        assert_eq!(validate_period_us(10_000), Ok(10_000));
        assert_eq!(validate_period_us(10_001), Err(PeriodError::TooLong));
        assert_eq!(check_offset_ns(1000), 750_000);
        assert_eq!(check_offset_us(1000), 750);
        assert_eq!(check_offset_ns(250), 187_500);
        assert_eq!(check_offset_us(u32::MAX), (u32::MAX as u64 * 3 / 4) as u32);
    }
}
