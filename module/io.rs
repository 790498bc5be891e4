// SPDX-License-Identifier: GPL-2.0

//! hap_io's kernel side: the arm's power-on request line (the spec's
//! footnote 3: "a dedicated RT-FIFO, an associated handler and a global
//! flag"). Motor commands stay inhibited (hap-core's `MotorLine` gate)
//! until a power-on request; the fail-safe inhibits them for good.
//!
//! `/dev/hap_power`: write `1` (power on) or `0` (power off), optionally
//! followed by a newline; anything else is `EINVAL`. Reading gives the arm's
//! state as its lines show it, read from hap_io's motor line without any lock:
//! `power=<0|1> motors=<0|1> inhibited=<0|1> gate=<enabled|inhibited|fail_safe>`
//! then `command=` (what the DAC holds) and `applied=` (what the motors
//! produce now), six joint torques each in µN·m.

use crate::{
    device::{HapDevice, OpenFile},
    hap_core::{fixed::Joints, io::Gate, io::MotorLine, servo::PowerRequest, vp::status},
};
use core::{
    fmt::Write,
    sync::atomic::{AtomicU32, AtomicU8, Ordering},
};
use kernel::{
    iov::{IovIterDest, IovIterSource},
    prelude::*,
    sync::Arc,
};

/// The arm's lines: hap_io's motor line (gate, supply, the DAC's command),
/// the power request for SERVO, and the status bits of SERVO's last answer.
///
/// Protocol:
/// - `motor_line` (hap-core's `MotorLine`, its own orderings): SERVO writes
///   commands, the simulated motors read it at every sub-step, the
///   fail-safe and rmmod cut it with two stores; outside every lock.
/// - `power_request` (`PowerRequest` as its `u8`): stored (Release) by
///   /dev/hap_power and by PROTO_IN (the client's request); SERVO swaps it
///   back to `None` (AcqRel) at the top of its cycle. The last request
///   before SERVO's swap wins.
/// - `last_status`: SERVO stores (Release) each cycle's answer status; the
///   devices read it (Acquire), with the power and motor bits replaced by
///   what the motor line shows now.
pub(crate) struct ArmIo {
    pub(crate) motor_line: MotorLine,
    power_request: AtomicU8,
    last_status: AtomicU32,
}

impl ArmIo {
    pub(crate) const fn new() -> Self {
        ArmIo {
            motor_line: MotorLine::new(),
            power_request: AtomicU8::new(PowerRequest::None.as_u8()),
            last_status: AtomicU32::new(0),
        }
    }

    /// A power request (from /dev/hap_power or the client), for SERVO.
    pub(crate) fn request_power(&self, r: PowerRequest) {
        self.power_request.store(r.as_u8(), Ordering::Release);
    }

    /// SERVO: take the pending power request, if any.
    pub(crate) fn take_power_request(&self) -> PowerRequest {
        PowerRequest::from_u8(
            self.power_request
                .swap(PowerRequest::None.as_u8(), Ordering::AcqRel),
        )
    }

    /// SERVO: the status bits of this cycle's answer.
    pub(crate) fn set_last_status(&self, st: u32) {
        self.last_status.store(st, Ordering::Release);
    }

    /// The arm's status bits as the hardware lines show them: SERVO's last
    /// answer, with the power and motor bits read from the motor line now
    /// (the fail-safe cuts the line whatever SERVO does).
    pub(crate) fn arm_status(&self) -> u32 {
        let mut st =
            self.last_status.load(Ordering::Acquire) & !(status::POWER_ON | status::MOTORS_ENABLED);
        if self.motor_line.supply_on() {
            st |= status::POWER_ON;
        }
        if self.motor_line.motors_enabled() {
            st |= status::MOTORS_ENABLED;
        }
        st
    }
}

/// Joint torques as whole µN·m, comma-separated.
fn write_torques(w: &mut impl Write, tau: &Joints) -> core::fmt::Result {
    for (i, t) in tau.iter().enumerate() {
        let sep = if i == 0 { "" } else { "," };
        write!(w, "{sep}{}", t.mul_int(1_000_000).round_to_i64())?;
    }
    Ok(())
}

/// `/dev/hap_power`.
pub(crate) struct Power;

impl HapDevice for Power {
    const NAMES: &'static [&'static CStr] = &[c"hap_power", c"hap1_power"];

    type Part = ArmIo;

    fn open(_io: &Arc<ArmIo>) -> Result<Self> {
        Ok(Power)
    }

    fn write(f: &OpenFile<Self>, iov: &mut IovIterSource<'_>) -> Result<usize> {
        let mut buf = [0u8; 4];
        let len = iov.len();
        let dst = buf.get_mut(..len).filter(|d| !d.is_empty()).ok_or(EINVAL)?;
        let n = iov.copy_from_iter(dst);
        let req = match buf.get(..n) {
            Some(b"1") | Some(b"1\n") => PowerRequest::On,
            Some(b"0") | Some(b"0\n") => PowerRequest::Off,
            _ => return Err(EINVAL),
        };
        f.part.request_power(req);
        Ok(n)
    }

    fn read(f: &OpenFile<Self>, pos: &mut i64, iov: &mut IovIterDest<'_>) -> Result<usize> {
        let io = &f.part;
        let st = io.arm_status();
        let line = &io.motor_line;
        let gate = line.gate();
        let mut text = crate::uaccess::TextBuf::<256>::new();
        let _ = write!(
            text,
            "power={} motors={} inhibited={} gate={} command=",
            u8::from(st & status::POWER_ON != 0),
            u8::from(st & status::MOTORS_ENABLED != 0),
            u8::from(gate == Gate::FailSafe),
            gate.name()
        );
        let _ = write_torques(&mut text, &line.command());
        let _ = write!(text, " applied=");
        let _ = write_torques(&mut text, &line.applied());
        let _ = writeln!(text);
        crate::uaccess::read_at(iov, pos, text.as_bytes())
    }
}
