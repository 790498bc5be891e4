// SPDX-License-Identifier: GPL-2.0

//! hapticctrl: a real-time haptic servo controller for a (simulated) 6-DoF
//! Virtuose arm, after the OCERA "robotic application V0" design (D9rb.2).
//!
//! This file is the spec's hapticctrl_app. Module init creates the
//! controller's components (`controller.rs`: the ITCs and the state each
//! owns; the servo state is hap-core's, calibrated at rest), registers each
//! char device with the component it serves, then creates the kernel tasks:
//! PROTO_IN, SERVO and CLOCK (its thread, then its timers, which start the
//! synchronous cycle). Any failure unwinds what was created, in reverse,
//! and insmod fails with a dmesg line and the errno. Module exit runs the
//! fail-safe's actions (`Controller::shut_down`), stops the tasks and frees
//! everything.
//!
//! All computation lives in hap-core (`userspace/hap-core`), compiled into
//! this module by source path; this crate only schedules, synchronises and
//! moves bytes. Documentation/architecture.md has the picture.

use kernel::{c_str, prelude::*, sync::Arc};

#[path = "../userspace/hap-core/src/lib.rs"]
#[allow(
    unused_attributes,
    unreachable_pub,
    dead_code,
    missing_docs,
    clippy::all
)]
mod hap_core;

/// Compile-time proof that a type is not `Send` (a guard or a token that
/// must stay in its task): if it were, the trait lookup below would be
/// ambiguous between the two impls and the build would fail.
macro_rules! assert_not_send {
    ($t:ty) => {
        const _: fn() = || {
            trait AmbiguousIfSend<A> {
                fn item() {}
            }
            impl<T: ?Sized> AmbiguousIfSend<()> for T {}
            impl<T: ?Sized + Send> AmbiguousIfSend<u8> for T {}
            let _ = <$t as AmbiguousIfSend<_>>::item;
        };
    };
}

mod arm;
mod clock;
mod completion;
mod controller;
mod cycle_clock;
mod device;
mod effort;
mod fault;
mod io;
mod kconfig;
mod kthread;
mod lifecycle;
mod position_log;
mod proto_in;
mod proto_state;
mod ring;
mod rtf;
mod rwsem;
mod servo;
mod servo_cycle;
mod servo_data;
mod stats;
mod stats_publication;
mod time;
mod uaccess;

use arm::{Arm, MAX_ARMS};
use clock::Timers;
use controller::Controller;
use device::Registration;
use effort::Effort;
use fault::FaultDevice;
use hap_core::clock::{validate_period_us, PERIOD_MAX_US, PERIOD_MIN_US};
use io::Power;
use kthread::{KThread, SchedClass};
use lifecycle::Stop;
use position_log::SimLog;
use proto_in::ProtoInTask;
use rtf::{RtfIn, RtfOut};
use stats::{HistDevice, StatsDevice, StatsView};

module! {
    type: HapticCtrl,
    name: "hapticctrl",
    authors: ["hapticctrl developers"],
    description: "Real-time haptic servo controller (simulated Virtuose arm)",
    license: "GPL",
    params: {
        period_us: u32 {
            default: 1000,
            description: "Servo period in microseconds (100..=10000)",
        },
        arms: u32 {
            default: 1,
            description: "Arms served by the controller (1 or 2; arm 1's devices are /dev/hap1_*)",
        },
        allow_non_rt: bool {
            default: false,
            description: "Load on a kernel without CONFIG_PREEMPT_RT (development only: no bounded latency)",
        },
    },
}

/// Scheduling classes (spec §3.4–3.5: CLOCK above SERVO above PROTO_IN;
/// Documentation/architecture.md argues each level). PROTO_IN takes the
/// kernel's `sched_set_fifo_low()`; CLOCK and SERVO need two distinct levels
/// above the threaded interrupts (FIFO 50), which the kernel's helpers do
/// not offer. FIFO 99 stays free for the administrator's own tools.
const CLOCK_PRIORITY: u8 = 90;
const SERVO_PRIORITY: u8 = 80;
const PROTO_IN_CLASS: SchedClass = SchedClass::FifoLow;
const PROTO_IN_PRIORITY: u8 = 1;

/// One arm's char devices, each with the component it serves.
struct ArmDevices {
    _rtf_in: Pin<KBox<Registration<RtfIn>>>,
    _rtf_out: Pin<KBox<Registration<RtfOut>>>,
    _power: Pin<KBox<Registration<Power>>>,
    _stats: Pin<KBox<Registration<StatsDevice>>>,
    _effort: Pin<KBox<Registration<Effort>>>,
    _simlog: Pin<KBox<Registration<SimLog>>>,
}

impl ArmDevices {
    fn register(c: &Arc<Controller>, arm: &Arc<Arm>) -> Result<Self> {
        let i = arm.index;
        let view = Arc::new(
            StatsView {
                ctrl: c.clone(),
                arm: arm.clone(),
            },
            GFP_KERNEL,
        )?;
        Ok(ArmDevices {
            _rtf_in: Registration::register(i, arm.rtf.clone())?,
            _rtf_out: Registration::register(i, arm.rtf.clone())?,
            _power: Registration::register(i, arm.io.clone())?,
            _stats: Registration::register(i, view)?,
            _effort: Registration::register(i, arm.effort.clone())?,
            _simlog: Registration::register(i, arm.log.clone())?,
        })
    }
}

/// The char devices (registered before the tasks, removed after them): the
/// controller's own, then each arm's.
struct Devices {
    _stop: Pin<KBox<Registration<Stop>>>,
    _hist: Pin<KBox<Registration<HistDevice>>>,
    _fault: Pin<KBox<Registration<FaultDevice>>>,
    _arms: [Option<ArmDevices>; MAX_ARMS],
}

impl Devices {
    fn register(c: &Arc<Controller>) -> Result<Self> {
        let mut arms: [Option<ArmDevices>; MAX_ARMS] = [const { None }; MAX_ARMS];
        let stop = Registration::register(0, c.life.clone())?;
        let hist = Registration::register(0, c.clone())?;
        let fault = Registration::register(0, c.faults.clone())?;
        for (slot, arm) in arms.iter_mut().zip(c.arms()) {
            *slot = Some(ArmDevices::register(c, arm)?);
        }
        Ok(Devices {
            _stop: stop,
            _hist: hist,
            _fault: fault,
            _arms: arms,
        })
    }
}

/// PROTO_IN's thread name for each arm.
const PROTO_IN_NAMES: [&CStr; MAX_ARMS] = [c"hap_proto_in", c"hap_proto_in1"];

/// The kernel tasks, in creation order.
struct Tasks {
    proto_in: [Option<KThread<ProtoInTask>>; MAX_ARMS],
    servo: Option<KThread<Controller>>,
    clock: Option<KThread<Controller>>,
    timers: Option<Timers>,
}

impl Tasks {
    fn start(ctrl: &Arc<Controller>) -> Result<Self> {
        let spawn = |name: &'static CStr, class, body| {
            KThread::spawn(name, class, ctrl.clone(), body)
                .inspect_err(|e| pr_err!("cannot start {}: {:?}\n", name, e))
        };
        // Partial failures unwind through `Drop for Tasks` (reverse order).
        let mut tasks = Tasks {
            proto_in: [const { None }; MAX_ARMS],
            servo: None,
            clock: None,
            timers: None,
        };
        for ((arm, name), slot) in ctrl
            .arms()
            .zip(PROTO_IN_NAMES)
            .zip(tasks.proto_in.iter_mut())
        {
            let task = Arc::new(
                ProtoInTask {
                    ctrl: ctrl.clone(),
                    arm: arm.index,
                },
                GFP_KERNEL,
            )?;
            let t = KThread::spawn(name, PROTO_IN_CLASS, task, proto_in::proto_in_main)
                .inspect_err(|e| pr_err!("cannot start {}: {:?}\n", name, e))?;
            *slot = Some(t);
        }
        tasks.servo = Some(spawn(
            c_str!("hap_servo"),
            SchedClass::Fifo(SERVO_PRIORITY),
            servo::servo_main,
        )?);
        tasks.clock = Some(spawn(
            c_str!("hap_clock"),
            SchedClass::Fifo(CLOCK_PRIORITY),
            clock::clock_main,
        )?);
        tasks.timers = Some(Timers::start(ctrl)?);
        Ok(tasks)
    }
}

impl Drop for Tasks {
    fn drop(&mut self) {
        // The cycle first (cancelling waits for a running callback), then the
        // tasks, each released from its wait (`stopping` is already set).
        drop(self.timers.take());
        drop(self.clock.take());
        drop(self.servo.take());
        for t in self.proto_in.iter_mut().rev() {
            drop(t.take());
        }
    }
}

struct HapticCtrl {
    ctrl: Arc<Controller>,
    tasks: Option<Tasks>,
    devices: Option<Devices>,
}

impl kernel::Module for HapticCtrl {
    fn init(_module: &'static ThisModule) -> Result<Self> {
        let period_us = module_parameters::period_us.value();
        if validate_period_us(period_us).is_err() {
            pr_err!(
                "period_us={} out of range {}..={}\n",
                period_us,
                PERIOD_MIN_US,
                PERIOD_MAX_US
            );
            return Err(EINVAL);
        }
        let arms = module_parameters::arms.value();
        let n_arms = usize::try_from(arms).unwrap_or(0);
        if n_arms == 0 || n_arms > MAX_ARMS {
            pr_err!("arms={} out of range 1..={}\n", arms, MAX_ARMS);
            return Err(EINVAL);
        }
        let allow_non_rt = module_parameters::allow_non_rt.value();
        kconfig::check(period_us, allow_non_rt)?;
        let ctrl = Arc::pin_init(Controller::new(period_us, n_arms)?, GFP_KERNEL)
            .inspect_err(|e| pr_err!("cannot create the channels: {:?}\n", e))?;
        let mut this = HapticCtrl {
            ctrl: ctrl.clone(),
            tasks: None,
            devices: None,
        };
        // On error `this` drops: tasks stopped, devices removed, channels freed.
        servo::calibrate(&ctrl)?;
        this.devices = Some(Devices::register(&ctrl)?);
        this.tasks = Some(Tasks::start(&ctrl)?);
        if n_arms > 1 {
            pr_info!("serving {} arms (arm 1: /dev/hap1_*)\n", n_arms);
        }
        pr_info!(
            "loaded, period {} us, CLOCK/SERVO/PROTO_IN at SCHED_FIFO {}/{}/{}, crc32c check {:#010x}\n",
            period_us,
            CLOCK_PRIORITY,
            SERVO_PRIORITY,
            PROTO_IN_PRIORITY,
            hap_core::crc::crc32c(b"123456789")
        );
        Ok(this)
    }
}

impl Drop for HapticCtrl {
    fn drop(&mut self) {
        // Termination (spec §3.2): the fail-safe's actions in their order
        // (cut the motor line whatever SERVO is doing, close the client
        // connection, release the tasks' waits, close the channels), then
        // stop the tasks, remove the devices and free the memory.
        self.ctrl.shut_down();
        drop(self.tasks.take());
        drop(self.devices.take());
        pr_info!("unloaded\n");
    }
}
