//! The replay campaign: a recording UDP proxy on loopback in front of the
//! authenticating bridge (the binary, its devices named pipes, hap-core's
//! PROTO_IN behind them as the kernel), real sessions of the client library
//! recorded through it, then every client datagram of them replayed: at once
//! from many source ports, from the key holder's own address (the proxy's
//! upstream socket is the address the bridge knows the holder by) while it
//! servos, after thousands of newer handshakes, and after a bridge restart.
//! Asserted: no replayed datagram reaches PROTO_IN, the live session loses
//! nothing, no source ever gets back more than 3x the bytes it sent, and the
//! bridge keeps serving. The figures are printed (`--nocapture`).

use std::collections::HashSet;
use std::ffi::CString;
use std::fs::File;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, UdpSocket};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use hap_auth::{ClientAuth, Psk, Reply, NONCE_LEN};
use hap_core::config::CommandType;
use hap_core::proto_in::ProtoIn;
use hap_core::protocol::{
    decode, encode, expected_len, Answer, Frame, FrameHeader, FrameType, CTRL_ACK_REQUEST,
    MAX_FRAME_LEN,
};
use virtuose_api::{Options, VirtContext};

fn mkfifo(p: &Path) {
    let c = CString::new(p.to_str().unwrap()).unwrap();
    // SAFETY: valid NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
}

/// What reached the kernel: every v1 frame read from rtf_in, in order.
type KernelLog = Arc<Mutex<Vec<Vec<u8>>>>;

/// The kernel behind the FIFOs: PROTO_IN, and an answer for every VPr
/// (as SERVO would answer every cycle). Reopens the FIFOs when a bridge
/// goes and the next one comes.
fn kernel(rin: PathBuf, rout: PathBuf, log: KernelLog, proto: Arc<Mutex<ProtoIn>>) {
    std::thread::spawn(move || {
        let mut seq = 0u32;
        loop {
            let Ok(mut f) = File::open(&rin) else { return };
            let Ok(mut out) = File::options().write(true).open(&rout) else {
                return;
            };
            let mut acc: Vec<u8> = Vec::new();
            let mut buf = [0u8; 4096];
            'bridge: loop {
                let n = match f.read(&mut buf) {
                    Ok(0) | Err(_) => break 'bridge,
                    Ok(n) => n,
                };
                acc.extend_from_slice(&buf[..n]);
                while acc.len() >= 4 {
                    let len = expected_len(&acc).expect("the bridge wrote a non-frame");
                    if acc.len() < len {
                        break;
                    }
                    let fr: Vec<u8> = acc.drain(..len).collect();
                    log.lock().unwrap().push(fr.clone());
                    let mut p = proto.lock().unwrap();
                    let o = p.handle(&fr, 1, 1000);
                    let mut replies: Vec<Frame> = o.reply.into_iter().collect();
                    if let (true, Ok((h, Frame::VprStream { .. }))) = (o.accepted, decode(&fr)) {
                        replies.push(Frame::Answer(Answer {
                            cycle: h.seq,
                            vpr_seq: h.seq,
                            ..Answer::default()
                        }));
                    }
                    for r in replies {
                        seq = seq.wrapping_add(1);
                        let h = FrameHeader {
                            control: 0,
                            session: p.session(),
                            seq,
                            timestamp_us: seq,
                        };
                        let mut b = [0u8; MAX_FRAME_LEN];
                        let n = encode(&h, &r, &mut b);
                        // The device hands the bridge one frame per read; a
                        // pipe hands it what is there: one frame at a time.
                        wait_drained(&out);
                        if out.write_all(&b[..n]).is_err() {
                            break 'bridge;
                        }
                    }
                }
            }
        }
    });
}

/// Wait (up to 100 ms) until the pipe `f` holds no unread byte.
fn wait_drained(f: &File) {
    use std::os::fd::AsRawFd;
    for _ in 0..2000 {
        let mut pending: libc::c_int = 0;
        // SAFETY: FIONREAD on a valid pipe descriptor writes one c_int.
        let rc = unsafe { libc::ioctl(f.as_raw_fd(), libc::FIONREAD, &mut pending) };
        if rc != 0 || pending == 0 {
            return;
        }
        std::thread::sleep(Duration::from_micros(50));
    }
}

struct Bridge {
    child: Child,
    addr: SocketAddr,
}

impl Bridge {
    /// The bridge with its budgets off: loopback sources all share
    /// 127.0.0.1, and the replays are to be examined (and refused) one by
    /// one here. The flood tests run it with its default budgets.
    fn start(dir: &Path, port: u16) -> Bridge {
        Bridge::start_with(
            dir,
            port,
            &[
                "--refusal-budget",
                "0",
                "--handshake-budget",
                "0",
                "--handshake-budget-per-ip",
                "0",
            ],
        )
    }

    fn start_with(dir: &Path, port: u16, extra: &[&str]) -> Bridge {
        let mut child = Command::new(env!("CARGO_BIN_EXE_proto_interface"))
            .args([
                "--bind",
                "127.0.0.1",
                "--port",
                &port.to_string(),
                "--print-addr",
            ])
            .arg("--key")
            .arg(dir.join("key"))
            .arg("--rtf-in")
            .arg(dir.join("rtf_in"))
            .arg("--rtf-out")
            .arg(dir.join("rtf_out"))
            .arg("--stats-file")
            .arg(dir.join("stats"))
            .args(extra)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        let addr = line
            .trim()
            .trim_start_matches("listening on ")
            .parse()
            .unwrap_or_else(|_| panic!("bridge did not start: {line:?}"));
        Bridge { child, addr }
    }

    fn stop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// Every counter, from one rewrite of the stats file.
    fn stats(&self, dir: &Path) -> std::collections::HashMap<String, u64> {
        // SAFETY: kill(2) on our child: rewrite the stats file now.
        unsafe { libc::kill(self.child.id() as i32, libc::SIGUSR1) };
        std::thread::sleep(Duration::from_millis(150));
        let s = std::fs::read_to_string(dir.join("stats")).unwrap_or_default();
        s.lines()
            .filter_map(|l| l.split_once(": "))
            .filter_map(|(k, v)| Some((k.to_string(), v.trim().parse().ok()?)))
            .collect()
    }

    fn stat(&self, dir: &Path, key: &str) -> u64 {
        // SAFETY: kill(2) on our child: rewrite the stats file now.
        unsafe { libc::kill(self.child.id() as i32, libc::SIGUSR1) };
        std::thread::sleep(Duration::from_millis(150));
        let s = std::fs::read_to_string(dir.join("stats")).unwrap_or_default();
        s.lines()
            .find_map(|l| l.strip_prefix(&format!("{key}: ")))
            .and_then(|v| v.trim().parse().ok())
            .unwrap_or_else(|| panic!("no {key} in {s}"))
    }
}

impl Drop for Bridge {
    fn drop(&mut self) {
        self.stop();
    }
}

/// A recording proxy for one client: the client sends to `front`; the
/// proxy relays from its `upstream` socket (the address the bridge sees)
/// and relays the bridge's answers back. Every client datagram is recorded.
struct Proxy {
    front: SocketAddr,
    upstream: UdpSocket,
    recorded: Arc<Mutex<Vec<Vec<u8>>>>,
    recording: Arc<AtomicBool>,
    /// Datagrams from the bridge to `upstream` other than answers (kinds a
    /// replay can draw: cookies, errors, acks), and their bytes.
    other_replies: Arc<AtomicU64>,
    other_reply_bytes: Arc<AtomicU64>,
    /// Breaks in the sequence numbers of the answers relayed to the client.
    answer_gaps: Arc<AtomicU64>,
    stop: Arc<AtomicBool>,
}

impl Proxy {
    fn start(bridge: SocketAddr) -> Proxy {
        let front = UdpSocket::bind("127.0.0.1:0").unwrap();
        let upstream = UdpSocket::bind("127.0.0.1:0").unwrap();
        upstream.connect(bridge).unwrap();
        for s in [&front, &upstream] {
            s.set_read_timeout(Some(Duration::from_millis(20))).unwrap();
        }
        let p = Proxy {
            front: front.local_addr().unwrap(),
            upstream: upstream.try_clone().unwrap(),
            recorded: Arc::default(),
            recording: Arc::new(AtomicBool::new(true)),
            other_replies: Arc::default(),
            other_reply_bytes: Arc::default(),
            answer_gaps: Arc::default(),
            stop: Arc::default(),
        };
        let client: Arc<Mutex<Option<SocketAddr>>> = Arc::default();
        let (f, u, c, rec, on, stop) = (
            front.try_clone().unwrap(),
            upstream.try_clone().unwrap(),
            client.clone(),
            p.recorded.clone(),
            p.recording.clone(),
            p.stop.clone(),
        );
        std::thread::spawn(move || {
            let mut buf = [0u8; 2048];
            while !stop.load(Ordering::SeqCst) {
                if let Ok((n, src)) = f.recv_from(&mut buf) {
                    *c.lock().unwrap() = Some(src);
                    if on.load(Ordering::SeqCst) {
                        rec.lock().unwrap().push(buf[..n].to_vec());
                    }
                    let _ = u.send(&buf[..n]);
                }
            }
        });
        let (others, other_bytes, stop) = (
            p.other_replies.clone(),
            p.other_reply_bytes.clone(),
            p.stop.clone(),
        );
        let last: Mutex<Option<u32>> = Mutex::new(None);
        let gaps = p.answer_gaps.clone();
        std::thread::spawn(move || {
            let mut buf = [0u8; 2048];
            while !stop.load(Ordering::SeqCst) {
                if let Ok(n) = upstream.recv(&mut buf) {
                    let ty = buf.get(3).copied().unwrap_or(0);
                    if ty == FrameType::Answer as u8 {
                        let seq = u32::from_be_bytes([buf[8], buf[9], buf[10], buf[11]]);
                        let mut l = last.lock().unwrap();
                        if l.is_some_and(|p| seq != p.wrapping_add(1)) {
                            gaps.fetch_add(1, Ordering::SeqCst);
                        }
                        *l = Some(seq);
                    }
                    if ty != FrameType::Answer as u8 && ty != FrameType::AnswerTwist as u8 {
                        others.fetch_add(1, Ordering::SeqCst);
                        other_bytes.fetch_add(n as u64, Ordering::SeqCst);
                    }
                    if let Some(to) = *client.lock().unwrap() {
                        let _ = front.send_to(&buf[..n], to);
                    }
                }
            }
        });
        p
    }

    fn address(&self) -> String {
        format!("127.0.0.1#{}", self.front.port())
    }
}

impl Drop for Proxy {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
    }
}

/// Replay `datagrams` to `bridge` from `socks` (round robin), paced so
/// that the bridge's receive buffer never overflows; then collect every
/// reply for a while. Returns (bytes sent, bytes received back, largest
/// reply) per socket.
fn replay_from(
    socks: &[UdpSocket],
    bridge: SocketAddr,
    datagrams: &[Vec<u8>],
) -> Vec<(u64, u64, usize)> {
    let mut sent = vec![0u64; socks.len()];
    for (k, d) in datagrams.iter().enumerate() {
        let i = k % socks.len();
        socks[i].send_to(d, bridge).unwrap();
        sent[i] += d.len() as u64;
        if k % 16 == 15 {
            std::thread::sleep(Duration::from_millis(2));
        }
    }
    std::thread::sleep(Duration::from_millis(200));
    let mut out = Vec::new();
    let mut buf = [0u8; 2048];
    for (i, s) in socks.iter().enumerate() {
        s.set_nonblocking(true).unwrap();
        let (mut back, mut largest) = (0u64, 0usize);
        while let Ok(n) = s.recv(&mut buf) {
            back += n as u64;
            largest = largest.max(n);
        }
        out.push((sent[i], back, largest));
    }
    out
}

/// Bytes replayed and sent back over the whole campaign.
#[derive(Default)]
struct Totals {
    sent: u64,
    back: u64,
    largest: usize,
}

impl Totals {
    /// Check and add one replay's figures: no socket got back more than 3x.
    fn tally(&mut self, r: &[(u64, u64, usize)], what: &str) {
        let (s, bk) = r.iter().fold((0, 0), |(s, b), x| (s + x.0, b + x.1));
        for (i, (sent, back, big)) in r.iter().enumerate() {
            assert!(
                *back <= 3 * *sent,
                "{what}: socket {i} got {back} bytes for {sent}"
            );
            self.largest = self.largest.max(*big);
        }
        println!(
            "replay {what}: {s} bytes replayed from {} ports, {bk} bytes back",
            r.len()
        );
        self.sent += s;
        self.back += bk;
    }
}

fn sockets(n: usize) -> Vec<UdpSocket> {
    (0..n)
        .map(|_| UdpSocket::bind("127.0.0.1:0").unwrap())
        .collect()
}

fn opts(psk: &Psk) -> Options {
    Options {
        reply_timeout: Duration::from_secs(2),
        attempts: 3,
        key: Some(psk.clone()),
        ..Options::default()
    }
}

/// The sequence numbers of the VPr frames of kernel session `session` in
/// `log[from..]`, and whether anything else is there.
fn vpr_seqs(log: &[Vec<u8>]) -> (Vec<u32>, Vec<Frame>) {
    let mut seqs = Vec::new();
    let mut others = Vec::new();
    for fr in log {
        match decode(fr) {
            Ok((h, Frame::VprStream { .. })) => seqs.push(h.seq),
            Ok((_, f)) => others.push(f),
            Err(e) => panic!("a non-frame reached the kernel: {e:?}"),
        }
    }
    (seqs, others)
}

#[test]
fn replayed_sessions_reach_nothing_disturb_nothing_and_amplify_nothing() {
    let _g = serial();
    let t0 = Instant::now();
    let dir = std::env::temp_dir().join(format!("proto_replay_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let psk = Psk::generate().unwrap();
    psk.write_new(&dir.join("key")).unwrap();
    mkfifo(&dir.join("rtf_in"));
    mkfifo(&dir.join("rtf_out"));
    let log: KernelLog = Arc::default();
    let proto = Arc::new(Mutex::new(ProtoIn::new()));
    kernel(
        dir.join("rtf_in"),
        dir.join("rtf_out"),
        log.clone(),
        proto.clone(),
    );
    let mut bridge = Bridge::start(&dir, 0);
    let port = bridge.addr.port();

    // 1. Record real sessions: one opened, configured, streamed and closed
    //    (A), one left open and servoing (B).
    let pa = Proxy::start(bridge.addr);
    let mut a = VirtContext::open_with(&pa.address(), opts(&psk)).unwrap();
    a.set_command_type(CommandType::Impedance).unwrap();
    a.set_power_on(true).unwrap();
    for i in 0..100 {
        a.set_position(&[0.001 * i as f32, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
            .unwrap();
        std::thread::sleep(Duration::from_millis(1));
    }
    a.close().unwrap();
    let pb = Proxy::start(bridge.addr);
    let b = Arc::new(VirtContext::open_with(&pb.address(), opts(&psk)).unwrap());
    let b_session = b.session_id();
    b.set_command_type(CommandType::Impedance).unwrap();
    for _ in 0..100 {
        b.set_position(&[0.01, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
            .unwrap();
        std::thread::sleep(Duration::from_millis(1));
    }
    pa.recording.store(false, Ordering::SeqCst);
    pb.recording.store(false, Ordering::SeqCst);
    let mut recorded: Vec<Vec<u8>> = pa.recorded.lock().unwrap().clone();
    recorded.extend(pb.recorded.lock().unwrap().iter().cloned());
    let hellos = recorded.iter().filter(|d| d[3] == 0x01).count();
    let proofs = recorded
        .iter()
        .filter(|d| d[3] == hap_auth::TYPE_OPEN_PROOF)
        .count();
    assert!(hellos >= 2 && proofs >= 2, "{hellos} {proofs}");
    let opened = proto.lock().unwrap().counters().sessions_opened;
    assert_eq!(opened, 2);

    // B servos at about 1 kHz from now on, until told to stop.
    let servo_stop = Arc::new(AtomicBool::new(false));
    let servo = {
        let (b, stop) = (b.clone(), servo_stop.clone());
        std::thread::spawn(move || {
            let mut n = 0u64;
            while !stop.load(Ordering::SeqCst) {
                b.set_position(&[0.02, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
                    .unwrap();
                n += 1;
                std::thread::sleep(Duration::from_millis(1));
            }
            n
        })
    };
    let mark = log.lock().unwrap().len();
    let mut totals = Totals::default();

    // 2a. At once, from 50 source ports.
    let socks = sockets(50);
    let r = replay_from(&socks, bridge.addr, &recorded);
    totals.tally(&r, "at once");
    // 2b. From the key holder's own address (the proxy's upstream socket,
    //     which the bridge knows as B's client) while B servos.
    let before = (
        pb.other_replies.load(Ordering::SeqCst),
        pb.other_reply_bytes.load(Ordering::SeqCst),
    );
    let holder = [pb.upstream.try_clone().unwrap()];
    let mut replayed_bytes = 0u64;
    for (k, d) in recorded.iter().enumerate() {
        holder[0].send(d).unwrap();
        replayed_bytes += d.len() as u64;
        if k % 16 == 15 {
            std::thread::sleep(Duration::from_millis(2));
        }
    }
    std::thread::sleep(Duration::from_millis(300));
    let back = pb.other_reply_bytes.load(Ordering::SeqCst) - before.1;
    println!(
        "replay from the holder's address: {replayed_bytes} bytes replayed, {back} bytes of \
         non-answer replies ({} datagrams)",
        pb.other_replies.load(Ordering::SeqCst) - before.0
    );
    assert!(back <= 3 * replayed_bytes);
    totals.sent += replayed_bytes;
    totals.back += back;

    // Nothing of it reached the kernel: only B's live VPr stream, every
    // number once and in order, in B's session.
    servo_stop.store(true, Ordering::SeqCst);
    let servoed = servo.join().unwrap();
    std::thread::sleep(Duration::from_millis(200));
    let (seqs, others) = vpr_seqs(&log.lock().unwrap()[mark..]);
    assert!(
        others.is_empty(),
        "non-VPr frames reached the kernel: {others:?}"
    );
    assert_eq!(
        seqs.len() as u64,
        servoed,
        "the live session lost or gained VPr frames"
    );
    assert!(
        seqs.windows(2).all(|w| w[1] == w[0].wrapping_add(1)),
        "a gap in the live stream"
    );
    assert_eq!(
        proto.lock().unwrap().session(),
        b_session,
        "the live session was replaced"
    );
    assert_eq!(proto.lock().unwrap().counters().sessions_opened, opened);
    let st = b.link_stats();
    assert_eq!(st.lost, 0, "{st:?}");
    assert_eq!(
        pb.answer_gaps.load(Ordering::SeqCst),
        0,
        "answers missing on the wire"
    );
    assert!(st.answers >= servoed, "{st:?}");
    println!(
        "live session during the replays: {servoed} VPr sent, {} forwarded in order, {} answers, {} lost",
        seqs.len(),
        st.answers,
        st.lost
    );
    drop(b);

    // 3. After 2000 newer handshakes (each proven and committed).
    let s = UdpSocket::bind("127.0.0.1:0").unwrap();
    s.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
    s.connect(bridge.addr).unwrap();
    let mut buf = [0u8; 256];
    let newer = 2000u32;
    for k in 0..newer {
        let mut c = ClientAuth::new(psk.clone());
        let mut nc = [0u8; NONCE_LEN];
        nc[..4].copy_from_slice(&k.to_be_bytes());
        nc[4..8].copy_from_slice(&std::process::id().to_be_bytes());
        let h = |seq: u32| FrameHeader {
            control: 0,
            session: 0,
            seq,
            timestamp_us: seq,
        };
        // One client numbering on: each proof newer than the last (a proof
        // from the live session's client commits only forward).
        s.send(c.hello(&h(2 * k + 1), nc).bytes()).unwrap();
        loop {
            let n = s.recv(&mut buf).expect("cookie");
            if let Ok((_, Reply::Cookie)) = c.open(&buf[..n]) {
                break;
            }
        }
        s.send(c.prove(&h(2 * k + 2)).unwrap().bytes()).unwrap();
        loop {
            let n = s.recv(&mut buf).expect("session_ack");
            match c.open(&buf[..n]) {
                Ok((_, Reply::SessionAck { .. })) => break,
                Ok((_, Reply::HandshakeRefused { reason })) => {
                    panic!("handshake {k} refused: {reason:#x}")
                }
                _ => {}
            }
        }
    }
    let opened = proto.lock().unwrap().counters().sessions_opened;
    assert_eq!(opened, 2 + u64::from(newer));
    let mark = log.lock().unwrap().len();
    let r = replay_from(&sockets(20), bridge.addr, &recorded);
    totals.tally(&r, "after 2000 newer handshakes");
    std::thread::sleep(Duration::from_millis(100));
    assert_eq!(
        log.lock().unwrap().len(),
        mark,
        "a replay reached the kernel"
    );

    // 4. After a bridge restart (same port, a new cookie secret).
    bridge.stop();
    bridge = Bridge::start(&dir, port);
    let probe = VirtContext::open_with(&format!("127.0.0.1#{port}"), opts(&psk)).unwrap();
    drop(probe);
    std::thread::sleep(Duration::from_millis(100));
    let mark = log.lock().unwrap().len();
    let opened = proto.lock().unwrap().counters().sessions_opened;
    let r = replay_from(&sockets(20), bridge.addr, &recorded);
    totals.tally(&r, "after a bridge restart");
    std::thread::sleep(Duration::from_millis(100));
    assert_eq!(
        log.lock().unwrap().len(),
        mark,
        "a replay reached the kernel"
    );
    assert_eq!(proto.lock().unwrap().counters().sessions_opened, opened);
    assert!(bridge.stat(&dir, "rejected_bad_cookie") >= proofs as u64);

    // The bridge keeps serving: a new session, configured and streaming.
    let mut c = VirtContext::open_with(&format!("127.0.0.1#{port}"), opts(&psk)).unwrap();
    c.set_command_type(CommandType::Impedance).unwrap();
    c.set_position(&[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
        .unwrap();
    assert!(c.wait_answer(Duration::from_secs(1)));
    c.close().unwrap();
    assert_eq!(bridge.stat(&dir, "amplification_refused"), 0);

    let uniq: HashSet<&Vec<u8>> = recorded.iter().collect();
    println!(
        "replay campaign (host native, loopback): {} recorded client datagrams ({} distinct), \
         {} bytes replayed, {} bytes sent back (ratio {:.3}), largest reply {} bytes; {:.1} s",
        recorded.len(),
        uniq.len(),
        totals.sent,
        totals.back,
        totals.back as f64 / totals.sent.max(1) as f64,
        totals.largest,
        t0.elapsed().as_secs_f64()
    );
    bridge.stop();
    let _ = std::fs::remove_dir_all(&dir);
}

// ---------------------------------------------------------------------------
// Floods, held-back proofs and what the C ABI reports.
//
// The tests of this file share the machine's two cores: they take turns.

static SERIAL: Mutex<()> = Mutex::new(());

fn serial() -> std::sync::MutexGuard<'static, ()> {
    SERIAL.lock().unwrap_or_else(|e| e.into_inner())
}

/// A directory with a key, the two FIFOs and a fresh PSK.
fn rig_dir(tag: &str) -> (PathBuf, Psk) {
    let dir = std::env::temp_dir().join(format!("proto_{tag}_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let psk = Psk::generate().unwrap();
    psk.write_new(&dir.join("key")).unwrap();
    mkfifo(&dir.join("rtf_in"));
    mkfifo(&dir.join("rtf_out"));
    (dir, psk)
}

/// What the servo kernel did.
#[derive(Default)]
struct ServoCounts {
    /// `answer` frames written, in total.
    answers: AtomicU64,
    /// Servo periods that found the output busy for a whole period (the
    /// bridge's reader late): no answer that period.
    skipped: AtomicU64,
    stop: AtomicBool,
}

/// The kernel behind the FIFOs as the module is: PROTO_IN, and an `answer`
/// every 1 ms period while a session is open (SERVO), whether or not a VPr
/// came; its `vpr_seq` is the newest VPr's. One frame at a time on the
/// output (the device hands the bridge one frame per read).
fn servo_kernel(rin: PathBuf, rout: PathBuf, proto: Arc<Mutex<ProtoIn>>) -> Arc<ServoCounts> {
    let counts = Arc::new(ServoCounts::default());
    let out: Arc<Mutex<Option<File>>> = Arc::default();
    let seq = Arc::new(AtomicU64::new(0));
    let write = {
        let (out, seq) = (out.clone(), seq.clone());
        move |f: Frame, session: u16| -> bool {
            let mut o = out.lock().unwrap();
            let Some(file) = o.as_mut() else {
                return false;
            };
            let s = seq.fetch_add(1, Ordering::SeqCst) as u32 + 1;
            let h = FrameHeader {
                control: 0,
                session,
                seq: s,
                timestamp_us: s,
            };
            let mut b = [0u8; MAX_FRAME_LEN];
            let n = encode(&h, &f, &mut b);
            wait_drained(file);
            file.write_all(&b[..n]).is_ok()
        }
    };
    {
        let (proto, write, out) = (proto.clone(), write.clone(), out.clone());
        std::thread::spawn(move || {
            let Ok(mut f) = File::open(&rin) else { return };
            let Ok(o) = File::options().write(true).open(&rout) else {
                return;
            };
            *out.lock().unwrap() = Some(o);
            let mut acc: Vec<u8> = Vec::new();
            let mut buf = [0u8; 4096];
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
                    let (reply, session) = {
                        let mut p = proto.lock().unwrap();
                        let o = p.handle(&fr, 1, 1000);
                        (o.reply, p.session())
                    };
                    if let Some(r) = reply {
                        write(r, session);
                    }
                }
            }
        });
    }
    {
        let counts = counts.clone();
        std::thread::spawn(move || {
            let period = Duration::from_millis(1);
            let mut next = Instant::now() + period;
            let mut cycle = 0u32;
            while !counts.stop.load(Ordering::SeqCst) {
                let now = Instant::now();
                if next > now {
                    std::thread::sleep(next - now);
                }
                next += period;
                if next + period < Instant::now() {
                    // Late by more than a period: as SERVO, no catch-up burst.
                    counts.skipped.fetch_add(1, Ordering::SeqCst);
                    next = Instant::now() + period;
                }
                cycle = cycle.wrapping_add(1);
                let (session, vpr_seq) = {
                    let p = proto.lock().unwrap();
                    (p.session(), p.vpr().seq)
                };
                if session == 0 {
                    continue;
                }
                let a = Answer {
                    cycle,
                    vpr_seq,
                    ..Answer::default()
                };
                if write(Frame::Answer(a), session) {
                    counts.answers.fetch_add(1, Ordering::SeqCst);
                }
            }
        });
    }
    counts
}

/// The bridge's socket as the kernel sees it (`/proc/net/udp`): bytes
/// waiting to be read, and datagrams the kernel dropped for a full buffer.
fn udp_queue(port: u16) -> Option<(u64, u64)> {
    let text = std::fs::read_to_string("/proc/net/udp").ok()?;
    let local = format!("0100007F:{port:04X}");
    let line = text
        .lines()
        .find(|l| l.split_whitespace().nth(1) == Some(local.as_str()))?;
    let f: Vec<&str> = line.split_whitespace().collect();
    let rx = u64::from_str_radix(f.get(4)?.split(':').nth(1)?, 16).ok()?;
    let drops = f.last()?.parse().ok()?;
    Some((rx, drops))
}

/// Bytes kept waiting on the bridge's socket by the flooder: half its
/// receive buffer (the bridge asks for 1 MiB, the kernel grants up to
/// `net.core.rmem_max` and doubles it), enough that the bridge never finds
/// it empty, little enough that it never overflows (so that every datagram
/// the key holder sends is read, if late).
fn flood_queue() -> u64 {
    let max: u64 = std::fs::read_to_string("/proc/sys/net/core/rmem_max")
        .ok()
        .and_then(|s| s.trim().parse().ok())
        .unwrap_or(212_992);
    max.min(1 << 20)
}

/// A flood at the rate the bridge's socket can read: its sender keeps the
/// socket's receive queue at [`flood_queue`] bytes (read from
/// `/proc/net/udp` after every 256 datagrams), from `socks` in turn, the
/// datagrams of `kinds` in turn.
struct Flooder {
    stop: Arc<AtomicBool>,
    sent: Arc<AtomicU64>,
    /// Queue samples taken, and those that found the socket empty (the
    /// bridge had caught up: the flood was slower than it could read).
    samples: Arc<AtomicU64>,
    empty: Arc<AtomicU64>,
    threads: Vec<std::thread::JoinHandle<()>>,
}

/// Sending threads of a flood (one alone is at times slower than the
/// bridge reads).
const FLOOD_THREADS: usize = 2;

impl Flooder {
    fn start(to: SocketAddr, socks: Vec<UdpSocket>, kinds: Vec<Vec<u8>>) -> Flooder {
        let stop = Arc::new(AtomicBool::new(false));
        let sent = Arc::new(AtomicU64::new(0));
        let samples = Arc::new(AtomicU64::new(0));
        let empty = Arc::new(AtomicU64::new(0));
        let high = flood_queue();
        let socks = Arc::new(socks);
        let kinds = Arc::new(kinds);
        let threads = (0..FLOOD_THREADS)
            .map(|t| {
                let (st, se, sa, em) = (stop.clone(), sent.clone(), samples.clone(), empty.clone());
                let (socks, kinds) = (socks.clone(), kinds.clone());
                std::thread::spawn(move || {
                    let mut k = t;
                    while !st.load(Ordering::SeqCst) {
                        for _ in 0..256 {
                            let s = &socks[k % socks.len()];
                            let d = &kinds[(k / socks.len()) % kinds.len()];
                            if s.send_to(d, to).is_ok() {
                                se.fetch_add(1, Ordering::Relaxed);
                            }
                            k += FLOOD_THREADS;
                        }
                        loop {
                            let q = udp_queue(to.port()).map_or(0, |q| q.0);
                            sa.fetch_add(1, Ordering::Relaxed);
                            if q == 0 {
                                em.fetch_add(1, Ordering::Relaxed);
                            }
                            if q <= high || st.load(Ordering::SeqCst) {
                                break;
                            }
                            std::thread::sleep(Duration::from_micros(200));
                        }
                    }
                })
            })
            .collect();
        Flooder {
            stop,
            sent,
            samples,
            empty,
            threads,
        }
    }

    fn stop(&mut self) -> u64 {
        self.stop.store(true, Ordering::SeqCst);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
        self.sent.load(Ordering::SeqCst)
    }
}

impl Drop for Flooder {
    fn drop(&mut self) {
        self.stop();
    }
}

/// One socket at 127.0.0.1 (the key holder's own IP), or `n` sockets at
/// 127.0.0.2, 127.0.0.3, ... (each its own source IP).
fn flood_sockets(n: usize) -> Vec<UdpSocket> {
    if n == 1 {
        return vec![UdpSocket::bind("127.0.0.1:0").unwrap()];
    }
    (0..n)
        .map(|i| UdpSocket::bind(SocketAddr::from(([127, 0, 0, 2 + i as u8], 0))).unwrap())
        .collect()
}

/// Keyless datagrams: half of them the 4 bytes `48 43 02 01`, the others
/// full size: 90 bytes of noise after "HC" 2 1, a 48-byte `open_session`
/// under another key, 68-byte `open_proof`s with the bridge's first live
/// epochs and nonces of their own (each costs the bridge one HMAC to
/// refute), an 84-byte `vpr_stream` with the live session's id.
fn keyless_datagrams(session: u16) -> Vec<Vec<u8>> {
    let mut x = 0x2545_f491_u32;
    let mut noise = |n: usize| -> Vec<u8> {
        (0..n)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 17;
                x ^= x << 5;
                x as u8
            })
            .collect()
    };
    let four = vec![0x48, 0x43, 0x02, 0x01];
    let mut full = vec![0x48, 0x43, 0x02, 0x01];
    full.extend(noise(86));
    let stranger = ClientAuth::new(Psk::generate().unwrap());
    let mut stranger = stranger;
    let h = |seq: u32, session: u16| FrameHeader {
        control: 0,
        session,
        seq,
        timestamp_us: seq,
    };
    let mut nc = [0u8; NONCE_LEN];
    nc.copy_from_slice(&noise(NONCE_LEN));
    let hello = stranger.hello(&h(1, 0), nc).bytes().to_vec();
    let mut out = vec![four.clone(), full, hello];
    for epoch in 0..3u32 {
        let mut p = vec![0x48, 0x43, 0x02, hap_auth::TYPE_OPEN_PROOF];
        p.extend([0u8; 12]);
        p.extend(noise(2 * NONCE_LEN));
        p.extend(epoch.to_be_bytes());
        p.extend(noise(16));
        assert_eq!(p.len(), hap_auth::PROOF_FRAME_LEN);
        out.push(p);
    }
    let mut v = vec![0x48, 0x43, 0x02, 0x0c, 0, 0];
    v.extend(session.to_be_bytes());
    v.extend(0x4000_0000u32.to_be_bytes());
    v.extend(noise(84 - 12));
    out.push(v);
    // Half of them 4 bytes.
    let n = out.len();
    out.extend(std::iter::repeat_n(four, n));
    out
}

/// `p`-th percentile (0..=100) of sorted `v`.
fn pct(v: &[u32], p: usize) -> u32 {
    if v.is_empty() {
        return 0;
    }
    v[(v.len() - 1) * p / 100]
}

/// What one flood run measured.
struct FloodFigures {
    opened: usize,
    tries: usize,
}

/// A flood of `kinds` from `socks` against the bridge with its default
/// budgets, while (1) a live session servos at 1 kHz for 2 s, then (2) the
/// key holder opens fresh sessions 100 times (each a new context: a new
/// source port; each replaces the last). Asserts on counts only; prints
/// the rates and times it measured.
fn flood_run(
    name: &str,
    socks: Vec<UdpSocket>,
    kinds: impl Fn(u16) -> Vec<Vec<u8>>,
) -> FloodFigures {
    let t0 = Instant::now();
    let (dir, psk) = rig_dir(name);
    let proto = Arc::new(Mutex::new(ProtoIn::new()));
    let servo = servo_kernel(dir.join("rtf_in"), dir.join("rtf_out"), proto.clone());
    let bridge = Bridge::start_with(&dir, 0, &[]);
    let port = bridge.addr.port();
    let addr = format!("127.0.0.1#{port}");
    let opts = Options {
        key: Some(psk.clone()),
        ..Options::default()
    };

    // The live session, opened before the flood.
    let live = Arc::new(VirtContext::open_with(&addr, opts.clone()).unwrap());
    live.set_command_type(CommandType::Impedance).unwrap();
    let live_session = live.session_id();
    let n_sources = socks.len();
    let received0 = bridge.stat(&dir, "received");
    let drops0 = udp_queue(port).map_or(0, |q| q.1);
    // The same without a flood, for comparison: the host's own figures.
    let quiet = live_servo(&live, &servo, 1000);
    println!("{name}: live session without a flood: {quiet}");
    let mut flood = Flooder::start(bridge.addr, socks, kinds(live_session));
    let flood_t0 = Instant::now();
    std::thread::sleep(Duration::from_millis(300));

    // (1) The live session servos at 1 kHz under the flood, until the
    // servo wrote 2000 answers (or 10 s went by).
    let flooded = live_servo(&live, &servo, 2000);
    println!("{name}: live session under the flood: {flooded}");
    assert_eq!(live.check_session(), Ok(()), "the live session was ended");
    assert_eq!(proto.lock().unwrap().session(), live_session);
    assert_eq!(flooded.lost, 0, "answers lost on the way");
    // Every answer the servo wrote reached the client.
    assert!(
        flooded.received + 5 >= flooded.written,
        "{} answers for {}",
        flooded.received,
        flooded.written
    );

    // (2) Fresh opens by the key holder under the same flood.
    let opens_t0 = Instant::now();
    let mut rounds: Vec<u32> = Vec::new();
    let mut open_ms: Vec<u32> = Vec::new();
    let mut failures = Vec::new();
    let tries = 100;
    let sessions0 = proto.lock().unwrap().counters().sessions_opened;
    for k in 0..tries {
        let t = Instant::now();
        match VirtContext::open_with(&addr, opts.clone()) {
            Ok(mut vc) => {
                open_ms.push(t.elapsed().as_millis() as u32);
                rounds.push(vc.open_attempts());
                // The session is the kernel's: its answers come.
                if !vc.wait_answer(Duration::from_secs(2)) {
                    failures.push(format!("try {k}: no answer"));
                }
                let _ = vc.close();
            }
            Err(e) => failures.push(format!("try {k}: {e}")),
        }
    }
    let opens_secs = opens_t0.elapsed().as_secs_f64();
    let sessions = proto.lock().unwrap().counters().sessions_opened - sessions0;
    let flood_secs = flood_t0.elapsed().as_secs_f64();
    let flood_sent = flood.stop();
    let (samples, empty) = (
        flood.samples.load(Ordering::SeqCst),
        flood.empty.load(Ordering::SeqCst),
    );
    let received = bridge.stat(&dir, "received") - received0;
    let drops = udp_queue(port).map_or(0, |q| q.1) - drops0;
    open_ms.sort_unstable();
    let within_two = rounds.iter().filter(|r| **r <= 2).count();
    let stat = |k: &str| bridge.stat(&dir, k);
    println!(
        "{name}: {within_two} of {tries} fresh opens within two rounds ({} opened; rounds: {} in \
         one, {} in two, {} in more); open time p50 {} ms, p99 {} ms, max {} ms; {sessions} \
         sessions opened in the kernel; {:.1} s",
        rounds.len(),
        rounds.iter().filter(|r| **r == 1).count(),
        rounds.iter().filter(|r| **r == 2).count(),
        rounds.iter().filter(|r| **r > 2).count(),
        pct(&open_ms, 50),
        pct(&open_ms, 99),
        open_ms.last().copied().unwrap_or(0),
        opens_secs
    );
    println!(
        "{name}: flood from {n_sources} source address(es): {flood_sent} datagrams sent, {received} \
         read by the bridge in {flood_secs:.1} s ({:.0}/s), {drops} dropped by the kernel for a \
         full socket buffer, its queue empty in {empty} of {samples} samples; refused: undersize {}, length_mismatch {}, bad_tag {}, bad_cookie \
         {}, wrong_session {}, rate_limited {}, hello_replay {}, handshake_budget {}, \
         handshake_ip_budget {}; cookies {} ({} under load); (host native, loopback, {})",
        received as f64 / flood_secs,
        stat("rejected_undersize"),
        stat("rejected_length_mismatch"),
        stat("rejected_bad_tag"),
        stat("rejected_bad_cookie"),
        stat("rejected_wrong_session"),
        stat("rejected_rate_limited"),
        stat("rejected_hello_replay"),
        stat("rejected_handshake_budget"),
        stat("rejected_handshake_ip_budget"),
        stat("cookies_sent"),
        stat("cookies_under_load"),
        date()
    );
    for f in &failures {
        println!("{name}: {f}");
    }
    // Every datagram the bridge read is accounted for (the flood over, the
    // sessions closed: a stable count).
    std::thread::sleep(Duration::from_millis(200));
    let all = bridge.stats(&dir);
    let get = |k: &str| all.get(k).copied().unwrap_or_else(|| panic!("no {k}"));
    assert_eq!(get("write_errors") + get("send_errors"), 0);
    assert_eq!(
        get("received"),
        get("forwarded")
            + get("rejected")
            + get("retransmits_reacked")
            + get("proofs_reacked")
            + get("cookies_sent"),
        "{all:?}"
    );
    // Each open that succeeded opened exactly one kernel session (a round
    // that sent the proof again opened none).
    assert_eq!(
        sessions,
        rounds.len() as u64,
        "sessions opened in the kernel"
    );
    // Nothing of the flood reached the kernel: every frame it read came
    // from a key holder (PROTO_IN refused none).
    assert_eq!(proto.lock().unwrap().counters().rejected_total(), 0);
    assert!(
        received >= 10_000,
        "the bridge read only {received} datagrams: no flood"
    );
    assert!(failures.len() <= 1, "{failures:?}");
    assert!(
        within_two >= tries * 99 / 100,
        "{within_two} of {tries} opened within two rounds"
    );
    servo.stop.store(true, Ordering::SeqCst);
    println!("{name}: {:.1} s in all", t0.elapsed().as_secs_f64());
    drop(bridge);
    let _ = std::fs::remove_dir_all(&dir);
    FloodFigures {
        opened: within_two,
        tries,
    }
}

/// What a live session saw while it servoed.
struct Servoed {
    secs: f64,
    vpr_sent: u64,
    written: u64,
    received: u64,
    lost: u64,
    skipped: u64,
    rtt_us: Vec<u32>,
}

impl std::fmt::Display for Servoed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} VPr sent in {:.2} s, {} answers received for {} written by the servo ({:.0} Hz \
             received), {} lost, {} servo periods skipped (the servo thread late); RTT p50 {} \
             us, p99 {} us, max {} us ({} samples)",
            self.vpr_sent,
            self.secs,
            self.received,
            self.written,
            self.received as f64 / self.secs,
            self.lost,
            self.skipped,
            pct(&self.rtt_us, 50),
            pct(&self.rtt_us, 99),
            self.rtt_us.last().copied().unwrap_or(0),
            self.rtt_us.len()
        )
    }
}

/// `live` streams a VPr every 1 ms until the servo kernel wrote `answers`
/// more answers (at most 10 s); then 200 ms for the last ones to arrive.
fn live_servo(live: &Arc<VirtContext>, servo: &ServoCounts, answers: u64) -> Servoed {
    live.record_rtt(false);
    live.record_rtt(true);
    let before = live.link_stats();
    let written0 = servo.answers.load(Ordering::SeqCst);
    let skipped0 = servo.skipped.load(Ordering::SeqCst);
    let t0 = Instant::now();
    let mut next = t0;
    let mut vpr_sent = 0;
    while servo.answers.load(Ordering::SeqCst) - written0 < answers
        && t0.elapsed() < Duration::from_secs(10)
    {
        if live
            .set_position(&[0.01, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
            .is_ok()
        {
            vpr_sent += 1;
        }
        next += Duration::from_millis(1);
        let now = Instant::now();
        if next > now {
            std::thread::sleep(next - now);
        } else {
            next = now;
        }
    }
    let secs = t0.elapsed().as_secs_f64();
    let written = servo.answers.load(Ordering::SeqCst) - written0;
    let skipped = servo.skipped.load(Ordering::SeqCst) - skipped0;
    std::thread::sleep(Duration::from_millis(200));
    let after = live.link_stats();
    let mut rtt = Vec::new();
    live.drain_rtt(&mut rtt);
    let mut rtt_us: Vec<u32> = rtt.iter().map(|s| s.rtt_us).collect();
    rtt_us.sort_unstable();
    // Those written in the window, received in it or in the 200 ms after
    // (the servo goes on writing: the surplus is not counted).
    let received = (after.answers - before.answers).min(written);
    Servoed {
        secs,
        vpr_sent,
        written,
        received,
        lost: after.lost - before.lost,
        skipped,
        rtt_us,
    }
}

fn date() -> String {
    Command::new("date")
        .arg("+%Y-%m-%d")
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .unwrap_or_default()
}

#[test]
fn a_keyless_flood_from_one_socket_never_locks_the_key_holder_out() {
    let _g = serial();
    let f = flood_run("flood-one-socket", flood_sockets(1), keyless_datagrams);
    assert!(f.opened * 100 >= f.tries * 99);
}

#[test]
fn a_keyless_flood_from_64_addresses_never_locks_the_key_holder_out() {
    let _g = serial();
    let f = flood_run("flood-64-addresses", flood_sockets(64), keyless_datagrams);
    assert!(f.opened * 100 >= f.tries * 99);
}

/// Valid `open_session`s, recorded, replayed: from 64 addresses an archive
/// of 20 000 (more than the bridge remembers: the global cookie budget is
/// spent, the bridge is under load and serves the IPs that answered a
/// cookie first); from one socket at the key holder's own IP, 50 (each
/// draws one cookie, then nothing).
#[test]
fn replayed_open_sessions_from_many_addresses_leave_the_key_holder_served_first() {
    let _g = serial();
    fn archive(psk: &Psk, n: u32, tag: u8) -> Vec<Vec<u8>> {
        (0..n)
            .map(|k| {
                let mut nc = [tag; NONCE_LEN];
                nc[..4].copy_from_slice(&k.to_be_bytes());
                let h = FrameHeader {
                    control: 0,
                    session: 0,
                    seq: k,
                    timestamp_us: k,
                };
                ClientAuth::new(psk.clone()).hello(&h, nc).bytes().to_vec()
            })
            .collect()
    }
    // The flood_run's key is made inside it: the archive is made from the
    // key file it wrote, as a recorder of that key holder would have it.
    let psk_of = |name: &str| {
        let dir = std::env::temp_dir().join(format!("proto_{name}_{}", std::process::id()));
        Psk::load(&dir.join("key")).unwrap()
    };
    let many = flood_run("replay-64-addresses", flood_sockets(64), |_| {
        archive(&psk_of("replay-64-addresses"), 20_000, 0xa5)
    });
    assert!(many.opened * 100 >= many.tries * 99);
    let one = flood_run("replay-one-socket", flood_sockets(1), |_| {
        archive(&psk_of("replay-one-socket"), 50, 0x5a)
    });
    assert!(one.opened * 100 >= one.tries * 99);
}

/// A proxy in front of the bridge that holds back the client's
/// `open_proof`s: every one sent within `hold` of the first arrives at
/// `first + hold`, in order (`only_first`: the first one alone is held,
/// the others pass). Everything else passes at once, both ways.
struct HoldingProxy {
    front: SocketAddr,
    held: Arc<AtomicU64>,
    /// Every `open_proof` the client sent.
    proofs: Arc<Mutex<Vec<Vec<u8>>>>,
    stop: Arc<AtomicBool>,
}

impl HoldingProxy {
    fn start(bridge: SocketAddr, hold: Duration, only_first: bool) -> HoldingProxy {
        let front = UdpSocket::bind("127.0.0.1:0").unwrap();
        let upstream = UdpSocket::bind("127.0.0.1:0").unwrap();
        upstream.connect(bridge).unwrap();
        for s in [&front, &upstream] {
            s.set_read_timeout(Some(Duration::from_millis(20))).unwrap();
        }
        let p = HoldingProxy {
            front: front.local_addr().unwrap(),
            held: Arc::default(),
            proofs: Arc::default(),
            stop: Arc::default(),
        };
        let client: Arc<Mutex<Option<SocketAddr>>> = Arc::default();
        let (f, u, c, stop, held, proofs) = (
            front.try_clone().unwrap(),
            upstream.try_clone().unwrap(),
            client.clone(),
            p.stop.clone(),
            p.held.clone(),
            p.proofs.clone(),
        );
        std::thread::spawn(move || {
            let mut buf = [0u8; 2048];
            let mut first: Option<Instant> = None;
            while !stop.load(Ordering::SeqCst) {
                let Ok((n, src)) = f.recv_from(&mut buf) else {
                    continue;
                };
                *c.lock().unwrap() = Some(src);
                let d = buf[..n].to_vec();
                let proof = d.get(3) == Some(&hap_auth::TYPE_OPEN_PROOF);
                if proof {
                    proofs.lock().unwrap().push(d.clone());
                }
                let now = Instant::now();
                let release = match (proof, first) {
                    (true, None) => {
                        first = Some(now);
                        Some(now + hold)
                    }
                    (true, Some(t)) if !only_first && now < t + hold => Some(t + hold),
                    _ => None,
                };
                match release {
                    Some(at) => {
                        held.fetch_add(1, Ordering::SeqCst);
                        let u = u.try_clone().unwrap();
                        std::thread::spawn(move || {
                            std::thread::sleep(at.saturating_duration_since(Instant::now()));
                            let _ = u.send(&d);
                        });
                    }
                    None => {
                        let _ = u.send(&d);
                    }
                }
            }
        });
        let stop = p.stop.clone();
        std::thread::spawn(move || {
            let mut buf = [0u8; 2048];
            while !stop.load(Ordering::SeqCst) {
                if let Ok(n) = upstream.recv(&mut buf) {
                    if let Some(to) = *client.lock().unwrap() {
                        let _ = front.send_to(&buf[..n], to);
                    }
                }
            }
        });
        p
    }

    fn address(&self) -> String {
        format!("127.0.0.1#{}", self.front.port())
    }
}

impl Drop for HoldingProxy {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
    }
}

/// The library through a link that holds its `open_proof` back by 400 ms
/// (the first alone, or every one of the first 400 ms): its second round
/// sends the same proof again, never a new attempt's; the held proof
/// arrives after the session opened and changes nothing. Exactly one
/// session opens in the kernel, and it servos 300 set-points unbroken.
#[test]
fn a_held_back_open_proof_never_replaces_the_session_and_one_session_opens() {
    let _g = serial();
    let (dir, psk) = rig_dir("held_proof");
    let proto = Arc::new(Mutex::new(ProtoIn::new()));
    let servo = servo_kernel(dir.join("rtf_in"), dir.join("rtf_out"), proto.clone());
    let bridge = Bridge::start_with(&dir, 0, &[]);
    let opts = Options {
        key: Some(psk.clone()),
        ..Options::default()
    };
    for only_first in [true, false] {
        let proxy = HoldingProxy::start(bridge.addr, Duration::from_millis(400), only_first);
        let opened0 = proto.lock().unwrap().counters().sessions_opened;
        let reacked0 = bridge.stat(&dir, "proofs_reacked");
        let replays0 = bridge.stat(&dir, "rejected_handshake_replay");
        let vc = VirtContext::open_with(&proxy.address(), opts.clone()).unwrap();
        let session = vc.session_id();
        // The held proof (and any copy) arrives at 400 ms: wait past it.
        std::thread::sleep(Duration::from_millis(600));
        let held = proxy.held.load(Ordering::SeqCst);
        let mut answered = 0;
        for k in 0..300 {
            vc.set_position(&[0.001 * k as f32, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
                .unwrap();
            if vc.wait_answer(Duration::from_millis(100)) {
                answered += 1;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        let opened = proto.lock().unwrap().counters().sessions_opened - opened0;
        let reacked = bridge.stat(&dir, "proofs_reacked") - reacked0;
        let replays = bridge.stat(&dir, "rejected_handshake_replay") - replays0;
        println!(
            "held-back proof ({}): opened in {} rounds, {held} proof(s) held 400 ms, {reacked} \
             answered with the session_ack again, {replays} refused as a copy before the \
             kernel's session_ack, {opened} session(s) opened in the kernel, 300 set-points: \
             {answered} answered, session ended: {:?}",
            if only_first {
                "the first"
            } else {
                "all of the first 400 ms"
            },
            vc.open_attempts(),
            vc.session_ended()
        );
        assert!(held >= 1, "nothing was held back");
        // One proof, sent again as it was (never a second attempt's).
        let proofs = proxy.proofs.lock().unwrap().clone();
        assert!(proofs.len() >= 2, "the proof was not sent again");
        assert!(proofs.iter().all(|p| *p == proofs[0]), "a second proof");
        assert!(vc.open_attempts() >= 2);
        assert_eq!(opened, 1, "one session opened in the kernel");
        // The copies arrived: each answered with the session_ack, or, while
        // the kernel had not granted the session yet, dropped.
        assert!(reacked + replays >= 1, "the held proof was taken for new");
        assert_eq!(vc.check_session(), Ok(()));
        assert_eq!(proto.lock().unwrap().session(), session);
        assert_eq!(answered, 300);
        assert_eq!(vc.link_stats().lost, 0);
        drop(vc);
    }
    assert_eq!(bridge.stat(&dir, "rejected_stale_proof"), 0);
    servo.stop.store(true, Ordering::SeqCst);
    drop(bridge);
    let _ = std::fs::remove_dir_all(&dir);
}

/// A client that does abandon an attempt (a new `open_session` after its
/// proof went out; `virtuose_api` never does), its old proof delivered late
/// from the same address: refused (`stale_proof`), the live session
/// stays. A copy of the live session's own proof gets its session_ack
/// again. The key holder on another port still takes the session.
#[test]
fn a_late_open_proof_of_an_abandoned_attempt_is_refused() {
    let _g = serial();
    let (dir, psk) = rig_dir("late_proof");
    let proto = Arc::new(Mutex::new(ProtoIn::new()));
    let servo = servo_kernel(dir.join("rtf_in"), dir.join("rtf_out"), proto.clone());
    let bridge = Bridge::start_with(&dir, 0, &[]);
    let s = UdpSocket::bind("127.0.0.1:0").unwrap();
    s.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
    s.connect(bridge.addr).unwrap();
    let h = |seq: u32, session: u16, control: u16| FrameHeader {
        control,
        session,
        seq,
        timestamp_us: seq,
    };
    let mut buf = [0u8; 256];
    let mut recv = |c: &mut ClientAuth| -> Reply {
        loop {
            let n = s.recv(&mut buf).expect("a reply");
            if let Ok((_, r)) = c.open(&buf[..n]) {
                if !matches!(r, Reply::Frame(Frame::Answer(_))) {
                    return r;
                }
            }
        }
    };
    // Attempt 1: its proof is made and kept back.
    let mut a = ClientAuth::new(psk.clone());
    s.send(a.hello(&h(1, 0, 0), [0x71; NONCE_LEN]).bytes())
        .unwrap();
    assert_eq!(recv(&mut a), Reply::Cookie);
    let late = a.prove(&h(2, 0, 0)).unwrap();
    // Attempt 2 of the same client opens the session.
    let mut b = ClientAuth::new(psk.clone());
    s.send(b.hello(&h(3, 0, 0), [0x72; NONCE_LEN]).bytes())
        .unwrap();
    assert_eq!(recv(&mut b), Reply::Cookie);
    let proof_b = b.prove(&h(4, 0, 0)).unwrap();
    s.send(proof_b.bytes()).unwrap();
    assert!(matches!(recv(&mut b), Reply::SessionAck { .. }));
    let session = proto.lock().unwrap().session();
    let opened = proto.lock().unwrap().counters().sessions_opened;
    // The late proof of attempt 1, from the same address: refused, silent.
    s.send(late.bytes()).unwrap();
    std::thread::sleep(Duration::from_millis(200));
    assert_eq!(bridge.stat(&dir, "rejected_stale_proof"), 1);
    assert_eq!(proto.lock().unwrap().counters().sessions_opened, opened);
    assert_eq!(proto.lock().unwrap().session(), session);
    // The session works: a request is acknowledged.
    let w = b
        .seal(&h(5, session, CTRL_ACK_REQUEST), &Frame::PowerRequest(true))
        .unwrap();
    s.send(w.bytes()).unwrap();
    assert!(matches!(
        recv(&mut b),
        Reply::Frame(Frame::Ack { acked_seq: 5, .. })
    ));
    // A copy of the session's own proof: its session_ack again, verified by
    // a client still waiting for it (a copy of b before the ack).
    s.send(proof_b.bytes()).unwrap();
    std::thread::sleep(Duration::from_millis(200));
    assert_eq!(bridge.stat(&dir, "proofs_reacked"), 1);
    assert_eq!(proto.lock().unwrap().counters().sessions_opened, opened);
    // From another port, the key holder restarted: it takes the session.
    let mut vc = VirtContext::open_with(
        &format!("127.0.0.1#{}", bridge.addr.port()),
        Options {
            key: Some(psk.clone()),
            ..Options::default()
        },
    )
    .unwrap();
    assert_eq!(proto.lock().unwrap().counters().sessions_opened, opened + 1);
    assert!(vc.wait_answer(Duration::from_secs(1)));
    vc.close().unwrap();
    servo.stop.store(true, Ordering::SeqCst);
    drop(bridge);
    let _ = std::fs::remove_dir_all(&dir);
}

/// C's view of a session the controller ended: `virtSetPosition` and
/// `virtGetPosition` fail (-1), `virtGetErrorCode` gives
/// VIRT_E_COMMUNICATION_FAILURE and `virtGetErrorMessage` names 0x102;
/// `virtClose` succeeds.
#[test]
fn c_users_see_a_replaced_session_as_an_error() {
    use std::ffi::CStr;
    use virtuose_api::ffi::{
        virtClose, virtGetErrorCode, virtGetErrorMessage, virtGetPosition, virtOpen,
        virtSetPosition, VIRT_E_COMMUNICATION_FAILURE,
    };
    let _g = serial();
    let (dir, psk) = rig_dir("c_replaced");
    let proto = Arc::new(Mutex::new(ProtoIn::new()));
    let servo = servo_kernel(dir.join("rtf_in"), dir.join("rtf_out"), proto.clone());
    let bridge = Bridge::start_with(&dir, 0, &[]);
    let port = bridge.addr.port();
    let name = CString::new(format!(
        "127.0.0.1#{port}?key={}",
        dir.join("key").display()
    ))
    .unwrap();
    // SAFETY: a NUL-terminated address.
    let vc = unsafe { virtOpen(name.as_ptr()) };
    assert!(!vc.is_null());
    let pose = [0.0f32, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0];
    let mut out = [0f32; 7];
    // SAFETY: a live context, 7 floats each way.
    unsafe {
        assert_eq!(virtSetPosition(vc, pose.as_ptr()), 0);
        assert_eq!(virtGetPosition(vc, out.as_mut_ptr()), 0);
    }
    // Another application with the key takes the arm.
    let other = VirtContext::open_with(
        &format!("127.0.0.1#{port}"),
        Options {
            key: Some(psk.clone()),
            ..Options::default()
        },
    )
    .unwrap();
    let deadline = Instant::now() + Duration::from_secs(10);
    // SAFETY: as above.
    while unsafe { virtSetPosition(vc, pose.as_ptr()) } == 0 && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(5));
    }
    // SAFETY: a live context; the message is a NUL-terminated string the
    // library keeps until this thread's next call.
    let (code, msg) = unsafe {
        let code = virtGetErrorCode(vc);
        let msg = CStr::from_ptr(virtGetErrorMessage(code))
            .to_string_lossy()
            .into_owned();
        (code, msg)
    };
    println!("C after the session was replaced: virtGetErrorCode {code}, \"{msg}\"");
    assert_eq!(code, VIRT_E_COMMUNICATION_FAILURE);
    assert!(msg.contains("0x102") && msg.contains("replaced"), "{msg}");
    // SAFETY: as above.
    unsafe {
        assert_eq!(virtGetPosition(vc, out.as_mut_ptr()), -1);
        assert_eq!(virtGetErrorCode(vc), VIRT_E_COMMUNICATION_FAILURE);
        assert_eq!(virtClose(vc), 0);
    }
    assert!(other.wait_answer(Duration::from_secs(1)));
    drop(other);
    servo.stop.store(true, Ordering::SeqCst);
    drop(bridge);
    let _ = std::fs::remove_dir_all(&dir);
}
