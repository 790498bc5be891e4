//! The haptic frame format (spec §3.3): one UDP datagram / one RT-FIFO
//! record per frame, at most [`MAX_FRAME_LEN`] = 90 bytes.
//!
//! ```text
//! offset size field
//!  0     2    magic 0x48 0x43 ("HC")
//!  2     1    version (1)
//!  3     1    frame type (FrameType)
//!  4     2    control word (flags, CTRL_*), big-endian
//!  6     2    session id, big-endian (0 = no session yet)
//!  8     4    sequence number, big-endian, per sender, wraps
//! 12     4    sender timestamp, µs, big-endian, wraps
//! 16     n    payload: XDR (RFC 4506), length fixed by the frame type
//! 16+n   4    CRC-32C of bytes 0..16+n, big-endian
//! ```
//!
//! Byte-by-byte layout of every payload: `Documentation/protocol.md`.
//! Floats are XDR `float` (IEEE-754 single) converted to and from `Fx`
//! with integer operations only ([`super::xdr`]). `decode` never panics and
//! returns a typed [`DecodeError`] for every malformed input.

use super::config::{CommandType, IndexingMode, ServoConfig, VirtualObjectParams};
use super::crc::crc32c;
use super::fixed::{Fx, Pose, Quat, Twist, Vec3, Wrench};
use super::vp::VpReceived;
use super::xdr::{fx_to_f32_bits, Decoder, Encoder, XdrError};

/// Largest frame, header and CRC included (spec §3.3.1.1).
pub const MAX_FRAME_LEN: usize = 90;
/// Bytes before the payload.
pub const HEADER_LEN: usize = 16;
/// Trailing CRC-32C.
pub const CRC_LEN: usize = 4;
/// Smallest frame (empty payload).
pub const MIN_FRAME_LEN: usize = HEADER_LEN + CRC_LEN;
/// Largest payload.
pub const MAX_PAYLOAD_LEN: usize = MAX_FRAME_LEN - MIN_FRAME_LEN;
/// First two bytes of every frame: "HC".
pub const MAGIC: [u8; 2] = [0x48, 0x43];
/// Protocol version carried at offset 2.
pub const VERSION: u8 = 1;

/// Control word: the sender asks for an [`Frame::Ack`] of this frame.
pub const CTRL_ACK_REQUEST: u16 = 1 << 0;
/// Control word: this frame is a retransmission (informational).
pub const CTRL_RETRANSMIT: u16 = 1 << 1;
/// Control word: on a `VprStream`, the header's timestamp field carries the
/// client's link energy grants (`link`: the energy it granted the
/// controller, a running total, u32 in 2⁻²⁰ J, wrapping) instead of its
/// clock; the controller then keeps the link passive
/// (`Documentation/control.md`). Ignored on other frames.
pub const CTRL_LINK_ENERGY: u16 = 1 << 2;
/// Control word bits that are defined; the others must be zero.
pub const CTRL_KNOWN: u16 = CTRL_ACK_REQUEST | CTRL_RETRANSMIT | CTRL_LINK_ENERGY;

/// Tolerance on |q|² of a received quaternion: accepted when
/// |1 − |q|²| ≤ 1/16 (the controller renormalises).
pub const QUAT_NORM2_TOLERANCE: Fx = Fx(1 << 28);
/// Largest accepted time step (s).
pub const MAX_TIME_STEP: Fx = Fx::ONE;

/// The header fields a sender chooses (magic, version and type are implied).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FrameHeader {
    /// `CTRL_*` flags.
    pub control: u16,
    /// Session id assigned by the controller in [`Frame::SessionAck`].
    pub session: u16,
    /// Sender's sequence number (wraps; compare with [`seq_newer`]).
    pub seq: u32,
    /// Sender's clock, µs (wraps).
    pub timestamp_us: u32,
}

/// Wire value of each frame type (offset 3).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum FrameType {
    OpenSession = 0x01,
    CloseSession = 0x02,
    SetBaseFrame = 0x03,
    SetObservationFrame = 0x04,
    SetFactors = 0x05,
    SetTimeStep = 0x06,
    SetCommandType = 0x07,
    SetIndexingMode = 0x08,
    AttachVirtualObject = 0x09,
    DetachVirtualObject = 0x0A,
    PowerRequest = 0x0B,
    VprStream = 0x0C,
    Answer = 0x81,
    AnswerTwist = 0x82,
    SessionAck = 0x83,
    Ack = 0x84,
    Error = 0x85,
}

impl FrameType {
    /// Every frame type, client → controller first.
    pub const ALL: [FrameType; 17] = [
        FrameType::OpenSession,
        FrameType::CloseSession,
        FrameType::SetBaseFrame,
        FrameType::SetObservationFrame,
        FrameType::SetFactors,
        FrameType::SetTimeStep,
        FrameType::SetCommandType,
        FrameType::SetIndexingMode,
        FrameType::AttachVirtualObject,
        FrameType::DetachVirtualObject,
        FrameType::PowerRequest,
        FrameType::VprStream,
        FrameType::Answer,
        FrameType::AnswerTwist,
        FrameType::SessionAck,
        FrameType::Ack,
        FrameType::Error,
    ];

    pub const fn from_u8(v: u8) -> Option<FrameType> {
        Some(match v {
            0x01 => FrameType::OpenSession,
            0x02 => FrameType::CloseSession,
            0x03 => FrameType::SetBaseFrame,
            0x04 => FrameType::SetObservationFrame,
            0x05 => FrameType::SetFactors,
            0x06 => FrameType::SetTimeStep,
            0x07 => FrameType::SetCommandType,
            0x08 => FrameType::SetIndexingMode,
            0x09 => FrameType::AttachVirtualObject,
            0x0A => FrameType::DetachVirtualObject,
            0x0B => FrameType::PowerRequest,
            0x0C => FrameType::VprStream,
            0x81 => FrameType::Answer,
            0x82 => FrameType::AnswerTwist,
            0x83 => FrameType::SessionAck,
            0x84 => FrameType::Ack,
            0x85 => FrameType::Error,
            _ => return None,
        })
    }

    /// True for client → controller frames (what PROTO_IN accepts).
    pub const fn is_request(self) -> bool {
        (self as u8) < 0x80
    }

    /// XDR payload length in bytes (always a multiple of 4).
    pub const fn payload_len(self) -> usize {
        match self {
            FrameType::OpenSession => 4,
            FrameType::CloseSession => 0,
            FrameType::SetBaseFrame | FrameType::SetObservationFrame => POSE_LEN,
            FrameType::SetFactors => 8,
            FrameType::SetTimeStep => 4,
            FrameType::SetCommandType => 4,
            FrameType::SetIndexingMode => 4,
            FrameType::AttachVirtualObject => 16,
            FrameType::DetachVirtualObject => 0,
            FrameType::PowerRequest => 4,
            FrameType::VprStream => POSE_LEN + TWIST_LEN,
            FrameType::Answer => POSE_LEN + WRENCH_LEN + 16,
            FrameType::AnswerTwist => TWIST_LEN + 20,
            FrameType::SessionAck => 8,
            FrameType::Ack => 8,
            FrameType::Error => 8,
        }
    }

    /// Whole frame length in bytes (header + payload + CRC).
    pub const fn frame_len(self) -> usize {
        MIN_FRAME_LEN + self.payload_len()
    }

    /// Name for logs.
    pub const fn name(self) -> &'static str {
        match self {
            FrameType::OpenSession => "open_session",
            FrameType::CloseSession => "close_session",
            FrameType::SetBaseFrame => "set_base_frame",
            FrameType::SetObservationFrame => "set_observation_frame",
            FrameType::SetFactors => "set_factors",
            FrameType::SetTimeStep => "set_time_step",
            FrameType::SetCommandType => "set_command_type",
            FrameType::SetIndexingMode => "set_indexing_mode",
            FrameType::AttachVirtualObject => "attach_virtual_object",
            FrameType::DetachVirtualObject => "detach_virtual_object",
            FrameType::PowerRequest => "power_request",
            FrameType::VprStream => "vpr_stream",
            FrameType::Answer => "answer",
            FrameType::AnswerTwist => "answer_twist",
            FrameType::SessionAck => "session_ack",
            FrameType::Ack => "ack",
            FrameType::Error => "error",
        }
    }
}

const POSE_LEN: usize = 7 * 4;
const TWIST_LEN: usize = 6 * 4;
const WRENCH_LEN: usize = 6 * 4;

/// The controller's per-cycle answer: handle pose, coupling wrench, status.
/// The handle twist does not fit in 90 bytes next to these (7 + 6 + 6 floats
/// + 4 words = 92 bytes of payload); it travels in [`AnswerTwist`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Answer {
    pub handle_pose: Pose,
    pub coupling_wrench: Wrench,
    /// `vp::status::*` bits.
    pub status: u32,
    /// `vp::alarm::*` bits.
    pub alarms: u32,
    /// Low 32 bits of the servo cycle counter.
    pub cycle: u32,
    /// Sequence number of the last VPr frame used.
    pub vpr_seq: u32,
}

/// The handle twist, sent every `proto_synchro::TWIST_EVERY` cycles.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AnswerTwist {
    pub handle_twist: Twist,
    pub status: u32,
    pub alarms: u32,
    pub cycle: u32,
    pub vpr_seq: u32,
    /// The controller's link energy grants: the energy it granted the
    /// client, a running total, 2⁻²⁰ J, wrapping (`link::energy_to_wire`).
    pub link_energy: u32,
}

/// One frame with its typed payload.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Frame {
    /// Client asks for a session; `client_nonce` is echoed in the ack.
    OpenSession {
        client_nonce: u32,
    },
    CloseSession,
    SetBaseFrame(Pose),
    SetObservationFrame(Pose),
    /// Force and speed factors, both > 0.
    SetFactors {
        force: Fx,
        speed: Fx,
    },
    /// Client time step, s, in (0, 1].
    SetTimeStep(Fx),
    SetCommandType(CommandType),
    SetIndexingMode(IndexingMode),
    /// Mass > 0 kg, inertia ≥ 0 kg·m².
    AttachVirtualObject(VirtualObjectParams),
    DetachVirtualObject,
    /// Arm supply on (true) or off (false).
    PowerRequest(bool),
    /// The client's virtual object (VPr).
    VprStream {
        pose: Pose,
        twist: Twist,
    },
    Answer(Answer),
    AnswerTwist(AnswerTwist),
    /// Session granted: id in the header, servo period in µs.
    SessionAck {
        client_nonce: u32,
        period_us: u32,
    },
    /// Acknowledges a frame sent with `CTRL_ACK_REQUEST`.
    Ack {
        acked_type: FrameType,
        acked_seq: u32,
    },
    /// A request was refused; `reason` is a `DecodeError::reason_index`
    /// or one of `ERROR_*`.
    Error {
        reason: u32,
        rejected_seq: u32,
    },
}

/// `Frame::Error` reasons beyond the decode reasons.
pub const ERROR_NO_SESSION: u32 = 0x100;
/// The request is valid but not allowed in the current state.
pub const ERROR_REFUSED: u32 = 0x101;

impl Frame {
    pub const fn frame_type(&self) -> FrameType {
        match self {
            Frame::OpenSession { .. } => FrameType::OpenSession,
            Frame::CloseSession => FrameType::CloseSession,
            Frame::SetBaseFrame(_) => FrameType::SetBaseFrame,
            Frame::SetObservationFrame(_) => FrameType::SetObservationFrame,
            Frame::SetFactors { .. } => FrameType::SetFactors,
            Frame::SetTimeStep(_) => FrameType::SetTimeStep,
            Frame::SetCommandType(_) => FrameType::SetCommandType,
            Frame::SetIndexingMode(_) => FrameType::SetIndexingMode,
            Frame::AttachVirtualObject(_) => FrameType::AttachVirtualObject,
            Frame::DetachVirtualObject => FrameType::DetachVirtualObject,
            Frame::PowerRequest(_) => FrameType::PowerRequest,
            Frame::VprStream { .. } => FrameType::VprStream,
            Frame::Answer(_) => FrameType::Answer,
            Frame::AnswerTwist(_) => FrameType::AnswerTwist,
            Frame::SessionAck { .. } => FrameType::SessionAck,
            Frame::Ack { .. } => FrameType::Ack,
            Frame::Error { .. } => FrameType::Error,
        }
    }

    /// Encoded length of this frame.
    pub const fn encoded_len(&self) -> usize {
        self.frame_type().frame_len()
    }
}

/// Why a frame was rejected. Checked in declaration order: length, magic,
/// version, CRC, type, length for the type, control word, then the payload
/// field by field.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DecodeError {
    /// Fewer than `MIN_FRAME_LEN` bytes.
    TooShort,
    /// More than `MAX_FRAME_LEN` bytes.
    TooLong,
    /// Bytes 0..2 are not "HC".
    BadMagic,
    /// Byte 2 is not `VERSION`.
    BadVersion,
    /// The trailing CRC-32C does not match.
    BadCrc,
    /// Byte 3 is not a known `FrameType`.
    UnknownType,
    /// The length does not match the frame type's.
    LengthMismatch,
    /// Reserved control-word bits set.
    BadFlags,
    /// A float is NaN or ±Inf.
    NotFinite,
    /// A value is outside its documented range.
    OutOfRange,
    /// An enum value is unknown.
    BadEnum,
    /// A bool is neither 0 nor 1.
    BadBool,
}

/// Names of the reject reasons, indexed by [`DecodeError::reason_index`].
pub const REASON_NAMES: [&str; DecodeError::COUNT] = [
    "too_short",
    "too_long",
    "bad_magic",
    "bad_version",
    "bad_crc",
    "unknown_type",
    "length_mismatch",
    "bad_flags",
    "not_finite",
    "out_of_range",
    "bad_enum",
    "bad_bool",
];

impl DecodeError {
    /// Number of reasons.
    pub const COUNT: usize = 12;
    /// Every reason, in index order.
    pub const ALL: [DecodeError; DecodeError::COUNT] = [
        DecodeError::TooShort,
        DecodeError::TooLong,
        DecodeError::BadMagic,
        DecodeError::BadVersion,
        DecodeError::BadCrc,
        DecodeError::UnknownType,
        DecodeError::LengthMismatch,
        DecodeError::BadFlags,
        DecodeError::NotFinite,
        DecodeError::OutOfRange,
        DecodeError::BadEnum,
        DecodeError::BadBool,
    ];

    /// Dense index 0..COUNT, for per-reason reject counters.
    pub const fn reason_index(self) -> usize {
        match self {
            DecodeError::TooShort => 0,
            DecodeError::TooLong => 1,
            DecodeError::BadMagic => 2,
            DecodeError::BadVersion => 3,
            DecodeError::BadCrc => 4,
            DecodeError::UnknownType => 5,
            DecodeError::LengthMismatch => 6,
            DecodeError::BadFlags => 7,
            DecodeError::NotFinite => 8,
            DecodeError::OutOfRange => 9,
            DecodeError::BadEnum => 10,
            DecodeError::BadBool => 11,
        }
    }

    /// The reason's name (`REASON_NAMES[reason_index()]`).
    pub const fn name(self) -> &'static str {
        REASON_NAMES[self.reason_index()]
    }

    /// Inverse of `reason_index`.
    pub const fn from_index(i: usize) -> Option<DecodeError> {
        if i < DecodeError::COUNT {
            Some(DecodeError::ALL[i])
        } else {
            None
        }
    }
}

impl From<XdrError> for DecodeError {
    fn from(e: XdrError) -> Self {
        match e {
            // The payload length is checked before decoding, so running out
            // of bytes means the length did not fit the type.
            XdrError::Short => DecodeError::LengthMismatch,
            XdrError::BadBool => DecodeError::BadBool,
            XdrError::NotFinite => DecodeError::NotFinite,
            XdrError::OutOfRange => DecodeError::OutOfRange,
        }
    }
}

/// Serial-number comparison (RFC 1982 style): is `a` newer than `b`?
pub const fn seq_newer(a: u32, b: u32) -> bool {
    let d = a.wrapping_sub(b);
    d != 0 && d < 0x8000_0000
}

/// Anti-replay window over a sender's sequence numbers (RFC 4303 §3.4.3
/// style): the newest accepted number and a bitmap of the
/// [`SeqWindow::SIZE`] numbers below it. A frame is fresh if it is newer
/// than the newest (serial-number order) or falls inside the window and was
/// not seen yet; a number seen before is a duplicate, one older than the
/// window is too old. Used by PROTO_IN (kernel) and by the authenticating
/// bridge and client (userspace), so both apply the same rule.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SeqWindow {
    top: u32,
    seen: u64,
    valid: bool,
}

/// What [`SeqWindow::check`] says about a sequence number.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SeqCheck {
    /// Newer than every accepted number (or the window is empty).
    Newer,
    /// Older than the newest, inside the window, not seen yet (reordered).
    InWindow,
    /// Already accepted once.
    Duplicate,
    /// Older than the window.
    TooOld,
}

impl SeqWindow {
    /// Sequence numbers remembered below the newest (the newest included).
    pub const SIZE: u32 = 64;

    /// An empty window: the first number is `Newer`.
    pub const fn new() -> Self {
        SeqWindow {
            top: 0,
            seen: 0,
            valid: false,
        }
    }

    /// Forget everything, then accept `seq` as the newest.
    pub fn reset(&mut self, seq: u32) {
        self.top = seq;
        self.seen = 1;
        self.valid = true;
    }

    /// Forget everything.
    pub fn clear(&mut self) {
        *self = SeqWindow::new();
    }

    /// The newest accepted number, if any.
    pub const fn newest(&self) -> Option<u32> {
        if self.valid {
            Some(self.top)
        } else {
            None
        }
    }

    /// Classify `seq` without changing the window.
    pub const fn check(&self, seq: u32) -> SeqCheck {
        if !self.valid || seq_newer(seq, self.top) {
            return SeqCheck::Newer;
        }
        let back = self.top.wrapping_sub(seq);
        if back >= Self::SIZE {
            return SeqCheck::TooOld;
        }
        if (self.seen >> back) & 1 == 1 {
            SeqCheck::Duplicate
        } else {
            SeqCheck::InWindow
        }
    }

    /// Accept `seq` if it is `Newer` or `InWindow`; returns its
    /// classification (the window changed only for those two).
    pub fn accept(&mut self, seq: u32) -> SeqCheck {
        let c = self.check(seq);
        match c {
            SeqCheck::Newer => {
                if self.valid {
                    let shift = seq.wrapping_sub(self.top);
                    self.seen = if shift >= Self::SIZE {
                        0
                    } else {
                        self.seen << shift
                    };
                    self.seen |= 1;
                    self.top = seq;
                } else {
                    self.reset(seq);
                }
            }
            SeqCheck::InWindow => {
                let back = self.top.wrapping_sub(seq);
                self.seen |= 1u64.checked_shl(back).unwrap_or(0);
            }
            SeqCheck::Duplicate | SeqCheck::TooOld => {}
        }
        c
    }
}

/// Length of the frame that starts with `prefix` (at least 4 bytes), from
/// its type; `None` if the prefix is too short or not a valid frame start.
/// For reassembling frames from a byte stream (the RT-FIFO handler).
pub fn expected_len(prefix: &[u8]) -> Option<usize> {
    match prefix {
        [m0, m1, ver, ty, ..] if [*m0, *m1] == MAGIC && *ver == VERSION => {
            FrameType::from_u8(*ty).map(FrameType::frame_len)
        }
        _ => None,
    }
}

fn put_vec3(e: &mut Encoder<'_>, v: &Vec3) -> Result<(), XdrError> {
    e.put_fx(v.x)?;
    e.put_fx(v.y)?;
    e.put_fx(v.z)
}

fn put_pose(e: &mut Encoder<'_>, p: &Pose) -> Result<(), XdrError> {
    put_vec3(e, &p.position)?;
    e.put_fx(p.orientation.x)?;
    e.put_fx(p.orientation.y)?;
    e.put_fx(p.orientation.z)?;
    e.put_fx(p.orientation.w)
}

fn put_twist(e: &mut Encoder<'_>, t: &Twist) -> Result<(), XdrError> {
    put_vec3(e, &t.linear)?;
    put_vec3(e, &t.angular)
}

fn put_wrench(e: &mut Encoder<'_>, w: &Wrench) -> Result<(), XdrError> {
    put_vec3(e, &w.force)?;
    put_vec3(e, &w.torque)
}

fn put_payload(e: &mut Encoder<'_>, frame: &Frame) -> Result<(), XdrError> {
    match frame {
        Frame::OpenSession { client_nonce } => e.put_u32(*client_nonce),
        Frame::CloseSession | Frame::DetachVirtualObject => Ok(()),
        Frame::SetBaseFrame(p) | Frame::SetObservationFrame(p) => put_pose(e, p),
        Frame::SetFactors { force, speed } => {
            e.put_fx(*force)?;
            e.put_fx(*speed)
        }
        Frame::SetTimeStep(dt) => e.put_fx(*dt),
        Frame::SetCommandType(c) => e.put_enum(*c as i32),
        Frame::SetIndexingMode(m) => e.put_enum(*m as i32),
        Frame::AttachVirtualObject(vo) => {
            e.put_fx(vo.mass)?;
            put_vec3(e, &vo.inertia)
        }
        Frame::PowerRequest(on) => e.put_bool(*on),
        Frame::VprStream { pose, twist } => {
            put_pose(e, pose)?;
            put_twist(e, twist)
        }
        Frame::Answer(a) => {
            put_pose(e, &a.handle_pose)?;
            put_wrench(e, &a.coupling_wrench)?;
            e.put_u32(a.status)?;
            e.put_u32(a.alarms)?;
            e.put_u32(a.cycle)?;
            e.put_u32(a.vpr_seq)
        }
        Frame::AnswerTwist(a) => {
            put_twist(e, &a.handle_twist)?;
            e.put_u32(a.status)?;
            e.put_u32(a.alarms)?;
            e.put_u32(a.cycle)?;
            e.put_u32(a.vpr_seq)?;
            e.put_u32(a.link_energy)
        }
        Frame::SessionAck {
            client_nonce,
            period_us,
        } => {
            e.put_u32(*client_nonce)?;
            e.put_u32(*period_us)
        }
        Frame::Ack {
            acked_type,
            acked_seq,
        } => {
            e.put_enum(*acked_type as u8 as i32)?;
            e.put_u32(*acked_seq)
        }
        Frame::Error {
            reason,
            rejected_seq,
        } => {
            e.put_u32(*reason)?;
            e.put_u32(*rejected_seq)
        }
    }
}

fn put_header(
    e: &mut Encoder<'_>,
    version: u8,
    ty: FrameType,
    h: &FrameHeader,
) -> Result<(), XdrError> {
    e.put_bytes(&MAGIC)?;
    e.put_bytes(&[version, ty as u8])?;
    e.put_bytes(&h.control.to_be_bytes())?;
    e.put_bytes(&h.session.to_be_bytes())?;
    e.put_u32(h.seq)?;
    e.put_u32(h.timestamp_us)
}

/// Write the 16-byte frame header at the start of `out`: magic "HC",
/// `version`, the type, then control, session, sequence number and
/// timestamp, big-endian (protocol.md §2; version 2 keeps this layout).
/// Returns false, having written nothing whole, if `out` is shorter than
/// [`HEADER_LEN`].
pub fn write_header(out: &mut [u8], version: u8, ty: FrameType, h: &FrameHeader) -> bool {
    if out.len() < HEADER_LEN {
        return false;
    }
    put_header(&mut Encoder::new(out), version, ty, h).is_ok()
}

/// The sender's header fields (control, session, sequence number,
/// timestamp) of a frame's first 16 bytes; `None` if there are fewer.
/// Magic, version and type (offsets 0–3) are not checked here.
pub fn read_header(bytes: &[u8]) -> Option<FrameHeader> {
    Some(FrameHeader {
        control: be16(bytes, 4)?,
        session: be16(bytes, 6)?,
        seq: be32(bytes, 8)?,
        timestamp_us: be32(bytes, 12)?,
    })
}

fn encode_inner(
    h: &FrameHeader,
    frame: &Frame,
    out: &mut [u8; MAX_FRAME_LEN],
) -> Result<usize, XdrError> {
    let ty = frame.frame_type();
    let len = ty.frame_len();
    let mut e = Encoder::new(&mut out[..]);
    put_header(&mut e, VERSION, ty, h)?;
    put_payload(&mut e, frame)?;
    let body = e.position();
    if body.checked_add(CRC_LEN) != Some(len) {
        return Err(XdrError::Short);
    }
    if !seal_crc(out.get_mut(..len).ok_or(XdrError::Short)?) {
        return Err(XdrError::Short);
    }
    Ok(len)
}

/// Write the frame's CRC-32C trailer: the last `CRC_LEN` bytes of `frame`
/// become the big-endian CRC of all the bytes before them (what [`decode`]
/// checks). For tools and tests that build or mutate raw frames. Returns
/// false, changing nothing, if `frame` is shorter than the trailer.
pub fn seal_crc(frame: &mut [u8]) -> bool {
    let Some(body_len) = frame.len().checked_sub(CRC_LEN) else {
        return false;
    };
    let (body, trailer) = frame.split_at_mut(body_len);
    trailer.copy_from_slice(&crc32c(body).to_be_bytes());
    true
}

/// Encode `frame` with header `h` into `out`; returns the frame length
/// (`frame.encoded_len()`, always ≤ `MAX_FRAME_LEN`). `Fx` values are
/// rounded to the nearest IEEE single. Bytes of `out` past the returned
/// length are left untouched. Cannot fail for any `Frame` (every type fits);
/// returns 0 only if that invariant were broken.
pub fn encode(h: &FrameHeader, frame: &Frame, out: &mut [u8; MAX_FRAME_LEN]) -> usize {
    // The answers SERVO sends every cycle: their fields as XDR words
    // written straight into place (the same bytes as the encoder's).
    let (words, n) = match frame {
        Frame::Answer(a) => (answer_words(a), ANSWER_WORDS),
        Frame::AnswerTwist(a) => (answer_twist_words(a), ANSWER_TWIST_WORDS),
        _ => return encode_inner(h, frame, out).unwrap_or(0),
    };
    let ty = frame.frame_type();
    let len = ty.frame_len();
    let body_end = len.wrapping_sub(CRC_LEN);
    if body_end != HEADER_LEN.wrapping_add(n.wrapping_mul(4)) || !write_header(out, VERSION, ty, h)
    {
        return encode_inner(h, frame, out).unwrap_or(0);
    }
    let Some(body) = out.get_mut(HEADER_LEN..body_end) else {
        return 0;
    };
    for (d, w) in body.chunks_exact_mut(4).zip(words.iter()) {
        d.copy_from_slice(&w.to_be_bytes());
    }
    let sealed = out.get_mut(..len).is_some_and(seal_crc);
    if sealed {
        len
    } else {
        0
    }
}

/// XDR words of an `Answer`'s payload and of an `AnswerTwist`'s.
const ANSWER_WORDS: usize = 17;
const ANSWER_TWIST_WORDS: usize = 11;

fn answer_words(a: &Answer) -> [u32; ANSWER_WORDS] {
    let (p, o) = (a.handle_pose.position, a.handle_pose.orientation);
    let (f, t) = (a.coupling_wrench.force, a.coupling_wrench.torque);
    let fl = fx_to_f32_bits;
    [
        fl(p.x),
        fl(p.y),
        fl(p.z),
        fl(o.x),
        fl(o.y),
        fl(o.z),
        fl(o.w),
        fl(f.x),
        fl(f.y),
        fl(f.z),
        fl(t.x),
        fl(t.y),
        fl(t.z),
        a.status,
        a.alarms,
        a.cycle,
        a.vpr_seq,
    ]
}

fn answer_twist_words(a: &AnswerTwist) -> [u32; ANSWER_WORDS] {
    let (l, w) = (a.handle_twist.linear, a.handle_twist.angular);
    let fl = fx_to_f32_bits;
    [
        fl(l.x),
        fl(l.y),
        fl(l.z),
        fl(w.x),
        fl(w.y),
        fl(w.z),
        a.status,
        a.alarms,
        a.cycle,
        a.vpr_seq,
        a.link_energy,
        0,
        0,
        0,
        0,
        0,
        0,
    ]
}

fn get_vec3(d: &mut Decoder<'_>) -> Result<Vec3, XdrError> {
    Ok(Vec3 {
        x: d.get_fx()?,
        y: d.get_fx()?,
        z: d.get_fx()?,
    })
}

/// `a·b` for |a|,|b| ≤ 2 (Q32.32, both pre-shifted to Q16.16: exact enough
/// for a norm check, no overflow).
fn mul_small(a: Fx, b: Fx) -> i64 {
    (a.0 >> 16).saturating_mul(b.0 >> 16)
}

fn check_quat(q: &Quat) -> Result<(), DecodeError> {
    let two = 2i64 << 32;
    for c in [q.x, q.y, q.z, q.w] {
        if !(-two..=two).contains(&c.0) {
            return Err(DecodeError::OutOfRange);
        }
    }
    let n2 = mul_small(q.x, q.x)
        .saturating_add(mul_small(q.y, q.y))
        .saturating_add(mul_small(q.z, q.z))
        .saturating_add(mul_small(q.w, q.w));
    let dev = n2.saturating_sub(Fx::ONE.0);
    if !(-QUAT_NORM2_TOLERANCE.0..=QUAT_NORM2_TOLERANCE.0).contains(&dev) {
        return Err(DecodeError::OutOfRange);
    }
    Ok(())
}

fn get_pose(d: &mut Decoder<'_>) -> Result<Pose, DecodeError> {
    let position = get_vec3(d)?;
    let orientation = Quat {
        x: d.get_fx()?,
        y: d.get_fx()?,
        z: d.get_fx()?,
        w: d.get_fx()?,
    };
    check_quat(&orientation)?;
    Ok(Pose {
        position,
        orientation,
    })
}

fn get_twist(d: &mut Decoder<'_>) -> Result<Twist, XdrError> {
    Ok(Twist {
        linear: get_vec3(d)?,
        angular: get_vec3(d)?,
    })
}

fn get_wrench(d: &mut Decoder<'_>) -> Result<Wrench, XdrError> {
    Ok(Wrench {
        force: get_vec3(d)?,
        torque: get_vec3(d)?,
    })
}

fn positive(v: Fx) -> Result<Fx, DecodeError> {
    if v.0 > 0 {
        Ok(v)
    } else {
        Err(DecodeError::OutOfRange)
    }
}

fn get_payload(ty: FrameType, d: &mut Decoder<'_>) -> Result<Frame, DecodeError> {
    Ok(match ty {
        FrameType::OpenSession => Frame::OpenSession {
            client_nonce: d.get_u32()?,
        },
        FrameType::CloseSession => Frame::CloseSession,
        FrameType::SetBaseFrame => Frame::SetBaseFrame(get_pose(d)?),
        FrameType::SetObservationFrame => Frame::SetObservationFrame(get_pose(d)?),
        FrameType::SetFactors => {
            let force = d.get_fx()?;
            let speed = d.get_fx()?;
            Frame::SetFactors {
                force: positive(force)?,
                speed: positive(speed)?,
            }
        }
        FrameType::SetTimeStep => {
            let dt = positive(d.get_fx()?)?;
            if dt > MAX_TIME_STEP {
                return Err(DecodeError::OutOfRange);
            }
            Frame::SetTimeStep(dt)
        }
        FrameType::SetCommandType => {
            let v = d.get_enum()?;
            let c = u32::try_from(v)
                .ok()
                .and_then(CommandType::from_u32)
                .ok_or(DecodeError::BadEnum)?;
            Frame::SetCommandType(c)
        }
        FrameType::SetIndexingMode => {
            let v = d.get_enum()?;
            let m = u32::try_from(v)
                .ok()
                .and_then(IndexingMode::from_u32)
                .ok_or(DecodeError::BadEnum)?;
            Frame::SetIndexingMode(m)
        }
        FrameType::AttachVirtualObject => {
            let mass = positive(d.get_fx()?)?;
            let inertia = get_vec3(d)?;
            if inertia.x.0 < 0 || inertia.y.0 < 0 || inertia.z.0 < 0 {
                return Err(DecodeError::OutOfRange);
            }
            Frame::AttachVirtualObject(VirtualObjectParams { mass, inertia })
        }
        FrameType::DetachVirtualObject => Frame::DetachVirtualObject,
        FrameType::PowerRequest => Frame::PowerRequest(d.get_bool()?),
        FrameType::VprStream => {
            let pose = get_pose(d)?;
            let twist = get_twist(d)?;
            Frame::VprStream { pose, twist }
        }
        FrameType::Answer => {
            let handle_pose = get_pose(d)?;
            let coupling_wrench = get_wrench(d)?;
            Frame::Answer(Answer {
                handle_pose,
                coupling_wrench,
                status: d.get_u32()?,
                alarms: d.get_u32()?,
                cycle: d.get_u32()?,
                vpr_seq: d.get_u32()?,
            })
        }
        FrameType::AnswerTwist => {
            let handle_twist = get_twist(d)?;
            Frame::AnswerTwist(AnswerTwist {
                handle_twist,
                status: d.get_u32()?,
                alarms: d.get_u32()?,
                cycle: d.get_u32()?,
                vpr_seq: d.get_u32()?,
                link_energy: d.get_u32()?,
            })
        }
        FrameType::SessionAck => Frame::SessionAck {
            client_nonce: d.get_u32()?,
            period_us: d.get_u32()?,
        },
        FrameType::Ack => {
            let v = d.get_enum()?;
            let acked_type = u8::try_from(v)
                .ok()
                .and_then(FrameType::from_u8)
                .ok_or(DecodeError::BadEnum)?;
            Frame::Ack {
                acked_type,
                acked_seq: d.get_u32()?,
            }
        }
        FrameType::Error => Frame::Error {
            reason: d.get_u32()?,
            rejected_seq: d.get_u32()?,
        },
    })
}

fn be16(b: &[u8], at: usize) -> Option<u16> {
    match b.get(at..at.checked_add(2)?)? {
        [x, y] => Some(u16::from_be_bytes([*x, *y])),
        _ => None,
    }
}

fn be32(b: &[u8], at: usize) -> Option<u32> {
    match b.get(at..at.checked_add(4)?)? {
        [a, b2, c, d] => Some(u32::from_be_bytes([*a, *b2, *c, *d])),
        _ => None,
    }
}

/// Decode one whole frame. Never panics; every malformed input gives a
/// [`DecodeError`] (see its doc for the order of the checks).
pub fn decode(bytes: &[u8]) -> Result<(FrameHeader, Frame), DecodeError> {
    let len = bytes.len();
    if len < MIN_FRAME_LEN {
        return Err(DecodeError::TooShort);
    }
    if len > MAX_FRAME_LEN {
        return Err(DecodeError::TooLong);
    }
    let (m0, m1, ver, ty) = match bytes {
        [a, b, c, d, ..] => (*a, *b, *c, *d),
        _ => return Err(DecodeError::TooShort),
    };
    if [m0, m1] != MAGIC {
        return Err(DecodeError::BadMagic);
    }
    if ver != VERSION {
        return Err(DecodeError::BadVersion);
    }
    let body_len = len - CRC_LEN; // len ≥ MIN_FRAME_LEN > CRC_LEN
    let body = bytes.get(..body_len).ok_or(DecodeError::TooShort)?;
    let crc = be32(bytes, body_len).ok_or(DecodeError::TooShort)?;
    if crc32c(body) != crc {
        return Err(DecodeError::BadCrc);
    }
    let ty = FrameType::from_u8(ty).ok_or(DecodeError::UnknownType)?;
    if len != ty.frame_len() {
        return Err(DecodeError::LengthMismatch);
    }
    let header = read_header(bytes).ok_or(DecodeError::TooShort)?;
    if header.control & !CTRL_KNOWN != 0 {
        return Err(DecodeError::BadFlags);
    }
    let payload = body.get(HEADER_LEN..).ok_or(DecodeError::TooShort)?;
    let mut d = Decoder::new(payload);
    let frame = get_payload(ty, &mut d)?;
    if d.remaining() != 0 {
        return Err(DecodeError::LengthMismatch);
    }
    Ok((header, frame))
}

/// Apply a configuration frame to `cfg` (PROTO_IN, under the configuration
/// lock). Returns true if `frame` was a configuration frame (base and
/// observation frames, factors, time step, command type, indexing mode,
/// attach/detach); false (and `cfg` untouched) for any other frame.
pub fn apply_to_config(frame: &Frame, cfg: &mut ServoConfig) -> bool {
    match frame {
        Frame::SetBaseFrame(p) => cfg.base_frame = *p,
        Frame::SetObservationFrame(p) => cfg.observation_frame = *p,
        Frame::SetFactors { force, speed } => {
            cfg.force_factor = *force;
            cfg.speed_factor = *speed;
        }
        Frame::SetTimeStep(dt) => cfg.time_step = *dt,
        Frame::SetCommandType(c) => cfg.command_type = *c,
        Frame::SetIndexingMode(m) => cfg.indexing_mode = *m,
        Frame::AttachVirtualObject(vo) => cfg.attached_object = Some(*vo),
        Frame::DetachVirtualObject => cfg.attached_object = None,
        _ => return false,
    }
    true
}

/// The VPr record a `VprStream` frame carries (PROTO_IN, under the protocol
/// lock); `None` for any other frame. `received_cycle` is the servo cycle
/// counter at decode time.
pub fn vpr_from(header: &FrameHeader, frame: &Frame, received_cycle: u64) -> Option<VpReceived> {
    match frame {
        Frame::VprStream { pose, twist } => Some(VpReceived {
            pose: *pose,
            twist: *twist,
            seq: header.seq,
            client_time_us: header.timestamp_us,
            received_cycle,
            valid: true,
            link_energy: header.control & CTRL_LINK_ENERGY != 0,
            heard_cycle: received_cycle,
        }),
        _ => None,
    }
}

/// Whether a decoded VPr frame should replace the current VPr: it must be
/// newer (serial-number order) unless the current one is not valid yet.
pub fn vpr_accept(current: &VpReceived, new_seq: u32) -> bool {
    !current.valid || seq_newer(new_seq, current.seq)
}

/// Power request carried by `frame`, if any.
pub const fn power_request(frame: &Frame) -> Option<bool> {
    match frame {
        Frame::PowerRequest(on) => Some(*on),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The answers' direct encoding gives the encoder's bytes and leaves
    /// the rest of the buffer alone, for any field values.
    #[test]
    fn answers_written_directly_equal_the_encoder() {
        let mut x = 0x2545_F491_4F6C_DD1Du64;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        for n in 0..20_000 {
            let mut fx = || {
                let r = next();
                Fx((r as i64) >> (r >> 58))
            };
            let pose = Pose {
                position: Vec3::new(fx(), fx(), fx()),
                orientation: Quat::new(fx(), fx(), fx(), fx()),
            };
            let a = Vec3::new(fx(), fx(), fx());
            let b = Vec3::new(fx(), fx(), fx());
            let words = [next() as u32, next() as u32, next() as u32, next() as u32];
            let h = FrameHeader {
                control: next() as u16,
                session: next() as u16,
                seq: next() as u32,
                timestamp_us: next() as u32,
            };
            let frame = if n % 2 == 0 {
                Frame::Answer(Answer {
                    handle_pose: pose,
                    coupling_wrench: Wrench {
                        force: a,
                        torque: b,
                    },
                    status: words[0],
                    alarms: words[1],
                    cycle: words[2],
                    vpr_seq: words[3],
                })
            } else {
                Frame::AnswerTwist(AnswerTwist {
                    handle_twist: Twist {
                        linear: a,
                        angular: b,
                    },
                    status: words[0],
                    alarms: words[1],
                    cycle: words[2],
                    vpr_seq: words[3],
                    link_energy: words[0] ^ words[3],
                })
            };
            let fill = next() as u8;
            let mut fast = [fill; MAX_FRAME_LEN];
            let mut slow = [fill; MAX_FRAME_LEN];
            let len = encode(&h, &frame, &mut fast);
            assert_eq!(Ok(len), encode_inner(&h, &frame, &mut slow));
            assert_eq!(len, frame.encoded_len());
            assert_eq!(fast, slow, "{frame:?}");
        }
    }

    fn v(x: i32, y: i32, z: i32) -> Vec3 {
        Vec3 {
            x: Fx::from_int(x),
            y: Fx::from_int(y),
            z: Fx::from_int(z),
        }
    }

    /// One sample of every frame type (values exactly representable in f32).
    pub(crate) fn samples() -> [Frame; 17] {
        let pose = Pose {
            position: Vec3 {
                x: Fx(1 << 31),
                y: Fx(-(1 << 30)),
                z: Fx(3 << 32),
            },
            orientation: Quat {
                x: Fx::ZERO,
                y: Fx::ZERO,
                z: Fx(-(1 << 31)),
                w: Fx(1 << 31),
            },
        };
        let pose = Pose {
            // |q|² = 0.5, out of tolerance: use a unit quaternion instead.
            orientation: Quat {
                x: Fx::ZERO,
                y: Fx::ZERO,
                z: Fx::ZERO,
                w: Fx::ONE,
            },
            ..pose
        };
        let twist = Twist {
            linear: v(1, 2, 3),
            angular: v(-1, 0, 1),
        };
        let wrench = Wrench {
            force: v(4, 5, 6),
            torque: v(0, -2, 0),
        };
        [
            Frame::OpenSession {
                client_nonce: 0xCAFE_F00D,
            },
            Frame::CloseSession,
            Frame::SetBaseFrame(pose),
            Frame::SetObservationFrame(Pose::default()),
            Frame::SetFactors {
                force: Fx::ONE,
                speed: Fx(1 << 31),
            },
            Frame::SetTimeStep(Fx(1 << 22)),
            Frame::SetCommandType(CommandType::Impedance),
            Frame::SetIndexingMode(IndexingMode::TransForceFeedbackInhibition),
            Frame::AttachVirtualObject(VirtualObjectParams {
                mass: Fx::from_int(2),
                inertia: v(0, 1, 2),
            }),
            Frame::DetachVirtualObject,
            Frame::PowerRequest(true),
            Frame::VprStream { pose, twist },
            Frame::Answer(Answer {
                handle_pose: pose,
                coupling_wrench: wrench,
                status: 3,
                alarms: 1,
                cycle: 77,
                vpr_seq: 76,
            }),
            Frame::AnswerTwist(AnswerTwist {
                handle_twist: twist,
                status: 3,
                alarms: 0,
                cycle: 78,
                vpr_seq: 76,
                link_energy: 0xFFFF_FFFF,
            }),
            Frame::SessionAck {
                client_nonce: 0xCAFE_F00D,
                period_us: 1000,
            },
            Frame::Ack {
                acked_type: FrameType::SetFactors,
                acked_seq: 9,
            },
            Frame::Error {
                reason: 4,
                rejected_seq: 10,
            },
        ]
    }

    #[test]
    fn every_type_round_trips_and_fits() {
        let h = FrameHeader {
            control: CTRL_ACK_REQUEST,
            session: 7,
            seq: 0x0102_0304,
            timestamp_us: 99,
        };
        for f in samples() {
            let mut buf = [0u8; MAX_FRAME_LEN];
            let n = encode(&h, &f, &mut buf);
            assert_eq!(n, f.encoded_len());
            assert!(n <= MAX_FRAME_LEN);
            assert_eq!(expected_len(&buf[..4]), Some(n));
            assert_eq!(decode(&buf[..n]), Ok((h, f)), "{:?}", f.frame_type());
        }
        let types: [FrameType; 17] = samples().map(|f| f.frame_type());
        assert_eq!(types, FrameType::ALL);
    }

    #[test]
    fn reason_names_match() {
        for (i, e) in DecodeError::ALL.iter().enumerate() {
            assert_eq!(e.reason_index(), i);
            assert_eq!(DecodeError::from_index(i), Some(*e));
        }
        assert_eq!(DecodeError::from_index(DecodeError::COUNT), None);
        assert_eq!(DecodeError::BadCrc.name(), "bad_crc");
    }

    #[test]
    fn seq_window_accepts_reordered_once_and_refuses_replays() {
        let mut w = SeqWindow::new();
        assert_eq!(w.accept(100), SeqCheck::Newer);
        assert_eq!(w.accept(105), SeqCheck::Newer);
        assert_eq!(w.accept(103), SeqCheck::InWindow);
        assert_eq!(w.accept(103), SeqCheck::Duplicate);
        assert_eq!(w.accept(105), SeqCheck::Duplicate);
        assert_eq!(w.accept(100), SeqCheck::Duplicate);
        assert_eq!(w.accept(105 - 63), SeqCheck::InWindow);
        assert_eq!(w.accept(105 - 64), SeqCheck::TooOld);
        assert_eq!(w.accept(105 + 64), SeqCheck::Newer);
        assert_eq!(w.check(105), SeqCheck::TooOld);
        assert_eq!(w.accept(106), SeqCheck::InWindow);
        // Wrap-around.
        let mut w = SeqWindow::new();
        w.reset(u32::MAX - 1);
        assert_eq!(w.accept(1), SeqCheck::Newer);
        assert_eq!(w.accept(u32::MAX), SeqCheck::InWindow);
        assert_eq!(w.accept(u32::MAX - 1), SeqCheck::Duplicate);
        assert_eq!(w.newest(), Some(1));
        // A jump of more than half the space is "older": refused.
        assert_eq!(w.accept(1u32.wrapping_add(0x8000_0000)), SeqCheck::TooOld);
    }

    #[test]
    fn header_codec_round_trip_and_short_buffers() {
        let h = FrameHeader {
            control: CTRL_ACK_REQUEST,
            session: 0x1234,
            seq: 0xdead_beef,
            timestamp_us: 7,
        };
        let mut out = [0u8; MAX_FRAME_LEN];
        assert!(write_header(&mut out, 2, FrameType::VprStream, &h));
        assert_eq!(
            out[..HEADER_LEN],
            [0x48, 0x43, 2, 0x0c, 0, 1, 0x12, 0x34, 0xde, 0xad, 0xbe, 0xef, 0, 0, 0, 7]
        );
        assert_eq!(read_header(&out), Some(h));
        // The header `encode` writes is the same.
        let mut enc = [0u8; MAX_FRAME_LEN];
        let n = encode(&h, &Frame::PowerRequest(true), &mut enc);
        assert!(write_header(&mut out, VERSION, FrameType::PowerRequest, &h));
        assert_eq!(enc[..HEADER_LEN], out[..HEADER_LEN]);
        assert_eq!(read_header(&enc[..n]), Some(h));
        for short in 0..HEADER_LEN {
            let mut b = [0u8; HEADER_LEN];
            assert!(!write_header(&mut b[..short], 2, FrameType::VprStream, &h));
            assert_eq!(read_header(&out[..short]), None);
        }
    }

    #[test]
    fn seq_order() {
        assert!(seq_newer(1, 0));
        assert!(seq_newer(0, u32::MAX));
        assert!(!seq_newer(5, 5));
        assert!(!seq_newer(4, 5));
    }
}
