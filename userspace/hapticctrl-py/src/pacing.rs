//! The periodic loop's bookkeeping, independent of Python: the link-loss
//! fade applied to the coupling wrench and the timing figures (achieved
//! period, jitter, lateness, work time per cycle).

use std::time::{Duration, Instant};

/// Scale of the coupling wrench given to the application: 1 while answers
/// arrive; once none has arrived for `timeout`, it falls linearly to 0 over
/// `fade` (a stale wrench is not applied for ever to the simulated object);
/// when answers come back it rises at the same rate (no step).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LinkFade {
    timeout: Duration,
    fade: Duration,
    level: f64,
}

impl LinkFade {
    pub fn new(timeout: Duration, fade: Duration) -> LinkFade {
        LinkFade {
            timeout,
            fade,
            level: 1.0,
        }
    }

    /// True when an answer arrived less than `timeout` ago.
    pub fn link_ok(&self, answer_age: Duration) -> bool {
        answer_age < self.timeout
    }

    /// Advance by `dt` given the age of the last answer; the new level.
    pub fn step(&mut self, dt: Duration, answer_age: Duration) -> f64 {
        let rate = if self.fade.is_zero() {
            f64::INFINITY
        } else {
            dt.as_secs_f64() / self.fade.as_secs_f64()
        };
        self.level = if self.link_ok(answer_age) {
            (self.level + rate).min(1.0)
        } else {
            (self.level - rate).max(0.0)
        };
        self.level
    }

    pub fn level(&self) -> f64 {
        self.level
    }
}

/// Timing of a periodic loop: one [`record`](Self::record) per cycle.
#[derive(Clone, Debug, Default)]
pub struct LoopTiming {
    pub cycles: u64,
    /// Wake-ups more than one period late (the missed periods skipped).
    pub overruns: u64,
    period_sum: f64,
    period_sq: f64,
    pub period_min_us: f64,
    pub period_max_us: f64,
    lateness_sum: f64,
    pub lateness_max_us: f64,
    work_sum: f64,
    pub work_max_us: f64,
    last_wake: Option<Instant>,
    /// Every period (µs) and work time (µs), when recording.
    pub trace: Option<(Vec<f32>, Vec<f32>)>,
}

impl LoopTiming {
    pub fn new(record: bool) -> LoopTiming {
        LoopTiming {
            trace: record.then(|| (Vec::new(), Vec::new())),
            ..Default::default()
        }
    }

    /// A cycle that woke at `wake` (due at `due`) and finished its work at
    /// `done`.
    pub fn record(&mut self, due: Instant, wake: Instant, done: Instant) {
        let late = wake.saturating_duration_since(due).as_secs_f64() * 1e6;
        let work = done.saturating_duration_since(wake).as_secs_f64() * 1e6;
        self.cycles += 1;
        self.lateness_sum += late;
        self.lateness_max_us = self.lateness_max_us.max(late);
        self.work_sum += work;
        self.work_max_us = self.work_max_us.max(work);
        let mut period = None;
        if let Some(prev) = self.last_wake {
            let p = wake.saturating_duration_since(prev).as_secs_f64() * 1e6;
            let n = self.cycles - 1;
            if n == 1 {
                self.period_min_us = p;
                self.period_max_us = p;
            }
            self.period_min_us = self.period_min_us.min(p);
            self.period_max_us = self.period_max_us.max(p);
            self.period_sum += p;
            self.period_sq += p * p;
            period = Some(p);
        }
        self.last_wake = Some(wake);
        if let (Some((ps, ws)), Some(p)) = (self.trace.as_mut(), period) {
            ps.push(p as f32);
            ws.push(work as f32);
        }
    }

    /// Periods measured (one fewer than the cycles).
    pub fn periods(&self) -> u64 {
        self.cycles.saturating_sub(1)
    }

    pub fn period_mean_us(&self) -> f64 {
        match self.periods() {
            0 => 0.0,
            n => self.period_sum / n as f64,
        }
    }

    /// Standard deviation of the period (the jitter), µs.
    pub fn period_std_us(&self) -> f64 {
        match self.periods() {
            0 => 0.0,
            n => {
                let m = self.period_mean_us();
                (self.period_sq / n as f64 - m * m).max(0.0).sqrt()
            }
        }
    }

    pub fn rate_hz(&self) -> f64 {
        let m = self.period_mean_us();
        if m > 0.0 {
            1e6 / m
        } else {
            0.0
        }
    }

    pub fn lateness_mean_us(&self) -> f64 {
        match self.cycles {
            0 => 0.0,
            n => self.lateness_sum / n as f64,
        }
    }

    pub fn work_mean_us(&self) -> f64 {
        match self.cycles {
            0 => 0.0,
            n => self.work_sum / n as f64,
        }
    }
}

/// The next deadline after `due` once a cycle ended at `now`: one period
/// later, or, if that is already past (an overrun), one period after `now`.
/// Returns it and whether periods were skipped.
pub fn next_due(due: Instant, period: Duration, now: Instant) -> (Instant, bool) {
    let next = due + period;
    if next <= now {
        (now + period, true)
    } else {
        (next, false)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_fade_falls_after_the_timeout_and_rises_back() {
        let ms = Duration::from_millis;
        let mut f = LinkFade::new(ms(50), ms(100));
        assert_eq!(f.step(ms(1), ms(10)), 1.0);
        assert_eq!(f.step(ms(1), ms(49)), 1.0);
        let mut levels = Vec::new();
        for i in 0..120 {
            levels.push(f.step(ms(1), ms(50 + i)));
        }
        assert!((levels[0] - 0.99).abs() < 1e-9);
        assert!((levels[49] - 0.5).abs() < 1e-9);
        assert_eq!(levels[99], 0.0);
        assert_eq!(*levels.last().unwrap(), 0.0);
        assert!(levels.windows(2).all(|w| w[1] <= w[0]));
        // Back: rises by dt/fade per step, not at once.
        assert!((f.step(ms(1), ms(0)) - 0.01).abs() < 1e-9);
        for _ in 0..200 {
            f.step(ms(1), ms(0));
        }
        assert_eq!(f.level(), 1.0);
        let mut now = LinkFade::new(ms(50), Duration::ZERO);
        assert_eq!(now.step(ms(1), ms(60)), 0.0);
    }

    #[test]
    fn timing_figures() {
        let t0 = Instant::now();
        let us = Duration::from_micros;
        let mut t = LoopTiming::new(true);
        // Wakes at 0, 1000, 2100, 2900 µs (due every 1000), work 10 µs.
        for (i, w) in [0u64, 1000, 2100, 2900].iter().enumerate() {
            let due = t0 + us(1000 * i as u64);
            let wake = t0 + us(*w);
            t.record(due, wake.max(due), wake.max(due) + us(10));
        }
        assert_eq!(t.cycles, 4);
        assert_eq!(t.periods(), 3);
        let (ps, ws) = t.trace.clone().unwrap();
        assert_eq!(ps, vec![1000.0, 1100.0, 900.0]);
        assert_eq!(ws.len(), 3);
        assert!((t.period_mean_us() - 1000.0).abs() < 1e-6);
        assert!((t.period_std_us() - (20000.0f64 / 3.0).sqrt()).abs() < 1e-6);
        assert_eq!(t.period_min_us, 900.0);
        assert_eq!(t.period_max_us, 1100.0);
        assert!((t.lateness_max_us - 100.0).abs() < 1e-6);
        assert!((t.work_mean_us() - 10.0).abs() < 1e-6);
        assert!((t.rate_hz() - 1000.0).abs() < 1e-6);
        let (n, skipped) = next_due(t0, us(1000), t0 + us(2500));
        assert!(skipped);
        assert_eq!(n, t0 + us(3500));
        assert_eq!(next_due(t0, us(1000), t0 + us(10)), (t0 + us(1000), false));
    }
}
