//! The full link passivity campaign (`scripts/bench-link-passivity.sh` runs
//! it in release): for each round trip of 0, 20, 100, 300 and 1000 ms, runs
//! of the controller and a client (a free mass and a stiff wall) through a
//! channel with ±50 % jitter, 10 % and 20 % loss and the reordering that
//! jitter makes, random user efforts then a release; the same at 300 ms
//! with both passivity controllers off; and the wall probe (felt
//! stiffness, drift) per delay. Deterministic seeds; stops at the first
//! run whose channel created energy, whose force or speed bound broke,
//! whose oscillation grew after the release or whose live link faded.
//! Usage: link_passivity [RUNS_PER_CASE] [CYCLES_PER_RUN]
#[path = "../tests/common/campaign.rs"]
mod campaign;
#[path = "../tests/common/link_campaign.rs"]
mod link_campaign;

use link_campaign::{force_bound, probe_wall, run, Link, LinkFigures, Object};

fn check(l: &Link, seed: u64, r: &LinkFigures) {
    let bad = |what: &str| -> ! {
        panic!("seed {seed} {l:?}: {what}: {r:?}");
    };
    if l.passivity {
        if r.channel_min < -1e-4 {
            bad("the channel created energy");
        }
        if r.release_end > r.release_peak * 1.05 + 1e-6 {
            bad("oscillation grew after the release");
        }
        if r.faded_cycles != 0 {
            bad("a live link faded");
        }
    }
    if r.max_force > force_bound() * (1.0 + 1e-6) {
        bad("force bound");
    }
    // The safety campaign's proven handle speed bound at 1 ms.
    if r.max_speed > campaign::handle_speed_bound(1_000_000) {
        bad("speed bound");
    }
}

fn main() {
    let mut args = std::env::args().skip(1);
    let runs: u64 = args.next().and_then(|a| a.parse().ok()).unwrap_or(6);
    let cycles: u64 = args.next().and_then(|a| a.parse().ok()).unwrap_or(20_000);
    // Where to write the wall probe's plot (felt stiffness and drift per
    // round trip), if given.
    let plot_dir = args.next();
    println!(
        "mode: host native, deterministic; {runs} runs × {cycles} cycles per case, 1 ms period"
    );
    println!(
        "bounds: force {} N, handle speed {:.2} m/s (the safety campaign's)",
        force_bound(),
        campaign::handle_speed_bound(1_000_000)
    );
    println!(
        "{:>7} {:>5} {:>5} {:>6} {:>6} {:>13} {:>13} {:>8} {:>8} {:>9} {:>9} {:>8} {:>8}",
        "rtt_ms",
        "jit",
        "loss",
        "object",
        "PC",
        "channel_min_J",
        "worst_end_J",
        "F_max_N",
        "v_max",
        "lim_srv%",
        "lim_cli%",
        "drift_mm",
        "decay"
    );
    let mut total = 0u64;
    let mut worst = f64::INFINITY;
    for (ci, &rtt) in [0.0, 20.0, 100.0, 300.0, 1000.0].iter().enumerate() {
        let losses: &[f64] = if rtt == 0.0 { &[0.0] } else { &[0.1, 0.2] };
        for &loss in losses {
            for object in [Object::FreeMass, Object::Wall] {
                let jitter = if rtt == 0.0 { 0.0 } else { 0.5 };
                let l = Link {
                    rtt_ms: rtt,
                    jitter,
                    loss,
                    passivity: true,
                    object,
                };
                let (mut cmin, mut cend, mut fmax, mut vmax) =
                    (f64::INFINITY, f64::INFINITY, 0.0f64, 0.0f64);
                let (mut ls, mut lc, mut drift, mut decay, mut cyc) =
                    (0u64, 0u64, 0.0f64, 0.0f64, 0u64);
                for k in 0..runs {
                    let seed = 10_000 + ci as u64 * 1000 + k * 7 + (loss * 100.0) as u64;
                    let r = run(seed, l, cycles);
                    check(&l, seed, &r);
                    cmin = cmin.min(r.channel_min);
                    cend = cend.min(r.channel_end);
                    fmax = fmax.max(r.max_force);
                    vmax = vmax.max(r.max_speed);
                    ls += r.limited_server;
                    lc += r.limited_client;
                    drift = drift.max(r.drift);
                    decay = decay.max(r.release_end / r.release_peak.max(1e-12));
                    cyc += r.cycles;
                }
                total += cyc;
                worst = worst.min(cmin);
                println!(
                    "{:>7} {:>5} {:>5} {:>6} {:>6} {:>13.3e} {:>13.3e} {:>8.3} {:>8.3} {:>9.1} {:>9.1} {:>8.1} {:>8.3}",
                    rtt,
                    jitter,
                    l.loss,
                    format!("{object:?}").chars().take(6).collect::<String>(),
                    "on",
                    cmin,
                    cend,
                    fmax,
                    vmax,
                    100.0 * ls as f64 / cyc as f64,
                    100.0 * lc as f64 / cyc as f64,
                    drift * 1000.0,
                    decay
                );
            }
        }
    }
    // The same slow link with both controllers off.
    for object in [Object::FreeMass, Object::Wall] {
        let l = Link {
            rtt_ms: 300.0,
            jitter: 0.5,
            loss: 0.1,
            passivity: false,
            object,
        };
        let r = run(99, l, cycles);
        check(&l, 99, &r);
        total += r.cycles;
        println!(
            "{:>7} {:>5} {:>5} {:>6} {:>6} {:>13.3e} {:>13.3e} {:>8.3} {:>8.3} {:>9} {:>9} {:>8.1} {:>8.3}",
            300,
            0.5,
            0.1,
            format!("{object:?}").chars().take(6).collect::<String>(),
            "off",
            r.channel_min,
            r.channel_end,
            r.max_force,
            r.max_speed,
            "-",
            "-",
            r.drift * 1000.0,
            r.release_end / r.release_peak.max(1e-12)
        );
    }
    println!("cycles: {total}; lowest channel energy with the controllers on: {worst:.3e} J");
    println!();
    println!(
        "wall probe (the user pushes 5 N then 10 N into a 20 kN/m wall; jitter ±50 %, loss 10 %):"
    );
    println!(
        "{:>7} {:>6} {:>18} {:>16} {:>10} {:>13}",
        "rtt_ms", "PC", "felt_stiff_N_per_m", "penetr_10N_mm", "drift_mm", "channel_min_J"
    );
    let mut plotted = Vec::new();
    for &rtt in &[0.0, 20.0, 100.0, 300.0, 1000.0] {
        for pc in [true, false] {
            if !pc && rtt != 300.0 {
                continue;
            }
            let jitter = if rtt == 0.0 { 0.0 } else { 0.5 };
            let loss = if rtt == 0.0 { 0.0 } else { 0.1 };
            let p = probe_wall(rtt, jitter, loss, pc, 7);
            println!(
                "{:>7} {:>6} {:>18.0} {:>16.2} {:>10.2} {:>13.3e}",
                rtt,
                if pc { "on" } else { "off" },
                p.stiffness,
                p.penetration_10n * 1000.0,
                p.drift * 1000.0,
                p.channel_min
            );
            if pc {
                plotted.push((rtt, p.stiffness, p.drift * 1000.0));
            }
        }
    }
    if let Some(dir) = plot_dir {
        let path = format!("{dir}/link-probe.svg");
        std::fs::write(&path, probe_svg(&plotted)).expect("write the wall probe's plot");
        println!("plot: {path}");
    }
}

/// The wall probe per round trip as one small SVG: felt stiffness (N/m,
/// left axis, bars) and the handle–object drift (mm, right axis, dots).
fn probe_svg(points: &[(f64, f64, f64)]) -> String {
    let (w, h) = (640.0, 400.0);
    let (x0, y0, x1, y1) = (70.0, 30.0, 570.0, 340.0);
    let kmax = points.iter().map(|p| p.1).fold(1.0, f64::max) * 1.1;
    let dmax = points.iter().map(|p| p.2).fold(1.0, f64::max) * 1.1;
    let n = points.len().max(1) as f64;
    let slot = (x1 - x0) / n;
    let ky = |k: f64| y1 - k / kmax * (y1 - y0);
    let dy = |d: f64| y1 - d / dmax * (y1 - y0);
    let mut s = format!("<svg xmlns='http://www.w3.org/2000/svg' width='{w}' height='{h}' font-family='sans-serif' font-size='12'>\n<rect width='100%' height='100%' fill='white'/>\n");
    s += &format!("<text x='{}' y='18' text-anchor='middle'>Wall probe across the link (±50 % jitter, 10 % loss; 0 ms: none): felt stiffness and drift</text>\n", w / 2.0);
    s += &format!("<line x1='{x0}' y1='{y1}' x2='{x1}' y2='{y1}' stroke='black'/><line x1='{x0}' y1='{y0}' x2='{x0}' y2='{y1}' stroke='#1f77b4'/><line x1='{x1}' y1='{y0}' x2='{x1}' y2='{y1}' stroke='#d62728'/>\n");
    for i in 0..=4 {
        let k = kmax * i as f64 / 4.0;
        let d = dmax * i as f64 / 4.0;
        s += &format!(
            "<text x='{}' y='{}' text-anchor='end' fill='#1f77b4'>{k:.0}</text>\n",
            x0 - 5.0,
            ky(k) + 4.0
        );
        s += &format!(
            "<text x='{}' y='{}' fill='#d62728'>{d:.0}</text>\n",
            x1 + 5.0,
            dy(d) + 4.0
        );
    }
    for (i, (rtt, k, d)) in points.iter().enumerate() {
        let cx = x0 + slot * (i as f64 + 0.5);
        s += &format!(
            "<rect x='{}' y='{}' width='{}' height='{}' fill='#1f77b4' opacity='0.6'/>\n",
            cx - slot * 0.3,
            ky(*k),
            slot * 0.6,
            y1 - ky(*k)
        );
        s += &format!("<circle cx='{cx}' cy='{}' r='5' fill='#d62728'/>\n", dy(*d));
        s += &format!(
            "<text x='{cx}' y='{}' text-anchor='middle'>{rtt:.0} ms</text>\n",
            y1 + 16.0
        );
    }
    s += &format!(
        "<text x='{}' y='{}' text-anchor='middle'>round trip</text>\n",
        (x0 + x1) / 2.0,
        h - 20.0
    );
    s += &format!("<text x='15' y='{}' transform='rotate(-90 15 {})' text-anchor='middle' fill='#1f77b4'>felt stiffness (N/m), bars</text>\n", (y0 + y1) / 2.0, (y0 + y1) / 2.0);
    s += &format!("<text x='{}' y='{}' transform='rotate(90 {} {})' text-anchor='middle' fill='#d62728'>drift handle–object (mm), dots</text>\n", w - 20.0, (y0 + y1) / 2.0, w - 20.0, (y0 + y1) / 2.0);
    s += "</svg>\n";
    s
}
