// SPDX-License-Identifier: GPL-2.0

//! Readings of the monotonic clock without a panic path.
//!
//! The kernel's `Instant<Monotonic>` subtracts and adds with overflow-checked
//! arithmetic (and an `assert!` on the sum): correct by its invariant, but a
//! `core::panicking` reference in every function of this module that does
//! time arithmetic (see scripts/check-ko-symbols.sh), and its nanoseconds are
//! not public. [`Ktime`] is the same `ktime_t`, read from `ktime_get()` as
//! rust/kernel/time.rs does, with saturating arithmetic; it converts to and
//! from `Instant<Monotonic>` only where the hrtimer API needs one.

use kernel::{
    bindings,
    time::{Instant, Monotonic},
};

/// A reading of `CLOCK_MONOTONIC`: nanoseconds as the kernel's `ktime_t`.
///
/// # Invariants
///
/// The value is in the range from 0 to `KTIME_MAX` (as `Instant`'s).
#[repr(transparent)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub(crate) struct Ktime(bindings::ktime_t);

// `Instant<C>` is `#[repr(transparent)]` over its `ktime_t` (rust/kernel/time.rs);
// the conversions below rely on it (`transmute` also checks the sizes).
const _: () = assert!(
    core::mem::size_of::<Instant<Monotonic>>() == core::mem::size_of::<bindings::ktime_t>()
        && core::mem::align_of::<Instant<Monotonic>>()
            == core::mem::align_of::<bindings::ktime_t>()
);

impl Ktime {
    /// Now.
    #[inline]
    pub(crate) fn now() -> Self {
        // SAFETY: It is always safe to call `ktime_get()` outside of NMI context.
        let t = unsafe { bindings::ktime_get() };
        // INVARIANT: `ktime_get()` returns a value in 0..=KTIME_MAX (`S64_MAX`);
        // the `max` only restates it.
        Ktime(t.max(0))
    }

    /// Nanoseconds from `earlier` to `self` (negative if `self` is earlier).
    #[inline]
    pub(crate) fn ns_since(self, earlier: Ktime) -> i64 {
        self.0.saturating_sub(earlier.0)
    }

    /// `self` plus `ns` nanoseconds, within 0..=KTIME_MAX.
    #[inline]
    pub(crate) fn saturating_add_ns(self, ns: i64) -> Self {
        // INVARIANT: saturated at KTIME_MAX (`S64_MAX`), floored at 0.
        Ktime(self.0.saturating_add(ns).max(0))
    }

    /// The reading an `Instant<Monotonic>` holds (a timer's expiry).
    #[inline]
    pub(crate) fn from_instant(t: Instant<Monotonic>) -> Self {
        // SAFETY: `Instant<Monotonic>` is `#[repr(transparent)]` over a
        // `ktime_t` (checked above): the value is that `ktime_t`, and every bit
        // pattern is a valid `ktime_t`.
        let ns = unsafe { core::mem::transmute::<Instant<Monotonic>, bindings::ktime_t>(t) };
        // INVARIANT: `Instant`'s own invariant is the same range.
        Ktime(ns.max(0))
    }

    /// This reading as an `Instant<Monotonic>` (a timer's absolute expiry).
    #[inline]
    pub(crate) fn to_instant(self) -> Instant<Monotonic> {
        // SAFETY: `Instant<Monotonic>` is `#[repr(transparent)]` over a
        // `ktime_t` (checked above), and by the type invariant the value is in
        // 0..=KTIME_MAX, which is `Instant`'s invariant.
        unsafe { core::mem::transmute::<bindings::ktime_t, Instant<Monotonic>>(self.0) }
    }
}

/// The controller's time base: the servo period and the origin of every
/// nanosecond stamp (set once at insmod, read by everyone, never written).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Timebase {
    pub(crate) period_us: u32,
    epoch: Ktime,
}

impl Timebase {
    pub(crate) fn new(period_us: u32) -> Self {
        Timebase {
            period_us,
            epoch: Ktime::now(),
        }
    }

    /// Nanoseconds since the epoch of a clock reading.
    pub(crate) fn ns_of(&self, t: Ktime) -> i64 {
        t.ns_since(self.epoch)
    }

    /// Nanoseconds since the epoch, now.
    pub(crate) fn now_ns(&self) -> i64 {
        self.ns_of(Ktime::now())
    }

    pub(crate) fn period_ns(&self) -> i64 {
        i64::from(self.period_us).saturating_mul(1000)
    }
}
