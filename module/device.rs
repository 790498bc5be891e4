// SPDX-License-Identifier: GPL-2.0

//! One char-device type for every device of the controller: the per-device
//! behaviour is a [`HapDevice`] implementation (its name, the component it
//! serves, its `open`, `read`, `write`), the boilerplate is written once
//! here, after samples/rust/rust_misc_device.rs. Each device is registered
//! with its component ([`Registration::register`]): the registration holds
//! it, and every open file gets its own reference (no global lookup), whether
//! it was opened `O_NONBLOCK` (7.3's `Kiocb` does not expose the flags), and
//! the device's own per-open state.

use kernel::{
    container_of,
    fs::{File, Kiocb},
    iov::{IovIterDest, IovIterSource},
    miscdevice::{MiscDevice, MiscDeviceOptions, MiscDeviceRegistration},
    prelude::*,
    sync::Arc,
};

/// What a device does; the default `read`/`write` refuse (`EINVAL`).
pub(crate) trait HapDevice: Sized + Send + Sync + 'static {
    /// `/dev/<NAMES[i]>` for arm `i` (one name: a device of the whole
    /// controller).
    const NAMES: &'static [&'static CStr];

    /// The component the device serves (all it can reach).
    type Part: Send + Sync + 'static;

    /// The per-open state.
    fn open(part: &Arc<Self::Part>) -> Result<Self>;

    /// `read()` at `*pos` (advance it for a file-like device).
    fn read(_f: &OpenFile<Self>, _pos: &mut i64, _iov: &mut IovIterDest<'_>) -> Result<usize> {
        Err(EINVAL)
    }

    /// `write()`.
    fn write(_f: &OpenFile<Self>, _iov: &mut IovIterSource<'_>) -> Result<usize> {
        Err(EINVAL)
    }
}

/// An open file of device `D`.
pub(crate) struct OpenFile<D: HapDevice> {
    pub(crate) part: Arc<D::Part>,
    pub(crate) nonblock: bool,
    pub(crate) dev: D,
}

/// A registered device and the component it serves.
///
/// # Invariants
///
/// Every `MiscDeviceRegistration<OpenFile<D>>` is the `misc` field of a
/// `Registration<D>`: `misc` is private and only [`Registration::register`]
/// creates one.
#[pin_data]
pub(crate) struct Registration<D: HapDevice> {
    #[pin]
    misc: MiscDeviceRegistration<OpenFile<D>>,
    part: Arc<D::Part>,
}

impl<D: HapDevice> Registration<D> {
    /// Register `/dev/<D::NAMES[index]>`, serving `part`. Dropping the
    /// registration removes the device first (`misc` is the first field),
    /// then its reference to `part`; open files hold their own.
    pub(crate) fn register(index: usize, part: Arc<D::Part>) -> Result<Pin<KBox<Self>>> {
        let name = *D::NAMES.get(index).ok_or(EINVAL)?;
        KBox::try_pin_init(
            try_pin_init!(Self {
                misc <- MiscDeviceRegistration::register(MiscDeviceOptions { name }),
                part,
            }? Error),
            GFP_KERNEL,
        )
        .inspect_err(|e| pr_err!("cannot register /dev/{}: {:?}\n", name, e))
    }
}

#[vtable]
impl<D: HapDevice> MiscDevice for OpenFile<D> {
    type Ptr = KBox<Self>;

    fn open(file: &File, misc: &MiscDeviceRegistration<Self>) -> Result<KBox<Self>> {
        let misc_ptr = core::ptr::from_ref(misc).cast_mut();
        // SAFETY: by the type invariant `misc` is the `misc` field of a
        // `Registration<D>`, which `misc_open()` keeps registered, hence
        // alive, for the duration of this call: the containing pointer is in
        // bounds of the same allocation and valid to read.
        let reg = unsafe { &*container_of!(misc_ptr, Registration<D>, misc) };
        let part = reg.part.clone();
        let dev = D::open(&part)?;
        Ok(KBox::new(
            OpenFile {
                part,
                nonblock: file.flags() & kernel::fs::file::flags::O_NONBLOCK != 0,
                dev,
            },
            GFP_KERNEL,
        )?)
    }

    fn read_iter(mut kiocb: Kiocb<'_, Self::Ptr>, iov: &mut IovIterDest<'_>) -> Result<usize> {
        let f = kiocb.file();
        D::read(f, kiocb.ki_pos_mut(), iov)
    }

    fn write_iter(kiocb: Kiocb<'_, Self::Ptr>, iov: &mut IovIterSource<'_>) -> Result<usize> {
        D::write(kiocb.file(), iov)
    }
}
