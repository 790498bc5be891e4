//! The bridge's counters, shared by the SERVER and CLIENT threads, and their
//! text form (`key: value` lines, the same shape as `/dev/hap_stats`).

use std::fmt::Write as _;
use std::sync::atomic::{AtomicU64, Ordering};

use crate::session::Reject;

/// All counters. Relaxed atomics: they are statistics, not synchronisation.
#[derive(Debug, Default)]
pub struct Counters {
    /// Datagrams received on the UDP socket (valid or not).
    pub received: AtomicU64,
    /// Frames written whole to the kernel's input device.
    pub forwarded: AtomicU64,
    pub rejected_oversize: AtomicU64,
    pub rejected_undersize: AtomicU64,
    pub rejected_malformed: AtomicU64,
    pub rejected_stray_source: AtomicU64,
    pub rejected_no_session: AtomicU64,
    /// write() to the input device failed or was short.
    pub write_errors: AtomicU64,
    /// Answer frames read from the kernel's output device.
    pub answers: AtomicU64,
    /// Answer frames sent to the client.
    pub sent: AtomicU64,
    /// Answers dropped because no session was open.
    pub answers_no_client: AtomicU64,
    pub send_errors: AtomicU64,
    pub sessions_opened: AtomicU64,
    pub sessions_closed: AtomicU64,
    pub sessions_expired: AtomicU64,
}

impl Counters {
    pub fn inc(c: &AtomicU64) {
        c.fetch_add(1, Ordering::Relaxed);
    }

    pub fn reject(&self, r: Reject) {
        Counters::inc(match r {
            Reject::Oversize => &self.rejected_oversize,
            Reject::Undersize => &self.rejected_undersize,
            Reject::Malformed => &self.rejected_malformed,
            Reject::StraySource => &self.rejected_stray_source,
            Reject::NoSession => &self.rejected_no_session,
        });
    }

    /// Total rejected datagrams, all reasons.
    pub fn rejected(&self) -> u64 {
        [
            &self.rejected_oversize,
            &self.rejected_undersize,
            &self.rejected_malformed,
            &self.rejected_stray_source,
            &self.rejected_no_session,
        ]
        .iter()
        .map(|c| c.load(Ordering::Relaxed))
        .sum()
    }

    /// `key: value` lines, one counter a line, plus the session's client.
    pub fn render(&self, client: Option<std::net::SocketAddr>) -> String {
        let l = |c: &AtomicU64| c.load(Ordering::Relaxed);
        let mut s = String::new();
        let rows: [(&str, u64); 16] = [
            ("received", l(&self.received)),
            ("forwarded", l(&self.forwarded)),
            ("rejected", self.rejected()),
            ("rejected_oversize", l(&self.rejected_oversize)),
            ("rejected_undersize", l(&self.rejected_undersize)),
            ("rejected_malformed", l(&self.rejected_malformed)),
            ("rejected_stray_source", l(&self.rejected_stray_source)),
            ("rejected_no_session", l(&self.rejected_no_session)),
            ("write_errors", l(&self.write_errors)),
            ("answers", l(&self.answers)),
            ("sent", l(&self.sent)),
            ("answers_no_client", l(&self.answers_no_client)),
            ("send_errors", l(&self.send_errors)),
            ("sessions_opened", l(&self.sessions_opened)),
            ("sessions_closed", l(&self.sessions_closed)),
            ("sessions_expired", l(&self.sessions_expired)),
        ];
        for (k, v) in rows {
            let _ = writeln!(s, "{k}: {v}");
        }
        match client {
            Some(c) => {
                let _ = writeln!(s, "client: {c}");
            }
            None => s.push_str("client: none\n"),
        }
        s
    }
}

/// Parse `key: value` lines into pairs (blank and malformed lines skipped).
pub fn parse_kv(text: &str) -> Vec<(String, String)> {
    hap_core::stats::key_values(text)
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn render_then_parse() {
        let c = Counters::default();
        Counters::inc(&c.received);
        c.reject(Reject::Oversize);
        c.reject(Reject::StraySource);
        let text = c.render(Some("127.0.0.1:9".parse().unwrap()));
        let kv = parse_kv(&text);
        let get = |k: &str| kv.iter().find(|(kk, _)| kk == k).map(|(_, v)| v.clone());
        assert_eq!(get("received").as_deref(), Some("1"));
        assert_eq!(get("rejected").as_deref(), Some("2"));
        assert_eq!(get("client").as_deref(), Some("127.0.0.1:9"));
    }
}
