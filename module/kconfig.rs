// SPDX-License-Identifier: GPL-2.0

//! What the module needs from the kernel's configuration, checked once at
//! load: high-resolution timers (CONFIG_HIGH_RES_TIMERS, active) and a fully
//! preemptible kernel (CONFIG_PREEMPT_RT: sleeping locks with priority
//! inheritance, threaded interrupts). Without PREEMPT_RT a reader of a module
//! device that holds a mutex SERVO needs is not boosted, and the cycle's
//! wake-up latency has no bound; loading there anyway is an explicit choice
//! (`allow_non_rt=1`), for development only.

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

/// Why the module refuses this kernel, if it does.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Unfit {
    /// Built without CONFIG_HIGH_RES_TIMERS: timers expire on the tick.
    NoHighResTimers,
    /// High-resolution timers not active (yet): the resolution, ns.
    LowResolution(u32),
    /// Built without CONFIG_PREEMPT_RT and `allow_non_rt` not set.
    NotPreemptRt,
}

/// Check the kernel for a cycle of `period_us`: high-resolution timers built
/// in and active (resolution at most 1/20 of the period: before the switch
/// hrtimers expire on the periodic tick, the 3/4-period check would land on
/// the next cycle's tick and every cycle would miss), and PREEMPT_RT unless
/// `allow_non_rt`.
pub(crate) fn check(period_us: u32, allow_non_rt: bool) -> Result<(), Unfit> {
    if !cfg!(CONFIG_HIGH_RES_TIMERS) {
        return Err(Unfit::NoHighResTimers);
    }
    let resolution = hrtimer_resolution_ns();
    if u64::from(resolution).saturating_mul(20) > u64::from(period_us).saturating_mul(1000) {
        return Err(Unfit::LowResolution(resolution));
    }
    if !cfg!(CONFIG_PREEMPT_RT) && !allow_non_rt {
        return Err(Unfit::NotPreemptRt);
    }
    Ok(())
}

impl Unfit {
    /// Print why (one dmesg line) and give insmod's errno.
    pub(crate) fn report(self) -> Error {
        match self {
            Unfit::NoHighResTimers => {
                pr_err!("refusing to load: kernel built without CONFIG_HIGH_RES_TIMERS (timers expire on the tick)\n");
                ENODEV
            }
            Unfit::LowResolution(ns) => {
                pr_err!(
                    "high-resolution timers are not active (resolution {} ns); retry once the clocksource switched (see dmesg)\n",
                    ns
                );
                EAGAIN
            }
            Unfit::NotPreemptRt => {
                pr_err!("refusing to load: kernel built without CONFIG_PREEMPT_RT (no priority inheritance on the module's locks, unbounded wake-up latency); load with allow_non_rt=1 to run anyway\n");
                ENODEV
            }
        }
    }
}
