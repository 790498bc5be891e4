// SPDX-License-Identifier: GPL-2.0

//! One char-device type for every device of the controller: the per-device
//! behaviour is a [`HapDevice`] implementation (its name and its `open`,
//! `read`, `write`), the boilerplate is written once here, after
//! samples/rust/rust_misc_device.rs. Every open file holds the running
//! controller (`open` fails with `ENODEV` once it is gone), whether it was
//! opened `O_NONBLOCK` (7.3's `Kiocb` does not expose the flags), and the
//! device's own per-open state.

use crate::shared::{self, Shared};
use kernel::{
    fs::{File, Kiocb},
    iov::{IovIterDest, IovIterSource},
    miscdevice::{MiscDevice, MiscDeviceOptions, MiscDeviceRegistration},
    prelude::*,
    sync::Arc,
};

/// What a device does; the default `read`/`write` refuse (`EINVAL`).
pub(crate) trait HapDevice: Sized + Send + Sync + 'static {
    /// `/dev/<NAME>`.
    const NAME: &'static CStr;

    /// The per-open state.
    fn open(sh: &Arc<Shared>) -> Result<Self>;

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
pub(crate) struct OpenFile<D> {
    pub(crate) shared: Arc<Shared>,
    pub(crate) nonblock: bool,
    pub(crate) dev: D,
}

#[vtable]
impl<D: HapDevice> MiscDevice for OpenFile<D> {
    type Ptr = KBox<Self>;

    fn open(file: &File, _misc: &MiscDeviceRegistration<Self>) -> Result<KBox<Self>> {
        let shared = shared::get()?;
        let dev = D::open(&shared)?;
        Ok(KBox::new(
            OpenFile {
                shared,
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

/// A registered device.
pub(crate) type Registration<D> = Pin<KBox<MiscDeviceRegistration<OpenFile<D>>>>;

/// Register `/dev/<D::NAME>`.
pub(crate) fn register<D: HapDevice>() -> Result<Registration<D>> {
    KBox::pin_init(
        MiscDeviceRegistration::register(MiscDeviceOptions { name: D::NAME }),
        GFP_KERNEL,
    )
    .inspect_err(|e| pr_err!("cannot register /dev/{}: {:?}\n", D::NAME, e))
}
