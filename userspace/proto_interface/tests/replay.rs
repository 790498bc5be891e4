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
    decode, encode, expected_len, Answer, Frame, FrameHeader, FrameType, MAX_FRAME_LEN,
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
    fn start(dir: &Path, port: u16) -> Bridge {
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
            // Loopback: every source shares 127.0.0.1, so the per-IP budget
            // would soon drop the replays unexamined; they are to be examined
            // (and refused) one by one here. The budgets have their own test.
            .args([
                "--refusal-budget",
                "0",
                "--handshake-budget",
                "0",
                "--handshake-budget-per-ip",
                "0",
            ])
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
