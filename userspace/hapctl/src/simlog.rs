//! Simulator I/O: effort sequences (validated with hap-core's parser before
//! they go to the device), live effort lines, and the binary position log
//! (`hap_core::position_log::LogRecord`, decoded by hap-core).

use std::fs::File;
use std::io::{BufWriter, Read, Write};
use std::path::Path;

use hap_core::effort::{parse_effort_sequence, parse_milli, EffortKeyframe, EFFORT_CAPACITY};
use hap_core::mode::Mode;
use hap_core::position_log::LogRecord;

/// Validate an effort sequence; returns a one-line summary.
pub fn validate_effort(text: &str) -> Result<String, String> {
    let mut keys = [EffortKeyframe::ZERO; EFFORT_CAPACITY];
    match parse_effort_sequence(text.as_bytes(), &mut keys) {
        Ok(n) => {
            let last = keys.get(n.saturating_sub(1)).map(|k| k.t_ms).unwrap_or(0);
            Ok(format!("{n} keyframes, {last} ms"))
        }
        Err(e) => Err(format!(
            "line {}, column {}: {:?} (format: Documentation/userguide.md, \"Effort sequences\")",
            e.line, e.column, e.kind
        )),
    }
}

/// The `live fx fy fz tx ty tz` line for `/dev/hap_effort`, each value
/// checked with hap-core's number parser (|v| ≤ 1000).
pub fn live_line(w: &[f64]) -> Result<String, String> {
    if w.len() != 6 {
        return Err(format!(
            "live effort needs 6 values (fx fy fz tx ty tz), got {}",
            w.len()
        ));
    }
    let mut s = String::from("live");
    for v in w {
        if !v.is_finite() {
            return Err(format!("{v}: not a finite number"));
        }
        let f = format!("{v:.4}");
        parse_milli(f.as_bytes()).map_err(|e| format!("{v}: {e:?} (|value| must be <= 1000)"))?;
        s.push(' ');
        s.push_str(&f);
    }
    s.push('\n');
    Ok(s)
}

/// CSV header matching [`csv_row`].
pub const CSV_HEADER: &str = "cycle,time_us,mode,fail_safe_step,flags,status,alarms,vpr_age_cycles,hx,hy,hz,qx,qy,qz,qw,vx,vy,vz,user_fx,user_fy,user_fz,user_tx,user_ty,user_tz,coupling_fx,coupling_fy,coupling_fz,po_energy,link_gain,tick,wakeup_ns,exec_ns,tau_cmd_1,tau_cmd_2,tau_cmd_3,tau_cmd_4,tau_cmd_5,tau_cmd_6,tau_applied_1,tau_applied_2,tau_applied_3,tau_applied_4,tau_applied_5,tau_applied_6";

/// A fail-safe step record written while SERVO held its data: its servo
/// fields (cycle, time, pose, speeds, forces, commanded torques) are
/// unknown, not zero.
pub fn pose_unknown(r: &LogRecord) -> bool {
    r.mode == Mode::FailSafe && r.flags & hap_core::servo::log_flags::POSE_UNKNOWN != 0
}

/// One CSV line of a record; the fields of a [`pose_unknown`] record that
/// it does not carry are left empty.
pub fn csv_row(r: &LogRecord) -> String {
    let unknown = pose_unknown(r);
    let f = |v: &[hap_core::fixed::Fx], prec: usize, valid: bool| -> String {
        v.iter()
            .map(|x| {
                if valid {
                    format!("{:.prec$}", x.to_f64())
                } else {
                    String::new()
                }
            })
            .collect::<Vec<_>>()
            .join(",")
    };
    let k = !unknown;
    let opt = |v: String| if k { v } else { String::new() };
    format!(
        "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
        opt(r.cycle.to_string()),
        opt(r.time_us.to_string()),
        r.mode.name(),
        r.fail_safe_step,
        r.flags,
        r.status,
        r.alarms,
        opt(r.vpr_age_cycles.to_string()),
        f(&r.handle_position.to_array(), 6, k),
        f(&r.handle_orientation, 6, k),
        f(&r.handle_velocity.to_array(), 5, k),
        f(&r.user_wrench, 4, k),
        f(&r.coupling_force.to_array(), 4, k),
        opt(format!("{:.6}", r.po_energy.to_f64())),
        opt(format!("{:.6}", r.link_gain.to_f64())),
        r.timing.tick,
        r.timing.wakeup_ns,
        r.timing.exec_ns,
        f(&r.torque_command, 4, k),
        f(&r.motor_torque, 4, true)
    )
}

/// Continuity of a position log: the servo writes one record per cycle
/// with consecutive cycle numbers, so a gap is records the ring dropped.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Continuity {
    /// Records in the log (servo cycles and fail-safe steps).
    pub records: u64,
    /// Fail-safe step records.
    pub fail_safe: u64,
    /// Of those, records whose servo fields are unknown (SERVO held its
    /// data as the step ran: [`pose_unknown`]).
    pub pose_unknown: u64,
    /// Cycles missing between consecutive servo records (dropped by the ring).
    pub dropped: u64,
    /// Times the cycle count went back (module reloaded: a new run).
    pub restarts: u64,
    /// First and last servo cycle seen.
    pub first_cycle: Option<u64>,
    pub last_cycle: Option<u64>,
}

impl Continuity {
    /// Account for the next record.
    pub fn add(&mut self, r: &LogRecord) {
        self.records = self.records.saturating_add(1);
        if r.mode == Mode::FailSafe {
            self.fail_safe = self.fail_safe.saturating_add(1);
            if pose_unknown(r) {
                self.pose_unknown = self.pose_unknown.saturating_add(1);
            }
            return;
        }
        if let Some(last) = self.last_cycle {
            if r.cycle > last {
                self.dropped = self.dropped.saturating_add(r.cycle - last - 1);
            } else {
                self.restarts = self.restarts.saturating_add(1);
            }
        } else {
            self.first_cycle = Some(r.cycle);
        }
        self.last_cycle = Some(r.cycle);
    }

    #[cfg_attr(not(feature = "analyze"), allow(dead_code))]
    pub fn of(recs: &[LogRecord]) -> Continuity {
        let mut c = Continuity::default();
        for r in recs {
            c.add(r);
        }
        c
    }

    /// `key: value` lines.
    pub fn text(&self) -> String {
        let opt = |v: Option<u64>| v.map(|c| c.to_string()).unwrap_or_else(|| "-".into());
        format!(
            "records: {}\nfirst_cycle: {}\nlast_cycle: {}\ndropped_records: {}\nfail_safe_records: {}\nfail_safe_pose_unknown: {}\nrestarts: {}\n",
            self.records,
            opt(self.first_cycle),
            opt(self.last_cycle),
            self.dropped,
            self.fail_safe,
            self.pose_unknown,
            self.restarts
        )
    }
}

#[cfg_attr(not(feature = "analyze"), allow(dead_code))]
/// Decode whole records from a byte buffer (a trailing partial record is
/// ignored; undecodable records are counted).
pub fn decode_all(bytes: &[u8]) -> (Vec<LogRecord>, usize) {
    let mut out = Vec::new();
    let mut bad = 0;
    for chunk in bytes.chunks_exact(LogRecord::SIZE) {
        let mut a = [0u8; LogRecord::SIZE];
        a.copy_from_slice(chunk);
        match LogRecord::decode(&a) {
            Ok(r) => out.push(r),
            Err(_) => bad += 1,
        }
    }
    (out, bad)
}

/// Drain `dev` until end of file (the fail-safe closes the log once it is
/// read) or `cycles` records: raw records to `out` (flushed after every
/// read, so the file is whole up to the last read if the reader is killed),
/// else CSV on stdout. At the end, prints the log's continuity (records,
/// records the ring dropped) and the module's own `simlog.dropped` count
/// from `stats` if it can be read, to stderr and to `summary` if given.
pub fn capture(
    dev: &Path,
    out: Option<&Path>,
    cycles: Option<u64>,
    stats: &Path,
    summary: Option<&Path>,
) -> Result<(), String> {
    let mut f =
        File::open(dev).map_err(|e| format!("{}: {e} (is the module loaded?)", dev.display()))?;
    let mut sink: Box<dyn Write> = match out {
        Some(p) => Box::new(BufWriter::new(
            File::create(p).map_err(|e| format!("{}: {e}", p.display()))?,
        )),
        None => {
            println!("{CSV_HEADER}");
            Box::new(BufWriter::new(std::io::stdout()))
        }
    };
    let mut buf = vec![0u8; LogRecord::SIZE * 64];
    let mut pending: Vec<u8> = Vec::new();
    let mut n: u64 = 0;
    let mut bad = 0usize;
    let mut cont = Continuity::default();
    let limit = cycles.unwrap_or(u64::MAX);
    'outer: while n < limit {
        let got = match f.read(&mut buf) {
            Ok(0) => break,
            Ok(k) => k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(format!("{}: read: {e}", dev.display())),
        };
        pending.extend_from_slice(buf.get(..got).unwrap_or(&[]));
        let whole = pending.len() / LogRecord::SIZE * LogRecord::SIZE;
        for chunk in pending[..whole].chunks_exact(LogRecord::SIZE) {
            if n >= limit {
                break;
            }
            let mut a = [0u8; LogRecord::SIZE];
            a.copy_from_slice(chunk);
            match LogRecord::decode(&a) {
                Ok(r) => {
                    let w = if out.is_some() {
                        sink.write_all(chunk)
                    } else {
                        writeln!(sink, "{}", csv_row(&r))
                    };
                    if w.is_err() {
                        break 'outer;
                    }
                    cont.add(&r);
                    n += 1;
                }
                Err(_) => bad += 1,
            }
        }
        pending.drain(..whole);
        if sink.flush().is_err() {
            break;
        }
    }
    sink.flush().map_err(|e| format!("write: {e}"))?;
    let mut text = cont.text();
    text.push_str(&format!("undecodable_records: {bad}\n"));
    if let Ok(st) = std::fs::read_to_string(stats) {
        for (k, v) in hap_core::stats::key_values(&st) {
            if k.starts_with("simlog.") {
                text.push_str(&format!("module.{k}: {v}\n"));
            }
        }
    }
    if let Some(p) = summary {
        std::fs::write(p, &text).map_err(|e| format!("{}: {e}", p.display()))?;
    }
    for line in text.lines() {
        eprintln!("hapctl log: {line}");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn effort_validation() {
        assert!(validate_effort("0 0 0 0 0 0 0 1\n500 1.5 0 0 0 0 0\n")
            .unwrap()
            .starts_with("2 keyframes, 500 ms"));
        let e = validate_effort("0 0 0 0 0 0 0\n10 x 0 0 0 0 0\n").unwrap_err();
        assert!(e.contains("line 2"), "{e}");
        assert!(validate_effort("# nothing\n").is_err());
    }

    #[test]
    fn live_lines() {
        assert_eq!(
            live_line(&[1.0, 0.0, -2.5, 0.0, 0.0, 0.1]).unwrap(),
            "live 1.0000 0.0000 -2.5000 0.0000 0.0000 0.1000\n"
        );
        assert!(live_line(&[1e6, 0.0, 0.0, 0.0, 0.0, 0.0]).is_err());
        assert!(live_line(&[f64::NAN, 0.0, 0.0, 0.0, 0.0, 0.0]).is_err());
        assert!(live_line(&[0.0]).is_err());
    }

    #[test]
    fn records_roundtrip() {
        let mut r = LogRecord::ZERO;
        r.cycle = 42;
        let mut b = [0u8; LogRecord::SIZE];
        r.encode(&mut b);
        let mut bytes = b.to_vec();
        bytes.extend_from_slice(&[0u8; LogRecord::SIZE]); // bad magic
        bytes.extend_from_slice(&[1, 2, 3]); // partial
        let (recs, bad) = decode_all(&bytes);
        assert_eq!((recs.len(), bad), (1, 1));
        assert_eq!(recs[0].cycle, 42);
        assert!(csv_row(&recs[0]).starts_with("42,"));
        let cols = CSV_HEADER.split(',').count();
        assert_eq!(csv_row(&recs[0]).split(',').count(), cols);
    }

    /// A fail-safe step written while SERVO held its data: its pose is
    /// unknown, and the CSV says so (empty fields), not 0; the torques the
    /// motors apply (read from the motor line) are there.
    #[test]
    fn unknown_pose_is_not_written_as_zero() {
        let mut r = LogRecord::ZERO;
        r.mode = Mode::FailSafe;
        r.fail_safe_step = 1;
        r.flags = hap_core::servo::log_flags::POSE_UNKNOWN;
        r.timing.tick = 77;
        r.motor_torque[2] = hap_core::fixed::Fx::from_f64(0.5);
        assert!(pose_unknown(&r));
        let c = Continuity::of(&[r, LogRecord { flags: 0, ..r }]);
        assert_eq!((c.fail_safe, c.pose_unknown), (2, 1));
        assert!(c.text().contains("fail_safe_pose_unknown: 1\n"));
        let row = csv_row(&r);
        let cols: Vec<&str> = row.split(',').collect();
        let head: Vec<&str> = CSV_HEADER.split(',').collect();
        assert_eq!(cols.len(), head.len(), "{row}");
        let col = |n: &str| cols[head.iter().position(|h| *h == n).unwrap()];
        for n in [
            "cycle",
            "time_us",
            "hx",
            "hy",
            "hz",
            "vx",
            "coupling_fx",
            "tau_cmd_1",
        ] {
            assert_eq!(col(n), "", "{n} in {row}");
        }
        assert_eq!(col("mode"), "fail_safe");
        assert_eq!(col("tick"), "77");
        assert_eq!(col("tau_applied_3"), "0.5000");
        // The same record from an idle SERVO (flag clear) has its pose.
        r.flags = 0;
        assert!(!pose_unknown(&r));
        assert_eq!(csv_row(&r).split(',').nth(8), Some("0.000000"));
    }
}
