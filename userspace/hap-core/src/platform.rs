//! What hapticctrl needs from the kernel it runs on, decided from facts the
//! module reads (its build configuration, the hrtimer resolution) and its
//! `allow_non_rt` parameter.

/// Why a kernel is refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Unfit {
    /// Built without CONFIG_HIGH_RES_TIMERS: timers expire on the tick.
    NoHighResTimers,
    /// High-resolution timers not active (yet): the resolution, ns.
    LowResolution(u32),
    /// Built without CONFIG_PREEMPT_RT and `allow_non_rt` not set.
    NotPreemptRt,
}

/// The kernel as the module sees it at load.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct KernelFacts {
    /// CONFIG_HIGH_RES_TIMERS is set.
    pub high_res_timers: bool,
    /// The current hrtimer resolution, ns (1 once high-resolution mode is on).
    pub hrtimer_resolution_ns: u32,
    /// CONFIG_PREEMPT_RT is set.
    pub preempt_rt: bool,
}

/// Largest hrtimer resolution accepted for a period: 1/20 of it. Before the
/// kernel switches to high-resolution mode, hrtimers expire on the periodic
/// tick: the 3/4-period check would land on the next cycle's tick and every
/// cycle would miss.
pub const fn max_resolution_ns(period_us: u32) -> u64 {
    (period_us as u64).saturating_mul(1000) / 20
}

/// Whether a cycle of `period_us` can run on this kernel. The first reason
/// found, in this order: no high-resolution timers built in, not active,
/// no PREEMPT_RT (unless `allow_non_rt`).
pub const fn check(k: KernelFacts, period_us: u32, allow_non_rt: bool) -> Result<(), Unfit> {
    if !k.high_res_timers {
        return Err(Unfit::NoHighResTimers);
    }
    if k.hrtimer_resolution_ns as u64 > max_resolution_ns(period_us) {
        return Err(Unfit::LowResolution(k.hrtimer_resolution_ns));
    }
    if !k.preempt_rt && !allow_non_rt {
        return Err(Unfit::NotPreemptRt);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const RT: KernelFacts = KernelFacts {
        high_res_timers: true,
        hrtimer_resolution_ns: 1,
        preempt_rt: true,
    };

    #[test]
    fn a_preempt_rt_kernel_with_high_resolution_timers_is_fit() {
        assert_eq!(check(RT, 250, false), Ok(()));
        assert_eq!(check(RT, 10_000, false), Ok(()));
    }

    #[test]
    fn resolution_limit_is_a_twentieth_of_the_period() {
        assert_eq!(max_resolution_ns(1000), 50_000);
        let at = KernelFacts {
            hrtimer_resolution_ns: 50_000,
            ..RT
        };
        assert_eq!(check(at, 1000, false), Ok(()));
        let above = KernelFacts {
            hrtimer_resolution_ns: 50_001,
            ..RT
        };
        assert_eq!(check(above, 1000, false), Err(Unfit::LowResolution(50_001)));
        // The tick (1 ms at HZ=1000) before the switch to high resolution.
        let tick = KernelFacts {
            hrtimer_resolution_ns: 1_000_000,
            ..RT
        };
        assert_eq!(
            check(tick, 10_000, true),
            Err(Unfit::LowResolution(1_000_000))
        );
        // No overflow for any period.
        assert_eq!(max_resolution_ns(u32::MAX), u64::from(u32::MAX) * 50);
    }

    #[test]
    fn non_rt_kernel_only_with_allow_non_rt() {
        let stock = KernelFacts {
            preempt_rt: false,
            ..RT
        };
        assert_eq!(check(stock, 1000, false), Err(Unfit::NotPreemptRt));
        assert_eq!(check(stock, 1000, true), Ok(()));
    }

    #[test]
    fn no_high_res_timers_is_refused_whatever_the_parameter() {
        let lowres = KernelFacts {
            high_res_timers: false,
            hrtimer_resolution_ns: 1_000_000,
            preempt_rt: false,
        };
        assert_eq!(check(lowres, 1000, true), Err(Unfit::NoHighResTimers));
        // The reasons come in order: timers before PREEMPT_RT.
        let both = KernelFacts {
            hrtimer_resolution_ns: 1_000_000,
            preempt_rt: false,
            ..RT
        };
        assert_eq!(
            check(both, 1000, false),
            Err(Unfit::LowResolution(1_000_000))
        );
    }
}
