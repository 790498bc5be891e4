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
use physics::{World, V3};
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
    /// Reply timeout of acknowledged requests, ms.
    #[arg(long, default_value_t = 250)]
    timeout_ms: u64,
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
}

fn a3(v: &V3) -> [f64; 3] {
    [v.x, v.y, v.z]
}

fn init(vc: &mut VirtContext, dt: f32, mass: f32) -> Result<(), virtuose_api::VirtError> {
    let identity = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0];
    // References: the scene's origin is where the handle rests when the
    // client connects (the arm's base may be anywhere in the room). Only a
    // translation: the scene's "down" stays the arm's "down".
    let t_wait = Instant::now();
    while vc.get_position().is_err() && t_wait.elapsed() < Duration::from_secs(2) {
        vc.wait_answer(Duration::from_millis(5));
    }
    let base = match vc.get_position() {
        Ok(h) => [-h[0], -h[1], -h[2], 0.0, 0.0, 0.0, 1.0],
        Err(_) => identity,
    };
    println!(
        "init: references (base frame: translation {:.3},{:.3},{:.3} puts the resting handle at the scene origin; observation frame = identity)",
        base[0], base[1], base[2]
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
    let dt = 1.0 / args.rate as f64;
    let mut world = World::default();
    let opts = Options {
        reply_timeout: Duration::from_millis(args.timeout_ms),
        attempts: 4,
    };
    println!("connecting to {server}");
    let mut vc = VirtContext::open_with(&server, opts).map_err(|e| format!("{server}: {e}"))?;
    let ls = vc.link_stats();
    println!(
        "session {} open, controller period {} us",
        vc.session_id(),
        ls.period_us
    );
    init(&mut vc, dt as f32, world.a.mass as f32).map_err(|e| format!("initialisation: {e}"))?;

    // Start sphere A where the handle is.
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
    let (mut handle_travel, mut coupled_travel) = (0.0f64, 0.0f64);
    let mut prev_a = world.a.pos;
    let mut prev_h: Option<V3> = None;
    let mut force = V3::zeros();

    loop {
        let t = t0.elapsed().as_secs_f64();
        if stop.load(Ordering::Relaxed) || (args.duration > 0.0 && t >= args.duration) {
            break;
        }
        if let (Ok(h), Ok(f)) = (vc.get_position(), vc.get_force()) {
            handle = V3::new(h[0] as f64, h[1] as f64, h[2] as f64);
            handle_q = [h[3], h[4], h[5], h[6]];
            force = V3::new(f[0] as f64, f[1] as f64, f[2] as f64);
        }
        let power = vc.get_power_on().unwrap_or(false);
        world.step(dt, force);
        let a = world.a;
        let sp = [
            a.vel.x as f32,
            a.vel.y as f32,
            a.vel.z as f32,
            0.0,
            0.0,
            0.0,
        ];
        let _ = vc.set_speed(&sp);
        // A sphere has no orientation to couple: it takes the handle's, so
        // the coupling is a pure translation.
        let _ = vc.set_position(&[
            a.pos.x as f32,
            a.pos.y as f32,
            a.pos.z as f32,
            handle_q[0],
            handle_q[1],
            handle_q[2],
            handle_q[3],
        ]);

        // bookkeeping
        loops += 1;
        if loop_t.elapsed() >= Duration::from_millis(500) {
            loop_hz = loops as f64 / loop_t.elapsed().as_secs_f64();
            loops = 0;
            loop_t = Instant::now();
        }
        if let Some(ph) = prev_h {
            handle_travel += (handle - ph).norm();
        }
        prev_h = Some(handle);
        coupled_travel += (a.pos - prev_a).norm();
        prev_a = a.pos;
        if t > 1.0 {
            let e = (handle - a.pos).norm();
            err_sum += e;
            err_n += 1;
            err_max = err_max.max(e);
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
    let ls = vc.link_stats();
    let _ = vc.set_power_on(false);
    let _ = vc.close();
    let mut summary = String::new();
    let _ = writeln!(summary, "server: {server}");
    let _ = writeln!(summary, "duration_s: {dur:.3}");
    let _ = writeln!(summary, "vpr_sent: {}", ls.vpr_sent);
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
    let _ = writeln!(summary, "handle_travel_m: {handle_travel:.5}");
    let _ = writeln!(summary, "coupled_travel_m: {coupled_travel:.5}");
    print!("summary:\n{summary}");
    if let Some(dir) = &args.results {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        std::fs::write(dir.join("run.csv"), csv).map_err(|e| format!("{}: {e}", dir.display()))?;
        std::fs::write(dir.join("summary.txt"), &summary)
            .map_err(|e| format!("{}: {e}", dir.display()))?;
        println!("results in {}", dir.display());
    }
    Ok(())
}
