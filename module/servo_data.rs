// SPDX-License-Identifier: GPL-2.0

//! SERVO's state (the spec's `data` structure, under `mtx_data`) and the
//! inputs and counters around it.
//!
//! Protocol:
//! - `data` (`mtx_data`): SERVO locks it for each cycle; module init locks
//!   it for the calibration, before the tasks start; the fail-safe only
//!   try-locks it, to log SERVO's last record. Device writes reach SERVO
//!   through lock-free hand-offs, never through this lock.
//! - `config`: PROTO_IN writes it (a configuration frame); SERVO only
//!   try-reads it and keeps its own copy when PROTO_IN is writing
//!   (counted in `config_busy`).
//! - The counters are SERVO's (Relaxed, statistics): `config_busy`,
//!   `vpr_extrapolated`, and `power_on_cycle`, the servo cycle of the last
//!   power-on request.

use crate::{
    hap_core::{
        config::ServoConfig,
        cycle::ServoCycle,
        effort::{EffortKeyframe, EFFORT_CAPACITY, EFFORT_RECORD_BYTES},
    },
    rwsem::RwSem,
};
use kernel::{
    c_str, new_mutex,
    prelude::*,
    static_lock_class,
    sync::{
        atomic::{Atomic, Relaxed},
        Mutex,
    },
};
use pin_init::init_zeroed;

/// No event recorded yet (a cycle number that never comes).
pub(crate) const NEVER: u64 = u64::MAX;

/// SERVO's data, under `mtx_data`.
#[pin_data]
pub(crate) struct ServoData {
    pub(crate) cycle: ServoCycle,
    /// SERVO's copy of the configuration, refreshed when the rwsem is free.
    pub(crate) config: ServoConfig,
    /// Scratch for an effort hand-off record and its keyframes.
    pub(crate) handoff: [u8; EFFORT_RECORD_BYTES],
    pub(crate) keys: [EffortKeyframe; EFFORT_CAPACITY],
}

// SAFETY: `EffortKeyframe` is integers only (`u32`, `[i32; 3]` twice, `u8`):
// all-zero is a valid value (`EffortKeyframe::ZERO`).
unsafe impl Zeroable for EffortKeyframe {}

impl ServoData {
    /// SERVO's data, built in its allocation: the scratch buffers zeroed in
    /// place, the servo state written by hap-core's constructor.
    fn new_boxed(period_us: u32) -> Result<KBox<ServoData>> {
        let mut data = KBox::init(
            init!(ServoData {
                cycle: ServoCycle::new(period_us),
                config: ServoConfig::default(),
                handoff <- init_zeroed(),
                keys <- init_zeroed(),
            }),
            GFP_KERNEL,
        )?;
        data.cycle.servo.init();
        Ok(data)
    }
}

/// See the module documentation for who writes and reads each field.
#[pin_data]
pub(crate) struct ServoState {
    /// `mtx_data`.
    #[pin]
    pub(crate) data: Mutex<KBox<ServoData>>,
    /// Read-mostly configuration: PROTO_IN writes, SERVO try-reads.
    #[pin]
    pub(crate) config: RwSem<ServoConfig>,
    pub(crate) config_busy: Atomic<u64>,
    pub(crate) vpr_extrapolated: Atomic<u64>,
    pub(crate) power_on_cycle: Atomic<u64>,
}

impl ServoState {
    pub(crate) fn new(period_us: u32) -> Result<impl PinInit<Self, Error>> {
        let data = ServoData::new_boxed(period_us)?;
        Ok(try_pin_init!(Self {
            data <- new_mutex!(data),
            config <- RwSem::new(ServoConfig::default(), c_str!("hap_config"), static_lock_class!()),
            config_busy: Atomic::new(0),
            vpr_extrapolated: Atomic::new(0),
            power_on_cycle: Atomic::new(NEVER),
        }? Error))
    }

    /// The servo cycle of the last power-on request, or `NEVER`.
    pub(crate) fn power_on_cycle(&self) -> u64 {
        self.power_on_cycle.load(Relaxed)
    }
}
