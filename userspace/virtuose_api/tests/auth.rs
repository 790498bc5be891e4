//! The library's protocol v2 against hap-auth's gate in front of hap-core's
//! PROTO_IN (a bridge and a kernel in one thread, over UDP): the key
//! holder opens, configures and streams; a client with another key or none
//! gets nothing; the key is found in the options, the address or the
//! environment.

use std::net::UdpSocket;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use hap_auth::{Action, EndReason, Gate, Psk};
use hap_core::config::CommandType;
use hap_core::proto_in::ProtoIn;
use hap_core::protocol::{encode, Answer, Frame, FrameHeader, MAX_FRAME_LEN};
use virtuose_api::{Options, VirtContext, VirtError};

struct Peer {
    addr: String,
    stop: Arc<AtomicBool>,
    kernel: Arc<Mutex<ProtoIn>>,
}

impl Drop for Peer {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
    }
}

fn peer() -> Peer {
    peer_ending_after(None)
}

/// As `peer`; with `Some(end_after)`, the gate ends the session as expired after
/// `end_after` forwarded requests (what the bridge does after a silence): it tells
/// the client and closes the session in PROTO_IN.
fn peer_ending_after(end_after: Option<usize>) -> Peer {
    let sock = UdpSocket::bind("127.0.0.1:0").unwrap();
    sock.set_read_timeout(Some(Duration::from_millis(20)))
        .unwrap();
    let addr = format!("127.0.0.1#{}", sock.local_addr().unwrap().port());
    let stop = Arc::new(AtomicBool::new(false));
    let kernel = Arc::new(Mutex::new(ProtoIn::new()));
    let (st, k) = (stop.clone(), kernel.clone());
    std::thread::spawn(move || {
        let mut gate = Gate::with_random_secret(psk()).unwrap();
        let t0 = std::time::Instant::now();
        let mut buf = [0u8; 256];
        let mut seq = 0u32;
        let mut client = None;
        let mut forwarded = 0usize;
        while !st.load(Ordering::SeqCst) {
            let mut out: Vec<Frame> = Vec::new();
            if let Ok((n, src)) = sock.recv_from(&mut buf) {
                let Ok(i) = gate.inspect(&buf[..n], src, t0.elapsed()) else {
                    continue;
                };
                match gate.commit(&i, t0.elapsed()) {
                    Action::Reply(w, _) | Action::Challenge(w) => {
                        let _ = sock.send_to(w.bytes(), src);
                    }
                    Action::Forward(v1) => {
                        client = Some(src);
                        let o = k.lock().unwrap().handle(v1.bytes(), 1, 1000);
                        out.extend(o.reply);
                        forwarded += 1;
                        if Some(forwarded) == end_after {
                            if let Some(e) = gate.end_session(EndReason::Expired) {
                                let _ = sock.send_to(e.notice.bytes(), src);
                                if let Some(c) = e.kernel_close {
                                    k.lock().unwrap().handle(c.bytes(), 1, 1000);
                                }
                            }
                        }
                    }
                }
            }
            // One answer per loop while a session is open.
            let session = k.lock().unwrap().session();
            if session != 0 {
                out.push(Frame::Answer(Answer {
                    cycle: seq,
                    ..Answer::default()
                }));
            }
            for f in out {
                seq += 1;
                let h = FrameHeader {
                    control: 0,
                    session,
                    seq,
                    timestamp_us: 0,
                };
                let mut b = [0u8; MAX_FRAME_LEN];
                let n = encode(&h, &f, &mut b);
                if let (Some(w), Some(c)) = (gate.seal_from_kernel(&b[..n]), client) {
                    let _ = sock.send_to(w.bytes(), c);
                }
            }
        }
    });
    Peer { addr, stop, kernel }
}

/// The key of this test process's peers (generated: a key file must not
/// hold the published test key).
fn psk() -> Psk {
    static KEY: std::sync::OnceLock<Psk> = std::sync::OnceLock::new();
    KEY.get_or_init(|| Psk::generate().unwrap()).clone()
}

fn quick(key: Option<Psk>) -> Options {
    Options {
        reply_timeout: Duration::from_millis(150),
        attempts: 2,
        key,
        ..Options::default()
    }
}

#[test]
fn the_key_holder_opens_configures_and_streams() {
    let p = peer();
    let mut vc = VirtContext::open_with(&p.addr, quick(Some(psk()))).unwrap();
    assert!(vc.authenticated());
    assert_ne!(vc.session_id(), 0);
    vc.set_command_type(CommandType::Impedance).unwrap();
    assert_eq!(
        p.kernel.lock().unwrap().config().command_type,
        CommandType::Impedance
    );
    vc.set_position(&[0.01, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
        .unwrap();
    assert!(vc.wait_answer(Duration::from_secs(1)));
    vc.get_position().unwrap();
    std::thread::sleep(Duration::from_millis(50));
    assert!(p.kernel.lock().unwrap().vpr().valid);
    vc.close().unwrap();
    assert_eq!(p.kernel.lock().unwrap().session(), 0);
}

#[test]
fn without_the_key_nothing_happens() {
    let p = peer();
    let mut other = *psk().as_bytes();
    other[5] ^= 0x10;
    let e = VirtContext::open_with(&p.addr, quick(Some(Psk::from_bytes(other))));
    assert!(
        matches!(e, Err(VirtError::Timeout("open_session"))),
        "{:?}",
        e.err()
    );
    // v1 (no key anywhere).
    if std::env::var_os(virtuose_api::KEY_ENV).is_none() {
        let e = VirtContext::open_with(&p.addr, quick(None));
        assert!(matches!(e, Err(VirtError::Timeout(_))), "{:?}", e.err());
    }
    assert_eq!(p.kernel.lock().unwrap().counters().sessions_opened, 0);
}

#[test]
fn the_key_file_in_the_address() {
    let p = peer();
    let dir = std::env::temp_dir().join(format!("virt_auth_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let key = dir.join("hap.key");
    psk().write_new(&key).unwrap();
    let url = format!("{}?key={}", p.addr, key.display());
    let mut vc = VirtContext::open_with(&url, quick(None)).unwrap();
    assert!(vc.authenticated());
    vc.close().unwrap();
    // A key file readable by others is refused before anything is sent.
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&key, std::fs::Permissions::from_mode(0o644)).unwrap();
    let e = VirtContext::open_with(&url, quick(None));
    assert!(
        matches!(&e, Err(VirtError::InvalidArgument(m)) if m.contains("chmod 600")),
        "{:?}",
        e.err()
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_session_the_bridge_ends_is_reported_and_closed_in_proto_in() {
    // Forwarded: open_proof (1), set_command_type (2), then expiry.
    let p = peer_ending_after(Some(2));
    let vc = VirtContext::open_with(&p.addr, quick(Some(psk()))).unwrap();
    // The request the session ended on is answered with the reason (the
    // notice names the newest request the bridge accepted).
    let e = vc.set_command_type(CommandType::Impedance).unwrap_err();
    assert!(
        matches!(&e, VirtError::SessionEnded { reason: 0x103, name } if name.contains("expired")),
        "{e:?}"
    );
    assert!(e.to_string().contains("(0x103)"), "{e}");
    let deadline = std::time::Instant::now() + Duration::from_secs(2);
    while vc.session_ended().is_none() && std::time::Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(10));
    }
    assert_eq!(vc.session_ended(), Some(hap_auth::ERROR_EXPIRED));
    // The peer tells the client first, then closes PROTO_IN's session.
    while p.kernel.lock().unwrap().session() != 0 && std::time::Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(10));
    }
    assert_eq!(p.kernel.lock().unwrap().session(), 0, "PROTO_IN closed it");
    // Every call but close then fails with the reason: set-points,
    // requests and readings (the last answer is not the arm's any more).
    for r in [
        vc.set_position(&[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]),
        vc.set_power_on(true),
        vc.get_position().map(|_| ()),
        vc.check_session(),
    ] {
        assert!(
            matches!(&r, Err(VirtError::SessionEnded { reason: 0x103, .. })),
            "{r:?}"
        );
    }
    let mut vc = vc;
    assert_eq!(vc.close(), Ok(()), "nothing to close");
}

/// Once its proof went out, the library never abandons it while the bridge
/// could still commit it: with no session_ack coming (a bridge that answers
/// the cookie and drops every proof), it sends the same proof again, past
/// its `attempts`, until the cookie is dead (10 s after it came), and
/// never a second open_session.
#[test]
fn a_sent_proof_is_sent_again_until_its_cookie_is_dead() {
    let sock = UdpSocket::bind("127.0.0.1:0").unwrap();
    sock.set_read_timeout(Some(Duration::from_millis(20)))
        .unwrap();
    let addr = format!("127.0.0.1#{}", sock.local_addr().unwrap().port());
    let stop = Arc::new(AtomicBool::new(false));
    let seen: Arc<Mutex<Vec<Vec<u8>>>> = Arc::default();
    let (st, sn) = (stop.clone(), seen.clone());
    std::thread::spawn(move || {
        let mut gate = Gate::with_random_secret(psk()).unwrap();
        let t0 = std::time::Instant::now();
        let mut buf = [0u8; 256];
        while !st.load(Ordering::SeqCst) {
            if let Ok((n, src)) = sock.recv_from(&mut buf) {
                sn.lock().unwrap().push(buf[..n].to_vec());
                if let Ok(i) = gate.inspect(&buf[..n], src, t0.elapsed()) {
                    if let Action::Challenge(w) = gate.commit(&i, t0.elapsed()) {
                        let _ = sock.send_to(w.bytes(), src);
                    }
                }
            }
        }
    });
    let t = std::time::Instant::now();
    let r = VirtContext::open_with(
        &addr,
        Options {
            reply_timeout: Duration::from_millis(50),
            attempts: 2,
            key: Some(psk()),
            ..Options::default()
        },
    );
    let secs = t.elapsed().as_secs_f64();
    stop.store(true, Ordering::SeqCst);
    assert!(
        matches!(r, Err(VirtError::Timeout("open_session"))),
        "{:?}",
        r.err()
    );
    let seen = seen.lock().unwrap();
    let hellos = seen.iter().filter(|d| d[3] == 0x01).count();
    let proofs: Vec<&Vec<u8>> = seen
        .iter()
        .filter(|d| d[3] == hap_auth::TYPE_OPEN_PROOF)
        .collect();
    println!(
        "a proof without a session_ack: {hellos} open_session, {} open_proof (all the same \
         bytes), gave up after {secs:.1} s",
        proofs.len()
    );
    assert_eq!(hellos, 1, "no new attempt while the proof could commit");
    assert!(proofs.len() > 2, "sent again past the 2 attempts");
    assert!(proofs.iter().all(|p| *p == proofs[0]), "one proof, resent");
}
