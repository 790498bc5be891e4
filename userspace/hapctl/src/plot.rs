//! `hapctl plot`: generic PNG + SVG charts from CSV files, for the benchmark
//! scripts (`scripts/bench-*.sh`), so that no plotting stack beyond hapctl
//! is needed.
//!
//! - `hapctl plot hist`: histograms, one CSV per series, lines
//!   `value,count` (value: bucket start, e.g. µs). Drawn as steps on a
//!   logarithmic count axis, several series overlaid (SERVO next to
//!   cyclictest).
//! - `hapctl plot lines`: x/y series, one CSV per series, lines `x,y`.
//!
//! CSV: `#` lines and a non-numeric first line (a header) are skipped;
//! any other line that does not parse is an error with its line number.

use std::path::{Path, PathBuf};

use plotters::coord::ranged1d::ValueFormatter;
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;

type DynErr = Box<dyn std::error::Error>;

/// One `NAME=FILE` argument, read.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
}

/// Parse `NAME=FILE` and read FILE's `x,y` lines.
pub fn load_series(arg: &str) -> Result<Series, String> {
    let (name, file) = arg
        .split_once('=')
        .filter(|(n, f)| !n.is_empty() && !f.is_empty())
        .ok_or_else(|| format!("'{arg}': expected NAME=FILE.csv"))?;
    let text = std::fs::read_to_string(file).map_err(|e| format!("{file}: {e}"))?;
    let points = parse_csv(&text).map_err(|e| format!("{file}: {e}"))?;
    Ok(Series {
        name: name.to_string(),
        points,
    })
}

/// `x,y` lines → points (see the module doc for what is skipped).
pub fn parse_csv(text: &str) -> Result<Vec<(f64, f64)>, String> {
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let mut it = line.split(',').map(str::trim);
        let parsed = match (it.next(), it.next()) {
            (Some(x), Some(y)) => x.parse::<f64>().ok().zip(y.parse::<f64>().ok()),
            _ => None,
        };
        match parsed {
            Some((x, y)) if x.is_finite() && y.is_finite() => out.push((x, y)),
            Some(_) => return Err(format!("line {}: not a finite number", i + 1)),
            None if out.is_empty() && i == first_data_line(text) => {} // header
            None => return Err(format!("line {}: expected 'x,y', got '{line}'", i + 1)),
        }
    }
    Ok(out)
}

fn first_data_line(text: &str) -> usize {
    text.lines()
        .position(|l| !l.trim().is_empty() && !l.trim().starts_with('#'))
        .unwrap_or(0)
}

/// What to draw.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    Hist,
    Lines,
}

pub struct Spec<'a> {
    pub kind: Kind,
    pub title: &'a str,
    pub x_label: &'a str,
    pub y_label: &'a str,
    pub log_y: bool,
    pub x_max: Option<f64>,
    pub series: &'a [Series],
}

/// Write `<out>.png` and `<out>.svg`; returns their paths.
pub fn run(out: &Path, spec: &Spec<'_>) -> Result<Vec<PathBuf>, String> {
    if spec.series.iter().all(|s| s.points.is_empty()) {
        return Err("no data points in any series".into());
    }
    crate::analyze::register_font();
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    }
    let mut written = Vec::new();
    for ext in ["png", "svg"] {
        let mut p = out.as_os_str().to_owned();
        p.push(format!(".{ext}"));
        let p = PathBuf::from(p);
        let size = (1000, 600);
        let r = if ext == "svg" {
            let root = SVGBackend::new(&p, size).into_drawing_area();
            draw(&root, spec).and_then(|_| root.present().map_err(Into::into))
        } else {
            let root = BitMapBackend::new(&p, size).into_drawing_area();
            draw(&root, spec).and_then(|_| root.present().map_err(Into::into))
        };
        r.map_err(|e| format!("{}: {e}", p.display()))?;
        written.push(p);
    }
    Ok(written)
}

const COLOURS: [RGBColor; 6] = [
    RGBColor(200, 30, 30),
    RGBColor(30, 60, 200),
    RGBColor(20, 140, 40),
    RGBColor(220, 130, 0),
    RGBColor(130, 40, 160),
    RGBColor(0, 0, 0),
];

/// Histogram steps: bucket [x, x + w) at height y, w the smallest gap
/// between bucket starts (1 for µs histograms).
fn steps(points: &[(f64, f64)], floor: f64) -> Vec<(f64, f64)> {
    let mut p: Vec<(f64, f64)> = points.to_vec();
    p.sort_by(|a, b| a.0.total_cmp(&b.0));
    let w = p
        .windows(2)
        .map(|w| w[1].0 - w[0].0)
        .filter(|d| *d > 0.0)
        .fold(f64::INFINITY, f64::min);
    let w = if w.is_finite() { w } else { 1.0 };
    let mut out = Vec::with_capacity(p.len() * 4);
    let mut prev_end: Option<f64> = None;
    for &(x, y) in &p {
        if prev_end.is_some_and(|e| e < x) {
            out.push((prev_end.unwrap_or(x), floor));
            out.push((x, floor));
        } else if prev_end.is_none() {
            out.push((x, floor));
        }
        out.push((x, y.max(floor)));
        out.push((x + w, y.max(floor)));
        prev_end = Some(x + w);
    }
    if let Some(e) = prev_end {
        out.push((e, floor));
    }
    out
}

/// Mesh, one line per series (histograms as steps down to `floor`, values
/// raised to `floor` for a log axis), legend.
fn draw_series<'a, DB, Y>(
    c: &mut ChartContext<'a, DB, Cartesian2d<RangedCoordf64, Y>>,
    s: &Spec<'_>,
    floor: f64,
) -> Result<(), DynErr>
where
    DB: DrawingBackend + 'a,
    DB::ErrorType: 'static,
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    c.configure_mesh()
        .x_desc(s.x_label)
        .y_desc(s.y_label)
        .draw()?;
    for (k, se) in s.series.iter().enumerate() {
        let col = COLOURS[k % COLOURS.len()];
        let pts = if s.kind == Kind::Hist {
            steps(&se.points, floor.max(0.0))
        } else {
            se.points.iter().map(|&(x, y)| (x, y.max(floor))).collect()
        };
        c.draw_series(LineSeries::new(pts, col.stroke_width(2)))?
            .label(se.name.as_str())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], col.stroke_width(2)));
    }
    c.configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}

fn draw<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, s: &Spec<'_>) -> Result<(), DynErr>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let all = || s.series.iter().flat_map(|se| se.points.iter());
    let x_lo = all().map(|p| p.0).fold(f64::INFINITY, f64::min).min(0.0);
    let x_hi_data = all().map(|p| p.0).fold(f64::NEG_INFINITY, f64::max);
    let x_hi = s
        .x_max
        .unwrap_or(if s.kind == Kind::Hist {
            x_hi_data + 1.0
        } else {
            x_hi_data
        })
        .max(x_lo + 1e-9);
    let y_hi = all().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max);
    let y_lo_data = all().map(|p| p.1).fold(f64::INFINITY, f64::min);
    let mut ch = ChartBuilder::on(root);
    ch.caption(s.title, ("sans-serif", 22))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(80);
    if s.log_y {
        let floor = if s.kind == Kind::Hist {
            0.5
        } else {
            (y_lo_data.max(1e-12)) / 2.0
        };
        let mut c = ch.build_cartesian_2d(
            x_lo..x_hi,
            (floor..(y_hi * 2.0).max(floor * 10.0)).log_scale(),
        )?;
        draw_series(&mut c, s, floor)?;
    } else {
        let y_lo = y_lo_data.min(0.0);
        let y_top = if y_hi > y_lo {
            y_hi + (y_hi - y_lo) * 0.05
        } else {
            y_lo + 1.0
        };
        let mut c = ch.build_cartesian_2d(x_lo..x_hi, y_lo..y_top)?;
        draw_series(&mut c, s, f64::NEG_INFINITY)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_skips_comments_and_header_and_rejects_garbage() {
        let p = parse_csv("# c\nus,count\n1,10\n 2 , 3\n\n").unwrap();
        assert_eq!(p, vec![(1.0, 10.0), (2.0, 3.0)]);
        let e = parse_csv("1,2\nx,y\n").unwrap_err();
        assert!(e.contains("line 2"), "{e}");
        assert!(parse_csv("1,inf\n").is_err());
        assert!(
            parse_csv("1\n2,3\n").is_ok(),
            "a lone first line is a header"
        );
        assert!(parse_csv("1,2\n3\n").is_err());
    }

    #[test]
    fn series_argument_needs_name_and_file() {
        assert!(load_series("nofile").unwrap_err().contains("NAME=FILE"));
        assert!(load_series("=x.csv").is_err());
        assert!(load_series("a=/nonexistent/x.csv")
            .unwrap_err()
            .contains("/nonexistent/x.csv"));
    }

    #[test]
    fn steps_outline_each_bucket_and_drop_to_the_floor_in_gaps() {
        let s = steps(&[(3.0, 5.0), (1.0, 2.0)], 0.5);
        assert_eq!(
            s,
            vec![
                (1.0, 0.5),
                (1.0, 2.0),
                (3.0, 2.0), // width 2: smallest gap between starts
                (3.0, 5.0),
                (5.0, 5.0),
                (5.0, 0.5)
            ]
        );
        let s = steps(&[(1.0, 2.0), (2.0, 4.0), (5.0, 1.0)], 0.5);
        assert!(s.contains(&(3.0, 0.5)) && s.contains(&(5.0, 0.5)), "{s:?}");
    }

    #[test]
    fn writes_png_and_svg() {
        let dir = std::env::temp_dir().join(format!("hapctl-plot-{}", std::process::id()));
        let series = vec![
            Series {
                name: "servo".into(),
                points: vec![(2.0, 9000.0), (3.0, 900.0), (7.0, 1.0)],
            },
            Series {
                name: "cyclictest".into(),
                points: vec![(2.0, 8000.0), (4.0, 10.0)],
            },
        ];
        let spec = Spec {
            kind: Kind::Hist,
            title: "t",
            x_label: "µs",
            y_label: "count",
            log_y: true,
            x_max: None,
            series: &series,
        };
        let files = run(&dir.join("h"), &spec).unwrap();
        assert_eq!(files.len(), 2);
        for f in &files {
            assert!(
                std::fs::metadata(f).unwrap().len() > 1000,
                "{}",
                f.display()
            );
        }
        let svg = std::fs::read_to_string(&files[1]).unwrap();
        assert!(svg.contains("cyclictest") && svg.contains("<svg"));
        let empty = [Series {
            name: "e".into(),
            points: vec![],
        }];
        assert!(run(
            &dir.join("e"),
            &Spec {
                series: &empty,
                ..spec
            }
        )
        .is_err());
        std::fs::remove_dir_all(&dir).ok();
    }
}
