//! Budgets that bound what unauthenticated traffic costs the bridge.
//!
//! - [`RateLimit`]: refused datagrams per source **IP** (all its ports
//!   together): a source whose datagrams keep being refused gets a token
//!   bucket; once it is empty, that IP's datagrams are dropped before any
//!   tag is computed (counted as `rate_limited`), so a flood costs the
//!   bridge a hash-map lookup, not an HMAC. The exact address (IP and port)
//!   of the session's client is never dropped, so that its live session
//!   sees no gap, but what is refused from it is charged to its IP like
//!   anybody's (forgeries spoofing the client's other ports are limited).
//! - [`TokenBucket`]: the global budget of `open_session` datagrams per
//!   second (each costs two HMACs and a reply), whatever their source.
//!
//! Memory is bounded ([`MAX_SOURCES`] IPs) and never cleared wholesale:
//! when the table is full, IPs not in it share one overflow bucket, and
//! buckets that have refilled completely are swept out once a second.

use std::collections::HashMap;
use std::net::{IpAddr, SocketAddr};
use std::time::{Duration, Instant};

/// Source IPs tracked at most.
pub const MAX_SOURCES: usize = 4096;

/// How often refilled buckets are swept out of the table.
const SWEEP_EVERY: Duration = Duration::from_secs(1);

/// A token bucket: `per_s` tokens a second, at most `burst`.
#[derive(Clone, Copy, Debug)]
pub struct TokenBucket {
    tokens: f64,
    last: Instant,
    per_s: f64,
    burst: f64,
}

impl TokenBucket {
    /// `per_s` a second, bursts of `2 * per_s`, starting full; 0 disables.
    pub fn new(per_s: u32, now: Instant) -> TokenBucket {
        TokenBucket {
            tokens: 2.0 * f64::from(per_s),
            last: now,
            per_s: f64::from(per_s),
            burst: 2.0 * f64::from(per_s),
        }
    }

    fn refill(&mut self, now: Instant) {
        let dt = now.saturating_duration_since(self.last).as_secs_f64();
        self.tokens = (self.tokens + dt * self.per_s).min(self.burst);
        self.last = now;
    }

    /// Would a token be there at `now`? (Takes none.)
    pub fn has_token(&mut self, now: Instant) -> bool {
        if self.per_s <= 0.0 {
            return true;
        }
        self.refill(now);
        self.tokens >= 1.0
    }

    /// Take a token if there is one; false: the budget is spent.
    pub fn take(&mut self, now: Instant) -> bool {
        if !self.has_token(now) {
            return false;
        }
        if self.per_s > 0.0 {
            self.tokens -= 1.0;
        }
        true
    }

    /// Take a token if there is one, else nothing (a charge never fails).
    fn charge(&mut self, now: Instant) {
        if self.per_s > 0.0 {
            self.refill(now);
            self.tokens = (self.tokens - 1.0).max(0.0);
        }
    }

    fn full(&mut self, now: Instant) -> bool {
        self.refill(now);
        self.tokens >= self.burst
    }
}

/// Token buckets of refusals per source IP.
#[derive(Debug)]
pub struct RateLimit {
    per_s: u32,
    buckets: HashMap<IpAddr, TokenBucket>,
    /// Shared by the IPs that found the table full.
    overflow: TokenBucket,
    last_sweep: Instant,
}

impl RateLimit {
    /// `per_s` refusals per second and IP, bursts of `2 * per_s`; 0 disables.
    pub fn new(per_s: u32) -> RateLimit {
        let now = Instant::now();
        RateLimit {
            per_s,
            buckets: HashMap::new(),
            overflow: TokenBucket::new(per_s, now),
            last_sweep: now,
        }
    }

    /// IPs tracked now.
    pub fn tracked(&self) -> usize {
        self.buckets.len()
    }

    /// May a datagram from `src` be examined? False: drop it unexamined.
    pub fn allow(&mut self, src: SocketAddr, client: Option<SocketAddr>, now: Instant) -> bool {
        if self.per_s == 0 || client == Some(src) {
            return true;
        }
        let full = self.buckets.len() >= MAX_SOURCES;
        match self.buckets.get_mut(&src.ip()) {
            Some(b) => b.has_token(now),
            None if full => self.overflow.has_token(now),
            None => true,
        }
    }

    /// A datagram from `src` was refused: take a token from its IP.
    pub fn charge(&mut self, src: SocketAddr, now: Instant) {
        if self.per_s == 0 {
            return;
        }
        self.sweep(now);
        let ip = src.ip();
        if let Some(b) = self.buckets.get_mut(&ip) {
            b.charge(now);
        } else if self.buckets.len() < MAX_SOURCES {
            let mut b = TokenBucket::new(self.per_s, now);
            b.charge(now);
            self.buckets.insert(ip, b);
        } else {
            self.overflow.charge(now);
        }
    }

    /// Drop the buckets that have refilled completely (their IPs are back
    /// to a fresh budget anyway), at most once per [`SWEEP_EVERY`].
    fn sweep(&mut self, now: Instant) {
        if now.saturating_duration_since(self.last_sweep) < SWEEP_EVERY {
            return;
        }
        self.last_sweep = now;
        self.buckets.retain(|_, b| !b.full(now));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn a(ip: u8, port: u16) -> SocketAddr {
        SocketAddr::from(([10, 0, 0, ip], port))
    }

    #[test]
    fn a_refused_ip_runs_dry_on_every_port_but_the_clients_own_address() {
        let mut r = RateLimit::new(10);
        let t = Instant::now();
        let client = Some(a(1, 5000));
        for port in 0..20 {
            assert!(r.allow(a(1, 6000 + port), client, t));
            r.charge(a(1, 6000 + port), t);
        }
        assert!(!r.allow(a(1, 6000), client, t));
        assert!(!r.allow(a(1, 7000), client, t), "another port: the same IP");
        assert!(r.allow(a(1, 5000), client, t), "the client's own address");
        assert!(r.allow(a(2, 6000), client, t), "another IP");
        assert!(r.allow(a(1, 6000), client, t + Duration::from_millis(150)));
        // Disabled.
        let mut off = RateLimit::new(0);
        for _ in 0..100 {
            off.charge(a(3, 1), t);
        }
        assert!(off.allow(a(3, 1), None, t));
    }

    #[test]
    fn the_table_is_bounded_and_never_cleared_wholesale() {
        let mut r = RateLimit::new(1);
        let t = Instant::now();
        // A flooder empties its bucket.
        for _ in 0..3 {
            r.charge(a(9, 1), t);
        }
        assert!(!r.allow(a(9, 1), None, t));
        // Many other IPs fill the table: the flooder's bucket stays.
        for i in 0..(MAX_SOURCES as u32 + 10) {
            let ip = IpAddr::from((0x0b00_0000 + i).to_be_bytes());
            r.charge(SocketAddr::new(ip, 1), t);
            r.charge(SocketAddr::new(ip, 1), t);
        }
        assert!(r.tracked() <= MAX_SOURCES);
        assert!(!r.allow(a(9, 1), None, t), "still limited");
        // The IPs beyond the table share the overflow bucket, spent too.
        assert!(!r.allow(a(200, 1), None, t));
        // Refilled buckets are swept out; the table makes room again.
        let later = t + Duration::from_secs(10);
        r.charge(a(201, 1), later);
        assert!(r.tracked() < 10, "{}", r.tracked());
        assert!(r.allow(a(9, 1), None, later));
    }

    #[test]
    fn the_global_bucket_refills() {
        let t = Instant::now();
        let mut b = TokenBucket::new(5, t);
        let taken = (0..100).filter(|_| b.take(t)).count();
        assert_eq!(taken, 10, "a burst of twice the rate");
        assert!(!b.take(t));
        assert!(b.take(t + Duration::from_millis(250)));
        let mut off = TokenBucket::new(0, t);
        assert!((0..1000).all(|_| off.take(t)));
    }
}
