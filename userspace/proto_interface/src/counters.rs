//! The bridge's counters, shared by the SERVER and CLIENT threads, and their
//! text form (`key: value` lines, the same shape as `/dev/hap_stats`).

use std::fmt::Write as _;
use std::sync::atomic::{AtomicU64, Ordering};

use hap_auth::Refusal;

/// All counters. Relaxed atomics: they are statistics, not synchronisation.
#[derive(Debug, Default)]
pub struct Counters {
    /// 1 when the bridge runs unauthenticated v1 (`--insecure`).
    pub insecure: AtomicU64,
    /// Datagrams received on the UDP socket (valid or not).
    pub received: AtomicU64,
    /// Datagrams whose tag verified (v2).
    pub verified: AtomicU64,
    /// Unauthenticated v1 frames forwarded (`--insecure` only).
    pub insecure_frames: AtomicU64,
    /// Frames written whole to the kernel's input device.
    pub forwarded: AtomicU64,
    /// Refused datagrams, by reason (`hap_auth::Refusal`).
    pub refused: [AtomicU64; Refusal::COUNT],
    /// Replayed acknowledged requests answered with their ack again.
    pub retransmits_reacked: AtomicU64,
    /// Authenticated refusals sent (handshake refused, malformed request).
    pub refusals_answered: AtomicU64,
    /// write() to the input device failed or was short.
    pub write_errors: AtomicU64,
    /// Answer frames read from the kernel's output device.
    pub answers: AtomicU64,
    /// Answer frames sent to the client.
    pub sent: AtomicU64,
    /// Answers dropped because no session was open.
    pub answers_no_client: AtomicU64,
    /// Kernel frames that could not be sealed (no session keys).
    pub answers_unsealed: AtomicU64,
    pub send_errors: AtomicU64,
    /// Sessions opened: every open_session forwarded to the kernel (the
    /// module's `sessions_opened` counts the same).
    pub sessions_opened: AtomicU64,
    pub sessions_closed: AtomicU64,
    pub sessions_expired: AtomicU64,
    /// Sessions the bridge ended itself (expired, sequence numbers spent),
    /// each closed in the module and its client told why.
    pub sessions_ended_by_bridge: AtomicU64,
    /// `close_session` frames the bridge wrote to the module itself.
    pub kernel_closes: AtomicU64,
    /// `cookie` answers sent, and their bytes (v2 handshakes, first round).
    pub cookies_sent: AtomicU64,
    pub cookie_bytes: AtomicU64,
    /// Cookies sent while the global handshake budget was spent, to IPs
    /// that answered a cookie lately (served first).
    pub cookies_under_load: AtomicU64,
    /// Copies of the live session's `open_proof` answered with its
    /// `session_ack` again (the client's retransmission).
    pub proofs_reacked: AtomicU64,
    /// Answers not sent because they exceeded 3x the datagram they answer
    /// (the anti-amplification rule; 0 unless a frame size changes).
    pub amplification_refused: AtomicU64,
    /// The SERVER thread left SCHED_FIFO for SCHED_OTHER: a budget window
    /// in which it used more than its share of the CPU (`rtbudget`).
    pub rt_demotions: AtomicU64,
    /// ... and came back to SCHED_FIFO after a window within its share.
    pub rt_restores: AtomicU64,
    /// A change of policy the kernel refused.
    pub rt_policy_errors: AtomicU64,
    /// 1 while the SERVER thread runs demoted (SCHED_OTHER).
    pub server_demoted: AtomicU64,
}

impl Counters {
    pub fn inc(c: &AtomicU64) {
        c.fetch_add(1, Ordering::Relaxed);
    }

    pub fn refuse(&self, r: Refusal) {
        if let Some(c) = self.refused.get(r.index()) {
            Counters::inc(c);
        }
    }

    pub fn refused_by(&self, r: Refusal) -> u64 {
        self.refused
            .get(r.index())
            .map_or(0, |c| c.load(Ordering::Relaxed))
    }

    /// Total refused datagrams, all reasons.
    pub fn rejected(&self) -> u64 {
        self.refused.iter().map(|c| c.load(Ordering::Relaxed)).sum()
    }

    /// `key: value` lines, one counter a line, plus the session's client.
    pub fn render(&self, client: Option<std::net::SocketAddr>) -> String {
        let l = |c: &AtomicU64| c.load(Ordering::Relaxed);
        let mut s = String::new();
        let mut row = |k: &str, v: u64| {
            let _ = writeln!(s, "{k}: {v}");
        };
        row("insecure", l(&self.insecure));
        row("received", l(&self.received));
        row("verified", l(&self.verified));
        row("insecure_frames", l(&self.insecure_frames));
        row("forwarded", l(&self.forwarded));
        row("rejected", self.rejected());
        for r in Refusal::ALL {
            row(&format!("rejected_{}", r.name()), self.refused_by(r));
        }
        row("retransmits_reacked", l(&self.retransmits_reacked));
        row("refusals_answered", l(&self.refusals_answered));
        row("write_errors", l(&self.write_errors));
        row("answers", l(&self.answers));
        row("sent", l(&self.sent));
        row("answers_no_client", l(&self.answers_no_client));
        row("answers_unsealed", l(&self.answers_unsealed));
        row("send_errors", l(&self.send_errors));
        row("sessions_opened", l(&self.sessions_opened));
        row("sessions_closed", l(&self.sessions_closed));
        row("sessions_expired", l(&self.sessions_expired));
        row(
            "sessions_ended_by_bridge",
            l(&self.sessions_ended_by_bridge),
        );
        row("kernel_closes", l(&self.kernel_closes));
        row("cookies_sent", l(&self.cookies_sent));
        row("cookie_bytes", l(&self.cookie_bytes));
        row("cookies_under_load", l(&self.cookies_under_load));
        row("proofs_reacked", l(&self.proofs_reacked));
        row("amplification_refused", l(&self.amplification_refused));
        row("rt_demotions", l(&self.rt_demotions));
        row("rt_restores", l(&self.rt_restores));
        row("rt_policy_errors", l(&self.rt_policy_errors));
        row("server_demoted", l(&self.server_demoted));
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
        c.refuse(Refusal::Oversize);
        c.refuse(Refusal::StraySource);
        c.refuse(Refusal::BadTag);
        let text = c.render(Some("127.0.0.1:9".parse().unwrap()));
        let kv = parse_kv(&text);
        let get = |k: &str| kv.iter().find(|(kk, _)| kk == k).map(|(_, v)| v.clone());
        assert_eq!(get("received").as_deref(), Some("1"));
        assert_eq!(get("rejected").as_deref(), Some("3"));
        assert_eq!(get("rejected_bad_tag").as_deref(), Some("1"));
        assert_eq!(get("rejected_stray_source").as_deref(), Some("1"));
        assert_eq!(get("rejected_replay").as_deref(), Some("0"));
        assert_eq!(get("client").as_deref(), Some("127.0.0.1:9"));
    }
}
