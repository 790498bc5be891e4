//! The user's effort on the handle: a pre-computed sequence of keyframes
//! (parsed without floats, allocation or panics) or a live value.
//!
//! # Text format (`.eff`, version 1)
//!
//! ```text
//! # comment lines start with '#'; blank lines are ignored; a '#' ends a line
//! # t_ms   fx    fy   fz    tx   ty   tz   [deadman [button1 [button2]]]
//! 0        0     0    0     0    0    0    1
//! 500      2.5   0   -1.25  0    0    0.05 1 0 0
//! 1500     0     0    0     0    0    0
//! ```
//!
//! * One keyframe per line, fields separated by spaces or tabs; `\r` is ignored.
//! * `t_ms`: time in milliseconds since the sequence start, unsigned integer
//!   ≤ 4 000 000 000, strictly increasing from line to line.
//! * `fx fy fz` (N) and `tx ty tz` (N·m): the wrench the user applies to the
//!   handle, in the arm base frame, force at the handle centre. Decimal
//!   numbers `[+|-]digits[.digits]` (no exponent), |value| ≤ 1000; stored in
//!   milli-units (mN, mN·m), rounded half away from zero at the 4th decimal.
//! * Optional flags, each `0` or `1`: `deadman` (user holds the handle,
//!   default 1), `button1` (indexing button, default 0), `button2` (default 0).
//! * Between keyframes the wrench is interpolated linearly; flags hold the
//!   value of the keyframe at or before the time. Before the first keyframe
//!   the first keyframe's values apply, after the last one the last's.
//!
//! Errors carry the 1-based line and byte column of the offending field (for
//! `Empty`, the line after the last one, column 1).

use super::fixed::{Fx, Vec3, Wrench};

/// Keyframe storage of an [`EffortPlayer`].
pub const EFFORT_CAPACITY: usize = 128;
/// Largest accepted |value| in the text format, in milli-units.
pub const EFFORT_MAX_MILLI: i64 = 1_000_000;
/// Largest accepted keyframe time, ms.
pub const EFFORT_MAX_T_MS: u64 = 4_000_000_000;

/// Keyframe flag: dead-man switch held.
pub const FLAG_DEAD_MAN: u8 = 1 << 0;
/// Keyframe flag: button 1 (indexing).
pub const FLAG_BUTTON_1: u8 = 1 << 1;
/// Keyframe flag: button 2.
pub const FLAG_BUTTON_2: u8 = 1 << 2;

/// One keyframe (32 bytes): time and wrench in milli-units.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EffortKeyframe {
    pub t_ms: u32,
    /// Force, mN, arm base frame.
    pub force_mn: [i32; 3],
    /// Torque, mN·m, arm base frame.
    pub torque_mnm: [i32; 3],
    /// `FLAG_*` bits.
    pub flags: u8,
}

impl EffortKeyframe {
    pub const ZERO: EffortKeyframe = EffortKeyframe {
        t_ms: 0,
        force_mn: [0; 3],
        torque_mnm: [0; 3],
        flags: 0,
    };

    fn milli(&self) -> [i32; 6] {
        let [a, b, c] = self.force_mn;
        let [d, e, f] = self.torque_mnm;
        [a, b, c, d, e, f]
    }
}

/// The user's action on the handle for one cycle.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EffortSample {
    /// Wrench applied by the user at the handle, arm base frame (N, N·m).
    pub wrench: Wrench,
    /// The user holds the handle (dead-man switch).
    pub dead_man: bool,
    /// Bit 0: button 1 (indexing), bit 1: button 2.
    pub buttons: u8,
}

impl EffortSample {
    pub const NONE: EffortSample = EffortSample {
        wrench: Wrench::ZERO,
        dead_man: false,
        buttons: 0,
    };
}

/// What went wrong, see [`EffortParseError`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EffortErrorKind {
    /// `t_ms` is not an unsigned integer.
    BadTime,
    /// `t_ms` > 4 000 000 000.
    TimeOutOfRange,
    /// `t_ms` not strictly greater than the previous keyframe's.
    TimeNotIncreasing,
    /// A wrench field is not a decimal number.
    BadNumber,
    /// |value| > 1000.
    ValueOutOfRange,
    /// Fewer than the 7 mandatory fields.
    MissingField,
    /// More than 10 fields.
    TooManyFields,
    /// A flag is not `0` or `1`.
    BadFlag,
    /// More keyframes than the output slice holds.
    TooManyKeyframes,
    /// No keyframe at all.
    Empty,
}

/// A parse error with its 1-based line and byte column.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EffortParseError {
    pub line: u32,
    pub column: u32,
    pub kind: EffortErrorKind,
}

fn is_space(b: u8) -> bool {
    b == b' ' || b == b'\t' || b == b'\r'
}

/// Parse an unsigned integer time in ms.
fn parse_time(f: &[u8]) -> Result<u32, EffortErrorKind> {
    if f.is_empty() {
        return Err(EffortErrorKind::BadTime);
    }
    let mut v: u64 = 0;
    for &b in f {
        if !b.is_ascii_digit() {
            return Err(EffortErrorKind::BadTime);
        }
        v = v.saturating_mul(10).saturating_add((b - b'0') as u64);
    }
    if v > EFFORT_MAX_T_MS {
        return Err(EffortErrorKind::TimeOutOfRange);
    }
    Ok(v as u32)
}

/// Parse `[+|-]digits[.digits]` into milli-units.
pub fn parse_milli(f: &[u8]) -> Result<i32, EffortErrorKind> {
    let (neg, rest) = match f.split_first() {
        Some((b'-', r)) => (true, r),
        Some((b'+', r)) => (false, r),
        Some(_) => (false, f),
        None => return Err(EffortErrorKind::BadNumber),
    };
    let mut int: i64 = 0;
    let mut frac: i64 = 0;
    let mut frac_digits = 0u32;
    let mut round_up = false;
    let mut seen_dot = false;
    let mut digits = 0u32;
    for &b in rest {
        if b == b'.' {
            if seen_dot {
                return Err(EffortErrorKind::BadNumber);
            }
            seen_dot = true;
        } else if b.is_ascii_digit() {
            digits = digits.saturating_add(1);
            let d = i64::from(b.wrapping_sub(b'0'));
            if !seen_dot {
                int = int.saturating_mul(10).saturating_add(d);
            } else if frac_digits < 3 {
                frac = frac.saturating_mul(10).saturating_add(d);
                frac_digits += 1;
            } else if frac_digits == 3 {
                round_up = d >= 5;
                frac_digits += 1;
            }
        } else {
            return Err(EffortErrorKind::BadNumber);
        }
    }
    if digits == 0 {
        return Err(EffortErrorKind::BadNumber);
    }
    while frac_digits < 3 {
        frac = frac.saturating_mul(10);
        frac_digits += 1;
    }
    let mut m = int.saturating_mul(1000).saturating_add(frac);
    if round_up {
        m = m.saturating_add(1);
    }
    if m > EFFORT_MAX_MILLI {
        return Err(EffortErrorKind::ValueOutOfRange);
    }
    // 0 <= m <= 1e6 fits in i32.
    let m = i32::try_from(m).map_err(|_| EffortErrorKind::ValueOutOfRange)?;
    Ok(if neg { m.saturating_neg() } else { m })
}

fn parse_flag(f: &[u8]) -> Result<bool, EffortErrorKind> {
    match f {
        b"0" => Ok(false),
        b"1" => Ok(true),
        _ => Err(EffortErrorKind::BadFlag),
    }
}

/// Parse an effort sequence into `out`; returns the number of keyframes.
pub fn parse_effort_sequence(
    text: &[u8],
    out: &mut [EffortKeyframe],
) -> Result<usize, EffortParseError> {
    let capacity = out.len();
    parse_into(text, capacity, |i, kf| {
        if let Some(slot) = out.get_mut(i) {
            *slot = kf;
        }
    })
}

/// Check an effort sequence without storing it: the number of keyframes it
/// holds (at most `capacity`), or the same error `parse_effort_sequence`
/// would return.
pub fn validate_effort_sequence(text: &[u8], capacity: usize) -> Result<usize, EffortParseError> {
    parse_into(text, capacity, |_, _| {})
}

fn parse_into(
    text: &[u8],
    capacity: usize,
    mut sink: impl FnMut(usize, EffortKeyframe),
) -> Result<usize, EffortParseError> {
    let mut n = 0usize;
    let mut last_line = 0u32;
    let mut prev_t: Option<u32> = None;
    // Lines counted by hand (saturating): `enumerate()` would add an
    // overflow-checked counter, a panic path in the kernel.
    for raw_line in text.split(|&b| b == b'\n') {
        let line_no = last_line.saturating_add(1);
        last_line = line_no;
        // Strip a trailing comment.
        let line = match raw_line.iter().position(|&b| b == b'#') {
            Some(p) => raw_line.get(..p).unwrap_or(raw_line),
            None => raw_line,
        };
        let err = |col: usize, kind| EffortParseError {
            line: line_no,
            column: u32::try_from(col).unwrap_or(u32::MAX - 1).saturating_add(1),
            kind,
        };
        let mut kf = EffortKeyframe {
            flags: FLAG_DEAD_MAN,
            ..EffortKeyframe::ZERO
        };
        let mut field = 0usize;
        let mut pos = 0usize;
        let len = line.len();
        let mut milli = [0i32; 6];
        while pos < len {
            // skip blanks
            while line.get(pos).is_some_and(|&b| is_space(b)) {
                pos = pos.saturating_add(1);
            }
            if pos >= len {
                break;
            }
            let start = pos;
            while line.get(pos).is_some_and(|&b| !is_space(b)) {
                pos = pos.saturating_add(1);
            }
            let f = line.get(start..pos).unwrap_or(&[]);
            match field {
                0 => {
                    let t = parse_time(f).map_err(|k| err(start, k))?;
                    if prev_t.is_some_and(|p| t <= p) {
                        return Err(err(start, EffortErrorKind::TimeNotIncreasing));
                    }
                    kf.t_ms = t;
                }
                1..=6 => {
                    let v = parse_milli(f).map_err(|k| err(start, k))?;
                    if let Some(slot) = milli.get_mut(field.wrapping_sub(1)) {
                        *slot = v;
                    }
                }
                7..=9 => {
                    let bit = match field {
                        7 => FLAG_DEAD_MAN,
                        8 => FLAG_BUTTON_1,
                        _ => FLAG_BUTTON_2,
                    };
                    if parse_flag(f).map_err(|k| err(start, k))? {
                        kf.flags |= bit;
                    } else {
                        kf.flags &= !bit;
                    }
                }
                _ => return Err(err(start, EffortErrorKind::TooManyFields)),
            }
            field = field.saturating_add(1);
        }
        if field == 0 {
            continue;
        }
        if field < 7 {
            // Column just past the end of the line content.
            let trailing = line.iter().rev().take_while(|&&b| is_space(b)).count();
            let end = line.len().saturating_sub(trailing);
            return Err(err(end, EffortErrorKind::MissingField));
        }
        let [a, b, c, d, e, f] = milli;
        kf.force_mn = [a, b, c];
        kf.torque_mnm = [d, e, f];
        if n >= capacity {
            return Err(err(0, EffortErrorKind::TooManyKeyframes));
        }
        sink(n, kf);
        n = n.saturating_add(1);
        prev_t = Some(kf.t_ms);
    }
    if n == 0 {
        return Err(EffortParseError {
            line: last_line.saturating_add(1),
            column: 1,
            kind: EffortErrorKind::Empty,
        });
    }
    Ok(n)
}

/// What one write to the simulator's effort device (`/dev/hap_effort`) asks
/// for. A trailing newline is ignored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EffortCommand<'a> {
    /// A whole effort sequence (`.eff` text), already validated.
    Sequence { text: &'a [u8], keyframes: usize },
    /// `live fx fy fz tx ty tz` (N, N·m, decimals): the user holds the handle
    /// (dead-man closed) with this wrench, overriding the sequence.
    Live(EffortSample),
    /// `live off`: back to the sequence.
    LiveOff,
    /// `clear`: unload the sequence.
    Clear,
}

/// Why an effort-device write was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EffortCommandError {
    /// `live` needs exactly six decimal values.
    BadLive,
    /// The text is neither a command nor a valid sequence.
    Sequence(EffortParseError),
}

/// Parse one effort-device write (see [`EffortCommand`]); a sequence is
/// validated against `capacity` keyframes but not stored.
pub fn parse_effort_command(
    text: &[u8],
    capacity: usize,
) -> Result<EffortCommand<'_>, EffortCommandError> {
    let body = text.strip_suffix(b"\n").unwrap_or(text);
    if body == b"clear" {
        return Ok(EffortCommand::Clear);
    }
    if body == b"live off" {
        return Ok(EffortCommand::LiveOff);
    }
    if let Some(args) = body.strip_prefix(b"live ") {
        let mut v = [Fx::ZERO; 6];
        let mut words = args
            .split(|c| *c == b' ' || *c == b'\t')
            .filter(|w| !w.is_empty());
        for slot in v.iter_mut() {
            let word = words.next().ok_or(EffortCommandError::BadLive)?;
            let m = parse_milli(word).map_err(|_| EffortCommandError::BadLive)?;
            *slot = Fx::from_milli(i64::from(m));
        }
        if words.next().is_some() {
            return Err(EffortCommandError::BadLive);
        }
        let [fx, fy, fz, tx, ty, tz] = v;
        return Ok(EffortCommand::Live(EffortSample {
            wrench: Wrench {
                force: Vec3 {
                    x: fx,
                    y: fy,
                    z: fz,
                },
                torque: Vec3 {
                    x: tx,
                    y: ty,
                    z: tz,
                },
            },
            dead_man: true,
            buttons: 0,
        }));
    }
    let keyframes =
        validate_effort_sequence(text, capacity).map_err(EffortCommandError::Sequence)?;
    Ok(EffortCommand::Sequence { text, keyframes })
}

/// One effort command as the device writer hands it to SERVO: the
/// parsed and validated form of an [`EffortCommand`], a sequence already
/// turned into keyframes. It crosses a lock-free ring as one record of at
/// most [`EFFORT_RECORD_BYTES`] ([`EffortHandoff::encode`], read back by
/// [`EffortHandoff::decode`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EffortHandoff<'a> {
    /// Unload the sequence.
    Clear,
    /// End the live effort (back to the sequence).
    LiveOff,
    /// A live effort overriding the sequence.
    Live(EffortSample),
    /// Load these keyframes (at most [`EFFORT_CAPACITY`]).
    Sequence(&'a [EffortKeyframe]),
}

/// Bytes of one keyframe in a handoff record: `t_ms` (4), the six mN/mN·m
/// values (4 each), the flags (1), 3 bytes of padding.
const HANDOFF_KEY_BYTES: usize = 32;
/// Bytes of the handoff record's header: kind (1), then for `Live` the
/// dead-man flag and buttons (1 each); the keyframe count at byte 8 (8).
const HANDOFF_HEADER_BYTES: usize = 16;
/// The largest handoff record: a full sequence.
pub const EFFORT_RECORD_BYTES: usize = HANDOFF_HEADER_BYTES + EFFORT_CAPACITY * HANDOFF_KEY_BYTES;

const KIND_CLEAR: u8 = 1;
const KIND_LIVE_OFF: u8 = 2;
const KIND_LIVE: u8 = 3;
const KIND_SEQUENCE: u8 = 4;

fn put(out: &mut [u8], at: usize, bytes: &[u8]) {
    if let Some(d) = at
        .checked_add(bytes.len())
        .and_then(|end| out.get_mut(at..end))
    {
        d.copy_from_slice(bytes);
    }
}

fn get<const N: usize>(rec: &[u8], at: usize) -> [u8; N] {
    let mut b = [0u8; N];
    if let Some(s) = at.checked_add(N).and_then(|end| rec.get(at..end)) {
        b.copy_from_slice(s);
    }
    b
}

impl<'a> EffortHandoff<'a> {
    /// Encode into `out`; the record's length. A sequence longer than
    /// [`EFFORT_CAPACITY`] keeps its first `EFFORT_CAPACITY` keyframes
    /// (the writer's parser never produces one).
    pub fn encode(&self, out: &mut [u8; EFFORT_RECORD_BYTES]) -> usize {
        match self {
            EffortHandoff::Clear => {
                put(out, 0, &[KIND_CLEAR]);
                1
            }
            EffortHandoff::LiveOff => {
                put(out, 0, &[KIND_LIVE_OFF]);
                1
            }
            EffortHandoff::Live(s) => {
                put(out, 0, &[KIND_LIVE, u8::from(s.dead_man), s.buttons]);
                let w = &s.wrench;
                let raw = [
                    w.force.x, w.force.y, w.force.z, w.torque.x, w.torque.y, w.torque.z,
                ];
                let mut at = HANDOFF_HEADER_BYTES;
                for v in raw {
                    put(out, at, &v.0.to_le_bytes());
                    at = at.saturating_add(8);
                }
                at
            }
            EffortHandoff::Sequence(keys) => {
                let keys = keys.get(..EFFORT_CAPACITY).unwrap_or(keys);
                put(out, 0, &[KIND_SEQUENCE]);
                put(out, 8, &(keys.len() as u64).to_le_bytes());
                let mut at = HANDOFF_HEADER_BYTES;
                for k in keys {
                    put(out, at, &k.t_ms.to_le_bytes());
                    let mut v_at = at.saturating_add(4);
                    for v in Iterator::chain(k.force_mn.iter(), k.torque_mnm.iter()) {
                        put(out, v_at, &v.to_le_bytes());
                        v_at = v_at.saturating_add(4);
                    }
                    put(out, at.saturating_add(28), &[k.flags]);
                    at = at.saturating_add(HANDOFF_KEY_BYTES);
                }
                at
            }
        }
    }

    /// Decode record `rec`, a sequence's keyframes into `keys` (at most
    /// `keys.len()` of them). `None` for a record of no known kind; a short
    /// record reads its missing bytes as 0.
    pub fn decode(rec: &[u8], keys: &'a mut [EffortKeyframe]) -> Option<EffortHandoff<'a>> {
        match rec.first().copied()? {
            KIND_CLEAR => Some(EffortHandoff::Clear),
            KIND_LIVE_OFF => Some(EffortHandoff::LiveOff),
            KIND_LIVE => {
                let fx = |j: usize| {
                    Fx(i64::from_le_bytes(get(
                        rec,
                        HANDOFF_HEADER_BYTES.saturating_add(j.saturating_mul(8)),
                    )))
                };
                Some(EffortHandoff::Live(EffortSample {
                    wrench: Wrench {
                        force: Vec3 {
                            x: fx(0),
                            y: fx(1),
                            z: fx(2),
                        },
                        torque: Vec3 {
                            x: fx(3),
                            y: fx(4),
                            z: fx(5),
                        },
                    },
                    dead_man: get::<1>(rec, 1)[0] != 0,
                    buttons: get::<1>(rec, 2)[0],
                }))
            }
            KIND_SEQUENCE => {
                let count = usize::try_from(u64::from_le_bytes(get(rec, 8))).unwrap_or(0);
                let count = count.min(keys.len()).min(EFFORT_CAPACITY);
                for (i, k) in keys.iter_mut().enumerate().take(count) {
                    let at =
                        HANDOFF_HEADER_BYTES.saturating_add(i.saturating_mul(HANDOFF_KEY_BYTES));
                    let i32_at = |j: usize| {
                        i32::from_le_bytes(get(
                            rec,
                            at.saturating_add(4).saturating_add(j.saturating_mul(4)),
                        ))
                    };
                    *k = EffortKeyframe {
                        t_ms: u32::from_le_bytes(get(rec, at)),
                        force_mn: [i32_at(0), i32_at(1), i32_at(2)],
                        torque_mnm: [i32_at(3), i32_at(4), i32_at(5)],
                        flags: get::<1>(rec, at.saturating_add(28))[0],
                    };
                }
                Some(EffortHandoff::Sequence(keys.get(..count).unwrap_or(&[])))
            }
            _ => None,
        }
    }
}

/// Plays a keyframe sequence (fixed capacity, no allocation) and an optional
/// live override.
#[derive(Clone, Debug)]
pub struct EffortPlayer {
    keys: [EffortKeyframe; EFFORT_CAPACITY],
    len: usize,
    cursor: usize,
    live: Option<EffortSample>,
}

impl Default for EffortPlayer {
    fn default() -> Self {
        EffortPlayer::new()
    }
}

impl EffortPlayer {
    pub const fn new() -> EffortPlayer {
        EffortPlayer {
            keys: [EffortKeyframe::ZERO; EFFORT_CAPACITY],
            len: 0,
            cursor: 0,
            live: None,
        }
    }

    /// Replace the sequence by `keys` (at most `EFFORT_CAPACITY` taken; times
    /// should increase). Returns the number stored.
    pub fn load(&mut self, keys: &[EffortKeyframe]) -> usize {
        let mut n = 0;
        for (d, s) in self.keys.iter_mut().zip(keys.iter()) {
            *d = *s;
            n += 1;
        }
        self.len = n;
        self.cursor = 0;
        n
    }

    /// Parse and load `text`. On error the current sequence is kept as it
    /// was (the text is validated before anything is overwritten).
    pub fn load_text(&mut self, text: &[u8]) -> Result<usize, EffortParseError> {
        validate_effort_sequence(text, self.keys.len())?;
        let n = parse_effort_sequence(text, &mut self.keys)?;
        self.len = n;
        self.cursor = 0;
        Ok(n)
    }

    pub fn clear(&mut self) {
        self.len = 0;
        self.cursor = 0;
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    pub fn keyframes(&self) -> &[EffortKeyframe] {
        self.keys.get(..self.len).unwrap_or(&[])
    }

    /// Set or clear the live effort (a device write); it overrides the sequence.
    pub fn set_live(&mut self, live: Option<EffortSample>) {
        self.live = live;
    }

    pub fn live(&self) -> Option<EffortSample> {
        self.live
    }

    /// The effort at `t_us` µs since the sequence start (live value first;
    /// no sequence → nobody at the handle).
    pub fn sample(&mut self, t_us: u64) -> EffortSample {
        if let Some(l) = self.live {
            return l;
        }
        let keys = self.keys.get(..self.len).unwrap_or(&[]);
        let (first, last) = match (keys.first(), keys.last()) {
            (Some(f), Some(l)) => (f, l),
            _ => return EffortSample::NONE,
        };
        let t_ms_floor = t_us / 1000;
        if t_ms_floor < first.t_ms as u64 {
            return sample_of(first);
        }
        if t_ms_floor >= last.t_ms as u64 {
            return sample_of(last);
        }
        // Move the cursor to the segment [k, k+1] containing t (monotone
        // playback is O(1) amortised; going back restarts the search).
        if keys
            .get(self.cursor)
            .is_none_or(|k| (k.t_ms as u64) * 1000 > t_us)
        {
            self.cursor = 0;
        }
        while keys
            .get(self.cursor + 1)
            .is_some_and(|k| (k.t_ms as u64) * 1000 <= t_us)
        {
            self.cursor += 1;
        }
        let (a, b) = match (keys.get(self.cursor), keys.get(self.cursor + 1)) {
            (Some(a), Some(b)) => (a, b),
            (Some(a), None) => return sample_of(a),
            _ => return EffortSample::NONE,
        };
        let t0 = (a.t_ms as u64) * 1000;
        let t1 = (b.t_ms as u64) * 1000;
        let num = t_us.saturating_sub(t0).min(i64::MAX as u64) as i64;
        let den = t1.saturating_sub(t0).min(i64::MAX as u64) as i64;
        let frac = Fx::ratio(num, den);
        let va = a.milli();
        let vb = b.milli();
        let mut v = [Fx::ZERO; 6];
        for ((o, x), y) in v.iter_mut().zip(va.iter()).zip(vb.iter()) {
            let fa = Fx::from_milli(*x as i64);
            let fb = Fx::from_milli(*y as i64);
            *o = fa.add_sat(frac.mul_sat(fb.sub_sat(fa)));
        }
        let [fx, fy, fz, tx, ty, tz] = v;
        EffortSample {
            wrench: Wrench {
                force: Vec3::new(fx, fy, fz),
                torque: Vec3::new(tx, ty, tz),
            },
            dead_man: a.flags & FLAG_DEAD_MAN != 0,
            buttons: (a.flags >> 1) & 3,
        }
    }
}

fn sample_of(k: &EffortKeyframe) -> EffortSample {
    let m = k.milli();
    let [fx, fy, fz, tx, ty, tz] = m.map(|x| Fx::from_milli(x as i64));
    EffortSample {
        wrench: Wrench {
            force: Vec3::new(fx, fy, fz),
            torque: Vec3::new(tx, ty, tz),
        },
        dead_man: k.flags & FLAG_DEAD_MAN != 0,
        buttons: (k.flags >> 1) & 3,
    }
}

#[cfg(test)]
mod handoff_tests {
    use super::*;

    fn round_trip(
        h: EffortHandoff<'_>,
    ) -> (usize, std::vec::Vec<EffortKeyframe>, EffortHandoff<'static>) {
        let mut rec = [0u8; EFFORT_RECORD_BYTES];
        let n = h.encode(&mut rec);
        let keys: &'static mut [EffortKeyframe] = std::boxed::Box::leak(std::boxed::Box::new(
            [EffortKeyframe::ZERO; EFFORT_CAPACITY],
        ));
        let back = EffortHandoff::decode(&rec[..n], keys).expect("a known kind");
        let seq = match back {
            EffortHandoff::Sequence(k) => k.to_vec(),
            _ => std::vec::Vec::new(),
        };
        (n, seq, back)
    }

    #[test]
    fn every_kind_round_trips() {
        assert_eq!(round_trip(EffortHandoff::Clear).2, EffortHandoff::Clear);
        assert_eq!(round_trip(EffortHandoff::LiveOff).2, EffortHandoff::LiveOff);
        let v3 = |a, b, c| Vec3 {
            x: Fx(a),
            y: Fx(b),
            z: Fx(c),
        };
        let live = EffortSample {
            wrench: Wrench {
                force: v3(1, -2, i64::MAX),
                torque: v3(i64::MIN, 5, -6),
            },
            dead_man: true,
            buttons: 3,
        };
        let (n, _, back) = round_trip(EffortHandoff::Live(live));
        assert_eq!(back, EffortHandoff::Live(live));
        assert_eq!(n, HANDOFF_HEADER_BYTES + 6 * 8);
        // Every keyframe field distinct, a full sequence (the largest record).
        let keys: std::vec::Vec<EffortKeyframe> = (0..EFFORT_CAPACITY as i32)
            .map(|i| EffortKeyframe {
                t_ms: u32::MAX - i as u32,
                force_mn: [i, -i - 1, i32::MAX - i],
                torque_mnm: [i32::MIN + i, 7 * i, -7 * i],
                flags: (i % 8) as u8,
            })
            .collect();
        let (n, seq, _) = round_trip(EffortHandoff::Sequence(&keys));
        assert_eq!(n, EFFORT_RECORD_BYTES);
        assert_eq!(seq, keys);
        let (n, seq, _) = round_trip(EffortHandoff::Sequence(&keys[..1]));
        assert_eq!(n, HANDOFF_HEADER_BYTES + HANDOFF_KEY_BYTES);
        assert_eq!(seq, keys[..1]);
        let (_, seq, _) = round_trip(EffortHandoff::Sequence(&[]));
        assert!(seq.is_empty());
    }

    #[test]
    fn bad_records_decode_to_nothing_or_zeroes() {
        let mut keys = [EffortKeyframe::ZERO; 4];
        assert_eq!(EffortHandoff::decode(&[], &mut keys), None);
        assert_eq!(EffortHandoff::decode(&[0], &mut keys), None);
        assert_eq!(EffortHandoff::decode(&[9, 1, 2], &mut keys), None);
        // A sequence announcing more keyframes than the scratch holds, in a
        // short record: bounded by the scratch, missing bytes read as 0.
        let mut rec = [0u8; 24];
        rec[0] = KIND_SEQUENCE;
        rec[8..16].copy_from_slice(&u64::MAX.to_le_bytes());
        rec[16..20].copy_from_slice(&7u32.to_le_bytes());
        match EffortHandoff::decode(&rec, &mut keys) {
            Some(EffortHandoff::Sequence(k)) => {
                assert_eq!(k.len(), 4);
                assert_eq!(k[0].t_ms, 7);
                assert!(k[1..].iter().all(|k| *k == EffortKeyframe::ZERO));
            }
            other => panic!("{other:?}"),
        }
    }
}
