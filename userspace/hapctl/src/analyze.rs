//! `hapctl analyze`: the spec's "off-line result analysis" (§3.6) of a whole
//! run, in physical units, as PNG and SVG figures (plotters, bitmap + SVG
//! backends, a bundled DejaVu Sans font through ab_glyph: no system
//! fontconfig needed) and a one-page report (`summary.html`).
//!
//! From the position log (`hapctl log --out FILE`, [`LogRecord`] v2), on
//! one time axis (servo time since insmod, s) with the run's events as
//! vertical markers:
//! - `trajectory`: handle and VPr positions in the client's frame, x/y/z;
//! - `forces`: coupling force on the handle and the user's force, N, one
//!   panel each (their ranges differ by orders of magnitude);
//! - `torques`: per joint, commanded and applied torque against ±`arm::TAU_MAX`;
//! - `speed`: handle speed, and joint speeds against the velocity brake's
//!   thresholds (`control::BRAKE_START`);
//! - `energy`: power at the coupling port (coupling force · handle velocity)
//!   and its running sum, next to the passivity observer's energy;
//! - `events`: power, session, link fading, degraded mode, misses and
//!   fail-safe steps as lanes;
//! - `timing`: per-cycle wake-up + execution time against the deadline
//!   check (3/4 period), misses marked.
//!
//! From a `/dev/hap_hist` dump (`--hist`): `latency_hist`, cyclictest's
//! histogram (1 µs buckets, log counts) of wake-up latency, execution time
//! and period jitter.
//!
//! Every figure is first built as data ([`Figure`]: panels, series, axis
//! ranges, markers) and then drawn exactly as built, so tests check what is
//! drawn: every axis range holds every plotted sample, every marker sits at
//! its event's cycle.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use hap_core::arm::TAU_MAX;
use hap_core::control::{BRAKE_START, MAX_FORCE};
use hap_core::fixed::Fx;
use hap_core::mode::Mode;
use hap_core::position_log::LogRecord;
use hap_core::servo::log_flags;
use hap_core::stats::{histogram_entries, key_values, parse_summary, StatsSummary, HIST_SERIES};
use hap_core::vp::status;
use plotters::coord::Shift;
use plotters::prelude::*;

use crate::simlog::Continuity;

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

/// The largest |q̇ᵢ| / `BRAKE_START`ᵢ of a record (1: the velocity brake's
/// threshold).
fn joint_speed_ratio(r: &LogRecord) -> f64 {
    r.qd.iter()
        .zip(BRAKE_START.iter())
        .map(|(q, b)| q.to_f64().abs() / b.to_f64().max(1e-9))
        .fold(0.0, f64::max)
}

/// The felt stiffness of the run's contacts, N/mm: over the coupled,
/// quasi-static cycles that push (|F| ≥ 1 N at the handle, handle speed
/// ≤ 2 cm/s), |F| over the distance from the handle to the client's object
/// (client frame; the stiffness the hand feels against a rigid client wall
/// when the force and speed factors are 1). Returns (p10, median, p90,
/// cycles), or `None` without such cycles.
pub fn felt_stiffness<'a>(
    recs: impl IntoIterator<Item = &'a LogRecord>,
) -> Option<(f64, f64, f64, usize)> {
    let mut k: Vec<f64> = recs
        .into_iter()
        .filter(|r| r.flags & log_flags::COUPLED != 0)
        .filter_map(|r| {
            let f = r.coupling_force.norm().to_f64();
            let v = r.handle_velocity.norm().to_f64();
            let d = r.handle_position_client.sub(r.vpr_position).norm().to_f64();
            (f >= 1.0 && v <= 0.02 && d > 1e-6).then(|| f / (d * 1000.0))
        })
        .collect();
    if k.is_empty() {
        return None;
    }
    k.sort_by(|a, b| a.total_cmp(b));
    let at = |q: f64| k[((k.len() - 1) as f64 * q).round() as usize];
    Some((at(0.1), at(0.5), at(0.9), k.len()))
}

/// A yes/no property of a record.
type RecordTest = fn(&LogRecord) -> bool;

/// Fail-safe steps, in `FAIL_SAFE_SEQUENCE` order.
const FAIL_SAFE_STEPS: [&str; 5] = [
    "inhibit motor commands",
    "power off the arm",
    "close the protocol",
    "stop the tasks",
    "release the resources",
];

/// Most points drawn per series: longer series are reduced to the minimum
/// and maximum of each bucket (peaks kept).
const MAX_POINTS: usize = 3000;

/// Inputs besides the log.
#[derive(Default)]
pub struct Inputs<'a> {
    /// A `/dev/hap_stats` dump.
    pub stats: Option<&'a Path>,
    /// A `/dev/hap_hist` dump.
    pub hist: Option<&'a Path>,
    /// `key: value` files whose lines go into the report as they are
    /// (the client's summary.txt, `hapctl log --summary`).
    pub summaries: &'a [PathBuf],
}

pub fn run(log: &Path, out: &Path, inputs: &Inputs<'_>) -> Result<(), String> {
    register_font();
    let bytes = std::fs::read(log).map_err(|e| format!("{}: {e}", log.display()))?;
    let (recs, bad) = crate::simlog::decode_all(&bytes);
    if recs.is_empty() {
        return Err(format!(
            "{}: no position-log records ({} bytes, {bad} undecodable records; expected {}-byte version-{} records from `hapctl log --out`)",
            log.display(),
            bytes.len(),
            LogRecord::SIZE,
            LogRecord::VERSION
        ));
    }
    let stats = match inputs.stats {
        Some(p) => {
            let text = std::fs::read_to_string(p).map_err(|e| format!("{}: {e}", p.display()))?;
            Some((
                parse_summary(&text)
                    .map_err(|e| format!("{}: line {}: {:?}", p.display(), e.line, e.kind))?,
                text,
            ))
        }
        None => None,
    };
    let hist = match inputs.hist {
        Some(p) => Some(std::fs::read_to_string(p).map_err(|e| format!("{}: {e}", p.display()))?),
        None => None,
    };
    let mut summaries = Vec::new();
    for p in inputs.summaries {
        let text = std::fs::read_to_string(p).map_err(|e| format!("{}: {e}", p.display()))?;
        let name = p
            .file_name()
            .map(|n| n.to_string_lossy().to_string())
            .unwrap_or_else(|| p.display().to_string());
        summaries.push((name, text));
    }
    std::fs::create_dir_all(out).map_err(|e| format!("{}: {e}", out.display()))?;

    let period_us = stats
        .as_ref()
        .map(|s| s.0.period_us)
        .filter(|p| *p > 0)
        .unwrap_or_else(|| period_from_log(&recs));
    let run = Run::new(&recs, period_us, bad);
    let mut figs = run.figures();
    if let (Some((st, _)), Some(f)) = (&stats, figs.iter_mut().find(|f| f.name == "timing")) {
        f.title = format!(
            "Cycle timing: {} deadline misses located in the log (red markers); the module counted {}",
            run.misses(),
            st.counters.misses
        );
    }
    if let Some(h) = &hist {
        figs.push(latency_histogram(h));
    }
    let mut written = Vec::new();
    for f in &figs {
        for ext in ["png", "svg"] {
            let p = out.join(format!("{}.{ext}", f.name));
            render_file(&p, f).map_err(|e| format!("{}: {e}", p.display()))?;
            written.push(p);
        }
    }
    let text = run.summary_text(stats.as_ref().map(|s| &s.0));
    let txt = out.join("analysis.txt");
    std::fs::write(&txt, &text).map_err(|e| format!("{}: {e}", txt.display()))?;
    std::fs::write(out.join("events.csv"), run.events_csv())
        .map_err(|e| format!("{}: {e}", out.display()))?;
    let html = out.join("summary.html");
    std::fs::write(
        &html,
        report_html(
            &run,
            &figs,
            &text,
            stats.as_ref().map(|s| s.1.as_str()),
            &summaries,
        ),
    )
    .map_err(|e| format!("{}: {e}", html.display()))?;
    print!("{text}");
    println!(
        "wrote {} figures (PNG + SVG) to {}",
        figs.len(),
        out.display()
    );
    println!("report: {}", html.display());
    Ok(())
}

/// The period from the log itself (time_us / cycle), 1000 µs if unknown.
fn period_from_log(recs: &[LogRecord]) -> u32 {
    recs.iter()
        .filter(|r| r.mode != Mode::FailSafe && r.cycle > 0)
        .map(|r| r.time_us / r.cycle)
        .find(|p| *p > 0)
        .and_then(|p| u32::try_from(p).ok())
        .unwrap_or(1000)
}

/// What happened, when.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EventKind {
    PowerOn,
    PowerOff,
    SessionOpen,
    SessionClose,
    LinkFading,
    LinkRestored,
    DegradedEnter,
    DegradedExit,
    Miss,
    FailSafeStep(u8),
    Dropped,
}

impl EventKind {
    fn lane(self) -> usize {
        match self {
            EventKind::PowerOn | EventKind::PowerOff => 0,
            EventKind::SessionOpen | EventKind::SessionClose => 1,
            EventKind::LinkFading | EventKind::LinkRestored => 2,
            EventKind::DegradedEnter | EventKind::DegradedExit => 3,
            EventKind::Miss => 4,
            EventKind::FailSafeStep(_) => 5,
            EventKind::Dropped => 6,
        }
    }

    fn colour(self) -> RGBColor {
        match self.lane() {
            0 => RGBColor(0, 150, 0),
            1 => RGBColor(30, 90, 220),
            2 => RGBColor(230, 140, 0),
            3 => RGBColor(150, 60, 190),
            4 => RGBColor(220, 0, 0),
            5 => RGBColor(0, 0, 0),
            _ => RGBColor(120, 120, 120),
        }
    }

    pub fn label(self) -> String {
        match self {
            EventKind::PowerOn => "power on".into(),
            EventKind::PowerOff => "power off".into(),
            EventKind::SessionOpen => "session open".into(),
            EventKind::SessionClose => "session closed".into(),
            EventKind::LinkFading => "link fading".into(),
            EventKind::LinkRestored => "link restored".into(),
            EventKind::DegradedEnter => "degraded mode".into(),
            EventKind::DegradedExit => "main mode".into(),
            EventKind::Miss => "deadline miss".into(),
            EventKind::FailSafeStep(n) => format!(
                "fail-safe {n}/5: {}",
                FAIL_SAFE_STEPS
                    .get(usize::from(n).wrapping_sub(1))
                    .unwrap_or(&"?")
            ),
            EventKind::Dropped => "records dropped".into(),
        }
    }
}

const LANES: [&str; 7] = [
    "power",
    "session",
    "link",
    "degraded",
    "misses",
    "fail-safe",
    "dropped",
];

#[derive(Clone, Debug, PartialEq)]
pub struct Event {
    /// The servo cycle it happened at (for a fail-safe step: the cycle the
    /// timer had reached).
    pub cycle: u64,
    pub t: f64,
    pub kind: EventKind,
    /// Extra detail (e.g. how many records a gap lost).
    pub count: u64,
}

/// The decoded run.
pub struct Run<'a> {
    recs: Vec<&'a LogRecord>,
    period_s: f64,
    period_us: u32,
    /// Time of each servo record, s.
    t: Vec<f64>,
    pub events: Vec<Event>,
    /// Fail-safe step records with the time they ran at, s. Only their
    /// applied torques (read from the motor line) are drawn: their other
    /// servo fields are SERVO's last cycle's, or unknown
    /// ([`crate::simlog::pose_unknown`]).
    fail_safe: Vec<(f64, &'a LogRecord)>,
    pub continuity: Continuity,
    undecodable: usize,
    /// Cycles with kernel timing (tick ≠ 0): the log came from the module.
    timed: bool,
}

fn has(st: u32, bit: u32) -> bool {
    st & bit != 0
}

impl<'a> Run<'a> {
    pub fn new(all: &'a [LogRecord], period_us: u32, undecodable: usize) -> Run<'a> {
        let period_s = f64::from(period_us.max(1)) * 1e-6;
        let continuity = Continuity::of(all);
        let recs: Vec<&LogRecord> = all.iter().filter(|r| r.mode != Mode::FailSafe).collect();
        let t_of = |c: u64| c as f64 * period_s;
        let t: Vec<f64> = recs.iter().map(|r| t_of(r.cycle)).collect();
        let timed = recs.iter().any(|r| r.timing.tick != 0);
        let check_ns = u64::from(period_us).saturating_mul(750);
        let mut events = Vec::new();
        let mut ev = |cycle: u64, kind: EventKind, count: u64| {
            events.push(Event {
                cycle,
                t: t_of(cycle),
                kind,
                count,
            })
        };
        let mut prev: Option<&LogRecord> = None;
        for r in &recs {
            let c = r.cycle;
            let p = prev.copied();
            let was = |bit: u32| p.is_some_and(|p| has(p.status, bit));
            let now = |bit: u32| has(r.status, bit);
            if now(status::POWER_ON) && !was(status::POWER_ON) {
                ev(c, EventKind::PowerOn, 0);
            }
            if p.is_some() && !now(status::POWER_ON) && was(status::POWER_ON) {
                ev(c, EventKind::PowerOff, 0);
            }
            let sess = r.timing.session != 0;
            let sess_was = p.is_some_and(|p| p.timing.session != 0);
            if sess && !sess_was {
                ev(c, EventKind::SessionOpen, u64::from(r.timing.session));
            }
            if !sess && sess_was {
                ev(c, EventKind::SessionClose, 0);
            }
            // Link fading matters while a VPr is in use.
            let fading = now(status::LINK_FADING) && r.vpr_age_cycles != LogRecord::NO_VPR;
            let fading_was = p.is_some_and(|p| {
                has(p.status, status::LINK_FADING) && p.vpr_age_cycles != LogRecord::NO_VPR
            });
            if fading && !fading_was {
                ev(c, EventKind::LinkFading, 0);
            }
            if !fading && fading_was {
                ev(c, EventKind::LinkRestored, 0);
            }
            let deg = r.mode == Mode::Degraded;
            let deg_was = p.is_some_and(|p| p.mode == Mode::Degraded);
            if deg && !deg_was {
                ev(c, EventKind::DegradedEnter, 0);
            }
            if !deg && deg_was {
                ev(c, EventKind::DegradedExit, 0);
            }
            if let Some(p) = p {
                if c > p.cycle.saturating_add(1) {
                    ev(
                        p.cycle.saturating_add(1),
                        EventKind::Dropped,
                        c - p.cycle - 1,
                    );
                }
                // Timer ticks with no servo cycle (more ticks than cycles
                // between two records): each was a missed deadline.
                let ticks = r.timing.tick.saturating_sub(p.timing.tick);
                let cycles = c.saturating_sub(p.cycle);
                if timed && ticks > cycles {
                    ev(c, EventKind::Miss, ticks - cycles);
                }
            }
            // A cycle still running at the 3/4 check missed its deadline.
            if timed
                && u64::from(r.timing.wakeup_ns).saturating_add(u64::from(r.timing.exec_ns))
                    > check_ns
            {
                ev(c, EventKind::Miss, 1);
            }
            prev = Some(r);
        }
        // Fail-safe steps: at the tick they ran at, mapped onto cycles by
        // the last servo record before them.
        let mut last: Option<&LogRecord> = None;
        let mut fail_safe = Vec::new();
        for r in all {
            if r.mode != Mode::FailSafe {
                last = Some(r);
                continue;
            }
            let cycle = match last {
                Some(l) if r.timing.tick >= l.timing.tick && l.timing.tick != 0 => {
                    l.cycle.saturating_add(r.timing.tick - l.timing.tick)
                }
                Some(l) => l.cycle,
                // No servo record before it: its own cycle if it has one,
                // else the tick (cycle n starts at tick n + 1).
                None if crate::simlog::pose_unknown(r) => r.timing.tick.saturating_sub(1),
                None => r.cycle,
            };
            fail_safe.push((t_of(cycle), r));
            events.push(Event {
                cycle,
                t: t_of(cycle),
                kind: EventKind::FailSafeStep(r.fail_safe_step),
                count: 0,
            });
        }
        events.sort_by(|a, b| {
            a.cycle
                .cmp(&b.cycle)
                .then(a.kind.lane().cmp(&b.kind.lane()))
        });
        Run {
            recs,
            period_s,
            period_us,
            t,
            events,
            fail_safe,
            continuity,
            undecodable,
            timed,
        }
    }

    /// Deadline misses located on the time axis.
    pub fn misses(&self) -> u64 {
        self.events
            .iter()
            .filter(|e| e.kind == EventKind::Miss)
            .map(|e| e.count)
            .sum()
    }

    /// The run's time span, s: first record to last event.
    fn span(&self) -> (f64, f64) {
        let lo = self.t.first().copied().unwrap_or(0.0);
        let hi = self
            .events
            .iter()
            .map(|e| e.t)
            .chain(self.t.last().copied())
            .fold(lo, f64::max);
        (lo, if hi > lo { hi } else { lo + self.period_s })
    }

    /// The time axis: the run's span and a margin, so that markers and
    /// dots at either end stay whole.
    fn x_range(&self) -> (f64, f64) {
        let (lo, hi) = self.span();
        let pad = (hi - lo) * 0.01;
        (lo - pad, hi + pad)
    }

    /// One value per servo record; a gap in the cycle count (dropped
    /// records) breaks the line.
    fn series(&self, name: &str, colour: RGBColor, f: impl Fn(&LogRecord) -> f64) -> Line {
        let mut pts = Vec::with_capacity(self.recs.len());
        let mut prev: Option<u64> = None;
        for (t, r) in self.t.iter().zip(&self.recs) {
            if prev.is_some_and(|c| r.cycle > c.saturating_add(1)) {
                pts.push((*t, f64::NAN));
            }
            pts.push((*t, f(r)));
            prev = Some(r.cycle);
        }
        Line::new(name, colour, pts)
    }

    fn figure(&self, name: &str, title: &str, panels: Vec<Panel>) -> Figure {
        Figure {
            name: name.into(),
            title: title.into(),
            x_label: "time since insmod (s)".into(),
            x: self.x_range(),
            panels,
            markers: self.events.clone(),
            columns: 1,
        }
    }

    pub fn figures(&self) -> Vec<Figure> {
        let xyz = [
            RGBColor(200, 30, 30),
            RGBColor(20, 140, 40),
            RGBColor(30, 60, 200),
        ];
        let mut out = Vec::new();

        // Trajectories: handle and VPr in the client's frame while a VPr
        // is in use (the frame is the session's: outside it the two are
        // not comparable), then the handle in the arm's base frame over
        // the whole run.
        let mut panels = Vec::new();
        for (i, axis) in ["x", "y", "z"].iter().enumerate() {
            let h = self.series(&format!("handle {axis}"), xyz[i], |r| {
                if r.vpr_age_cycles == LogRecord::NO_VPR {
                    f64::NAN
                } else {
                    r.handle_position_client.to_f64()[i]
                }
            });
            let mut v = self.series(&format!("VPr {axis}"), RGBColor(0, 0, 0), |r| {
                if r.vpr_age_cycles == LogRecord::NO_VPR {
                    f64::NAN
                } else {
                    r.vpr_position.to_f64()[i]
                }
            });
            v.dashed = true;
            panels.push(Panel::fit(
                &format!("{axis} in the client's frame, while a VPr is in use"),
                "client units",
                vec![h, v],
                vec![],
            ));
        }
        let base: Vec<Line> = (0..3)
            .map(|i| {
                self.series(
                    &format!("handle {}", ["x", "y", "z"][i]),
                    xyz[i],
                    move |r| r.handle_position.to_f64()[i],
                )
            })
            .collect();
        panels.push(Panel::fit(
            "handle in the arm's base frame, whole run",
            "m",
            base,
            vec![],
        ));
        out.push(self.figure(
            "trajectory",
            "Handle and VPr (the client's virtual object) trajectories",
            panels,
        ));

        // Forces, one panel each: their ranges differ.
        let comp = |name: &str, get: fn(&LogRecord) -> [f64; 3]| -> Vec<Line> {
            let mut v: Vec<Line> = (0..3)
                .map(|i| {
                    self.series(
                        &format!("{name} f{}", ["x", "y", "z"][i]),
                        xyz[i],
                        move |r| get(r)[i],
                    )
                })
                .collect();
            let mut n = self.series(&format!("|{name}|"), RGBColor(0, 0, 0), move |r| {
                let a = get(r);
                (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt()
            });
            n.width = 1;
            v.push(n);
            v
        };
        out.push(self.figure(
            "forces",
            "Forces on the handle (arm base frame)",
            vec![
                Panel::fit(
                    "coupling force (controller → handle); grey: its saturation ±MAX_FORCE",
                    "N",
                    comp("coupling", |r| r.coupling_force.to_f64()),
                    vec![
                        (MAX_FORCE.to_f64(), "+MAX_FORCE".into()),
                        (-MAX_FORCE.to_f64(), "-MAX_FORCE".into()),
                    ],
                ),
                Panel::fit(
                    "user's force",
                    "N",
                    comp("user", |r| {
                        [
                            r.user_wrench[0].to_f64(),
                            r.user_wrench[1].to_f64(),
                            r.user_wrench[2].to_f64(),
                        ]
                    }),
                    vec![],
                ),
            ],
        ));

        // Joint torques against their limits.
        let mut panels = Vec::new();
        for (j, lim) in TAU_MAX.iter().enumerate() {
            let lim = lim.to_f64();
            // Wide and light under the applied torque: where the two
            // differ (unpowered, cut, clamped) the command shows.
            let mut cmd = self.series("commanded", RGBColor(120, 160, 255), |r| {
                r.torque_command[j].to_f64()
            });
            cmd.width = 4;
            let app = self.series("applied", RGBColor(200, 30, 30), |r| {
                r.motor_torque[j].to_f64()
            });
            let mut lines = vec![cmd, app];
            if !self.fail_safe.is_empty() {
                // What the motors applied as each fail-safe step ran.
                let mut fs = Line::new(
                    "applied at fail-safe steps",
                    RGBColor(0, 0, 0),
                    self.fail_safe
                        .iter()
                        .map(|(t, r)| (*t, r.motor_torque[j].to_f64()))
                        .collect(),
                );
                fs.points_only = true;
                lines.push(fs);
            }
            panels.push(Panel::fit(
                &format!("joint {} (limit ±{} N·m)", j + 1, short(lim)),
                "N·m",
                lines,
                vec![(lim, "+limit".into()), (-lim, "-limit".into())],
            ));
        }
        let mut f = self.figure("torques", "Joint torques: commanded and applied", panels);
        f.columns = 2;
        out.push(f);

        // Speeds: the handle's, and the joints' against the velocity
        // brake's thresholds (`control::BRAKE_START`, joint space).
        let v = self.series("|v| handle", RGBColor(30, 60, 200), |r| {
            r.handle_velocity.norm().to_f64()
        });
        let mut hand = Panel::fit("handle linear speed (log scale)", "m/s", vec![v], vec![]);
        hand.log_y = true;
        hand.y = log_range(&hand);
        hand.y.0 = hand.y.0.max(hand.y.1 * 1e-6);
        let ratio = self.series(
            "max over joints |dq/dt| / brake threshold",
            RGBColor(200, 30, 30),
            joint_speed_ratio,
        );
        let joints = Panel::fit(
            "joint speeds against the velocity brake (grey: 1 = the brake's threshold, control::BRAKE_START)",
            "ratio",
            vec![ratio],
            vec![(1.0, "brake threshold".into())],
        );
        out.push(self.figure("speed", "Speeds and their bound", vec![hand, joints]));

        // Energy at the coupling port.
        let power: Vec<f64> = self
            .recs
            .iter()
            .map(|r| {
                let f = r.coupling_force.to_f64();
                let v = r.handle_velocity.to_f64();
                f[0] * v[0] + f[1] * v[1] + f[2] * v[2]
            })
            .collect();
        let mut sum = 0.0;
        let energy: Vec<(f64, f64)> = self
            .t
            .iter()
            .zip(&power)
            .map(|(t, p)| {
                sum += p * self.period_s;
                (*t, sum)
            })
            .collect();
        let p_line = Line::new(
            "F·v",
            RGBColor(200, 30, 30),
            self.t.iter().copied().zip(power.iter().copied()).collect(),
        );
        let e_line = Line::new("∑ F·v·T", RGBColor(30, 60, 200), energy);
        let po = self.series("passivity observer", RGBColor(20, 140, 40), |r| {
            r.po_energy.to_f64()
        });
        out.push(self.figure(
            "energy",
            "Energy flow at the coupling port (> 0: the coupling does work on the handle)",
            vec![
                Panel::fit("power at the handle port", "W", vec![p_line], vec![]),
                Panel::fit(
                    "energy delivered at the handle port (running sum)",
                    "J",
                    vec![e_line],
                    vec![],
                ),
                // Its own axis: it also counts the work at the VPr's port and
                // the arm's viscous dissipation, so it is not the sum above.
                Panel::fit(
                    "passivity observer: energy into the coupling plus the arm's proven dissipation (≥ 0: passive)",
                    "J",
                    vec![po],
                    vec![(0.0, "0".into())],
                ),
            ],
        ));

        // Events as lanes.
        let mut lines: Vec<Line> = Vec::new();
        for (lane, name) in LANES.iter().enumerate() {
            let pts: Vec<(f64, f64)> = self
                .events
                .iter()
                .filter(|e| e.kind.lane() == lane)
                .map(|e| (e.t, lane as f64))
                .collect();
            if pts.is_empty() {
                continue;
            }
            let colour = self
                .events
                .iter()
                .find(|e| e.kind.lane() == lane)
                .map(|e| e.kind.colour())
                .unwrap_or(BLACK);
            let mut l = Line::new(name, colour, pts);
            l.points_only = true;
            lines.push(l);
        }
        // Spans: powered, in session, degraded, fading.
        let spans: [(usize, RecordTest); 4] = [
            (0, |r| has(r.status, status::POWER_ON)),
            (1, |r| r.timing.session != 0),
            (2, |r| {
                has(r.status, status::LINK_FADING) && r.vpr_age_cycles != LogRecord::NO_VPR
            }),
            (3, |r| r.mode == Mode::Degraded),
        ];
        // Dropped records: the span they covered.
        for e in self.events.iter().filter(|e| e.kind == EventKind::Dropped) {
            let t1 = e.t + e.count as f64 * self.period_s;
            let lane = EventKind::Dropped.lane() as f64;
            let mut l = Line::new("", RGBColor(160, 160, 160), vec![(e.t, lane), (t1, lane)]);
            l.width = 6;
            lines.push(l);
        }
        for (lane, on) in spans {
            let pts: Vec<(f64, f64)> = self
                .t
                .iter()
                .zip(&self.recs)
                .map(|(t, r)| (*t, if on(r) { lane as f64 } else { f64::NAN }))
                .collect();
            if pts.iter().any(|p| p.1.is_finite()) {
                let mut l = Line::new("", RGBColor(160, 160, 160), pts);
                l.width = 6;
                lines.push(l);
            }
        }
        let p = Panel {
            title: "events (bars: state held; dots: changes)".into(),
            y_label: String::new(),
            y: (-0.5, LANES.len() as f64 - 0.5),
            log_y: false,
            lines,
            hlines: vec![],
            lanes: Some(LANES.iter().map(|s| s.to_string()).collect()),
        };
        out.push(self.figure("events", "The run's events", vec![p]));

        // Timing per cycle.
        if self.timed {
            let deadline = f64::from(self.period_us) * 0.75;
            let mut l = self.series("wake-up + execution", RGBColor(30, 60, 200), |r| {
                (f64::from(r.timing.wakeup_ns) + f64::from(r.timing.exec_ns)) / 1e3
            });
            l.points_only = true;
            let w = self.series("wake-up latency", RGBColor(20, 140, 40), |r| {
                f64::from(r.timing.wakeup_ns) / 1e3
            });
            let mut w = w;
            w.points_only = true;
            let mut panel = Panel::fit(
                &format!(
                    "per cycle (log scale); grey: the deadline check at 3/4 period ({} µs)",
                    short(deadline)
                ),
                "µs",
                vec![l, w],
                vec![(deadline, "deadline check (3/4 period)".into())],
            );
            panel.log_y = true;
            panel.y = log_range(&panel);
            out.push(self.figure(
                "timing",
                &format!(
                    "Cycle timing: {} deadline misses located (red markers)",
                    self.misses()
                ),
                vec![panel],
            ));
        }
        out
    }

    pub fn events_csv(&self) -> String {
        let mut s = String::from("cycle,time_s,event,count\n");
        for e in &self.events {
            let _ = writeln!(s, "{},{:.4},{},{}", e.cycle, e.t, e.kind.label(), e.count);
        }
        s
    }

    /// The figures of the run as `key: value` lines.
    pub fn summary_text(&self, stats: Option<&StatsSummary>) -> String {
        let c = &self.continuity;
        let mut s = String::new();
        let _ = writeln!(s, "records: {}", c.records);
        let _ = writeln!(s, "servo_records: {}", self.recs.len());
        let _ = writeln!(
            s,
            "cycles: {}..={}",
            c.first_cycle.unwrap_or(0),
            c.last_cycle.unwrap_or(0)
        );
        let (t0, t1) = self.span();
        let _ = writeln!(s, "duration_s: {:.3}", t1 - t0);
        let _ = writeln!(s, "period_us: {}", self.period_us);
        let _ = writeln!(s, "dropped_records: {}", c.dropped);
        if c.restarts > 0 {
            let _ = writeln!(s, "restarts: {} (the cycle count went back)", c.restarts);
        }
        if self.undecodable > 0 {
            let _ = writeln!(s, "undecodable_records: {}", self.undecodable);
        }
        let count = |k: fn(EventKind) -> bool| self.events.iter().filter(|e| k(e.kind)).count();
        let _ = writeln!(s, "power_on_events: {}", count(|k| k == EventKind::PowerOn));
        let _ = writeln!(
            s,
            "power_off_events: {}",
            count(|k| k == EventKind::PowerOff)
        );
        let _ = writeln!(
            s,
            "sessions_opened: {}",
            count(|k| k == EventKind::SessionOpen)
        );
        let _ = writeln!(
            s,
            "link_fading_events: {}",
            count(|k| k == EventKind::LinkFading)
        );
        // The link watchdog's gain over the cycles where the coupling acts
        // (powered, in session, a VPr in use): the fraction at full gain (1:
        // the coupling never faded), the fades (entries below full gain),
        // the lowest gain and the oldest VPr. A client that powers off
        // before it closes leaves its last VPr to age unpowered: not counted.
        let coupled = |r: &LogRecord| {
            has(r.status, status::POWER_ON)
                && r.timing.session != 0
                && r.vpr_age_cycles != LogRecord::NO_VPR
        };
        let linked: Vec<&&LogRecord> = self.recs.iter().filter(|r| coupled(r)).collect();
        let full = linked.iter().filter(|r| r.link_gain == Fx::ONE).count();
        let mut fades = 0u64;
        let mut fading = false;
        for r in &self.recs {
            let now = coupled(r) && r.link_gain != Fx::ONE;
            if now && !fading {
                fades += 1;
            }
            fading = now;
        }
        let _ = writeln!(s, "link_cycles: {}", linked.len());
        let _ = writeln!(s, "link_fades: {fades}");
        let _ = writeln!(
            s,
            "link_full_gain_fraction: {:.6}",
            if linked.is_empty() {
                0.0
            } else {
                full as f64 / linked.len() as f64
            }
        );
        let _ = writeln!(
            s,
            "link_gain_min: {:.6}",
            linked
                .iter()
                .map(|r| r.link_gain.to_f64())
                .fold(f64::NAN, f64::min)
        );
        let _ = writeln!(
            s,
            "vpr_age_max_ms: {:.3}",
            linked.iter().map(|r| r.vpr_age_cycles).max().unwrap_or(0) as f64
                * f64::from(self.period_us)
                / 1000.0
        );
        let _ = writeln!(
            s,
            "degraded_cycles: {}",
            self.recs
                .iter()
                .filter(|r| r.mode == Mode::Degraded)
                .count()
        );
        if self.timed {
            let _ = writeln!(s, "misses_located: {}", self.misses());
        } else {
            let _ = writeln!(s, "misses_located: - (log without kernel timing)");
        }
        if let Some(st) = stats {
            let _ = writeln!(s, "misses_module: {}", st.counters.misses);
        }
        let _ = writeln!(
            s,
            "fail_safe_steps: {}",
            count(|k| matches!(k, EventKind::FailSafeStep(_)))
        );
        let max =
            |f: &dyn Fn(&LogRecord) -> f64| self.recs.iter().map(|r| f(r)).fold(0.0, f64::max);
        let _ = writeln!(
            s,
            "max_coupling_force_n: {:.3}",
            max(&|r| r.coupling_force.norm().to_f64())
        );
        let _ = writeln!(
            s,
            "max_user_force_n: {:.3}",
            max(&|r| {
                let w = &r.user_wrench;
                let (a, b, c) = (w[0].to_f64(), w[1].to_f64(), w[2].to_f64());
                (a * a + b * b + c * c).sqrt()
            })
        );
        let _ = writeln!(
            s,
            "max_handle_speed_m_s: {:.4}",
            max(&|r| r.handle_velocity.norm().to_f64())
        );
        let _ = writeln!(
            s,
            "max_joint_speed_over_brake_start: {:.3} (the velocity brake acts above 1)",
            max(&|r| joint_speed_ratio(r))
        );
        for (j, lim) in TAU_MAX.iter().enumerate() {
            let _ = writeln!(
                s,
                "max_applied_torque_j{}_nm: {:.4} (limit {})",
                j + 1,
                max(&|r| r.motor_torque[j].to_f64().abs()),
                short(lim.to_f64())
            );
        }
        let mut e = 0.0;
        for r in &self.recs {
            let f = r.coupling_force.to_f64();
            let v = r.handle_velocity.to_f64();
            e += (f[0] * v[0] + f[1] * v[1] + f[2] * v[2]) * self.period_s;
        }
        let _ = writeln!(s, "coupling_port_energy_j: {e:.4}");
        match felt_stiffness(self.recs.iter().copied()) {
            Some((lo, med, hi, n)) => {
                let _ = writeln!(
                    s,
                    "felt_stiffness_n_per_mm: {med:.3} (p10 {lo:.3}, p90 {hi:.3}; {n} quasi-static contact cycles: |F| >= 1 N, |v| <= 2 cm/s)"
                );
            }
            None => {
                let _ = writeln!(s, "felt_stiffness_n_per_mm: - (no quasi-static contact)");
            }
        }
        s
    }
}

/// One drawn series.
#[derive(Clone, Debug)]
pub struct Line {
    pub name: String,
    pub colour: RGBColor,
    /// NaN y: a break in the line.
    pub points: Vec<(f64, f64)>,
    pub width: u32,
    pub dashed: bool,
    pub points_only: bool,
}

impl Line {
    fn new(name: &str, colour: RGBColor, points: Vec<(f64, f64)>) -> Line {
        Line {
            name: name.into(),
            colour,
            points,
            width: 1,
            dashed: false,
            points_only: false,
        }
    }
}

#[derive(Clone, Debug)]
pub struct Panel {
    pub title: String,
    pub y_label: String,
    pub y: (f64, f64),
    pub log_y: bool,
    pub lines: Vec<Line>,
    /// Horizontal reference lines (limits).
    pub hlines: Vec<(f64, String)>,
    /// Lane names for an event panel (y = lane index).
    pub lanes: Option<Vec<String>>,
}

impl Panel {
    /// A panel whose y range holds every sample and every reference line.
    fn fit(title: &str, y_label: &str, lines: Vec<Line>, hlines: Vec<(f64, String)>) -> Panel {
        let vals = lines
            .iter()
            .flat_map(|l| l.points.iter().map(|p| p.1))
            .chain(hlines.iter().map(|h| h.0));
        Panel {
            title: title.into(),
            y_label: y_label.into(),
            y: fit_range(vals),
            log_y: false,
            lines,
            hlines,
            lanes: None,
        }
    }
}

/// [lo, hi] holding every finite value, with a 5 % margin (a constant
/// series gets a small band around it).
pub fn fit_range(vals: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in vals.filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return (-1.0, 1.0);
    }
    let span = hi - lo;
    let pad = if span > 0.0 {
        span * 0.05
    } else {
        // A constant: a band readable in any of the units drawn.
        (lo.abs() * 0.05).max(1e-3)
    };
    (lo - pad, hi + pad)
}

/// A log range for a panel's positive values (values ≤ 0 are drawn at the
/// floor).
fn log_range(p: &Panel) -> (f64, f64) {
    let vals = p
        .lines
        .iter()
        .flat_map(|l| l.points.iter().map(|q| q.1))
        .chain(p.hlines.iter().map(|h| h.0))
        .filter(|v| v.is_finite() && *v > 0.0);
    let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
    for v in vals {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return (0.1, 10.0);
    }
    (lo / 1.5, hi * 1.5)
}

#[derive(Clone, Debug)]
pub struct Figure {
    pub name: String,
    pub title: String,
    pub x_label: String,
    pub x: (f64, f64),
    pub panels: Vec<Panel>,
    /// Events drawn as vertical lines on every panel.
    pub markers: Vec<Event>,
    pub columns: usize,
}

impl Default for Figure {
    fn default() -> Self {
        Figure {
            name: String::new(),
            title: String::new(),
            x_label: String::new(),
            x: (0.0, 1.0),
            panels: vec![],
            markers: vec![],
            columns: 1,
        }
    }
}

/// The latency histogram of a `/dev/hap_hist` dump, cyclictest style.
fn latency_histogram(text: &str) -> Figure {
    let colours = [
        RGBColor(200, 30, 30),
        RGBColor(30, 60, 200),
        RGBColor(20, 140, 40),
    ];
    let mut lines = Vec::new();
    for (name, c) in HIST_SERIES.iter().zip(colours) {
        let pts: Vec<(f64, f64)> = histogram_entries(text, name)
            .map(|(us, n)| (f64::from(us), n as f64))
            .collect();
        if pts.is_empty() {
            continue;
        }
        let label = match *name {
            "wakeup" => "wake-up latency",
            "exec" => "execution time",
            _ => "period jitter",
        };
        lines.push(Line::new(label, c, hist_steps(&pts, 0.5)));
    }
    let xmax = lines
        .iter()
        .flat_map(|l| l.points.iter().map(|p| p.0))
        .fold(1.0, f64::max);
    let ymax = lines
        .iter()
        .flat_map(|l| l.points.iter().map(|p| p.1))
        .fold(1.0, f64::max);
    Figure {
        name: "latency_hist".into(),
        title: "Latency histogram (1 µs buckets; last bucket: ≥ 1000 µs)".into(),
        x_label: "µs".into(),
        x: (0.0, xmax * 1.02),
        panels: vec![Panel {
            title: String::new(),
            y_label: "cycles (log)".into(),
            y: (0.5, ymax * 2.0),
            log_y: true,
            lines,
            hlines: vec![],
            lanes: None,
        }],
        markers: vec![],
        columns: 1,
    }
}

/// The outline of 1 µs buckets `(start, count)`: each bucket [x, x + 1) at
/// its count, down to `floor` between non-adjacent buckets.
fn hist_steps(buckets: &[(f64, f64)], floor: f64) -> Vec<(f64, f64)> {
    let mut b = buckets.to_vec();
    b.sort_by(|a, c| a.0.total_cmp(&c.0));
    let mut out = Vec::with_capacity(b.len() * 4);
    let mut end: Option<f64> = None;
    for (x, n) in b {
        if end != Some(x) {
            if let Some(e) = end {
                out.push((e, floor));
            }
            out.push((x, floor));
        }
        out.push((x, n.max(floor)));
        out.push((x + 1.0, n.max(floor)));
        end = Some(x + 1.0);
    }
    if let Some(e) = end {
        out.push((e, floor));
    }
    out
}

/// At most `MAX_POINTS` points: per bucket, its minimum and maximum in
/// time order (peaks kept); NaN breaks are kept.
pub fn reduce(points: &[(f64, f64)]) -> Vec<(f64, f64)> {
    if points.len() <= MAX_POINTS {
        return points.to_vec();
    }
    let per = points.len().div_ceil(MAX_POINTS / 2);
    let mut out = Vec::with_capacity(MAX_POINTS + 2);
    for chunk in points.chunks(per) {
        if chunk.iter().any(|p| !p.1.is_finite()) {
            // Keep the break: the chunk's finite extremes around a NaN.
            let mut seen_nan = false;
            for p in chunk {
                if !p.1.is_finite() {
                    if !seen_nan {
                        out.push(*p);
                        seen_nan = true;
                    }
                } else if seen_nan || out.last().is_none_or(|q| !q.1.is_finite()) {
                    out.push(*p);
                    seen_nan = false;
                }
            }
            continue;
        }
        let (mut lo, mut hi) = (chunk[0], chunk[0]);
        for p in chunk {
            if p.1 < lo.1 {
                lo = *p;
            }
            if p.1 > hi.1 {
                hi = *p;
            }
        }
        if lo.0 <= hi.0 {
            out.push(lo);
            if hi != lo {
                out.push(hi);
            }
        } else {
            out.push(hi);
            out.push(lo);
        }
    }
    out
}

/// A dense point series as `MAX_POINTS / 2` bars: per bucket of
/// consecutive points, (first x, min y, max y) of its finite values.
pub fn range_bars(points: &[(f64, f64)]) -> Vec<(f64, f64, f64)> {
    let per = points.len().div_ceil(MAX_POINTS / 2).max(1);
    points
        .chunks(per)
        .filter_map(|c| {
            let f = c.iter().filter(|p| p.1.is_finite());
            let lo = f.clone().map(|p| p.1).fold(f64::INFINITY, f64::min);
            let hi = f.clone().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max);
            let x = f.map(|p| p.0).next()?;
            Some((x, lo, hi))
        })
        .collect()
}

/// Contiguous finite runs of a series (NaN breaks it).
fn segments(points: &[(f64, f64)]) -> Vec<Vec<(f64, f64)>> {
    let mut out = Vec::new();
    let mut cur = Vec::new();
    for p in points {
        if p.1.is_finite() {
            cur.push(*p);
        } else if !cur.is_empty() {
            out.push(std::mem::take(&mut cur));
        }
    }
    if !cur.is_empty() {
        out.push(cur);
    }
    out
}

fn render_file(path: &Path, f: &Figure) -> Result<(), DynErr> {
    let rows = f.panels.len().div_ceil(f.columns.max(1)).max(1);
    let h = (120 + rows as u32 * 260).min(1400);
    let size = (1400, h);
    if path.extension().and_then(|e| e.to_str()) == Some("svg") {
        let root = SVGBackend::new(path, size).into_drawing_area();
        draw_figure(&root, f)?;
        root.present()?;
    } else {
        let root = BitMapBackend::new(path, size).into_drawing_area();
        draw_figure(&root, f)?;
        root.present()?;
    }
    Ok(())
}

fn draw_figure<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, f: &Figure) -> Result<(), DynErr>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let root = root.titled(&f.title, ("sans-serif", 24))?;
    let cols = f.columns.max(1);
    let rows = f.panels.len().div_ceil(cols).max(1);
    let areas = root.split_evenly((rows, cols));
    for (p, area) in f.panels.iter().zip(areas.iter()) {
        draw_panel(area, f, p)?;
    }
    Ok(())
}

fn draw_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    f: &Figure,
    p: &Panel,
) -> Result<(), DynErr>
where
    DB::ErrorType: 'static,
{
    let mut b = ChartBuilder::on(area);
    b.caption(&p.title, ("sans-serif", 16))
        .margin(8)
        .x_label_area_size(32)
        .y_label_area_size(if p.lanes.is_some() { 90 } else { 70 });
    let (x0, x1) = f.x;
    let (y0, y1) = p.y;
    let x_decimals = tick_decimals(x1 - x0);
    let x_fmt = move |v: &f64| tick_label(*v, x_decimals);
    if p.log_y {
        let mut ch = b.build_cartesian_2d(x0..x1, (y0..y1).log_scale())?;
        ch.configure_mesh()
            .x_desc(&f.x_label)
            .y_desc(&p.y_label)
            .y_label_formatter(&|v| log_label(*v))
            .x_label_formatter(&x_fmt)
            .light_line_style(WHITE.mix(0.0))
            .draw()?;
        let floor = y0;
        draw_content(&mut ch, f, p, y0, y1, |v| v.max(floor))?;
    } else {
        let mut ch = b.build_cartesian_2d(x0..x1, y0..y1)?;
        let lanes = p.lanes.clone();
        let decimals = tick_decimals(y1 - y0);
        let fmt = move |v: &f64| -> String {
            match &lanes {
                Some(names) => {
                    let i = v.round();
                    if (v - i).abs() > 0.01 || i < 0.0 {
                        String::new()
                    } else {
                        names.get(i as usize).cloned().unwrap_or_default()
                    }
                }
                None => tick_label(*v, decimals),
            }
        };
        let mut mesh = ch.configure_mesh();
        mesh.x_desc(&f.x_label)
            .y_desc(&p.y_label)
            .y_label_formatter(&fmt)
            .x_label_formatter(&x_fmt)
            .light_line_style(WHITE.mix(0.0));
        if p.lanes.is_some() {
            mesh.y_labels(LANES.len() * 2 + 1);
        }
        mesh.draw()?;
        draw_content(&mut ch, f, p, y0, y1, |v| v)?;
    }
    Ok(())
}

fn draw_content<'a, DB, Y>(
    ch: &mut ChartContext<'a, DB, Cartesian2d<plotters::coord::types::RangedCoordf64, Y>>,
    f: &Figure,
    p: &Panel,
    y0: f64,
    y1: f64,
    clampv: impl Fn(f64) -> f64,
) -> Result<(), DynErr>
where
    DB: DrawingBackend + 'a,
    DB::ErrorType: 'static,
    Y: Ranged<ValueType = f64>,
{
    // Event markers first (behind the data).
    for e in &f.markers {
        let c = e.kind.colour();
        ch.draw_series(std::iter::once(PathElement::new(
            vec![(e.t, clampv(y0)), (e.t, y1)],
            c.mix(0.55).stroke_width(1),
        )))?;
    }
    for (lim, _) in &p.hlines {
        ch.draw_series(std::iter::once(PathElement::new(
            vec![(f.x.0, *lim), (f.x.1, *lim)],
            RGBColor(110, 110, 110).stroke_width(2),
        )))?;
    }
    for l in &p.lines {
        let c = l.colour;
        let pts: Vec<(f64, f64)> = reduce(&l.points)
            .into_iter()
            .map(|(x, y)| (x, if y.is_finite() { clampv(y) } else { y }))
            .collect();
        let style = c.stroke_width(l.width);
        if l.points_only {
            let anno = if l.points.len() > MAX_POINTS {
                // Dense: each bucket's range as a vertical bar (min to max).
                let bars: Vec<PathElement<(f64, f64)>> = range_bars(&l.points)
                    .into_iter()
                    .map(|(x, lo, hi)| {
                        PathElement::new(vec![(x, clampv(lo)), (x, clampv(hi))], c.stroke_width(1))
                    })
                    .collect();
                ch.draw_series(bars)?
            } else {
                ch.draw_series(
                    pts.iter()
                        .filter(|p| p.1.is_finite())
                        .map(|p| Circle::new(*p, 3, c.filled())),
                )?
            };
            if !l.name.is_empty() {
                anno.label(l.name.as_str())
                    .legend(move |(x, y)| Circle::new((x + 10, y), 3, c.filled()));
            }
            continue;
        }
        let mut first = true;
        for seg in segments(&pts) {
            let anno = if l.dashed {
                ch.draw_series(DashedLineSeries::new(seg, 6, 4, style))?
            } else if l.width > 1 {
                // A wide line as separate strokes: a joined wide polyline
                // gets miter spikes at sharp reversals, far past its data
                // (and past the panel) in the bitmap backend.
                ch.draw_series(
                    seg.windows(2)
                        .map(|w| PathElement::new(w.to_vec(), style))
                        .collect::<Vec<_>>(),
                )?
            } else {
                ch.draw_series(LineSeries::new(seg, style))?
            };
            if first && !l.name.is_empty() {
                anno.label(l.name.as_str()).legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2))
                });
                first = false;
            }
        }
    }
    if p.lines.iter().any(|l| !l.name.is_empty()) && p.lanes.is_none() {
        ch.configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 13))
            .draw()?;
    }
    Ok(())
}

/// Decimals for tick labels about a tenth of `span` apart.
fn tick_decimals(span: f64) -> usize {
    if !(span.is_finite() && span > 0.0) {
        return 3;
    }
    (-(span / 10.0).log10()).ceil().clamp(0.0, 9.0) as usize
}

fn tick_label(v: f64, decimals: usize) -> String {
    let s = format!("{v:.decimals$}");
    if s.trim_start_matches('-')
        .chars()
        .all(|c| c == '0' || c == '.')
    {
        s.trim_start_matches('-').to_string()
    } else {
        s
    }
}

/// A log-axis label: 1000, 10, 0.01.
fn log_label(v: f64) -> String {
    if v >= 1.0 || v <= 0.0 || !v.is_finite() {
        format!("{v:.0}")
    } else {
        let d = (-v.log10()).ceil().clamp(0.0, 12.0) as usize;
        format!("{v:.d$}")
    }
}

/// A limit for a title: 0.8, not 0.79998779296875.
fn short(v: f64) -> String {
    let s = format!("{v:.3}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

fn kv_table(text: &str, keep: impl Fn(&str) -> bool) -> String {
    let mut s = String::from("<table>");
    for (k, v) in key_values(text).filter(|(k, _)| keep(k)) {
        let _ = write!(s, "<tr><th>{}</th><td>{}</td></tr>", esc(k), esc(v));
    }
    s.push_str("</table>");
    s
}

/// The one-page report.
fn report_html(
    run: &Run<'_>,
    figs: &[Figure],
    analysis: &str,
    stats: Option<&str>,
    summaries: &[(String, String)],
) -> String {
    let mut h = String::from(
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>hapticctrl run report</title><style>\
         body{font-family:sans-serif;margin:1em 2em;color:#222}h1{font-size:1.4em}h2{font-size:1.1em;margin-top:1.2em}\
         table{border-collapse:collapse;font-size:0.85em;margin:0.3em 1.5em 0.3em 0;vertical-align:top;display:inline-table}\
         th,td{border:1px solid #ccc;padding:2px 6px;text-align:left}th{background:#f4f4f4;font-weight:normal}\
         img{width:100%;max-width:1400px;border:1px solid #ddd;margin:0.3em 0}.warn{color:#b00}</style></head><body>",
    );
    let c = &run.continuity;
    let _ = write!(
        h,
        "<h1>hapticctrl run report</h1><p>{} servo records, cycles {}..={} ({:.1} s at {} µs).",
        run.recs.len(),
        c.first_cycle.unwrap_or(0),
        c.last_cycle.unwrap_or(0),
        run.span().1 - run.span().0,
        run.period_us
    );
    if c.dropped > 0 {
        let _ = write!(
            h,
            " <b class=\"warn\">{} records dropped by the ring (nobody read fast enough): the plots have gaps there.</b>",
            c.dropped
        );
    } else {
        h.push_str(" No record dropped: the log covers every cycle.");
    }
    h.push_str("</p><h2>The run in figures</h2><p>Marker colours on every time axis: power (green), session (blue), link (orange), degraded (purple), misses (red), fail-safe (black), dropped records (grey).</p>");
    h.push_str(&kv_table(analysis, |_| true));
    for (name, text) in summaries {
        let _ = write!(h, "<table><tr><th colspan=2>{}</th></tr>", esc(name));
        for (k, v) in key_values(text) {
            let _ = write!(h, "<tr><th>{}</th><td>{}</td></tr>", esc(k), esc(v));
        }
        h.push_str("</table>");
    }
    if let Some(st) = stats {
        let keys = [
            "period_us",
            "cycles",
            "misses",
            "max_consecutive_misses",
            "degraded_cycles",
            "fail_safe",
            "wakeup.p50_us",
            "wakeup.p99_us",
            "wakeup.max_ns",
            "exec.p99_us",
            "exec.max_ns",
            "jitter.p99_us",
            "frames_in",
            "answers_sent",
            "answers_dropped",
            "vpr_extrapolated",
            "sessions_opened",
            "simlog.dropped",
            "state",
        ];
        h.push_str("<table><tr><th colspan=2>module (/dev/hap_stats)</th></tr>");
        for (k, v) in key_values(st).filter(|(k, _)| keys.contains(k)) {
            let _ = write!(h, "<tr><th>{}</th><td>{}</td></tr>", esc(k), esc(v));
        }
        h.push_str("</table>");
    }
    for f in figs {
        let _ = write!(
            h,
            "<h2>{}</h2><a href=\"{n}.svg\"><img src=\"{n}.png\" alt=\"{t}\"></a>",
            esc(&f.title),
            n = f.name,
            t = esc(&f.title)
        );
    }
    h.push_str("<h2>Events</h2><table><tr><th>cycle</th><th>time (s)</th><th>event</th><th>count</th></tr>");
    let n = run.events.len();
    for (i, e) in run.events.iter().enumerate() {
        if i == 200 && n > 220 {
            let _ = write!(
                h,
                "<tr><td colspan=4>… {} more in events.csv</td></tr>",
                n - 200
            );
            break;
        }
        let _ = write!(
            h,
            "<tr><td>{}</td><td>{:.3}</td><td>{}</td><td>{}</td></tr>",
            e.cycle,
            e.t,
            esc(&e.kind.label()),
            e.count
        );
    }
    h.push_str("</table><p>Time axis: servo time since insmod (cycle × period). Markers: power (green), session (blue), link (orange), degraded (purple), misses (red), fail-safe (black), dropped records (grey).</p></body></html>\n");
    h
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn felt_stiffness_is_force_over_the_distance_to_the_object_in_contact() {
        let mut r = LogRecord::ZERO;
        r.flags = log_flags::COUPLED;
        r.vpr_position = Vec3::from_f64([0.5, 0.0, 0.3]);
        // 5 N at 4.4 mm: 1.136 N/mm; a fast cycle and an uncoupled one are
        // not contacts.
        r.handle_position_client = Vec3::from_f64([0.5, 0.0, 0.3 - 0.0044]);
        r.coupling_force = Vec3::from_f64([0.0, 0.0, 5.0]);
        let mut fast = r;
        fast.handle_velocity = Vec3::from_f64([0.5, 0.0, 0.0]);
        let mut free = r;
        free.flags = 0;
        let (lo, med, hi, n) = felt_stiffness(&[r, r, fast, free]).expect("contacts");
        assert_eq!(n, 2);
        assert!(
            (med - 5.0 / 4.4).abs() < 1e-3 && lo == med && hi == med,
            "{med}"
        );
        assert!(felt_stiffness(&[fast, free]).is_none());
    }
    use hap_core::fixed::Vec3;
    use hap_core::position_log::LogTiming;
    use hap_core::vp::alarm;

    const PERIOD_US: u32 = 1000;

    /// A scripted run: power on at 100, session at 200 (VPr from 210),
    /// fading from 700 to 760, a degraded span 400..410 after a late cycle
    /// at 399, a missed tick before 500, power off at 900, records 950..=959
    /// dropped, fail-safe steps after cycle 999.
    fn scripted() -> Vec<LogRecord> {
        let mut v = Vec::new();
        for c in 0..1000u64 {
            if (950..960).contains(&c) {
                continue;
            }
            let mut r = LogRecord::ZERO;
            r.cycle = c;
            r.time_us = c * u64::from(PERIOD_US);
            let tick = if c >= 500 { c + 2 } else { c + 1 };
            r.timing = LogTiming {
                tick,
                start_ns: c * 1_000_000,
                wakeup_ns: 20_000,
                exec_ns: if c == 399 { 900_000 } else { 30_000 },
                session: if (200..800).contains(&c) { 7 } else { 0 },
            };
            if (100..900).contains(&c) {
                r.status |= status::POWER_ON | status::MOTORS_ENABLED;
            }
            if (210..800).contains(&c) {
                r.vpr_age_cycles = 0;
                r.vpr_position = Vec3::from_f64([0.1, 0.0, (c as f64) * 1e-4]);
            }
            if (700..760).contains(&c) {
                r.status |= status::LINK_FADING;
                r.link_gain = Fx::from_f64(0.5);
                r.vpr_age_cycles = 60;
            } else if (210..800).contains(&c) {
                r.link_gain = Fx::ONE;
            }
            if (400..410).contains(&c) {
                r.mode = Mode::Degraded;
                r.alarms |= alarm::DEADLINE_MISS;
            }
            // A force peak of 19 N next to a user force of 3 mN.
            let f = if c == 600 {
                19.0
            } else {
                (c as f64 * 0.01).sin()
            };
            r.coupling_force = Vec3::from_f64([f, -f / 2.0, 0.1]);
            r.user_wrench[0] = Fx::from_f64(0.003);
            r.handle_velocity = Vec3::from_f64([0.01 * (c as f64 * 0.02).cos(), 0.0, 0.0]);
            r.handle_position_client = Vec3::from_f64([0.1, 0.02, -0.3 + c as f64 * 1e-4]);
            r.motor_torque[1] = Fx::from_f64(if c == 300 { 19.9 } else { 2.0 });
            r.torque_command[1] = Fx::from_f64(if c == 300 { 25.0 } else { 2.0 });
            v.push(r);
        }
        let last = *v.last().unwrap();
        for step in 1..=5u8 {
            let mut r = last;
            r.mode = Mode::FailSafe;
            r.fail_safe_step = step;
            r.timing.tick = last.timing.tick + 1;
            v.push(r);
        }
        v
    }

    fn at(run: &Run<'_>, kind: EventKind) -> Vec<u64> {
        run.events
            .iter()
            .filter(|e| e.kind == kind)
            .map(|e| e.cycle)
            .collect()
    }

    #[test]
    fn each_event_is_found_at_its_cycle() {
        let recs = scripted();
        let run = Run::new(&recs, PERIOD_US, 0);
        assert_eq!(at(&run, EventKind::PowerOn), vec![100]);
        assert_eq!(at(&run, EventKind::PowerOff), vec![900]);
        assert_eq!(at(&run, EventKind::SessionOpen), vec![200]);
        assert_eq!(at(&run, EventKind::SessionClose), vec![800]);
        assert_eq!(at(&run, EventKind::LinkFading), vec![700]);
        assert_eq!(at(&run, EventKind::LinkRestored), vec![760]);
        assert_eq!(at(&run, EventKind::DegradedEnter), vec![400]);
        assert_eq!(at(&run, EventKind::DegradedExit), vec![410]);
        // The late cycle and the missed tick before cycle 500.
        assert_eq!(at(&run, EventKind::Miss), vec![399, 500]);
        assert_eq!(run.misses(), 2);
        assert_eq!(at(&run, EventKind::Dropped), vec![950]);
        let fs: Vec<(u64, EventKind)> = run
            .events
            .iter()
            .filter(|e| matches!(e.kind, EventKind::FailSafeStep(_)))
            .map(|e| (e.cycle, e.kind))
            .collect();
        assert_eq!(fs.len(), 5);
        assert!(fs.iter().all(|(c, _)| *c == 1000), "{fs:?}");
        for e in &run.events {
            assert!((e.t - e.cycle as f64 * 1e-3).abs() < 1e-9, "{e:?}");
        }
    }

    #[test]
    fn link_gain_figures_cover_the_cycles_with_a_vpr_in_session() {
        let recs = scripted();
        let text = Run::new(&recs, PERIOD_US, 0).summary_text(None);
        // 210..800 powered in session with a VPr; 700..760 at half gain, 60
        // cycles old: one fade.
        assert!(text.contains("link_cycles: 590\n"), "{text}");
        assert!(text.contains("link_fades: 1\n"), "{text}");
        assert!(
            text.contains(&format!("link_full_gain_fraction: {:.6}\n", 530.0 / 590.0)),
            "{text}"
        );
        assert!(text.contains("link_gain_min: 0.500000\n"), "{text}");
        assert!(text.contains("vpr_age_max_ms: 60.000\n"), "{text}");
    }

    #[test]
    fn a_log_with_dropped_records_says_how_many() {
        let recs = scripted();
        let run = Run::new(&recs, PERIOD_US, 0);
        assert_eq!(run.continuity.dropped, 10);
        assert_eq!(run.continuity.fail_safe, 5);
        let text = run.summary_text(None);
        assert!(text.contains("dropped_records: 10\n"), "{text}");
        let ev = at(&run, EventKind::Dropped);
        assert_eq!(ev, vec![950]);
        let e = run
            .events
            .iter()
            .find(|e| e.kind == EventKind::Dropped)
            .unwrap();
        assert_eq!(e.count, 10);
        // A whole log: nothing dropped.
        let full: Vec<LogRecord> = recs.iter().filter(|r| r.cycle < 950).copied().collect();
        assert_eq!(Run::new(&full, PERIOD_US, 0).continuity.dropped, 0);
    }

    #[test]
    fn every_axis_range_holds_every_plotted_sample() {
        let recs = scripted();
        let run = Run::new(&recs, PERIOD_US, 0);
        let figs = run.figures();
        let names: Vec<&str> = figs.iter().map(|f| f.name.as_str()).collect();
        for n in [
            "trajectory",
            "forces",
            "torques",
            "speed",
            "energy",
            "events",
            "timing",
        ] {
            assert!(names.contains(&n), "{n} missing from {names:?}");
        }
        let mut checked = 0usize;
        for f in &figs {
            for p in &f.panels {
                for l in &p.lines {
                    // The full series and what is drawn after reduction.
                    let bars: Vec<(f64, f64)> = range_bars(&l.points)
                        .into_iter()
                        .flat_map(|(x, lo, hi)| [(x, lo), (x, hi)])
                        .collect();
                    for (x, y) in l.points.iter().chain(reduce(&l.points).iter()).chain(&bars) {
                        assert!(
                            (f.x.0..=f.x.1).contains(x),
                            "{}/{}/{}: x {x} outside {:?}",
                            f.name,
                            p.title,
                            l.name,
                            f.x
                        );
                        if !y.is_finite() {
                            continue;
                        }
                        // A log axis draws what is below its floor (0
                        // included) on the floor, as `draw_content` does.
                        let y = &if p.log_y { y.max(p.y.0) } else { *y };
                        assert!(
                            (p.y.0..=p.y.1).contains(y),
                            "{}/{}/{}: y {y} outside {:?}",
                            f.name,
                            p.title,
                            l.name,
                            p.y
                        );
                        checked += 1;
                    }
                }
                for (lim, _) in &p.hlines {
                    assert!((p.y.0..=p.y.1).contains(lim), "{}: limit {lim}", p.title);
                }
            }
            for m in &f.markers {
                assert!((f.x.0..=f.x.1).contains(&m.t), "{}: marker {m:?}", f.name);
            }
        }
        assert!(checked > 10_000, "{checked}");
        // The 19 N peak is inside the coupling panel, and the user's 3 mN
        // have a panel of their own (not flattened against 19 N).
        let forces = figs.iter().find(|f| f.name == "forces").unwrap();
        assert!(forces.panels[0].y.1 >= 19.0);
        assert!(forces.panels[1].y.1 < 0.01, "{:?}", forces.panels[1].y);
        // The torque limits are on the torque axes.
        let tq = figs.iter().find(|f| f.name == "torques").unwrap();
        assert!(tq.panels[1].y.1 >= 25.0 && tq.panels[1].y.0 <= -20.0);
    }

    /// Fail-safe steps written while SERVO held its data (a hung cycle):
    /// their servo fields are unknown and 0 in the record. The analysis
    /// places them by their tick, draws only what they carry (the torques
    /// at the motors), and never a pose, force or speed of 0.
    #[test]
    fn fail_safe_steps_with_unknown_pose_are_not_drawn_as_a_pose() {
        use hap_core::servo::log_flags::POSE_UNKNOWN;
        let mut recs = scripted();
        let last_tick = recs
            .iter()
            .filter(|r| r.mode != Mode::FailSafe)
            .map(|r| r.timing.tick)
            .max()
            .unwrap();
        for r in recs.iter_mut().filter(|r| r.mode == Mode::FailSafe) {
            let step = r.fail_safe_step;
            *r = LogRecord::ZERO;
            r.mode = Mode::FailSafe;
            r.fail_safe_step = step;
            r.flags = POSE_UNKNOWN;
            r.timing.tick = last_tick + u64::from(step);
        }
        let run = Run::new(&recs, PERIOD_US, 0);
        let fs: Vec<u64> = run
            .events
            .iter()
            .filter(|e| matches!(e.kind, EventKind::FailSafeStep(_)))
            .map(|e| e.cycle)
            .collect();
        assert_eq!(fs, vec![1000, 1001, 1002, 1003, 1004]);
        let figs = run.figures();
        let servo_t: Vec<f64> = run.t.clone();
        for f in figs
            .iter()
            .filter(|f| f.name != "events" && f.name != "torques")
        {
            for p in &f.panels {
                for l in &p.lines {
                    for (x, _) in l.points.iter().filter(|q| q.1.is_finite()) {
                        assert!(
                            servo_t.contains(x),
                            "{}/{}/{}: a point at {x} s, not a servo cycle",
                            f.name,
                            p.title,
                            l.name
                        );
                    }
                }
            }
        }
        // The handle sits at x = 0.1 all run: a pose of 0 would pull the
        // axis down to 0.
        let traj = figs.iter().find(|f| f.name == "trajectory").unwrap();
        assert!(traj.panels[0].y.0 > 0.05, "{:?}", traj.panels[0].y);
        // The torques the motors applied at each step are drawn, at their
        // steps' times.
        let tq = figs.iter().find(|f| f.name == "torques").unwrap();
        let at_steps = tq.panels[1]
            .lines
            .iter()
            .find(|l| l.name == "applied at fail-safe steps")
            .unwrap();
        let want: Vec<(f64, f64)> = fs.iter().map(|c| (*c as f64 * 1e-3, 0.0)).collect();
        assert_eq!(at_steps.points.len(), 5);
        for (got, want) in at_steps.points.iter().zip(&want) {
            assert!((got.0 - want.0).abs() < 1e-9 && got.1 == want.1, "{got:?}");
        }
        // A log holding only such steps still places them by their tick.
        let only: Vec<LogRecord> = recs
            .iter()
            .filter(|r| r.mode == Mode::FailSafe)
            .copied()
            .collect();
        let run = Run::new(&only, PERIOD_US, 0);
        assert_eq!(run.events.first().map(|e| e.cycle), Some(last_tick));
    }

    /// What the bitmap shows: a wide line with sharp reversals (the
    /// commanded torque of a chattering joint) stays within its axis. Its
    /// pixels lie between the rows of the two limit lines drawn at the
    /// data's extremes (a joined wide polyline put miter spikes far past
    /// them, out of the panel).
    #[test]
    fn a_wide_zigzag_stays_inside_its_axis() {
        register_font();
        let colour = RGBColor(120, 160, 255);
        let pts: Vec<(f64, f64)> = (0..400)
            .map(|i| (i as f64 * 1e-3, if i % 2 == 0 { 1.0 } else { -1.0 }))
            .collect();
        let mut line = Line::new("zigzag", colour, pts);
        line.width = 4;
        let panel = Panel::fit(
            "zigzag",
            "N·m",
            vec![line],
            vec![(1.0, "+".into()), (-1.0, "-".into())],
        );
        let fig = Figure {
            name: "zigzag".into(),
            title: "zigzag".into(),
            x_label: "s".into(),
            x: (0.0, 0.4),
            panels: vec![panel],
            markers: vec![],
            columns: 1,
        };
        let (w, h) = (800u32, 400u32);
        let mut buf = vec![0u8; (w * h * 3) as usize];
        {
            let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
            draw_figure(&root, &fig).unwrap();
            root.present().unwrap();
        }
        let px = |x: u32, y: u32| {
            let i = ((y * w + x) * 3) as usize;
            (buf[i], buf[i + 1], buf[i + 2])
        };
        let rows_of = |c: (u8, u8, u8)| -> Vec<u32> {
            (0..h).filter(|y| (0..w).any(|x| px(x, *y) == c)).collect()
        };
        // The limit lines: grey rows (the widest grey runs).
        let grey = (110u8, 110u8, 110u8);
        let limit_rows: Vec<u32> = (0..h)
            .filter(|y| (0..w).filter(|x| px(*x, *y) == grey).count() > (w / 2) as usize)
            .collect();
        let (top, bottom) = (*limit_rows.first().unwrap(), *limit_rows.last().unwrap());
        assert!(bottom > top + 100, "{limit_rows:?}");
        let rows = rows_of((colour.0, colour.1, colour.2));
        assert!(!rows.is_empty(), "the line is drawn");
        // Half the width (2 px) on either side of a limit, and the
        // legend's sample (drawn inside the panel).
        for y in rows {
            assert!(
                y + 3 >= top && y <= bottom + 3,
                "line pixel at row {y}, limits at rows {top}..{bottom}"
            );
        }
    }

    #[test]
    fn histogram_buckets_are_one_microsecond_wide() {
        let s = hist_steps(&[(5.0, 10.0), (3.0, 2.0), (4.0, 7.0)], 0.5);
        assert_eq!(
            s,
            vec![
                (3.0, 0.5),
                (3.0, 2.0),
                (4.0, 2.0),
                (4.0, 7.0),
                (5.0, 7.0),
                (5.0, 10.0),
                (6.0, 10.0),
                (6.0, 0.5)
            ]
        );
        let s = hist_steps(&[(2.0, 4.0), (40.0, 1.0)], 0.5);
        assert!(s.contains(&(3.0, 0.5)) && s.contains(&(40.0, 0.5)) && s.contains(&(41.0, 1.0)));
        assert_eq!(log_label(10000.0), "10000");
        assert_eq!(log_label(0.01), "0.01");
    }

    #[test]
    fn reduction_keeps_the_peaks() {
        let pts: Vec<(f64, f64)> = (0..100_000)
            .map(|i| (i as f64, if i == 54_321 { 1e3 } else { (i as f64).sin() }))
            .collect();
        let r = reduce(&pts);
        assert!(r.len() <= MAX_POINTS + 2, "{}", r.len());
        assert!(r.contains(&(54_321.0, 1e3)));
        assert!(r.windows(2).all(|w| w[0].0 <= w[1].0));
    }

    /// What is drawn: the SVG of the events figure has a marker line at the
    /// pixel column of each event's time.
    #[test]
    fn markers_are_drawn_at_their_cycles() {
        register_font();
        let recs = scripted();
        let run = Run::new(&recs, PERIOD_US, 0);
        let figs = run.figures();
        let f = figs.iter().find(|f| f.name == "speed").unwrap();
        let dir = std::env::temp_dir().join(format!("hapctl-analyze-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("speed.svg");
        render_file(&p, f).unwrap();
        let svg = std::fs::read_to_string(&p).unwrap();
        // Marker polylines: two points with the same x, in the marker
        // colour at the marker opacity.
        let mut xs: Vec<(String, f64)> = Vec::new();
        for part in svg.split("<polyline").skip(1) {
            let attr = |name: &str| {
                part.split(&format!("{name}=\""))
                    .nth(1)
                    .and_then(|s| s.split('"').next())
                    .map(str::to_string)
            };
            if attr("opacity").as_deref() != Some("0.55") {
                continue;
            }
            let (Some(stroke), Some(pts)) = (attr("stroke"), attr("points")) else {
                continue;
            };
            let v: Vec<(f64, f64)> = pts
                .split_whitespace()
                .filter_map(|q| {
                    let (a, b) = q.split_once(',')?;
                    Some((a.parse().ok()?, b.parse().ok()?))
                })
                .collect();
            if v.len() == 2 && v[0].0 == v[1].0 && v[0].1 != v[1].1 {
                xs.push((stroke.to_uppercase(), v[0].0));
            }
        }
        // Every panel has every marker: check the first panel's.
        assert_eq!(xs.len(), f.markers.len() * f.panels.len(), "{xs:?}");
        xs.truncate(f.markers.len());
        // Each in its kind's colour; pixel x linear in time (fit on the
        // first and last event, check all).
        for (m, (stroke, _)) in f.markers.iter().zip(&xs) {
            let c = m.kind.colour();
            assert_eq!(
                *stroke,
                format!("#{:02X}{:02X}{:02X}", c.0, c.1, c.2),
                "{m:?}"
            );
        }
        let a = &f.markers[0];
        let b = f.markers.last().unwrap();
        let xa = xs[0].1;
        let xb = xs[xs.len() - 1].1;
        assert!(xb > xa);
        for (m, (_, x)) in f.markers.iter().zip(&xs) {
            let want = xa + (m.t - a.t) / (b.t - a.t) * (xb - xa);
            assert!(
                (x - want).abs() <= 1.0,
                "{:?} at {x}, expected {want}",
                m.kind
            );
        }
        // And the event times are their cycles: power on at cycle 100 lies
        // 100/1000 of the way from cycle 0 along the axis (x from 0 s).
        let on = f
            .markers
            .iter()
            .position(|m| m.kind == EventKind::PowerOn)
            .unwrap();
        assert!((f.markers[on].t - 0.1).abs() < 1e-12);
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn analyze_writes_the_figures_and_the_report() {
        let recs = scripted();
        let dir = std::env::temp_dir().join(format!("hapctl-analyze-run-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let log = dir.join("sim.bin");
        let mut bytes = Vec::new();
        for r in &recs {
            let mut b = [0u8; LogRecord::SIZE];
            r.encode(&mut b);
            bytes.extend_from_slice(&b);
        }
        std::fs::write(&log, &bytes).unwrap();
        let hist = dir.join("hist.txt");
        std::fs::write(
            &hist,
            "version: 1\nwakeup.hist_us.3: 900\nwakeup.hist_us.40: 2\nwakeup.hist_overflow: 1\nexec.hist_us.10: 902\n",
        )
        .unwrap();
        let summ = dir.join("summary.txt");
        std::fs::write(&summ, "sample_rate_hz: 333\nloss_ratio: 0.001\n").unwrap();
        let out = dir.join("plots");
        run(
            &log,
            &out,
            &Inputs {
                stats: None,
                hist: Some(&hist),
                summaries: &[summ],
            },
        )
        .unwrap();
        for n in [
            "trajectory",
            "forces",
            "torques",
            "speed",
            "energy",
            "events",
            "timing",
            "latency_hist",
        ] {
            for ext in ["png", "svg"] {
                let p = out.join(format!("{n}.{ext}"));
                assert!(
                    std::fs::metadata(&p).unwrap().len() > 1000,
                    "{}",
                    p.display()
                );
            }
        }
        let html = std::fs::read_to_string(out.join("summary.html")).unwrap();
        assert!(
            html.contains("10 records dropped"),
            "dropped records not reported"
        );
        assert!(html.contains("sample_rate_hz") && html.contains("latency_hist.png"));
        assert!(html.contains("fail-safe 5/5: release the resources"));
        let a = std::fs::read_to_string(out.join("analysis.txt")).unwrap();
        assert!(a.contains("dropped_records: 10"));
        assert!(a.contains("misses_located: 2"));
        // A file of the old layout is refused with a clear message.
        std::fs::write(&log, [0u8; 288]).unwrap();
        let e = run(&log, &out, &Inputs::default()).unwrap_err();
        assert!(e.contains("version-2"), "{e}");
        if std::env::var_os("HAPCTL_KEEP_TEST_OUTPUT").is_none() {
            std::fs::remove_dir_all(&dir).ok();
        }
    }
}
