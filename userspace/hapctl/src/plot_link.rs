//! `hapctl plot-link`: the link benchmark's plots (scripts/bench-link.sh)
//! from the client's `rtt_hist.csv` (`value_us,count`) and `rate.csv`
//! (`t_s,answers_per_s,...,answers_per_guest_s`): an RTT histogram with
//! log-spaced bins on log-log axes, and the answer rate per real second.

use std::error::Error;
use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

type DynErr = Box<dyn Error>;

/// `(value_us, count)` rows.
pub fn read_hist(text: &str) -> Result<Vec<(u64, u64)>, String> {
    let mut rows = Vec::new();
    for (i, line) in text.lines().enumerate().skip(1) {
        if line.trim().is_empty() {
            continue;
        }
        let mut it = line.split(',');
        let parse = |s: Option<&str>| -> Result<u64, String> {
            s.unwrap_or("")
                .trim()
                .parse::<u64>()
                .map_err(|e| format!("rtt_hist.csv line {}: {e}", i + 1))
        };
        rows.push((parse(it.next())?, parse(it.next())?));
    }
    Ok(rows)
}

/// `(t_s, answers_per_s, answers_per_guest_s)` rows (the first, third... columns by name).
pub fn read_rate(text: &str) -> Result<Vec<(f64, f64, f64)>, String> {
    let mut lines = text.lines();
    let head: Vec<&str> = lines.next().unwrap_or("").split(',').collect();
    let col = |name: &str| {
        head.iter()
            .position(|h| h.trim() == name)
            .ok_or_else(|| format!("rate.csv: no column {name}"))
    };
    let (ct, cr, cg) = (
        col("t_s")?,
        col("answers_per_s")?,
        col("answers_per_guest_s")?,
    );
    let mut rows = Vec::new();
    for (i, line) in lines.enumerate() {
        let f: Vec<&str> = line.split(',').collect();
        let get = |c: usize| -> Result<f64, String> {
            f.get(c)
                .unwrap_or(&"")
                .trim()
                .parse::<f64>()
                .map_err(|e| format!("rate.csv line {}: {e}", i + 2))
        };
        rows.push((get(ct)?, get(cr)?, get(cg)?));
    }
    Ok(rows)
}

/// Log-spaced bins (10 per decade) of a 1 µs histogram: `(lo_ms, hi_ms, count)`.
pub fn log_bins(hist: &[(u64, u64)]) -> Vec<(f64, f64, u64)> {
    let mut bins: std::collections::BTreeMap<i64, u64> = Default::default();
    for &(v, c) in hist {
        let k = ((v.max(1) as f64).log10() * 10.0).floor() as i64;
        *bins.entry(k).or_default() += c;
    }
    bins.into_iter()
        .map(|(k, c)| {
            let lo = 10f64.powf(k as f64 / 10.0) / 1000.0;
            let hi = 10f64.powf((k + 1) as f64 / 10.0) / 1000.0;
            (lo, hi, c)
        })
        .collect()
}

fn draw_hist<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    title: &str,
    bins: &[(f64, f64, u64)],
) -> Result<(), DynErr>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let xlo = bins.first().map_or(0.1, |b| b.0);
    let xhi = bins.last().map_or(1.0, |b| b.1);
    let ymax = bins.iter().map(|b| b.2).max().unwrap_or(1) as f64 * 2.0;
    let mut ch = ChartBuilder::on(root)
        .caption(title, ("sans-serif", 20))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d((xlo..xhi).log_scale(), (0.5f64..ymax).log_scale())?;
    ch.configure_mesh()
        .x_desc("round-trip time, ms (log; bins of 1/10 decade)")
        .y_desc("samples (log)")
        .draw()?;
    ch.draw_series(
        bins.iter().map(|&(lo, hi, c)| {
            Rectangle::new([(lo, 0.5), (hi, c as f64)], BLUE.mix(0.6).filled())
        }),
    )?;
    Ok(())
}

fn draw_rate<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    title: &str,
    rows: &[(f64, f64, f64)],
) -> Result<(), DynErr>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let tmax = rows.last().map_or(1.0, |r| r.0).max(1.0);
    let ymax = rows.iter().map(|r| r.1.max(r.2)).fold(100.0f64, f64::max) * 1.1;
    let mut ch = ChartBuilder::on(root)
        .caption(title, ("sans-serif", 20))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(0f64..tmax, 0f64..ymax)?;
    ch.configure_mesh()
        .x_desc("real time, s")
        .y_desc("answers per second")
        .draw()?;
    ch.draw_series(LineSeries::new(rows.iter().map(|r| (r.0, r.1)), &RED))?
        .label("per real second")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 15, y)], RED));
    ch.draw_series(LineSeries::new(rows.iter().map(|r| (r.0, r.2)), &BLUE))?
        .label("per guest second (servo cycles x period)")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 15, y)], BLUE));
    ch.configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}

fn save(
    path: &Path,
    f: impl Fn(&DrawingArea<SVGBackend, Shift>) -> Result<(), DynErr>,
    g: impl Fn(&DrawingArea<BitMapBackend, Shift>) -> Result<(), DynErr>,
) -> Result<(), DynErr> {
    let size = (900, 500);
    let svg = path.with_extension("svg");
    let root = SVGBackend::new(&svg, size).into_drawing_area();
    f(&root)?;
    root.present()?;
    let png = path.with_extension("png");
    let root = BitMapBackend::new(&png, size).into_drawing_area();
    g(&root)?;
    root.present()?;
    Ok(())
}

/// Read `dir/rtt_hist.csv` and `dir/rate.csv`, write `out/rtt_hist.{svg,png}`
/// and `out/rate.{svg,png}`.
pub fn run(dir: &Path, out: &Path, title: &str) -> Result<(), String> {
    crate::analyze::register_font();
    let read = |n: &str| {
        std::fs::read_to_string(dir.join(n)).map_err(|e| format!("{}: {e}", dir.join(n).display()))
    };
    let hist = read_hist(&read("rtt_hist.csv")?)?;
    let rate = read_rate(&read("rate.csv")?)?;
    std::fs::create_dir_all(out).map_err(|e| format!("{}: {e}", out.display()))?;
    let bins = log_bins(&hist);
    let n: u64 = hist.iter().map(|h| h.1).sum();
    let t1 = format!("Link RTT, {n} samples {title}");
    save(
        &out.join("rtt_hist"),
        |r| draw_hist(r, &t1, &bins),
        |r| draw_hist(r, &t1, &bins),
    )
    .map_err(|e| format!("rtt_hist: {e}"))?;
    let t2 = format!("Answer rate {title}");
    save(
        &out.join("rate"),
        |r| draw_rate(r, &t2, &rate),
        |r| draw_rate(r, &t2, &rate),
    )
    .map_err(|e| format!("rate: {e}"))?;
    println!("wrote {}/rtt_hist.svg|png and rate.svg|png", out.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_bins() {
        let h = read_hist("value_us,count\n450,2\n1000,5\n1300,1\n120000,1\n").unwrap();
        assert_eq!(h.len(), 4);
        let b = log_bins(&h);
        assert_eq!(b.iter().map(|x| x.2).sum::<u64>(), 9);
        assert!(b.windows(2).all(|w| w[0].1 <= w[1].0 + 1e-12));
        assert!(read_hist("value_us,count\nx,1\n").is_err());
        let r = read_rate("t_s,answers_per_s,answers,lost,requests,guest_time_ratio,answers_per_guest_s\n1.0,400.0,400,0,1000,0.4,1000.0\n").unwrap();
        assert_eq!(r, vec![(1.0, 400.0, 1000.0)]);
        assert!(read_rate("t_s\n1\n").is_err());
    }

    #[test]
    fn writes_the_plots() {
        let d = std::env::temp_dir().join(format!("hapctl-plot-link-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        std::fs::write(d.join("rtt_hist.csv"), "value_us,count\n450,2\n1000,5\n").unwrap();
        std::fs::write(
            d.join("rate.csv"),
            "t_s,answers_per_s,answers,lost,requests,guest_time_ratio,answers_per_guest_s\n1.0,400.0,400,0,1000,0.4,1000.0\n2.0,420.0,420,0,1000,0.42,1000.0\n",
        )
        .unwrap();
        run(&d, &d, "(test)").unwrap();
        for f in ["rtt_hist.svg", "rtt_hist.png", "rate.svg", "rate.png"] {
            assert!(std::fs::metadata(d.join(f)).unwrap().len() > 100, "{f}");
        }
        let _ = std::fs::remove_dir_all(&d);
    }
}
