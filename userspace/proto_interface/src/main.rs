//! proto_interface: UDP <-> hapticctrl kernel module bridge.
//! See `lib.rs` and Documentation/userguide.md.

use std::net::{IpAddr, SocketAddr};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use clap::Parser;
use proto_interface::{write_stats_file, Bridge, Config};
use signal_hook::consts::{SIGINT, SIGTERM, SIGUSR1};
use signal_hook::iterator::Signals;

/// Bridge between the client application (UDP) and the hapticctrl kernel
/// module's devices (spec D9rb.2 §3.3.1.1 SERVER and §3.3.1.4 CLIENT).
#[derive(Parser, Debug)]
#[command(name = "proto_interface", version)]
struct Args {
    /// Address to bind the UDP socket to.
    #[arg(long, default_value = "0.0.0.0")]
    bind: IpAddr,
    /// UDP port to listen on.
    #[arg(long, default_value_t = 5000)]
    port: u16,
    /// Kernel input device (one whole frame per write).
    #[arg(long, default_value = "/dev/hap_rtf_in")]
    rtf_in: PathBuf,
    /// Kernel output device (one whole answer frame per read).
    #[arg(long, default_value = "/dev/hap_rtf_out")]
    rtf_out: PathBuf,
    /// Counters file, rewritten every second and at exit (`hapctl stats` reads it).
    #[arg(long, default_value = "/run/proto_interface.stats")]
    stats_file: PathBuf,
    /// Do not write a counters file.
    #[arg(long)]
    no_stats_file: bool,
    /// A session whose client sends nothing for this long is closed, in ms.
    #[arg(long, default_value_t = 3000, value_parser = clap::value_parser!(u64).range(1..=3_600_000))]
    session_timeout_ms: u64,
    /// Print the bound address on stdout once listening (for scripts and tests).
    #[arg(long)]
    print_addr: bool,
    /// Run the bridge's threads under SCHED_FIFO at this priority (1..=99;
    /// below SERVO's 80). Default: SCHED_OTHER. Fails if not permitted.
    #[arg(long, value_parser = clap::value_parser!(i32).range(1..=99))]
    rt_priority: Option<i32>,
    /// Pre-shared key file (one line: 64 lowercase hex digits; mode 0600;
    /// weak keys refused; `hapctl keygen`):
    /// only clients holding it can open a session (protocol v2).
    #[arg(long, value_name = "FILE", required_unless_present = "insecure")]
    key: Option<PathBuf>,
    /// Accept unauthenticated protocol v1 from anyone who can reach the port.
    /// Logged loudly and shown as `insecure: 1` in the counters.
    #[arg(long, conflicts_with = "key")]
    insecure: bool,
    /// After reading the key and setting the priority, run as this user
    /// (`USER[:GROUP]`, names or numbers), keeping only CAP_SYS_NICE when
    /// --rt-priority is given. The group must own the two FIFO devices.
    #[arg(long, value_name = "USER[:GROUP]")]
    user: Option<String>,
    /// Refused datagrams per second a source IP (all its ports together)
    /// may send before its datagrams are dropped unexamined (0: no limit).
    /// The session's client address (IP and port) is never dropped.
    #[arg(long, default_value_t = 1000)]
    refusal_budget: u32,
    /// Cookies per second the bridge sends (each answers a verified
    /// `open_session`: nothing without the key spends it), from all sources
    /// together, bursts of twice that (0: no limit); beyond, verified
    /// `open_session`s are dropped (`rejected_handshake_budget`), but for
    /// those from IPs that answered a cookie in the last 2 minutes.
    #[arg(long, default_value_t = 500)]
    handshake_budget: u32,
    /// Cookies per second and source IP (all its ports together), bursts
    /// of twice that (0: no limit); beyond, `rejected_handshake_ip_budget`.
    #[arg(long, default_value_t = 100)]
    handshake_budget_per_ip: u32,
    /// With --rt-priority: the share of one CPU, in percent, the receiving
    /// thread may use at that priority over a 100 ms window; a window above
    /// it runs the thread as SCHED_OTHER until a window within it (a flood
    /// of forged datagrams, each verified, must not hold the CPU above the
    /// kernel's SCHED_OTHER tasks). 100: never demoted.
    #[arg(long, default_value_t = 25, value_parser = clap::value_parser!(u32).range(1..=100))]
    rt_budget: u32,
}

fn main() -> ExitCode {
    let args = Args::parse();
    let cfg = Config {
        bind: SocketAddr::new(args.bind, args.port),
        rtf_in: args.rtf_in,
        rtf_out: args.rtf_out,
        stats_file: if args.no_stats_file {
            None
        } else {
            Some(args.stats_file)
        },
        session_timeout: Duration::from_millis(args.session_timeout_ms),
        stats_interval: Duration::from_secs(1),
        key: None,
        refusal_budget: args.refusal_budget,
        handshake_budget: args.handshake_budget,
        handshake_budget_per_ip: args.handshake_budget_per_ip,
        rt_priority: args.rt_priority,
        rt_budget_percent: args.rt_budget,
    };
    let mut cfg = cfg;
    match &args.key {
        Some(path) => match hap_auth::Psk::load(path) {
            Ok(k) => cfg.key = Some(k),
            Err(e) => {
                eprintln!("proto_interface: key {}: {e}", path.display());
                return ExitCode::FAILURE;
            }
        },
        None => eprintln!(
            "proto_interface: WARNING: --insecure: unauthenticated protocol v1, any host \
             that can reach the port can steer the arm"
        ),
    }
    if cfg.key.is_some() {
        if let Err(e) = hap_auth::fresh_nonce() {
            eprintln!("proto_interface: no random numbers (/dev/urandom): {e}");
            return ExitCode::FAILURE;
        }
    }

    if let Some(p) = args.rt_priority {
        // Before any thread is started: they inherit the policy.
        if let Err(e) = proto_interface::set_fifo_priority(p) {
            eprintln!("proto_interface: cannot run at SCHED_FIFO {p}: {e}");
            return ExitCode::FAILURE;
        }
    }
    if let Some(spec) = &args.user {
        let passwd = std::fs::read_to_string("/etc/passwd").unwrap_or_default();
        let group = std::fs::read_to_string("/etc/group").unwrap_or_default();
        let r = proto_interface::privdrop::resolve(spec, &passwd, &group).and_then(|ids| {
            proto_interface::privdrop::drop_to(ids, args.rt_priority.is_some()).map(|()| ids)
        });
        match r {
            Ok(ids) => eprintln!(
                "proto_interface: running as uid {} gid {}, capabilities {:#x}",
                ids.uid,
                ids.gid,
                proto_interface::privdrop::effective_caps().unwrap_or(0)
            ),
            Err(e) => {
                eprintln!("proto_interface: cannot run as {spec}: {e}");
                return ExitCode::FAILURE;
            }
        }
    }
    let mut signals = match Signals::new([SIGTERM, SIGINT, SIGUSR1]) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("proto_interface: cannot install signal handlers: {e}");
            return ExitCode::FAILURE;
        }
    };
    let handle = signals.handle();
    let stats_file = cfg.stats_file.clone();
    let mut bridge = match Bridge::start(cfg.clone(), move || handle.close()) {
        Ok(b) => b,
        Err(e) => {
            eprintln!("proto_interface: cannot listen on {}: {e}", cfg.bind);
            return ExitCode::FAILURE;
        }
    };
    if args.print_addr {
        println!("listening on {}", bridge.local_addr);
    }
    eprintln!(
        "proto_interface: listening on udp {} (udp -> {}, {} -> client), {}",
        bridge.local_addr,
        cfg.rtf_in.display(),
        cfg.rtf_out.display(),
        if cfg.key.is_some() {
            "authenticated (protocol v2)"
        } else {
            "INSECURE (unauthenticated protocol v1)"
        }
    );

    let mut why = String::from("device gone");
    for sig in signals.forever() {
        match sig {
            SIGUSR1 => {
                eprint!("{}", bridge.shared.render());
                if let Some(p) = &stats_file {
                    let _ = write_stats_file(p, &bridge.shared.render());
                }
            }
            SIGTERM => {
                why = "SIGTERM".into();
                break;
            }
            _ => {
                why = "SIGINT".into();
                break;
            }
        }
    }
    bridge.stop();
    let fatal = bridge.shared.fatal.lock().ok().and_then(|f| f.clone());
    if let Some(f) = &fatal {
        why = f.clone();
    }
    let text = bridge.shared.render();
    if let Some(p) = &stats_file {
        let _ = write_stats_file(p, &text);
    }
    eprintln!("proto_interface: exiting ({why})");
    eprint!("{text}");
    ExitCode::SUCCESS
}
