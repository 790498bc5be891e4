// SPDX-License-Identifier: GPL-2.0

//! SERVO (the spec's hap_servo): waits at the cycle barrier, then runs one
//! servo cycle under `mtx_data`: takes the effort commands handed over since
//! its last cycle, then the cycle itself (`servo_cycle.rs`: hap-core's
//! `ServoCycle::run` between the synchronizer's `receive_vp` and
//! `send_vp`); after
//! `mtx_data` is released it logs the simulator's position with the cycle's
//! timing. The main and the auxiliary (degraded) path
//! are the same code (spec §3.5); CLOCK's supervisor picks the mode through
//! the cycle handshake (`hap_core::handshake`); in `FailSafe` SERVO runs
//! nothing and leaves.
//!
//! Locks inside the cycle: `mtx_data` (SERVO's; module init takes it before
//! the tasks start, the fail-safe only try-locks it) and a try-read of the
//! configuration rwsem (PROTO_IN writes it). VPr and the session come from
//! the VPr latch, a seqcount read without any lock: SERVO never takes
//! `mtx_proto`. No lock a system call can hold: rtf_out, the position log
//! and the effort handoff are lock-free rings, a reader being stopped or
//! preempted cannot delay SERVO; SERVO rings their doorbells (a completion:
//! a raw spinlock held for a bounded wake-up) only when a reader sleeps. No
//! allocation and no printk inside the cycle. Motor commands go through
//! hap_io's motor line (`ArmIo::motor_line`), which is outside every lock:
//! the fail-safe cuts it whatever SERVO is doing.

use crate::{
    arm::{Arm, MAX_ARMS},
    completion::{Timeout, Wait},
    controller::Controller,
    effort::EffortTaker,
    hap_core::{
        mode::Mode,
        position_log::{LogRecord, LogTiming},
        protocol::MAX_FRAME_LEN,
    },
    kthread::CurrentKThread,
    ring::Producer,
    servo_cycle,
};
use kernel::prelude::*;

/// SERVO wakes at least this often at the barrier to check for a stop.
const BARRIER_WAIT: Timeout = Timeout::from_millis(100);

/// SERVO's sides of one arm's rings, held for SERVO's lifetime, and the
/// arm's protocol session for its log (kept while the latch is being
/// written).
struct ArmSides<'a> {
    arm: &'a Arm,
    answers: Producer<'a, MAX_FRAME_LEN>,
    effort: EffortTaker<'a>,
    session: u16,
}

/// SERVO's thread body: one cycle steps every arm, arm 0 first.
pub(crate) fn servo_main(kt: &CurrentKThread, sh: &Controller) {
    let clock = &sh.clock;
    let hs = &clock.handshake;
    let mut sides: [Option<ArmSides<'_>>; MAX_ARMS] = [const { None }; MAX_ARMS];
    for (slot, arm) in sides.iter_mut().zip(sh.arms()) {
        let (Some(answers), Some(effort)) =
            (arm.rtf.rtf_out.claim_producer(), arm.effort.claim_taker())
        else {
            pr_err!("SERVO: arm {}'s FIFO sides are already held\n", arm.index);
            return;
        };
        *slot = Some(ArmSides {
            arm,
            answers,
            effort,
            session: 0,
        });
    }
    let mut recs = [LogRecord::ZERO; MAX_ARMS];
    'cycles: while !kt.should_stop() && !sh.life.is_stopping() {
        hs.set_servo_waiting(true);
        let w = clock.cycle_start.wait_timeout(BARRIER_WAIT);
        hs.set_servo_waiting(false);
        if sh.life.is_stopping() {
            break;
        }
        if w == Wait::TimedOut {
            continue;
        }
        // The spec's servo_working = TRUE.
        let start = hs.servo_begin();
        if start.mode == Mode::FailSafe {
            // Fail-safe: SERVO runs nothing and leaves.
            hs.servo_leave();
            break;
        }
        let mode = start.mode;
        let start_ns = sh.time.now_ns();
        let expiry_ns = clock.expiry_ns();
        clock.stamp_servo_start(start_ns);

        for (s, rec) in sides.iter().flatten().zip(recs.iter_mut()) {
            let mut data = s.arm.servo.data.lock();
            // Faults are acted out inside the first arm's `mtx_data`.
            if s.arm.index == 0 && inject_fault(kt, sh) == Injected::Hung {
                // The hung SERVO is released only by rmmod: it never finishes.
                break 'cycles;
            }
            s.effort.take(&mut data);
            servo_cycle::run(sh, s.arm, &s.answers, &mut data, mode);
            *rec = *data.cycle.servo.log_record();
            drop(data);
        }

        for s in sides.iter_mut().flatten() {
            if let Some((session, _)) = s.arm.proto.latest_vpr() {
                s.session = session;
            }
        }
        let end_ns = sh.time.now_ns();
        clock.stamp_servo_end(end_ns);
        // Each arm's position log, with this cycle's timing (pushed after
        // the cycle so that the execution time includes everything SERVO
        // did).
        for (s, rec) in sides.iter().flatten().zip(recs.iter_mut()) {
            rec.timing = LogTiming {
                tick: start.tick,
                start_ns: u64::try_from(start_ns).unwrap_or(0),
                wakeup_ns: ns_u32(start_ns.saturating_sub(expiry_ns)),
                exec_ns: ns_u32(end_ns.saturating_sub(start_ns)),
                session: s.session,
            };
            s.arm.log.push(rec);
        }
        hs.servo_end(start.tick);
    }
}

/// The initial calibration (spec §3.2), at insmod before the tasks start:
/// one servo cycle of each arm at rest and no client. It takes every lock
/// of the cycle once, so first-use costs (lockdep registering its classes on
/// the debug kernel: milliseconds) are not paid inside the first real-time
/// cycle. Its inputs are those of every cycle before a client or a user acts,
/// so the host replay starts from the same state.
pub(crate) fn calibrate(sh: &Controller) -> Result {
    for arm in sh.arms() {
        // SERVO's side of rtf_out, given back before SERVO starts.
        let answers = arm.rtf.rtf_out.claim_producer().ok_or(EBUSY)?;
        let mut data = arm.servo.data.lock();
        servo_cycle::run(sh, arm, &answers, &mut data, Mode::Main);
        let rec = *data.cycle.servo.log_record();
        drop(data);
        arm.log.push(&rec);
    }
    Ok(())
}

fn ns_u32(ns: i64) -> u32 {
    u32::try_from(ns.max(0)).unwrap_or(u32::MAX)
}

/// What the fault injection did to this cycle.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Injected {
    Nothing,
    /// Stayed busy past the 3/4 check, then let the cycle run (late).
    Overrun,
    /// Hung until the module is removed.
    Hung,
}

/// Fault injection (`/dev/hap_fault`), called with `mtx_data` held, before
/// the cycle's work: the real fault is a cycle that takes too long (or never
/// ends) while holding SERVO's data, with the last motor command still on
/// the line. `overrun N`: stay busy past the 3/4 check, then run the cycle
/// late; `hang`: never finish, blocked (as in a deadlock) until rmmod stops
/// the thread.
fn inject_fault(kt: &CurrentKThread, sh: &Controller) -> Injected {
    if sh.faults.hang_requested() {
        while !kt.should_stop() {
            kernel::time::delay::fsleep(kernel::time::Delta::from_millis(1));
        }
        return Injected::Hung;
    }
    if !sh.faults.take_overrun() {
        return Injected::Nothing;
    }
    let until = sh
        .clock
        .expiry_ns()
        .saturating_add(sh.time.period_ns() / 8 * 7);
    while sh.time.now_ns() < until && !sh.life.is_stopping() {
        kernel::time::delay::udelay(kernel::time::Delta::from_micros(5));
    }
    Injected::Overrun
}
