// SPDX-License-Identifier: GPL-2.0

//! `/dev/hap_fault`: fault injection for tests. Writing `overrun N` makes
//! SERVO overrun its deadline (stay busy past CLOCK's 3/4 check) for the next
//! N cycles (0 < N <= 1000). Anything else is `EINVAL`.

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

fn parse_overrun(b: &[u8]) -> Option<u32> {
    let b = b.strip_suffix(b"\n").unwrap_or(b);
    let digits = b.strip_prefix(b"overrun ")?;
    if digits.is_empty() || digits.len() > 4 {
        return None;
    }
    let mut n = 0u32;
    for d in digits {
        if !d.is_ascii_digit() {
            return None;
        }
        n = n * 10 + u32::from(d - b'0');
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
        let count = parse_overrun(buf.get(..n).unwrap_or(&[])).ok_or(EINVAL)?;
        kiocb.file().f.shared.fault_overruns.store(count, Release);
        pr_info!(
            "fault injection: SERVO overruns the next {} cycles\n",
            count
        );
        Ok(n)
    }
}
