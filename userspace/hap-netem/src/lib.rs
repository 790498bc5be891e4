//! hap-netem: what the link emulator decides for each datagram, and how it
//! counts. The proxy binary (`src/main.rs`) moves the datagrams; this file
//! holds the decisions, so that they are tested without sockets.
//!
//! Each direction has its own [`Shaper`]: a pseudo-random stream seeded from
//! the run's seed and the direction, drawn a fixed number of times per
//! datagram in arrival order. The `n`-th datagram of a direction therefore
//! meets the same fate in every run with the same seed and settings,
//! whatever the other direction does and whenever it arrives.

use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::fmt::Write as _;

/// Which way a datagram travels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Direction {
    /// Client → bridge.
    ToServer,
    /// Bridge → client.
    ToClient,
}

impl Direction {
    pub const ALL: [Direction; 2] = [Direction::ToServer, Direction::ToClient];

    /// The name used in the statistics and the trace.
    pub fn name(self) -> &'static str {
        match self {
            Direction::ToServer => "to_server",
            Direction::ToClient => "to_client",
        }
    }

    fn seed_salt(self) -> u64 {
        match self {
            Direction::ToServer => 0x7365_7276_6572_2d3e,
            Direction::ToClient => 0x3c2d_636c_6965_6e74,
        }
    }
}

/// SplitMix64 (Steele, Lea, Flood 2014): a small, fast generator whose
/// output is equidistributed over 64 bits; enough for an emulator's draws.
#[derive(Clone, Debug)]
pub struct SplitMix64 {
    state: u64,
}

impl SplitMix64 {
    pub fn new(seed: u64) -> Self {
        SplitMix64 { state: seed }
    }

    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1) with 53 bits.
    pub fn next_unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// What one direction does to its datagrams.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Impairment {
    /// Mean one-way delay, µs.
    pub delay_us: u64,
    /// Jitter: each delay is uniform in `delay · (1 ± jitter_pct / 100)`.
    pub jitter_pct: f64,
    /// Probability that a datagram is dropped, %.
    pub loss_pct: f64,
    /// Probability that a forwarded datagram is sent twice, %; the copy
    /// gets its own delay draw.
    pub dup_pct: f64,
    /// Probability that a forwarded datagram skips the delay and leaves at
    /// once (`tc netem`'s `reorder`), %: it overtakes the ones in flight.
    pub reorder_pct: f64,
}

impl Default for Impairment {
    fn default() -> Self {
        Impairment {
            delay_us: 0,
            jitter_pct: 0.0,
            loss_pct: 0.0,
            dup_pct: 0.0,
            reorder_pct: 0.0,
        }
    }
}

/// The longest one-way delay accepted, µs (a minute).
pub const MAX_DELAY_US: u64 = 60_000_000;

impl Impairment {
    /// Checks the ranges: delay ≤ 60 s, every percentage in [0, 100].
    pub fn validate(&self) -> Result<(), String> {
        if self.delay_us > MAX_DELAY_US {
            return Err(format!(
                "delay {} ms: at most {} ms",
                self.delay_us as f64 / 1000.0,
                MAX_DELAY_US / 1000
            ));
        }
        for (name, v) in [
            ("jitter", self.jitter_pct),
            ("loss", self.loss_pct),
            ("duplication", self.dup_pct),
            ("reorder", self.reorder_pct),
        ] {
            if !(0.0..=100.0).contains(&v) {
                return Err(format!("{name} {v} %: must be within 0..=100"));
            }
        }
        Ok(())
    }
}

/// What happens to one datagram.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fate {
    Dropped,
    /// Forwarded after `delay_us`; with `copy_delay_us`, a duplicate too.
    Forwarded {
        delay_us: u64,
        copy_delay_us: Option<u64>,
    },
}

/// The decisions of one direction, from its own seeded stream.
#[derive(Clone, Debug)]
pub struct Shaper {
    imp: Impairment,
    rng: SplitMix64,
}

impl Shaper {
    pub fn new(imp: Impairment, seed: u64, dir: Direction) -> Self {
        Shaper {
            imp,
            rng: SplitMix64::new(seed ^ dir.seed_salt()),
        }
    }

    pub fn impairment(&self) -> &Impairment {
        &self.imp
    }

    fn draw_delay(&mut self) -> u64 {
        let u = self.rng.next_unit();
        let j = self.imp.jitter_pct / 100.0;
        let d = self.imp.delay_us as f64 * (1.0 + j * (2.0 * u - 1.0));
        d.round().max(0.0) as u64
    }

    /// The fate of the next datagram. Always five draws, whatever the
    /// outcome, so that datagram `n` meets the same fate for a seed.
    pub fn decide(&mut self) -> Fate {
        let lost = self.rng.next_unit() * 100.0 < self.imp.loss_pct;
        let reordered = self.rng.next_unit() * 100.0 < self.imp.reorder_pct;
        let delay = self.draw_delay();
        let dup = self.rng.next_unit() * 100.0 < self.imp.dup_pct;
        let copy_delay = self.draw_delay();
        if lost {
            return Fate::Dropped;
        }
        Fate::Forwarded {
            delay_us: if reordered { 0 } else { delay },
            copy_delay_us: dup.then_some(copy_delay),
        }
    }
}

/// One direction's counts. `received + duplicated = forwarded + dropped +
/// in_flight + send_errors` at every snapshot taken between two datagrams.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counters {
    /// Datagrams that arrived.
    pub received: u64,
    /// Datagrams sent on (duplicates included).
    pub forwarded: u64,
    /// Datagrams dropped by the loss draw.
    pub dropped: u64,
    /// Copies made by the duplication draw.
    pub duplicated: u64,
    /// Datagrams sent after one that arrived later than them.
    pub reordered: u64,
    /// Datagrams (and copies) waiting for their departure time.
    pub in_flight: u64,
    /// Sends the socket refused (counted, not retried).
    pub send_errors: u64,
    /// The latest a datagram left after its due time, µs (the host's
    /// scheduling; a figure, not part of the emulation).
    pub late_us_max: u64,
    /// Datagrams that left more than 1 ms after their due time.
    pub late_over_1ms: u64,
}

impl Counters {
    /// `received + duplicated == forwarded + dropped + in_flight + send_errors`.
    pub fn reconciles(&self) -> bool {
        self.received + self.duplicated
            == self.forwarded + self.dropped + self.in_flight + self.send_errors
    }

    /// `key: value` lines, each key prefixed with the direction's name.
    pub fn render(&self, dir: Direction, out: &mut String) {
        let p = dir.name();
        for (k, v) in [
            ("received", self.received),
            ("forwarded", self.forwarded),
            ("dropped", self.dropped),
            ("duplicated", self.duplicated),
            ("reordered", self.reordered),
            ("in_flight", self.in_flight),
            ("send_errors", self.send_errors),
            ("late_us_max", self.late_us_max),
            ("late_over_1ms", self.late_over_1ms),
        ] {
            let _ = writeln!(out, "{p}_{k}: {v}");
        }
    }
}

/// A datagram waiting for its departure, ordered by (due time, arrival
/// index, copy): equal due times leave in arrival order.
#[derive(Debug)]
pub struct Pending<T> {
    pub due_ns: u64,
    pub index: u64,
    pub copy: bool,
    pub arrival_ns: u64,
    pub item: T,
}

impl<T> Pending<T> {
    fn key(&self) -> (u64, u64, bool) {
        (self.due_ns, self.index, self.copy)
    }
}

impl<T> PartialEq for Pending<T> {
    fn eq(&self, o: &Self) -> bool {
        self.key() == o.key()
    }
}
impl<T> Eq for Pending<T> {}
impl<T> PartialOrd for Pending<T> {
    fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(o))
    }
}
impl<T> Ord for Pending<T> {
    fn cmp(&self, o: &Self) -> std::cmp::Ordering {
        self.key().cmp(&o.key())
    }
}

/// One direction: its shaper, its departure queue and its counters.
#[derive(Debug)]
pub struct Lane<T> {
    shaper: Shaper,
    queue: BinaryHeap<Reverse<Pending<T>>>,
    next_index: u64,
    /// Highest arrival index sent so far (reorder detection).
    max_sent_index: Option<u64>,
    pub counters: Counters,
}

impl<T: Clone> Lane<T> {
    pub fn new(shaper: Shaper) -> Self {
        Lane {
            shaper,
            queue: BinaryHeap::new(),
            next_index: 0,
            max_sent_index: None,
            counters: Counters::default(),
        }
    }

    /// A datagram arrived at `now_ns`: decide its fate and queue it (and
    /// its copy). Returns its arrival index and fate.
    pub fn arrive(&mut self, now_ns: u64, item: T) -> (u64, Fate) {
        let index = self.next_index;
        self.next_index += 1;
        self.counters.received += 1;
        let fate = self.shaper.decide();
        match fate {
            Fate::Dropped => self.counters.dropped += 1,
            Fate::Forwarded {
                delay_us,
                copy_delay_us,
            } => {
                if let Some(cd) = copy_delay_us {
                    self.counters.duplicated += 1;
                    self.push(now_ns, cd, index, true, item.clone());
                }
                self.push(now_ns, delay_us, index, false, item);
            }
        }
        (index, fate)
    }

    fn push(&mut self, now_ns: u64, delay_us: u64, index: u64, copy: bool, item: T) {
        self.counters.in_flight += 1;
        self.queue.push(Reverse(Pending {
            due_ns: now_ns.saturating_add(delay_us.saturating_mul(1000)),
            index,
            copy,
            arrival_ns: now_ns,
            item,
        }));
    }

    /// The earliest due time queued.
    pub fn next_due_ns(&self) -> Option<u64> {
        self.queue.peek().map(|p| p.0.due_ns)
    }

    /// The next datagram due at `now_ns`, if any. The caller sends it and
    /// reports with [`Lane::sent`].
    pub fn pop_due(&mut self, now_ns: u64) -> Option<Pending<T>> {
        if self.next_due_ns()? <= now_ns {
            self.queue.pop().map(|p| p.0)
        } else {
            None
        }
    }

    /// `p` was sent at `sent_ns` (`ok`: the socket took it).
    pub fn sent(&mut self, p: &Pending<T>, sent_ns: u64, ok: bool) {
        self.counters.in_flight -= 1;
        if !ok {
            self.counters.send_errors += 1;
            return;
        }
        self.counters.forwarded += 1;
        if !p.copy {
            match self.max_sent_index {
                Some(m) if p.index < m => self.counters.reordered += 1,
                Some(m) if p.index == m => {}
                _ => self.max_sent_index = Some(p.index),
            }
        }
        let late_us = sent_ns.saturating_sub(p.due_ns) / 1000;
        self.counters.late_us_max = self.counters.late_us_max.max(late_us);
        if late_us > 1000 {
            self.counters.late_over_1ms += 1;
        }
    }
}

/// One line of the trace (`--trace FILE`): a datagram's arrival index,
/// length and times (ns since the proxy started), and what became of it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TraceRecord {
    pub dir: Direction,
    pub index: u64,
    pub len: usize,
    pub arrival_ns: u64,
    pub event: TraceEvent,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TraceEvent {
    Dropped,
    /// Sent (`copy`: the duplicate) at `sent_ns`, due at `due_ns`.
    Sent {
        copy: bool,
        due_ns: u64,
        sent_ns: u64,
    },
    /// The socket refused it.
    SendError {
        copy: bool,
        due_ns: u64,
    },
}

/// The trace's first line.
pub const TRACE_HEADER: &str = "dir,index,len,arrival_ns,event,due_ns,sent_ns";

impl TraceRecord {
    pub fn to_line(&self) -> String {
        let (ev, due, sent) = match self.event {
            TraceEvent::Dropped => ("dropped", String::new(), String::new()),
            TraceEvent::Sent {
                copy,
                due_ns,
                sent_ns,
            } => (
                if copy { "sent_copy" } else { "sent" },
                due_ns.to_string(),
                sent_ns.to_string(),
            ),
            TraceEvent::SendError { copy, due_ns } => (
                if copy {
                    "send_error_copy"
                } else {
                    "send_error"
                },
                due_ns.to_string(),
                String::new(),
            ),
        };
        format!(
            "{},{},{},{},{ev},{due},{sent}",
            self.dir.name(),
            self.index,
            self.len,
            self.arrival_ns
        )
    }

    pub fn parse(line: &str) -> Result<Self, String> {
        let f: Vec<&str> = line.split(',').collect();
        if f.len() != 7 {
            return Err(format!("trace line {line:?}: 7 fields expected"));
        }
        let num = |s: &str| {
            s.parse::<u64>()
                .map_err(|e| format!("trace line {line:?}: {s:?}: {e}"))
        };
        let dir = match f[0] {
            "to_server" => Direction::ToServer,
            "to_client" => Direction::ToClient,
            d => return Err(format!("trace line {line:?}: direction {d:?}")),
        };
        let event = match f[4] {
            "dropped" => TraceEvent::Dropped,
            "sent" | "sent_copy" => TraceEvent::Sent {
                copy: f[4] == "sent_copy",
                due_ns: num(f[5])?,
                sent_ns: num(f[6])?,
            },
            "send_error" | "send_error_copy" => TraceEvent::SendError {
                copy: f[4] == "send_error_copy",
                due_ns: num(f[5])?,
            },
            e => return Err(format!("trace line {line:?}: event {e:?}")),
        };
        Ok(TraceRecord {
            dir,
            index: num(f[1])?,
            len: num(f[2])? as usize,
            arrival_ns: num(f[3])?,
            event,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn imp(delay_ms: u64, jitter: f64, loss: f64) -> Impairment {
        Impairment {
            delay_us: delay_ms * 1000,
            jitter_pct: jitter,
            loss_pct: loss,
            ..Default::default()
        }
    }

    #[test]
    fn same_seed_same_fates_other_seed_other_fates() {
        let i = imp(150, 50.0, 10.0);
        let run = |seed| {
            let mut s = Shaper::new(i, seed, Direction::ToServer);
            (0..1000).map(|_| s.decide()).collect::<Vec<_>>()
        };
        assert_eq!(run(7), run(7));
        assert_ne!(run(7), run(8));
        // The directions draw from different streams.
        let mut a = Shaper::new(i, 7, Direction::ToServer);
        let mut b = Shaper::new(i, 7, Direction::ToClient);
        let fa: Vec<_> = (0..100).map(|_| a.decide()).collect();
        let fb: Vec<_> = (0..100).map(|_| b.decide()).collect();
        assert_ne!(fa, fb);
    }

    #[test]
    fn delays_are_uniform_within_the_jitter_band() {
        // 150 ms ± 50 %: [75, 225] ms, mean 150, and each quarter of the
        // band holds a quarter of the draws (binomial, 6 sigma).
        let n = 100_000u64;
        let mut s = Shaper::new(imp(150, 50.0, 0.0), 1, Direction::ToServer);
        let mut sum = 0u64;
        let mut quarters = [0u64; 4];
        for _ in 0..n {
            let Fate::Forwarded { delay_us, .. } = s.decide() else {
                panic!("no loss asked")
            };
            assert!((75_000..=225_000).contains(&delay_us), "{delay_us}");
            sum += delay_us;
            quarters[(((delay_us - 75_000) * 4 / 150_001) as usize).min(3)] += 1;
        }
        let mean = sum as f64 / n as f64;
        // sd of the mean: 150 ms / sqrt(12 n) = 0.137 ms.
        assert!((mean - 150_000.0).abs() < 6.0 * 137.0, "mean {mean}");
        let sd = (n as f64 * 0.25 * 0.75).sqrt();
        for q in quarters {
            assert!((q as f64 - n as f64 / 4.0).abs() < 6.0 * sd, "{quarters:?}");
        }
    }

    #[test]
    fn no_jitter_is_the_exact_delay() {
        let mut s = Shaper::new(imp(20, 0.0, 0.0), 3, Direction::ToClient);
        for _ in 0..1000 {
            assert_eq!(
                s.decide(),
                Fate::Forwarded {
                    delay_us: 20_000,
                    copy_delay_us: None
                }
            );
        }
    }

    #[test]
    fn loss_rate_within_a_binomial_bound() {
        for (loss, seed) in [(10.0, 1u64), (20.0, 2), (1.0, 3)] {
            let n = 100_000u64;
            let mut s = Shaper::new(imp(0, 0.0, loss), seed, Direction::ToServer);
            let dropped = (0..n).filter(|_| s.decide() == Fate::Dropped).count() as f64;
            let p = loss / 100.0;
            let sd = (n as f64 * p * (1.0 - p)).sqrt();
            assert!(
                (dropped - n as f64 * p).abs() < 6.0 * sd,
                "{loss} %: {dropped} dropped"
            );
        }
        let mut none = Shaper::new(imp(0, 0.0, 0.0), 1, Direction::ToServer);
        assert!((0..10_000).all(|_| none.decide() != Fate::Dropped));
        let mut all = Shaper::new(imp(0, 0.0, 100.0), 1, Direction::ToServer);
        assert!((0..10_000).all(|_| all.decide() == Fate::Dropped));
    }

    #[test]
    fn lane_reorders_when_jitter_exceeds_the_gap_and_not_without() {
        // Datagrams 1 ms apart; 20 ms ± 50 % spreads them over 20 ms.
        let drain = |jitter: f64| {
            let mut lane = Lane::new(Shaper::new(imp(20, jitter, 0.0), 5, Direction::ToServer));
            let mut order = Vec::new();
            for i in 0..1000u64 {
                let now = i * 1_000_000;
                lane.arrive(now, i);
                while let Some(p) = lane.pop_due(now) {
                    lane.sent(&p, now, true);
                    order.push(p.item);
                }
            }
            while let Some(p) = lane.pop_due(u64::MAX) {
                lane.sent(&p, u64::MAX, true);
                order.push(p.item);
            }
            assert!(lane.counters.reconciles(), "{:?}", lane.counters);
            assert_eq!(lane.counters.forwarded, 1000);
            let inversions = order.windows(2).filter(|w| w[1] < w[0]).count() as u64;
            (lane.counters.reordered, inversions)
        };
        let (r, inv) = drain(50.0);
        assert!(r > 100, "reordered {r}");
        assert!(inv > 0);
        assert_eq!(drain(0.0), (0, 0));
    }

    #[test]
    fn explicit_reorder_overtakes_without_jitter() {
        let mut i = imp(20, 0.0, 0.0);
        i.reorder_pct = 25.0;
        let mut lane = Lane::new(Shaper::new(i, 9, Direction::ToServer));
        let mut overtook = 0;
        for k in 0..400u64 {
            let now = k * 1_000_000;
            let (_, fate) = lane.arrive(now, k);
            if fate
                == (Fate::Forwarded {
                    delay_us: 0,
                    copy_delay_us: None,
                })
            {
                overtook += 1;
            }
            while let Some(p) = lane.pop_due(now) {
                lane.sent(&p, now, true);
            }
        }
        assert!((50..=150).contains(&overtook), "{overtook}");
        assert!(lane.counters.reordered > 0);
    }

    #[test]
    fn duplicates_are_counted_and_reconcile() {
        let mut i = imp(5, 20.0, 10.0);
        i.dup_pct = 30.0;
        let mut lane = Lane::new(Shaper::new(i, 11, Direction::ToClient));
        for k in 0..2000u64 {
            lane.arrive(k * 100_000, k);
            assert!(lane.counters.reconciles());
        }
        let c = lane.counters;
        assert_eq!(c.in_flight, c.received - c.dropped + c.duplicated);
        assert!(c.duplicated > 300 && c.duplicated < 800, "{c:?}");
        while let Some(p) = lane.pop_due(u64::MAX) {
            lane.sent(&p, u64::MAX, true);
        }
        assert!(lane.counters.reconciles());
        assert_eq!(lane.counters.in_flight, 0);
    }

    #[test]
    fn lateness_is_counted_from_the_due_time() {
        let mut lane = Lane::new(Shaper::new(imp(10, 0.0, 0.0), 1, Direction::ToServer));
        lane.arrive(0, 0u8);
        lane.arrive(0, 1u8);
        assert!(lane.pop_due(9_999_999).is_none());
        let a = lane.pop_due(10_000_000).unwrap();
        lane.sent(&a, 10_500_000, true); // 0.5 ms late
        let b = lane.pop_due(u64::MAX).unwrap();
        lane.sent(&b, 13_000_000, true); // 3 ms late
        assert_eq!(lane.counters.late_us_max, 3000);
        assert_eq!(lane.counters.late_over_1ms, 1);
        assert_eq!(lane.counters.reordered, 0);
    }

    #[test]
    fn validation_refuses_out_of_range_settings() {
        assert!(imp(150, 50.0, 10.0).validate().is_ok());
        assert!(imp(60_001, 0.0, 0.0).validate().is_err());
        let mut i = imp(1, 0.0, 0.0);
        i.jitter_pct = 100.5;
        assert!(i.validate().unwrap_err().contains("jitter"));
        i.jitter_pct = 0.0;
        i.loss_pct = -1.0;
        assert!(i.validate().unwrap_err().contains("loss"));
        i.loss_pct = f64::NAN;
        assert!(i.validate().is_err());
    }

    #[test]
    fn trace_lines_round_trip() {
        for event in [
            TraceEvent::Dropped,
            TraceEvent::Sent {
                copy: true,
                due_ns: 5,
                sent_ns: 9,
            },
            TraceEvent::SendError {
                copy: false,
                due_ns: 3,
            },
        ] {
            let r = TraceRecord {
                dir: Direction::ToClient,
                index: 42,
                len: 88,
                arrival_ns: 1,
                event,
            };
            assert_eq!(TraceRecord::parse(&r.to_line()), Ok(r));
        }
        assert!(TraceRecord::parse("to_server,1,2,3,sent,4").is_err());
        assert!(TraceRecord::parse("sideways,1,2,3,dropped,,").is_err());
    }
}
