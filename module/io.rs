// SPDX-License-Identifier: GPL-2.0

//! hap_io's kernel side: the arm's power-on request line (the spec's
//! footnote 3: "a dedicated RT-FIFO, an associated handler and a global
//! flag"). Motor commands stay inhibited (in hap-core's `Io`) until a
//! power-on request; the fail-safe inhibits them for good.
//!
//! `/dev/hap_power`: write `1` (power on) or `0` (power off), optionally
//! followed by a newline; anything else is `EINVAL`. Reading gives the arm's
//! state as its lines show it, read from hap_io's motor line without any lock:
//! `power=<0|1> motors=<0|1> inhibited=<0|1> gate=<enabled|inhibited|fail_safe>`
//! then `command=` (what the DAC holds) and `applied=` (what the motors
//! produce now), six joint torques each in µN·m.

use crate::{
    hap_core::{
        fixed::Joints,
        io::Gate,
        vp::status,
    },
    shared::{DeviceFile, Shared},
};
use core::fmt::Write;
use kernel::{
    fs::{File, Kiocb},
    iov::{IovIterDest, IovIterSource},
    miscdevice::{MiscDevice, MiscDeviceRegistration},
    prelude::*,
    sync::atomic::{Acquire, Release},
};

/// The arm's status bits as the hardware lines show them: SERVO's last
/// answer, with the power and motor bits read from the motor line now (the
/// fail-safe cuts the line whatever SERVO does).
pub(crate) fn arm_status(sh: &Shared) -> u32 {
    let mut st = sh.last_status.load(Acquire) & !(status::POWER_ON | status::MOTORS_ENABLED);
    if sh.motor_line.supply_on() {
        st |= status::POWER_ON;
    }
    if sh.motor_line.motors_enabled() {
        st |= status::MOTORS_ENABLED;
    }
    st
}

/// Joint torques as whole µN·m, comma-separated.
fn write_torques(w: &mut impl Write, tau: &Joints) -> core::fmt::Result {
    for (i, t) in tau.iter().enumerate() {
        let sep = if i == 0 { "" } else { "," };
        write!(w, "{sep}{}", t.mul_int(1_000_000).round_to_i64())?;
    }
    Ok(())
}

pub(crate) struct PowerDevice {
    f: DeviceFile,
}

#[vtable]
impl MiscDevice for PowerDevice {
    type Ptr = KBox<Self>;

    fn open(file: &File, _misc: &MiscDeviceRegistration<Self>) -> Result<KBox<Self>> {
        Ok(KBox::new(
            PowerDevice {
                f: DeviceFile::open(file)?,
            },
            GFP_KERNEL,
        )?)
    }

    fn write_iter(kiocb: Kiocb<'_, Self::Ptr>, iov: &mut IovIterSource<'_>) -> Result<usize> {
        let mut buf = [0u8; 4];
        let len = iov.len();
        if len == 0 || len > buf.len() {
            return Err(EINVAL);
        }
        let n = iov.copy_from_iter(&mut buf[..len]);
        let req = match buf.get(..n) {
            Some(b"1") | Some(b"1\n") => 1,
            Some(b"0") | Some(b"0\n") => 2,
            _ => return Err(EINVAL),
        };
        kiocb.file().f.shared.power_request.store(req, Release);
        Ok(n)
    }

    fn read_iter(mut kiocb: Kiocb<'_, Self::Ptr>, iov: &mut IovIterDest<'_>) -> Result<usize> {
        let sh = &kiocb.file().f.shared;
        let st = arm_status(sh);
        let line = &sh.motor_line;
        let gate = line.gate();
        let mut text = crate::stats::TextBuf::<256>::new();
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
        iov.simple_read_from_buffer(kiocb.ki_pos_mut(), text.as_bytes())
    }
}
