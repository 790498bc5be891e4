// SPDX-License-Identifier: GPL-2.0

//! One servo cycle, in SERVO's context with `mtx_data` held: the
//! configuration refreshed (a try-read of the rwsem), the power request
//! taken, then the spec's hap_proto_synchro around hap-core's
//! `ServoCycle::run` (get_measures → logical/physical state →
//! cartesian_control → send_commands → simulate_arm):
//! - `receive_vp`: VPr from the VPr latch (`ProtoState::latest_vpr`, a
//!   seqcount PROTO_IN publishes under `mtx_proto` after each frame; if
//!   every read attempt overlaps a publication, hap-core extrapolates VPr);
//! - `send_vp`: the latch's session read again, the answer frames encoded
//!   into rtf_out (skipped, and counted in `answers_skipped_latch_busy`,
//!   when that read overlaps a publication on every attempt).
//!
//! SERVO never takes `mtx_proto`: neither PROTO_IN decoding a frame nor
//! monitoring can make it wait or skip for a held lock. rtf_out is a
//! lock-free ring: a full one refuses the answer (counted in
//! `answers_dropped`), SERVO never waits for its reader.

use crate::{
    arm::Arm,
    controller::Controller,
    hap_core::{
        cycle::ServoCycle,
        mode::Mode,
        protocol::MAX_FRAME_LEN,
        servo::{PowerRequest, ServoInputs},
    },
    ring::Producer,
    servo_data::ServoData,
};
use kernel::sync::atomic::Relaxed;

/// Run one servo cycle of `arm` in `mode` on its SERVO `data`; the answers
/// go out through `answers`, SERVO's side of the arm's rtf_out.
pub(crate) fn run(
    sh: &Controller,
    arm: &Arm,
    answers: &Producer<'_, MAX_FRAME_LEN>,
    data: &mut ServoData,
    mode: Mode,
) {
    // Configuration: a fresh copy unless PROTO_IN is writing it.
    match arm.servo.config.try_read() {
        Some(cfg) => data.config = *cfg,
        None => {
            arm.servo.config_busy.add(1, Relaxed);
        }
    }
    // After a fail-safe the motor line refuses a power-on by itself.
    let power_request = arm.io.take_power_request();
    if power_request == PowerRequest::On {
        arm.servo
            .power_on_cycle
            .store(data.cycle.servo.cycle(), Relaxed);
    }
    let inputs = ServoInputs {
        power_request,
        live_effort: None,
    };

    // receive_vp: the VPr latch (`None` while a publication is being
    // written: hap-core extrapolates).
    let vpr = arm.proto.latest_vpr().map(|(_, v)| v);
    let config = data.config;
    let result = data
        .cycle
        .run(&arm.io.motor_line, &inputs, &config, vpr.as_ref(), mode);
    arm.io.set_last_status(result.vp.status);
    if result.extrapolated {
        arm.servo.vpr_extrapolated.add(1, Relaxed);
    }

    // send_vp: the session as it is now (it may have closed meanwhile).
    let rtf = &arm.rtf;
    let Some((session, _)) = arm.proto.latest_vpr() else {
        rtf.answers_skipped_latch_busy.add(1, Relaxed);
        return;
    };
    if session == 0 {
        return;
    }
    let mut frames = [[0u8; MAX_FRAME_LEN]; 2];
    let mut lens = [0usize; 2];
    let time_us = (sh.time.now_ns() / 1000) as u32; // wraps every ~71 min, as on the wire
    let n = ServoCycle::encode_answers(
        &result.vp,
        session,
        time_us,
        || rtf.next_seq(),
        &mut frames,
        &mut lens,
    );
    for (frame, len) in frames.iter().zip(lens.iter()).take(n) {
        if answers.push(frame.get(..*len).unwrap_or(&[])).is_ok() {
            rtf.answers_sent.add(1, Relaxed);
        } else {
            rtf.answers_dropped.add(1, Relaxed);
        }
    }
}
