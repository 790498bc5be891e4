//! The demo's web page: a plain std TcpListener HTTP/1.0 server.
//!
//! - `/`          the page (web/index.html, canvas 3D renderer, no CDN)
//! - `/app.js`    its script
//! - `/state.json?since=T`  the current sample + plot history as JSON; a
//!   long poll: answers once the demo time passed T + 40 ms (or after 500 ms).
//! - `/report/NAME` the run's report files (RESULTS/plots: summary.html and
//!   its figures) once `hapctl analyze` has written them; `state.json`'s
//!   `report` says when summary.html is there.

use std::fmt::Write as _;
use std::io::{BufRead, BufReader, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::{Sample, Shared};

const INDEX: &str = include_str!("../web/index.html");
const APP: &str = include_str!("../web/app.js");
const MAX_CONNECTIONS: usize = 32;

pub fn start(addr: SocketAddr, shared: Arc<Shared>) -> std::io::Result<String> {
    let l = TcpListener::bind(addr)?;
    let url = format!("http://{}/", l.local_addr()?);
    let active = Arc::new(AtomicUsize::new(0));
    std::thread::Builder::new()
        .name("web".into())
        .spawn(move || {
            for s in l.incoming().flatten() {
                if active.load(Ordering::SeqCst) >= MAX_CONNECTIONS {
                    continue; // dropped: closes the connection
                }
                active.fetch_add(1, Ordering::SeqCst);
                let (sh, act) = (shared.clone(), active.clone());
                let r = std::thread::Builder::new()
                    .name("web-conn".into())
                    .spawn(move || {
                        let _ = serve(s, &sh);
                        act.fetch_sub(1, Ordering::SeqCst);
                    });
                if r.is_err() {
                    active.fetch_sub(1, Ordering::SeqCst);
                }
            }
        })?;
    Ok(url)
}

fn respond(s: &mut TcpStream, status: &str, ctype: &str, body: &str) -> std::io::Result<()> {
    write!(
        s,
        "HTTP/1.0 {status}\r\nContent-Type: {ctype}\r\nContent-Length: {}\r\nCache-Control: no-store\r\nConnection: close\r\n\r\n{body}",
        body.len()
    )?;
    s.flush()
}

fn serve(mut s: TcpStream, shared: &Shared) -> std::io::Result<()> {
    s.set_read_timeout(Some(Duration::from_secs(5)))?;
    let mut line = String::new();
    let mut r = BufReader::new(s.try_clone()?);
    r.read_line(&mut line)?;
    // Skip the headers (bounded).
    let mut hdr = String::new();
    for _ in 0..100 {
        hdr.clear();
        if r.read_line(&mut hdr)? == 0 || hdr == "\r\n" || hdr == "\n" {
            break;
        }
    }
    let mut parts = line.split_whitespace();
    let (method, target) = (parts.next().unwrap_or(""), parts.next().unwrap_or(""));
    if method != "GET" {
        return respond(&mut s, "405 Method Not Allowed", "text/plain", "GET only\n");
    }
    let (path, query) = target.split_once('?').unwrap_or((target, ""));
    match path {
        "/" | "/index.html" => respond(&mut s, "200 OK", "text/html; charset=utf-8", INDEX),
        "/app.js" => respond(&mut s, "200 OK", "text/javascript; charset=utf-8", APP),
        "/state.json" => {
            let since: f64 = query
                .split('&')
                .find_map(|kv| kv.strip_prefix("since="))
                .and_then(|v| v.parse().ok())
                .filter(|v: &f64| v.is_finite())
                .unwrap_or(-1.0);
            let deadline = Instant::now() + Duration::from_millis(500);
            loop {
                let t = shared.now.lock().map(|n| n.t).unwrap_or(0.0);
                if t >= since + 0.04
                    || Instant::now() >= deadline
                    || shared.done.load(Ordering::SeqCst)
                {
                    break;
                }
                std::thread::sleep(Duration::from_millis(5));
            }
            let body = state_json(shared);
            respond(&mut s, "200 OK", "application/json", &body)
        }
        _ if path.starts_with("/report/") => {
            serve_report(&mut s, shared, &path["/report/".len()..])
        }
        _ => respond(&mut s, "404 Not Found", "text/plain", "not found\n"),
    }
}

/// A file of the report directory: a plain name (letters, digits, `_`,
/// `-`, `.`, not starting with `.`) with a known extension, nothing else.
fn serve_report(s: &mut TcpStream, shared: &Shared, name: &str) -> std::io::Result<()> {
    let ctype = match name.rsplit_once('.').map(|(_, e)| e) {
        Some("html") => "text/html; charset=utf-8",
        Some("png") => "image/png",
        Some("svg") => "image/svg+xml",
        Some("txt") | Some("csv") => "text/plain; charset=utf-8",
        _ => "",
    };
    let plain = !name.starts_with('.')
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'));
    let body = match (&shared.report_dir, plain && !ctype.is_empty()) {
        (Some(dir), true) => std::fs::read(dir.join(name)).ok(),
        _ => None,
    };
    let Some(body) = body else {
        return respond(
            s,
            "404 Not Found",
            "text/plain",
            "no such report file (yet)\n",
        );
    };
    write!(
        s,
        "HTTP/1.0 200 OK\r\nContent-Type: {ctype}\r\nContent-Length: {}\r\nCache-Control: no-store\r\nConnection: close\r\n\r\n",
        body.len()
    )?;
    s.write_all(&body)?;
    s.flush()
}

fn arr(v: &[f64; 3]) -> String {
    format!("[{:.5},{:.5},{:.5}]", v[0], v[1], v[2])
}

fn num(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.5}")
    } else {
        "0".into()
    }
}

fn sample_json(s: &Sample) -> String {
    format!(
        "{{\"t\":{},\"handle\":{},\"coupled\":{},\"free\":{},\"force\":{},\"contact\":{},\"loopHz\":{},\"rateHz\":{},\"loss\":{},\"rttMs\":{},\"answers\":{},\"lost\":{},\"power\":{}}}",
        num(s.t),
        arr(&s.handle),
        arr(&s.coupled),
        arr(&s.free),
        arr(&s.force),
        arr(&s.contact),
        num(s.loop_hz),
        num(s.rate_hz),
        num(s.loss),
        num(s.rtt_ms),
        s.answers,
        s.lost,
        s.power
    )
}

/// The JSON the page polls.
pub fn state_json(shared: &Shared) -> String {
    let now = shared.now.lock().map(|n| n.clone()).unwrap_or_default();
    let mut hist = String::from("[");
    if let Ok(h) = shared.history.lock() {
        for (i, s) in h.iter().enumerate() {
            if i > 0 {
                hist.push(',');
            }
            let _ = write!(
                hist,
                "[{},{},{},{},{}]",
                num(s.t),
                num(s.force[0]),
                num(s.force[1]),
                num(s.force[2]),
                num(s.loop_hz)
            );
        }
    }
    hist.push(']');
    let w = &shared.world;
    let server: String = shared
        .server
        .chars()
        .filter(|c| c.is_ascii_graphic() && *c != '"' && *c != '\\')
        .collect();
    format!(
        "{{\"server\":\"{server}\",\"done\":{},\"report\":{},\"world\":{{\"radiusA\":{},\"radiusB\":{},\"floorZ\":{},\"halfWidth\":{}}},\"now\":{},\"history\":{hist}}}",
        shared.done.load(Ordering::SeqCst),
        shared
            .report_dir
            .as_ref()
            .is_some_and(|d| d.join("summary.html").is_file()),
        num(w.a.radius),
        num(w.b.radius),
        num(w.floor_z),
        num(w.half_width),
        sample_json(&now)
    )
}
