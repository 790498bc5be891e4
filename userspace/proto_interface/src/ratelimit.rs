//! Per-source budget for refused datagrams: a source address (IP and port)
//! whose datagrams keep being refused gets a token bucket; once it is empty,
//! that source's datagrams are dropped before any tag is computed (counted
//! as `rate_limited`), so a flood costs the bridge a hash-map lookup, not an
//! HMAC. Per address, not per IP: a client behind the same NAT as a flooder
//! (or, with QEMU's user network, every host process) opens its session from
//! a fresh port with a full budget. The session's client is never limited.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::time::Instant;

/// Sources tracked at most; beyond, the table is cleared (an attacker
/// cycling through addresses only resets the budgets, never grows memory).
pub const MAX_SOURCES: usize = 4096;

#[derive(Clone, Copy, Debug)]
struct Bucket {
    tokens: f64,
    last: Instant,
}

/// Token buckets of refusals per source address.
#[derive(Debug)]
pub struct RateLimit {
    per_s: f64,
    burst: f64,
    buckets: HashMap<SocketAddr, Bucket>,
}

impl RateLimit {
    /// `per_s` refusals per second, bursts of `2 * per_s`; 0 disables.
    pub fn new(per_s: u32) -> RateLimit {
        RateLimit {
            per_s: f64::from(per_s),
            burst: 2.0 * f64::from(per_s),
            buckets: HashMap::new(),
        }
    }

    fn refill(&self, b: &mut Bucket, now: Instant) {
        let dt = now.saturating_duration_since(b.last).as_secs_f64();
        b.tokens = (b.tokens + dt * self.per_s).min(self.burst);
        b.last = now;
    }

    /// May a datagram from `src` be examined? False: drop it unexamined.
    pub fn allow(&mut self, src: SocketAddr, client: Option<SocketAddr>, now: Instant) -> bool {
        if self.per_s <= 0.0 || client == Some(src) {
            return true;
        }
        let Some(mut b) = self.buckets.get(&src).copied() else {
            return true;
        };
        self.refill(&mut b, now);
        self.buckets.insert(src, b);
        b.tokens >= 1.0
    }

    /// A datagram from `src` was refused: take a token.
    pub fn charge(&mut self, src: SocketAddr, client: Option<SocketAddr>, now: Instant) {
        if self.per_s <= 0.0 || client == Some(src) {
            return;
        }
        if self.buckets.len() >= MAX_SOURCES && !self.buckets.contains_key(&src) {
            self.buckets.clear();
        }
        let burst = self.burst;
        let mut b = self.buckets.get(&src).copied().unwrap_or(Bucket {
            tokens: burst,
            last: now,
        });
        self.refill(&mut b, now);
        b.tokens = (b.tokens - 1.0).max(0.0);
        self.buckets.insert(src, b);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    fn a(ip: u8, port: u16) -> SocketAddr {
        SocketAddr::from(([10, 0, 0, ip], port))
    }

    #[test]
    fn a_refused_source_runs_dry_then_refills_and_the_client_is_exempt() {
        let mut r = RateLimit::new(10);
        let t = Instant::now();
        let client = Some(a(1, 5000));
        for _ in 0..20 {
            assert!(r.allow(a(1, 6000), client, t));
            r.charge(a(1, 6000), client, t);
        }
        assert!(!r.allow(a(1, 6000), client, t));
        assert!(
            r.allow(a(1, 7000), client, t),
            "another port: its own budget"
        );
        assert!(r.allow(a(1, 5000), client, t), "the client's own address");
        assert!(r.allow(a(2, 6000), client, t), "another source");
        assert!(r.allow(a(1, 6000), client, t + Duration::from_millis(150)));
        // Disabled.
        let mut off = RateLimit::new(0);
        for _ in 0..100 {
            off.charge(a(3, 1), None, t);
        }
        assert!(off.allow(a(3, 1), None, t));
    }

    #[test]
    fn the_table_is_bounded() {
        let mut r = RateLimit::new(1);
        let t = Instant::now();
        for i in 0..(MAX_SOURCES as u32 + 10) {
            let ip = std::net::IpAddr::from(i.to_be_bytes());
            r.charge(SocketAddr::new(ip, 1), None, t);
        }
        assert!(r.buckets.len() <= MAX_SOURCES);
    }
}
