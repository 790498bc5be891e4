//! The controller's mode, one enum for every place that names it, in a leaf
//! module that everything above may use: the supervisor's verdict and the
//! cycle handshake (`clock`, `handshake`), the path a servo step runs
//! (`servo`, `state_model`, `cycle`), and the position log's record
//! (`position_log`). Its byte ([`Mode::as_u8`]) is the same in the
//! handshake's atomic and in the log's record.

/// The controller's mode: which SERVO path runs, or the fail-safe.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Mode {
    /// SERVO's main path.
    #[default]
    Main,
    /// SERVO's auxiliary (degraded) path after a deadline miss (spec §3.5,
    /// OCERA FT).
    Degraded,
    /// Fail-safe engaged: everything is being shut down. SERVO steps no
    /// more (the supervisor starts no cycle in it); in the position log, a
    /// record written by a fail-safe step.
    FailSafe,
}

impl Mode {
    /// The name the position log's readers print (`hapctl simlog` CSV).
    pub const fn name(self) -> &'static str {
        match self {
            Mode::Main => "main",
            Mode::Degraded => "degraded",
            Mode::FailSafe => "fail_safe",
        }
    }

    /// The word `/dev/hap_stats` prints on its `mode:` line: `normal` for
    /// the main path (the statistics' word since the first release).
    pub const fn stats_word(self) -> &'static str {
        match self {
            Mode::Main => "normal",
            Mode::Degraded => "degraded",
            Mode::FailSafe => "fail_safe",
        }
    }

    /// The mode's byte, in the cycle handshake's atomic and in the log
    /// record; [`Mode::from_u8`] is its inverse.
    pub const fn as_u8(self) -> u8 {
        match self {
            Mode::Main => 0,
            Mode::Degraded => 1,
            Mode::FailSafe => 2,
        }
    }

    /// The mode stored as `v`; `None` for a byte no mode has.
    pub const fn from_u8(v: u8) -> Option<Mode> {
        match v {
            0 => Some(Mode::Main),
            1 => Some(Mode::Degraded),
            2 => Some(Mode::FailSafe),
            _ => None,
        }
    }

    /// The path a servo step runs in this mode: the main path in `Main`,
    /// the degraded (cautious) one otherwise. The supervisor starts no
    /// cycle in `FailSafe`; a step asked in it anyway runs the degraded
    /// path, and its record says so.
    pub const fn servo_path(self) -> Mode {
        match self {
            Mode::Main => Mode::Main,
            Mode::Degraded | Mode::FailSafe => Mode::Degraded,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::Mode;

    #[test]
    fn the_byte_round_trips_and_unknown_bytes_are_refused() {
        for m in [Mode::Main, Mode::Degraded, Mode::FailSafe] {
            assert_eq!(Mode::from_u8(m.as_u8()), Some(m));
        }
        for v in 3..=u8::MAX {
            assert_eq!(Mode::from_u8(v), None);
        }
        // The wire values the log format and the handshake document.
        assert_eq!(
            [Mode::Main, Mode::Degraded, Mode::FailSafe].map(Mode::as_u8),
            [0, 1, 2]
        );
    }

    #[test]
    fn a_servo_step_runs_main_or_degraded() {
        assert_eq!(Mode::Main.servo_path(), Mode::Main);
        assert_eq!(Mode::Degraded.servo_path(), Mode::Degraded);
        assert_eq!(Mode::FailSafe.servo_path(), Mode::Degraded);
    }

    #[test]
    fn the_names() {
        assert_eq!(Mode::Main.name(), "main");
        assert_eq!(Mode::Main.stats_word(), "normal");
        assert_eq!(Mode::FailSafe.stats_word(), Mode::FailSafe.name());
    }
}
