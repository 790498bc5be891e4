// SPDX-License-Identifier: GPL-2.0

//! The synchronizer (the spec's hap_proto_synchro), in SERVO's context:
//! try-lock `mtx_proto` to copy VPr (else hap-core extrapolates it), run the
//! servo cycle, then try-lock `mtx_proto` again to encode the answer frames
//! into rtf_out (skipped, and counted, when the lock is busy).

use crate::{
    hap_core::{
        cycle::{CycleResult, ServoCycle},
        io::MotorLine,
        protocol::MAX_FRAME_LEN,
        servo::{ServoInputs, ServoMode},
    },
    shared::{ServoData, Shared},
};
use kernel::sync::atomic::Relaxed;

pub(crate) fn run_cycle(
    sh: &Shared,
    data: &mut ServoData,
    line: &MotorLine,
    inputs: &ServoInputs,
    mode: ServoMode,
) -> CycleResult {
    // receive_vp
    let proto = sh.proto.try_lock();
    let vpr = proto.as_ref().map(|p| *p.vpr());
    drop(proto);
    let config = data.config;
    let result = data.cycle.run(line, inputs, &config, vpr.as_ref(), mode);

    // send_vp
    let Some(proto) = sh.proto.try_lock() else {
        sh.answers_skipped.add(1, Relaxed);
        return result;
    };
    let session = proto.session();
    drop(proto);
    if session == 0 {
        return result;
    }
    let mut frames = [[0u8; MAX_FRAME_LEN]; 2];
    let mut lens = [0usize; 2];
    let time_us = (sh.now_ns() / 1000) as u32;
    let n = ServoCycle::encode_answers(
        &result.vp,
        session,
        time_us,
        || sh.answer_seq.fetch_add(1, Relaxed).wrapping_add(1),
        &mut frames,
        &mut lens,
    );
    for (frame, len) in frames.iter().zip(lens.iter()).take(n) {
        if sh.rtf_out.push_overwrite(&frame[..*len]) {
            sh.answers_sent.add(1, Relaxed);
        } else {
            sh.answers_dropped.add(1, Relaxed);
        }
    }
    result
}
