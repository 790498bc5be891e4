// SPDX-License-Identifier: GPL-2.0

//! hapticctrl: a real-time haptic servo controller for a (simulated) 6-DoF
//! Virtuose arm, after the OCERA "robotic application V0" design.
//!
//! This file is the spec's hapticctrl_app: module init creates the channels,
//! the devices, the CLOCK timer and the SERVO thread; module exit tears them
//! down in reverse. All computation lives in hap-core (`userspace/hap-core`),
//! compiled into this module by source path.

use kernel::{
    c_str,
    miscdevice::{MiscDeviceOptions, MiscDeviceRegistration},
    prelude::*,
    sync::{atomic::Release, Arc},
    time::hrtimer::ArcHrTimerHandle,
};

#[path = "../userspace/hap-core/src/lib.rs"]
#[allow(unused_attributes, unreachable_pub, dead_code, missing_docs)]
#[allow(clippy::all)]
mod hap_core;

mod clock;
mod completion;
mod devices;
mod kthread;
mod servo;
mod shared;

use clock::CycleTimer;
use devices::{RtfInDevice, StatsDevice};
use kthread::{KThread, SchedClass};
use shared::Shared;

module! {
    type: HapticCtrl,
    name: "hapticctrl",
    authors: ["hapticctrl developers"],
    description: "Real-time haptic servo controller (simulated Virtuose arm)",
    license: "GPL",
    params: {
        period_us: u32 {
            default: 1000,
            description: "Servo period in microseconds (250..=10000)",
        },
    },
}

kernel::sync::global_lock! {
    // SAFETY: initialised in `HapticCtrl::init` before any device is registered.
    unsafe(uninit) static SHARED: Mutex<Option<Arc<Shared>>> = None;
}

/// SCHED_FIFO priority of SERVO (below CLOCK's hard-IRQ timer).
const SERVO_PRIORITY: u8 = 80;

struct HapticCtrl {
    shared: Arc<Shared>,
    // Teardown order is explicit in `Drop`.
    timer: Option<ArcHrTimerHandle<CycleTimer>>,
    servo: Option<KThread<Shared>>,
    _stats_dev: Pin<KBox<MiscDeviceRegistration<StatsDevice>>>,
    _rtf_in_dev: Pin<KBox<MiscDeviceRegistration<RtfInDevice>>>,
}

impl kernel::Module for HapticCtrl {
    fn init(_module: &'static ThisModule) -> Result<Self> {
        let period_us = module_parameters::period_us.value();
        if !(250..=10_000).contains(&period_us) {
            pr_err!("period_us={} out of range 250..=10000\n", period_us);
            return Err(EINVAL);
        }
        // SAFETY: called once, before any other use of `SHARED`.
        unsafe { SHARED.init() };
        let shared = Arc::pin_init(Shared::new(i64::from(period_us) * 1000), GFP_KERNEL)?;
        *SHARED.lock() = Some(shared.clone());

        let stats_dev = KBox::pin_init(
            MiscDeviceRegistration::register(MiscDeviceOptions { name: c_str!("hap_stats") }),
            GFP_KERNEL,
        )?;
        let rtf_in_dev = KBox::pin_init(
            MiscDeviceRegistration::register(MiscDeviceOptions { name: c_str!("hap_rtf_in") }),
            GFP_KERNEL,
        )?;
        let servo = KThread::spawn(
            c_str!("hap_servo"),
            SchedClass::Fifo(SERVO_PRIORITY),
            shared.clone(),
            servo::servo_main,
        )?;
        let timer = CycleTimer::start(shared.clone())?;
        pr_info!(
            "hapticctrl: loaded, period {} us, crc32c check {:#010x}\n",
            period_us,
            hap_core::crc::crc32c(b"123456789")
        );
        Ok(HapticCtrl {
            shared,
            timer: Some(timer),
            servo: Some(servo),
            _stats_dev: stats_dev,
            _rtf_in_dev: rtf_in_dev,
        })
    }
}

impl Drop for HapticCtrl {
    fn drop(&mut self) {
        self.shared.stopping.store(true, Release);
        // Timer first (cancel waits for a running callback), then release
        // SERVO from its wait and stop it.
        drop(self.timer.take());
        self.shared.cycle_start.complete_all();
        drop(self.servo.take());
        *SHARED.lock() = None;
        pr_info!("hapticctrl: unloaded\n");
    }
}
