// SPDX-License-Identifier: GPL-2.0

//! A counting completion (`struct completion`) with the operations the
//! kernel crate's `Completion` lacks in 7.3: `complete()` one waiter from any
//! context (hard IRQ included) and a timed wait whose time-out is a
//! duration ([`Timeout`], converted to jiffies at the call into C).

use kernel::{bindings, prelude::*, types::Opaque};

/// How long a wait may last: whole milliseconds, converted to jiffies by
/// the kernel's `msecs_to_jiffies` (rounded up: on HZ=250 one jiffy is
/// 4 ms, so 1 ms waits one jiffy).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Timeout {
    ms: u32,
}

impl Timeout {
    pub(crate) const fn from_millis(ms: u32) -> Self {
        Timeout { ms }
    }

    /// The time-out in jiffies, for the C wait functions.
    pub(crate) fn jiffies(self) -> kernel::time::Jiffies {
        kernel::time::msecs_to_jiffies(self.ms)
    }
}

/// Outcome of [`Completion::wait_timeout`].
#[derive(Clone, Copy, PartialEq, Eq)]
pub(crate) enum Wait {
    Completed,
    TimedOut,
}

#[pin_data]
pub(crate) struct Completion {
    #[pin]
    inner: Opaque<bindings::completion>,
}

// SAFETY: a `struct completion` may be signalled and waited on from any task.
unsafe impl Send for Completion {}
// SAFETY: all operations go through the kernel's own locking.
unsafe impl Sync for Completion {}

impl Completion {
    pub(crate) fn new() -> impl PinInit<Self> {
        pin_init!(Self {
            inner <- Opaque::ffi_init(|slot: *mut bindings::completion| {
                // SAFETY: `slot` points to an uninitialised `struct completion`.
                unsafe { bindings::init_completion(slot) };
            }),
        })
    }

    /// Wake one waiter (or let the next wait return at once). Safe in hard
    /// IRQ context: completions use a raw spinlock, also on PREEMPT_RT.
    pub(crate) fn complete(&self) {
        // SAFETY: `inner` is an initialised completion.
        unsafe { bindings::complete(self.inner.get()) };
    }

    /// Wake every present and future waiter (used to release threads at stop).
    pub(crate) fn complete_all(&self) {
        // SAFETY: `inner` is an initialised completion.
        unsafe { bindings::complete_all(self.inner.get()) };
    }

    /// Sleep (uninterruptibly) until completed or `timeout` elapsed.
    pub(crate) fn wait_timeout(&self, timeout: Timeout) -> Wait {
        // SAFETY: `inner` is an initialised completion; we may sleep here.
        let left =
            unsafe { bindings::wait_for_completion_timeout(self.inner.get(), timeout.jiffies()) };
        if left == 0 {
            Wait::TimedOut
        } else {
            Wait::Completed
        }
    }
}
