// SPDX-License-Identifier: GPL-2.0

//! PROTO_IN (the spec's hap_proto_in): the lowest-priority RT task, one per
//! arm (`hap_proto_in`, `hap_proto_in1`), each serving its arm only. Sleeps
//! until rtf_in holds a frame (`sem_rtf_in`), then under `mtx_proto` lets
//! hap-core's `ProtoIn` check and decode it into VPr, and carries out the
//! outcome: configuration published under the rwsem, power request handed to
//! SERVO, reply queued on rtf_out's replies lane (PROTO_IN is its only
//! producer). Bad frames are counted by reason and never reach VPr. After
//! each frame, still under `mtx_proto`, the VPr latch and PROTO_IN's
//! counters are published (`ProtoState`, two seqcounts), so that SERVO and
//! /dev/hap_stats never take `mtx_proto`.

use crate::{
    arm::Arm,
    completion::{Timeout, Wait},
    controller::Controller,
    hap_core::protocol::{encode, FrameHeader, MAX_FRAME_LEN},
    hap_core::servo::PowerRequest,
    kthread::CurrentKThread,
    ring::Producer,
};
use kernel::{
    prelude::*,
    sync::{atomic::Relaxed, Arc},
};

/// PROTO_IN wakes at least this often to check for a stop.
const FRAME_WAIT: Timeout = Timeout::from_millis(100);

/// What one PROTO_IN thread serves: arm `arm` of the controller.
pub(crate) struct ProtoInTask {
    pub(crate) ctrl: Arc<Controller>,
    pub(crate) arm: usize,
}

/// PROTO_IN's thread body.
pub(crate) fn proto_in_main(kt: &CurrentKThread, task: &ProtoInTask) {
    let sh = &*task.ctrl;
    let Some(arm) = sh.arm(task.arm) else {
        pr_err!("PROTO_IN: no arm {}\n", task.arm);
        return;
    };
    // PROTO_IN's sides of the arm's FIFOs, held for its lifetime.
    let (Some(frames), Some(replies)) = (
        arm.rtf.rtf_in.claim_consumer(),
        arm.rtf.rtf_replies.claim_producer(),
    ) else {
        pr_err!(
            "PROTO_IN: arm {}'s FIFO sides are already held\n",
            arm.index
        );
        return;
    };
    let mut frame = [0u8; MAX_FRAME_LEN];
    while !kt.should_stop() && !sh.life.is_stopping() {
        if arm.rtf.rtf_in_ready.wait_timeout(FRAME_WAIT) == Wait::TimedOut {
            continue;
        }
        while let Some(len) = frames.pop(&mut frame) {
            if sh.life.is_stopping() {
                return;
            }
            handle_frame(sh, arm, &replies, frame.get(..len).unwrap_or(&[]));
        }
    }
}

fn handle_frame(sh: &Controller, arm: &Arm, replies: &Producer<'_, MAX_FRAME_LEN>, bytes: &[u8]) {
    let now_cycle = sh.clock.handshake.tick();
    let mut proto = arm.proto.lock();
    let outcome = proto.handle(bytes, now_cycle, sh.time.period_us);
    let session = proto.session();
    let config = if outcome.config_changed {
        Some(*proto.config())
    } else {
        None
    };
    // SERVO's view of VPr and session, and the counters, under `mtx_proto`.
    arm.proto.publish_vpr(&proto);
    arm.proto.publish_counters(&proto);
    drop(proto);

    if let Some(cfg) = config {
        *arm.servo.config.write() = cfg;
    }
    if let Some(on) = outcome.power {
        arm.io.request_power(if on {
            PowerRequest::On
        } else {
            PowerRequest::Off
        });
    }
    if let Some(reply) = outcome.reply {
        let rtf = &arm.rtf;
        let header = FrameHeader {
            control: 0,
            session,
            seq: rtf.next_seq(),
            timestamp_us: (sh.time.now_ns() / 1000) as u32, // wraps, as on the wire
        };
        let mut out = [0u8; MAX_FRAME_LEN];
        let n = encode(&header, &reply, &mut out);
        if replies.push(out.get(..n).unwrap_or(&[])).is_ok() {
            rtf.rtf_out.wake_readers();
        } else {
            rtf.answers_dropped.add(1, Relaxed);
        }
    }
}
