// SPDX-License-Identifier: GPL-2.0

//! What the module needs from the kernel's configuration, checked once at
//! load (hap-core's `platform::check` decides): high-resolution timers
//! (CONFIG_HIGH_RES_TIMERS, active) and a fully preemptible kernel
//! (CONFIG_PREEMPT_RT: sleeping locks with priority inheritance, threaded
//! interrupts). Without PREEMPT_RT a reader of a module device that holds a
//! mutex SERVO needs is not boosted, and the cycle's wake-up latency has no
//! bound; loading there anyway is an explicit choice (`allow_non_rt=1`), for
//! development only.

use crate::hap_core::platform::{self, KernelFacts, Unfit};
use kernel::prelude::*;

/// The hrtimer resolution in ns: 1 once the kernel runs high-resolution
/// timers, the tick length (`LOW_RES_NSEC`, 1 ms) before the switch (early
/// boot, or no high-resolution clock event device) and always on a kernel
/// built without CONFIG_HIGH_RES_TIMERS, where `hrtimer_resolution` is a
/// macro for that constant rather than a variable.
#[cfg(CONFIG_HIGH_RES_TIMERS)]
pub(crate) fn hrtimer_resolution_ns() -> u32 {
    // SAFETY: with CONFIG_HIGH_RES_TIMERS, `hrtimer_resolution` is an
    // exported, naturally aligned `unsigned int` that the kernel only writes
    // when it switches timer modes; a racy read gives the old or the new
    // value, both meaningful.
    unsafe { core::ptr::read_volatile(&raw const kernel::bindings::hrtimer_resolution) }
}

/// See the CONFIG_HIGH_RES_TIMERS variant.
#[cfg(not(CONFIG_HIGH_RES_TIMERS))]
pub(crate) fn hrtimer_resolution_ns() -> u32 {
    kernel::bindings::LOW_RES_NSEC
}

/// Refuse a kernel the cycle cannot run on, with one dmesg line saying why
/// and insmod's errno; warn when `allow_non_rt` lets a non-RT kernel in.
pub(crate) fn check(period_us: u32, allow_non_rt: bool) -> Result {
    let facts = KernelFacts {
        high_res_timers: cfg!(CONFIG_HIGH_RES_TIMERS),
        hrtimer_resolution_ns: hrtimer_resolution_ns(),
        preempt_rt: cfg!(CONFIG_PREEMPT_RT),
    };
    match platform::check(facts, period_us, allow_non_rt) {
        Ok(()) => {
            if !facts.preempt_rt {
                pr_warn!("kernel without CONFIG_PREEMPT_RT, loading because allow_non_rt=1: no latency bound\n");
            }
            Ok(())
        }
        Err(Unfit::NoHighResTimers) => {
            pr_err!("refusing to load: kernel built without CONFIG_HIGH_RES_TIMERS (timers expire on the tick)\n");
            Err(ENODEV)
        }
        Err(Unfit::LowResolution(ns)) => {
            pr_err!(
                "high-resolution timers are not active (resolution {} ns); retry once the clocksource switched (see dmesg)\n",
                ns
            );
            Err(EAGAIN)
        }
        Err(Unfit::NotPreemptRt) => {
            pr_err!("refusing to load: kernel built without CONFIG_PREEMPT_RT (no priority inheritance on the module's locks, unbounded wake-up latency); load with allow_non_rt=1 to run anyway\n");
            Err(ENODEV)
        }
    }
}
