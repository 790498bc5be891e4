//! hap-netem: a UDP proxy on loopback that emulates a slow, lossy link
//! between a client and proto_interface. Each client source address gets
//! its own upstream socket (the bridge sees one source port per client);
//! datagrams both ways are delayed, jittered, reordered, dropped and
//! duplicated as asked, from a seed. Prints its counters at exit (SIGINT,
//! SIGTERM, `--duration`) and writes them to `--stats FILE` on SIGUSR1.

use std::collections::HashMap;
use std::fs::File;
use std::io::{BufWriter, Write as _};
use std::net::{SocketAddr, UdpSocket};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use clap::Parser;
use hap_netem::{
    Counters, Direction, Impairment, Lane, Pending, Shaper, TraceEvent, TraceRecord, TRACE_HEADER,
};

/// hapticctrl link emulator: a UDP proxy with delay, jitter, reordering,
/// loss and duplication.
#[derive(Parser, Debug)]
#[command(name = "hap-netem", version, allow_negative_numbers = true)]
struct Args {
    /// Address the clients send to.
    #[arg(long, default_value = "127.0.0.1:0")]
    listen: SocketAddr,
    /// The bridge's address (proto_interface, or QEMU's forward to it).
    #[arg(long)]
    upstream: SocketAddr,
    /// Round-trip delay, ms: half of it each way (conflicts with --delay-ms).
    #[arg(long, value_parser = parse_ms, conflicts_with = "delay_ms")]
    rtt_ms: Option<f64>,
    /// One-way delay, ms, both directions.
    #[arg(long, value_parser = parse_ms)]
    delay_ms: Option<f64>,
    /// One-way delay client → bridge, ms (overrides the above).
    #[arg(long, value_parser = parse_ms)]
    to_server_delay_ms: Option<f64>,
    /// One-way delay bridge → client, ms (overrides the above).
    #[arg(long, value_parser = parse_ms)]
    to_client_delay_ms: Option<f64>,
    /// Jitter, % of each direction's delay: every delay is uniform in
    /// delay · (1 ± pct/100). Datagrams closer than the spread reorder.
    #[arg(long, default_value_t = 0.0, value_parser = parse_pct)]
    jitter_pct: f64,
    /// Loss, % of the datagrams, each direction.
    #[arg(long, default_value_t = 0.0, value_parser = parse_pct)]
    loss_pct: f64,
    /// Duplication, % of the forwarded datagrams (the copy has its own delay).
    #[arg(long, default_value_t = 0.0, value_parser = parse_pct)]
    dup_pct: f64,
    /// Explicit reordering, %: these datagrams skip the delay and overtake
    /// the ones in flight (as `tc netem ... reorder`).
    #[arg(long, default_value_t = 0.0, value_parser = parse_pct)]
    reorder_pct: f64,
    /// Seed of the draws (each direction draws from its own stream).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Write the counters here at exit and on SIGUSR1.
    #[arg(long, value_name = "FILE")]
    stats: Option<PathBuf>,
    /// Write one CSV line per datagram here (arrival, due and send times).
    #[arg(long, value_name = "FILE")]
    trace: Option<PathBuf>,
    /// Exit after this many seconds (0: at SIGINT/SIGTERM only).
    #[arg(long, default_value_t = 0.0, value_parser = parse_seconds)]
    duration: f64,
    /// At most this many client source addresses (later ones are refused
    /// and counted).
    #[arg(long, default_value_t = 64, value_parser = clap::value_parser!(u32).range(1..=4096))]
    max_clients: u32,
}

fn parse_ms(s: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|_| format!("'{s}' is not a number"))?;
    let max = hap_netem::MAX_DELAY_US as f64 / 1000.0;
    if !(0.0..=max).contains(&v) {
        return Err(format!("{v} ms: must be within 0..={max}"));
    }
    Ok(v)
}

fn parse_pct(s: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|_| format!("'{s}' is not a number"))?;
    if !(0.0..=100.0).contains(&v) {
        return Err(format!("{v} %: must be within 0..=100"));
    }
    Ok(v)
}

fn parse_seconds(s: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|_| format!("'{s}' is not a number"))?;
    if !(v >= 0.0 && v.is_finite()) {
        return Err(format!("{v} s: must be >= 0"));
    }
    Ok(v)
}

/// Where a datagram goes.
#[derive(Clone, Debug)]
enum Route {
    /// Through this client's connected upstream socket.
    Upstream(Arc<UdpSocket>),
    /// From the listening socket to this client.
    Client(SocketAddr),
}

#[derive(Clone, Debug)]
struct Datagram {
    data: Arc<[u8]>,
    route: Route,
}

struct LaneCell {
    dir: Direction,
    lane: Mutex<Lane<Datagram>>,
    wake: Condvar,
}

struct Proxy {
    clock: Instant,
    stop: AtomicBool,
    lanes: [LaneCell; 2],
    listen: Arc<UdpSocket>,
    trace: Mutex<Option<BufWriter<File>>>,
    clients: AtomicU64,
    clients_refused: AtomicU64,
    upstream: SocketAddr,
    settings: String,
}

impl Proxy {
    fn now_ns(&self) -> u64 {
        self.clock.elapsed().as_nanos() as u64
    }

    fn lane(&self, dir: Direction) -> &LaneCell {
        &self.lanes[match dir {
            Direction::ToServer => 0,
            Direction::ToClient => 1,
        }]
    }

    fn trace(&self, r: TraceRecord) {
        if let Ok(mut t) = self.trace.lock() {
            if let Some(w) = t.as_mut() {
                let _ = writeln!(w, "{}", r.to_line());
            }
        }
    }

    fn arrive(&self, dir: Direction, data: &[u8], route: Route) {
        let cell = self.lane(dir);
        let Ok(mut lane) = cell.lane.lock() else {
            return;
        };
        let now = self.now_ns();
        let (index, fate) = lane.arrive(
            now,
            Datagram {
                data: data.into(),
                route,
            },
        );
        drop(lane);
        if fate == hap_netem::Fate::Dropped {
            self.trace(TraceRecord {
                dir,
                index,
                len: data.len(),
                arrival_ns: now,
                event: TraceEvent::Dropped,
            });
        }
        cell.wake.notify_one();
    }

    fn send(&self, p: &Pending<Datagram>) -> bool {
        let d = &p.item;
        let r = match &d.route {
            Route::Upstream(s) => s.send(&d.data),
            Route::Client(a) => self.listen.send_to(&d.data, a),
        };
        matches!(r, Ok(n) if n == d.data.len())
    }

    /// One direction's sender: sends each datagram at its due time.
    fn run_sender(&self, dir: Direction) {
        let cell = self.lane(dir);
        let Ok(mut lane) = cell.lane.lock() else {
            return;
        };
        while !self.stop.load(Ordering::Relaxed) {
            let now = self.now_ns();
            if let Some(p) = lane.pop_due(now) {
                drop(lane);
                let ok = self.send(&p);
                let sent_ns = self.now_ns();
                self.trace(TraceRecord {
                    dir,
                    index: p.index,
                    len: p.item.data.len(),
                    arrival_ns: p.arrival_ns,
                    event: if ok {
                        TraceEvent::Sent {
                            copy: p.copy,
                            due_ns: p.due_ns,
                            sent_ns,
                        }
                    } else {
                        TraceEvent::SendError {
                            copy: p.copy,
                            due_ns: p.due_ns,
                        }
                    },
                });
                lane = match cell.lane.lock() {
                    Ok(l) => l,
                    Err(_) => return,
                };
                lane.sent(&p, sent_ns, ok);
                continue;
            }
            // Sleep until the next due time (at most 50 ms: the stop flag).
            let wait_ns = lane
                .next_due_ns()
                .map_or(50_000_000, |d| d.saturating_sub(now).min(50_000_000));
            lane = match cell.wake.wait_timeout(lane, Duration::from_nanos(wait_ns)) {
                Ok((l, _)) => l,
                Err(_) => return,
            };
        }
    }

    fn counters(&self, dir: Direction) -> Counters {
        self.lane(dir)
            .lane
            .lock()
            .map(|l| l.counters)
            .unwrap_or_default()
    }

    fn render_stats(&self) -> String {
        let mut s = String::new();
        s.push_str(&self.settings);
        s.push_str(&format!("upstream: {}\n", self.upstream));
        s.push_str(&format!("uptime_ms: {}\n", self.now_ns() / 1_000_000));
        s.push_str(&format!(
            "clients: {}\n",
            self.clients.load(Ordering::Relaxed)
        ));
        s.push_str(&format!(
            "clients_refused: {}\n",
            self.clients_refused.load(Ordering::Relaxed)
        ));
        for dir in Direction::ALL {
            self.counters(dir).render(dir, &mut s);
        }
        s
    }
}

/// Receives the bridge's datagrams for one client.
fn run_upstream_rx(proxy: Arc<Proxy>, sock: Arc<UdpSocket>, client: SocketAddr) {
    let mut buf = vec![0u8; 65536];
    while !proxy.stop.load(Ordering::Relaxed) {
        match sock.recv(&mut buf) {
            Ok(n) => proxy.arrive(Direction::ToClient, &buf[..n], Route::Client(client)),
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) => {}
            // ICMP port unreachable from a bridge not up yet: keep going.
            Err(_) => std::thread::sleep(Duration::from_millis(1)),
        }
    }
}

/// Receives the clients' datagrams; opens an upstream socket per client.
fn run_client_rx(proxy: Arc<Proxy>, max_clients: u32, rx_threads: Arc<Mutex<Vec<JoinHandle<()>>>>) {
    let mut buf = vec![0u8; 65536];
    let mut clients: HashMap<SocketAddr, Arc<UdpSocket>> = HashMap::new();
    while !proxy.stop.load(Ordering::Relaxed) {
        let (n, from) = match proxy.listen.recv_from(&mut buf) {
            Ok(r) => r,
            Err(_) => continue,
        };
        let sock = match clients.get(&from) {
            Some(s) => s.clone(),
            None => {
                if clients.len() >= max_clients as usize {
                    proxy.clients_refused.fetch_add(1, Ordering::Relaxed);
                    continue;
                }
                let s = match open_upstream(proxy.upstream) {
                    Ok(s) => Arc::new(s),
                    Err(e) => {
                        eprintln!("hap-netem: upstream socket for {from}: {e}");
                        proxy.clients_refused.fetch_add(1, Ordering::Relaxed);
                        continue;
                    }
                };
                clients.insert(from, s.clone());
                proxy.clients.fetch_add(1, Ordering::Relaxed);
                let (p, sc) = (proxy.clone(), s.clone());
                let h = std::thread::spawn(move || run_upstream_rx(p, sc, from));
                if let Ok(mut v) = rx_threads.lock() {
                    v.push(h);
                }
                s
            }
        };
        proxy.arrive(Direction::ToServer, &buf[..n], Route::Upstream(sock));
    }
}

fn open_upstream(upstream: SocketAddr) -> std::io::Result<UdpSocket> {
    let bind: SocketAddr = if upstream.is_ipv4() {
        "127.0.0.1:0".parse().expect("a literal address")
    } else {
        "[::1]:0".parse().expect("a literal address")
    };
    let s = UdpSocket::bind(bind)?;
    s.connect(upstream)?;
    s.set_read_timeout(Some(Duration::from_millis(50)))?;
    Ok(s)
}

fn write_stats(path: &Option<PathBuf>, text: &str) {
    if let Some(p) = path {
        // Write then rename: a reader never sees half a file.
        let tmp = p.with_extension("tmp");
        if let Err(e) = std::fs::write(&tmp, text).and_then(|_| std::fs::rename(&tmp, p)) {
            eprintln!("hap-netem: stats {}: {e}", p.display());
        }
    }
}

fn main() -> ExitCode {
    let args = Args::parse();
    match run(args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("hap-netem: error: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run(args: Args) -> Result<(), String> {
    let both_ms = args
        .rtt_ms
        .map(|r| r / 2.0)
        .or(args.delay_ms)
        .unwrap_or(0.0);
    let to_us = |ms: f64| (ms * 1000.0).round() as u64;
    let imp = |ms: Option<f64>| Impairment {
        delay_us: to_us(ms.unwrap_or(both_ms)),
        jitter_pct: args.jitter_pct,
        loss_pct: args.loss_pct,
        dup_pct: args.dup_pct,
        reorder_pct: args.reorder_pct,
    };
    let up = imp(args.to_server_delay_ms);
    let down = imp(args.to_client_delay_ms);
    up.validate()?;
    down.validate()?;

    let stop_signal = Arc::new(AtomicBool::new(false));
    let usr1 = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(sig, stop_signal.clone())
            .map_err(|e| format!("signals: {e}"))?;
    }
    signal_hook::flag::register(signal_hook::consts::SIGUSR1, usr1.clone())
        .map_err(|e| format!("signals: {e}"))?;

    let listen =
        UdpSocket::bind(args.listen).map_err(|e| format!("--listen {}: {e}", args.listen))?;
    listen
        .set_read_timeout(Some(Duration::from_millis(50)))
        .map_err(|e| format!("socket: {e}"))?;
    let local = listen.local_addr().map_err(|e| format!("socket: {e}"))?;
    let trace = match &args.trace {
        Some(p) => {
            let mut w = BufWriter::new(
                File::create(p).map_err(|e| format!("--trace {}: {e}", p.display()))?,
            );
            writeln!(w, "{TRACE_HEADER}").map_err(|e| format!("--trace {}: {e}", p.display()))?;
            Some(w)
        }
        None => None,
    };
    let settings = format!(
        "listen: {local}\nseed: {}\nto_server_delay_us: {}\nto_client_delay_us: {}\njitter_pct: {}\nloss_pct: {}\ndup_pct: {}\nreorder_pct: {}\n",
        args.seed, up.delay_us, down.delay_us, args.jitter_pct, args.loss_pct, args.dup_pct, args.reorder_pct
    );
    let cell = |dir, imp| LaneCell {
        dir,
        lane: Mutex::new(Lane::new(Shaper::new(imp, args.seed, dir))),
        wake: Condvar::new(),
    };
    let proxy = Arc::new(Proxy {
        clock: Instant::now(),
        stop: AtomicBool::new(false),
        lanes: [
            cell(Direction::ToServer, up),
            cell(Direction::ToClient, down),
        ],
        listen: Arc::new(listen),
        trace: Mutex::new(trace),
        clients: AtomicU64::new(0),
        clients_refused: AtomicU64::new(0),
        upstream: args.upstream,
        settings,
    });

    let rx_threads = Arc::new(Mutex::new(Vec::new()));
    let mut threads = Vec::new();
    for i in 0..2 {
        let p = proxy.clone();
        threads.push(std::thread::spawn(move || {
            let dir = p.lanes[i].dir;
            p.run_sender(dir)
        }));
    }
    {
        let (p, r) = (proxy.clone(), rx_threads.clone());
        let max = args.max_clients;
        threads.push(std::thread::spawn(move || run_client_rx(p, max, r)));
    }
    println!(
        "hap-netem: listening on {local}, upstream {}; to server {} us, to client {} us, jitter {} %, loss {} %, dup {} %, reorder {} %, seed {}",
        args.upstream, up.delay_us, down.delay_us, args.jitter_pct, args.loss_pct, args.dup_pct, args.reorder_pct, args.seed
    );
    let _ = std::io::stdout().flush();

    let t0 = Instant::now();
    let timed_out = || args.duration > 0.0 && t0.elapsed().as_secs_f64() >= args.duration;
    while !stop_signal.load(Ordering::Relaxed) && !timed_out() {
        if usr1.swap(false, Ordering::Relaxed) {
            write_stats(&args.stats, &proxy.render_stats());
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    proxy.stop.store(true, Ordering::Relaxed);
    for c in &proxy.lanes {
        c.wake.notify_all();
    }
    for t in threads {
        let _ = t.join();
    }
    if let Ok(mut v) = rx_threads.lock() {
        for t in v.drain(..) {
            let _ = t.join();
        }
    }
    if let Ok(mut t) = proxy.trace.lock() {
        if let Some(w) = t.as_mut() {
            w.flush().map_err(|e| format!("--trace: {e}"))?;
        }
    }
    let text = proxy.render_stats();
    write_stats(&args.stats, &text);
    eprint!("hap-netem: stats\n{text}");
    Ok(())
}
