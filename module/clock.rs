// SPDX-License-Identifier: GPL-2.0

//! CLOCK (the spec's hap_clock): the synchronous cycle's top. An absolute,
//! hard-IRQ hrtimer on the period grid posts the cycle-start completion that
//! SERVO waits on.

use crate::shared::Shared;
use kernel::{
    impl_has_hr_timer,
    prelude::*,
    sync::{
        atomic::{Relaxed, Release},
        Arc, ArcBorrow,
    },
    time::{
        hrtimer::{
            AbsoluteHardMode, ArcHrTimerHandle, HrTimer, HrTimerCallback, HrTimerCallbackContext,
            HrTimerPointer, HrTimerRestart,
        },
        Instant, Monotonic,
    },
};

#[pin_data]
pub(crate) struct CycleTimer {
    #[pin]
    timer: HrTimer<Self>,
    shared: Arc<Shared>,
}

impl CycleTimer {
    /// Start the timer: first expiry one period from now, then every period.
    pub(crate) fn start(shared: Arc<Shared>) -> Result<ArcHrTimerHandle<Self>> {
        let first = Instant::<Monotonic>::now() + shared.period();
        let this = Arc::pin_init(
            pin_init!(Self {
                timer <- HrTimer::new(),
                shared,
            }),
            GFP_KERNEL,
        )?;
        Ok(this.start(first))
    }
}

impl HrTimerCallback for CycleTimer {
    type Pointer<'a> = Arc<Self>;

    fn run(this: ArcBorrow<'_, Self>, mut ctx: HrTimerCallbackContext<'_, Self>) -> HrTimerRestart {
        let shared = &this.shared;
        if shared.is_stopping() {
            return HrTimerRestart::NoRestart;
        }
        let expiry = shared.ns_of(this.timer.expires());
        shared.cycle_expiry_ns.store(expiry, Release);
        shared.timer_ticks.add(1, Relaxed);
        shared.cycle_start.complete();
        // Stay on the period grid; periods already past are skipped.
        ctx.forward_now(shared.period());
        HrTimerRestart::Restart
    }
}

impl_has_hr_timer! {
    impl HasHrTimer<Self> for CycleTimer {
        mode: AbsoluteHardMode<Monotonic>, field: self.timer
    }
}
