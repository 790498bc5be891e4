//! Round trip through the bridge, v1 (`--insecure`) against v2 (key), on
//! this host (a figure for Documentation/performance.md; not a test):
//!
//!   cargo run --release -p proto_interface --example link_rtt [N]
//!
//! Mode: host loopback, no QEMU: virtuose_api → UDP → the bridge (library,
//! its two threads) → named pipes → a fake kernel thread (hap-core's
//! PROTO_IN) that answers every `vpr_stream` at once with an `answer`
//! echoing it → pipe → bridge → UDP → client. N requests, one every 200 µs,
//! each waiting for its answer; RTT = the client's VprStream → answer time.

use std::ffi::CString;
use std::fs::File;
use std::io::{Read, Write};
use std::net::SocketAddr;
use std::path::Path;
use std::time::Duration;

use hap_auth::Psk;
use hap_core::proto_in::ProtoIn;
use hap_core::protocol::{encode, expected_len, Answer, Frame, FrameHeader, MAX_FRAME_LEN};
use proto_interface::{Bridge, Config};
use virtuose_api::{Options, RttSample, VirtContext};

fn mkfifo(p: &Path) {
    let c = CString::new(p.to_str().unwrap()).unwrap();
    // SAFETY: valid NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
}

fn kernel(rin: std::path::PathBuf, rout: std::path::PathBuf) {
    let mut out = File::options().write(true).open(rout).unwrap();
    let mut f = File::open(rin).unwrap();
    let mut p = ProtoIn::new();
    let (mut acc, mut buf, mut seq) = (Vec::new(), [0u8; 4096], 0u32);
    loop {
        let n = match f.read(&mut buf) {
            Ok(0) | Err(_) => return,
            Ok(n) => n,
        };
        acc.extend_from_slice(&buf[..n]);
        while acc.len() >= 4 {
            let Some(len) = expected_len(&acc) else {
                return;
            };
            if acc.len() < len {
                break;
            }
            let fr: Vec<u8> = acc.drain(..len).collect();
            let o = p.handle(&fr, u64::from(seq), 1000);
            let mut replies: Vec<Frame> = o.reply.into_iter().collect();
            if o.vpr_updated {
                replies.push(Frame::Answer(Answer {
                    cycle: seq,
                    vpr_seq: p.vpr().seq,
                    ..Answer::default()
                }));
            }
            for r in replies {
                seq += 1;
                let h = FrameHeader {
                    control: 0,
                    session: p.session(),
                    seq,
                    timestamp_us: seq,
                };
                let mut b = [0u8; MAX_FRAME_LEN];
                let n = encode(&h, &r, &mut b);
                if out.write_all(&b[..n]).is_err() {
                    return;
                }
            }
        }
    }
}

fn run(n: usize, key: Option<Psk>) -> Vec<u32> {
    let dir =
        std::env::temp_dir().join(format!("link_rtt_{}_{}", std::process::id(), key.is_some()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let (rin, rout) = (dir.join("rtf_in"), dir.join("rtf_out"));
    mkfifo(&rin);
    mkfifo(&rout);
    let cfg = Config {
        bind: "127.0.0.1:0".parse::<SocketAddr>().unwrap(),
        rtf_in: rin.clone(),
        rtf_out: rout.clone(),
        stats_file: None,
        session_timeout: Duration::from_secs(3),
        stats_interval: Duration::from_secs(1),
        key: key.clone(),
        refusal_budget: 1000,
        handshake_budget: 500,
        handshake_budget_per_ip: 100,
        rt_priority: None,
        rt_budget_percent: 25,
    };
    let mut bridge = Bridge::start(cfg, || {}).unwrap();
    std::thread::spawn(move || kernel(rin, rout));
    let addr = format!("127.0.0.1#{}", bridge.local_addr.port());
    let mut vc = VirtContext::open_with(
        &addr,
        Options {
            key: key.clone(),
            ..Options::default()
        },
    )
    .unwrap();
    assert_eq!(vc.authenticated(), key.is_some());
    vc.record_rtt(true);
    let pose = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0];
    for _ in 0..n {
        vc.set_position(&pose).unwrap();
        vc.wait_answer(Duration::from_millis(50));
        std::thread::sleep(Duration::from_micros(200));
    }
    let mut s: Vec<RttSample> = Vec::new();
    vc.drain_rtt(&mut s);
    let _ = vc.close();
    bridge.stop();
    let _ = std::fs::remove_dir_all(&dir);
    let mut v: Vec<u32> = s.iter().map(|x| x.rtt_us).collect();
    v.sort_unstable();
    v
}

fn pct(v: &[u32], p: f64) -> u32 {
    v.get(((v.len() as f64 - 1.0) * p).round() as usize)
        .copied()
        .unwrap_or(0)
}

fn main() {
    let n: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(5000);
    println!("{n} requests per protocol, host loopback, fake kernel answering at once");
    for (name, key) in [
        ("v1 (--insecure)", None),
        ("v2 (key)       ", Some(Psk::generate().unwrap())),
    ] {
        let v = run(n, key);
        let mean = v.iter().map(|x| f64::from(*x)).sum::<f64>() / v.len().max(1) as f64;
        println!(
            "{name}: samples {:6}  RTT us min {:4}  p50 {:4}  p99 {:5}  max {:6}  mean {:7.1}",
            v.len(),
            pct(&v, 0.0),
            pct(&v, 0.5),
            pct(&v, 0.99),
            pct(&v, 1.0),
            mean
        );
    }
}
