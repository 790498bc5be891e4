//! Simulator I/O: effort sequences (validated with hap-core's parser before
//! they go to the device), live effort lines, and the binary position log
//! (`hap_core::simulator::LogRecord`, decoded by hap-core).

use std::fs::File;
use std::io::{BufWriter, Read, Write};
use std::path::Path;

use hap_core::effort::{parse_effort_sequence, parse_milli, EffortKeyframe, EFFORT_CAPACITY};
use hap_core::simulator::LogRecord;

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
pub const CSV_HEADER: &str = "cycle,flags,status,alarms,hx,hy,hz,qx,qy,qz,qw,user_fx,user_fy,user_fz,user_tx,user_ty,user_tz,coupling_force,po_energy";

pub fn csv_row(r: &LogRecord) -> String {
    let h = r.handle_position.to_f64();
    let q: Vec<String> = r
        .handle_orientation
        .iter()
        .map(|v| format!("{:.6}", v.to_f64()))
        .collect();
    let u: Vec<String> = r
        .user_wrench
        .iter()
        .map(|v| format!("{:.4}", v.to_f64()))
        .collect();
    format!(
        "{},{},{},{},{:.6},{:.6},{:.6},{},{},{:.4},{:.6}",
        r.cycle,
        r.flags,
        r.status,
        r.alarms,
        h[0],
        h[1],
        h[2],
        q.join(","),
        u.join(","),
        r.coupling_force.to_f64(),
        r.po_energy.to_f64()
    )
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

/// Read records from `dev` until EOF or `cycles` records; write them raw to
/// `out` (or as CSV on stdout).
pub fn capture(dev: &Path, out: Option<&Path>, cycles: Option<u64>) -> Result<(), String> {
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
    let limit = cycles.unwrap_or(u64::MAX);
    'outer: while n < limit {
        let got = match f.read(&mut buf) {
            Ok(0) => break,
            Ok(k) => k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(format!("{}: read: {e}", dev.display())),
        };
        pending.extend_from_slice(&buf[..got]);
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
                    n += 1;
                }
                Err(_) => bad += 1,
            }
        }
        pending.drain(..whole);
        let _ = sink.flush();
    }
    sink.flush().map_err(|e| format!("write: {e}"))?;
    if let Some(p) = out {
        eprintln!(
            "hapctl: {n} records written to {}{}",
            p.display(),
            if bad > 0 {
                format!(" ({bad} undecodable skipped)")
            } else {
                String::new()
            }
        );
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
    }
}
