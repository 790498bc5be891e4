//! The fake controller behind the bridge's authentication: `hap_auth`'s
//! [`Gate`] (the code proto_interface runs) in front of
//! `virtuose_api::fake_peer` (the scripted arm), relaying over loopback UDP.
//! A client holding the key gets a session; one with another key, or none,
//! gets nothing and is counted; a second key holder is told the session is
//! taken, as the bridge does. The link can be cut and restored (every
//! datagram dropped both ways) to test what a client does when it is lost.

use std::collections::BTreeMap;
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use hap_auth::{Action, Gate, Kind, Psk, Refusal};
use virtuose_api::fake_peer::{FakePeer, FakePeerConfig, FakePeerStats};

/// What the relay counted.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RelayStats {
    /// Client datagrams forwarded to the fake controller.
    pub forwarded: u64,
    /// Controller datagrams sealed and sent to the client.
    pub replied: u64,
    /// Client datagrams refused, by `Refusal::name()`.
    pub refused: BTreeMap<&'static str, u64>,
    /// Handshakes the gate accepted.
    pub handshakes: u64,
    /// Datagrams dropped (both ways) while the link was cut.
    pub cut_dropped: u64,
}

/// A running fake controller with its gate; stops when dropped.
pub struct AuthFake {
    /// The address clients talk to.
    pub addr: SocketAddr,
    peer: FakePeer,
    shared: Arc<Shared>,
    threads: Vec<JoinHandle<()>>,
}

struct Shared {
    stop: AtomicBool,
    link_up: AtomicBool,
    /// `None`: protocol v1 relayed verbatim (a bridge run `--insecure`).
    gate: Option<Mutex<Gate>>,
    /// The gate's clock (cookie lifetimes) starts here.
    epoch: Instant,
    client: Mutex<Option<SocketAddr>>,
    stats: Mutex<RelayStats>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    match m.lock() {
        Ok(g) => g,
        Err(p) => p.into_inner(),
    }
}

impl AuthFake {
    /// Start the fake controller `cfg` (its `bind` is ignored: it listens on
    /// loopback behind the relay) and the relay on `bind`, with `key` (or
    /// unauthenticated with `None`).
    pub fn start(
        bind: SocketAddr,
        key: Option<Psk>,
        cfg: FakePeerConfig,
    ) -> std::io::Result<AuthFake> {
        let peer = FakePeer::start(FakePeerConfig {
            bind: SocketAddr::from(([127, 0, 0, 1], 0)),
            ..cfg
        })?;
        let front = UdpSocket::bind(bind)?;
        front.set_read_timeout(Some(Duration::from_millis(50)))?;
        let back = UdpSocket::bind("127.0.0.1:0")?;
        back.connect(peer.addr)?;
        back.set_read_timeout(Some(Duration::from_millis(50)))?;
        let addr = front.local_addr()?;
        let shared = Arc::new(Shared {
            stop: AtomicBool::new(false),
            link_up: AtomicBool::new(true),
            gate: match key {
                Some(k) => Some(Mutex::new(Gate::with_random_secret(k)?)),
                None => None,
            },
            epoch: Instant::now(),
            client: Mutex::new(None),
            stats: Mutex::new(RelayStats::default()),
        });
        let (f2, b2, s2) = (front.try_clone()?, back.try_clone()?, shared.clone());
        let up = std::thread::Builder::new()
            .name("fake_gate_in".into())
            .spawn(move || client_to_peer(&f2, &b2, &s2))?;
        let s3 = shared.clone();
        let down = std::thread::Builder::new()
            .name("fake_gate_out".into())
            .spawn(move || peer_to_client(&front, &back, &s3))?;
        Ok(AuthFake {
            addr,
            peer,
            shared,
            threads: vec![up, down],
        })
    }

    /// `"127.0.0.1#port"`.
    pub fn address(&self) -> String {
        format!("{}#{}", self.addr.ip(), self.addr.port())
    }

    /// Cut (false) or restore (true) the link.
    pub fn set_link(&self, up: bool) {
        self.shared.link_up.store(up, Ordering::SeqCst);
    }

    pub fn relay_stats(&self) -> RelayStats {
        lock(&self.shared.stats).clone()
    }

    pub fn peer_stats(&self) -> FakePeerStats {
        self.peer.stats()
    }

    pub fn stop(&mut self) {
        self.shared.stop.store(true, Ordering::SeqCst);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
        self.peer.stop();
    }
}

impl Drop for AuthFake {
    fn drop(&mut self) {
        self.stop();
    }
}

fn refuse(s: &Shared, r: Refusal) {
    *lock(&s.stats).refused.entry(r.name()).or_insert(0) += 1;
}

fn client_to_peer(front: &UdpSocket, back: &UdpSocket, s: &Shared) {
    let mut buf = [0u8; 2048];
    while !s.stop.load(Ordering::SeqCst) {
        let Ok((n, src)) = front.recv_from(&mut buf) else {
            continue;
        };
        if !s.link_up.load(Ordering::SeqCst) {
            lock(&s.stats).cut_dropped += 1;
            continue;
        }
        let Some(gate) = s.gate.as_ref() else {
            *lock(&s.client) = Some(src);
            if back.send(&buf[..n]).is_ok() {
                lock(&s.stats).forwarded += 1;
            }
            continue;
        };
        let now = s.epoch.elapsed();
        let mut g = lock(gate);
        let i = match g.inspect(&buf[..n], src, now) {
            Ok(i) => i,
            Err(r) => {
                refuse(s, r);
                continue;
            }
        };
        // The bridge's address policy: requests of the open session come
        // from the address that proved the key; a proven handshake from
        // any address takes the session (its holder is told by the gate).
        let holder = *lock(&s.client);
        if matches!(i.kind, Kind::Close | Kind::Other) && holder.is_some_and(|c| c != src) {
            refuse(s, Refusal::StraySource);
            continue;
        }
        match g.commit(&i, now) {
            Action::Forward(w) => {
                if i.kind == Kind::Proof {
                    lock(&s.stats).handshakes += 1;
                    *lock(&s.client) = Some(src);
                    if let Some(e) = g.take_replaced() {
                        if let Some(old) = holder.filter(|c| *c != src) {
                            let _ = front.send_to(e.notice.bytes(), old);
                        }
                    }
                }
                if back.send(w.bytes()).is_ok() {
                    lock(&s.stats).forwarded += 1;
                }
            }
            Action::Challenge(w) => {
                let _ = front.send_to(w.bytes(), src);
            }
            Action::Reply(w, r) => {
                if r != Refusal::Replay {
                    refuse(s, r);
                }
                let _ = front.send_to(w.bytes(), src);
            }
        }
    }
}

fn peer_to_client(front: &UdpSocket, back: &UdpSocket, s: &Shared) {
    let mut buf = [0u8; 2048];
    while !s.stop.load(Ordering::SeqCst) {
        let Ok(n) = back.recv(&mut buf) else {
            continue;
        };
        if !s.link_up.load(Ordering::SeqCst) {
            lock(&s.stats).cut_dropped += 1;
            continue;
        }
        let Some(client) = *lock(&s.client) else {
            continue;
        };
        let sent = match s.gate.as_ref() {
            None => front.send_to(&buf[..n], client).is_ok(),
            Some(gate) => match lock(gate).seal_from_kernel(&buf[..n]) {
                Some(w) => front.send_to(w.bytes(), client).is_ok(),
                None => false,
            },
        };
        if sent {
            lock(&s.stats).replied += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use virtuose_api::{Options, VirtContext, VirtError};

    fn quick(key: Option<Psk>) -> Options {
        Options {
            reply_timeout: Duration::from_millis(150),
            attempts: 2,
            key,
            ..Options::default()
        }
    }

    fn fake() -> AuthFake {
        let cfg = FakePeerConfig {
            answer_every_period: true,
            ..Default::default()
        };
        AuthFake::start(
            SocketAddr::from(([127, 0, 0, 1], 0)),
            Some(Psk::test_key()),
            cfg,
        )
        .unwrap()
    }

    #[test]
    fn the_key_holder_gets_answers_and_a_cut_stops_them() {
        let f = fake();
        let mut vc = VirtContext::open_with(&f.address(), quick(Some(Psk::test_key()))).unwrap();
        assert!(vc.authenticated());
        vc.set_power_on(true).unwrap();
        assert!(vc.wait_answer(Duration::from_secs(1)));
        assert!(f.peer_stats().powered);
        f.set_link(false);
        std::thread::sleep(Duration::from_millis(100));
        let dropped = f.relay_stats().cut_dropped;
        assert!(dropped > 0);
        // Drain what was in flight, then nothing arrives.
        vc.wait_answer(Duration::from_millis(20));
        assert!(!vc.wait_answer(Duration::from_millis(100)));
        f.set_link(true);
        assert!(vc.wait_answer(Duration::from_secs(1)));
        vc.close().unwrap();
        assert!(f.peer_stats().client.is_none());
        assert_eq!(f.relay_stats().handshakes, 1);
    }

    #[test]
    fn another_key_is_refused_and_a_second_holder_takes_the_session() {
        let f = fake();
        let mut other = *Psk::test_key().as_bytes();
        other[0] ^= 1;
        let e = VirtContext::open_with(&f.address(), quick(Some(Psk::from_bytes(other))));
        assert!(matches!(e, Err(VirtError::Timeout("open_session"))));
        assert!(f.relay_stats().refused.get("bad_tag").copied().unwrap_or(0) >= 1);
        assert_eq!(f.relay_stats().handshakes, 0);
        // A proven handshake takes the session (protocol.md §7): the
        // second key holder gets it, the first is told it was replaced.
        let first = VirtContext::open_with(&f.address(), quick(Some(Psk::test_key()))).unwrap();
        let second = VirtContext::open_with(&f.address(), quick(Some(Psk::test_key())));
        assert!(second.is_ok(), "{:?}", second.err());
        assert_eq!(f.relay_stats().handshakes, 2);
        drop(first);
    }
}
