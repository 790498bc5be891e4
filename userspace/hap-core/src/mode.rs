//! The modes of the cycle, in a leaf module that everything above may use:
//! [`ServoMode`], the path a servo step runs (the servo, the state model and
//! the controller read it). The supervisor's mode (`clock::Mode`, which adds
//! the fail-safe) and the position log's (`position_log::LogMode`, which
//! adds the fail-safe step records) name the same paths; [`ServoMode::of`]
//! and [`ServoMode::log_mode`] convert.

use super::clock::Mode;
use super::position_log::LogMode;

/// Which SERVO path runs this cycle.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ServoMode {
    /// Normal behaviour.
    #[default]
    Main,
    /// Auxiliary (degraded) behaviour after a deadline miss.
    Degraded,
}

impl ServoMode {
    /// The path SERVO runs in the supervisor's mode `m`; `None` in
    /// fail-safe, where SERVO runs nothing.
    pub const fn of(m: Mode) -> Option<ServoMode> {
        match m {
            Mode::Normal => Some(ServoMode::Main),
            Mode::Degraded => Some(ServoMode::Degraded),
            Mode::FailSafe => None,
        }
    }

    /// The mode a servo step's log record carries.
    pub const fn log_mode(self) -> LogMode {
        match self {
            ServoMode::Main => LogMode::Main,
            ServoMode::Degraded => LogMode::Degraded,
        }
    }
}
