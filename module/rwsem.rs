// SPDX-License-Identifier: GPL-2.0

//! A read-mostly value behind a `struct rw_semaphore`: the kernel crate has
//! no rwsem abstraction in 7.3, so the raw bindings are wrapped once here.
//! PROTO_IN writes the servo configuration; SERVO only try-reads it and keeps
//! its previous copy when a write is in progress.

use core::{cell::UnsafeCell, marker::PhantomPinned};
use kernel::{
    bindings,
    prelude::*,
    sync::LockClassKey,
    types::{NotThreadSafe, Opaque},
};

#[pin_data]
pub(crate) struct RwSem<T> {
    #[pin]
    sem: Opaque<bindings::rw_semaphore>,
    data: UnsafeCell<T>,
    #[pin]
    _pin: PhantomPinned,
}

// SAFETY: access to `data` is serialised by the rwsem (shared for readers,
// exclusive for the writer), so `RwSem<T>` may be shared when `T: Send + Sync`.
unsafe impl<T: Send + Sync> Sync for RwSem<T> {}
// SAFETY: the rwsem may be moved between threads with its (pinned) data.
unsafe impl<T: Send> Send for RwSem<T> {}

impl<T> RwSem<T> {
    pub(crate) fn new(
        data: T,
        name: &'static CStr,
        key: Pin<&'static LockClassKey>,
    ) -> impl PinInit<Self> {
        pin_init!(Self {
            sem <- Opaque::ffi_init(move |slot: *mut bindings::rw_semaphore| {
                // SAFETY: `slot` points to an uninitialised rw_semaphore that
                // stays pinned; `name` and `key` are static.
                unsafe { bindings::__init_rwsem(slot, name.as_char_ptr(), key.as_ptr()) };
            }),
            data: UnsafeCell::new(data),
            _pin: PhantomPinned,
        })
    }

    /// Shared access if no writer holds or waits for the rwsem; never sleeps.
    pub(crate) fn try_read(&self) -> Option<ReadGuard<'_, T>> {
        // SAFETY: `sem` is initialised.
        if unsafe { bindings::down_read_trylock(self.sem.get()) } != 0 {
            Some(ReadGuard {
                lock: self,
                _not_send: NotThreadSafe,
            })
        } else {
            None
        }
    }

    /// Exclusive access; may sleep.
    pub(crate) fn write(&self) -> WriteGuard<'_, T> {
        // SAFETY: `sem` is initialised; the caller may sleep.
        unsafe { bindings::down_write(self.sem.get()) };
        WriteGuard {
            lock: self,
            _not_send: NotThreadSafe,
        }
    }
}

/// Shared access to an [`RwSem`]'s data; released on drop, by the task that
/// took it (`!Send`, like the kernel's lock guards: on PREEMPT_RT the rwsem
/// is an rt_mutex-based lock whose owner must release it).
pub(crate) struct ReadGuard<'a, T> {
    lock: &'a RwSem<T>,
    _not_send: NotThreadSafe,
}

assert_not_send!(ReadGuard<'static, u32>);
assert_not_send!(WriteGuard<'static, u32>);

impl<T> core::ops::Deref for ReadGuard<'_, T> {
    type Target = T;
    fn deref(&self) -> &T {
        // SAFETY: we hold the rwsem for reading: no writer can exist.
        unsafe { &*self.lock.data.get() }
    }
}

impl<T> Drop for ReadGuard<'_, T> {
    fn drop(&mut self) {
        // SAFETY: we took the rwsem for reading in `try_read`.
        unsafe { bindings::up_read(self.lock.sem.get()) };
    }
}

/// Exclusive access to an [`RwSem`]'s data; released on drop, by the task
/// that took it (`!Send`, see [`ReadGuard`]).
pub(crate) struct WriteGuard<'a, T> {
    lock: &'a RwSem<T>,
    _not_send: NotThreadSafe,
}

impl<T> core::ops::Deref for WriteGuard<'_, T> {
    type Target = T;
    fn deref(&self) -> &T {
        // SAFETY: we hold the rwsem for writing: access is exclusive.
        unsafe { &*self.lock.data.get() }
    }
}

impl<T> core::ops::DerefMut for WriteGuard<'_, T> {
    fn deref_mut(&mut self) -> &mut T {
        // SAFETY: we hold the rwsem for writing: access is exclusive.
        unsafe { &mut *self.lock.data.get() }
    }
}

impl<T> Drop for WriteGuard<'_, T> {
    fn drop(&mut self) {
        // SAFETY: we took the rwsem for writing in `write`.
        unsafe { bindings::up_write(self.lock.sem.get()) };
    }
}
