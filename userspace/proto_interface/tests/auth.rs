//! The authenticating bridge on the host (devices are named pipes, a fake
//! kernel answers): only a client holding the key gets a session; v1
//! frames, wrong keys, spoofed and forged datagrams never reach rtf_in and
//! are counted by reason; floods from a source are rate limited without
//! starving the client.

use std::ffi::CString;
use std::fs::File;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, UdpSocket};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use hap_auth::{ClientAuth, Psk, Reply, SessionKeys, NONCE_LEN};
use hap_core::fixed::{Pose, Twist};
use hap_core::protocol::{
    decode, encode, expected_len, Frame, FrameHeader, CTRL_ACK_REQUEST, MAX_FRAME_LEN,
};

fn tmpdir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("proto_auth_{tag}_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn mkfifo(p: &Path) {
    let c = CString::new(p.to_str().unwrap()).unwrap();
    // SAFETY: valid NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
}

fn hdr(seq: u32, session: u16, control: u16) -> FrameHeader {
    FrameHeader {
        control,
        session,
        seq,
        timestamp_us: seq,
    }
}

fn vpr() -> Frame {
    Frame::VprStream {
        pose: Pose::default(),
        twist: Twist::default(),
    }
}

struct Rig {
    psk: Psk,
    dir: PathBuf,
    child: Child,
    addr: SocketAddr,
    frames: mpsc::Receiver<Vec<u8>>,
}

impl Rig {
    /// The bridge with the test key, and a fake kernel that answers every
    /// open_session with a session_ack (session 7) and every request asking
    /// for it with an ack, as PROTO_IN does.
    fn start(tag: &str, extra: &[&str]) -> Rig {
        Rig::start_as(tag, extra, None)
    }

    /// As `start`; with `fifo_gid`, the two FIFOs belong to that group with
    /// mode 0660 (what the launch script does for the bridge's user).
    fn start_as(tag: &str, extra: &[&str], fifo_gid: Option<u32>) -> Rig {
        let dir = tmpdir(tag);
        let key = dir.join("key");
        let psk = Psk::generate().unwrap();
        psk.write_new(&key).unwrap();
        let (rin, rout) = (dir.join("rtf_in"), dir.join("rtf_out"));
        mkfifo(&rin);
        mkfifo(&rout);
        if let Some(gid) = fifo_gid {
            use std::os::unix::fs::PermissionsExt;
            for p in [&rin, &rout] {
                std::os::unix::fs::chown(p, Some(0), Some(gid)).unwrap();
                std::fs::set_permissions(p, std::fs::Permissions::from_mode(0o660)).unwrap();
            }
            std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o755)).unwrap();
        }
        let mut child = Command::new(env!("CARGO_BIN_EXE_proto_interface"))
            .args(["--bind", "127.0.0.1", "--port", "0", "--print-addr"])
            .arg("--key")
            .arg(&key)
            .arg("--rtf-in")
            .arg(&rin)
            .arg("--rtf-out")
            .arg(&rout)
            .arg("--stats-file")
            .arg(dir.join("stats"))
            .args(extra)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        let addr: SocketAddr = line
            .trim()
            .trim_start_matches("listening on ")
            .parse()
            .unwrap();
        let (tx, frames) = mpsc::channel();
        std::thread::spawn(move || {
            let mut f = File::open(rin).unwrap();
            let mut out = File::options().write(true).open(rout).unwrap();
            let mut acc: Vec<u8> = Vec::new();
            let mut buf = [0u8; 4096];
            let mut seq = 100u32;
            loop {
                let n = match f.read(&mut buf) {
                    Ok(0) | Err(_) => return,
                    Ok(n) => n,
                };
                acc.extend_from_slice(&buf[..n]);
                while acc.len() >= 4 {
                    let len = expected_len(&acc).expect("the bridge wrote a non-frame");
                    if acc.len() < len {
                        break;
                    }
                    let fr: Vec<u8> = acc.drain(..len).collect();
                    let (h, f) = decode(&fr).expect("the bridge forwarded a valid v1 frame");
                    let reply = match f {
                        Frame::OpenSession { client_nonce } => Some(Frame::SessionAck {
                            client_nonce,
                            period_us: 1000,
                        }),
                        f if h.control & CTRL_ACK_REQUEST != 0 => Some(Frame::Ack {
                            acked_type: f.frame_type(),
                            acked_seq: h.seq,
                        }),
                        _ => None,
                    };
                    if let Some(r) = reply {
                        seq += 1;
                        let mut b = [0u8; MAX_FRAME_LEN];
                        let n = encode(&hdr(seq, 7, 0), &r, &mut b);
                        out.write_all(&b[..n]).unwrap();
                    }
                    if tx.send(fr).is_err() {
                        return;
                    }
                }
            }
        });
        Rig {
            psk,
            dir,
            child,
            addr,
            frames,
        }
    }

    fn socket(&self) -> UdpSocket {
        let s = UdpSocket::bind("127.0.0.1:0").unwrap();
        s.set_read_timeout(Some(Duration::from_millis(500)))
            .unwrap();
        s.connect(self.addr).unwrap();
        s
    }

    fn forwarded(&self) -> Vec<Vec<u8>> {
        let mut v = Vec::new();
        while let Ok(f) = self.frames.recv_timeout(Duration::from_millis(300)) {
            v.push(f);
        }
        v
    }

    fn stat(&self, key: &str) -> u64 {
        // SAFETY: kill(2) on our child: rewrite the stats file now.
        unsafe { libc::kill(self.child.id() as i32, libc::SIGUSR1) };
        std::thread::sleep(Duration::from_millis(150));
        let s = std::fs::read_to_string(self.dir.join("stats")).unwrap_or_default();
        s.lines()
            .find_map(|l| l.strip_prefix(&format!("{key}: ")))
            .and_then(|v| v.trim().parse().ok())
            .unwrap_or_else(|| panic!("no {key} in {s}"))
    }
}

impl Drop for Rig {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// Handshake on `sock` (both rounds); returns the session id.
fn handshake(sock: &UdpSocket, c: &mut ClientAuth, nc: u8) -> u16 {
    let open = c.hello(&hdr(1, 0, 0), [nc; NONCE_LEN]);
    sock.send(open.bytes()).unwrap();
    let mut buf = [0u8; 256];
    let n = sock.recv(&mut buf).expect("cookie");
    assert!(n <= 3 * open.len, "{n} bytes for {}", open.len);
    assert_eq!(c.open(&buf[..n]).unwrap().1, Reply::Cookie);
    sock.send(c.prove(&hdr(1, 0, 0)).unwrap().bytes()).unwrap();
    let n = sock.recv(&mut buf).expect("session_ack");
    let (h, r) = c.open(&buf[..n]).unwrap();
    assert_eq!(r, Reply::SessionAck { period_us: 1000 });
    h.session
}

#[test]
fn only_the_key_holder_gets_through() {
    let rig = Rig::start("key", &[]);
    // v1 and a wrong key: refused, nothing reaches rtf_in, no reply.
    let stranger = rig.socket();
    let mut b = [0u8; MAX_FRAME_LEN];
    let n = encode(
        &hdr(1, 0, 0),
        &Frame::OpenSession { client_nonce: 1 },
        &mut b,
    );
    stranger.send(&b[..n]).unwrap();
    let mut wrong_key = *rig.psk.as_bytes();
    wrong_key[0] ^= 1;
    let mut wrong = ClientAuth::new(Psk::from_bytes(wrong_key));
    stranger
        .send(wrong.hello(&hdr(2, 0, 0), [9; NONCE_LEN]).bytes())
        .unwrap();
    let mut buf = [0u8; 256];
    assert!(stranger.recv(&mut buf).is_err(), "a stranger got a reply");
    assert!(rig.forwarded().is_empty());
    assert_eq!(rig.stat("rejected_unauthenticated_v1"), 1);
    assert_eq!(rig.stat("rejected_bad_tag"), 1);

    // The key holder: session, config acked, VPr forwarded as v1.
    let sock = rig.socket();
    let mut c = ClientAuth::new(rig.psk.clone());
    let s = handshake(&sock, &mut c, 1);
    assert_eq!(s, 7);
    let w = c
        .seal(&hdr(2, s, CTRL_ACK_REQUEST), &Frame::PowerRequest(true))
        .unwrap();
    sock.send(w.bytes()).unwrap();
    let n = sock.recv(&mut buf).unwrap();
    assert!(matches!(
        c.open(&buf[..n]).unwrap().1,
        Reply::Frame(Frame::Ack { acked_seq: 2, .. })
    ));
    sock.send(c.seal(&hdr(3, s, 0), &vpr()).unwrap().bytes())
        .unwrap();
    let fwd = rig.forwarded();
    assert_eq!(fwd.len(), 3);
    assert_eq!(fwd[2][2], 1, "the kernel reads v1");
    assert_eq!(decode(&fwd[2]).unwrap().1, vpr());

    // The same ack again for a retransmission, nothing forwarded.
    sock.send(w.bytes()).unwrap();
    let n = sock.recv(&mut buf).unwrap();
    assert!(matches!(
        c.open(&buf[..n]).unwrap().1,
        Reply::Frame(Frame::Ack { acked_seq: 2, .. })
    ));
    assert!(rig.forwarded().is_empty());
    assert_eq!(rig.stat("retransmits_reacked"), 1);

    // The key holder restarted on another port: its proven handshake takes
    // the session at once, and the old address is told why.
    let other = rig.socket();
    let mut c2 = ClientAuth::new(rig.psk.clone());
    let s2 = handshake(&other, &mut c2, 2);
    let n = sock
        .recv(&mut buf)
        .expect("the notice to the replaced client");
    assert_eq!(
        c.open(&buf[..n]).unwrap().1,
        Reply::Frame(Frame::Error {
            reason: hap_auth::ERROR_REPLACED,
            rejected_seq: 3
        })
    );
    assert!(!c.established());
    assert_eq!(rig.forwarded().len(), 1, "the new open_session");
    // The old session's frames are refused now (old keys: the tag).
    sock.send(w.bytes()).unwrap();
    assert!(rig.forwarded().is_empty());
    assert_eq!(rig.stat("rejected_bad_tag"), 2);

    // close_session is acknowledged to the closing client.
    let w = c2
        .seal(&hdr(4, s2, CTRL_ACK_REQUEST), &Frame::CloseSession)
        .unwrap();
    other.send(w.bytes()).unwrap();
    let n = other.recv(&mut buf).expect("the ack of close_session");
    assert!(matches!(
        c2.open(&buf[..n]).unwrap().1,
        Reply::Frame(Frame::Ack { acked_seq: 4, .. })
    ));
}

#[test]
fn a_second_binder_of_the_port_is_refused() {
    let rig = Rig::start("bind", &[]);
    // Another process (this one) cannot bind the bridge's port, with or
    // without SO_REUSEADDR.
    assert!(UdpSocket::bind(rig.addr).is_err());
    let e = proto_interface::bind_socket(rig.addr).unwrap_err();
    assert_eq!(e.kind(), std::io::ErrorKind::AddrInUse);
    assert!(e.to_string().contains("already in use"), "{e}");
    // A second bridge on the same port refuses to start, and says why.
    let key = rig.dir.join("key");
    let out = Command::new(env!("CARGO_BIN_EXE_proto_interface"))
        .args(["--bind", "127.0.0.1", "--port"])
        .arg(rig.addr.port().to_string())
        .arg("--key")
        .arg(&key)
        .args([
            "--rtf-in",
            "/nonexistent/in",
            "--rtf-out",
            "/nonexistent/out",
        ])
        .arg("--no-stats-file")
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("already in use"), "{err}");
}

#[test]
fn a_weak_or_malformed_key_file_stops_the_bridge_with_a_clear_message() {
    let dir = tmpdir("weakkey");
    for (name, content, expect) in [
        (
            "test",
            format!("{}\n", Psk::test_key().to_hex()),
            "weak key refused",
        ),
        ("zero", format!("{}\n", "0".repeat(64)), "weak key refused"),
        (
            "space",
            format!(" {}\n", Psk::generate().unwrap().to_hex()),
            "not a key file",
        ),
        (
            "upper",
            format!("{}\n", Psk::generate().unwrap().to_hex().to_uppercase()),
            "not a key file",
        ),
    ] {
        let p = dir.join(name);
        use std::os::unix::fs::OpenOptionsExt;
        let mut f = File::options()
            .write(true)
            .create_new(true)
            .mode(0o600)
            .open(&p)
            .unwrap();
        f.write_all(content.as_bytes()).unwrap();
        let out = Command::new(env!("CARGO_BIN_EXE_proto_interface"))
            .args(["--bind", "127.0.0.1", "--port", "0", "--key"])
            .arg(&p)
            .arg("--no-stats-file")
            .output()
            .unwrap();
        assert!(!out.status.success(), "{name}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(expect), "{name}: {err}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn spoofed_and_forged_datagrams_never_reach_the_kernel() {
    let rig = Rig::start("forge", &[]);
    let sock = rig.socket();
    let mut c = ClientAuth::new(rig.psk.clone());
    let s = handshake(&sock, &mut c, 3);
    assert_eq!(rig.forwarded().len(), 1);
    // From the session's own source address: a forged frame (guessed keys),
    // a replay, and 10^4 frames with random tags.
    let guessed = SessionKeys::derive(&rig.psk, &[3; 16], &[0; 16]);
    let forged = hap_auth::seal_request(&guessed, &hdr(10, s, 0), &vpr()).unwrap();
    sock.send(forged.bytes()).unwrap();
    let real = c.seal(&hdr(11, s, 0), &vpr()).unwrap();
    sock.send(real.bytes()).unwrap();
    sock.send(real.bytes()).unwrap();
    let mut x = 0x9E37_79B9u32;
    for i in 0..10_000u32 {
        let mut w = c.seal(&hdr(20 + i, s, 0), &vpr()).unwrap();
        for b in &mut w.buf[w.len - 16..w.len] {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            *b = x as u8;
        }
        sock.send(w.bytes()).unwrap();
        if i % 256 == 0 {
            std::thread::sleep(Duration::from_millis(1));
        }
    }
    // A flood from another port of the same host: rate limited, and the
    // client's own frames still pass.
    let flood = rig.socket();
    for i in 0..5000 {
        flood.send(forged.bytes()).unwrap();
        if i % 256 == 0 {
            std::thread::sleep(Duration::from_millis(1));
        }
    }
    std::thread::sleep(Duration::from_millis(100));
    let after = c.seal(&hdr(20_000, s, 0), &vpr()).unwrap();
    sock.send(after.bytes()).unwrap();
    let fwd = rig.forwarded();
    assert_eq!(
        fwd.len(),
        2,
        "only the real frame and the one after the flood"
    );
    assert_eq!(decode(&fwd[0]).unwrap().0.seq, 11);
    assert_eq!(decode(&fwd[1]).unwrap().0.seq, 20_000);
    assert_eq!(rig.stat("rejected_replay"), 1);
    let bad_tag = rig.stat("rejected_bad_tag");
    let limited = rig.stat("rejected_rate_limited");
    assert!(limited > 0, "the flood was never limited");
    // Loopback may drop datagrams of a burst (socket buffer): every one
    // that arrived is accounted for.
    // (+ 1 replay, + 4: the two handshake rounds, the real frame, the one
    // after the flood.)
    assert_eq!(bad_tag + limited + 1 + 4, rig.stat("received"));
    assert!(bad_tag > 1000, "{bad_tag}");
    // Every datagram forwarded, refused, or answered with a cookie.
    assert_eq!(
        rig.stat("received"),
        rig.stat("forwarded") + rig.stat("rejected") + rig.stat("cookies_sent")
    );
}

/// As root only: the bridge drops to an unprivileged user that can use the
/// two FIFOs (group, mode 0660) and nothing else, with no capability left,
/// and still serves the key holder.
#[test]
fn runs_unprivileged_with_only_the_fifos() {
    // SAFETY: getuid has no preconditions.
    if unsafe { libc::getuid() } != 0 {
        eprintln!("skipped: not root");
        return;
    }
    let rig = Rig::start_as("priv", &["--user", "65534:65534"], Some(65534));
    let sock = rig.socket();
    let mut c = ClientAuth::new(rig.psk.clone());
    let s = handshake(&sock, &mut c, 5);
    sock.send(c.seal(&hdr(2, s, 0), &vpr()).unwrap().bytes())
        .unwrap();
    assert_eq!(rig.forwarded().len(), 2);
    let st = std::fs::read_to_string(format!("/proc/{}/status", rig.child.id())).unwrap();
    let field = |k: &str| {
        st.lines()
            .find(|l| l.starts_with(k))
            .map(|l| {
                l[k.len()..]
                    .split_whitespace()
                    .collect::<Vec<_>>()
                    .join(" ")
            })
            .unwrap()
    };
    assert_eq!(field("Uid:"), "65534 65534 65534 65534");
    assert_eq!(field("Gid:"), "65534 65534 65534 65534");
    assert_eq!(field("Groups:"), "");
    assert_eq!(field("CapEff:"), "0000000000000000");
    assert_eq!(field("CapPrm:"), "0000000000000000");
    assert_eq!(field("NoNewPrivs:"), "1");
}
