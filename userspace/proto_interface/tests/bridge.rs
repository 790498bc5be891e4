//! proto_interface on the host, without the kernel: the devices are named
//! pipes and a "fake kernel" thread reads frames from rtf_in and writes
//! answers to rtf_out. Proves forwarding, oversize/undersize/garbage drops,
//! stray-source drops, session expiry, answer routing, SIGUSR1/SIGTERM and
//! exit when the device goes away.

use std::ffi::CString;
use std::fs::File;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, UdpSocket};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use hap_core::protocol::{decode, encode, expected_len, Frame, FrameHeader, MAX_FRAME_LEN};

fn tmpdir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("proto_if_{tag}_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn mkfifo(p: &Path) {
    let c = CString::new(p.to_str().unwrap()).unwrap();
    // SAFETY: valid NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
}

fn enc(seq: u32, f: &Frame) -> Vec<u8> {
    let mut b = [0u8; MAX_FRAME_LEN];
    let h = FrameHeader {
        seq,
        ..Default::default()
    };
    let n = encode(&h, f, &mut b);
    b[..n].to_vec()
}

struct Rig {
    dir: PathBuf,
    child: Child,
    addr: SocketAddr,
    /// Frames the fake kernel read from rtf_in.
    frames: mpsc::Receiver<Vec<u8>>,
    /// The fake kernel's rtf_out writer.
    out: Option<File>,
}

impl Rig {
    fn start(tag: &str, extra: &[&str]) -> Rig {
        let dir = tmpdir(tag);
        let (rin, rout) = (dir.join("rtf_in"), dir.join("rtf_out"));
        mkfifo(&rin);
        mkfifo(&rout);
        let mut child = Command::new(env!("CARGO_BIN_EXE_proto_interface"))
            .args([
                "--bind",
                "127.0.0.1",
                "--port",
                "0",
                "--print-addr",
                "--rtf-in",
            ])
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

        // Fake kernel, input side: reassemble whole frames from the pipe.
        let (tx, frames) = mpsc::channel();
        std::thread::spawn(move || {
            let mut f = File::open(rin).unwrap();
            let mut acc: Vec<u8> = Vec::new();
            let mut buf = [0u8; 4096];
            loop {
                let n = match f.read(&mut buf) {
                    Ok(0) | Err(_) => return,
                    Ok(n) => n,
                };
                acc.extend_from_slice(&buf[..n]);
                while acc.len() >= 4 {
                    let Some(len) = expected_len(&acc) else {
                        panic!("the bridge wrote a non-frame into rtf_in: {acc:?}");
                    };
                    if acc.len() < len {
                        break;
                    }
                    let fr: Vec<u8> = acc.drain(..len).collect();
                    if tx.send(fr).is_err() {
                        return;
                    }
                }
            }
        });
        let out = File::options().write(true).open(rout).unwrap();
        Rig {
            dir,
            child,
            addr,
            frames,
            out: Some(out),
        }
    }

    fn client(&self) -> UdpSocket {
        let s = UdpSocket::bind("127.0.0.1:0").unwrap();
        s.set_read_timeout(Some(Duration::from_millis(1000)))
            .unwrap();
        s.connect(self.addr).unwrap();
        s
    }

    fn next_frame(&self) -> Option<Frame> {
        let b = self.frames.recv_timeout(Duration::from_secs(2)).ok()?;
        Some(decode(&b).expect("forwarded frame decodes").1)
    }

    fn no_frame(&self) {
        if let Ok(b) = self.frames.recv_timeout(Duration::from_millis(200)) {
            panic!("unexpected frame forwarded: {:?}", decode(&b));
        }
    }

    fn answer(&mut self, f: &Frame) {
        self.out.as_mut().unwrap().write_all(&enc(1, f)).unwrap();
    }

    fn stats(&self) -> String {
        std::fs::read_to_string(self.dir.join("stats")).unwrap_or_default()
    }

    fn stat(&self, key: &str) -> u64 {
        for l in self.stats().lines() {
            if let Some(v) = l.strip_prefix(&format!("{key}: ")) {
                return v.trim().parse().unwrap_or(0);
            }
        }
        0
    }

    fn signal(&self, sig: i32) {
        // SAFETY: plain kill(2) on our child.
        unsafe { libc::kill(self.child.id() as i32, sig) };
    }

    fn wait_exit(&mut self, within: Duration) -> (std::process::ExitStatus, String) {
        let t = Instant::now();
        loop {
            if let Some(st) = self.child.try_wait().unwrap() {
                let mut e = String::new();
                self.child
                    .stderr
                    .take()
                    .unwrap()
                    .read_to_string(&mut e)
                    .unwrap();
                return (st, e);
            }
            if t.elapsed() > within {
                let _ = self.child.kill();
                panic!("proto_interface did not exit");
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Drop for Rig {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

#[test]
fn forwards_drops_and_routes() {
    let mut rig = Rig::start("fwd", &["--insecure", "--refusal-budget", "0"]);
    let a = rig.client();
    rig.signal(libc::SIGUSR1);
    std::thread::sleep(Duration::from_millis(200));
    assert_eq!(rig.stat("insecure"), 1, "{}", rig.stats());
    let b = rig.client();

    // Before any session: only OpenSession passes.
    a.send(&enc(1, &Frame::PowerRequest(true))).unwrap();
    rig.no_frame();
    a.send(&enc(2, &Frame::OpenSession { client_nonce: 9 }))
        .unwrap();
    assert_eq!(
        rig.next_frame(),
        Some(Frame::OpenSession { client_nonce: 9 })
    );

    // Junk of every kind, from the client itself: dropped, never truncated.
    a.send(&[0x48u8; 91]).unwrap();
    a.send(&[0u8; 1500]).unwrap();
    a.send(&[1, 2, 3]).unwrap();
    let mut bad = enc(3, &Frame::PowerRequest(true));
    bad[18] ^= 0xff; // CRC mismatch
    a.send(&bad).unwrap();
    a.send(&enc(
        4,
        &Frame::SessionAck {
            client_nonce: 1,
            period_us: 1,
        },
    ))
    .unwrap();
    // A stray source, even with a valid OpenSession: dropped.
    b.send(&enc(1, &Frame::OpenSession { client_nonce: 5 }))
        .unwrap();
    b.send(&enc(2, &Frame::PowerRequest(true))).unwrap();
    rig.no_frame();

    // The client's frames go through, whole and in order.
    a.send(&enc(5, &Frame::PowerRequest(true))).unwrap();
    a.send(&enc(6, &Frame::DetachVirtualObject)).unwrap();
    assert_eq!(rig.next_frame(), Some(Frame::PowerRequest(true)));
    assert_eq!(rig.next_frame(), Some(Frame::DetachVirtualObject));

    // Answers go to the client only.
    let ack = Frame::SessionAck {
        client_nonce: 9,
        period_us: 1000,
    };
    rig.answer(&ack);
    let mut buf = [0u8; 256];
    let n = a.recv(&mut buf).unwrap();
    assert_eq!(decode(&buf[..n]).unwrap().1, ack);
    b.set_read_timeout(Some(Duration::from_millis(200)))
        .unwrap();
    assert!(b.recv(&mut buf).is_err(), "stray client got an answer");

    // A flood of garbage from the stray host changes nothing.
    for i in 0..10_000u32 {
        let len = 1 + (i as usize * 7) % 120;
        let junk: Vec<u8> = (0..len).map(|k| (k as u32 ^ i) as u8).collect();
        let _ = b.send(&junk);
    }
    // Let the bridge drain its socket (a full receive buffer would drop the
    // next datagram in the kernel, before the bridge sees it).
    std::thread::sleep(Duration::from_millis(300));
    a.send(&enc(7, &Frame::DetachVirtualObject)).unwrap();
    assert_eq!(rig.next_frame(), Some(Frame::DetachVirtualObject));
    rig.no_frame();

    // Counters, via SIGUSR1 (stats file rewritten at once).
    std::thread::sleep(Duration::from_millis(100));
    rig.signal(libc::SIGUSR1);
    std::thread::sleep(Duration::from_millis(200));
    println!("{}", rig.stats());
    assert_eq!(rig.stat("forwarded"), 4);
    assert!(rig.stat("rejected_oversize") >= 2);
    assert!(rig.stat("rejected_undersize") >= 1);
    assert!(rig.stat("rejected_malformed") >= 2);
    assert!(rig.stat("rejected_stray_source") >= 2);
    assert_eq!(rig.stat("rejected_no_session"), 1);
    assert_eq!(rig.stat("sent"), 1);
    let total = rig.stat("received");
    assert_eq!(total, rig.stat("forwarded") + rig.stat("rejected"));
    assert!(total > 5000, "flood mostly lost? received={total}");

    // CloseSession frees the bridge for another client.
    a.send(&enc(8, &Frame::CloseSession)).unwrap();
    assert_eq!(rig.next_frame(), Some(Frame::CloseSession));
    b.send(&enc(3, &Frame::OpenSession { client_nonce: 6 }))
        .unwrap();
    assert_eq!(
        rig.next_frame(),
        Some(Frame::OpenSession { client_nonce: 6 })
    );

    // The module goes away (the writer side closes): the bridge exits cleanly.
    rig.out = None;
    let (st, err) = rig.wait_exit(Duration::from_secs(3));
    assert!(st.success(), "{st:?} {err}");
    assert!(err.contains("module gone"), "{err}");
    assert!(err.contains("forwarded: 6"), "{err}");
}

#[test]
fn session_expires_and_sigterm_exits() {
    let mut rig = Rig::start("exp", &["--insecure", "--session-timeout-ms", "300"]);
    let a = rig.client();
    let b = rig.client();
    a.send(&enc(1, &Frame::OpenSession { client_nonce: 1 }))
        .unwrap();
    assert!(rig.next_frame().is_some());
    b.send(&enc(1, &Frame::OpenSession { client_nonce: 2 }))
        .unwrap();
    rig.no_frame();
    std::thread::sleep(Duration::from_millis(400));
    b.send(&enc(2, &Frame::OpenSession { client_nonce: 2 }))
        .unwrap();
    assert_eq!(
        rig.next_frame(),
        Some(Frame::OpenSession { client_nonce: 2 })
    );
    // The old client is now the stray one.
    a.send(&enc(2, &Frame::PowerRequest(false))).unwrap();
    rig.no_frame();

    rig.signal(libc::SIGTERM);
    let (st, err) = rig.wait_exit(Duration::from_secs(3));
    assert!(st.success(), "{st:?} {err}");
    assert!(err.contains("exiting (SIGTERM)"), "{err}");
    assert!(err.contains("sessions_expired: 1"), "{err}");
    assert!(
        rig.stats().contains("rejected_stray_source: 2"),
        "{}",
        rig.stats()
    );
}

#[test]
fn bad_command_line_is_refused() {
    for args in [
        &["--port", "70000"][..],
        &["--bind", "nowhere"],
        &["--session-timeout-ms", "0"],
        &["--rt-priority", "0"],
        &["--rt-priority", "100"],
        &["--rt-priority", "high"],
        &["--bogus"],
        &[],
        &["--insecure", "--key", "/nonexistent"],
        &["--insecure", "--refusal-budget", "-1"],
    ] {
        let o = Command::new(env!("CARGO_BIN_EXE_proto_interface"))
            .args(args)
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(2), "{args:?}");
        assert!(
            String::from_utf8_lossy(&o.stderr).contains("error:"),
            "{args:?}"
        );
    }
}

#[test]
fn sigterm_while_waiting_for_the_module() {
    // The launch script starts the bridge before insmod: it must wait for
    // the devices, and still exit at once on SIGTERM.
    let dir = tmpdir("wait");
    let (rin, rout) = (dir.join("rtf_in"), dir.join("rtf_out"));
    mkfifo(&rin); // no reader: open() for writing blocks
    let mut child = Command::new(env!("CARGO_BIN_EXE_proto_interface"))
        .args([
            "--bind",
            "127.0.0.1",
            "--port",
            "0",
            "--no-stats-file",
            "--insecure",
            "--rtf-in",
        ])
        .arg(&rin)
        .arg("--rtf-out")
        .arg(&rout) // does not exist yet
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_millis(300));
    // SAFETY: plain kill(2) on our child.
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    let t = Instant::now();
    let st = loop {
        if let Some(st) = child.try_wait().unwrap() {
            break st;
        }
        if t.elapsed() > Duration::from_secs(3) {
            let _ = child.kill();
            panic!("proto_interface hung on SIGTERM while waiting for its devices");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let mut e = String::new();
    child.stderr.take().unwrap().read_to_string(&mut e).unwrap();
    assert!(st.success(), "{e}");
    assert!(
        e.contains("waiting for") && e.contains("exiting (SIGTERM)"),
        "{e}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
