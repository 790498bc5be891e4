// SPDX-License-Identifier: GPL-2.0

//! hapticctrl: a real-time haptic servo controller for a (simulated) 6-DoF
//! Virtuose arm, after the OCERA "robotic application V0" design (D9rb.2).
//!
//! This file is the spec's hapticctrl_app. Module init creates the ITCs
//! (`shared.rs`), initialises the components (protocol, servo, io, state
//! model, control, simulator — all hap-core, calibrated at rest), registers
//! the char devices, then creates the kernel tasks: PROTO_IN, SERVO and CLOCK
//! (its thread, then its timers, which start the synchronous cycle). Any
//! failure unwinds what was created, in reverse, and insmod fails with a
//! dmesg line and the errno. Module exit stops the cycle, closes the
//! protocol, stops the tasks and frees everything.
//!
//! All computation lives in hap-core (`userspace/hap-core`), compiled into
//! this module by source path; this crate only schedules, synchronises and
//! moves bytes. Documentation/architecture.md has the picture.

use kernel::{
    c_str,
    prelude::*,
    sync::{atomic::Release, Arc},
};

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

mod clock;
mod completion;
mod device;
mod fault;
mod io;
mod kconfig;
mod kthread;
mod proto_in;
mod proto_synchro;
mod ring;
mod rtf;
mod rwsem;
mod servo;
mod shared;
mod simulator;
mod stats;
mod time;
mod uaccess;

use clock::{Stop, Timers};
use device::{register, Registration};
use fault::FaultDevice;
use hap_core::clock::{validate_period_us, PERIOD_MAX_US, PERIOD_MIN_US};
use io::Power;
use kthread::{KThread, SchedClass};
use rtf::{RtfIn, RtfOut};
use shared::Shared;
use simulator::{Effort, SimLog};
use stats::{HistDevice, StatsDevice};

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

/// The char devices (registered before the tasks, removed after them).
struct Devices {
    _rtf_in: Registration<RtfIn>,
    _rtf_out: Registration<RtfOut>,
    _stop: Registration<Stop>,
    _power: Registration<Power>,
    _stats: Registration<StatsDevice>,
    _hist: Registration<HistDevice>,
    _effort: Registration<Effort>,
    _simlog: Registration<SimLog>,
    _fault: Registration<FaultDevice>,
}

impl Devices {
    fn register() -> Result<Self> {
        Ok(Devices {
            _rtf_in: register()?,
            _rtf_out: register()?,
            _stop: register()?,
            _power: register()?,
            _stats: register()?,
            _hist: register()?,
            _effort: register()?,
            _simlog: register()?,
            _fault: register()?,
        })
    }
}

/// The kernel tasks, in creation order.
struct Tasks {
    proto_in: Option<KThread<Shared>>,
    servo: Option<KThread<Shared>>,
    clock: Option<KThread<Shared>>,
    timers: Option<Timers>,
}

impl Tasks {
    fn start(shared: &Arc<Shared>) -> Result<Self> {
        let spawn = |name: &'static CStr, class, body| {
            KThread::spawn(name, class, shared.clone(), body)
                .inspect_err(|e| pr_err!("cannot start {}: {:?}\n", name, e))
        };
        // Partial failures unwind through `Drop for Tasks` (reverse order).
        let mut tasks = Tasks {
            proto_in: None,
            servo: None,
            clock: None,
            timers: None,
        };
        tasks.proto_in = Some(spawn(
            c_str!("hap_proto_in"),
            PROTO_IN_CLASS,
            proto_in::proto_in_main,
        )?);
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
        tasks.timers = Some(Timers::start(shared)?);
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
        drop(self.proto_in.take());
    }
}

struct HapticCtrl {
    shared: Arc<Shared>,
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
        let allow_non_rt = module_parameters::allow_non_rt.value();
        kconfig::check(period_us, allow_non_rt)?;
        shared::init_global();
        let shared = Arc::pin_init(Shared::new(period_us)?, GFP_KERNEL)
            .inspect_err(|e| pr_err!("cannot create the channels: {:?}\n", e))?;
        shared::publish(Some(shared.clone()));
        let mut this = HapticCtrl {
            shared: shared.clone(),
            tasks: None,
            devices: None,
        };
        // On error `this` drops: tasks stopped, devices removed, channels freed.
        servo::calibrate(&shared);
        this.devices = Some(Devices::register()?);
        this.tasks = Some(Tasks::start(&shared)?);
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
        let sh = &self.shared;
        // Termination (spec §3.2): cut the motor line (whatever SERVO is
        // doing), close the client connection, stop the tasks, then destroy
        // the channels and free the memory.
        sh.motor_line.fail_safe_inhibit();
        sh.motor_line.power_off();
        sh.close_protocol();
        sh.stopping.store(true, Release);
        sh.rtf_out.close(true);
        sh.rtf_replies.close(true);
        sh.rtf_in.close(true);
        sh.effort.close(true);
        sh.effort_taken.complete_all();
        sh.cycle_start.complete_all();
        sh.check_due.complete_all();
        sh.rtf_in_ready.complete_all();
        sh.simlog.close(true);
        drop(self.tasks.take());
        drop(self.devices.take());
        shared::publish(None);
        pr_info!("unloaded\n");
    }
}
