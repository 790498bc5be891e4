//! PROTO_IN's logic (spec §3.3.1.2): what one frame received on rtf_in does.
//!
//! The kernel's PROTO_IN thread takes the protocol lock (`mtx_proto`), calls
//! [`ProtoIn::handle`] with the frame's bytes, and carries out the returned
//! [`Outcome`]: publish the new configuration (under the configuration
//! rwsem), forward a power request, queue the reply on rtf_out, count the
//! reject. The VPr shared memory lives here ([`ProtoIn::vpr`]); the kernel
//! publishes it with the session into the VPr latch after each frame, and
//! SERVO reads the latch, never this lock.
//!
//! Session rules:
//! - `OpenSession` opens a new session (a new client, or the same one after a
//!   restart): a fresh session id, an invalid VPr (the coupling fades out
//!   until the first `VprStream`), the default configuration, and a
//!   `SessionAck` echoing the client's nonce with the servo period. A copy
//!   of the request that opened the current session (same nonce: a client
//!   retransmitting because the ack was slow) is acknowledged again with the
//!   same session id and changes nothing.
//! - Every other request must carry the current session id, else it is
//!   rejected (`NoSession`) and answered with `Error(ERROR_NO_SESSION)`.
//! - Sequence numbers are checked against an anti-replay window
//!   ([`SeqWindow`], 64 numbers): a frame newer than the newest, or older
//!   but inside the window and not seen yet (reordered by the network), is
//!   applied; a duplicate or a frame older than the window is dropped as
//!   `Stale`, never applied twice. A `VprStream` older than the current VPr
//!   is counted but does not replace it (`vpr_accept`), and a reordered
//!   configuration or power request is not applied over a newer request of
//!   the same setting (counted in `superseded`, acknowledged all the same).
//! - Retransmission is idempotent: a duplicate of one of the last
//!   [`REACK_MEMORY`] acknowledged requests (same sequence number, same type,
//!   `CTRL_ACK_REQUEST`) gets the same `Ack` again and changes nothing
//!   (counted in `retransmits_reacked`), so a client whose ack was lost
//!   gets one by sending the same frame again.
//! - Frames only the controller sends (answers, acks, errors) are rejected
//!   as `NotARequest`.
//! - `CTRL_ACK_REQUEST` in the control word asks for an `Ack` reply.
//!
//! Malformed bytes never reach the VPr or the configuration: they are
//! rejected with the decoder's typed reason and get no reply (no
//! amplification of garbage).

use super::config::ServoConfig;
use super::protocol::{
    apply_to_config, decode, power_request, vpr_accept, vpr_from, DecodeError, Frame, FrameHeader,
    FrameType, SeqCheck, SeqWindow, CTRL_ACK_REQUEST, ERROR_NO_SESSION,
};

/// How many acknowledged requests PROTO_IN remembers to acknowledge a
/// retransmitted copy again.
pub const REACK_MEMORY: usize = 8;

/// Settings a request changes; a reordered request is not applied over a
/// newer one of the same setting.
const SLOTS: usize = 8;

/// The setting `frame` changes, if it is a configuration or power request.
const fn slot(frame: &Frame) -> Option<usize> {
    match frame {
        Frame::SetBaseFrame(_) => Some(0),
        Frame::SetObservationFrame(_) => Some(1),
        Frame::SetFactors { .. } => Some(2),
        Frame::SetTimeStep(_) => Some(3),
        Frame::SetCommandType(_) => Some(4),
        Frame::SetIndexingMode(_) => Some(5),
        Frame::AttachVirtualObject(_) | Frame::DetachVirtualObject => Some(6),
        Frame::PowerRequest(_) => Some(7),
        _ => None,
    }
}
use super::vp::VpReceived;
use super::words::WordWalk;

/// Why PROTO_IN dropped a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reject {
    /// The bytes are not a valid frame.
    Decode(DecodeError),
    /// A request without the current session id (or with no session open).
    NoSession,
    /// A sequence number not newer than the last accepted one.
    Stale,
    /// A frame type only the controller sends.
    NotARequest,
}

impl Reject {
    /// Number of PROTO_IN-level reasons (after the decoder's).
    pub const PROTOCOL_COUNT: usize = 3;
    /// Names of the PROTO_IN-level reasons, indexed by [`Reject::protocol_index`].
    pub const PROTOCOL_NAMES: [&'static str; Reject::PROTOCOL_COUNT] =
        ["no_session", "stale_seq", "not_a_request"];

    /// Index among the PROTO_IN-level reasons; `None` for decode errors.
    pub const fn protocol_index(self) -> Option<usize> {
        match self {
            Reject::Decode(_) => None,
            Reject::NoSession => Some(0),
            Reject::Stale => Some(1),
            Reject::NotARequest => Some(2),
        }
    }
}

/// What the kernel must do after [`ProtoIn::handle`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct Outcome {
    /// The frame was accepted and applied.
    pub accepted: bool,
    /// A reply to queue on rtf_out (the caller fills in seq and timestamp;
    /// the session is [`ProtoIn::session`]).
    pub reply: Option<Frame>,
    /// The configuration changed: publish [`ProtoIn::config`].
    pub config_changed: bool,
    /// A power request for the arm.
    pub power: Option<bool>,
    /// The VPr shared memory was replaced.
    pub vpr_updated: bool,
    /// A session was opened (true) or closed (false) by this frame.
    pub session_change: Option<bool>,
    /// Why the frame was dropped.
    pub rejected: Option<Reject>,
}

/// Counters kept by PROTO_IN.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct ProtoCounters {
    pub accepted: u64,
    pub decode_rejects: [u64; DecodeError::COUNT],
    pub protocol_rejects: [u64; Reject::PROTOCOL_COUNT],
    pub vpr_frames: u64,
    pub config_frames: u64,
    pub sessions_opened: u64,
    pub replies: u64,
    /// Duplicates of acknowledged requests answered with the same ack again.
    pub retransmits_reacked: u64,
    /// Reordered requests not applied because a newer request of the same
    /// setting already was (acknowledged all the same).
    pub superseded: u64,
}

impl ProtoCounters {
    /// All rejected frames.
    pub fn rejected_total(&self) -> u64 {
        let d = self
            .decode_rejects
            .iter()
            .fold(0u64, |a, b| a.saturating_add(*b));
        self.protocol_rejects
            .iter()
            .fold(d, |a, b| a.saturating_add(*b))
    }
}

/// PROTO_IN's publication after each frame: its counters and the session
/// (what /dev/hap_stats shows of PROTO_IN, without taking its lock).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct ProtoPublication {
    pub counters: ProtoCounters,
    /// The open session (0: none).
    pub session: u16,
}

/// Words of a [`ProtoPublication`] ([`ProtoPublication::visit_words`]).
pub const PROTO_PUBLICATION_WORDS: usize = 8 + DecodeError::COUNT + Reject::PROTOCOL_COUNT;

impl ProtoPublication {
    /// The publication's words (`PROTO_PUBLICATION_WORDS`, word `i` handed
    /// to `f` as `(i, &mut value)`: reading `*value` encodes, writing it
    /// decodes). The destructuring names every counter: a counter added to
    /// [`ProtoCounters`] without a word here does not compile.
    pub fn visit_words(&mut self, f: impl FnMut(usize, &mut u64)) {
        let ProtoCounters {
            accepted,
            decode_rejects,
            protocol_rejects,
            vpr_frames,
            config_frames,
            sessions_opened,
            replies,
            retransmits_reacked,
            superseded,
        } = &mut self.counters;
        let mut k = WordWalk::new(0, f);
        k.word(accepted);
        k.words(decode_rejects);
        k.words(protocol_rejects);
        k.word(vpr_frames);
        k.word(config_frames);
        k.word(sessions_opened);
        k.word(replies);
        k.word(retransmits_reacked);
        k.word(superseded);
        k.u16(&mut self.session);
    }

    /// PROTO_IN's lines of /dev/hap_stats (`key: value`), after the
    /// summary (which has `frames_in` and the decoder's `rejected.*`).
    /// Every key is listed in Documentation/protocol.md, §4.
    pub fn render(&self, w: &mut impl core::fmt::Write) -> core::fmt::Result {
        let c = &self.counters;
        writeln!(w, "session: {}", self.session)?;
        writeln!(w, "sessions_opened: {}", c.sessions_opened)?;
        writeln!(w, "vpr_frames: {}", c.vpr_frames)?;
        writeln!(w, "config_frames: {}", c.config_frames)?;
        writeln!(w, "replies: {}", c.replies)?;
        writeln!(w, "retransmits_reacked: {}", c.retransmits_reacked)?;
        writeln!(w, "superseded: {}", c.superseded)?;
        for (name, v) in Reject::PROTOCOL_NAMES.iter().zip(c.protocol_rejects.iter()) {
            writeln!(w, "rejected.{name}: {v}")?;
        }
        Ok(())
    }
}

/// PROTO_IN's state: the session, the VPr shared memory and the shadow of the
/// configuration (PROTO_IN is its only writer).
#[derive(Clone, Debug)]
pub struct ProtoIn {
    session: u16,
    session_nonce: u32,
    last_session: u16,
    window: SeqWindow,
    /// (sequence number, type) of the last acknowledged requests, a ring.
    acked: [Option<(u32, FrameType)>; REACK_MEMORY],
    acked_next: usize,
    /// Sequence number of the last applied request of each setting.
    applied: [Option<u32>; SLOTS],
    vpr: VpReceived,
    config: ServoConfig,
    counters: ProtoCounters,
}

impl Default for ProtoIn {
    fn default() -> Self {
        Self::new()
    }
}

impl ProtoIn {
    pub fn new() -> Self {
        ProtoIn {
            session: 0,
            session_nonce: 0,
            last_session: 0,
            window: SeqWindow::new(),
            acked: [None; REACK_MEMORY],
            acked_next: 0,
            applied: [None; SLOTS],
            vpr: VpReceived::default(),
            config: ServoConfig::default(),
            counters: ProtoCounters::default(),
        }
    }

    /// The open session's id (0: none).
    pub const fn session(&self) -> u16 {
        self.session
    }

    /// The VPr shared memory.
    pub const fn vpr(&self) -> &VpReceived {
        &self.vpr
    }

    /// The configuration as last set by the client.
    pub const fn config(&self) -> &ServoConfig {
        &self.config
    }

    pub const fn counters(&self) -> &ProtoCounters {
        &self.counters
    }

    /// Close the protocol (fail-safe step 3, or CloseSession): no session,
    /// VPr invalid, configuration back to its safe default.
    pub fn close(&mut self) {
        self.session = 0;
        self.window.clear();
        self.acked = [None; REACK_MEMORY];
        self.applied = [None; SLOTS];
        self.vpr = VpReceived::default();
        self.config = ServoConfig::default();
    }

    /// Handle one frame received on rtf_in at servo cycle `now_cycle`;
    /// `period_us` is reported to new sessions.
    pub fn handle(&mut self, bytes: &[u8], now_cycle: u64, period_us: u32) -> Outcome {
        let mut out = Outcome::default();
        let (header, frame) = match decode(bytes) {
            Ok(hf) => hf,
            Err(e) => {
                if let Some(n) = self.counters.decode_rejects.get_mut(e.reason_index()) {
                    *n = n.saturating_add(1);
                }
                out.rejected = Some(Reject::Decode(e));
                return out;
            }
        };
        let ty = frame.frame_type();
        if !ty.is_request() {
            return self.reject(out, Reject::NotARequest);
        }
        if let Frame::OpenSession { client_nonce } = frame {
            if self.session != 0 && client_nonce == self.session_nonce {
                // A retransmitted open: same session, nothing reset.
                self.counters.accepted = self.counters.accepted.saturating_add(1);
                self.counters.replies = self.counters.replies.saturating_add(1);
                out.accepted = true;
                out.reply = Some(Frame::SessionAck {
                    client_nonce,
                    period_us,
                });
                return out;
            }
            self.close();
            self.session_nonce = client_nonce;
            self.last_session = self.last_session.wrapping_add(1);
            if self.last_session == 0 {
                self.last_session = 1;
            }
            self.session = self.last_session;
            self.window.reset(header.seq);
            self.counters.sessions_opened = self.counters.sessions_opened.saturating_add(1);
            self.counters.accepted = self.counters.accepted.saturating_add(1);
            out.accepted = true;
            out.config_changed = true;
            out.session_change = Some(true);
            out.reply = Some(Frame::SessionAck {
                client_nonce,
                period_us,
            });
            self.counters.replies = self.counters.replies.saturating_add(1);
            return out;
        }
        if self.session == 0 || header.session != self.session {
            out = self.reject(out, Reject::NoSession);
            out.reply = Some(Frame::Error {
                reason: ERROR_NO_SESSION,
                rejected_seq: header.seq,
            });
            self.counters.replies = self.counters.replies.saturating_add(1);
            return out;
        }
        // A frame of the session: the link is alive, whatever its order.
        self.vpr.heard_cycle = now_cycle;
        match self.window.check(header.seq) {
            SeqCheck::Newer | SeqCheck::InWindow => {}
            SeqCheck::Duplicate
                if header.control & CTRL_ACK_REQUEST != 0 && self.was_acked(header.seq, ty) =>
            {
                // A retransmission whose ack was lost: the same ack again,
                // nothing applied twice.
                self.counters.retransmits_reacked =
                    self.counters.retransmits_reacked.saturating_add(1);
                self.counters.replies = self.counters.replies.saturating_add(1);
                out.reply = Some(Frame::Ack {
                    acked_type: ty,
                    acked_seq: header.seq,
                });
                return out;
            }
            SeqCheck::Duplicate | SeqCheck::TooOld => return self.reject(out, Reject::Stale),
        }
        self.window.accept(header.seq);
        self.apply(&header, &frame, now_cycle, &mut out);
        self.counters.accepted = self.counters.accepted.saturating_add(1);
        out.accepted = true;
        if header.control & CTRL_ACK_REQUEST != 0 && out.reply.is_none() {
            out.reply = Some(Frame::Ack {
                acked_type: ty,
                acked_seq: header.seq,
            });
        }
        if let Some(Frame::Ack {
            acked_type,
            acked_seq,
        }) = out.reply
        {
            self.remember_ack(acked_seq, acked_type);
        }
        if out.reply.is_some() {
            self.counters.replies = self.counters.replies.saturating_add(1);
        }
        out
    }

    fn was_acked(&self, seq: u32, ty: FrameType) -> bool {
        self.acked.contains(&Some((seq, ty)))
    }

    fn remember_ack(&mut self, seq: u32, ty: FrameType) {
        if self.session == 0 {
            return; // CloseSession: nothing left to re-acknowledge
        }
        if let Some(slot) = self.acked.get_mut(self.acked_next) {
            *slot = Some((seq, ty));
        }
        self.acked_next = self.acked_next.wrapping_add(1) % REACK_MEMORY;
    }

    fn apply(&mut self, header: &FrameHeader, frame: &Frame, now_cycle: u64, out: &mut Outcome) {
        if let Frame::CloseSession = frame {
            // Ack before closing: the reply still carries the session id.
            if header.control & CTRL_ACK_REQUEST != 0 {
                out.reply = Some(Frame::Ack {
                    acked_type: frame.frame_type(),
                    acked_seq: header.seq,
                });
            }
            self.close();
            out.config_changed = true;
            out.session_change = Some(false);
            return;
        }
        if let Some(i) = slot(frame) {
            if let Some(newest) = self.applied.get(i).copied().flatten() {
                if super::protocol::seq_newer(newest, header.seq) {
                    // Reordered behind a newer request of the same setting:
                    // that one stands (the ack still tells the client its
                    // request arrived).
                    self.counters.superseded = self.counters.superseded.saturating_add(1);
                    return;
                }
            }
            if let Some(a) = self.applied.get_mut(i) {
                *a = Some(header.seq);
            }
        }
        if apply_to_config(frame, &mut self.config) {
            self.counters.config_frames = self.counters.config_frames.saturating_add(1);
            out.config_changed = true;
            return;
        }
        if let Some(on) = power_request(frame) {
            out.power = Some(on);
            return;
        }
        if let Some(vpr) = vpr_from(header, frame, now_cycle) {
            self.counters.vpr_frames = self.counters.vpr_frames.saturating_add(1);
            if vpr_accept(&self.vpr, vpr.seq) {
                self.vpr = vpr;
                out.vpr_updated = true;
            }
        }
    }

    fn reject(&mut self, mut out: Outcome, why: Reject) -> Outcome {
        if let Some(i) = why.protocol_index() {
            if let Some(n) = self.counters.protocol_rejects.get_mut(i) {
                *n = n.saturating_add(1);
            }
        }
        out.rejected = Some(why);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::super::config::{CommandType, IndexingMode};
    use super::super::fixed::{Fx, Pose, Twist};
    use super::super::protocol::{encode, FrameType, MAX_FRAME_LEN};
    use super::*;

    fn bytes(session: u16, seq: u32, control: u16, f: &Frame) -> ([u8; MAX_FRAME_LEN], usize) {
        let mut buf = [0u8; MAX_FRAME_LEN];
        let h = FrameHeader {
            control,
            session,
            seq,
            timestamp_us: seq.wrapping_mul(1000),
        };
        let n = encode(&h, f, &mut buf);
        (buf, n)
    }

    fn handle(p: &mut ProtoIn, session: u16, seq: u32, control: u16, f: &Frame) -> Outcome {
        let (b, n) = bytes(session, seq, control, f);
        p.handle(&b[..n], 7, 1000)
    }

    fn open(p: &mut ProtoIn) -> u16 {
        open_with(p, 42)
    }

    fn open_with(p: &mut ProtoIn, nonce: u32) -> u16 {
        let o = handle(
            p,
            0,
            1,
            0,
            &Frame::OpenSession {
                client_nonce: nonce,
            },
        );
        assert!(o.accepted);
        assert_eq!(
            o.reply,
            Some(Frame::SessionAck {
                client_nonce: nonce,
                period_us: 1000
            })
        );
        assert_eq!(o.session_change, Some(true));
        p.session()
    }

    fn vpr_frame(x: i32) -> Frame {
        let mut pose = Pose::default();
        pose.position.x = Fx::from_ratio(i64::from(x), 100);
        Frame::VprStream {
            pose,
            twist: Twist::default(),
        }
    }

    #[test]
    fn garbage_is_rejected_with_reason_and_no_reply() {
        let mut p = ProtoIn::new();
        let o = p.handle(b"not a frame at all, but long enough", 0, 1000);
        assert!(!o.accepted);
        assert!(o.reply.is_none());
        assert!(matches!(o.rejected, Some(Reject::Decode(_))));
        assert_eq!(p.counters().rejected_total(), 1);
        let o = p.handle(&[], 0, 1000);
        assert_eq!(o.rejected, Some(Reject::Decode(DecodeError::TooShort)));
        assert!(!p.vpr().valid);
    }

    #[test]
    fn requests_need_the_session() {
        let mut p = ProtoIn::new();
        let o = handle(&mut p, 0, 1, 0, &vpr_frame(10));
        assert_eq!(o.rejected, Some(Reject::NoSession));
        assert!(matches!(
            o.reply,
            Some(Frame::Error {
                reason: ERROR_NO_SESSION,
                rejected_seq: 1
            })
        ));
        assert!(!p.vpr().valid);
        let s = open(&mut p);
        assert_ne!(s, 0);
        let o = handle(&mut p, s.wrapping_add(1), 2, 0, &vpr_frame(10));
        assert_eq!(o.rejected, Some(Reject::NoSession));
        let o = handle(&mut p, s, 2, 0, &vpr_frame(10));
        assert!(o.accepted && o.vpr_updated);
        assert!(p.vpr().valid);
        assert_eq!(p.vpr().seq, 2);
        assert_eq!(p.vpr().received_cycle, 7);
    }

    #[test]
    fn stale_and_duplicate_frames_are_dropped() {
        let mut p = ProtoIn::new();
        let s = open(&mut p);
        assert!(handle(&mut p, s, 10, 0, &vpr_frame(1)).vpr_updated);
        let dup = handle(&mut p, s, 10, 0, &vpr_frame(2));
        assert_eq!(dup.rejected, Some(Reject::Stale));
        // Reordered inside the window: accepted once, but an older VPr
        // never replaces a newer one.
        let old = handle(&mut p, s, 9, 0, &vpr_frame(3));
        assert!(old.accepted && !old.vpr_updated);
        assert_eq!(
            handle(&mut p, s, 9, 0, &vpr_frame(3)).rejected,
            Some(Reject::Stale)
        );
        assert!(handle(&mut p, s, 200, 0, &vpr_frame(4)).vpr_updated);
        let too_old = handle(&mut p, s, 200 - 64, 0, &vpr_frame(5));
        assert_eq!(too_old.rejected, Some(Reject::Stale));
        assert_eq!(p.vpr().pose.position.x, Fx::from_ratio(4, 100));
        // Wrap-around is newer.
        let mut p = ProtoIn::new();
        let o = handle(
            &mut p,
            0,
            u32::MAX,
            0,
            &Frame::OpenSession { client_nonce: 1 },
        );
        assert!(o.accepted);
        let s = p.session();
        assert!(handle(&mut p, s, 0, 0, &vpr_frame(5)).vpr_updated);
    }

    #[test]
    fn config_power_and_acks() {
        let mut p = ProtoIn::new();
        let s = open(&mut p);
        let o = handle(
            &mut p,
            s,
            2,
            CTRL_ACK_REQUEST,
            &Frame::SetCommandType(CommandType::Impedance),
        );
        assert!(o.config_changed);
        assert_eq!(p.config().command_type, CommandType::Impedance);
        assert_eq!(
            o.reply,
            Some(Frame::Ack {
                acked_type: FrameType::SetCommandType,
                acked_seq: 2
            })
        );
        let o = handle(&mut p, s, 3, 0, &Frame::PowerRequest(true));
        assert_eq!(o.power, Some(true));
        assert!(o.reply.is_none());
        // A new session (another nonce) resets the configuration.
        let s2 = open_with(&mut p, 7);
        assert_ne!(s2, s);
        assert_eq!(p.config().command_type, CommandType::None);
    }

    #[test]
    fn a_retransmitted_request_gets_the_same_ack_and_is_not_reapplied() {
        let mut p = ProtoIn::new();
        let s = open(&mut p);
        let f = Frame::SetCommandType(CommandType::Impedance);
        let first = handle(&mut p, s, 5, CTRL_ACK_REQUEST, &f);
        assert!(first.accepted && first.config_changed);
        // VPr frames overtake it (newer sequence numbers)...
        for seq in 6..20 {
            assert!(handle(&mut p, s, seq, 0, &vpr_frame(1)).accepted);
        }
        // ...the ack was lost, the client sends the same frame again.
        let again = handle(&mut p, s, 5, CTRL_ACK_REQUEST | 2, &f);
        assert_eq!(again.reply, first.reply);
        assert!(!again.config_changed);
        assert_eq!(again.rejected, None);
        assert_eq!(p.counters().retransmits_reacked, 1);
        assert_eq!(p.counters().config_frames, 1);
        // A reordered configuration frame (older than the newest VPr, never
        // seen) is applied and acked...
        let late = handle(
            &mut p,
            s,
            4,
            CTRL_ACK_REQUEST,
            &Frame::SetIndexingMode(IndexingMode::Trans),
        );
        assert!(late.config_changed);
        assert_eq!(p.config().indexing_mode, IndexingMode::Trans);
        // ...but not over a newer request of the same setting (seq 5).
        let older = handle(
            &mut p,
            s,
            3,
            CTRL_ACK_REQUEST,
            &Frame::SetCommandType(CommandType::VirtMech),
        );
        assert!(!older.config_changed);
        assert!(matches!(older.reply, Some(Frame::Ack { acked_seq: 3, .. })));
        assert_eq!(p.config().command_type, CommandType::Impedance);
        assert_eq!(p.counters().superseded, 1);
        // A duplicate of an un-acked frame, or of another type, is stale.
        assert_eq!(
            handle(&mut p, s, 6, CTRL_ACK_REQUEST, &vpr_frame(1)).rejected,
            Some(Reject::Stale)
        );
        assert_eq!(
            handle(&mut p, s, 5, CTRL_ACK_REQUEST, &Frame::PowerRequest(true)).rejected,
            Some(Reject::Stale)
        );
    }

    #[test]
    fn a_retransmitted_open_keeps_the_session() {
        let mut p = ProtoIn::new();
        let s = open(&mut p);
        assert!(
            handle(
                &mut p,
                s,
                2,
                0,
                &Frame::SetCommandType(CommandType::Impedance)
            )
            .config_changed
        );
        // The client did not see the ack in time and sends the same open again.
        let o = handle(&mut p, 0, 1, 0, &Frame::OpenSession { client_nonce: 42 });
        assert!(o.accepted);
        assert_eq!(o.session_change, None);
        assert!(!o.config_changed);
        assert_eq!(p.session(), s);
        assert_eq!(p.config().command_type, CommandType::Impedance);
        assert_eq!(p.counters().sessions_opened, 1);
        // Another nonce is another client (or a restart): a new session.
        let o = handle(&mut p, 0, 1, 0, &Frame::OpenSession { client_nonce: 43 });
        assert_eq!(o.session_change, Some(true));
        assert_ne!(p.session(), s);
    }

    #[test]
    fn controller_frames_are_not_requests() {
        let mut p = ProtoIn::new();
        let s = open(&mut p);
        let o = handle(
            &mut p,
            s,
            2,
            0,
            &Frame::Ack {
                acked_type: FrameType::Ack,
                acked_seq: 0,
            },
        );
        assert_eq!(o.rejected, Some(Reject::NotARequest));
    }

    #[test]
    fn close_session_and_fail_safe_close() {
        let mut p = ProtoIn::new();
        let s = open(&mut p);
        handle(&mut p, s, 2, 0, &vpr_frame(1));
        let o = handle(&mut p, s, 3, CTRL_ACK_REQUEST, &Frame::CloseSession);
        assert_eq!(o.session_change, Some(false));
        assert!(matches!(o.reply, Some(Frame::Ack { .. })));
        assert_eq!(p.session(), 0);
        assert!(!p.vpr().valid);
        let s = open(&mut p);
        handle(&mut p, s, 2, 0, &vpr_frame(1));
        p.close();
        assert_eq!(p.session(), 0);
        assert!(!p.vpr().valid);
        assert_eq!(
            handle(&mut p, s, 3, 0, &vpr_frame(1)).rejected,
            Some(Reject::NoSession)
        );
    }

    #[test]
    fn random_bytes_never_panic_nor_touch_vpr() {
        let mut p = ProtoIn::new();
        let s = open(&mut p);
        let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
        for i in 0..20_000u32 {
            let mut buf = [0u8; 96];
            let len = (i as usize) % 97;
            for b in buf.iter_mut().take(len) {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                *b = x as u8;
            }
            if i % 3 == 0 && len >= 4 {
                buf[0] = b'H';
                buf[1] = b'C';
                buf[2] = 1;
            }
            let o = p.handle(&buf[..len], 0, 1000);
            assert!(!o.vpr_updated);
            assert!(!o.accepted);
        }
        assert_eq!(p.session(), s);
        assert!(!p.vpr().valid);
        assert_eq!(p.counters().rejected_total(), 20_000);
    }

    #[test]
    fn publication_words_round_trip_every_counter() {
        let mut p = ProtoPublication {
            counters: ProtoCounters {
                accepted: 1,
                decode_rejects: core::array::from_fn(|i| 100 + i as u64),
                protocol_rejects: core::array::from_fn(|i| 200 + i as u64),
                vpr_frames: 3,
                config_frames: 4,
                sessions_opened: 5,
                replies: 6,
                retransmits_reacked: 7,
                superseded: u64::MAX,
            },
            session: 0xabcd,
        };
        let w: [u64; PROTO_PUBLICATION_WORDS] =
            super::super::words::check::to_words(|f| p.visit_words(f));
        let decode = |w: &[u64; PROTO_PUBLICATION_WORDS]| {
            let mut q = ProtoPublication::default();
            q.visit_words(|i, v| *v = w[i]);
            q
        };
        assert_eq!(decode(&w), p);
        // Each word reaches its own counter.
        for i in 0..PROTO_PUBLICATION_WORDS {
            let mut w2 = w;
            w2[i] ^= 1;
            assert_ne!(decode(&w2), p, "word {i} is not decoded");
        }
        // The counters a frame moves arrive: a re-acked retransmission and a
        // superseded request, counted by PROTO_IN, read back as counted.
        let mut proto = ProtoIn::new();
        let s = open(&mut proto);
        let set = Frame::SetTimeStep(Fx::from_ratio(1, 1000));
        handle(&mut proto, s, 5, CTRL_ACK_REQUEST, &set);
        handle(&mut proto, s, 5, CTRL_ACK_REQUEST, &set);
        handle(&mut proto, s, 3, CTRL_ACK_REQUEST, &set);
        p = ProtoPublication {
            counters: *proto.counters(),
            session: proto.session(),
        };
        assert_eq!(p.counters.retransmits_reacked, 1);
        assert_eq!(p.counters.superseded, 1);
        let w: [u64; PROTO_PUBLICATION_WORDS] =
            super::super::words::check::to_words(|f| p.visit_words(f));
        assert_eq!(decode(&w), p);
        let mut text = std::string::String::new();
        p.render(&mut text).unwrap();
        assert!(text.contains("retransmits_reacked: 1\n"), "{text}");
        assert!(text.contains("superseded: 1\n"), "{text}");
        assert!(text.contains(&format!("session: {s}\n")), "{text}");
    }
}
