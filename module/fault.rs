// SPDX-License-Identifier: GPL-2.0

//! `/dev/hap_fault`: fault injection for tests, inside SERVO's cycle with
//! `mtx_data` held and the last motor command still on the line (the real
//! faults, see `servo.rs`):
//! - `overrun N`: SERVO overruns its deadline (stays busy past CLOCK's 3/4
//!   check, then finishes the cycle late) for the next N cycles (0 < N <= 1000);
//! - `hang`: SERVO never finishes its cycle (until rmmod stops the thread).
//!
//! Anything else is `EINVAL`.

use crate::device::{HapDevice, OpenFile};
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use kernel::{iov::IovIterSource, prelude::*, sync::Arc};

/// The faults asked for, for SERVO to act out.
///
/// Protocol: /dev/hap_fault stores (Release); SERVO reads them (Acquire) at
/// the top of each cycle, inside `mtx_data`, and is the only one to count
/// `overruns` down.
pub(crate) struct FaultInjection {
    /// SERVO overruns this many more cycles, inside `mtx_data`.
    overruns: AtomicU32,
    /// SERVO hangs inside its cycle, holding `mtx_data`, until rmmod.
    hang: AtomicBool,
}

impl FaultInjection {
    pub(crate) const fn new() -> Self {
        FaultInjection {
            overruns: AtomicU32::new(0),
            hang: AtomicBool::new(false),
        }
    }

    pub(crate) fn hang_requested(&self) -> bool {
        self.hang.load(Ordering::Acquire)
    }

    /// SERVO: take one pending overrun, if any.
    pub(crate) fn take_overrun(&self) -> bool {
        let left = self.overruns.load(Ordering::Acquire);
        if left == 0 {
            return false;
        }
        self.overruns
            .store(left.saturating_sub(1), Ordering::Release);
        true
    }

    pub(crate) fn overruns_pending(&self) -> u32 {
        self.overruns.load(Ordering::Relaxed)
    }
}

/// `/dev/hap_fault`.
pub(crate) struct FaultDevice;

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

impl HapDevice for FaultDevice {
    const NAMES: &'static [&'static CStr] = &[c"hap_fault"];

    type Part = FaultInjection;

    fn open(_faults: &Arc<FaultInjection>) -> Result<Self> {
        Ok(FaultDevice)
    }

    fn write(f: &OpenFile<Self>, iov: &mut IovIterSource<'_>) -> Result<usize> {
        let mut buf = [0u8; 16];
        let len = iov.len();
        let dst = buf.get_mut(..len).filter(|d| !d.is_empty()).ok_or(EINVAL)?;
        let n = iov.copy_from_iter(dst);
        let faults = &f.part;
        match parse_fault(buf.get(..n).unwrap_or(&[])).ok_or(EINVAL)? {
            Fault::Overrun(count) => {
                faults.overruns.store(count, Ordering::Release);
                pr_info!(
                    "fault injection: SERVO overruns the next {} cycles inside its cycle\n",
                    count
                );
            }
            Fault::Hang => {
                faults.hang.store(true, Ordering::Release);
                pr_info!("fault injection: SERVO hangs inside its next cycle\n");
            }
        }
        Ok(n)
    }
}
