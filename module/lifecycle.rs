// SPDX-License-Identifier: GPL-2.0

//! The controller's life cycle: running or in fail-safe, the stop request
//! (`/dev/hap_stop`, the spec's `servo_stop`) and the flag that makes every
//! task leave its loop.
//!
//! Protocol:
//! - `stop_request`: written by `/dev/hap_stop` (Release), read by CLOCK
//!   once per period (Acquire); never cleared.
//! - `state`: written by CLOCK's fail-safe (Release) before its first step,
//!   read by /dev/hap_stats (Acquire). Unknown values read as fail-safe.
//! - `stopping`: set once (Release) by the fail-safe's `StopTasks` step or
//!   by rmmod, before they release the tasks' waits; every task reads it
//!   (Acquire) after each wake-up and leaves.

use crate::device::{HapDevice, OpenFile};
use core::sync::atomic::{AtomicBool, AtomicU8, Ordering};
use kernel::{iov::IovIterSource, prelude::*, sync::Arc};

/// Controller state, as shown in /dev/hap_stats.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum ControllerState {
    Running,
    FailSafe,
}

impl ControllerState {
    pub(crate) const fn as_u8(self) -> u8 {
        match self {
            ControllerState::Running => 0,
            ControllerState::FailSafe => 1,
        }
    }

    /// Unknown values read as `FailSafe` (the safe side).
    pub(crate) const fn from_u8(v: u8) -> Self {
        match v {
            0 => ControllerState::Running,
            _ => ControllerState::FailSafe,
        }
    }

    pub(crate) const fn name(self) -> &'static str {
        match self {
            ControllerState::Running => "running",
            ControllerState::FailSafe => "fail_safe",
        }
    }
}

/// See the module documentation for who writes and reads each field.
pub(crate) struct Lifecycle {
    state: AtomicU8,
    stop_request: AtomicBool,
    stopping: AtomicBool,
}

impl Lifecycle {
    pub(crate) const fn new() -> Self {
        Lifecycle {
            state: AtomicU8::new(ControllerState::Running.as_u8()),
            stop_request: AtomicBool::new(false),
            stopping: AtomicBool::new(false),
        }
    }

    pub(crate) fn state(&self) -> ControllerState {
        ControllerState::from_u8(self.state.load(Ordering::Acquire))
    }

    pub(crate) fn set_state(&self, s: ControllerState) {
        self.state.store(s.as_u8(), Ordering::Release);
    }

    pub(crate) fn request_stop(&self) {
        self.stop_request.store(true, Ordering::Release);
    }

    pub(crate) fn stop_requested(&self) -> bool {
        self.stop_request.load(Ordering::Acquire)
    }

    /// Every task leaves its loop from here on.
    pub(crate) fn set_stopping(&self) {
        self.stopping.store(true, Ordering::Release);
    }

    pub(crate) fn is_stopping(&self) -> bool {
        self.stopping.load(Ordering::Acquire)
    }
}

/// `/dev/hap_stop`: any write requests the application's termination.
pub(crate) struct Stop;

impl HapDevice for Stop {
    const NAMES: &'static [&'static CStr] = &[c"hap_stop"];
    type Part = Lifecycle;

    fn open(_life: &Arc<Lifecycle>) -> Result<Self> {
        Ok(Stop)
    }

    fn write(f: &OpenFile<Self>, iov: &mut IovIterSource<'_>) -> Result<usize> {
        let n = iov.len();
        iov.advance(n);
        f.part.request_stop();
        Ok(n)
    }
}
