// SPDX-License-Identifier: GPL-2.0

//! The synchronizer (the spec's hap_proto_synchro), in SERVO's context,
//! without any lock: copy VPr from the VPr latch (`Shared::latest_vpr`, a
//! seqcount PROTO_IN publishes under `mtx_proto` after each frame; if every
//! read attempt overlaps a publication, hap-core extrapolates VPr), run the
//! servo cycle, then read the latch's session again to encode the answer
//! frames into rtf_out (skipped, and counted in `answers_skipped`, when the
//! read overlaps a publication). SERVO never takes `mtx_proto`: neither
//! PROTO_IN decoding a frame nor monitoring can make it wait or skip for a
//! held lock. rtf_out is a lock-free ring: a full one refuses the answer
//! (counted in `answers_dropped`), SERVO never waits for its reader.

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
    // receive_vp: the VPr latch (`None` while a publication is being
    // written: hap-core extrapolates).
    let vpr = sh.latest_vpr().map(|(_, v)| v);
    let config = data.config;
    let result = data.cycle.run(line, inputs, &config, vpr.as_ref(), mode);

    // send_vp: the session as it is now (it may have closed meanwhile).
    let Some((session, _)) = sh.latest_vpr() else {
        sh.answers_skipped.add(1, Relaxed);
        return result;
    };
    if session == 0 {
        return result;
    }
    let mut frames = [[0u8; MAX_FRAME_LEN]; 2];
    let mut lens = [0usize; 2];
    let time_us = (sh.now_ns() / 1000) as u32; // wraps every ~71 min, as on the wire
    let n = ServoCycle::encode_answers(
        &result.vp,
        session,
        time_us,
        || sh.answer_seq.fetch_add(1, Relaxed).wrapping_add(1),
        &mut frames,
        &mut lens,
    );
    for (frame, len) in frames.iter().zip(lens.iter()).take(n) {
        if sh.rtf_out.push(frame.get(..*len).unwrap_or(&[])).is_ok() {
            sh.answers_sent.add(1, Relaxed);
        } else {
            sh.answers_dropped.add(1, Relaxed);
        }
    }
    result
}
