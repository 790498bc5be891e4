// SPDX-License-Identifier: GPL-2.0

//! A counting completion (`struct completion`) with the operations the
//! kernel crate's `Completion` lacks in 7.3: `complete()` one waiter from any
//! context (hard IRQ included) and a timed wait.

use kernel::{bindings, prelude::*, types::Opaque};

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

    /// Sleep (uninterruptibly) until completed or `jiffies` elapsed.
    pub(crate) fn wait_timeout(&self, jiffies: c_ulong) -> Wait {
        // SAFETY: `inner` is an initialised completion; we may sleep here.
        let left = unsafe { bindings::wait_for_completion_timeout(self.inner.get(), jiffies) };
        if left == 0 {
            Wait::TimedOut
        } else {
            Wait::Completed
        }
    }
}
