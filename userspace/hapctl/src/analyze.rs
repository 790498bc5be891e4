//! `hapctl analyze`: the spec's "off-line result analysis" (§3.6) as PNG and
//! SVG plots (plotters, bitmap + SVG backends, a bundled DejaVu Sans font
//! through ab_glyph: no system fontconfig needed).
//!
//! From the position log (`hapctl log --out FILE`):
//! - `trajectory.{png,svg}`: handle x, y, z over time;
//! - `coupling_force.{png,svg}`: coupling force norm and user force over time.
//!
//! From a `/dev/hap_stats` dump (`--stats FILE`), parsed by hap-core:
//! - `timing.{png,svg}`: wake-up latency, cycle execution time and period
//!   jitter distributions. The device text carries the distribution as
//!   min / p50 / avg / p99 / p99.9 / max (no per-bucket counts), so the
//!   chart shows those points per series on a log scale.

use std::path::Path;

use hap_core::simulator::LogRecord;
use hap_core::stats::{parse_summary, StatsSummary, TimingSummary};
use plotters::coord::Shift;
use plotters::prelude::*;

static FONT: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");

pub(crate) fn register_font() {
    use std::sync::Once;
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // Cannot fail for a valid bundled TTF; ignore the error otherwise
        // (text would then be missing, plots still drawn).
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

type DynErr = Box<dyn std::error::Error>;

pub fn run(log: &Path, out: &Path, stats: Option<&Path>) -> Result<(), String> {
    register_font();
    let bytes = std::fs::read(log).map_err(|e| format!("{}: {e}", log.display()))?;
    let (recs, bad) = crate::simlog::decode_all(&bytes);
    if recs.is_empty() {
        return Err(format!(
            "{}: no position-log records ({} bytes, {bad} undecodable records; expected {}-byte records from `hapctl log --out`)",
            log.display(),
            bytes.len(),
            LogRecord::SIZE
        ));
    }
    let summary = match stats {
        Some(p) => {
            let text = std::fs::read_to_string(p).map_err(|e| format!("{}: {e}", p.display()))?;
            Some(
                parse_summary(&text)
                    .map_err(|e| format!("{}: line {}: {:?}", p.display(), e.line, e.kind))?,
            )
        }
        None => None,
    };
    std::fs::create_dir_all(out).map_err(|e| format!("{}: {e}", out.display()))?;
    let period_s = summary
        .as_ref()
        .map(|s| s.period_us)
        .filter(|p| *p > 0)
        .unwrap_or(1000) as f64
        * 1e-6;

    let mut written = Vec::new();
    let c0 = recs[0].cycle;
    let t: Vec<f64> = recs
        .iter()
        .map(|r| r.cycle.wrapping_sub(c0) as f64 * period_s)
        .collect();

    for ext in ["png", "svg"] {
        let p = out.join(format!("trajectory.{ext}"));
        plot_any(&p, &Chart::Trajectory(&t, &recs)).map_err(|e| format!("{}: {e}", p.display()))?;
        written.push(p);
        let p = out.join(format!("coupling_force.{ext}"));
        plot_any(&p, &Chart::Force(&t, &recs)).map_err(|e| format!("{}: {e}", p.display()))?;
        written.push(p);
        if let Some(s) = &summary {
            let p = out.join(format!("timing.{ext}"));
            plot_any(&p, &Chart::Timing(s)).map_err(|e| format!("{}: {e}", p.display()))?;
            written.push(p);
        }
    }
    println!(
        "{} records ({:.3} s){}; wrote:",
        recs.len(),
        t.last().copied().unwrap_or(0.0),
        if bad > 0 {
            format!(", {bad} undecodable skipped")
        } else {
            String::new()
        }
    );
    for p in written {
        println!("  {}", p.display());
    }
    Ok(())
}

enum Chart<'a> {
    Trajectory(&'a [f64], &'a [LogRecord]),
    Force(&'a [f64], &'a [LogRecord]),
    Timing(&'a StatsSummary),
}

fn draw<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, c: &Chart<'_>) -> Result<(), DynErr>
where
    DB::ErrorType: 'static,
{
    match c {
        Chart::Trajectory(t, r) => plot_trajectory(root, t, r),
        Chart::Force(t, r) => plot_force(root, t, r),
        Chart::Timing(s) => plot_timing(root, s),
    }
}

fn plot_any(path: &Path, c: &Chart<'_>) -> Result<(), DynErr> {
    let size = (1000, 600);
    if path.extension().and_then(|e| e.to_str()) == Some("svg") {
        let root = SVGBackend::new(path, size).into_drawing_area();
        draw(&root, c)?;
        root.present()?;
    } else {
        let root = BitMapBackend::new(path, size).into_drawing_area();
        draw(&root, c)?;
        root.present()?;
    }
    Ok(())
}

fn range(vals: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in vals.filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let pad = ((hi - lo) * 0.05).max(1e-6);
    (lo - pad, hi + pad)
}

fn plot_trajectory<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    t: &[f64],
    recs: &[LogRecord],
) -> Result<(), DynErr>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let pos: Vec<[f64; 3]> = recs.iter().map(|r| r.handle_position.to_f64()).collect();
    let (ylo, yhi) = range(pos.iter().flat_map(|p| p.iter().copied()));
    let tmax = t.last().copied().unwrap_or(0.0).max(1e-3);
    let mut ch = ChartBuilder::on(root)
        .caption("Handle trajectory (arm base frame)", ("sans-serif", 24))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(0.0..tmax, ylo..yhi)?;
    ch.configure_mesh()
        .x_desc("time (s)")
        .y_desc("position (m)")
        .draw()?;
    let colors = [RED, GREEN, BLUE];
    for (i, name) in ["x", "y", "z"].iter().enumerate() {
        let c = colors[i];
        ch.draw_series(LineSeries::new(
            t.iter().zip(&pos).map(|(t, p)| (*t, p[i])),
            c.stroke_width(2),
        ))?
        .label(*name)
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
    }
    ch.configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}

fn plot_force<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    t: &[f64],
    recs: &[LogRecord],
) -> Result<(), DynErr>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let coupling: Vec<f64> = recs.iter().map(|r| r.coupling_force.norm().to_f64()).collect();
    let user: Vec<f64> = recs
        .iter()
        .map(|r| {
            let w = &r.user_wrench;
            let (a, b, c) = (w[0].to_f64(), w[1].to_f64(), w[2].to_f64());
            (a * a + b * b + c * c).sqrt()
        })
        .collect();
    let (lo, hi) = range(coupling.iter().chain(user.iter()).copied().chain([0.0]));
    let tmax = t.last().copied().unwrap_or(0.0).max(1e-3);
    let mut ch = ChartBuilder::on(root)
        .caption("Coupling force at the handle", ("sans-serif", 24))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(0.0..tmax, lo..hi)?;
    ch.configure_mesh()
        .x_desc("time (s)")
        .y_desc("force (N)")
        .draw()?;
    ch.draw_series(LineSeries::new(
        t.iter().copied().zip(coupling.iter().copied()),
        RED.stroke_width(2),
    ))?
    .label("|coupling force|")
    .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED.stroke_width(2)));
    ch.draw_series(LineSeries::new(
        t.iter().copied().zip(user.iter().copied()),
        BLUE.stroke_width(1),
    ))?
    .label("|user force|")
    .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE.stroke_width(1)));
    ch.configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}

/// (label, µs) points of one timing series.
fn points(s: &TimingSummary) -> [(&'static str, f64); 6] {
    [
        ("min", s.min_ns as f64 / 1e3),
        ("p50", s.p50_us as f64),
        ("avg", s.avg_ns as f64 / 1e3),
        ("p99", s.p99_us as f64),
        ("p99.9", s.p999_us as f64),
        ("max", s.max_ns as f64 / 1e3),
    ]
}

fn plot_timing<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    s: &StatsSummary,
) -> Result<(), DynErr>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let series = [
        ("wake-up latency", &s.wakeup, RED),
        ("cycle execution time", &s.exec, BLUE),
        ("period jitter", &s.jitter, GREEN),
    ];
    let ymax = series
        .iter()
        .flat_map(|(_, t, _)| points(t).map(|p| p.1))
        .fold(1.0f64, f64::max)
        * 2.0;
    let title = format!(
        "Timing distribution: {} cycles, period {} µs, {} misses",
        s.counters.cycles, s.period_us, s.counters.misses
    );
    let mut ch = ChartBuilder::on(root)
        .caption(title, ("sans-serif", 22))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(-0.5f64..5.5f64, (0.1f64..ymax).log_scale())?;
    ch.configure_mesh()
        .x_labels(6)
        .x_label_formatter(&|x| {
            let i = x.round();
            if (x - i).abs() > 0.01 || !(0.0..=5.0).contains(&i) {
                return String::new();
            }
            ["min", "p50", "avg", "p99", "p99.9", "max"][i as usize].to_string()
        })
        .y_desc("µs (log)")
        .draw()?;
    for (k, (name, t, c)) in series.iter().enumerate() {
        let c = *c;
        let off = (k as f64 - 1.0) * 0.22;
        ch.draw_series(points(t).iter().enumerate().map(|(i, (_, v))| {
            let x = i as f64 + off;
            Rectangle::new([(x - 0.1, 0.1), (x + 0.1, v.max(0.1))], c.mix(0.7).filled())
        }))?
        .label(*name)
        .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 15, y + 5)], c.filled()));
    }
    ch.configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}
