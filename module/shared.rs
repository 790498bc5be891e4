// SPDX-License-Identifier: GPL-2.0

//! The inter-task channels and shared state of the running controller (the
//! spec's ITCs: rtf_in, rtf_out, sem_rtf_in, mtx_proto, mtx_data, bar_clock
//! and the flags), created once at insmod and shared by CLOCK, SERVO,
//! PROTO_IN and the char devices through an `Arc`.

use crate::{
    completion::Completion,
    hap_core::{
        config::ServoConfig,
        cycle::ServoCycle,
        effort::{EffortKeyframe, EFFORT_CAPACITY, EFFORT_RECORD_BYTES},
        handshake::CycleHandshake,
        io::MotorLine,
        proto_in::{ProtoIn, ProtoPublication, PROTO_PUBLICATION_WORDS},
        protocol::MAX_FRAME_LEN,
        seqlock::SeqWords,
        servo::PowerRequest,
        simulator::LogRecord,
        stats::{HapStats, STATS_WORDS},
        vp::{VpReceived, VprLatchRecord, VPR_LATCH_WORDS},
    },
    ring::{storage, AtomicU64, Fifo},
    rtf::{RtfInCounters, RTF_FRAMES},
    rwsem::RwSem,
    simulator::EffortScratch,
    time::Ktime,
};
use core::sync::atomic::{AtomicU8, Ordering};
use kernel::{
    c_str, new_mutex,
    prelude::*,
    static_lock_class,
    sync::{
        atomic::{Atomic, Relaxed},
        Arc, Mutex, MutexGuard,
    },
};
use pin_init::init_zeroed;

/// SERVO's data (the spec's `data` structure, under `mtx_data`). Only SERVO
/// locks `mtx_data` (and module init, for the calibration, before the tasks
/// start); the fail-safe only try-locks it, to log SERVO's last record;
/// device writes reach SERVO through lock-free handoffs.
#[pin_data]
pub(crate) struct ServoData {
    pub(crate) cycle: ServoCycle,
    /// SERVO's copy of the configuration, refreshed when the rwsem is free.
    pub(crate) config: ServoConfig,
    /// Scratch for an effort handoff record and its keyframes.
    pub(crate) handoff: [u8; EFFORT_RECORD_BYTES],
    pub(crate) keys: [EffortKeyframe; EFFORT_CAPACITY],
}

// SAFETY: `EffortKeyframe` is integers only (`u32`, `[i32; 3]` twice, `u8`):
// all-zero is a valid value (`EffortKeyframe::ZERO`).
unsafe impl Zeroable for EffortKeyframe {}
// SAFETY: every field of `HapStats` is an integer, a `bool` or an array or
// struct of them (see hap-core's stats.rs, which builds it from zeroes in
// `HapStats::reset`'s test): all-zero is a valid value.
unsafe impl Zeroable for HapStats {}

impl ServoData {
    /// SERVO's data, built in its allocation: the scratch buffers zeroed in
    /// place, the servo state written by hap-core's constructor.
    pub(crate) fn new_boxed(period_us: u32) -> Result<KBox<ServoData>> {
        let mut data = KBox::init(
            init!(ServoData {
                cycle: ServoCycle::new(period_us),
                config: ServoConfig::default(),
                handoff <- init_zeroed(),
                keys <- init_zeroed(),
            }),
            GFP_KERNEL,
        )?;
        data.cycle.servo.init();
        Ok(data)
    }
}

/// A `HapStats` built in its allocation (zeroed in place, then reset): the
/// ~24 KiB never touch the stack.
pub(crate) fn new_stats(period_us: u32) -> Result<KBox<HapStats>> {
    let mut st = KBox::<HapStats>::init(init_zeroed(), GFP_KERNEL)?;
    st.reset(period_us);
    Ok(st)
}

/// Position-log records kept until read (about 2 s at 1 kHz; 560-byte
/// records, one ~1.1 MB allocation).
pub(crate) const SIMLOG_RECORDS: usize = 2048;

/// Effort handoff records in flight (writers wait for SERVO to take theirs).
pub(crate) const EFFORT_SLOTS: usize = 2;

/// Controller state, as shown in /dev/hap_stats.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum ControllerState {
    Running,
    FailSafe,
}

impl ControllerState {
    pub(crate) const fn as_u8(self) -> u8 {
        match self {
            ControllerState::Running => 0,
            ControllerState::FailSafe => 1,
        }
    }

    /// Unknown values read as `FailSafe` (the safe side).
    pub(crate) const fn from_u8(v: u8) -> Self {
        match v {
            0 => ControllerState::Running,
            _ => ControllerState::FailSafe,
        }
    }

    pub(crate) const fn name(self) -> &'static str {
        match self {
            ControllerState::Running => "running",
            ControllerState::FailSafe => "fail_safe",
        }
    }
}

/// No event recorded yet.
pub(crate) const NEVER: u64 = u64::MAX;

/// A fixed array of atomic words (small publications, built inline).
pub(crate) struct Words<const N: usize>([AtomicU64; N]);

impl<const N: usize> Words<N> {
    pub(crate) const fn new() -> Self {
        Words([const { AtomicU64::new(0) }; N])
    }
}

impl<const N: usize> core::ops::Deref for Words<N> {
    type Target = [AtomicU64];
    fn deref(&self) -> &[AtomicU64] {
        &self.0
    }
}

#[pin_data]
pub(crate) struct Shared {
    pub(crate) period_us: u32,
    /// Time origin for every nanosecond stamp.
    epoch: Ktime,

    /// Cycle start (the spec's `bar_clock`): CLOCK's timer → SERVO.
    #[pin]
    pub(crate) cycle_start: Completion,
    /// Three quarters of the period: CLOCK's check timer → CLOCK thread.
    #[pin]
    pub(crate) check_due: Completion,
    /// A frame is in rtf_in (the spec's `sem_rtf_in`): rtf_in handler → PROTO_IN.
    #[pin]
    pub(crate) rtf_in_ready: Completion,
    /// Device writers (serialised among themselves) → PROTO_IN.
    #[pin]
    pub(crate) rtf_in: Fifo<MAX_FRAME_LEN>,
    /// SERVO's answers → readers of /dev/hap_rtf_out.
    #[pin]
    pub(crate) rtf_out: Fifo<MAX_FRAME_LEN>,
    /// PROTO_IN's replies → readers of /dev/hap_rtf_out (read before the
    /// answers; a second lane so that each ring has one producer).
    #[pin]
    pub(crate) rtf_replies: Fifo<MAX_FRAME_LEN>,
    pub(crate) rtf_in_counters: RtfInCounters,

    /// `mtx_proto`: the protocol state and the VPr shared memory. PROTO_IN
    /// locks it for each frame, the fail-safe and rmmod to close; SERVO
    /// never takes it (it reads the VPr latch) and no device takes it.
    #[pin]
    pub(crate) proto: Mutex<KBox<ProtoIn>>,
    /// PROTO_IN's counters and session, published after each frame.
    pub(crate) proto_pub: SeqWords<Words<PROTO_PUBLICATION_WORDS>>,
    /// The VPr latch: the session and the latest VPr, published under
    /// `mtx_proto` whenever they change (`Shared::publish_vpr`); SERVO reads
    /// it without any lock (`Shared::latest_vpr`).
    vpr_latch: SeqWords<Words<VPR_LATCH_WORDS>>,
    /// `mtx_data`: SERVO's data.
    #[pin]
    pub(crate) data: Mutex<KBox<ServoData>>,
    /// Read-mostly configuration: PROTO_IN writes, SERVO try-reads.
    #[pin]
    pub(crate) config: RwSem<ServoConfig>,
    /// CLOCK's own statistics, taken by CLOCK once when it starts.
    #[pin]
    pub(crate) clock_stats: Mutex<Option<KBox<HapStats>>>,
    /// The statistics as CLOCK publishes them every period (readers copy).
    pub(crate) stats: SeqWords<KVVec<AtomicU64>>,
    /// The simulator's position log: one `LogRecord` per cycle, SERVO →
    /// readers of /dev/hap_simlog (when full, new records are refused and
    /// counted).
    #[pin]
    pub(crate) simlog: Fifo<{ LogRecord::SIZE }>,
    /// Effort commands, parsed and validated by the device writer, taken by
    /// SERVO at the top of its next cycle.
    #[pin]
    pub(crate) effort: Fifo<EFFORT_RECORD_BYTES>,
    /// SERVO took an effort record (`effort_applied` moved).
    #[pin]
    pub(crate) effort_taken: Completion,
    /// The effort writers' lock and scratch (SERVO never takes it).
    #[pin]
    pub(crate) effort_writer: Mutex<KBox<EffortScratch>>,
    pub(crate) effort_applied: AtomicU64,

    /// The cycle handshake (tick, SERVO working / done tick / waiting, mode).
    pub(crate) cycle: CycleHandshake,
    /// Ticks at which SERVO was still busy, so the cycle start was not posted.
    pub(crate) ticks_not_posted: Atomic<u64>,
    /// ns since `epoch`: current cycle's timer expiry, the timer callback's
    /// actual run time, SERVO's start and end of its last cycle.
    pub(crate) expiry_ns: Atomic<i64>,
    pub(crate) tick_ns: Atomic<i64>,
    pub(crate) servo_start_ns: Atomic<i64>,
    pub(crate) servo_end_ns: Atomic<i64>,
    /// `ControllerState` as its `u8`.
    state: AtomicU8,
    /// `servo_stop`: a stop request from /dev/hap_stop.
    pub(crate) stop_request: Atomic<bool>,
    /// Power request for the arm (`PowerRequest` as its `u8`), consumed by SERVO.
    power_request: AtomicU8,
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
    /// Answer frames: sequence counter, frames queued, cycles whose answers
    /// were skipped (the VPr latch was being written: `answers_skipped_lock_busy`
    /// in /dev/hap_stats), frames a full rtf_out refused.
    pub(crate) answer_seq: Atomic<u32>,
    pub(crate) answers_sent: Atomic<u64>,
    pub(crate) answers_skipped: Atomic<u64>,
    pub(crate) answers_dropped: Atomic<u64>,
    pub(crate) vpr_extrapolated: Atomic<u64>,
    pub(crate) config_busy: Atomic<u64>,
    /// Reads of the statistics that overlapped CLOCK's writes every attempt.
    pub(crate) stats_read_busy: Atomic<u64>,
}

impl Shared {
    pub(crate) fn new(period_us: u32) -> Result<impl PinInit<Self, Error>> {
        let proto = KBox::new(ProtoIn::new(), GFP_KERNEL)?;
        // The latch starts as the protocol does (no session, its initial VPr).
        let vpr_latch = SeqWords::new(Words::new());
        {
            let mut rec = VprLatchRecord {
                session: proto.session(),
                vpr: *proto.vpr(),
            };
            let w = vpr_latch.write();
            rec.visit_words(|i, v| w.set(i, *v));
        }
        let data = ServoData::new_boxed(period_us)?;
        let mut own_stats = new_stats(period_us)?;
        let stats = SeqWords::new(storage(STATS_WORDS)?);
        {
            let w = stats.write();
            own_stats.visit_words(crate::hap_core::stats::WordSet::All, |i, v| w.set(i, *v));
        }
        let simlog = Fifo::new(SIMLOG_RECORDS)?;
        let rtf_in = Fifo::new(RTF_FRAMES)?;
        let rtf_out = Fifo::new(RTF_FRAMES)?;
        let rtf_replies = Fifo::new(RTF_FRAMES)?;
        let effort = Fifo::new(EFFORT_SLOTS)?;
        let effort_scratch = EffortScratch::new_boxed()?;
        Ok(try_pin_init!(Self {
            period_us,
            epoch: Ktime::now(),
            cycle_start <- Completion::new(),
            check_due <- Completion::new(),
            rtf_in_ready <- Completion::new(),
            rtf_in <- rtf_in,
            rtf_out <- rtf_out,
            rtf_replies <- rtf_replies,
            rtf_in_counters: RtfInCounters::new(),
            proto <- new_mutex!(proto),
            proto_pub: SeqWords::new(Words::new()),
            vpr_latch,
            data <- new_mutex!(data),
            config <- RwSem::new(ServoConfig::default(), c_str!("hap_config"), static_lock_class!()),
            clock_stats <- new_mutex!(Some(own_stats)),
            stats,
            simlog <- simlog,
            effort <- effort,
            effort_taken <- Completion::new(),
            effort_writer <- new_mutex!(effort_scratch),
            effort_applied: AtomicU64::new(0),
            cycle: CycleHandshake::new(),
            ticks_not_posted: Atomic::new(0),
            expiry_ns: Atomic::new(0),
            tick_ns: Atomic::new(0),
            servo_start_ns: Atomic::new(0),
            servo_end_ns: Atomic::new(0),
            state: AtomicU8::new(ControllerState::Running.as_u8()),
            stop_request: Atomic::new(false),
            power_request: AtomicU8::new(PowerRequest::None.as_u8()),
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
            stats_read_busy: Atomic::new(0),
        }? Error))
    }

    /// Nanoseconds since `epoch` of a clock reading.
    pub(crate) fn ns_of(&self, t: Ktime) -> i64 {
        t.ns_since(self.epoch)
    }

    /// Nanoseconds since `epoch`, now.
    pub(crate) fn now_ns(&self) -> i64 {
        self.ns_of(Ktime::now())
    }

    pub(crate) fn period_ns(&self) -> i64 {
        i64::from(self.period_us).saturating_mul(1000)
    }

    pub(crate) fn is_stopping(&self) -> bool {
        self.stopping.load(Relaxed)
    }

    pub(crate) fn state(&self) -> ControllerState {
        ControllerState::from_u8(self.state.load(Ordering::Acquire))
    }

    pub(crate) fn set_state(&self, s: ControllerState) {
        self.state.store(s.as_u8(), Ordering::Release);
    }

    /// A power request (from /dev/hap_power or the client), for SERVO.
    pub(crate) fn request_power(&self, r: PowerRequest) {
        self.power_request.store(r.as_u8(), Ordering::Release);
    }

    /// SERVO: take the pending power request, if any.
    pub(crate) fn take_power_request(&self) -> PowerRequest {
        PowerRequest::from_u8(
            self.power_request
                .swap(PowerRequest::None.as_u8(), Ordering::AcqRel),
        )
    }

    /// Copy the published statistics into `st` (built by `new_stats`),
    /// through `words` (`STATS_WORDS` long). Never blocks CLOCK: retries
    /// while a copy overlaps a write; `EBUSY` if every attempt did.
    pub(crate) fn read_stats(&self, words: &mut [u64], st: &mut HapStats) -> Result {
        if self.stats.read(words, STATS_READ_ATTEMPTS).is_none() {
            self.stats_read_busy.add(1, Relaxed);
            return Err(EBUSY);
        }
        st.load_words(words);
        Ok(())
    }

    /// Publish the protocol's session and VPr into the VPr latch. Taking
    /// the `mtx_proto` guard serialises the latch's writers (PROTO_IN after
    /// each frame, the fail-safe and rmmod after closing the protocol).
    pub(crate) fn publish_vpr(&self, proto: &MutexGuard<'_, KBox<ProtoIn>>) {
        let mut rec = VprLatchRecord {
            session: proto.session(),
            vpr: *proto.vpr(),
        };
        let w = self.vpr_latch.write();
        rec.visit_words(|i, v| w.set(i, *v));
    }

    /// Close the protocol (the fail-safe, rmmod) and publish the closed
    /// session and VPr.
    pub(crate) fn close_protocol(&self) {
        let mut proto = self.proto.lock();
        proto.close();
        self.publish_vpr(&proto);
    }

    /// SERVO: the session and the VPr last published, without any lock;
    /// `None` if every attempt overlapped a publication (a PROTO_IN
    /// preempted inside its few stores: SERVO extrapolates).
    pub(crate) fn latest_vpr(&self) -> Option<(u16, VpReceived)> {
        let mut words = [0u64; VPR_LATCH_WORDS];
        self.vpr_latch.read(&mut words, VPR_READ_ATTEMPTS)?;
        let mut rec = VprLatchRecord::default();
        rec.visit_words(|i, v| {
            if let Some(w) = words.get(i) {
                *v = *w;
            }
        });
        Some((rec.session, rec.vpr))
    }

    /// PROTO_IN's published counters and session.
    pub(crate) fn proto_publication(&self) -> ProtoPublication {
        let mut words = [0u64; PROTO_PUBLICATION_WORDS];
        let _ = self.proto_pub.read(&mut words, STATS_READ_ATTEMPTS);
        let mut p = ProtoPublication::default();
        p.visit_words(|i, v| {
            if let Some(w) = words.get(i) {
                *v = *w;
            }
        });
        p
    }
}

/// SERVO's read attempts of the VPr latch (a publication is 18 stores;
/// on one CPU a PROTO_IN preempted inside one does not finish meanwhile).
const VPR_READ_ATTEMPTS: usize = 4;

/// Read attempts before a statistics read gives up (each copies ~3 000
/// words; CLOCK writes a few dozen once per period).
const STATS_READ_ATTEMPTS: usize = 1000;

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
