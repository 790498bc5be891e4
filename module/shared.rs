// SPDX-License-Identifier: GPL-2.0

//! The inter-task channels and shared state of the running controller (the
//! spec's ITCs: rtf_in, rtf_out, sem_rtf_in, mtx_proto, mtx_data, bar_clock
//! and the flags), created once at insmod and shared by CLOCK, SERVO,
//! PROTO_IN and the char devices through an `Arc`.

use crate::{
    completion::Completion,
    hap_core::{
        config::ServoConfig, cycle::ServoCycle, io::MotorLine, proto_in::ProtoIn,
        protocol::MAX_FRAME_LEN,
        simulator::LogRecord, stats::HapStats,
    },
    rtf::{RtFifo, RtfInCounters, RTF_FRAMES},
    rwsem::RwSem,
};
use kernel::{
    c_str, new_mutex,
    prelude::*,
    static_lock_class,
    sync::{
        atomic::{Atomic, Relaxed},
        Arc, Mutex,
    },
    time::{Instant, Monotonic},
};

/// SERVO's data (the spec's `data` structure, under `mtx_data`).
pub(crate) struct ServoData {
    pub(crate) cycle: ServoCycle,
    /// SERVO's copy of the configuration, refreshed when the rwsem is free.
    pub(crate) config: ServoConfig,
}

/// Position-log records kept (about 4 s at 1 kHz).
pub(crate) const SIMLOG_RECORDS: usize = 4096;

/// Controller state, as shown in /dev/hap_stats.
pub(crate) mod state {
    pub(crate) const RUNNING: u32 = 0;
    pub(crate) const FAIL_SAFE: u32 = 1;
    pub(crate) const NAMES: [&str; 2] = ["running", "fail_safe"];
}

/// No event recorded yet.
pub(crate) const NEVER: u64 = u64::MAX;

#[pin_data]
pub(crate) struct Shared {
    pub(crate) period_us: u32,
    /// Time origin for every nanosecond stamp.
    epoch: Instant<Monotonic>,

    /// Cycle start (the spec's `bar_clock`): CLOCK's timer → SERVO.
    #[pin]
    pub(crate) cycle_start: Completion,
    /// Three quarters of the period: CLOCK's check timer → CLOCK thread.
    #[pin]
    pub(crate) check_due: Completion,
    /// A frame is in rtf_in (the spec's `sem_rtf_in`): rtf_in handler → PROTO_IN.
    #[pin]
    pub(crate) rtf_in_ready: Completion,
    #[pin]
    pub(crate) rtf_in: RtFifo<MAX_FRAME_LEN>,
    #[pin]
    pub(crate) rtf_out: RtFifo<MAX_FRAME_LEN>,
    pub(crate) rtf_in_counters: RtfInCounters,

    /// `mtx_proto`: the protocol state and the VPr shared memory. PROTO_IN
    /// locks it; SERVO only try-locks it.
    #[pin]
    pub(crate) proto: Mutex<KBox<ProtoIn>>,
    /// `mtx_data`: SERVO's data.
    #[pin]
    pub(crate) data: Mutex<KBox<ServoData>>,
    /// Read-mostly configuration: PROTO_IN writes, SERVO try-reads.
    #[pin]
    pub(crate) config: RwSem<ServoConfig>,
    /// Timing statistics and counters (CLOCK updates, /dev/hap_stats reads).
    #[pin]
    pub(crate) stats: Mutex<KBox<HapStats>>,
    /// The simulator's position log: one `LogRecord` per cycle (an RT-FIFO
    /// to the off-line analysis; the oldest record goes when nobody reads).
    #[pin]
    pub(crate) simlog: RtFifo<{ LogRecord::SIZE }>,

    // Flags and stamps (lock-free between the tasks).
    /// SERVO is inside its cycle (the spec's `servo_working`).
    pub(crate) servo_working: Atomic<bool>,
    /// SERVO waits at the cycle barrier.
    pub(crate) servo_waiting: Atomic<bool>,
    /// Timer ticks (cycle index); SERVO's last finished cycle index.
    pub(crate) tick: Atomic<u64>,
    pub(crate) servo_done_tick: Atomic<u64>,
    /// Ticks at which SERVO was still busy, so the cycle start was not posted.
    pub(crate) ticks_not_posted: Atomic<u64>,
    /// ns since `epoch`: current cycle's timer expiry, the timer callback's
    /// actual run time, SERVO's start and end of its last cycle.
    pub(crate) expiry_ns: Atomic<i64>,
    pub(crate) tick_ns: Atomic<i64>,
    pub(crate) servo_start_ns: Atomic<i64>,
    pub(crate) servo_end_ns: Atomic<i64>,
    /// Servo mode chosen by CLOCK's supervisor (`clock::Mode` as u32).
    pub(crate) mode: Atomic<u32>,
    /// `state::*`
    pub(crate) state: Atomic<u32>,
    /// `servo_stop`: a stop request from /dev/hap_stop.
    pub(crate) stop_request: Atomic<bool>,
    /// Power request for the arm: 0 none, 1 on, 2 off (consumed by SERVO).
    pub(crate) power_request: Atomic<u32>,
    /// hap_io's motor line (gate, supply, the DAC's command): outside every
    /// lock. SERVO writes commands through it, the simulated motors read it
    /// at every sub-step, the fail-safe cuts it with two stores.
    pub(crate) motor_line: MotorLine,
    /// Status bits of the last answer (for /dev/hap_power and stats).
    pub(crate) last_status: Atomic<u32>,
    /// Set at teardown and by the fail-safe: every task leaves its loop.
    pub(crate) stopping: Atomic<bool>,
    /// Fault injection: SERVO overruns this many more cycles, inside `mtx_data`.
    pub(crate) fault_overruns: Atomic<u32>,
    /// Fault injection: SERVO hangs inside its cycle, holding `mtx_data`,
    /// until the module is removed.
    pub(crate) fault_hang: Atomic<bool>,
    /// Servo cycle at which the effort sequence was (re)loaded / power requested.
    pub(crate) effort_loaded_cycle: Atomic<u64>,
    pub(crate) power_on_cycle: Atomic<u64>,
    /// Answer frames: sequence counter, frames queued, cycles skipped (lock busy).
    pub(crate) answer_seq: Atomic<u32>,
    pub(crate) answers_sent: Atomic<u64>,
    pub(crate) answers_skipped: Atomic<u64>,
    pub(crate) answers_dropped: Atomic<u64>,
    pub(crate) vpr_extrapolated: Atomic<u64>,
    pub(crate) config_busy: Atomic<u64>,
}

impl Shared {
    pub(crate) fn new(period_us: u32) -> Result<impl PinInit<Self, Error>> {
        let proto = KBox::new(ProtoIn::new(), GFP_KERNEL)?;
        // Built in place in the allocation (hap-core's types are a few KiB).
        let mut data = KBox::write(
            KBox::<ServoData>::new_uninit(GFP_KERNEL)?,
            ServoData {
                cycle: ServoCycle::new(period_us),
                config: ServoConfig::default(),
            },
        );
        data.cycle.servo.init();
        let stats = KBox::write(
            KBox::<HapStats>::new_uninit(GFP_KERNEL)?,
            HapStats::new(period_us),
        );
        let simlog = RtFifo::new(SIMLOG_RECORDS)?;
        let rtf_in = RtFifo::new(RTF_FRAMES)?;
        let rtf_out = RtFifo::new(RTF_FRAMES)?;
        Ok(try_pin_init!(Self {
            period_us,
            epoch: Instant::now(),
            cycle_start <- Completion::new(),
            check_due <- Completion::new(),
            rtf_in_ready <- Completion::new(),
            rtf_in <- rtf_in,
            rtf_out <- rtf_out,
            rtf_in_counters: RtfInCounters::new(),
            proto <- new_mutex!(proto),
            data <- new_mutex!(data),
            config <- RwSem::new(ServoConfig::default(), c_str!("hap_config"), static_lock_class!()),
            stats <- new_mutex!(stats),
            simlog <- simlog,
            servo_working: Atomic::new(false),
            servo_waiting: Atomic::new(false),
            tick: Atomic::new(0),
            servo_done_tick: Atomic::new(0),
            ticks_not_posted: Atomic::new(0),
            expiry_ns: Atomic::new(0),
            tick_ns: Atomic::new(0),
            servo_start_ns: Atomic::new(0),
            servo_end_ns: Atomic::new(0),
            mode: Atomic::new(0),
            state: Atomic::new(state::RUNNING),
            stop_request: Atomic::new(false),
            power_request: Atomic::new(0),
            motor_line: MotorLine::new(),
            last_status: Atomic::new(0),
            stopping: Atomic::new(false),
            fault_overruns: Atomic::new(0),
            fault_hang: Atomic::new(false),
            effort_loaded_cycle: Atomic::new(NEVER),
            power_on_cycle: Atomic::new(NEVER),
            answer_seq: Atomic::new(0),
            answers_sent: Atomic::new(0),
            answers_skipped: Atomic::new(0),
            answers_dropped: Atomic::new(0),
            vpr_extrapolated: Atomic::new(0),
            config_busy: Atomic::new(0),
        }? Error))
    }

    /// Nanoseconds since `epoch` of an instant.
    pub(crate) fn ns_of(&self, t: Instant<Monotonic>) -> i64 {
        (t - self.epoch).as_nanos()
    }

    /// Nanoseconds since `epoch`, now.
    pub(crate) fn now_ns(&self) -> i64 {
        self.ns_of(Instant::now())
    }

    pub(crate) fn period_ns(&self) -> i64 {
        i64::from(self.period_us).saturating_mul(1000)
    }

    pub(crate) fn is_stopping(&self) -> bool {
        self.stopping.load(Relaxed)
    }
}

kernel::sync::global_lock! {
    // SAFETY: initialised in module init before any device is registered.
    unsafe(uninit) static SHARED: Mutex<Option<Arc<Shared>>> = None;
}

/// Initialise the global once (module init).
pub(crate) fn init_global() {
    // SAFETY: called once, from module init, before any other use.
    unsafe { SHARED.init() };
}

/// Publish (or withdraw, with `None`) the running controller for the devices.
pub(crate) fn publish(shared: Option<Arc<Shared>>) {
    *SHARED.lock() = shared;
}

/// The running controller, or `ENODEV` between teardown steps.
pub(crate) fn get() -> Result<Arc<Shared>> {
    SHARED.lock().as_ref().cloned().ok_or(ENODEV)
}

/// What every open file of the controller's devices holds: the running
/// controller (open fails with `ENODEV` once it is gone) and whether the
/// file was opened `O_NONBLOCK` (7.3's `Kiocb` does not expose the flags).
pub(crate) struct DeviceFile {
    pub(crate) shared: Arc<Shared>,
    pub(crate) nonblock: bool,
}

impl DeviceFile {
    pub(crate) fn open(file: &kernel::fs::File) -> Result<Self> {
        Ok(DeviceFile {
            shared: get()?,
            nonblock: file.flags() & kernel::fs::file::flags::O_NONBLOCK != 0,
        })
    }
}
