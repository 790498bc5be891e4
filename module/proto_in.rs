// SPDX-License-Identifier: GPL-2.0

//! PROTO_IN (the spec's hap_proto_in): the lowest-priority RT task. Sleeps
//! until rtf_in holds a frame (`sem_rtf_in`), then under `mtx_proto` lets
//! hap-core's `ProtoIn` check and decode it into VPr, and carries out the
//! outcome: configuration published under the rwsem, power request handed to
//! SERVO, reply queued on rtf_out's replies lane (PROTO_IN is its only
//! producer). Bad frames are counted by reason and never reach VPr. After
//! each frame its counters and session are published (`Shared::proto_pub`,
//! a seqcount), so that /dev/hap_stats never takes `mtx_proto`.

use crate::{
    completion::Wait,
    hap_core::protocol::{encode, FrameHeader, MAX_FRAME_LEN},
    hap_core::servo::PowerRequest,
    kthread::CurrentKThread,
    hap_core::proto_in::ProtoPublication,
    shared::Shared,
};
use kernel::sync::atomic::Relaxed;

/// PROTO_IN's thread body.
pub(crate) fn proto_in_main(kt: &CurrentKThread, sh: &Shared) {
    let mut frame = [0u8; MAX_FRAME_LEN];
    while !kt.should_stop() && !sh.is_stopping() {
        if sh.rtf_in_ready.wait_timeout(100) == Wait::TimedOut {
            continue;
        }
        while let Some(len) = sh.rtf_in.pop(&mut frame) {
            if sh.is_stopping() {
                return;
            }
            handle_frame(sh, frame.get(..len).unwrap_or(&[]));
        }
    }
}

fn handle_frame(sh: &Shared, bytes: &[u8]) {
    let now_cycle = sh.cycle.tick();
    let mut proto = sh.proto.lock();
    let outcome = proto.handle(bytes, now_cycle, sh.period_us);
    let session = proto.session();
    let config = if outcome.config_changed {
        Some(*proto.config())
    } else {
        None
    };
    let mut publication = ProtoPublication {
        counters: *proto.counters(),
        session,
    };
    // The VPr latch (SERVO's view of VPr and session), under `mtx_proto`.
    sh.publish_vpr(&proto);
    drop(proto);
    {
        let w = sh.proto_pub.write();
        publication.visit_words(|i, v| w.set(i, *v));
    }

    if let Some(cfg) = config {
        *sh.config.write() = cfg;
    }
    if let Some(on) = outcome.power {
        sh.request_power(if on {
            PowerRequest::On
        } else {
            PowerRequest::Off
        });
    }
    if let Some(reply) = outcome.reply {
        let header = FrameHeader {
            control: 0,
            session,
            seq: sh.answer_seq.fetch_add(1, Relaxed).wrapping_add(1),
            timestamp_us: (sh.now_ns() / 1000) as u32, // wraps, as on the wire
        };
        let mut out = [0u8; MAX_FRAME_LEN];
        let n = encode(&header, &reply, &mut out);
        if sh.rtf_replies.push(out.get(..n).unwrap_or(&[])).is_ok() {
            sh.rtf_out.wake_readers();
        } else {
            sh.answers_dropped.add(1, Relaxed);
        }
    }
}
