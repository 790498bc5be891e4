//! Budgets that bound what traffic without the key costs the bridge, and
//! keep it from spending what the key holder needs.
//!
//! - [`RateLimit`]: refused datagrams per source **IP** (all its ports
//!   together). Every refused or dropped datagram is charged to its IP;
//!   once an IP's bucket is empty, its datagrams that would cost an HMAC
//!   are dropped before any tag is computed (counted as `rate_limited`, and
//!   charged too), so a flood costs the bridge a hash-map lookup. Not
//!   dropped: the exact address (IP and port) of the session's client, so
//!   that its live session sees no gap, and the client's handshake frames
//!   (`hap_auth::is_handshake`), which cost at most one HMAC to refute and
//!   which a key holder sharing the flooder's IP needs to get through.
//! - [`HandshakeBudget`]: cookies (the answer to a *verified*
//!   `open_session`; nothing without the key reaches it) per source IP,
//!   and from all sources together; IPs that answered a cookie lately (a
//!   proven `open_proof` came from them in the last [`PROVEN_FOR`]) are
//!   served first: they never wait on the global budget (cookie under
//!   load, as WireGuard serves the initiators that answered its cookie).
//!
//! Memory is bounded ([`MAX_SOURCES`] IPs per table) and never cleared
//! wholesale: when a table is full, IPs not in it share one overflow
//! bucket, and buckets that have refilled completely are swept out once a
//! second.

use std::collections::HashMap;
use std::net::{IpAddr, SocketAddr};
use std::time::{Duration, Instant};

use hap_auth::Refusal;

/// Source IPs tracked at most, per table.
pub const MAX_SOURCES: usize = 4096;

/// How long an IP that sent a proven `open_proof` is served first.
pub const PROVEN_FOR: Duration = Duration::from_secs(120);

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

/// A token bucket per IP, in a bounded table.
#[derive(Debug)]
struct BucketTable {
    per_s: u32,
    buckets: HashMap<IpAddr, TokenBucket>,
    /// Shared by the IPs that found the table full.
    overflow: TokenBucket,
    last_sweep: Instant,
}

impl BucketTable {
    fn new(per_s: u32, now: Instant) -> BucketTable {
        BucketTable {
            per_s,
            buckets: HashMap::new(),
            overflow: TokenBucket::new(per_s, now),
            last_sweep: now,
        }
    }

    fn has_token(&mut self, ip: IpAddr, now: Instant) -> bool {
        if self.per_s == 0 {
            return true;
        }
        let full = self.buckets.len() >= MAX_SOURCES;
        match self.buckets.get_mut(&ip) {
            Some(b) => b.has_token(now),
            None if full => self.overflow.has_token(now),
            None => true,
        }
    }

    /// The IP's bucket, made if there is room (else the overflow bucket).
    fn bucket(&mut self, ip: IpAddr, now: Instant) -> &mut TokenBucket {
        self.sweep(now);
        if !self.buckets.contains_key(&ip) && self.buckets.len() < MAX_SOURCES {
            self.buckets.insert(ip, TokenBucket::new(self.per_s, now));
        }
        match self.buckets.get_mut(&ip) {
            Some(b) => b,
            None => &mut self.overflow,
        }
    }

    fn take(&mut self, ip: IpAddr, now: Instant) -> bool {
        if self.per_s == 0 {
            return true;
        }
        self.bucket(ip, now).take(now)
    }

    fn charge(&mut self, ip: IpAddr, now: Instant) {
        if self.per_s == 0 {
            return;
        }
        self.bucket(ip, now).charge(now);
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

/// Token buckets of refusals per source IP.
#[derive(Debug)]
pub struct RateLimit {
    table: BucketTable,
}

impl RateLimit {
    /// `per_s` refusals per second and IP, bursts of `2 * per_s`; 0 disables.
    pub fn new(per_s: u32) -> RateLimit {
        RateLimit {
            table: BucketTable::new(per_s, Instant::now()),
        }
    }

    /// IPs tracked now.
    pub fn tracked(&self) -> usize {
        self.table.buckets.len()
    }

    /// May a datagram from `src` be examined? False: drop it unexamined
    /// (and charge it: [`RateLimit::charge`]). The session's client
    /// address always may.
    pub fn allow(&mut self, src: SocketAddr, client: Option<SocketAddr>, now: Instant) -> bool {
        client == Some(src) || self.table.has_token(src.ip(), now)
    }

    /// A datagram from `src` was refused or dropped: take a token from its IP.
    pub fn charge(&mut self, src: SocketAddr, now: Instant) {
        self.table.charge(src.ip(), now);
    }
}

/// What a verified `open_session` may cost: a cookie per IP and per
/// second, and all IPs together; IPs that proved the key lately first.
#[derive(Debug)]
pub struct HandshakeBudget {
    per_ip: BucketTable,
    global: TokenBucket,
    /// IPs a proven `open_proof` came from, and when (the newest).
    proven: HashMap<IpAddr, Instant>,
    last_sweep: Instant,
}

/// How a verified `open_session` is served.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Served {
    /// From the global budget.
    Normally,
    /// From its IP's own budget, its IP having answered a cookie lately;
    /// `under_load`: the global budget was spent at the time.
    First { under_load: bool },
}

impl HandshakeBudget {
    /// `per_ip` cookies per second and IP, `global` from all IPs together
    /// (bursts of twice each; 0 disables either).
    pub fn new(per_ip: u32, global: u32, now: Instant) -> HandshakeBudget {
        HandshakeBudget {
            per_ip: BucketTable::new(per_ip, now),
            global: TokenBucket::new(global, now),
            proven: HashMap::new(),
            last_sweep: now,
        }
    }

    /// Did `ip` send a proven `open_proof` in the last [`PROVEN_FOR`]?
    pub fn is_proven(&self, ip: IpAddr, now: Instant) -> bool {
        self.proven
            .get(&ip)
            .is_some_and(|t| now.saturating_duration_since(*t) < PROVEN_FOR)
    }

    /// May a verified `open_session` from `ip` be answered with a cookie?
    /// Takes the tokens it spends; the refusal otherwise (to count and to
    /// charge to the IP's refusal budget).
    pub fn allow_hello(&mut self, ip: IpAddr, now: Instant) -> Result<Served, Refusal> {
        if !self.per_ip.has_token(ip, now) {
            return Err(Refusal::HandshakeIpBudget);
        }
        let served = if self.is_proven(ip, now) {
            Served::First {
                under_load: !self.global.has_token(now),
            }
        } else if self.global.take(now) {
            Served::Normally
        } else {
            return Err(Refusal::HandshakeBudget);
        };
        self.per_ip.take(ip, now);
        Ok(served)
    }

    /// A proven `open_proof` came from `ip`: it is served first for
    /// [`PROVEN_FOR`]. Bounded: when [`MAX_SOURCES`] IPs are remembered,
    /// the one proven longest ago is forgotten.
    pub fn proven(&mut self, ip: IpAddr, now: Instant) {
        if now.saturating_duration_since(self.last_sweep) >= SWEEP_EVERY {
            self.last_sweep = now;
            self.proven
                .retain(|_, t| now.saturating_duration_since(*t) < PROVEN_FOR);
        }
        if !self.proven.contains_key(&ip) && self.proven.len() >= MAX_SOURCES {
            if let Some(oldest) = self.proven.iter().min_by_key(|(_, t)| **t).map(|(a, _)| *a) {
                self.proven.remove(&oldest);
            }
        }
        self.proven.insert(ip, now);
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
    fn a_dropped_datagram_charged_keeps_a_flooding_ip_dry() {
        // Charged drops (rate_limited ones included): an IP that keeps
        // sending faster than its budget never gets a token back while it
        // does; once it stops, it does.
        let mut r = RateLimit::new(100);
        let t0 = Instant::now();
        let mut allowed = Vec::new();
        for k in 0..2000u64 {
            // 10 000 datagrams a second, every one charged.
            let t = t0 + Duration::from_micros(100 * k);
            if r.allow(a(5, 1), None, t) {
                allowed.push(k);
            }
            r.charge(a(5, 1), t);
        }
        // The burst (200, and the 2 tokens refilled while it went), then
        // nothing for the 1.8 s the flood lasts.
        assert_eq!(allowed.len(), 202, "{allowed:?}");
        assert_eq!(allowed.last(), Some(&201));
        assert!(r.allow(a(5, 1), None, t0 + Duration::from_millis(250)));
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

    /// Verified open_sessions from many IPs spend the global budget; an IP
    /// that answered a cookie lately is still served (from its own
    /// budget), one that did not is not; each IP has its own ceiling.
    #[test]
    fn under_load_the_ips_that_answered_a_cookie_are_served_first() {
        let t = Instant::now();
        let mut h = HandshakeBudget::new(20, 500, t);
        let key_holder = IpAddr::from([10, 0, 0, 1]);
        let newcomer = IpAddr::from([10, 0, 0, 2]);
        h.proven(key_holder, t);
        // 64 IPs, 40 each (their bursts): 2560 > the global burst of 1000.
        let mut normal = 0;
        let mut refused = HashMap::<Refusal, u32>::new();
        for k in 0..40 {
            for ip in 0..64u8 {
                match h.allow_hello(IpAddr::from([192, 0, 2, ip]), t) {
                    Ok(Served::Normally) => normal += 1,
                    Ok(s) => panic!("{s:?}"),
                    Err(r) => *refused.entry(r).or_default() += 1,
                }
            }
            let _ = k;
        }
        assert_eq!(normal, 1000);
        assert_eq!(refused[&Refusal::HandshakeBudget], 2560 - 1000);
        // Under load: the key holder's IP is served, the newcomer is not.
        assert_eq!(
            h.allow_hello(key_holder, t),
            Ok(Served::First { under_load: true })
        );
        assert_eq!(h.allow_hello(newcomer, t), Err(Refusal::HandshakeBudget));
        // Its own ceiling: 40 in a burst, then 20 a second.
        let served = (0..100)
            .filter(|_| h.allow_hello(key_holder, t).is_ok())
            .count();
        assert_eq!(served, 39);
        assert_eq!(
            h.allow_hello(key_holder, t),
            Err(Refusal::HandshakeIpBudget)
        );
        assert!(h
            .allow_hello(key_holder, t + Duration::from_millis(60))
            .is_ok());
        // Proven only for a while.
        let later = t + PROVEN_FOR;
        assert!(!h.is_proven(key_holder, later));
        // The table of proven IPs is bounded.
        for i in 0..(MAX_SOURCES as u32 + 5) {
            h.proven(IpAddr::from((0x0c00_0000 + i).to_be_bytes()), t);
        }
        assert!(h.proven.len() <= MAX_SOURCES);
        // Disabled budgets serve everything.
        let mut off = HandshakeBudget::new(0, 0, t);
        assert!((0..5000).all(|_| off.allow_hello(newcomer, t).is_ok()));
    }
}
