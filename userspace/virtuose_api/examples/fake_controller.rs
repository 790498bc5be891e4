//! The fake controller (`virtuose_api::fake_peer`) as a process, for
//! testing programs written in other languages against the library:
//!
//!   fake_controller [--port N] [--period-us N] [--duration S] [--center X,Y,Z] [--amplitude X,Y,Z]
//!                   [--buttons MASK] [--power-lag N]
//!
//! `--buttons`: the handle's buttons held pressed in every answer (1: the
//! first, 2: the second, 3: both); `--power-lag`: answers that still report
//! the previous power state after a power request was acknowledged.
//! Prints `PORT <n>` (UDP, 127.0.0.1; `--port 0`, the default, picks a free
//! one) once listening, answers every period
//! like the controller, and after `--duration` seconds (or when stdin is
//! closed) prints what it saw as `key: value` lines (the last set-point
//! streamed as `last_vo_pose: x,y,z,qx,qy,qz,qw`).

use std::io::{BufRead, Write};
use std::time::{Duration, Instant};

use hap_core::vp::status;
use virtuose_api::fake_peer::{FakePeer, FakePeerConfig};

fn triple(s: &str) -> Result<[f64; 3], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>().map_err(|e| format!("{s}: {e}")))
        .collect::<Result<_, _>>()?;
    match v.as_slice() {
        [a, b, c] if v.iter().all(|x| x.is_finite()) => Ok([*a, *b, *c]),
        _ => Err(format!("{s}: expected three finite numbers X,Y,Z")),
    }
}

fn main() {
    let mut cfg = FakePeerConfig {
        answer_every_period: true,
        twist_every: 4,
        ..Default::default()
    };
    let mut duration = 60.0f64;
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut i = 0;
    let bad = |m: String| -> ! {
        eprintln!("fake_controller: {m}");
        std::process::exit(2)
    };
    while i < args.len() {
        let val = args.get(i + 1).cloned().unwrap_or_default();
        match args[i].as_str() {
            "--period-us" => {
                cfg.period_us = val
                    .parse()
                    .ok()
                    .filter(|p| (100..=100_000).contains(p))
                    .unwrap_or_else(|| bad(format!("--period-us {val}: 100..100000")))
            }
            "--duration" => {
                duration = val
                    .parse()
                    .ok()
                    .filter(|d: &f64| *d > 0.0 && d.is_finite())
                    .unwrap_or_else(|| bad(format!("--duration {val}: seconds > 0")))
            }
            "--port" => {
                let port: u16 = val
                    .parse()
                    .unwrap_or_else(|_| bad(format!("--port {val}: 0..65535")));
                cfg.bind = std::net::SocketAddr::from(([127, 0, 0, 1], port));
            }
            "--center" => cfg.center = triple(&val).unwrap_or_else(|e| bad(e)),
            "--amplitude" => cfg.amplitude = triple(&val).unwrap_or_else(|e| bad(e)),
            "--buttons" => {
                let mask: u32 = val
                    .parse()
                    .ok()
                    .filter(|m| *m <= 3)
                    .unwrap_or_else(|| bad(format!("--buttons {val}: 0..3")));
                cfg.extra_status = (if mask & 1 != 0 { status::BUTTON_1 } else { 0 })
                    | (if mask & 2 != 0 { status::BUTTON_2 } else { 0 });
            }
            "--power-lag" => {
                cfg.power_lag_answers = val
                    .parse()
                    .unwrap_or_else(|_| bad(format!("--power-lag {val}: a number of answers")))
            }
            a => bad(format!("unknown argument {a}")),
        }
        i += 2;
    }
    let peer = FakePeer::start(cfg).unwrap_or_else(|e| bad(format!("cannot bind: {e}")));
    println!("PORT {}", peer.addr.port());
    let _ = std::io::stdout().flush();
    // Stop at the deadline or when stdin closes, whichever comes first.
    let (tx, rx) = std::sync::mpsc::channel::<()>();
    std::thread::spawn(move || {
        let mut line = String::new();
        let stdin = std::io::stdin();
        let mut lock = stdin.lock();
        while lock.read_line(&mut line).map(|n| n > 0).unwrap_or(false) {
            line.clear();
        }
        let _ = tx.send(());
    });
    let end = Instant::now() + Duration::from_secs_f64(duration);
    let _ = rx.recv_timeout(end.saturating_duration_since(Instant::now()));
    let s = peer.stats();
    for (k, v) in &s.frames {
        println!("frames.{k}: {v}");
    }
    println!("answers_sent: {}", s.answers_sent);
    println!("garbage: {}", s.garbage);
    println!("powered: {}", s.powered as u8);
    println!("attached: {}", s.attached as u8);
    println!(
        "command_type: {}",
        s.command_type.map(|t| t.to_string()).unwrap_or("-".into())
    );
    println!("max_vo_offset_m: {:.6}", s.max_vo_offset);
    println!("link_energy_frames: {}", s.link_energy_frames);
    println!(
        "last_vo_pose: {}",
        s.last_vo_pose.map(|v| format!("{v:.6}")).join(",")
    );
    println!("session_open: {}", s.client.is_some() as u8);
    println!(
        "last_vo_pose: {}",
        s.last_vo_pose.map(|v| format!("{v:.6}")).join(",")
    );
    println!(
        "last_handle_position: {}",
        s.last_handle_position.map(|v| format!("{v:.6}")).join(",")
    );
}
