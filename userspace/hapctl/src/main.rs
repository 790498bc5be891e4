//! hapctl: control tool for hapticctrl (runs in the guest next to the
//! module; `analyze` also runs on the host). See Documentation/userguide.md.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::{Parser, Subcommand, ValueEnum};

#[cfg(feature = "analyze")]
mod analyze;
mod kv;
#[cfg(feature = "analyze")]
mod plot;
#[cfg(feature = "analyze")]
mod plot_link;
mod simlog;

/// Control the hapticctrl haptic controller.
#[derive(Parser, Debug)]
#[command(name = "hapctl", version, propagate_version = true)]
struct Cli {
    /// Directory holding the module's devices (hap_power, hap_stats, ...).
    #[arg(long, global = true, env = "HAPCTL_DEV_DIR", default_value = "/dev")]
    dev_dir: PathBuf,
    /// The arm whose devices to use (0: /dev/hap_*, 1: /dev/hap1_* of a
    /// controller loaded with arms=2).
    #[arg(long, global = true, default_value_t = 0, value_parser = clap::value_parser!(u8).range(0..=1))]
    arm: u8,
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand, Debug)]
enum Cmd {
    /// Start proto_interface then insert the module (runs the launch script).
    Start {
        /// Servo period in µs (module parameter period_us, 100..=10000).
        #[arg(long, value_parser = clap::value_parser!(u32).range(
            i64::from(hap_core::clock::PERIOD_MIN_US)..=i64::from(hap_core::clock::PERIOD_MAX_US)
        ))]
        period_us: Option<u32>,
        /// Arms the controller serves (module parameter arms; 2: arm 1's
        /// devices are /dev/hap1_*, and the launch script starts a bridge
        /// for each arm).
        #[arg(long, value_parser = clap::value_parser!(u8).range(1..=2))]
        arms: Option<u8>,
        /// The launch script (default: $HAPCTL_SCRIPT, else hapticctrl.sh next to hapctl, else from PATH).
        #[arg(long)]
        script: Option<PathBuf>,
    },
    /// Fail-safe stop, stop proto_interface, remove the module.
    Stop {
        #[arg(long)]
        script: Option<PathBuf>,
    },
    /// Write a new pre-shared key (32 random bytes as 64 hex digits) to
    /// FILE with mode 0600, for the bridge (`proto_interface --key FILE`)
    /// and its client (`virtOpen("host#port?key=FILE")`). Refuses to
    /// overwrite an existing file.
    Keygen { file: PathBuf },
    /// Simulated arm supply power request.
    Power {
        #[arg(value_enum)]
        state: OnOff,
    },
    /// Show the module's statistics and proto_interface's counters.
    Stats {
        /// proto_interface's counters file.
        #[arg(long, default_value = "/run/proto_interface.stats")]
        proto_stats: PathBuf,
        /// Print the raw `key: value` text instead of a table.
        #[arg(long)]
        raw: bool,
    },
    /// Simulator commands.
    Sim {
        #[command(subcommand)]
        cmd: SimCmd,
    },
    /// Record the simulator's position log (/dev/hap_simlog) for the whole
    /// session: drains it until the module's fail-safe closes it (or
    /// --cycles), then prints how many records the ring dropped.
    Log {
        /// Output file (binary records, as read); default stdout as CSV.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Stop after this many records (default: until end of file).
        #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
        cycles: Option<u64>,
        /// Also write the end summary (records, dropped_records, ...) there.
        #[arg(long)]
        summary: Option<PathBuf>,
    },
    /// Off-line analysis of a whole run: figures (PNG and SVG), events,
    /// analysis.txt and a one-page report (summary.html).
    #[cfg(feature = "analyze")]
    Analyze {
        /// A log captured by `hapctl log --out`.
        log: PathBuf,
        /// Output directory (created).
        #[arg(long)]
        out: PathBuf,
        /// A dump of /dev/hap_stats (`cat /dev/hap_stats > FILE`): the
        /// period and the module's counters for the report.
        #[arg(long)]
        stats: Option<PathBuf>,
        /// A dump of /dev/hap_hist: the latency histogram.
        #[arg(long)]
        hist: Option<PathBuf>,
        /// `key: value` files shown in the report as they are (the client's
        /// summary.txt, `hapctl log --summary`); repeatable.
        #[arg(long)]
        summary: Vec<PathBuf>,
    },
    /// Charts (PNG and SVG) from CSV files, for the benchmark scripts.
    #[cfg(feature = "analyze")]
    Plot {
        /// hist: `value,count` buckets drawn as steps; lines: `x,y` series.
        #[arg(value_enum)]
        kind: PlotKind,
        /// Output path without extension (writes OUT.png and OUT.svg).
        #[arg(long)]
        out: PathBuf,
        #[arg(long, default_value = "")]
        title: String,
        #[arg(long, default_value = "")]
        x_label: String,
        #[arg(long, default_value = "")]
        y_label: String,
        /// Logarithmic y axis.
        #[arg(long)]
        log_y: bool,
        /// Right end of the x axis (default: the data's).
        #[arg(long)]
        x_max: Option<f64>,
        /// One or more NAME=FILE.csv (the legend's name, the data).
        #[arg(required = true)]
        series: Vec<String>,
    },
    /// Link benchmark plots (scripts/bench-link.sh): rtt_hist and rate,
    /// SVG and PNG, from a client results directory.
    #[cfg(feature = "analyze")]
    PlotLink {
        /// Directory holding rtt_hist.csv and rate.csv.
        #[arg(long)]
        dir: PathBuf,
        /// Output directory (created).
        #[arg(long)]
        out: PathBuf,
        /// Appended to the plot titles (e.g. the mode).
        #[arg(long, default_value = "")]
        title: String,
    },
}

#[cfg(feature = "analyze")]
#[derive(Clone, Copy, Debug, ValueEnum)]
enum PlotKind {
    Hist,
    Lines,
}

#[derive(Subcommand, Debug)]
enum SimCmd {
    /// Validate an effort sequence file, then load it into the simulator.
    Load { file: PathBuf },
    /// Apply a constant live effort: fx fy fz (N) tx ty tz (N·m).
    Live {
        #[arg(num_args = 6, allow_negative_numbers = true)]
        wrench: Vec<f64>,
    },
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum OnOff {
    On,
    Off,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("hapctl: error: {e}");
            ExitCode::FAILURE
        }
    }
}

/// Arm `arm`'s device `name` (`hap_power`...) in `cli_dir`: arm 0's keep
/// their name, arm 1's are `hap1_*`.
fn dev(cli_dir: &Path, arm: u8, name: &str) -> PathBuf {
    match (arm, name.strip_prefix("hap_")) {
        (1, Some(rest)) => cli_dir.join(format!("hap1_{rest}")),
        _ => cli_dir.join(name),
    }
}

fn write_dev(path: &Path, data: &[u8]) -> Result<(), String> {
    use std::io::Write;
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .open(path)
        .map_err(|e| format!("{}: {e} (is the module loaded?)", path.display()))?;
    f.write_all(data)
        .map_err(|e| format!("{}: write: {e}", path.display()))
}

fn find_script(explicit: Option<PathBuf>) -> Result<PathBuf, String> {
    if let Some(p) = explicit {
        return Ok(p);
    }
    if let Ok(p) = std::env::var("HAPCTL_SCRIPT") {
        return Ok(PathBuf::from(p));
    }
    if let Ok(exe) = std::env::current_exe() {
        if let Some(dir) = exe.parent() {
            let p = dir.join("hapticctrl.sh");
            if p.exists() {
                return Ok(p);
            }
        }
    }
    if let Some(path) = std::env::var_os("PATH") {
        for d in std::env::split_paths(&path) {
            let p = d.join("hapticctrl.sh");
            if p.exists() {
                return Ok(p);
            }
        }
    }
    Err("cannot find the launch script hapticctrl.sh (use --script or HAPCTL_SCRIPT)".into())
}

fn run_script(script: Option<PathBuf>, args: &[String]) -> Result<(), String> {
    let script = find_script(script)?;
    let st = std::process::Command::new("sh")
        .arg(&script)
        .args(args)
        .status()
        .map_err(|e| format!("{}: {e}", script.display()))?;
    if st.success() {
        Ok(())
    } else {
        Err(format!(
            "{} {} failed ({st})",
            script.display(),
            args.join(" ")
        ))
    }
}

fn run(cli: Cli) -> Result<(), String> {
    let d = cli.dev_dir.as_path();
    let arm = cli.arm;
    let dev = |d: &Path, name: &str| dev(d, arm, name);
    match cli.cmd {
        Cmd::Start {
            period_us,
            arms,
            script,
        } => {
            let mut args = vec!["start".to_string()];
            if let Some(p) = period_us {
                args.push("--period-us".into());
                args.push(p.to_string());
            }
            if let Some(n) = arms {
                args.push(format!("arms={n}"));
            }
            run_script(script, &args)
        }
        Cmd::Stop { script } => run_script(script, &["stop".to_string()]),
        Cmd::Keygen { file } => {
            let k = hap_auth::Psk::generate().map_err(|e| format!("/dev/urandom: {e}"))?;
            k.write_new(&file)
                .map_err(|e| format!("{}: {e}", file.display()))?;
            println!("key written to {} (mode 0600)", file.display());
            Ok(())
        }
        Cmd::Power { state } => {
            let v: &[u8] = match state {
                OnOff::On => b"1",
                OnOff::Off => b"0",
            };
            write_dev(&dev(d, "hap_power"), v)?;
            println!(
                "power {}",
                if matches!(state, OnOff::On) {
                    "on requested"
                } else {
                    "off requested"
                }
            );
            Ok(())
        }
        Cmd::Stats { proto_stats, raw } => stats(&dev(d, "hap_stats"), &proto_stats, raw),
        Cmd::Sim { cmd } => match cmd {
            SimCmd::Load { file } => sim_load(&dev(d, "hap_effort"), &file),
            SimCmd::Live { wrench } => {
                let line = simlog::live_line(&wrench)?;
                write_dev(&dev(d, "hap_effort"), line.as_bytes())?;
                print!("{line}");
                Ok(())
            }
        },
        Cmd::Log {
            out,
            cycles,
            summary,
        } => simlog::capture(
            &dev(d, "hap_simlog"),
            out.as_deref(),
            cycles,
            &dev(d, "hap_stats"),
            summary.as_deref(),
        ),
        #[cfg(feature = "analyze")]
        Cmd::Analyze {
            log,
            out,
            stats,
            hist,
            summary,
        } => analyze::run(
            &log,
            &out,
            &analyze::Inputs {
                stats: stats.as_deref(),
                hist: hist.as_deref(),
                summaries: &summary,
            },
        ),
        #[cfg(feature = "analyze")]
        Cmd::Plot {
            kind,
            out,
            title,
            x_label,
            y_label,
            log_y,
            x_max,
            series,
        } => {
            let series = series
                .iter()
                .map(|a| plot::load_series(a))
                .collect::<Result<Vec<_>, _>>()?;
            let spec = plot::Spec {
                kind: match kind {
                    PlotKind::Hist => plot::Kind::Hist,
                    PlotKind::Lines => plot::Kind::Lines,
                },
                title: &title,
                x_label: &x_label,
                y_label: &y_label,
                log_y,
                x_max,
                series: &series,
            };
            for f in plot::run(&out, &spec)? {
                println!("{}", f.display());
            }
            Ok(())
        }
        #[cfg(feature = "analyze")]
        Cmd::PlotLink { dir, out, title } => plot_link::run(&dir, &out, &title),
    }
}

fn stats(module: &Path, proto: &Path, raw: bool) -> Result<(), String> {
    let mut any = false;
    match std::fs::read_to_string(module) {
        Ok(text) => {
            any = true;
            println!("== module ({}) ==", module.display());
            if raw {
                print!("{text}");
            } else {
                print!("{}", kv::table(&kv::parse(&text)));
            }
        }
        Err(e) => eprintln!("hapctl: {}: {e} (is the module loaded?)", module.display()),
    }
    match std::fs::read_to_string(proto) {
        Ok(text) => {
            any = true;
            println!("== proto_interface ({}) ==", proto.display());
            if raw {
                print!("{text}");
            } else {
                print!("{}", kv::table(&kv::parse(&text)));
            }
        }
        Err(e) => eprintln!(
            "hapctl: {}: {e} (is proto_interface running?)",
            proto.display()
        ),
    }
    if any {
        Ok(())
    } else {
        Err("no statistics available".into())
    }
}

fn sim_load(effort_dev: &Path, file: &Path) -> Result<(), String> {
    let text = std::fs::read_to_string(file).map_err(|e| format!("{}: {e}", file.display()))?;
    let summary = simlog::validate_effort(&text).map_err(|e| format!("{}: {e}", file.display()))?;
    write_dev(effort_dev, text.as_bytes())?;
    println!("loaded {} ({summary})", file.display());
    Ok(())
}
