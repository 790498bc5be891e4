//! Session pinning: which source address may steer the arm.
//!
//! An `OpenSession` (in protocol v2: a proven handshake, `open_proof` with a
//! valid cookie and tag) pins its source address as the session's client,
//! replacing any earlier client: in v2 only the key holder can make one,
//! from an address it receives at (the cookie proves it), so a client
//! restarted on a new port takes its session back at once. From then on,
//! other frames from any other source address are dropped (a stray host on
//! the network must not steer the arm) until the client sends
//! `CloseSession` or stays silent for longer than the session timeout.
//! Frames other than `OpenSession` that arrive while no session is open are
//! dropped too: the kernel would ignore them, and forwarding them would let
//! anybody probe the module. In `--insecure` v1 an `OpenSession` from
//! another address than the client's is dropped (anybody can make one).

use std::net::SocketAddr;
use std::time::{Duration, Instant};

/// What the bridge needs to know about a datagram to route it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameKind {
    OpenSession,
    CloseSession,
    /// Any other valid frame (configuration, VprStream, power request...).
    Other,
}

/// Why a datagram was not forwarded: the bridge's reasons are those of
/// the authenticating gate (`Oversize`, `Undersize`, `Malformed`,
/// `StraySource`, `NoSession` are the ones this module and `frames` use).
pub use hap_auth::Refusal as Reject;

/// The decision for one datagram.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Decision {
    /// Forward it to the kernel.
    Forward,
    /// Drop it and count the reason.
    Drop(Reject),
}

/// Session state, owned by the SERVER thread (the CLIENT thread reads the
/// pinned address through a shared copy).
#[derive(Debug)]
pub struct Session {
    client: Option<SocketAddr>,
    /// The client that closed the session last (its close is still to be
    /// acknowledged by the kernel).
    closed_by: Option<SocketAddr>,
    last_seen: Instant,
    timeout: Duration,
    /// Sessions opened, closed by the client, expired by the timeout.
    pub opened: u64,
    pub closed: u64,
    pub expired: u64,
}

impl Session {
    pub fn new(timeout: Duration) -> Session {
        Session {
            client: None,
            closed_by: None,
            last_seen: Instant::now(),
            timeout,
            opened: 0,
            closed: 0,
            expired: 0,
        }
    }

    /// The pinned client, if a session is open.
    pub fn client(&self) -> Option<SocketAddr> {
        self.client
    }

    /// The client that sent the last `CloseSession` (the kernel's ack of it
    /// goes there), until a new session opens.
    pub fn closed_by(&self) -> Option<SocketAddr> {
        if self.client.is_none() {
            self.closed_by
        } else {
            None
        }
    }

    /// Expire the session if the client has been silent too long.
    /// Returns true if it expired now.
    pub fn expire(&mut self, now: Instant) -> bool {
        if self.client.is_some() && now.saturating_duration_since(self.last_seen) > self.timeout {
            self.client = None;
            self.expired += 1;
            return true;
        }
        false
    }

    /// End the session on the bridge's decision (sequence numbers spent):
    /// returns the client it had.
    pub fn end(&mut self) -> Option<SocketAddr> {
        let c = self.client.take();
        if c.is_some() {
            self.expired += 1;
        }
        c
    }

    /// A proven handshake from `src` (protocol v2): it takes the session,
    /// whoever had it.
    pub fn admit_proven(&mut self, src: SocketAddr, now: Instant) -> Decision {
        self.expire(now);
        self.client = Some(src);
        self.last_seen = now;
        self.opened += 1;
        Decision::Forward
    }

    /// Decide what to do with a valid frame of `kind` from `src` at `now`.
    pub fn admit(&mut self, src: SocketAddr, kind: FrameKind, now: Instant) -> Decision {
        self.expire(now);
        match self.client {
            Some(client) if client != src => Decision::Drop(Reject::StraySource),
            Some(_) => {
                self.last_seen = now;
                if kind == FrameKind::OpenSession {
                    // The same client re-opening: the kernel opens a new session.
                    self.opened += 1;
                }
                if kind == FrameKind::CloseSession {
                    self.closed_by = self.client.take();
                    self.closed += 1;
                }
                Decision::Forward
            }
            None => match kind {
                FrameKind::OpenSession => {
                    self.client = Some(src);
                    self.last_seen = now;
                    self.opened += 1;
                    Decision::Forward
                }
                _ => Decision::Drop(Reject::NoSession),
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn a(port: u16) -> SocketAddr {
        SocketAddr::from(([127, 0, 0, 1], port))
    }

    #[test]
    fn first_open_pins_the_client() {
        let mut s = Session::new(Duration::from_secs(5));
        let t = Instant::now();
        assert_eq!(
            s.admit(a(1), FrameKind::Other, t),
            Decision::Drop(Reject::NoSession)
        );
        assert_eq!(s.admit(a(1), FrameKind::OpenSession, t), Decision::Forward);
        assert_eq!(s.client(), Some(a(1)));
        assert_eq!(s.admit(a(1), FrameKind::Other, t), Decision::Forward);
        // A second client is refused, even with an OpenSession.
        assert_eq!(
            s.admit(a(2), FrameKind::OpenSession, t),
            Decision::Drop(Reject::StraySource)
        );
        assert_eq!(
            s.admit(a(2), FrameKind::Other, t),
            Decision::Drop(Reject::StraySource)
        );
        // The same client re-opening is forwarded (the kernel opens a new
        // session) and counted, as the kernel counts it.
        assert_eq!(s.admit(a(1), FrameKind::OpenSession, t), Decision::Forward);
        assert_eq!(s.opened, 2);
    }

    #[test]
    fn a_proven_handshake_takes_the_session_from_any_address() {
        let mut s = Session::new(Duration::from_secs(5));
        let t = Instant::now();
        s.admit_proven(a(1), t);
        assert_eq!(s.admit_proven(a(2), t), Decision::Forward);
        assert_eq!(s.client(), Some(a(2)));
        assert_eq!(
            s.admit(a(1), FrameKind::Other, t),
            Decision::Drop(Reject::StraySource)
        );
        assert_eq!(s.end(), Some(a(2)));
        assert_eq!(s.client(), None);
        assert_eq!((s.opened, s.expired), (2, 1));
    }

    #[test]
    fn close_frees_the_session() {
        let mut s = Session::new(Duration::from_secs(5));
        let t = Instant::now();
        s.admit(a(1), FrameKind::OpenSession, t);
        assert_eq!(s.admit(a(1), FrameKind::CloseSession, t), Decision::Forward);
        assert_eq!(s.client(), None);
        assert_eq!(s.admit(a(2), FrameKind::OpenSession, t), Decision::Forward);
        assert_eq!(s.client(), Some(a(2)));
        assert_eq!((s.opened, s.closed), (2, 1));
    }

    #[test]
    fn silence_expires_the_session() {
        let mut s = Session::new(Duration::from_millis(100));
        let t = Instant::now();
        s.admit(a(1), FrameKind::OpenSession, t);
        let later = t + Duration::from_millis(50);
        assert_eq!(
            s.admit(a(2), FrameKind::OpenSession, later),
            Decision::Drop(Reject::StraySource)
        );
        // Stray traffic does not keep the session alive.
        let much_later = t + Duration::from_millis(200);
        assert_eq!(
            s.admit(a(2), FrameKind::OpenSession, much_later),
            Decision::Forward
        );
        assert_eq!(s.expired, 1);
        assert_eq!(s.client(), Some(a(2)));
    }
}
