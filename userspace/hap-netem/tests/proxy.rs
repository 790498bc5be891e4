//! The hap-netem binary between a test client and a test "bridge" on
//! loopback. Delays are checked on the proxy's own trace (arrival, due and
//! send times it recorded), never on how tight the host's clock is.

use std::collections::HashMap;
use std::io::{BufRead, BufReader};
use std::net::{SocketAddr, UdpSocket};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use hap_netem::{Direction, Fate, Impairment, Shaper, TraceEvent, TraceRecord};

const BIN: &str = env!("CARGO_BIN_EXE_hap-netem");

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("hap-netem-test-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d.join(name)
}

/// Datagrams as (source, bytes), in arrival order.
type Received = Arc<Mutex<Vec<(SocketAddr, Vec<u8>)>>>;

/// A test bridge: records every datagram (source, bytes) and optionally
/// echoes it back.
struct Bridge {
    addr: SocketAddr,
    got: Received,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Bridge {
    fn start(echo: bool) -> Self {
        let s = UdpSocket::bind("127.0.0.1:0").unwrap();
        s.set_read_timeout(Some(Duration::from_millis(20))).unwrap();
        let addr = s.local_addr().unwrap();
        let got: Received = Arc::new(Mutex::new(Vec::new()));
        let stop = Arc::new(AtomicBool::new(false));
        let (g, st) = (got.clone(), stop.clone());
        let thread = std::thread::spawn(move || {
            let mut buf = vec![0u8; 65536];
            while !st.load(Ordering::Relaxed) {
                if let Ok((n, from)) = s.recv_from(&mut buf) {
                    if echo {
                        s.send_to(&buf[..n], from).unwrap();
                    }
                    g.lock().unwrap().push((from, buf[..n].to_vec()));
                }
            }
        });
        Bridge {
            addr,
            got,
            stop,
            thread: Some(thread),
        }
    }

    fn received(&self) -> Vec<(SocketAddr, Vec<u8>)> {
        self.got.lock().unwrap().clone()
    }

    fn wait_for(&self, n: usize, timeout: Duration) {
        let t = Instant::now();
        while self.got.lock().unwrap().len() < n && t.elapsed() < timeout {
            std::thread::sleep(Duration::from_millis(10));
        }
    }
}

impl Drop for Bridge {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

struct Netem {
    child: Child,
    addr: SocketAddr,
    stats: PathBuf,
    trace: PathBuf,
}

impl Netem {
    fn start(name: &str, upstream: SocketAddr, extra: &[&str]) -> Self {
        let stats = tmp(&format!("{name}.stats"));
        let trace = tmp(&format!("{name}.trace"));
        let mut child = Command::new(BIN)
            .args(["--upstream", &upstream.to_string()])
            .arg("--stats")
            .arg(&stats)
            .arg("--trace")
            .arg(&trace)
            .args(extra)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        let addr = line
            .split("listening on ")
            .nth(1)
            .and_then(|r| r.split(',').next())
            .unwrap_or_else(|| panic!("no address in {line:?}"))
            .parse()
            .unwrap();
        Netem {
            child,
            addr,
            stats,
            trace,
        }
    }

    fn signal(&self, sig: &str) {
        let st = Command::new("kill")
            .args([sig, &self.child.id().to_string()])
            .status()
            .unwrap();
        assert!(st.success());
    }

    /// SIGTERM, wait, and return (final stats, trace records, stderr).
    fn stop(self) -> (HashMap<String, String>, Vec<TraceRecord>, String) {
        self.signal("-TERM");
        let out = self.child.wait_with_output().unwrap();
        assert!(out.status.success(), "{out:?}");
        let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
        assert!(stderr.contains("to_server_forwarded:"), "{stderr}");
        (read_stats(&self.stats), read_trace(&self.trace), stderr)
    }
}

fn read_stats(p: &Path) -> HashMap<String, String> {
    std::fs::read_to_string(p)
        .unwrap()
        .lines()
        .filter_map(|l| l.split_once(": "))
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect()
}

fn read_trace(p: &Path) -> Vec<TraceRecord> {
    let text = std::fs::read_to_string(p).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some(hap_netem::TRACE_HEADER));
    lines.map(|l| TraceRecord::parse(l).unwrap()).collect()
}

fn stat(s: &HashMap<String, String>, k: &str) -> u64 {
    s.get(k)
        .unwrap_or_else(|| panic!("no {k} in {s:?}"))
        .parse()
        .unwrap()
}

fn assert_reconciles(s: &HashMap<String, String>) {
    for d in ["to_server", "to_client"] {
        let g = |k: &str| stat(s, &format!("{d}_{k}"));
        assert_eq!(
            g("received") + g("duplicated"),
            g("forwarded") + g("dropped") + g("in_flight") + g("send_errors"),
            "{d}: {s:?}"
        );
    }
}

fn client() -> UdpSocket {
    let c = UdpSocket::bind("127.0.0.1:0").unwrap();
    c.set_read_timeout(Some(Duration::from_millis(20))).unwrap();
    c
}

/// A client socket and a thread that keeps reading it (a socket left
/// unread while the test sends overflows its receive buffer).
struct Client {
    sock: UdpSocket,
    got: Arc<Mutex<Vec<Vec<u8>>>>,
    stop: Arc<AtomicBool>,
}

impl Client {
    fn start() -> Self {
        let sock = client();
        let rx = sock.try_clone().unwrap();
        let got = Arc::new(Mutex::new(Vec::new()));
        let stop = Arc::new(AtomicBool::new(false));
        let (g, st) = (got.clone(), stop.clone());
        std::thread::spawn(move || {
            let mut buf = vec![0u8; 65536];
            while !st.load(Ordering::Relaxed) {
                if let Ok(k) = rx.recv(&mut buf) {
                    g.lock().unwrap().push(buf[..k].to_vec());
                }
            }
        });
        Client { sock, got, stop }
    }

    fn send(&self, data: &[u8], to: SocketAddr) {
        self.sock.send_to(data, to).unwrap();
    }

    /// What arrived once `n` have (or `timeout`).
    fn wait_for(&self, n: usize, timeout: Duration) -> Vec<Vec<u8>> {
        let t = Instant::now();
        while self.got.lock().unwrap().len() < n && t.elapsed() < timeout {
            std::thread::sleep(Duration::from_millis(10));
        }
        self.got.lock().unwrap().clone()
    }
}

impl Drop for Client {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

/// Delays (due − arrival, µs) of the originals sent one way.
fn delays(trace: &[TraceRecord], dir: Direction) -> Vec<u64> {
    trace
        .iter()
        .filter(|r| r.dir == dir)
        .filter_map(|r| match r.event {
            TraceEvent::Sent {
                copy: false,
                due_ns,
                sent_ns,
            } => {
                assert!(sent_ns >= due_ns, "{r:?} left before it was due");
                Some((due_ns - r.arrival_ns) / 1000)
            }
            _ => None,
        })
        .collect()
}

/// Mean within 6 standard errors of a uniform band's, every draw inside it.
fn assert_uniform(d: &[u64], mean_us: f64, half_band_us: f64) {
    let lo = (mean_us - half_band_us) as u64;
    let hi = (mean_us + half_band_us) as u64;
    for &x in d {
        assert!((lo..=hi).contains(&x), "{x} us outside {lo}..={hi}");
    }
    let m = d.iter().sum::<u64>() as f64 / d.len() as f64;
    let se = 2.0 * half_band_us / (12.0 * d.len() as f64).sqrt();
    assert!((m - mean_us).abs() <= 6.0 * se + 1.0, "mean {m} us");
    // The band is used, not just its middle: the spread is that of a
    // uniform draw (sd = band / sqrt 12), within 20 %.
    let var = d.iter().map(|&x| (x as f64 - m).powi(2)).sum::<f64>() / d.len() as f64;
    let sd_want = 2.0 * half_band_us / 12f64.sqrt();
    assert!(
        (var.sqrt() - sd_want).abs() < 0.2 * sd_want + 1.0,
        "sd {} us, want {sd_want}",
        var.sqrt()
    );
}

#[test]
fn delays_per_direction_follow_the_asked_distribution() {
    let bridge = Bridge::start(true);
    let px = Netem::start(
        "delay",
        bridge.addr,
        &[
            "--to-server-delay-ms",
            "20",
            "--to-client-delay-ms",
            "5",
            "--jitter-pct",
            "50",
            "--seed",
            "3",
        ],
    );
    let c = Client::start();
    let n = 600;
    for i in 0..n as u32 {
        c.send(&i.to_be_bytes(), px.addr);
        std::thread::sleep(Duration::from_micros(500));
    }
    let echoed = c.wait_for(n, Duration::from_secs(10));
    let (stats, trace, stderr) = px.stop();
    assert_eq!(echoed.len(), n, "{stderr}");
    let up = delays(&trace, Direction::ToServer);
    let down = delays(&trace, Direction::ToClient);
    assert_eq!((up.len(), down.len()), (n, n));
    assert_uniform(&up, 20_000.0, 10_000.0);
    assert_uniform(&down, 5_000.0, 2_500.0);
    assert_eq!(stat(&stats, "to_server_delay_us"), 20_000);
    assert_eq!(stat(&stats, "to_client_delay_us"), 5_000);
    assert_eq!(stat(&stats, "to_server_forwarded"), n as u64);
    assert_eq!(stat(&stats, "to_client_forwarded"), n as u64);
    assert_reconciles(&stats);
    println!(
        "FIGURE host native: late_us_max to_server {}, to_client {}",
        stat(&stats, "to_server_late_us_max"),
        stat(&stats, "to_client_late_us_max")
    );
}

#[test]
fn rtt_is_split_between_the_directions() {
    let bridge = Bridge::start(true);
    let px = Netem::start("rtt", bridge.addr, &["--rtt-ms", "30"]);
    let c = Client::start();
    for i in 0..50u32 {
        c.send(&i.to_be_bytes(), px.addr);
    }
    assert_eq!(c.wait_for(50, Duration::from_secs(5)).len(), 50);
    let (stats, trace, _) = px.stop();
    for dir in Direction::ALL {
        let d = delays(&trace, dir);
        assert_eq!(d.len(), 50);
        assert!(d.iter().all(|&x| x == 15_000), "{dir:?}: {d:?}");
    }
    assert_eq!(stat(&stats, "to_server_reordered"), 0);
}

#[test]
fn loss_is_the_seeds_and_within_a_binomial_bound() {
    let bridge = Bridge::start(false);
    let px = Netem::start("loss", bridge.addr, &["--loss-pct", "10", "--seed", "42"]);
    let c = client();
    let n = 2000u64;
    for i in 0..n as u32 {
        c.send_to(&i.to_be_bytes(), px.addr).unwrap();
        if i % 16 == 0 {
            std::thread::sleep(Duration::from_millis(1));
        }
    }
    // Exactly the seed's draws (the library's shaper, same seed)...
    let mut s = Shaper::new(
        Impairment {
            loss_pct: 10.0,
            ..Default::default()
        },
        42,
        Direction::ToServer,
    );
    let want: Vec<u64> = (0..n).filter(|_| s.decide() == Fate::Dropped).collect();
    bridge.wait_for((n as usize) - want.len(), Duration::from_secs(10));
    let (stats, trace, _) = px.stop();
    let dropped = stat(&stats, "to_server_dropped");
    assert_eq!(stat(&stats, "to_server_received"), n);
    let got: Vec<u64> = trace
        .iter()
        .filter(|r| r.dir == Direction::ToServer && r.event == TraceEvent::Dropped)
        .map(|r| r.index)
        .collect();
    assert_eq!(got, want);
    assert_eq!(dropped, want.len() as u64);
    // ...and within 6 sigma of n p.
    let sd = (n as f64 * 0.1 * 0.9).sqrt();
    assert!((dropped as f64 - 200.0).abs() < 6.0 * sd, "{dropped}");
    // What was not dropped reached the bridge.
    assert_eq!(bridge.received().len() as u64, n - dropped);
    assert_eq!(stat(&stats, "to_server_forwarded"), n - dropped);
    assert_reconciles(&stats);
}

fn read_stats_after_usr1(px: &Netem) -> HashMap<String, String> {
    let _ = std::fs::remove_file(&px.stats);
    px.signal("-USR1");
    let t = Instant::now();
    while !px.stats.exists() && t.elapsed() < Duration::from_secs(5) {
        std::thread::sleep(Duration::from_millis(10));
    }
    read_stats(&px.stats)
}

/// Sends `n` numbered datagrams 1 ms apart through a proxy with `extra`;
/// returns (the bridge's arrival order, the proxy's reordered count).
fn order_through(name: &str, extra: &[&str], n: u32) -> (Vec<u32>, u64) {
    let bridge = Bridge::start(false);
    let px = Netem::start(name, bridge.addr, extra);
    let c = client();
    for i in 0..n {
        c.send_to(&i.to_be_bytes(), px.addr).unwrap();
        std::thread::sleep(Duration::from_millis(1));
    }
    bridge.wait_for(n as usize, Duration::from_secs(10));
    let (stats, _, _) = px.stop();
    let order: Vec<u32> = bridge
        .received()
        .iter()
        .map(|(_, b)| u32::from_be_bytes(b[..4].try_into().unwrap()))
        .collect();
    assert_eq!(order.len(), n as usize);
    assert_reconciles(&stats);
    (order, stat(&stats, "to_server_reordered"))
}

/// Datagrams that arrived after one with a higher number.
fn late_ones(order: &[u32]) -> u64 {
    let mut max = None;
    let mut late = 0;
    for &x in order {
        match max {
            Some(m) if x < m => late += 1,
            _ => max = Some(x),
        }
    }
    late
}

#[test]
fn jitter_wider_than_the_gap_reorders_and_none_does_not() {
    // 10 ms ± 50 %: a 10 ms spread over datagrams 1 ms apart.
    let (order, reordered) =
        order_through("reorder", &["--delay-ms", "10", "--jitter-pct", "50"], 300);
    assert!(reordered > 30, "reordered {reordered}");
    // The proxy counts what the receiver sees.
    assert_eq!(late_ones(&order), reordered);
    // No jitter: the order is kept.
    let (order, reordered) = order_through("inorder", &["--delay-ms", "10"], 300);
    assert_eq!(reordered, 0);
    assert!(order.windows(2).all(|w| w[0] < w[1]));
}

#[test]
fn explicit_reorder_option_overtakes() {
    let (order, reordered) = order_through(
        "explicit",
        &["--delay-ms", "10", "--reorder-pct", "20"],
        300,
    );
    assert!(reordered > 10, "reordered {reordered}");
    assert_eq!(late_ones(&order), reordered);
}

/// A deterministic byte pattern: datagram `i`'s own length and contents.
fn payload(i: u32) -> Vec<u8> {
    let len = 4 + (i as usize * 7919) % 1400;
    let mut x = u64::from(i).wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
    let mut v = i.to_be_bytes().to_vec();
    while v.len() < len {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        v.push(x as u8);
    }
    v
}

#[test]
fn no_datagram_is_altered_either_way_copies_included() {
    let bridge = Bridge::start(true);
    let px = Netem::start(
        "intact",
        bridge.addr,
        &[
            "--delay-ms",
            "3",
            "--jitter-pct",
            "80",
            "--loss-pct",
            "10",
            "--dup-pct",
            "20",
            "--seed",
            "9",
        ],
    );
    let c = Client::start();
    let n = 500u32;
    for i in 0..n {
        c.send(&payload(i), px.addr);
        std::thread::sleep(Duration::from_micros(300));
    }
    std::thread::sleep(Duration::from_millis(300));
    let back = c.wait_for(usize::MAX, Duration::from_millis(500));
    let (stats, _, _) = px.stop();
    assert_reconciles(&stats);
    let check = |got: &[Vec<u8>], what: &str| -> (u64, u64) {
        let mut seen: HashMap<u32, u64> = HashMap::new();
        for b in got {
            let i = u32::from_be_bytes(b[..4].try_into().unwrap());
            assert!(i < n, "{what}: unknown datagram");
            assert_eq!(b, &payload(i), "{what}: datagram {i} altered");
            *seen.entry(i).or_default() += 1;
        }
        let twice = seen.values().filter(|&&k| k == 2).count() as u64;
        assert!(seen.values().all(|&k| k <= 4), "{what}: {seen:?}");
        (seen.len() as u64, twice)
    };
    let at_bridge: Vec<Vec<u8>> = bridge.received().into_iter().map(|(_, b)| b).collect();
    let (distinct, twice) = check(&at_bridge, "bridge");
    assert_eq!(at_bridge.len() as u64, stat(&stats, "to_server_forwarded"));
    assert_eq!(distinct, n as u64 - stat(&stats, "to_server_dropped"));
    assert_eq!(twice, stat(&stats, "to_server_duplicated"));
    assert!(twice > 0);
    check(&back, "client");
    assert_eq!(back.len() as u64, stat(&stats, "to_client_forwarded"));
}

#[test]
fn each_client_gets_its_own_upstream_source_and_its_own_answers() {
    let bridge = Bridge::start(true);
    let px = Netem::start("clients", bridge.addr, &["--delay-ms", "1"]);
    let (a, b) = (Client::start(), Client::start());
    for i in 0..20u32 {
        a.send(&[b'a', i as u8], px.addr);
        b.send(&[b'b', i as u8], px.addr);
    }
    let ga = a.wait_for(20, Duration::from_secs(5));
    let gb = b.wait_for(20, Duration::from_secs(5));
    assert!(ga.len() == 20 && ga.iter().all(|d| d[0] == b'a'), "{ga:?}");
    assert!(gb.len() == 20 && gb.iter().all(|d| d[0] == b'b'), "{gb:?}");
    let sources: std::collections::HashSet<SocketAddr> =
        bridge.received().iter().map(|(s, _)| *s).collect();
    assert_eq!(sources.len(), 2);
    let (stats, _, _) = px.stop();
    assert_eq!(stat(&stats, "clients"), 2);
}

#[test]
fn sigusr1_writes_counters_that_reconcile_mid_run() {
    let bridge = Bridge::start(true);
    let px = Netem::start(
        "usr1",
        bridge.addr,
        // 0.5 s ± 50 %: nothing leaves before the mid-run snapshot, even
        // on a loaded host.
        &[
            "--delay-ms",
            "500",
            "--jitter-pct",
            "50",
            "--loss-pct",
            "20",
            "--dup-pct",
            "10",
        ],
    );
    let c = Client::start();
    for i in 0..200u32 {
        c.send(&i.to_be_bytes(), px.addr);
    }
    // Mid-run: datagrams still in flight, and the counts add up.
    let mid = read_stats_after_usr1(&px);
    assert_reconciles(&mid);
    assert_eq!(stat(&mid, "to_server_received"), 200);
    assert!(stat(&mid, "to_server_in_flight") > 0, "{mid:?}");
    // Until two snapshots 50 ms apart find nothing in flight (an echo
    // takes 250 ms or more through the proxy).
    let t = Instant::now();
    let mut idle = 0;
    while idle < 2 && t.elapsed() < Duration::from_secs(10) {
        let s = read_stats_after_usr1(&px);
        assert_reconciles(&s);
        if stat(&s, "to_server_in_flight") + stat(&s, "to_client_in_flight") == 0 {
            idle += 1;
        } else {
            idle = 0;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let (end, _, _) = px.stop();
    assert_reconciles(&end);
    assert_eq!(stat(&end, "to_server_in_flight"), 0);
    assert_eq!(stat(&end, "to_client_in_flight"), 0);
    assert!(stat(&end, "to_client_dropped") > 0);
}

#[test]
fn bad_arguments_get_a_clear_error_and_no_panic() {
    let cases: &[(&[&str], &str)] = &[
        (&[], "--upstream"),
        (&["--upstream", "nowhere"], "--upstream"),
        (
            &["--upstream", "127.0.0.1:9", "--loss-pct", "150"],
            "--loss-pct",
        ),
        (
            &["--upstream", "127.0.0.1:9", "--jitter-pct", "-5"],
            "--jitter-pct",
        ),
        (
            &["--upstream", "127.0.0.1:9", "--dup-pct", "NaN"],
            "--dup-pct",
        ),
        (
            &["--upstream", "127.0.0.1:9", "--delay-ms", "abc"],
            "--delay-ms",
        ),
        (
            &["--upstream", "127.0.0.1:9", "--delay-ms", "1e9"],
            "--delay-ms",
        ),
        (
            &[
                "--upstream",
                "127.0.0.1:9",
                "--rtt-ms",
                "10",
                "--delay-ms",
                "5",
            ],
            "--rtt-ms",
        ),
        (
            &["--upstream", "127.0.0.1:9", "--duration", "-1"],
            "--duration",
        ),
        (&["--upstream", "127.0.0.1:9", "--seed", "x"], "--seed"),
        (&["--upstream", "127.0.0.1:9", "--bogus"], "--bogus"),
    ];
    for (args, names) in cases {
        let out = Command::new(BIN).args(*args).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(
            err.contains("error:") && err.contains(names),
            "{args:?}: {err}"
        );
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }
    // A port already taken: a runtime error naming the option.
    let taken = UdpSocket::bind("127.0.0.1:0").unwrap();
    let out = Command::new(BIN)
        .args(["--upstream", "127.0.0.1:9", "--listen"])
        .arg(taken.local_addr().unwrap().to_string())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("--listen") && !err.contains("panicked"),
        "{err}"
    );
}
