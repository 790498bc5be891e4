//! hapdev: drive hapticctrl's devices directly, without the UDP bridge.
//!
//! ```text
//! hapdev send open|close|power on|off|cmd none|impedance|virtmech|vpr X Y Z  [--session S --seq N --ack]
//! hapdev send garbage N | badcrc | short          (hostile frames, for reject counters)
//! hapdev recv [--count N] [--timeout-ms T]         (decode answer frames from rtf_out)
//! hapdev couple --target X,Y,Z --ms N              (open, impedance, power on, stream VPr, report)
//! hapdev simlog [--count N] [--raw FILE]           (read position-log records)
//! hapdev replay-compare --effort F --load-cycle K --guest FILE  (bit-for-bit check)
//! hapdev hostile net --to 127.0.0.1:PORT --count N  (hostile datagrams at the bridge)
//! hapdev hostile dev --session S --count N          (hostile frames into rtf_in)
//! ```
//! Exit status: 0 on success, 1 on a failed check, 2 on bad usage or I/O error.

mod hostile;

use clap::{Parser, Subcommand};
use hap_core::{
    config::CommandType,
    cycle::ServoCycle,
    fixed::{Fx, Pose, Twist, Vec3},
    mode::Mode,
    position_log::LogRecord,
    protocol::{
        decode, encode, Frame, FrameHeader, FrameType, CTRL_ACK_REQUEST, MAGIC, MAX_FRAME_LEN,
        VERSION,
    },
    servo::{PowerRequest, ServoInputs},
};
use std::{
    fs::{File, OpenOptions},
    io::{Read, Write},
    os::unix::fs::OpenOptionsExt,
    process::ExitCode,
    time::{Duration, Instant},
};

#[derive(Parser)]
#[command(name = "hapdev", about = "Drive hapticctrl's char devices directly")]
struct Cli {
    /// The rtf_in device.
    #[arg(long, default_value = "/dev/hap_rtf_in")]
    rtf_in: String,
    /// The rtf_out device.
    #[arg(long, default_value = "/dev/hap_rtf_out")]
    rtf_out: String,
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Send one frame (or hostile bytes) to rtf_in.
    Send {
        #[arg(long, default_value_t = 0)]
        session: u16,
        #[arg(long, default_value_t = 1)]
        seq: u32,
        /// Ask for an Ack.
        #[arg(long)]
        ack: bool,
        /// open | close | power on|off | cmd none|impedance|virtmech | vpr X Y Z | garbage N | badcrc | short
        #[arg(num_args = 1.., required = true)]
        what: Vec<String>,
    },
    /// Read and decode frames from rtf_out.
    Recv {
        #[arg(long, default_value_t = 1)]
        count: u32,
        #[arg(long, default_value_t = 1000)]
        timeout_ms: u64,
    },
    /// Couple the arm to a virtual object held at TARGET for MS milliseconds.
    Couple {
        /// Virtual object position x,y,z in metres (client frame).
        #[arg(long, value_parser = parse_xyz, conflicts_with = "offset", required_unless_present = "offset")]
        target: Option<[f64; 3]>,
        /// Or: the object at the handle's first reported position plus dx,dy,dz.
        #[arg(long, value_parser = parse_xyz)]
        offset: Option<[f64; 3]>,
        #[arg(long, default_value_t = 2000)]
        ms: u64,
    },
    /// Read position-log records from /dev/hap_simlog (non-blocking: what is there).
    Simlog {
        #[arg(long, default_value = "/dev/hap_simlog")]
        dev: String,
        /// Stop after this many records (0: all available).
        #[arg(long, default_value_t = 0)]
        count: usize,
        /// Also write the raw records to this file.
        #[arg(long)]
        raw: Option<String>,
        /// Print one line per record.
        #[arg(long)]
        print: bool,
        /// Leave out the first N records from the summary (not from --raw).
        #[arg(long, default_value_t = 0)]
        skip: usize,
    },
    /// Hostile-input campaign: malformed/hostile frames built with hap-core,
    /// printing how many went to each counter (`expect.<counter>: n`).
    Hostile {
        /// `net` (UDP datagrams to the bridge from a stray source) or `dev`
        /// (frames written to rtf_in next to the live session).
        #[arg(value_parser = ["net", "dev"])]
        target: String,
        #[arg(long, default_value_t = 100_000)]
        count: u64,
        /// net: the bridge's address (loopback only).
        #[arg(long, required_if_eq("target", "net"))]
        to: Option<std::net::SocketAddr>,
        /// dev: the live session id (`session:` in /dev/hap_stats).
        #[arg(long, required_if_eq("target", "dev"))]
        session: Option<u16>,
        /// Average interval between two frames, µs (0: as fast as possible).
        #[arg(long, default_value_t = 1000)]
        interval_us: u64,
        #[arg(long, default_value_t = 0x5eed)]
        seed: u64,
    },
    /// Replay a scripted run through hap-core and compare with a guest log.
    ReplayCompare {
        /// The effort sequence loaded in the guest.
        #[arg(long)]
        effort: String,
        /// Servo cycle at which the guest loaded it (stats: effort_loaded_cycle).
        #[arg(long)]
        load_cycle: u64,
        /// Raw records read from /dev/hap_simlog.
        #[arg(long)]
        guest: String,
        #[arg(long, default_value_t = 1000)]
        period_us: u32,
    },
}

fn parse_xyz(s: &str) -> Result<[f64; 3], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|p| p.trim().parse::<f64>().map_err(|e| format!("'{p}': {e}")))
        .collect::<Result<_, _>>()?;
    match v.as_slice() {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok([*x, *y, *z]),
        _ => Err(format!("expected x,y,z (3 finite numbers), got '{s}'")),
    }
}

fn fx(v: f64) -> Fx {
    Fx::from_f64(v)
}

fn pose_at(p: [f64; 3]) -> Pose {
    Pose {
        position: Vec3 {
            x: fx(p[0]),
            y: fx(p[1]),
            z: fx(p[2]),
        },
        ..Pose::default()
    }
}

fn frame_bytes(h: &FrameHeader, f: &Frame) -> Vec<u8> {
    let mut buf = [0u8; MAX_FRAME_LEN];
    let n = encode(h, f, &mut buf);
    buf[..n].to_vec()
}

fn parse_frame(what: &[String]) -> Result<Frame, String> {
    let w: Vec<&str> = what.iter().map(String::as_str).collect();
    Ok(match w.as_slice() {
        ["open"] => Frame::OpenSession {
            client_nonce: 0x1234,
        },
        ["close"] => Frame::CloseSession,
        ["power", "on"] => Frame::PowerRequest(true),
        ["power", "off"] => Frame::PowerRequest(false),
        ["cmd", "none"] => Frame::SetCommandType(CommandType::None),
        ["cmd", "impedance"] => Frame::SetCommandType(CommandType::Impedance),
        ["cmd", "virtmech"] => Frame::SetCommandType(CommandType::VirtMech),
        ["vpr", x, y, z] => {
            let p = parse_xyz(&format!("{x},{y},{z}"))?;
            Frame::VprStream {
                pose: pose_at(p),
                twist: Twist::default(),
            }
        }
        _ => return Err(format!("unknown frame '{}'", w.join(" "))),
    })
}

/// Writes frames to rtf_in, one write each; returns how many were refused.
fn write_frames(dev: &str, frames: &[Vec<u8>]) -> Result<u32, String> {
    let mut f = OpenOptions::new()
        .write(true)
        .open(dev)
        .map_err(|e| format!("{dev}: {e}"))?;
    let mut refused = 0;
    for fr in frames {
        match f.write(fr) {
            Ok(n) if n == fr.len() => {}
            Ok(n) => return Err(format!("{dev}: short write {n}/{}", fr.len())),
            Err(e) if e.raw_os_error() == Some(libc::EINVAL) => refused += 1,
            Err(e) => return Err(format!("{dev}: {e}")),
        }
    }
    Ok(refused)
}

fn xorshift(x: &mut u64) -> u64 {
    *x ^= *x << 13;
    *x ^= *x >> 7;
    *x ^= *x << 17;
    *x
}

fn cmd_send(cli: &Cli, session: u16, seq: u32, ack: bool, what: &[String]) -> Result<(), String> {
    let h = FrameHeader {
        control: if ack { CTRL_ACK_REQUEST } else { 0 },
        session,
        seq,
        timestamp_us: 0,
    };
    let frames: Vec<Vec<u8>> = match what
        .iter()
        .map(String::as_str)
        .collect::<Vec<_>>()
        .as_slice()
    {
        ["garbage", n] => {
            let n: u32 = n.parse().map_err(|e| format!("garbage N: {e}"))?;
            let mut x = 0x9E37_79B9_7F4A_7C15u64;
            (0..n)
                .map(|i| {
                    // A request type's header and length (from hap-core's
                    // frame table) with random contents: they reach PROTO_IN.
                    let requests: Vec<FrameType> = FrameType::ALL
                        .iter()
                        .copied()
                        .filter(|t| t.is_request())
                        .collect();
                    let ty = requests[(xorshift(&mut x) % requests.len() as u64) as usize];
                    let len = ty.frame_len();
                    let mut b: Vec<u8> = (0..len).map(|_| xorshift(&mut x) as u8).collect();
                    b[..2].copy_from_slice(&MAGIC);
                    b[2] = VERSION;
                    b[3] = ty as u8;
                    if i % 4 == 0 {
                        // Correct CRC over random payload: decoding must reject the values.
                        hap_core::protocol::seal_crc(&mut b);
                    }
                    b
                })
                .collect()
        }
        ["badcrc"] => {
            let mut b = frame_bytes(&h, &Frame::PowerRequest(true));
            let last = b.len() - 1;
            b[last] ^= 0xFF;
            vec![b]
        }
        ["short"] => vec![b"HC\x01\x0C short".to_vec()],
        _ => vec![frame_bytes(&h, &parse_frame(what)?)],
    };
    let refused = write_frames(&cli.rtf_in, &frames)?;
    println!(
        "sent {} frame(s), {} refused by the device",
        frames.len() as u32 - refused,
        refused
    );
    if refused > 0 {
        return Err(format!("{refused} frame(s) refused by {}", cli.rtf_in));
    }
    Ok(())
}

/// Non-blocking read of one frame; None when empty.
fn read_frame(f: &mut File) -> Result<Option<Vec<u8>>, String> {
    let mut buf = [0u8; MAX_FRAME_LEN];
    match f.read(&mut buf) {
        Ok(0) => Err("rtf_out closed".into()),
        Ok(n) => Ok(Some(buf[..n].to_vec())),
        Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => Ok(None),
        Err(e) => Err(format!("rtf_out: {e}")),
    }
}

fn open_nonblock(dev: &str) -> Result<File, String> {
    OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK)
        .open(dev)
        .map_err(|e| format!("{dev}: {e}"))
}

fn describe(bytes: &[u8]) -> String {
    match decode(bytes) {
        Ok((h, Frame::Answer(a))) => {
            let p = a.handle_pose.position;
            let f = a.coupling_wrench.force;
            format!(
                "answer session={} seq={} cycle={} status={:#06x} alarms={:#x} pos={:.5},{:.5},{:.5} force={:.4},{:.4},{:.4}",
                h.session,
                h.seq,
                a.cycle,
                a.status,
                a.alarms,
                p.x.to_f64(),
                p.y.to_f64(),
                p.z.to_f64(),
                f.x.to_f64(),
                f.y.to_f64(),
                f.z.to_f64()
            )
        }
        Ok((h, f)) => format!(
            "{} session={} seq={} {:?}",
            f.frame_type().name(),
            h.session,
            h.seq,
            f
        ),
        Err(e) => format!("undecodable ({})", e.name()),
    }
}

fn cmd_recv(cli: &Cli, count: u32, timeout_ms: u64) -> Result<(), String> {
    let mut f = open_nonblock(&cli.rtf_out)?;
    let deadline = Instant::now() + Duration::from_millis(timeout_ms);
    let mut got = 0;
    while got < count && Instant::now() < deadline {
        match read_frame(&mut f)? {
            Some(b) => {
                println!("{}", describe(&b));
                got += 1;
            }
            None => std::thread::sleep(Duration::from_millis(1)),
        }
    }
    if got < count {
        return Err(format!(
            "received {got} of {count} frame(s) before the timeout"
        ));
    }
    Ok(())
}

fn cmd_couple(
    cli: &Cli,
    target: Option<[f64; 3]>,
    offset: Option<[f64; 3]>,
    ms: u64,
) -> Result<(), String> {
    let mut out = open_nonblock(&cli.rtf_out)?;
    while read_frame(&mut out)?.is_some() {}
    let mut seq = 100u32;
    let mut send = |session: u16, f: Frame| -> Result<(), String> {
        seq += 1;
        let h = FrameHeader {
            control: 0,
            session,
            seq,
            timestamp_us: seq,
        };
        let refused = write_frames(&cli.rtf_in, &[frame_bytes(&h, &f)])?;
        if refused > 0 {
            return Err("rtf_in refused a valid frame".into());
        }
        Ok(())
    };
    send(0, Frame::OpenSession { client_nonce: 77 })?;
    // Wait for the SessionAck.
    let t0 = Instant::now();
    let session = loop {
        if t0.elapsed() > Duration::from_secs(2) {
            return Err("no SessionAck within 2 s".into());
        }
        match read_frame(&mut out)? {
            Some(b) => {
                if let Ok((
                    h,
                    Frame::SessionAck {
                        client_nonce: 77, ..
                    },
                )) = decode(&b)
                {
                    break h.session;
                }
            }
            None => std::thread::sleep(Duration::from_millis(1)),
        }
    };
    println!("session {session} open");
    // The handle's position from the first answer.
    let t0 = Instant::now();
    let (handle, orientation) = loop {
        if t0.elapsed() > Duration::from_secs(2) {
            return Err("no answer within 2 s of the SessionAck".into());
        }
        match read_frame(&mut out)? {
            Some(b) => {
                if let Ok((_, Frame::Answer(a))) = decode(&b) {
                    let p = a.handle_pose.position;
                    break (
                        [p.x.to_f64(), p.y.to_f64(), p.z.to_f64()],
                        a.handle_pose.orientation,
                    );
                }
            }
            None => std::thread::sleep(Duration::from_millis(1)),
        }
    };
    let target = match (target, offset) {
        (Some(t), _) => t,
        (None, Some(d)) => [handle[0] + d[0], handle[1] + d[1], handle[2] + d[2]],
        (None, None) => return Err("give --target or --offset".into()),
    };
    println!(
        "handle_start: {:.5},{:.5},{:.5}",
        handle[0], handle[1], handle[2]
    );
    println!("target: {:.5},{:.5},{:.5}", target[0], target[1], target[2]);
    send(session, Frame::SetCommandType(CommandType::Impedance))?;
    send(session, Frame::PowerRequest(true))?;
    let (mut first, mut last) = (None, None);
    let (mut answers, mut max_force, mut coupled) = (0u64, 0f64, 0u64);
    let start = Instant::now();
    let mut next = start;
    while start.elapsed() < Duration::from_millis(ms) {
        if Instant::now() >= next {
            // The object keeps the handle's orientation: a pure translation.
            let pose = Pose {
                orientation,
                ..pose_at(target)
            };
            send(
                session,
                Frame::VprStream {
                    pose,
                    twist: Twist::default(),
                },
            )?;
            next += Duration::from_millis(1);
        }
        while let Some(b) = read_frame(&mut out)? {
            if let Ok((_, Frame::Answer(a))) = decode(&b) {
                answers += 1;
                let p = a.handle_pose.position;
                let pos = [p.x.to_f64(), p.y.to_f64(), p.z.to_f64()];
                let w = a.coupling_wrench.force;
                let fnorm =
                    (w.x.to_f64().powi(2) + w.y.to_f64().powi(2) + w.z.to_f64().powi(2)).sqrt();
                max_force = max_force.max(fnorm);
                if a.status & hap_core::vp::status::COUPLED != 0 {
                    coupled += 1;
                }
                first.get_or_insert(pos);
                last = Some(pos);
            }
        }
        std::thread::sleep(Duration::from_micros(200));
    }
    let (Some(first), Some(last)) = (first, last) else {
        return Err("no answer frame received".into());
    };
    let dist = |p: [f64; 3]| {
        ((p[0] - target[0]).powi(2) + (p[1] - target[1]).powi(2) + (p[2] - target[2]).powi(2))
            .sqrt()
    };
    println!("answers: {answers}");
    println!("coupled_answers: {coupled}");
    println!("first_pos: {:.5},{:.5},{:.5}", first[0], first[1], first[2]);
    println!("last_pos: {:.5},{:.5},{:.5}", last[0], last[1], last[2]);
    println!("first_distance_mm: {:.3}", dist(first) * 1000.0);
    println!("last_distance_mm: {:.3}", dist(last) * 1000.0);
    println!("max_coupling_force_mN: {:.1}", max_force * 1000.0);
    Ok(())
}

fn read_records(dev: &str, count: usize) -> Result<Vec<[u8; LogRecord::SIZE]>, String> {
    let mut f = open_nonblock(dev)?;
    let mut recs = Vec::new();
    let mut buf = vec![0u8; LogRecord::SIZE * 64];
    loop {
        match f.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => {
                for chunk in buf[..n].chunks_exact(LogRecord::SIZE) {
                    let mut r = [0u8; LogRecord::SIZE];
                    r.copy_from_slice(chunk);
                    recs.push(r);
                    if count > 0 && recs.len() >= count {
                        return Ok(recs);
                    }
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => break,
            Err(e) => return Err(format!("{dev}: {e}")),
        }
    }
    Ok(recs)
}

fn cmd_simlog(
    dev: &str,
    count: usize,
    raw: Option<&str>,
    print: bool,
    skip: usize,
) -> Result<(), String> {
    let all = read_records(dev, count)?;
    if let Some(path) = raw {
        let mut out = File::create(path).map_err(|e| format!("{path}: {e}"))?;
        for r in &all {
            out.write_all(r).map_err(|e| format!("{path}: {e}"))?;
        }
    }
    let recs = all.get(skip..).unwrap_or(&[]);
    let mut first = None;
    let mut last = None;
    for r in recs {
        let rec = LogRecord::decode(r).map_err(|e| format!("bad record: {e:?}"))?;
        if print {
            let p = rec.handle_position;
            println!(
                "cycle={} flags={:#06x} pos={:.6},{:.6},{:.6} tau0={:.4}",
                rec.cycle,
                rec.flags,
                p.x.to_f64(),
                p.y.to_f64(),
                p.z.to_f64(),
                rec.motor_torque[0].to_f64()
            );
        }
        first.get_or_insert(rec);
        last = Some(rec);
    }
    println!("records: {}", all.len());
    if let (Some(a), Some(b)) = (first, last) {
        let d = b.handle_position.sub(a.handle_position).norm().to_f64();
        let tau_max = recs
            .iter()
            .filter_map(|r| LogRecord::decode(r).ok())
            .flat_map(|r| r.motor_torque)
            .map(|t| t.to_f64().abs())
            .fold(0.0f64, f64::max);
        println!("first_cycle: {}", a.cycle);
        println!("last_cycle: {}", b.cycle);
        println!("handle_moved_um: {:.3}", d * 1e6);
        println!("max_abs_motor_torque_mNm: {:.3}", tau_max * 1000.0);
    }
    let decoded: Vec<LogRecord> = recs
        .iter()
        .filter_map(|r| LogRecord::decode(r).ok())
        .collect();
    print!("{}", CutSummary::of(&decoded).render());
    Ok(())
}

/// The motor line as the position log saw it: records before the
/// fail-safe's cut, records from the first one flagged `LINE_CUT` on, and
/// how many of each carry a non-zero applied torque.
#[derive(Debug, Default, PartialEq, Eq)]
struct CutSummary {
    first_cut_cycle: Option<u64>,
    records_before_cut: usize,
    torque_nonzero_before_cut: usize,
    records_from_cut: usize,
    /// Of those, records of SERVO's own cycles (not the fail-safe's steps).
    servo_records_from_cut: usize,
    torque_nonzero_from_cut: usize,
    unflagged_after_cut: usize,
}

impl CutSummary {
    fn of(recs: &[LogRecord]) -> CutSummary {
        let mut s = CutSummary::default();
        for r in recs {
            let nonzero = r.motor_torque.iter().any(|t| t.0 != 0);
            let cut = r.flags & hap_core::servo::log_flags::LINE_CUT != 0;
            if s.first_cut_cycle.is_none() && cut {
                s.first_cut_cycle = Some(r.cycle);
            }
            if s.first_cut_cycle.is_some() {
                s.records_from_cut += 1;
                s.servo_records_from_cut += usize::from(r.mode != hap_core::mode::Mode::FailSafe);
                s.torque_nonzero_from_cut += usize::from(nonzero);
                s.unflagged_after_cut += usize::from(!cut);
            } else {
                s.records_before_cut += 1;
                s.torque_nonzero_before_cut += usize::from(nonzero);
            }
        }
        s
    }

    fn render(&self) -> String {
        format!(
            "first_cut_cycle: {}\nrecords_before_cut: {}\ntorque_nonzero_before_cut: {}\n\
             records_from_cut: {}\nservo_records_from_cut: {}\ntorque_nonzero_from_cut: {}\n\
             unflagged_after_cut: {}\n",
            self.first_cut_cycle
                .map_or_else(|| "none".to_string(), |c| c.to_string()),
            self.records_before_cut,
            self.torque_nonzero_before_cut,
            self.records_from_cut,
            self.servo_records_from_cut,
            self.torque_nonzero_from_cut,
            self.unflagged_after_cut
        )
    }
}

fn cmd_replay(effort: &str, load_cycle: u64, guest: &str, period_us: u32) -> Result<bool, String> {
    let text = std::fs::read(effort).map_err(|e| format!("{effort}: {e}"))?;
    let raw = std::fs::read(guest).map_err(|e| format!("{guest}: {e}"))?;
    let guest_recs: Vec<&[u8]> = raw.chunks_exact(LogRecord::SIZE).collect();
    if guest_recs.is_empty() {
        return Err("the guest log is empty".into());
    }
    let cycle_of = |r: &[u8]| -> Result<u64, String> {
        let mut b = [0u8; LogRecord::SIZE];
        b.copy_from_slice(r);
        Ok(LogRecord::decode(&b)
            .map_err(|e| format!("bad guest record: {e:?}"))?
            .cycle)
    };
    let first = cycle_of(guest_recs[0])?;
    let last = cycle_of(guest_recs[guest_recs.len() - 1])?;
    let mut c = Box::new(ServoCycle::new(period_us));
    c.servo.init();
    let inputs = ServoInputs {
        power_request: PowerRequest::None,
        live_effort: None,
    };
    let config = hap_core::config::ServoConfig::default();
    let invalid = hap_core::vp::VpReceived::default();
    let line = hap_core::io::MotorLine::new();
    let mut replay = std::collections::HashMap::new();
    while c.servo.cycle() <= last {
        if c.servo.cycle() == load_cycle {
            c.servo.load_effort_text(&text).map_err(|e| {
                format!(
                    "effort {effort}: line {} column {}: {:?}",
                    e.line, e.column, e.kind
                )
            })?;
        }
        c.run(&line, &inputs, &config, Some(&invalid), Mode::Main);
        let mut rec = [0u8; LogRecord::SIZE];
        c.servo.log_record().encode(&mut rec);
        let cyc = c.servo.log_record().cycle;
        if cyc >= first {
            replay.insert(cyc, rec);
        }
    }
    let mut same = 0usize;
    let mut first_diff = None;
    for r in &guest_recs {
        let cyc = cycle_of(r)?;
        // The kernel's timing fields are the guest's own; everything else
        // must be hap-core's output bit for bit.
        let mut g = [0u8; LogRecord::SIZE];
        g.copy_from_slice(r);
        if let Some(t) = g.get_mut(LogRecord::TIMING) {
            t.fill(0);
        }
        match replay.get(&cyc) {
            Some(h) if *h == g => same += 1,
            _ => {
                first_diff.get_or_insert(cyc);
            }
        }
    }
    println!(
        "compared: {} guest records (cycles {first}..={last}), effort loaded at cycle {load_cycle}",
        guest_recs.len()
    );
    println!("identical: {same}");
    if let Some(c) = first_diff {
        println!("first_difference_at_cycle: {c}");
    }
    Ok(same == guest_recs.len())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let res = match &cli.cmd {
        Cmd::Send {
            session,
            seq,
            ack,
            what,
        } => cmd_send(&cli, *session, *seq, *ack, what).map(|_| true),
        Cmd::Recv { count, timeout_ms } => cmd_recv(&cli, *count, *timeout_ms).map(|_| true),
        Cmd::Couple { target, offset, ms } => cmd_couple(&cli, *target, *offset, *ms).map(|_| true),
        Cmd::Simlog {
            dev,
            count,
            raw,
            print,
            skip,
        } => cmd_simlog(dev, *count, raw.as_deref(), *print, *skip).map(|_| true),
        Cmd::ReplayCompare {
            effort,
            load_cycle,
            guest,
            period_us,
        } => cmd_replay(effort, *load_cycle, guest, *period_us),
        Cmd::Hostile {
            target,
            count,
            to,
            session,
            interval_us,
            seed,
        } => {
            let iv = Duration::from_micros(*interval_us);
            let r = match (target.as_str(), to, session) {
                ("net", Some(to), _) => hostile::run_net(*to, *count, iv, *seed),
                ("dev", _, Some(s)) => hostile::run_dev(&cli.rtf_in, *s, *count, iv, *seed),
                _ => Err("hostile: net needs --to, dev needs --session".into()),
            };
            r.and_then(|r| {
                print!("{}", r.render());
                match r.error {
                    Some(e) => Err(format!("hostile: stopped early: {e}")),
                    None => Ok(true),
                }
            })
        }
    };
    match res {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::from(1),
        Err(e) => {
            eprintln!("hapdev: {e}");
            ExitCode::from(2)
        }
    }
}

#[cfg(test)]
mod cut_summary_tests {
    use super::*;
    use hap_core::servo::log_flags::LINE_CUT;

    fn rec(cycle: u64, tau: i64, flags: u16) -> LogRecord {
        LogRecord {
            cycle,
            flags,
            motor_torque: [Fx(tau); 6],
            ..LogRecord::ZERO
        }
    }

    fn step_rec() -> LogRecord {
        LogRecord {
            flags: LINE_CUT,
            mode: hap_core::mode::Mode::FailSafe,
            ..LogRecord::ZERO
        }
    }

    #[test]
    fn counts_torque_on_each_side_of_the_cut() {
        let recs = [
            rec(1, 5, 0),
            rec(2, 0, 0),
            step_rec(),
            rec(3, 0, LINE_CUT),
            rec(4, 7, LINE_CUT),
            rec(5, 0, 0),
        ];
        let s = CutSummary::of(&recs);
        assert_eq!(s.first_cut_cycle, Some(0));
        assert_eq!((s.records_before_cut, s.torque_nonzero_before_cut), (2, 1));
        assert_eq!((s.records_from_cut, s.torque_nonzero_from_cut), (4, 1));
        assert_eq!(s.servo_records_from_cut, 3);
        assert_eq!(s.unflagged_after_cut, 1);
        assert!(s.render().contains("torque_nonzero_from_cut: 1\n"));
        assert_eq!(CutSummary::of(&recs[..2]).first_cut_cycle, None);
    }
}

#[cfg(test)]
mod replay_tests {
    use super::*;
    use hap_core::position_log::LogTiming;

    /// A guest log as the module writes it: hap-core's records plus the
    /// kernel's timing fields.
    fn guest_log(effort: &[u8], load_cycle: u64, cycles: u64) -> Vec<u8> {
        let mut c = Box::new(ServoCycle::new(1000));
        c.servo.init();
        let inputs = ServoInputs {
            power_request: PowerRequest::None,
            live_effort: None,
        };
        let config = hap_core::config::ServoConfig::default();
        let line = hap_core::io::MotorLine::new();
        let mut out = Vec::new();
        for n in 0..cycles {
            if n == load_cycle {
                c.servo.load_effort_text(effort).unwrap();
            }
            // The module's proto try-lock fails now and then: no VPr copy.
            let vpr = hap_core::vp::VpReceived::default();
            let shared = if n % 7 == 3 { None } else { Some(&vpr) };
            c.run(&line, &inputs, &config, shared, Mode::Main);
            let mut r = *c.servo.log_record();
            r.timing = LogTiming {
                tick: n + 1,
                start_ns: n * 1_000_000 + 12_345,
                wakeup_ns: 12_345,
                exec_ns: 40_000 + n as u32,
                session: 0,
            };
            let mut b = [0u8; LogRecord::SIZE];
            r.encode(&mut b);
            out.extend_from_slice(&b);
        }
        out
    }

    #[test]
    fn replay_compares_everything_but_the_kernel_timing() {
        let dir = std::env::temp_dir().join(format!("hapdev-replay-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let eff = dir.join("push.eff");
        std::fs::write(
            &eff,
            "0 0 0 0 0 0 0 1\n200 2 0 -1 0 0 0 1\n600 0 0 0 0 0 0 1\n",
        )
        .unwrap();
        let effort = std::fs::read(&eff).unwrap();
        let log = guest_log(&effort, 50, 800);
        let guest = dir.join("guest.bin");
        let run = |bytes: &[u8]| {
            std::fs::write(&guest, bytes).unwrap();
            cmd_replay(eff.to_str().unwrap(), 50, guest.to_str().unwrap(), 1000).unwrap()
        };
        assert!(run(&log), "identical but for the timing fields");
        // One bit of a joint angle differs: found.
        let mut bad = log.clone();
        bad[LogRecord::SIZE * 400 + 40] ^= 1;
        assert!(!run(&bad));
        // One bit of the applied torques differs: found.
        let mut bad = log.clone();
        bad[LogRecord::SIZE * 700 + 290] ^= 1;
        assert!(!run(&bad));
        // The kernel's own fields are not hap-core's output.
        let mut other = log.clone();
        other[LogRecord::SIZE * 400 + LogRecord::TIMING.start] ^= 0xff;
        assert!(run(&other));
        std::fs::remove_dir_all(&dir).ok();
    }
}
