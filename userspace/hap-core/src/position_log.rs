//! The position log's record: one [`LogRecord`] per servo cycle (and per
//! fail-safe step), its binary layout written and read once here. The
//! servo step fills it from what it sent and what the arm's I/O seam
//! reported; the kernel streams it to `/dev/hap_simlog`, the host replay
//! and the off-line analysis read it back.

use super::fixed::{Fx, Joints, Vec3, JOINTS_ZERO};
use super::mode::Mode;

/// One cycle of the binary position log (little-endian, version 2,
/// [`LogRecord::SIZE`] bytes), streamed by the kernel to `/dev/hap_simlog`
/// and read by the off-line analysis. Fx values are i64 Q32.32.
///
/// | offset | size | field |
/// |---|---|---|
/// | 0 | 4 | magic `b"HAPL"` |
/// | 4 | 2 | version (2) |
/// | 6 | 2 | flags: bit0 power, bit1 motors enabled, bit2 dead-man, bit3 button1, bit4 button2, bit5 degraded, bit6 coupled, bit7 motor line cut by the fail-safe during the period, bit8 (fail-safe step records only) servo fields unknown: only mode, step, status, alarms, applied torques and tick are valid |
/// | 8 | 8 | cycle (u64), consecutive from 0 at insmod |
/// | 16 | 8 | servo time at the cycle start, µs (cycle × period) |
/// | 24 | 1 | mode: 0 main, 1 degraded, 2 fail-safe step |
/// | 25 | 1 | fail-safe step done (1..=5, `FAIL_SAFE_SEQUENCE` order), else 0 |
/// | 26 | 2 | reserved (0) |
/// | 28 | 4 | age of the VPr in use, cycles (u32, saturating; `NO_VPR` if none) |
/// | 32 | 48 | joint positions q, 6 × rad (from the encoders) |
/// | 80 | 48 | joint speeds q̇, 6 × rad/s |
/// | 128 | 24 | handle position, 3 × m (arm base frame) |
/// | 152 | 32 | handle orientation x, y, z, w |
/// | 184 | 24 | handle linear velocity, 3 × m/s (base frame) |
/// | 208 | 24 | handle angular velocity, 3 × rad/s (base frame) |
/// | 232 | 48 | joint torques commanded by the controller, 6 × N·m |
/// | 280 | 48 | joint torques the motors produced (what `simulate_arm` applied, last sub-step of the period), 6 × N·m |
/// | 328 | 24 | coupling force on the handle, 3 × N (base frame) |
/// | 352 | 24 | coupling torque on the handle, 3 × N·m (base frame) |
/// | 376 | 48 | user wrench fx fy fz tx ty tz (N, N·m, base frame) |
/// | 424 | 24 | VPr in use (estimate at this cycle): position, 3 × client units |
/// | 448 | 32 | VPr in use: orientation x, y, z, w |
/// | 480 | 24 | handle position in the client's frame, 3 × client units |
/// | 504 | 4 | status bits (`vp::status`, as answered) |
/// | 508 | 4 | alarm bits (`vp::alarm`) |
/// | 512 | 8 | passivity observer energy, J |
/// | 520 | 8 | link watchdog gain, [0, 1] |
/// | 528 | 8 | kernel: cycle-timer tick that started the cycle (u64) |
/// | 536 | 8 | kernel: cycle start, ns since insmod (u64) |
/// | 544 | 4 | kernel: wake-up latency, ns (u32, saturating) |
/// | 548 | 4 | kernel: execution time, ns (u32, saturating) |
/// | 552 | 2 | kernel: protocol session id (0: no session) |
/// | 554 | 6 | reserved (0) |
///
/// The last 32 bytes ([`LogRecord::TIMING`]) are filled by the kernel's
/// SERVO thread and are 0 in a host replay; everything before is the servo
/// step's own output, bit for bit the same on the host.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LogRecord {
    pub flags: u16,
    pub cycle: u64,
    pub time_us: u64,
    pub mode: Mode,
    pub fail_safe_step: u8,
    pub vpr_age_cycles: u32,
    pub q: Joints,
    pub qd: Joints,
    pub handle_position: Vec3,
    pub handle_orientation: [Fx; 4],
    pub handle_velocity: Vec3,
    pub handle_angular_velocity: Vec3,
    pub torque_command: Joints,
    /// The torques the motors produced (0 unpowered, clamped to `arm::TAU_MAX`).
    pub motor_torque: Joints,
    pub coupling_force: Vec3,
    pub coupling_torque: Vec3,
    pub user_wrench: [Fx; 6],
    pub vpr_position: Vec3,
    pub vpr_orientation: [Fx; 4],
    pub handle_position_client: Vec3,
    pub status: u32,
    pub alarms: u32,
    pub po_energy: Fx,
    pub link_gain: Fx,
    pub timing: LogTiming,
}

/// The kernel's timing of one cycle (0 in a host replay).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LogTiming {
    /// Cycle-timer tick that started the cycle.
    pub tick: u64,
    /// Cycle start (SERVO woke), ns since insmod.
    pub start_ns: u64,
    /// SERVO's wake-up latency after the tick, ns.
    pub wakeup_ns: u32,
    /// SERVO's execution time, ns.
    pub exec_ns: u32,
    /// The protocol session open at the cycle (0: none).
    pub session: u16,
}

impl LogTiming {
    pub const ZERO: LogTiming = LogTiming {
        tick: 0,
        start_ns: 0,
        wakeup_ns: 0,
        exec_ns: 0,
        session: 0,
    };
}

/// Error decoding a [`LogRecord`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LogDecodeError {
    BadMagic,
    BadVersion,
    BadMode,
}

impl LogRecord {
    pub const SIZE: usize = 560;
    pub const MAGIC: [u8; 4] = *b"HAPL";
    pub const VERSION: u16 = 2;
    /// `vpr_age_cycles` when no VPr has been received.
    pub const NO_VPR: u32 = u32::MAX;
    /// Byte range of the kernel's timing fields.
    pub const TIMING: core::ops::Range<usize> = 528..560;

    pub const ZERO: LogRecord = LogRecord {
        flags: 0,
        cycle: 0,
        time_us: 0,
        mode: Mode::Main,
        fail_safe_step: 0,
        vpr_age_cycles: LogRecord::NO_VPR,
        q: JOINTS_ZERO,
        qd: JOINTS_ZERO,
        handle_position: Vec3::ZERO,
        handle_orientation: [Fx::ZERO; 4],
        handle_velocity: Vec3::ZERO,
        handle_angular_velocity: Vec3::ZERO,
        torque_command: JOINTS_ZERO,
        motor_torque: JOINTS_ZERO,
        coupling_force: Vec3::ZERO,
        coupling_torque: Vec3::ZERO,
        user_wrench: [Fx::ZERO; 6],
        vpr_position: Vec3::ZERO,
        vpr_orientation: [Fx::ZERO; 4],
        handle_position_client: Vec3::ZERO,
        status: 0,
        alarms: 0,
        po_energy: Fx::ZERO,
        link_gain: Fx::ZERO,
        timing: LogTiming::ZERO,
    };

    pub fn encode(&self, out: &mut [u8; LogRecord::SIZE]) {
        let mut w = Writer { buf: out, pos: 0 };
        w.put(&LogRecord::MAGIC);
        w.put(&LogRecord::VERSION.to_le_bytes());
        w.put(&self.flags.to_le_bytes());
        w.put(&self.cycle.to_le_bytes());
        w.put(&self.time_us.to_le_bytes());
        w.put(&[self.mode.as_u8(), self.fail_safe_step, 0, 0]);
        w.put(&self.vpr_age_cycles.to_le_bytes());
        w.fxs(&self.q);
        w.fxs(&self.qd);
        w.fxs(&self.handle_position.to_array());
        w.fxs(&self.handle_orientation);
        w.fxs(&self.handle_velocity.to_array());
        w.fxs(&self.handle_angular_velocity.to_array());
        w.fxs(&self.torque_command);
        w.fxs(&self.motor_torque);
        w.fxs(&self.coupling_force.to_array());
        w.fxs(&self.coupling_torque.to_array());
        w.fxs(&self.user_wrench);
        w.fxs(&self.vpr_position.to_array());
        w.fxs(&self.vpr_orientation);
        w.fxs(&self.handle_position_client.to_array());
        w.put(&self.status.to_le_bytes());
        w.put(&self.alarms.to_le_bytes());
        w.fxs(&[self.po_energy, self.link_gain]);
        w.put(&self.timing.tick.to_le_bytes());
        w.put(&self.timing.start_ns.to_le_bytes());
        w.put(&self.timing.wakeup_ns.to_le_bytes());
        w.put(&self.timing.exec_ns.to_le_bytes());
        w.put(&self.timing.session.to_le_bytes());
        w.put(&[0u8; 6]);
    }

    pub fn decode(buf: &[u8; LogRecord::SIZE]) -> Result<LogRecord, LogDecodeError> {
        let mut r = Reader { buf, pos: 0 };
        if r.arr::<4>() != LogRecord::MAGIC {
            return Err(LogDecodeError::BadMagic);
        }
        if u16::from_le_bytes(r.arr()) != LogRecord::VERSION {
            return Err(LogDecodeError::BadVersion);
        }
        let flags = u16::from_le_bytes(r.arr());
        let cycle = u64::from_le_bytes(r.arr());
        let time_us = u64::from_le_bytes(r.arr());
        let [mode, fail_safe_step, _, _] = r.arr::<4>();
        let mode = Mode::from_u8(mode).ok_or(LogDecodeError::BadMode)?;
        let vpr_age_cycles = u32::from_le_bytes(r.arr());
        let q = r.fxs::<6>();
        let qd = r.fxs::<6>();
        let handle_position = Vec3::from_array(r.fxs::<3>());
        let handle_orientation = r.fxs::<4>();
        let handle_velocity = Vec3::from_array(r.fxs::<3>());
        let handle_angular_velocity = Vec3::from_array(r.fxs::<3>());
        let torque_command = r.fxs::<6>();
        let motor_torque = r.fxs::<6>();
        let coupling_force = Vec3::from_array(r.fxs::<3>());
        let coupling_torque = Vec3::from_array(r.fxs::<3>());
        let user_wrench = r.fxs::<6>();
        let vpr_position = Vec3::from_array(r.fxs::<3>());
        let vpr_orientation = r.fxs::<4>();
        let handle_position_client = Vec3::from_array(r.fxs::<3>());
        let status = u32::from_le_bytes(r.arr());
        let alarms = u32::from_le_bytes(r.arr());
        let [po_energy, link_gain] = r.fxs::<2>();
        let timing = LogTiming {
            tick: u64::from_le_bytes(r.arr()),
            start_ns: u64::from_le_bytes(r.arr()),
            wakeup_ns: u32::from_le_bytes(r.arr()),
            exec_ns: u32::from_le_bytes(r.arr()),
            session: u16::from_le_bytes(r.arr()),
        };
        Ok(LogRecord {
            flags,
            cycle,
            time_us,
            mode,
            fail_safe_step,
            vpr_age_cycles,
            q,
            qd,
            handle_position,
            handle_orientation,
            handle_velocity,
            handle_angular_velocity,
            torque_command,
            motor_torque,
            coupling_force,
            coupling_torque,
            user_wrench,
            vpr_position,
            vpr_orientation,
            handle_position_client,
            status,
            alarms,
            po_energy,
            link_gain,
            timing,
        })
    }
}

struct Writer<'a> {
    buf: &'a mut [u8; LogRecord::SIZE],
    pos: usize,
}

impl Writer<'_> {
    fn put(&mut self, b: &[u8]) {
        let end = self.pos.saturating_add(b.len());
        if let Some(d) = self.buf.get_mut(self.pos..end) {
            d.copy_from_slice(b);
        }
        self.pos = end;
    }

    fn fxs(&mut self, v: &[Fx]) {
        for x in v {
            self.put(&x.0.to_le_bytes());
        }
    }
}

struct Reader<'a> {
    buf: &'a [u8; LogRecord::SIZE],
    pos: usize,
}

impl Reader<'_> {
    fn arr<const N: usize>(&mut self) -> [u8; N] {
        let mut a = [0u8; N];
        let end = self.pos.saturating_add(N);
        if let Some(s) = self.buf.get(self.pos..end) {
            a.copy_from_slice(s);
        }
        self.pos = end;
        a
    }

    fn fxs<const N: usize>(&mut self) -> [Fx; N] {
        let mut v = [Fx::ZERO; N];
        for x in v.iter_mut() {
            *x = Fx(i64::from_le_bytes(self.arr()));
        }
        v
    }
}
