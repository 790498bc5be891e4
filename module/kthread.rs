// SPDX-License-Identifier: GPL-2.0

//! A kernel thread with a chosen scheduling class: the one safe wrapper around
//! the raw kthread bindings (the kernel crate has no kthread abstraction in 7.3).

use core::{ffi::c_void, ptr::NonNull};
use kernel::{bindings, error::from_err_ptr, prelude::*, sync::Arc, types::NotThreadSafe};

/// Scheduling class of a [`KThread`].
#[derive(Clone, Copy)]
pub(crate) enum SchedClass {
    /// `SCHED_FIFO` 1, set with the kernel's `sched_set_fifo_low()`: above
    /// every `SCHED_OTHER` task, below every other real-time one.
    FifoLow,
    /// `SCHED_FIFO` at the given priority (2..=99), for the levels the
    /// kernel's helpers do not offer (Documentation/architecture.md argues
    /// each one).
    Fifo(u8),
}

/// The uapi `struct sched_attr` (include/uapi/linux/sched/types.h,
/// `SCHED_ATTR_SIZE_VER1`): the kernel's bindings only see it as opaque,
/// and `sched_setattr_nocheck()` is the one exported way to give a kthread
/// a chosen `SCHED_FIFO` priority (`sched_setscheduler_nocheck()` is not
/// exported to modules).
#[repr(C)]
#[derive(Default)]
struct SchedAttr {
    size: u32,
    sched_policy: u32,
    sched_flags: u64,
    sched_nice: i32,
    sched_priority: u32,
    sched_runtime: u64,
    sched_deadline: u64,
    sched_period: u64,
    sched_util_min: u32,
    sched_util_max: u32,
}

// The layout of `SCHED_ATTR_SIZE_VER1`.
const _: () = assert!(core::mem::size_of::<SchedAttr>() == 56);

/// The running kthread, as its body sees it: only the trampoline of a
/// [`KThread`] creates one, and it cannot leave the thread (`!Send`), so
/// [`CurrentKThread::should_stop`] is only ever asked from a kthread, about
/// itself (`kthread_should_stop()` oopses in any other task).
pub(crate) struct CurrentKThread {
    _not_send: NotThreadSafe,
}

assert_not_send!(CurrentKThread);
assert_not_send!(&CurrentKThread);

impl CurrentKThread {
    /// True once `kthread_stop()` was called on this thread.
    pub(crate) fn should_stop(&self) -> bool {
        // SAFETY: `self` exists only on the stack of a kthread's trampoline
        // (type invariant), and that kthread is the current task.
        unsafe { bindings::kthread_should_stop() }
    }
}

/// What a thread runs: its body and the shared context it borrows.
struct Start<T: Send + Sync + 'static> {
    ctx: Arc<T>,
    body: fn(&CurrentKThread, &T),
}

/// A running kernel thread. Dropping it calls `kthread_stop()`, which waits
/// for the body to return: the body must poll [`CurrentKThread::should_stop`]
/// and whoever drops the handle must first wake the thread from any wait it
/// may be in.
pub(crate) struct KThread<T: Send + Sync + 'static> {
    task: NonNull<bindings::task_struct>,
    // Owned here, not by the thread: if the thread is stopped before it ever
    // ran, the kernel does not call the body at all, and this is still freed.
    _start: KBox<Start<T>>,
}

// SAFETY: the task pointer is a counted reference usable from any context
// that may sleep; `Start<T>` is `Send + Sync` because `T` is.
unsafe impl<T: Send + Sync + 'static> Send for KThread<T> {}
// SAFETY: `&KThread` gives no access to the task.
unsafe impl<T: Send + Sync + 'static> Sync for KThread<T> {}

unsafe extern "C" fn trampoline<T: Send + Sync + 'static>(data: *mut c_void) -> c_int {
    // SAFETY: `data` is the `Start<T>` owned by the `KThread`, which lives
    // until `kthread_stop()` has returned, i.e. until after this function.
    let start = unsafe { &*data.cast::<Start<T>>() };
    // INVARIANT: created on this kthread's stack, lent to its body only.
    let current = CurrentKThread {
        _not_send: NotThreadSafe,
    };
    (start.body)(&current, &start.ctx);
    0
}

impl<T: Send + Sync + 'static> KThread<T> {
    /// Create the thread `name`, set its scheduling class, and wake it.
    pub(crate) fn spawn(
        name: &CStr,
        class: SchedClass,
        ctx: Arc<T>,
        body: fn(&CurrentKThread, &T),
    ) -> Result<Self> {
        let start = KBox::new(Start { ctx, body }, GFP_KERNEL)?;
        let data = (&raw const *start).cast_mut().cast::<c_void>();
        // SAFETY: `trampoline::<T>` matches the kthread function signature and
        // `data` stays valid until the thread has exited (see `KThread`).
        // The format string is "%s" and `name` is a valid C string.
        let raw = unsafe {
            bindings::kthread_create_on_node(
                Some(trampoline::<T>),
                data,
                bindings::NUMA_NO_NODE,
                c"%s".as_ptr().cast(),
                name.as_char_ptr(),
            )
        };
        let task = from_err_ptr(raw)?;
        let task = NonNull::new(task).ok_or(ENOMEM)?;
        // SAFETY: `task` is a freshly created, not yet running kthread; taking
        // a reference keeps it valid for `kthread_stop_put()` in `drop`.
        unsafe { bindings::get_task_struct(task.as_ptr()) };
        let this = KThread {
            task,
            _start: start,
        };
        match class {
            // SAFETY: `task` is valid (we hold a reference).
            SchedClass::FifoLow => unsafe { bindings::sched_set_fifo_low(this.task.as_ptr()) },
            SchedClass::Fifo(prio) => {
                let attr = SchedAttr {
                    size: core::mem::size_of::<SchedAttr>() as u32,
                    sched_policy: bindings::SCHED_FIFO,
                    sched_priority: u32::from(prio),
                    ..SchedAttr::default()
                };
                // SAFETY: `task` is valid (we hold a reference); `attr` has the
                // layout of the uapi `struct sched_attr` (VER1, 56 bytes, its
                // `size` field says so) and lives for the duration of the call.
                let ret = unsafe {
                    bindings::sched_setattr_nocheck(
                        this.task.as_ptr(),
                        (&raw const attr).cast::<bindings::sched_attr>(),
                    )
                };
                if ret != 0 {
                    return Err(Error::from_errno(ret));
                }
            }
        }
        // SAFETY: `task` is valid; waking a new kthread starts it.
        unsafe { bindings::wake_up_process(this.task.as_ptr()) };
        Ok(this)
    }
}

impl<T: Send + Sync + 'static> Drop for KThread<T> {
    fn drop(&mut self) {
        // SAFETY: we hold a reference to the task (taken in `spawn`);
        // `kthread_stop_put()` waits for the thread to exit and drops it.
        unsafe { bindings::kthread_stop_put(self.task.as_ptr()) };
    }
}
