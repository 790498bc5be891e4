// SPDX-License-Identifier: GPL-2.0

//! `/dev/hap_fault`: fault injection for tests, inside SERVO's cycle with
//! `mtx_data` held and the last motor command still on the line (the real
//! faults, see `servo.rs`):
//! - `overrun N`: SERVO overruns its deadline (stays busy past CLOCK's 3/4
//!   check, then finishes the cycle late) for the next N cycles (0 < N <= 1000);
//! - `hang`: SERVO never finishes its cycle (until rmmod stops the thread).
//!
//! Anything else is `EINVAL`.

use crate::shared::DeviceFile;
use kernel::{
    fs::{File, Kiocb},
    iov::IovIterSource,
    miscdevice::{MiscDevice, MiscDeviceRegistration},
    prelude::*,
    sync::atomic::Release,
};

pub(crate) struct FaultDevice {
    f: DeviceFile,
}

/// A fault to inject.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Fault {
    Overrun(u32),
    Hang,
}

fn parse_fault(b: &[u8]) -> Option<Fault> {
    let b = b.strip_suffix(b"\n").unwrap_or(b);
    if b == b"hang" {
        return Some(Fault::Hang);
    }
    parse_overrun(b).map(Fault::Overrun)
}

fn parse_overrun(b: &[u8]) -> Option<u32> {
    let digits = b.strip_prefix(b"overrun ")?;
    if digits.is_empty() || digits.len() > 4 {
        return None;
    }
    let mut n = 0u32;
    for d in digits {
        if !d.is_ascii_digit() {
            return None;
        }
        n = n
            .checked_mul(10)?
            .checked_add(u32::from(d.checked_sub(b'0')?))?;
    }
    (1..=1000).contains(&n).then_some(n)
}

#[vtable]
impl MiscDevice for FaultDevice {
    type Ptr = KBox<Self>;

    fn open(file: &File, _misc: &MiscDeviceRegistration<Self>) -> Result<KBox<Self>> {
        Ok(KBox::new(
            FaultDevice {
                f: DeviceFile::open(file)?,
            },
            GFP_KERNEL,
        )?)
    }

    fn write_iter(kiocb: Kiocb<'_, Self::Ptr>, iov: &mut IovIterSource<'_>) -> Result<usize> {
        let mut buf = [0u8; 16];
        let len = iov.len();
        if len == 0 || len > buf.len() {
            return Err(EINVAL);
        }
        let n = iov.copy_from_iter(&mut buf[..len]);
        let sh = &kiocb.file().f.shared;
        match parse_fault(buf.get(..n).unwrap_or(&[])).ok_or(EINVAL)? {
            Fault::Overrun(count) => {
                sh.fault_overruns.store(count, Release);
                pr_info!(
                    "fault injection: SERVO overruns the next {} cycles inside its cycle\n",
                    count
                );
            }
            Fault::Hang => {
                sh.fault_hang.store(true, Release);
                pr_info!("fault injection: SERVO hangs inside its next cycle\n");
            }
        }
        Ok(n)
    }
}
