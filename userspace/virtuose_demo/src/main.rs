//! virtuose_demo: the spec's test client (D9rb.2 §3.1). Initialises the
//! controller (references, units, internal variables, interactive mode),
//! then runs a 1 kHz physics loop where sphere A is coupled to the arm and
//! sphere B is free; shows it in the terminal and on a 3D web page.

mod physics;
mod web;

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use clap::Parser;
use physics::{Bimanual, World, V3};
use virtuose_api::fake_peer::{FakePeer, FakePeerConfig};
use virtuose_api::{CommandType, IndexingMode, Options, VirtContext};

/// hapticctrl test client: two spheres, one coupled to the (simulated) arm.
#[derive(Parser, Debug)]
#[command(name = "virtuose_demo", version)]
struct Args {
    /// Controller address "host#port" (proto_interface), or "fake" for an
    /// in-process fake controller (no kernel needed).
    #[arg(long, default_value = "127.0.0.1#5000")]
    server: String,
    /// A second arm's address ("host#port", e.g. a controller's arm 1 on
    /// 5001, or "fake"): the bimanual scene, two hands (one per arm) and one
    /// object to hold between them, shown in the terminal (no web page).
    #[arg(long, value_name = "ADDR")]
    server2: Option<String>,
    /// Terminal summary only (no web page).
    #[arg(long)]
    headless: bool,
    /// Web page address (port 0: any free port; the URL is printed).
    #[arg(long, default_value = "127.0.0.1:8080")]
    http: std::net::SocketAddr,
    /// Run time in seconds (0: until Ctrl-C).
    #[arg(long, default_value_t = 0.0)]
    duration: f64,
    /// Directory for run.csv and summary.txt.
    #[arg(long)]
    results: Option<PathBuf>,
    /// Physics / streaming rate, Hz.
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u32).range(10..=5000))]
    rate: u32,
    /// Pre-shared key file (protocol v2; `hapctl keygen`). Also accepted:
    /// `--server "host#port?key=FILE"` or the HAP_KEY_FILE environment
    /// variable. Without a key the client speaks unauthenticated v1.
    #[arg(long, value_name = "FILE")]
    key: Option<PathBuf>,
    /// Reply timeout of acknowledged requests, ms.
    #[arg(long, default_value_t = 250)]
    timeout_ms: u64,
    /// Keep the link passive (time-domain passivity across the network,
    /// `Options::link_passivity`): for a slow link (WAN, cellular).
    #[arg(long)]
    link_passivity: bool,
    /// Client request interval in µs (overrides --rate; e.g. 3000 for the
    /// spec's 1 sample / 3 ms).
    #[arg(long, value_parser = clap::value_parser!(u32).range(200..=100_000))]
    interval_us: Option<u32>,
    /// Stop after this many client cycles (VprStream requests); 0: use
    /// --duration.
    #[arg(long, default_value_t = 0)]
    samples: u64,
    /// With --duration: go on after it until this many answers have been
    /// received (0: stop at --duration), at most --max-duration seconds.
    #[arg(long, default_value_t = 0)]
    answers: u64,
    /// Hard limit of the run, seconds (0: none).
    #[arg(long, default_value_t = 0.0)]
    max_duration: f64,
    /// Stream at most this many VprStream frames ahead of the answers
    /// received (0: no pacing; the client sends at --rate whatever the
    /// controller consumes).
    #[arg(long, default_value_t = 4)]
    window: u64,
    /// Link benchmark: record every round trip and write rtt_hist.csv and
    /// rate.csv next to summary.txt (needs --results), with percentiles and
    /// guest-time figures in the summary.
    #[arg(long, requires = "results")]
    bench: bool,
    /// Keep the web page up this many seconds after the run, so that it can
    /// link to the run's report (RESULTS/plots/summary.html, written by
    /// `hapctl analyze`) once it exists.
    #[arg(long, default_value_t = 0, requires = "results")]
    linger: u64,
}

/// Link-benchmark bookkeeping (`--bench`): the RTT histogram (1 µs
/// buckets) and one rate row per real second.
#[derive(Default)]
struct Bench {
    hist: std::collections::BTreeMap<u32, u64>,
    samples: Vec<virtuose_api::RttSample>,
    rate_csv: String,
    last_t: f64,
    last_answers: u64,
    last_lost: u64,
    last_vpr: u64,
    last_cycle: Option<u32>,
    first_cycle: Option<u32>,
    /// Servo cycles elapsed (wrap-safe sum of the 32-bit deltas).
    cycles: u64,
    /// Answers received before the benchmark started (initialisation).
    start_answers: u64,
}

impl Bench {
    fn drain(&mut self, vc: &VirtContext) {
        vc.drain_rtt(&mut self.samples);
        for s in self.samples.drain(..) {
            *self.hist.entry(s.rtt_us).or_default() += 1;
        }
    }

    /// One `rate.csv` row for the real time since the last one.
    fn row(&mut self, t: f64, vc: &VirtContext) {
        self.drain(vc);
        let ls = vc.link_stats();
        let cyc = vc.get_cycle().ok();
        let dcyc = match (self.last_cycle, cyc) {
            (Some(a), Some(b)) => b.wrapping_sub(a) as u64,
            _ => 0,
        };
        if self.first_cycle.is_none() {
            self.first_cycle = cyc;
        }
        if cyc.is_some() {
            self.last_cycle = cyc;
        }
        self.cycles += dcyc;
        let dt = (t - self.last_t).max(1e-9);
        let guest_s = dcyc as f64 * ls.period_us as f64 / 1e6;
        let _ = writeln!(
            self.rate_csv,
            "{:.3},{:.1},{},{},{},{:.4},{:.1}",
            t,
            (ls.answers - self.last_answers) as f64 / dt,
            ls.answers - self.last_answers,
            ls.lost - self.last_lost,
            ls.vpr_sent - self.last_vpr,
            guest_s / dt,
            if guest_s > 0.0 {
                (ls.answers - self.last_answers) as f64 / guest_s
            } else {
                0.0
            }
        );
        self.last_t = t;
        self.last_answers = ls.answers;
        self.last_lost = ls.lost;
        self.last_vpr = ls.vpr_sent;
    }

    /// The value at quantile `q` (0..=1) of the histogram (nearest rank).
    fn quantile(&self, q: f64) -> u32 {
        let n: u64 = self.hist.values().sum();
        if n == 0 {
            return 0;
        }
        let rank = ((q * n as f64).ceil() as u64).clamp(1, n);
        let mut acc = 0;
        for (v, c) in &self.hist {
            acc += c;
            if acc >= rank {
                return *v;
            }
        }
        0
    }

    fn summary(&self, out: &mut String, dur: f64, ls: &virtuose_api::LinkStats, overflow: u64) {
        let n: u64 = self.hist.values().sum();
        let sum: f64 = self.hist.iter().map(|(v, c)| *v as f64 * *c as f64).sum();
        let guest_s = self.cycles as f64 * ls.period_us as f64 / 1e6;
        let _ = writeln!(out, "requests: {}", ls.vpr_sent);
        let _ = writeln!(out, "bench_answers: {}", ls.answers - self.start_answers);
        let _ = writeln!(
            out,
            "request_rate_hz: {:.1}",
            ls.vpr_sent as f64 / dur.max(1e-9)
        );
        let _ = writeln!(out, "rtt_samples: {n}");
        let _ = writeln!(out, "rtt_overflow: {overflow}");
        let _ = writeln!(
            out,
            "requests_not_echoed: {}",
            ls.vpr_sent.saturating_sub(n)
        );
        let _ = writeln!(
            out,
            "rtt_us_min: {}",
            self.hist.keys().next().copied().unwrap_or(0)
        );
        let _ = writeln!(
            out,
            "rtt_us_mean: {:.1}",
            if n > 0 { sum / n as f64 } else { 0.0 }
        );
        for (k, q) in [("p50", 0.5), ("p99", 0.99), ("p99_9", 0.999)] {
            let _ = writeln!(out, "rtt_us_{k}: {}", self.quantile(q));
        }
        let _ = writeln!(
            out,
            "rtt_us_max: {}",
            self.hist.keys().next_back().copied().unwrap_or(0)
        );
        let _ = writeln!(out, "decode_errors: {}", ls.decode_errors);
        let _ = writeln!(out, "cycle_first: {}", self.first_cycle.unwrap_or(0));
        let _ = writeln!(out, "cycle_last: {}", self.last_cycle.unwrap_or(0));
        let _ = writeln!(out, "guest_s: {guest_s:.3}");
        let _ = writeln!(out, "guest_time_ratio: {:.4}", guest_s / dur.max(1e-9));
        let _ = writeln!(
            out,
            "answer_rate_guest_hz: {:.1}",
            if guest_s > 0.0 {
                ls.answers as f64 / guest_s
            } else {
                0.0
            }
        );
    }

    fn hist_csv(&self) -> String {
        let mut s = String::from("value_us,count\n");
        for (v, c) in &self.hist {
            let _ = writeln!(s, "{v},{c}");
        }
        s
    }
}

/// Everything the page and the terminal show (one sample).
#[derive(Clone, Debug, Default)]
pub struct Sample {
    pub t: f64,
    pub handle: [f64; 3],
    pub coupled: [f64; 3],
    pub free: [f64; 3],
    pub force: [f64; 3],
    pub contact: [f64; 3],
    pub loop_hz: f64,
    pub rate_hz: f64,
    pub loss: f64,
    pub rtt_ms: f64,
    pub answers: u64,
    pub lost: u64,
    pub power: bool,
}

/// Shared between the physics loop and the web server.
pub struct Shared {
    pub now: Mutex<Sample>,
    /// History for the plots (~20 Hz).
    pub history: Mutex<std::collections::VecDeque<Sample>>,
    pub world: World,
    pub server: String,
    pub done: AtomicBool,
    /// Directory of the run's report (served under /report/).
    pub report_dir: Option<PathBuf>,
}

fn a3(v: &V3) -> [f64; 3] {
    [v.x, v.y, v.z]
}

fn init(vc: &mut VirtContext, dt: f32, mass: f32) -> Result<(), virtuose_api::VirtError> {
    init_at(vc, dt, mass, [0.0; 3])
}

/// [`init`] with the resting handle put at `at` in the scene.
fn init_at(
    vc: &mut VirtContext,
    dt: f32,
    mass: f32,
    at: [f32; 3],
) -> Result<(), virtuose_api::VirtError> {
    let identity = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0];
    // References: the scene's origin (or `at`) is where the handle rests
    // when the client connects (the arm's base may be anywhere in the
    // room). Only a translation: the scene's "down" stays the arm's "down".
    let t_wait = Instant::now();
    while vc.get_position().is_err() && t_wait.elapsed() < Duration::from_secs(2) {
        vc.wait_answer(Duration::from_millis(5));
    }
    let base = match vc.get_position() {
        Ok(h) => [at[0] - h[0], at[1] - h[1], at[2] - h[2], 0.0, 0.0, 0.0, 1.0],
        // No answer yet: the handle taken at the arm's origin.
        Err(_) => [at[0], at[1], at[2], 0.0, 0.0, 0.0, 1.0],
    };
    println!(
        "init: references (base frame: translation {:.3},{:.3},{:.3} puts the resting handle at the scene's ({:.3},{:.3},{:.3}); observation frame = identity)",
        base[0], base[1], base[2], at[0], at[1], at[2]
    );
    vc.set_base_frame(&base)?;
    vc.set_observation_frame(&identity)?;
    println!("init: units (force factor 1, speed factor 1: SI units both sides)");
    vc.set_force_factor(1.0)?;
    vc.set_speed_factor(1.0)?;
    println!("init: internal variables (time step {dt} s, indexing all, virtual mechanism)");
    vc.set_time_step(dt)?;
    vc.set_indexing_mode(IndexingMode::All)?;
    vc.set_command_type(CommandType::VirtMech)?;
    println!("init: virtual object (sphere A, {mass} kg)");
    vc.attach_vo(mass, [1e-4, 1e-4, 1e-4])?;
    println!("init: interactive mode (power on)");
    vc.set_power_on(true)?;
    Ok(())
}

/// Wait (at most `timeout`) for an answer computed at least two servo cycles
/// after the first answer that arrives from now on.
fn fresh_answer(vc: &VirtContext, timeout: Duration) {
    let t = Instant::now();
    if !vc.wait_answer(timeout) {
        return;
    }
    let Ok(c0) = vc.get_cycle() else { return };
    while t.elapsed() < timeout {
        match vc.get_cycle() {
            Ok(c) if c.wrapping_sub(c0) >= 2 && c.wrapping_sub(c0) < u32::MAX / 2 => return,
            _ => {
                vc.wait_answer(Duration::from_millis(20));
            }
        }
    }
}

/// The client library's options from the command line (key file, reply
/// time-out, link passivity), for every arm.
fn client_options(args: &Args) -> Result<Options, String> {
    let key = match &args.key {
        Some(p) => {
            Some(virtuose_api::Psk::load(p).map_err(|e| format!("key {}: {e}", p.display()))?)
        }
        None => None,
    };
    Ok(Options {
        reply_timeout: Duration::from_millis(args.timeout_ms),
        attempts: 4,
        key,
        link_passivity: args.link_passivity,
    })
}

fn main() -> ExitCode {
    let args = Args::parse();
    match run(args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("virtuose_demo: error: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run(args: Args) -> Result<(), String> {
    if !(args.duration >= 0.0 && args.duration.is_finite()) {
        return Err(format!("--duration {}: must be >= 0", args.duration));
    }
    let stop = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(sig, stop.clone()).map_err(|e| format!("signals: {e}"))?;
    }
    if let Some(server2) = args.server2.clone() {
        return run_bimanual(&args, &server2, &stop);
    }
    let _fake; // keeps the fake controller alive
    let server = if args.server == "fake" {
        let p = FakePeer::start(FakePeerConfig {
            center: [0.0, 0.0, -0.03],
            ..Default::default()
        })
        .map_err(|e| format!("fake controller: {e}"))?;
        let a = p.address();
        println!("fake controller on {a}");
        _fake = Some(p);
        a
    } else {
        _fake = None;
        args.server.clone()
    };
    let dt = match args.interval_us {
        Some(us) => us as f64 / 1e6,
        None => 1.0 / args.rate as f64,
    };
    let mut world = World::default();
    let opts = client_options(&args)?;
    println!("connecting to {server}");
    let mut vc = VirtContext::open_with(&server, opts).map_err(|e| format!("{server}: {e}"))?;
    let ls = vc.link_stats();
    println!(
        "{}",
        if vc.authenticated() {
            "authenticated session (protocol v2)"
        } else {
            "UNAUTHENTICATED session (protocol v1)"
        }
    );
    println!(
        "session {} open, controller period {} us",
        vc.session_id(),
        ls.period_us
    );
    init(&mut vc, dt as f32, world.a.mass as f32).map_err(|e| format!("initialisation: {e}"))?;

    // Start sphere A where the handle is, in the base frame just set: the
    // answer held now may have been computed before the controller applied
    // it (the handle then still in the arm's frame, here 0.56 m below the
    // scene's floor, where the box's contact springs would throw the sphere
    // out at full speed). The acks came after the frame was applied and
    // answers arrive in order: an answer two servo cycles after the first
    // one received from now on was computed with the new frame.
    fresh_answer(&vc, Duration::from_secs(2));
    let t_wait = Instant::now();
    while vc.get_position().is_err() && t_wait.elapsed() < Duration::from_secs(2) {
        let p = [
            world.a.pos.x as f32,
            world.a.pos.y as f32,
            world.a.pos.z as f32,
            0.0,
            0.0,
            0.0,
            1.0,
        ];
        let _ = vc.set_position(&p);
        vc.wait_answer(Duration::from_millis(5));
    }
    if let Ok(h) = vc.get_position() {
        world.a.pos = V3::new(h[0] as f64, h[1] as f64, h[2] as f64);
    }

    let shared = Arc::new(Shared {
        now: Mutex::new(Sample::default()),
        history: Mutex::new(Default::default()),
        world,
        server: server.clone(),
        done: AtomicBool::new(false),
        report_dir: args.results.as_ref().map(|d| d.join("plots")),
    });
    if !args.headless {
        let url = web::start(args.http, shared.clone())
            .map_err(|e| format!("web server on {}: {e}", args.http))?;
        println!("UI: {url}");
    }
    let _ = std::io::stdout().flush();

    let mut csv = String::from("t,hx,hy,hz,ax,ay,az,bx,by,bz,fx,fy,fz,rate_hz,loss,rtt_ms\n");
    let t0 = Instant::now();
    let period = Duration::from_secs_f64(dt);
    let mut next = t0 + period;
    let mut handle = V3::from(world.a.pos);
    let mut handle_q: [f32; 4] = match vc.get_position() {
        Ok(h) => [h[3], h[4], h[5], h[6]],
        Err(_) => [0.0, 0.0, 0.0, 1.0],
    };
    let (mut loops, mut loop_t, mut loop_hz) = (0u64, Instant::now(), 0.0);
    let (mut last_print, mut last_hist, mut last_csv) = (0.0f64, 0.0f64, -1.0f64);
    let (mut err_sum, mut err_n, mut err_max) = (0.0f64, 0u64, 0.0f64);
    // Mean magnitude of the coupling force received over the same cycles:
    // the spring's stretch that force needs is |F| / K.
    let mut force_sum = 0.0f64;
    // The same over the cycles where nothing but the coupling and the drag
    // acts on the sphere (no wall, floor or sphere-B contact holding it
    // back), with the handle's path over them: the lag of a free sphere.
    let (mut free_sum, mut free_n, mut free_max) = (0.0f64, 0u64, 0.0f64);
    let (mut free_path, mut free_time) = (0.0f64, 0.0f64);
    let mut prev_t = 0.0f64;
    let (mut last_answers, mut last_answer_t) = (0u64, 0.0f64);
    let (mut handle_travel, mut coupled_travel) = (0.0f64, 0.0f64);
    let mut prev_a = world.a.pos;
    // The scene's stiff walls and floor (contact springs on sphere A) and
    // its free mass (sphere B): cycles in contact with each, B's path.
    let (mut wall_cycles, mut mass_cycles) = (0u64, 0u64);
    let mut mass_travel = 0.0f64;
    let mut prev_h: Option<V3> = None;
    let mut force = V3::zeros();
    let mut bench = args.bench.then(|| {
        vc.record_rtt(true);
        Bench {
            rate_csv: String::from(
                "t_s,answers_per_s,answers,lost,requests,guest_time_ratio,answers_per_guest_s\n",
            ),
            ..Default::default()
        }
    });
    if let Some(b) = bench.as_mut() {
        b.row(0.0, &vc);
        b.rate_csv
            .truncate(b.rate_csv.find('\n').map_or(0, |i| i + 1));
    }
    let mut requests = 0u64;
    let mut held = 0u64;
    let mut silent = false;
    let mut stale = 0u64;
    // Answers the controller sent for our frames: accepted, and those that
    // arrived behind a newer one (a reordering link) and were dropped.
    let answered = |ls: &virtuose_api::LinkStats| ls.answers + ls.stale;
    let answers0 = answered(&vc.link_stats());

    loop {
        let t = t0.elapsed().as_secs_f64();
        if stop.load(Ordering::Relaxed)
            || (args.duration > 0.0
                && t >= args.duration
                && vc.link_stats().answers >= args.answers)
            || (args.max_duration > 0.0 && t >= args.max_duration)
            || (args.samples > 0 && requests >= args.samples)
        {
            break;
        }
        if let Some(b) = bench.as_mut() {
            if t - b.last_t >= 1.0 {
                b.row(t, &vc);
            }
        }
        if let (Ok(h), Ok(f)) = (vc.get_position(), vc.get_force()) {
            handle = V3::new(h[0] as f64, h[1] as f64, h[2] as f64);
            handle_q = [h[3], h[4], h[5], h[6]];
            force = V3::new(f[0] as f64, f[1] as f64, f[2] as f64);
        }
        let power = vc.get_power_on().unwrap_or(false);
        // The force is the spring's pull toward the VPr it was computed
        // for. If that VPr left more than 100 ms ago (the round trip of the
        // last echoed one plus the time since the last answer: the
        // controller's own link-fade horizon), it is not applied and the
        // sphere is left to its drag (`stale_cycles`). (The drag alone keeps
        // a delayed spring passive only up to 2·drag/K ≈ 18 ms at 1 ms's
        // K_t: `World::drag_a`.) With
        // `--link-passivity` the library's link limiter keeps the client's
        // end passive at any delay (the force it returns is already what the
        // link's energy pays for): applied whatever its age.
        let loop_age_s = vc.link_stats().rtt_ms_last / 1000.0 + (t - last_answer_t);
        let fresh = args.link_passivity || loop_age_s <= 0.1;
        let applied = if fresh { force } else { V3::zeros() };
        if !fresh {
            stale += 1;
        }
        let b_before = world.b.pos;
        world.step(dt, applied);
        let a = world.a;
        if world.wall_on_a.norm() != 0.0 {
            wall_cycles += 1;
        }
        if world.contact_on_a.norm() != 0.0 {
            mass_cycles += 1;
        }
        mass_travel += (world.b.pos - b_before).norm();
        let sp = [
            a.vel.x as f32,
            a.vel.y as f32,
            a.vel.z as f32,
            0.0,
            0.0,
            0.0,
        ];
        let _ = vc.set_speed(&sp);
        // Pacing: the controller answers once per servo cycle and uses only
        // the newest target, so a client streaming faster than it consumes
        // (an emulated guest running slower than real time) only fills the
        // queues in front of it: its targets then reach the arm seconds
        // late, and a spring delayed by more than 2·drag/K (~18 ms here) is
        // no longer passive: the sphere runs away. So stay at most
        // `window` frames ahead of the answers; the newest pose goes out
        // with the next answer.
        let ahead = requests.saturating_sub(answered(&vc.link_stats()).saturating_sub(answers0));
        if args.window == 0 || ahead < args.window {
            // A sphere has no orientation to couple: it takes the handle's,
            // so the coupling is a pure translation.
            let _ = vc.set_position(&[
                a.pos.x as f32,
                a.pos.y as f32,
                a.pos.z as f32,
                handle_q[0],
                handle_q[1],
                handle_q[2],
                handle_q[3],
            ]);
            requests += 1;
        } else {
            held += 1;
        }

        // bookkeeping
        loops += 1;
        if loop_t.elapsed() >= Duration::from_millis(500) {
            loop_hz = loops as f64 / loop_t.elapsed().as_secs_f64();
            loops = 0;
            loop_t = Instant::now();
        }
        let step = prev_h.map_or(0.0, |ph| (handle - ph).norm());
        let dt_loop = t - prev_t;
        handle_travel += step;
        prev_h = Some(handle);
        coupled_travel += (a.pos - prev_a).norm();
        prev_a = a.pos;
        prev_t = t;
        // A controller that stopped answering (fail-safe, guest gone) ends
        // the run: nothing more can be measured.
        let answers_now = vc.link_stats().answers;
        if answers_now != last_answers {
            (last_answers, last_answer_t) = (answers_now, t);
        } else if t - last_answer_t > 5.0 {
            println!("no answer for 5 s: the controller stopped answering");
            silent = true;
            break;
        }
        if t > 1.0 && fresh {
            let e = (handle - a.pos).norm();
            err_sum += e;
            err_n += 1;
            force_sum += force.norm();
            err_max = err_max.max(e);
            if world.contact_on_a.norm() == 0.0 && world.wall_on_a.norm() == 0.0 {
                free_sum += e;
                free_n += 1;
                free_max = free_max.max(e);
                free_path += step;
                free_time += dt_loop;
            }
        }
        if t - last_hist >= 0.05 || t - last_csv >= 0.01 || t - last_print >= 1.0 {
            let ls = vc.link_stats();
            let s = Sample {
                t,
                handle: a3(&handle),
                coupled: a3(&a.pos),
                free: a3(&world.b.pos),
                force: a3(&force),
                contact: a3(&world.contact_on_a),
                loop_hz,
                rate_hz: ls.rate_hz,
                loss: ls.loss_ratio,
                rtt_ms: ls.rtt_ms_last,
                answers: ls.answers,
                lost: ls.lost,
                power,
            };
            if t - last_csv >= 0.01 {
                last_csv = t;
                let _ = writeln!(
                    csv,
                    "{:.4},{:.5},{:.5},{:.5},{:.5},{:.5},{:.5},{:.5},{:.5},{:.5},{:.4},{:.4},{:.4},{:.1},{:.5},{:.4}",
                    t, handle.x, handle.y, handle.z, a.pos.x, a.pos.y, a.pos.z, world.b.pos.x, world.b.pos.y, world.b.pos.z,
                    force.x, force.y, force.z, ls.rate_hz, ls.loss_ratio, ls.rtt_ms_last
                );
            }
            if t - last_print >= 1.0 {
                last_print = t;
                println!(
                    "t={:6.1}s loop={:5.0}Hz rate={:5.0}Hz loss={:.3}% rtt={:.3}ms power={} handle=({:+.4},{:+.4},{:+.4}) sphere=({:+.4},{:+.4},{:+.4}) force=({:+.2},{:+.2},{:+.2})N",
                    t, loop_hz, ls.rate_hz, ls.loss_ratio * 100.0, ls.rtt_ms_last, if power { "on" } else { "off" },
                    handle.x, handle.y, handle.z, a.pos.x, a.pos.y, a.pos.z, force.x, force.y, force.z
                );
                let _ = std::io::stdout().flush();
            }
            if t - last_hist >= 0.05 {
                last_hist = t;
                if let Ok(mut h) = shared.history.lock() {
                    h.push_back(s.clone());
                    while h.len() > 200 {
                        h.pop_front();
                    }
                }
            }
            if let Ok(mut n) = shared.now.lock() {
                *n = s;
            }
        }

        // fixed-rate loop
        let now = Instant::now();
        if next > now {
            std::thread::sleep(next - now);
            next += period;
        } else {
            // late: do not try to catch up with a burst
            next = now + period;
        }
    }
    shared.done.store(true, Ordering::SeqCst);

    let dur = t0.elapsed().as_secs_f64();
    // Let the last answers in (a round trip is a few ms), then account.
    if let Some(b) = bench.as_mut() {
        std::thread::sleep(Duration::from_millis(100));
        b.row(t0.elapsed().as_secs_f64(), &vc);
    }
    let ls = vc.link_stats();
    let rtt_overflow = vc.rtt_overflow();
    let _ = vc.set_power_on(false);
    let _ = vc.close();
    // Every frame of the session, the power-off and the close included.
    let frames_sent = vc.link_stats().sent;
    let mut summary = String::new();
    let _ = writeln!(summary, "server: {server}");
    let _ = writeln!(summary, "duration_s: {dur:.3}");
    let _ = writeln!(summary, "frames_sent: {frames_sent}");
    let _ = writeln!(summary, "vpr_sent: {}", ls.vpr_sent);
    let _ = writeln!(summary, "vpr_held: {held}");
    let _ = writeln!(summary, "answers: {}", ls.answers);
    let _ = writeln!(
        summary,
        "sample_rate_hz: {:.1}",
        ls.answers as f64 / dur.max(1e-9)
    );
    let _ = writeln!(summary, "lost: {}", ls.lost);
    let _ = writeln!(summary, "loss_ratio: {:.6}", ls.loss_ratio);
    let _ = writeln!(summary, "duplicates: {}", ls.duplicates);
    let _ = writeln!(summary, "stale: {}", ls.stale);
    let _ = writeln!(summary, "rtt_ms_mean: {:.4}", ls.rtt_ms_mean);
    let _ = writeln!(summary, "rtt_ms_max: {:.4}", ls.rtt_ms_max);
    let _ = writeln!(
        summary,
        "coupling_error_mean_m: {:.6}",
        if err_n > 0 {
            err_sum / err_n as f64
        } else {
            0.0
        }
    );
    let _ = writeln!(summary, "coupling_error_max_m: {err_max:.6}");
    let _ = writeln!(
        summary,
        "coupling_force_mean_n: {:.6}",
        if err_n > 0 {
            force_sum / err_n as f64
        } else {
            0.0
        }
    );
    let _ = writeln!(
        summary,
        "free_coupling_error_mean_m: {:.6}",
        if free_n > 0 {
            free_sum / free_n as f64
        } else {
            0.0
        }
    );
    let _ = writeln!(summary, "free_coupling_error_max_m: {free_max:.6}");
    let _ = writeln!(summary, "free_samples: {free_n}");
    let _ = writeln!(
        summary,
        "free_handle_speed_mean_m_s: {:.6}",
        if free_time > 0.0 {
            free_path / free_time
        } else {
            0.0
        }
    );
    let _ = writeln!(summary, "controller_silent: {}", u8::from(silent));
    let _ = writeln!(summary, "stale_cycles: {stale}");
    // The client's end of the link (with --link-passivity; 0 otherwise):
    // what its port put in and took out, what it granted the controller and
    // the controller granted it, and its reservoir (≥ 0: this end created
    // no energy).
    let ledger = vc.link_ledger();
    let _ = writeln!(
        summary,
        "link_energy_in_j: {:.9}",
        ledger.energy_in.to_f64()
    );
    let _ = writeln!(
        summary,
        "link_energy_out_j: {:.9}",
        ledger.energy_out.to_f64()
    );
    let _ = writeln!(summary, "link_granted_j: {:.9}", ledger.granted.to_f64());
    let _ = writeln!(
        summary,
        "link_received_j: {:.9}",
        ledger.peer.total().to_f64()
    );
    let _ = writeln!(
        summary,
        "link_reservoir_j: {:.9}",
        ledger.reservoir().to_f64()
    );
    let _ = writeln!(summary, "handle_travel_m: {handle_travel:.5}");
    let _ = writeln!(summary, "coupled_travel_m: {coupled_travel:.5}");
    let _ = writeln!(summary, "wall_contact_cycles: {wall_cycles}");
    let _ = writeln!(summary, "free_mass_contact_cycles: {mass_cycles}");
    let _ = writeln!(summary, "free_mass_travel_m: {mass_travel:.5}");
    if let Some(b) = &bench {
        b.summary(&mut summary, dur, &ls, rtt_overflow);
    }
    print!("summary:\n{summary}");
    if let Some(dir) = &args.results {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        std::fs::write(dir.join("run.csv"), csv).map_err(|e| format!("{}: {e}", dir.display()))?;
        std::fs::write(dir.join("summary.txt"), &summary)
            .map_err(|e| format!("{}: {e}", dir.display()))?;
        if let Some(b) = &bench {
            std::fs::write(dir.join("rtt_hist.csv"), b.hist_csv())
                .map_err(|e| format!("{}: {e}", dir.display()))?;
            std::fs::write(dir.join("rate.csv"), &b.rate_csv)
                .map_err(|e| format!("{}: {e}", dir.display()))?;
        }
        println!("results in {}", dir.display());
        if !args.headless && args.linger > 0 {
            println!(
                "web page kept up {} s for the run report (Ctrl-C ends it)",
                args.linger
            );
            let _ = std::io::stdout().flush();
            // SIGINT/SIGTERM set `stop`: the page goes down at once.
            let end = Instant::now() + Duration::from_secs(args.linger);
            while !stop.load(Ordering::Relaxed) && Instant::now() < end {
                std::thread::sleep(Duration::from_millis(100));
            }
        }
    }
    if silent {
        return Err("the controller stopped answering (no answer for 5 s)".into());
    }
    Ok(())
}

/// The two arms' hands rest here in the scene: 17 cm apart, the object on
/// the floor between them.
const HANDS_AT: [[f32; 3]; 2] = [[-0.085, 0.0, -0.07], [0.085, 0.0, -0.07]];

/// An arm of the bimanual scene: its context and link bookkeeping.
struct Hand {
    vc: VirtContext,
    force: V3,
    handle: V3,
    handle_q: [f32; 4],
    requests: u64,
    answers0: u64,
    last_answers: u64,
    last_answer_t: f64,
}

/// Open arm `i`'s context at `addr` ("fake": an in-process fake controller
/// whose handle squeezes in and rises, then parts and sinks, every 4 s).
fn open_hand(
    i: usize,
    addr: &str,
    args: &Args,
    dt: f64,
    fakes: &mut Vec<FakePeer>,
) -> Result<Hand, String> {
    let server = if addr == "fake" {
        let inward = if i == 0 { 0.03 } else { -0.03 };
        // The fake applies no base frame: its handle rests at the hand's
        // place in the scene.
        let p = FakePeer::start(FakePeerConfig {
            center: HANDS_AT[i].map(f64::from),
            amplitude: [inward, 0.0, 0.03],
            freq_hz: 0.25,
            ..Default::default()
        })
        .map_err(|e| format!("fake controller: {e}"))?;
        let a = p.address();
        println!("arm {i}: fake controller on {a}");
        fakes.push(p);
        a
    } else {
        addr.to_string()
    };
    let opts = client_options(args)?;
    println!("arm {i}: connecting to {server}");
    let mut vc = VirtContext::open_with(&server, opts).map_err(|e| format!("{server}: {e}"))?;
    init_at(&mut vc, dt as f32, 0.5, HANDS_AT[i])
        .map_err(|e| format!("arm {i}: initialisation: {e}"))?;
    fresh_answer(&vc, Duration::from_secs(2));
    let ls0 = vc.link_stats();
    let answers0 = ls0.answers + ls0.stale;
    Ok(Hand {
        vc,
        force: V3::zeros(),
        handle: V3::new(
            f64::from(HANDS_AT[i][0]),
            f64::from(HANDS_AT[i][1]),
            f64::from(HANDS_AT[i][2]),
        ),
        handle_q: [0.0, 0.0, 0.0, 1.0],
        requests: 0,
        answers0,
        last_answers: ls0.answers,
        last_answer_t: 0.0,
    })
}

/// The bimanual scene: each arm couples its hand; the object is held when
/// both hands grip it off the floor.
fn run_bimanual(args: &Args, server2: &str, stop: &AtomicBool) -> Result<(), String> {
    if !args.headless {
        println!("bimanual scene: terminal only (the web page shows the one-arm scene)");
    }
    let dt = match args.interval_us {
        Some(us) => us as f64 / 1e6,
        None => 1.0 / args.rate as f64,
    };
    let mut fakes = Vec::new();
    let mut hands = [
        open_hand(0, &args.server, args, dt, &mut fakes)?,
        open_hand(1, server2, args, dt, &mut fakes)?,
    ];
    let at = |i: usize| {
        let h = &hands[i].vc;
        match h.get_position() {
            Ok(p) => V3::new(p[0] as f64, p[1] as f64, p[2] as f64),
            Err(_) => V3::new(
                f64::from(HANDS_AT[i][0]),
                f64::from(HANDS_AT[i][1]),
                f64::from(HANDS_AT[i][2]),
            ),
        }
    };
    let mut scene = Bimanual::new([at(0), at(1)]);
    let t0 = Instant::now();
    let period = Duration::from_secs_f64(dt);
    let mut next = t0 + period;
    let (mut last_print, mut max_lift, mut held_cycles, mut cycles) = (0.0f64, 0.0f64, 0u64, 0u64);
    let mut silent = false;
    loop {
        let t = t0.elapsed().as_secs_f64();
        if stop.load(Ordering::Relaxed)
            || (args.duration > 0.0 && t >= args.duration)
            || (args.max_duration > 0.0 && t >= args.max_duration)
        {
            break;
        }
        let mut coupling = [V3::zeros(); 2];
        for (h, c) in hands.iter_mut().zip(coupling.iter_mut()) {
            if let (Ok(p), Ok(f)) = (h.vc.get_position(), h.vc.get_force()) {
                h.handle = V3::new(p[0] as f64, p[1] as f64, p[2] as f64);
                h.handle_q = [p[3], p[4], p[5], p[6]];
                h.force = V3::new(f[0] as f64, f[1] as f64, f[2] as f64);
            }
            let answers = h.vc.link_stats().answers;
            if answers != h.last_answers {
                (h.last_answers, h.last_answer_t) = (answers, t);
            }
            // As in the one-arm scene: a force older than 100 ms is not
            // applied (a delayed spring is not passive), unless the link
            // limiter keeps the client's end passive.
            let age = h.vc.link_stats().rtt_ms_last / 1000.0 + (t - h.last_answer_t);
            *c = if args.link_passivity || age <= 0.1 {
                h.force
            } else {
                V3::zeros()
            };
        }
        if hands.iter().any(|h| t - h.last_answer_t > 5.0) {
            println!("no answer for 5 s from an arm: the controller stopped answering");
            silent = true;
            break;
        }
        scene.step(dt, coupling);
        cycles += 1;
        max_lift = max_lift.max(scene.lift());
        held_cycles += u64::from(scene.held());
        for (h, s) in hands.iter_mut().zip(scene.hands.iter()) {
            let _ = h.vc.set_speed(&[
                s.vel.x as f32,
                s.vel.y as f32,
                s.vel.z as f32,
                0.0,
                0.0,
                0.0,
            ]);
            let ls = h.vc.link_stats();
            let ahead = h
                .requests
                .saturating_sub((ls.answers + ls.stale).saturating_sub(h.answers0));
            if args.window == 0 || ahead < args.window {
                let q = h.handle_q;
                let _ = h.vc.set_position(&[
                    s.pos.x as f32,
                    s.pos.y as f32,
                    s.pos.z as f32,
                    q[0],
                    q[1],
                    q[2],
                    q[3],
                ]);
                h.requests += 1;
            }
        }
        if t - last_print >= 1.0 {
            last_print = t;
            let [l, r] = &scene.hands;
            let o = &scene.object;
            println!(
                "t={:6.1}s hands=({:+.4},{:+.4},{:+.4}) ({:+.4},{:+.4},{:+.4}) object=({:+.4},{:+.4},{:+.4}) lift={:.1}mm {}",
                t, l.pos.x, l.pos.y, l.pos.z, r.pos.x, r.pos.y, r.pos.z, o.pos.x, o.pos.y, o.pos.z,
                scene.lift() * 1000.0,
                if scene.held() { "held" } else { "-" }
            );
            let _ = std::io::stdout().flush();
        }
        let now = Instant::now();
        if next > now {
            std::thread::sleep(next - now);
            next += period;
        } else {
            next = now + period;
        }
    }
    let dur = t0.elapsed().as_secs_f64();
    let mut summary = String::new();
    let _ = writeln!(summary, "scene: bimanual");
    let _ = writeln!(summary, "duration_s: {dur:.3}");
    let _ = writeln!(summary, "cycles: {cycles}");
    for (i, h) in hands.iter_mut().enumerate() {
        let ls = h.vc.link_stats();
        let _ = writeln!(summary, "arm{i}_answers: {}", ls.answers);
        let _ = writeln!(summary, "arm{i}_loss_ratio: {:.6}", ls.loss_ratio);
        let _ = h.vc.set_power_on(false);
        let _ = h.vc.close();
    }
    let _ = writeln!(summary, "object_max_lift_m: {max_lift:.5}");
    let _ = writeln!(summary, "held_cycles: {held_cycles}");
    let _ = writeln!(summary, "controller_silent: {}", u8::from(silent));
    print!("summary:\n{summary}");
    if let Some(dir) = &args.results {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        std::fs::write(dir.join("summary.txt"), &summary)
            .map_err(|e| format!("{}: {e}", dir.display()))?;
    }
    drop(fakes);
    if silent {
        return Err("the controller stopped answering (no answer for 5 s)".into());
    }
    Ok(())
}
