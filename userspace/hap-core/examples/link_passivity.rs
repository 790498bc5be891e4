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
        }
    }
}
