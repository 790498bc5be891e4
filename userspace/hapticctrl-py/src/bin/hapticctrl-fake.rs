//! The fake controller behind the bridge's authentication gate, as a
//! process (for the Python package's tests and examples):
//!
//!   hapticctrl-fake (--key FILE | --insecure) [--port N] [--period-us N]
//!                   [--per-request] [--center X,Y,Z] [--amplitude X,Y,Z]
//!                   [--freq HZ] [--stiffness N/m] [--damping N.s/m] [--powered]
//!
//! Prints `PORT <n>` (UDP, 127.0.0.1) once listening. Reads commands on
//! stdin, one a line: `cut` (drop every datagram both ways), `restore`,
//! `stats` (print the counters now); at the end of stdin prints the
//! counters as `key: value` lines and exits.

use std::io::{BufRead, Write};
use std::net::SocketAddr;

use hap_auth::Psk;
use hapticctrl_py::fake::AuthFake;
use virtuose_api::fake_peer::FakePeerConfig;

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

fn number(flag: &str, s: &str, lo: f64, hi: f64) -> Result<f64, String> {
    s.parse::<f64>()
        .ok()
        .filter(|v| (lo..=hi).contains(v))
        .ok_or_else(|| format!("{flag} {s}: a number in [{lo}, {hi}]"))
}

const USAGE: &str = "usage: hapticctrl-fake (--key FILE | --insecure) [--port N] [--period-us N] [--per-request] [--center X,Y,Z] [--amplitude X,Y,Z] [--freq HZ] [--stiffness N/m] [--damping N.s/m] [--powered]";

#[derive(Debug)]
struct Args {
    port: u16,
    key: Option<Psk>,
    cfg: FakePeerConfig,
}

fn parse(args: &[String]) -> Result<Args, String> {
    let mut cfg = FakePeerConfig {
        answer_every_period: true,
        twist_every: 1,
        ..Default::default()
    };
    let (mut port, mut key, mut insecure) = (0u16, None, false);
    let mut i = 0;
    while i < args.len() {
        let flag = args[i].as_str();
        let val = || -> Result<&str, String> {
            args.get(i + 1)
                .map(String::as_str)
                .ok_or_else(|| format!("{flag} needs a value"))
        };
        let mut takes_value = true;
        match flag {
            "--port" => {
                port = val()?
                    .parse()
                    .map_err(|_| format!("--port {}: 0..65535", val().unwrap_or("")))?
            }
            "--key" => {
                let path = val()?;
                key = Some(
                    Psk::load(std::path::Path::new(path))
                        .map_err(|e| format!("key {path}: {e}"))?,
                );
            }
            "--period-us" => cfg.period_us = number(flag, val()?, 100.0, 100_000.0)? as u32,
            "--center" => cfg.center = triple(val()?)?,
            "--amplitude" => cfg.amplitude = triple(val()?)?,
            "--freq" => cfg.freq_hz = number(flag, val()?, 0.0, 100.0)?,
            "--stiffness" => cfg.stiffness = number(flag, val()?, 0.0, 1e5)?,
            "--damping" => cfg.damping = number(flag, val()?, 0.0, 1e3)?,
            "--insecure" => {
                insecure = true;
                takes_value = false;
            }
            "--per-request" => {
                cfg.answer_every_period = false;
                takes_value = false;
            }
            "--powered" => {
                cfg.powered = true;
                takes_value = false;
            }
            "-h" | "--help" => return Err(USAGE.into()),
            a => return Err(format!("unknown argument {a}\n{USAGE}")),
        }
        i += if takes_value { 2 } else { 1 };
    }
    match (key.is_some(), insecure) {
        (true, true) => Err("--key and --insecure exclude each other".into()),
        (false, false) => Err("--key FILE (protocol v2) or --insecure (v1) is required".into()),
        _ => Ok(Args { port, key, cfg }),
    }
}

fn print_stats(f: &AuthFake) {
    let r = f.relay_stats();
    let p = f.peer_stats();
    let mut out = String::new();
    for (k, v) in &p.frames {
        out += &format!("frames.{k}: {v}\n");
    }
    for (k, v) in &r.refused {
        out += &format!("refused.{k}: {v}\n");
    }
    out += &format!(
        "handshakes: {}\nforwarded: {}\nreplied: {}\ncut_dropped: {}\nanswers_sent: {}\n",
        r.handshakes, r.forwarded, r.replied, r.cut_dropped, p.answers_sent
    );
    out += &format!(
        "powered: {}\nattached: {}\nsession_open: {}\n",
        p.powered as u8,
        p.attached as u8,
        p.client.is_some() as u8
    );
    out += &format!(
        "command_type: {}\nlink_energy_frames: {}\n",
        p.command_type.map_or("-".into(), |t| t.to_string()),
        p.link_energy_frames
    );
    let v = p.last_vo_pose;
    out += &format!(
        "last_vo_pose: {:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6}\nEND\n",
        v[0], v[1], v[2], v[3], v[4], v[5], v[6]
    );
    let mut so = std::io::stdout().lock();
    let _ = so.write_all(out.as_bytes());
    let _ = so.flush();
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let a = parse(&args).unwrap_or_else(|e| {
        eprintln!("hapticctrl-fake: {e}");
        std::process::exit(2)
    });
    let bind = SocketAddr::from(([127, 0, 0, 1], a.port));
    let mut f = AuthFake::start(bind, a.key, a.cfg).unwrap_or_else(|e| {
        eprintln!("hapticctrl-fake: cannot bind 127.0.0.1:{}: {e}", a.port);
        std::process::exit(1)
    });
    println!("PORT {}", f.addr.port());
    let _ = std::io::stdout().flush();
    for line in std::io::stdin().lock().lines() {
        let Ok(line) = line else { break };
        match line.trim() {
            "cut" => f.set_link(false),
            "restore" => f.set_link(true),
            "stats" => print_stats(&f),
            "" => {}
            other => eprintln!("hapticctrl-fake: unknown command '{other}' (cut, restore, stats)"),
        }
    }
    print_stats(&f);
    f.stop();
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(a: &[&str]) -> Result<Args, String> {
        parse(&a.iter().map(|s| s.to_string()).collect::<Vec<_>>())
    }

    #[test]
    fn bad_command_lines_are_refused_with_a_reason() {
        assert!(args(&[]).unwrap_err().contains("--key FILE"));
        assert!(args(&["--insecure", "--key", "/nonexistent"]).is_err());
        assert!(args(&["--key", "/nonexistent/hap.key"])
            .unwrap_err()
            .contains("/nonexistent/hap.key"));
        assert!(args(&["--insecure", "--port"])
            .unwrap_err()
            .contains("needs a value"));
        assert!(args(&["--insecure", "--port", "70000"]).is_err());
        assert!(args(&["--insecure", "--period-us", "10"]).is_err());
        assert!(args(&["--insecure", "--center", "1,2"]).is_err());
        assert!(args(&["--insecure", "--amplitude", "1,nan,2"]).is_err());
        assert!(args(&["--insecure", "--bogus"])
            .unwrap_err()
            .contains("usage"));
        assert!(args(&["--help"]).unwrap_err().starts_with("usage"));
    }

    #[test]
    fn a_good_command_line() {
        let a = args(&[
            "--insecure",
            "--port",
            "47551",
            "--period-us",
            "500",
            "--per-request",
            "--center",
            "0.1,0,0",
            "--amplitude",
            "0,0,0.06",
            "--freq",
            "0.5",
            "--powered",
        ])
        .unwrap();
        assert_eq!(a.port, 47551);
        assert!(a.key.is_none());
        assert_eq!(a.cfg.period_us, 500);
        assert!(!a.cfg.answer_every_period);
        assert!(a.cfg.powered);
        assert_eq!(a.cfg.center, [0.1, 0.0, 0.0]);
        assert_eq!(a.cfg.amplitude, [0.0, 0.0, 0.06]);
    }
}
