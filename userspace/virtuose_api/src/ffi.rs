//! C ABI: Haption's VirtuoseAPI 4.x (`include/VirtuoseAPI.h`) plus
//! hapticctrl's extensions (`include/virtuose_api.h`).
//!
//! Every function returns 0 on success and -1 on error (virtOpen: NULL);
//! the error is then available from `virtGetErrorCode` (VirtuoseAPI's
//! `VIRT_E_*` codes) and `virtGetErrorMessage`. As in Haption's library the
//! code is kept per context (the result of the last call on it, 0 after a
//! success); `virtGetErrorCode(NULL)` gives the calling thread's last one
//! (after a failed `virtOpen`). Float arrays: position `float[7]` (x, y, z, qx, qy, qz, qw),
//! speed and force `float[6]`.
//!
//! A `VirtContext` is a handle, not an address: `virtOpen` hands out each
//! value once, and a call on a closed or never-opened one fails at once
//! with `VIRT_E_INVALID_CONTEXT` (NULL too, except in the conversions,
//! which need no context).
//!
//! A context may be used from several threads at once (the application,
//! the periodic callback loop, the trajectory recorder): its session (a
//! read-write lock: requests, readings and set-points share it), its
//! VirtuoseAPI state and its loop are behind separate locks, never held
//! together.

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::ffi::{c_char, c_float, c_int, c_uint, c_ushort, c_void, CStr, CString};
use std::io::Write;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicI32, AtomicU32, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, RwLock, RwLockReadGuard, RwLockWriteGuard};
use std::thread::{JoinHandle, ThreadId};
use std::time::{Duration, Instant};

use hap_core::control::Gains;
use hap_core::fixed::Fx;
use hap_core::protocol::{ERROR_NO_SESSION, ERROR_REFUSED};
use hap_core::vp::{alarm, status};

use crate::kin::{self, Frames, Offset};
use crate::{CommandType, IndexingMode, VirtContext, VirtError};

mod dll;
pub use dll::{dispatch as call_dll, DllFunction};

// ---- VirtuoseAPI.h values ----------------------------------------------

pub const VIRT_E_NO_ERROR: c_int = 0;
pub const VIRT_E_OUT_OF_MEMORY: c_int = 1;
pub const VIRT_E_COMMUNICATION_FAILURE: c_int = 2;
pub const VIRT_E_INVALID_CONTEXT: c_int = 3;
pub const VIRT_E_FILE_NOT_FOUND: c_int = 4;
pub const VIRT_E_WRONG_FORMAT: c_int = 5;
pub const VIRT_E_TIME_OUT: c_int = 6;
pub const VIRT_E_NOT_IMPLEMENTED: c_int = 7;
pub const VIRT_E_VARIABLE_NOT_AVAILABLE: c_int = 8;
pub const VIRT_E_INCORRECT_VALUE: c_int = 9;
pub const VIRT_E_SYNTAX_ERROR: c_int = 10;
pub const VIRT_E_HARDWARE_ERROR: c_int = 11;
pub const VIRT_E_PERIODIC_FUNCTION: c_int = 14;
pub const VIRT_E_WRONG_MODE: c_int = 17;
pub const VIRT_E_CALL_TIME: c_int = 19;
pub const VIRT_E_ALREADY_CALLED: c_int = 22;

pub const COMMAND_TYPE_NONE: c_int = 0;
pub const COMMAND_TYPE_IMPEDANCE: c_int = 3;
pub const COMMAND_TYPE_VIRTMECH: c_int = 5;
pub const COMMAND_TYPE_ARTICULAR: c_int = 6;
pub const COMMAND_TYPE_ARTICULAR_IMPEDANCE: c_int = 7;

pub const VIRT_ALARM_SATURATE: c_uint = 0x0000_8000;
pub const VIRT_ALARM_CALLBACK_OVERRUN: c_uint = 0x0002_0000;

/// Value of `virtAPIVersion`: the VirtuoseAPI version these declarations follow.
pub const API_VERSION: (c_int, c_int) = (4, 4);
/// Device type reported by `virtGetDeviceID` ("HC").
pub const DEVICE_TYPE: c_int = 0x4843;
/// Trajectory recording: most samples one file receives.
pub const TRAJ_MAX_SAMPLES: u64 = 1_000_000;

// ---- errors --------------------------------------------------------------

/// An error as the C ABI reports it.
#[derive(Debug, Clone, PartialEq)]
pub struct ApiError {
    pub code: c_int,
    pub msg: String,
}

impl ApiError {
    fn new(code: c_int, msg: impl Into<String>) -> ApiError {
        ApiError {
            code,
            msg: msg.into(),
        }
    }

    fn not_implemented(what: &str) -> ApiError {
        ApiError::new(
            VIRT_E_NOT_IMPLEMENTED,
            format!("{what}: not implemented by hapticctrl (see Documentation/userguide.md)"),
        )
    }

    fn null() -> ApiError {
        ApiError::new(VIRT_E_INCORRECT_VALUE, "null pointer argument")
    }
}

/// VirtuoseAPI code of a crate error.
pub fn haption_code(e: &VirtError) -> c_int {
    match e {
        VirtError::InvalidAddress(_) => VIRT_E_SYNTAX_ERROR,
        VirtError::Io(_) => VIRT_E_COMMUNICATION_FAILURE,
        VirtError::Timeout(_) => VIRT_E_TIME_OUT,
        VirtError::Refused { reason, .. } => match *reason {
            ERROR_NO_SESSION => VIRT_E_COMMUNICATION_FAILURE,
            ERROR_REFUSED => VIRT_E_WRONG_MODE,
            _ => VIRT_E_INCORRECT_VALUE,
        },
        VirtError::InvalidArgument(_) => VIRT_E_INCORRECT_VALUE,
        VirtError::NoData => VIRT_E_VARIABLE_NOT_AVAILABLE,
        VirtError::Closed | VirtError::NullPointer => VIRT_E_INVALID_CONTEXT,
        // The session is gone (replaced, expired, spent, or closed by the
        // controller): the message names the reason and its code.
        VirtError::SessionEnded { .. } => VIRT_E_COMMUNICATION_FAILURE,
    }
}

impl From<VirtError> for ApiError {
    fn from(e: VirtError) -> ApiError {
        ApiError::new(haption_code(&e), e.to_string())
    }
}

type R<T> = Result<T, ApiError>;

thread_local! {
    static LAST: RefCell<(c_int, CString)> = RefCell::new((0, CString::default()));
}

fn set_error(e: &ApiError) {
    let msg = CString::new(e.msg.replace('\0', " ")).unwrap_or_default();
    LAST.with(|l| *l.borrow_mut() = (e.code, msg));
}

fn clear_error() {
    LAST.with(|l| *l.borrow_mut() = (0, CString::default()));
}

fn status_of(r: R<()>) -> c_int {
    match r {
        Ok(()) => {
            clear_error();
            0
        }
        Err(e) => {
            set_error(&e);
            -1
        }
    }
}

// ---- the context -----------------------------------------------------------

type PeriodicFn = unsafe extern "C" fn(*mut c_void, *mut c_void);

/// VirtuoseAPI state kept by the library (what the getters return).
struct ApiState {
    time_step: f32,
    /// Haption value (0, 3, 5).
    command: c_int,
    indexing: c_int,
    frames: Frames,
    /// The base frame as set (`frames.base` is normalized).
    base_set: [f32; 7],
    observation: [f32; 7],
    /// `virtSetObservationFrameSpeed`: the observation frame's twist.
    observation_speed: [f32; 6],
    timeout_s: f32,
    force_cmd: [f32; 6],
    added_force: [f32; 6],
    saturation: (f32, f32),
    force_feedback: bool,
    attachment: Attachment,
    /// The virtual object's pose last given by virtSetPosition (the
    /// application's frame) and its twist (virtSetSpeed).
    object_pose: Option<[f32; 7]>,
    object_speed: [f32; 6],
    shift: Shift,
    /// The indexing offset of the forced shifts (virtForceShiftButton).
    shift_offset: Offset,
    last_q: Option<[f64; 6]>,
    debug_flags: c_ushort,
    output_file: Option<PathBuf>,
    traj_step: f32,
    periodic: Option<(PeriodicFn, usize, f32)>,
}

impl Default for ApiState {
    fn default() -> Self {
        ApiState {
            time_step: 0.001,
            command: COMMAND_TYPE_NONE,
            indexing: 0,
            frames: Frames::default(),
            base_set: [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
            observation: [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
            observation_speed: [0.0; 6],
            timeout_s: 1.0,
            force_cmd: [0.0; 6],
            added_force: [0.0; 6],
            saturation: (
                hap_core::control::MAX_FORCE.to_f64() as f32,
                hap_core::control::MAX_TORQUE.to_f64() as f32,
            ),
            force_feedback: true,
            attachment: Attachment::None,
            object_pose: None,
            object_speed: [0.0; 6],
            shift: Shift::Released,
            shift_offset: Offset::default(),
            last_q: None,
            debug_flags: 0,
            output_file: None,
            traj_step: 0.01,
            periodic: None,
        }
    }
}

/// What is attached to the handle.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Attachment {
    None,
    /// A virtual object the application simulates (virtAttachVO): its mass
    /// caps the controller's stiffness in VIRTMECH.
    Object {
        mass: f32,
    },
    /// A quasi-static virtual object (virtAttachQSVO): stiffnesses and
    /// dampings, rotations then translations (client units).
    QuasiStatic {
        ks: [f32; 6],
        bs: [f32; 6],
    },
}

/// The shift (indexing) button as forced by virtForceShiftButton.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Shift {
    Released,
    /// Forced since the avatar was at `frozen` (None: INDEXING_NONE, the
    /// shift moves nothing).
    Forced {
        frozen: Option<[f32; 7]>,
    },
}

impl ApiState {
    /// Mass of an attached virtual object (the VIRTMECH stiffness cap).
    fn vo_mass(&self) -> Option<f32> {
        match self.attachment {
            Attachment::Object { mass } => Some(mass),
            _ => None,
        }
    }

    fn shift_forced(&self) -> bool {
        matches!(self.shift, Shift::Forced { .. })
    }

    /// The indexing mode moves the orientation too (INDEXING_ALL*).
    fn indexes_rotation(&self) -> bool {
        matches!(self.indexing, 0 | 3)
    }
}

/// A background thread of the context (callback loop, trajectory recorder).
struct Worker {
    stop: Arc<AtomicBool>,
    handle: Option<JoinHandle<()>>,
    id: ThreadId,
}

impl Worker {
    /// Ask the thread to stop; join it unless called from it.
    fn stop(mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if std::thread::current().id() != self.id {
            if let Some(h) = self.handle.take() {
                let _ = h.join();
            }
        }
    }

    fn running(&self) -> bool {
        !self.stop.load(Ordering::SeqCst)
            && self
                .handle
                .as_ref()
                .map(|h| !h.is_finished())
                .unwrap_or(false)
    }
}

/// Opaque handle given to C (`VirtContext`).
pub struct VirtContextS {
    /// Requests (an acknowledged round trip) and readings take it shared,
    /// so one thread's request does not stall another's readings and
    /// set-points; only closing, the factors and the time-out value take
    /// it exclusive.
    vc: RwLock<VirtContext>,
    st: Mutex<ApiState>,
    periodic_loop: Mutex<Option<Worker>>,
    recorder: Mutex<Option<Worker>>,
    overrun_latched: AtomicBool,
    overruns: AtomicU32,
    /// VIRT_E_* code of the last call on this context (0: it succeeded).
    last_error: AtomicI32,
    /// Set by the first `virtClose`: a second one (the periodic callback,
    /// still running while the first waits for it) is refused.
    closing: AtomicBool,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    match m.lock() {
        Ok(g) => g,
        Err(p) => p.into_inner(),
    }
}

impl VirtContextS {
    fn session(&self) -> RwLockReadGuard<'_, VirtContext> {
        match self.vc.read() {
            Ok(g) => g,
            Err(p) => p.into_inner(),
        }
    }

    fn session_mut(&self) -> RwLockWriteGuard<'_, VirtContext> {
        match self.vc.write() {
            Ok(g) => g,
            Err(p) => p.into_inner(),
        }
    }

    fn state(&self) -> MutexGuard<'_, ApiState> {
        lock(&self.st)
    }

    /// A reading from the last answer; before the first answer of the
    /// session, wait for it up to the time-out value.
    fn read<T>(&self, f: impl Fn(&VirtContext) -> crate::Result<T>) -> R<T> {
        let timeout = Duration::from_secs_f32(self.state().timeout_s);
        let deadline = Instant::now() + timeout;
        loop {
            let r = {
                let vc = self.session();
                f(&vc)
            };
            match r {
                Err(VirtError::NoData) if Instant::now() < deadline => {
                    // Wait without holding the session (the other thread
                    // of the context keeps using it).
                    let w = self.session().answer_waiter();
                    w.wait_newer(w.current().0, Duration::from_millis(20));
                }
                Err(VirtError::NoData) => {
                    return Err(ApiError::new(
                        VIRT_E_TIME_OUT,
                        "no answer received from the controller within the time-out value",
                    ))
                }
                r => return r.map_err(ApiError::from),
            }
        }
    }

    fn physical_pose(&self) -> R<[f32; 7]> {
        let world = self.read(|v| v.get_position())?;
        Ok(self.state().frames.physical_pose(&world))
    }

    fn joints(&self) -> R<[f64; 6]> {
        let phys = self.physical_pose()?;
        let prev = self.state().last_q;
        let q = kin::inverse_kinematics(&phys, prev.as_ref()).ok_or_else(|| {
            ApiError::new(
                VIRT_E_VARIABLE_NOT_AVAILABLE,
                "handle pose out of the arm's reach (base frame or indexing offset inconsistent)",
            )
        })?;
        self.state().last_q = Some(q);
        Ok(q)
    }

    /// The coupling stiffnesses the controller uses (arm units): its gains
    /// for the servo period (`Gains::for_period`), the translational one
    /// capped at `m / ts²` for a virtual object of mass `m` (VIRTMECH).
    fn gains(&self, vc: &VirtContext, vo_mass: Option<f32>, ts: f32) -> (f64, f64) {
        let g = Self::period_gains(vc);
        let mut k_lin = g.k_lin.to_f64();
        if let Some(m) = vo_mass {
            let ts = ts as f64;
            if ts > 0.0 {
                k_lin = k_lin.min(m as f64 / (ts * ts));
            }
        }
        (k_lin, g.k_rot.to_f64())
    }

    fn period_gains(vc: &VirtContext) -> Gains {
        let period_us = vc.link_stats().period_us.max(1);
        Gains::for_period(Fx::from_ratio(period_us as i64, 1_000_000))
    }

    /// The translational coupling (stiffness N/m, damping N·s/m) in the
    /// client's units (force factor, speed factor), as the controller
    /// applies it in the current command type.
    ///
    /// With a quasi-static object (virtAttachQSVO) in VIRTMECH: the mean of
    /// its three translational stiffnesses and dampings, each at most the
    /// controller's.
    fn simulation_coupling(&self) -> (f64, f64) {
        let (frames, cmd, attachment, ts) = {
            let st = self.state();
            (st.frames, st.command, st.attachment, st.time_step)
        };
        let vc = self.session();
        let virtmech = cmd == COMMAND_TYPE_VIRTMECH;
        let mass = match attachment {
            Attachment::Object { mass } if virtmech => Some(mass),
            _ => None,
        };
        let (k, _) = self.gains(&vc, mass, ts);
        let b = Self::period_gains(&vc).b_lin.to_f64();
        let scale = frames.force_factor / frames.speed_factor;
        let (k, b) = (k * scale, b * scale);
        match attachment {
            Attachment::QuasiStatic { ks, bs } if virtmech => {
                let mean =
                    |v: &[f32], cap: f64| v.iter().map(|x| (*x as f64).min(cap)).sum::<f64>() / 3.0;
                (mean(&ks[3..6], k), mean(&bs[3..6], b))
            }
            _ => (k, b),
        }
    }

    /// The handle as the application sees it (virtGetAvatarPosition): the
    /// controller's pose (its indexing offset and the speed factor applied)
    /// with the offset of the forced shifts; while a shift is forced, the
    /// avatar stays where it was (its orientation follows the handle in
    /// the translation-only indexing modes).
    fn avatar(&self) -> R<[f32; 7]> {
        let handle = self.read(|v| v.get_position())?;
        let st = self.state();
        let shown = st.shift_offset.apply(&handle);
        Ok(match st.shift {
            Shift::Forced {
                frozen: Some(frozen),
            } => {
                if st.indexes_rotation() {
                    frozen
                } else {
                    let mut a = shown;
                    a[..3].copy_from_slice(&frozen[..3]);
                    a
                }
            }
            _ => shown,
        })
    }

    /// A quasi-static object (virtAttachQSVO) in VIRTMECH: stream the
    /// set-point that makes the controller's spring apply the object's
    /// stiffness towards its pose (`kin::qsvo_setpoint`), with the twist
    /// that makes its damper apply the object's damping. Nothing while a
    /// shift is forced or before the application gave a pose.
    fn stream_qsvo(&self) -> R<()> {
        let (ks, bs, target, target_speed, frames, offset) = {
            let st = self.state();
            let Attachment::QuasiStatic { ks, bs } = st.attachment else {
                return Ok(());
            };
            if st.command != COMMAND_TYPE_VIRTMECH || st.shift_forced() {
                return Ok(());
            }
            let Some(target) = st.object_pose else {
                return Ok(());
            };
            (ks, bs, target, st.object_speed, st.frames, st.shift_offset)
        };
        let handle = self.read(|v| v.get_position())?;
        let twist = self.read(|v| v.get_speed()).unwrap_or([0.0; 6]);
        let vc = self.session();
        let g = Self::period_gains(&vc);
        let (ff, sf) = (frames.force_factor, frames.speed_factor);
        // The controller's gains in client units: F = ff·F_arm, x = sf·x_arm,
        // τ = ff·sf·τ_arm.
        let lin = ff / sf;
        let rot = ff * sf;
        let ratio = |want: f32, have: f64| if have > 0.0 { want as f64 / have } else { 0.0 };
        let mut s_lin = [0.0; 3];
        let mut s_rot = [0.0; 3];
        let mut out_twist = twist;
        for i in 0..3 {
            s_rot[i] = ratio(ks[i], g.k_rot.to_f64() * rot);
            s_lin[i] = ratio(ks[3 + i], g.k_lin.to_f64() * lin);
            let b_rot = ratio(bs[i], g.b_rot.to_f64() * rot).clamp(0.0, 1.0);
            let b_lin = ratio(bs[3 + i], g.b_lin.to_f64() * lin).clamp(0.0, 1.0);
            out_twist[i] = (twist[i] as f64 + b_lin * (target_speed[i] - twist[i]) as f64) as f32;
            out_twist[3 + i] =
                (twist[3 + i] as f64 + b_rot * (target_speed[3 + i] - twist[3 + i]) as f64) as f32;
        }
        let setpoint = kin::qsvo_setpoint(&handle, &offset.remove(&target), s_lin, s_rot);
        vc.set_speed(&out_twist)?;
        vc.set_position(&setpoint)?;
        Ok(())
    }

    /// What the callback loop streams after each call.
    fn stream_after_callback(&self) -> R<()> {
        self.stream_force()?;
        self.stream_qsvo()
    }

    /// COMMAND_TYPE_IMPEDANCE: stream the coupling set-point that applies
    /// the commanded force (virtSetForce + virtAddForce) to the handle.
    fn stream_force(&self) -> R<()> {
        let (frames, wrench, sat, ts) = {
            let st = self.state();
            if st.command != COMMAND_TYPE_IMPEDANCE || !st.force_feedback || st.shift_forced() {
                return Ok(());
            }
            let mut w = st.force_cmd;
            for (a, b) in w.iter_mut().zip(st.added_force.iter()) {
                *a += *b;
            }
            (st.frames, w, st.saturation, st.time_step)
        };
        let handle = self.read(|v| v.get_position())?;
        let twist = self.read(|v| v.get_speed()).unwrap_or([0.0; 6]);
        let w = kin::saturate(&wrench, sat.0, sat.1);
        let vc = self.session();
        // (The controller's mass cap is for VIRTMECH only.)
        let (k_lin, k_rot) = self.gains(&vc, None, ts);
        let target = kin::force_setpoint(&frames, &handle, &w, k_lin, k_rot);
        vc.set_speed(&twist)?;
        vc.set_position(&target)?;
        Ok(())
    }

    fn loop_running(&self) -> bool {
        lock(&self.periodic_loop)
            .as_ref()
            .map(|w| w.running())
            .unwrap_or(false)
    }

    /// Stop and join the callback loop and the recorder. Each worker is
    /// taken out of its slot and the slot's lock released before the join:
    /// a callback still running may call the API (which takes that lock)
    /// before it returns.
    fn stop_workers(&self) {
        let periodic = lock(&self.periodic_loop).take();
        if let Some(w) = periodic {
            w.stop();
        }
        let recorder = lock(&self.recorder).take();
        if let Some(w) = recorder {
            w.stop();
        }
    }
}

// ---- handles ------------------------------------------------------------------

/// The open contexts, by handle. A `VirtContext` given to C is a number
/// handed out once by `virtOpen` (never an address, never reused), so a
/// closed or never-opened handle is simply missing here: every call on it
/// fails at once with `VIRT_E_INVALID_CONTEXT`, whatever the memory it
/// once named holds now. The small values (from `HANDLE_BASE`) also
/// survive Haption's older headers that passed the context through an
/// `int`.
static CONTEXTS: RwLock<BTreeMap<usize, Arc<VirtContextS>>> = RwLock::new(BTreeMap::new());
/// The first handle; the next one `virtOpen` hands out.
const HANDLE_BASE: usize = 0x4843_0000;
static NEXT_HANDLE: AtomicUsize = AtomicUsize::new(HANDLE_BASE);

fn contexts() -> RwLockReadGuard<'static, BTreeMap<usize, Arc<VirtContextS>>> {
    match CONTEXTS.read() {
        Ok(g) => g,
        Err(p) => p.into_inner(),
    }
}

fn contexts_mut() -> RwLockWriteGuard<'static, BTreeMap<usize, Arc<VirtContextS>>> {
    match CONTEXTS.write() {
        Ok(g) => g,
        Err(p) => p.into_inner(),
    }
}

/// Register a new context; its handle.
fn register(c: VirtContextS) -> *mut c_void {
    let h = NEXT_HANDLE.fetch_add(1, Ordering::SeqCst);
    contexts_mut().insert(h, Arc::new(c));
    h as *mut c_void
}

/// The context of a handle: NULL, closed and never-opened handles are
/// `VIRT_E_INVALID_CONTEXT`.
fn ctx(vc: *mut c_void) -> R<Arc<VirtContextS>> {
    if vc.is_null() {
        return Err(ApiError::new(VIRT_E_INVALID_CONTEXT, "null context"));
    }
    contexts().get(&(vc as usize)).cloned().ok_or_else(|| {
        ApiError::new(
            VIRT_E_INVALID_CONTEXT,
            "invalid context: closed by virtClose or never returned by virtOpen",
        )
    })
}

/// Run `f` on the context and turn its result into the C status.
///
/// # Safety
/// The pointers `f` dereferences are valid as its caller's `# Safety`
/// requires (`vc` itself may be anything: it is looked up).
unsafe fn run(vc: *mut c_void, f: impl FnOnce(&Arc<VirtContextS>) -> R<()>) -> c_int {
    match ctx(vc) {
        Ok(c) => {
            let r = f(&c);
            c.last_error.store(
                r.as_ref().err().map(|e| e.code).unwrap_or(0),
                Ordering::SeqCst,
            );
            status_of(r)
        }
        Err(e) => status_of(Err(e)),
    }
}

/// # Safety
/// `p` is NULL or points to `N` readable floats.
unsafe fn read_arr<const N: usize>(p: *const c_float) -> R<[f32; N]> {
    if p.is_null() {
        return Err(ApiError::null());
    }
    let mut a = [0f32; N];
    // SAFETY: p points to N floats per the caller's contract.
    unsafe { std::ptr::copy_nonoverlapping(p, a.as_mut_ptr(), N) };
    Ok(a)
}

/// # Safety
/// `p` is NULL or points to `N` writable floats.
unsafe fn write_arr<const N: usize>(p: *mut c_float, a: [f32; N]) -> R<()> {
    if p.is_null() {
        return Err(ApiError::null());
    }
    // SAFETY: p points to N floats per the caller's contract.
    unsafe { std::ptr::copy_nonoverlapping(a.as_ptr(), p, N) };
    Ok(())
}

/// # Safety
/// `p` is NULL or points to a writable `T`.
unsafe fn put<T>(p: *mut T, v: T) -> R<()> {
    // SAFETY: per the contract.
    match unsafe { p.as_mut() } {
        Some(p) => {
            *p = v;
            Ok(())
        }
        None => Err(ApiError::null()),
    }
}

fn finite(name: &str, v: &[f32]) -> R<()> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(ApiError::new(
            VIRT_E_INCORRECT_VALUE,
            format!("{name}: NaN or infinite value"),
        ))
    }
}

fn hap_command(ty: c_int) -> R<CommandType> {
    match ty {
        COMMAND_TYPE_NONE => Ok(CommandType::None),
        // 1 and 2: the values of hapticctrl's first header.
        COMMAND_TYPE_IMPEDANCE | 1 => Ok(CommandType::Impedance),
        COMMAND_TYPE_VIRTMECH | 2 => Ok(CommandType::VirtMech),
        COMMAND_TYPE_ARTICULAR | COMMAND_TYPE_ARTICULAR_IMPEDANCE => {
            Err(ApiError::not_implemented(
                "articular command types (the controller has no joint-space mode)",
            ))
        }
        t => Err(ApiError::new(
            VIRT_E_INCORRECT_VALUE,
            format!("command type {t}"),
        )),
    }
}

fn haption_command(t: CommandType) -> c_int {
    match t {
        CommandType::None => COMMAND_TYPE_NONE,
        CommandType::Impedance => COMMAND_TYPE_IMPEDANCE,
        CommandType::VirtMech => COMMAND_TYPE_VIRTMECH,
    }
}

// ---- session ----------------------------------------------------------------

/// Open a session with the controller at `"host#port"`. NULL on error.
///
/// # Safety
/// `name` is NULL or a NUL-terminated string.
#[no_mangle]
pub unsafe extern "C" fn virtOpen(name: *const c_char) -> *mut c_void {
    if name.is_null() {
        set_error(&ApiError::new(VIRT_E_SYNTAX_ERROR, "null address"));
        return std::ptr::null_mut();
    }
    // SAFETY: NUL-terminated per the contract.
    let s = match unsafe { CStr::from_ptr(name) }.to_str() {
        Ok(s) => s,
        Err(_) => {
            set_error(&VirtError::InvalidAddress("not UTF-8".into()).into());
            return std::ptr::null_mut();
        }
    };
    match VirtContext::open(s) {
        Ok(vc) => {
            clear_error();
            let timeout_s = vc.options().reply_timeout.as_secs_f32() * vc.options().attempts as f32;
            register(VirtContextS {
                vc: RwLock::new(vc),
                st: Mutex::new(ApiState {
                    timeout_s,
                    ..Default::default()
                }),
                periodic_loop: Mutex::new(None),
                recorder: Mutex::new(None),
                overrun_latched: AtomicBool::new(false),
                overruns: AtomicU32::new(0),
                last_error: AtomicI32::new(0),
                closing: AtomicBool::new(false),
            })
        }
        Err(e) => {
            set_error(&e.into());
            std::ptr::null_mut()
        }
    }
}

/// Stop the callback loop and the recorder, close the session and free the
/// context: the handle is invalid from then on (every call on it fails
/// with `VIRT_E_INVALID_CONTEXT`).
///
/// Refused (`VIRT_E_CALL_TIME`) from the context's own periodic callback.
///
/// # Safety
/// None beyond the C ABI: `vc` may be any value (it is looked up).
#[no_mangle]
pub unsafe extern "C" fn virtClose(vc: *mut c_void) -> c_int {
    let c = match ctx(vc) {
        Ok(c) => c,
        Err(e) => return status_of(Err(e)),
    };
    // From the context's own callback, closing would join the loop's
    // thread from itself: refused. So is a second virtClose while the
    // first waits for a running callback to return (the callback calling
    // virtClose then): the first one closes the context.
    let in_callback = lock(&c.periodic_loop)
        .as_ref()
        .map(|w| w.id == std::thread::current().id())
        .unwrap_or(false);
    if in_callback || c.closing.swap(true, Ordering::SeqCst) {
        let e = ApiError::new(
            VIRT_E_CALL_TIME,
            "virtClose from the periodic callback or during virtClose: call virtStopLoop there, virtClose after",
        );
        c.last_error.store(e.code, Ordering::SeqCst);
        return status_of(Err(e));
    }
    // Joined while the handle is still valid: the callback may use it
    // until it returns.
    c.stop_workers();
    contexts_mut().remove(&(vc as usize));
    // A call another thread has in progress keeps its own reference; the
    // context is freed when the last one ends.
    let r = c.session_mut().close();
    status_of(r.map_err(ApiError::from))
}

/// # Safety
/// Each pointer is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn virtAPIVersion(major: *mut c_int, minor: *mut c_int) -> c_int {
    // SAFETY: per the contract.
    status_of(unsafe { put(major, API_VERSION.0).and_then(|_| put(minor, API_VERSION.1)) })
}

/// The controller's protocol version (major) and 0.
///
/// # Safety
/// Each pointer is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn virtGetControlerVersion(
    vc: *mut c_void,
    major: *mut c_int,
    minor: *mut c_int,
) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |_| {
            put(major, hap_core::protocol::VERSION as c_int)?;
            put(minor, 0)
        })
    }
}

/// Device type `0x4843` ("HC") and the session id as serial number.
///
/// # Safety
/// Each pointer is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn virtGetDeviceID(
    vc: *mut c_void,
    device_type: *mut c_int,
    serial: *mut c_int,
) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            let id = c.session().session_id();
            put(device_type, DEVICE_TYPE)?;
            put(serial, id as c_int)
        })
    }
}

/// Code of the last call on the context `vc` (0: it succeeded), whichever
/// thread made it; with `vc` NULL, of the calling thread's last call
/// (needed after a failed virtOpen).
///
/// # Safety
/// None: `vc` may be any value (a handle is looked up, never dereferenced).
#[no_mangle]
pub unsafe extern "C" fn virtGetErrorCode(vc: *mut c_void) -> c_int {
    if vc.is_null() {
        return LAST.with(|l| l.borrow().0);
    }
    match ctx(vc) {
        Ok(c) => c.last_error.load(Ordering::SeqCst),
        Err(e) => e.code,
    }
}

/// `virtGetErrorCode(vc)` in `*error`; -1 when `vc` is neither NULL nor an
/// open context (`*error` is then VIRT_E_INVALID_CONTEXT).
///
/// # Safety
/// `error` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn virtGetError(vc: *mut c_void, error: *mut c_int) -> c_int {
    // SAFETY: per the contract.
    let code = unsafe { virtGetErrorCode(vc) };
    // SAFETY: per the contract.
    match unsafe { error.as_mut() } {
        Some(p) => {
            *p = code;
            if vc.is_null() || ctx(vc).is_ok() {
                0
            } else {
                -1
            }
        }
        None => -1,
    }
}

/// Message for `code`: the detailed message of the calling thread's last
/// error if it has that code, else a generic one. The pointer stays valid
/// until the thread's next virt* call; the caller must not write to it.
#[no_mangle]
pub extern "C" fn virtGetErrorMessage(code: c_int) -> *mut c_char {
    LAST.with(|l| {
        let l = l.borrow();
        if l.0 == code && code != 0 && !l.1.as_bytes().is_empty() {
            l.1.as_ptr() as *mut c_char
        } else {
            generic(code).as_ptr() as *mut c_char
        }
    })
}

fn generic(code: c_int) -> &'static CStr {
    match code {
        0 => c"no error",
        1 => c"out of memory",
        2 => c"communication failure with the controller",
        3 => c"invalid context",
        4 => c"file not found",
        5 => c"wrong format",
        6 => c"time-out: no reply from the controller",
        7 => c"function not implemented by hapticctrl",
        8 => c"variable not available (no answer from the controller yet)",
        9 => c"incorrect value",
        10 => c"syntax error (address: \"host#port\" or \"host\")",
        11 => c"hardware error",
        12 => c"position discontinuity",
        13 => c"VirtuoseAPI library not found",
        14 => c"no periodic function set (virtSetPeriodicFunction)",
        15 => c"performance counter error",
        16 => c"major/minor version error",
        17 => c"wrong mode for this request",
        18 => c"mode not supported",
        19 => c"call time error",
        20 => c"incompatible version",
        21 => c"incorrect virtual-mechanism type",
        22 => c"already called",
        _ => c"unknown error code",
    }
}

/// Time-out of the requests and of the first answer, s (> 0).
///
/// # Safety
/// None: `vc` may be any value (a handle is looked up, never dereferenced).
#[no_mangle]
pub unsafe extern "C" fn virtSetTimeoutValue(vc: *mut c_void, t: c_float) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            if !(t > 0.0 && t.is_finite() && t <= 3600.0) {
                return Err(ApiError::new(
                    VIRT_E_INCORRECT_VALUE,
                    format!("time-out value {t} not in (0, 3600] s"),
                ));
            }
            {
                let mut s = c.session_mut();
                let mut o = s.options();
                let attempts = o.attempts.max(1);
                o.reply_timeout = Duration::from_secs_f32(t / attempts as f32);
                s.set_options(o);
            }
            c.state().timeout_s = t;
            Ok(())
        })
    }
}

/// # Safety
/// `t` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn virtGetTimeoutValue(vc: *mut c_void, t: *mut c_float) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe { run(vc, |c| put(t, c.state().timeout_s)) }
}

/// Stored; hapticctrl prints no debug output.
///
/// # Safety
/// None: `vc` may be any value (a handle is looked up, never dereferenced).
#[no_mangle]
pub unsafe extern "C" fn virtSetDebugFlags(vc: *mut c_void, flag: c_ushort) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            c.state().debug_flags = flag;
            Ok(())
        })
    }
}

/// The file the trajectory recorder writes (virtTrajRecordStart).
///
/// # Safety
/// `name` is NULL or a NUL-terminated string.
#[no_mangle]
pub unsafe extern "C" fn virtSetOutputFile(vc: *mut c_void, name: *mut c_char) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            if name.is_null() {
                return Err(ApiError::null());
            }
            let s = CStr::from_ptr(name)
                .to_str()
                .map_err(|_| ApiError::new(VIRT_E_INCORRECT_VALUE, "file name not UTF-8"))?;
            if s.is_empty() {
                return Err(ApiError::new(VIRT_E_INCORRECT_VALUE, "empty file name"));
            }
            c.state().output_file = Some(PathBuf::from(s));
            Ok(())
        })
    }
}

extern "C" {
    fn fputs(s: *const c_char, stream: *mut c_void) -> c_int;
    fn fflush(stream: *mut c_void) -> c_int;
}

/// Write the arm's status (power, dead-man, emergency stop, alarms, bounds)
/// to a C `FILE *`.
///
/// # Safety
/// `file` is NULL or an open `FILE *`.
#[no_mangle]
pub unsafe extern "C" fn virtDisplayHardwareStatus(vc: *mut c_void, file: *mut c_void) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            if file.is_null() {
                return Err(ApiError::null());
            }
            let st = c.read(|v| v.get_status())?;
            let al = c.read(|v| v.get_alarm())?;
            let b = c.joints().map(|q| kin::bounds(&q)).unwrap_or(0);
            let text = format!(
                "hapticctrl arm: power {}, motors {}, dead-man {}, emergency stop {}, \
                 status {st:#x}, alarms {al:#x}, bounds {b:#x}\n",
                on(st & status::POWER_ON),
                on(st & status::MOTORS_ENABLED),
                on(st & status::DEAD_MAN),
                if st & status::EMERGENCY_STOP != 0 {
                    "pressed"
                } else {
                    "released"
                },
            );
            let cs = CString::new(text).unwrap_or_default();
            // SAFETY: file is an open FILE * per the contract.
            if fputs(cs.as_ptr(), file) < 0 {
                return Err(ApiError::new(
                    VIRT_E_FILE_NOT_FOUND,
                    "cannot write the file",
                ));
            }
            fflush(file);
            Ok(())
        })
    }
}

fn on(bit: u32) -> &'static str {
    if bit != 0 {
        "on"
    } else {
        "off"
    }
}

// ---- configuration ------------------------------------------------------------

/// # Safety
/// None: `vc` may be any value (a handle is looked up, never dereferenced).
#[no_mangle]
pub unsafe extern "C" fn virtSetTimeStep(vc: *mut c_void, step: c_float) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            c.session().set_time_step(step)?;
            c.state().time_step = step;
            Ok(())
        })
    }
}

/// # Safety
/// `step` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn virtGetTimeStep(vc: *mut c_void, step: *mut c_float) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe { run(vc, |c| put(step, c.state().time_step)) }
}

/// 0 none, 3 impedance (the application sends forces), 5 virtual mechanism
/// (the application sends positions); 1 and 2 are accepted for 3 and 5.
/// 6 and 7 (articular): VIRT_E_NOT_IMPLEMENTED.
///
/// # Safety
/// None: `vc` may be any value (a handle is looked up, never dereferenced).
#[no_mangle]
pub unsafe extern "C" fn virtSetCommandType(vc: *mut c_void, ty: c_int) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            let t = hap_command(ty)?;
            let enabled = {
                let st = c.state();
                st.force_feedback && !st.shift_forced()
            };
            if enabled {
                c.session().set_command_type(t)?;
            }
            let mut st = c.state();
            st.command = haption_command(t);
            st.force_cmd = [0.0; 6];
            Ok(())
        })
    }
}

/// # Safety
/// `ty` is NULL or points to a writable VirtCommandType.
#[no_mangle]
pub unsafe extern "C" fn virtGetCommandType(vc: *mut c_void, ty: *mut c_int) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe { run(vc, |c| put(ty, c.state().command)) }
}

/// 0 all, 1 translations, 2 none, 3/4 with force-feedback inhibition;
/// 6 and 7 (rotations only): VIRT_E_NOT_IMPLEMENTED.
///
/// # Safety
/// None: `vc` may be any value (a handle is looked up, never dereferenced).
#[no_mangle]
pub unsafe extern "C" fn virtSetIndexingMode(vc: *mut c_void, mode: c_int) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            let m = match mode {
                6 | 7 => {
                    return Err(ApiError::not_implemented(
                        "rotation-only indexing (INDEXING_ROT*)",
                    ))
                }
                m => u32::try_from(m)
                    .ok()
                    .and_then(IndexingMode::from_u32)
                    .ok_or_else(|| {
                        ApiError::new(VIRT_E_INCORRECT_VALUE, format!("indexing mode {m}"))
                    })?,
            };
            c.session().set_indexing_mode(m)?;
            c.state().indexing = mode;
            Ok(())
        })
    }
}

/// # Safety
/// `mode` is NULL or points to a writable VirtIndexingType.
#[no_mangle]
pub unsafe extern "C" fn virtGetIndexingMode(vc: *mut c_void, mode: *mut c_int) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe { run(vc, |c| put(mode, c.state().indexing)) }
}

/// # Safety
/// None: `vc` may be any value (a handle is looked up, never dereferenced).
#[no_mangle]
pub unsafe extern "C" fn virtSetForceFactor(vc: *mut c_void, k: c_float) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            c.session_mut().set_force_factor(k)?;
            c.state().frames.force_factor = k as f64;
            Ok(())
        })
    }
}

/// # Safety
/// `k` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn virtGetForceFactor(vc: *mut c_void, k: *mut c_float) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe { run(vc, |c| put(k, c.state().frames.force_factor as f32)) }
}

/// # Safety
/// None: `vc` may be any value (a handle is looked up, never dereferenced).
#[no_mangle]
pub unsafe extern "C" fn virtSetSpeedFactor(vc: *mut c_void, k: c_float) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            c.session_mut().set_speed_factor(k)?;
            c.state().frames.speed_factor = k as f64;
            Ok(())
        })
    }
}

/// # Safety
/// `k` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn virtGetSpeedFactor(vc: *mut c_void, k: *mut c_float) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe { run(vc, |c| put(k, c.state().frames.speed_factor as f32)) }
}

fn normalized(p: [f32; 7]) -> [f32; 7] {
    let n = (p[3] as f64)
        .hypot(p[4] as f64)
        .hypot((p[5] as f64).hypot(p[6] as f64));
    let mut out = p;
    if n > 1e-6 {
        for v in &mut out[3..7] {
            *v = (*v as f64 / n) as f32;
        }
    }
    out
}

/// # Safety
/// `pos` is NULL or points to 7 floats.
#[no_mangle]
pub unsafe extern "C" fn virtSetBaseFrame(vc: *mut c_void, pos: *const c_float) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            let p = read_arr::<7>(pos)?;
            c.session().set_base_frame(&p)?;
            let mut st = c.state();
            st.frames.base = normalized(p);
            st.base_set = p;
            Ok(())
        })
    }
}

/// The base frame as set (the library computes with its quaternion
/// normalized).
///
/// # Safety
/// `pos` is NULL or points to 7 writable floats.
#[no_mangle]
pub unsafe extern "C" fn virtGetBaseFrame(vc: *mut c_void, pos: *mut c_float) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe { run(vc, |c| write_arr(pos, c.state().base_set)) }
}

/// # Safety
/// `pos` is NULL or points to 7 floats.
#[no_mangle]
pub unsafe extern "C" fn virtSetObservationFrame(vc: *mut c_void, pos: *const c_float) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            let p = read_arr::<7>(pos)?;
            c.session().set_observation_frame(&p)?;
            c.state().observation = p;
            Ok(())
        })
    }
}

/// The observation frame as set.
///
/// # Safety
/// `pos` is NULL or points to 7 writable floats.
#[no_mangle]
pub unsafe extern "C" fn virtGetObservationFrame(vc: *mut c_void, pos: *mut c_float) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe { run(vc, |c| write_arr(pos, c.state().observation)) }
}

/// The observation frame's twist `float[6]` (vx, vy, vz, wx, wy, wz in the
/// world frame), checked (finite) and kept with the observation frame:
/// hapticctrl's controller holds the observation frame where the last
/// virtSetObservationFrame put it (an application whose observer moves
/// sets the frame again as it moves).
///
/// # Safety
/// `speed` is NULL or points to 6 floats.
#[no_mangle]
pub unsafe extern "C" fn virtSetObservationFrameSpeed(
    vc: *mut c_void,
    speed: *const c_float,
) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            let v = read_arr::<6>(speed)?;
            finite("observation frame speed", &v)?;
            c.state().observation_speed = v;
            Ok(())
        })
    }
}

/// 6 joints.
///
/// # Safety
/// `n` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn virtGetNbAxes(vc: *mut c_void, n: *mut c_int) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe { run(vc, |_| put(n, kin::NB_AXES as c_int)) }
}

// ---- power, safety, buttons -------------------------------------------------------

/// # Safety
/// None: `vc` may be any value (a handle is looked up, never dereferenced).
#[no_mangle]
pub unsafe extern "C" fn virtSetPowerOn(vc: *mut c_void, power: c_int) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe { run(vc, |c| Ok(c.session().set_power_on(power != 0)?)) }
}

/// # Safety
/// `power` is NULL or points to a writable int.
#[no_mangle]
pub unsafe extern "C" fn virtGetPowerOn(vc: *mut c_void, power: *mut c_int) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe { run(vc, |c| put(power, c.read(|v| v.get_power_on())? as c_int)) }
}

/// 1 while the user holds the handle.
///
/// # Safety
/// `dead_man` is NULL or points to a writable int.
#[no_mangle]
pub unsafe extern "C" fn virtGetDeadMan(vc: *mut c_void, dead_man: *mut c_int) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            put(dead_man, c.read(|v| v.get_dead_man())? as c_int)
        })
    }
}

/// VirtuoseAPI's meaning: 1 when the system is operational (emergency stop
/// released), 0 when the emergency stop is pressed.
///
/// # Safety
/// `estop` is NULL or points to a writable int.
#[no_mangle]
pub unsafe extern "C" fn virtGetEmergencyStop(vc: *mut c_void, estop: *mut c_int) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            let pressed = c.read(|v| v.get_emergency_stop())?;
            put(estop, (!pressed) as c_int)
        })
    }
}

/// hapticctrl's alarm bits (`hap_core::vp::alarm`, bits 0–5) plus
/// VirtuoseAPI's: `VIRT_ALARM_SATURATE` when a motor torque was saturated,
/// `VIRT_ALARM_CALLBACK_OVERRUN` when the periodic callback overran since
/// the last read (cleared by this read).
///
/// # Safety
/// `alarm` is NULL or points to a writable unsigned int.
#[no_mangle]
pub unsafe extern "C" fn virtGetAlarm(vc: *mut c_void, alarm_out: *mut c_uint) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            let mut a = c.read(|v| v.get_alarm())?;
            if a & alarm::TORQUE_SATURATED != 0 {
                a |= VIRT_ALARM_SATURATE;
            }
            if c.overrun_latched.load(Ordering::SeqCst) {
                a |= VIRT_ALARM_CALLBACK_OVERRUN;
            }
            put(alarm_out, a)?;
            c.overrun_latched.store(false, Ordering::SeqCst);
            Ok(())
        })
    }
}

/// `VIRT_BREAKDOWN_MOTOR_1..6` all set while the controller's fail-safe is
/// engaged (it cuts every motor), 0 otherwise.
///
/// # Safety
/// `error` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn virtGetFailure(vc: *mut c_void, error: *mut c_uint) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            let a = c.read(|v| v.get_alarm())?;
            put(error, if a & alarm::FAIL_SAFE != 0 { 0x3f } else { 0 })
        })
    }
}

/// `VIRT_BOUND_*` bits from the joint angles and the simulator's joint
/// limits (`hap_core::arm::Q_MIN/Q_MAX`, margin 0.02 rad).
///
/// # Safety
/// `bounds` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn virtIsInBounds(vc: *mut c_void, bounds: *mut c_uint) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe { run(vc, |c| put(bounds, kin::bounds(&c.joints()?))) }
}

/// The status bit of a button of the handle, as Haption's applications
/// number them: 1 the first button (the shift, i.e. indexing, button), 2
/// the second; 0 is the first button too. None: the handle has no such
/// button.
pub fn button_bit(n: c_int) -> Option<u32> {
    match n {
        0 | 1 => Some(status::BUTTON_1),
        2 => Some(status::BUTTON_2),
        _ => None,
    }
}

/// Button `n` (1: the handle's first button, the shift/indexing one; 2:
/// its second; 0: the first): 1 while pressed. Any other number reads 0
/// (a button the handle does not have is never pressed), without error.
///
/// # Safety
/// `state` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn virtGetButton(vc: *mut c_void, n: c_int, state: *mut c_int) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            if state.is_null() {
                return Err(ApiError::null());
            }
            let pressed = match button_bit(n) {
                Some(bit) => c.read(|v| v.get_status())? & bit != 0,
                None => false,
            };
            put(state, pressed as c_int)
        })
    }
}

/// 1 while the shift (indexing) button is down: the handle's first button
/// pressed, or forced by virtForceShiftButton(1).
///
/// # Safety
/// `shift` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn virtIsInShiftPosition(vc: *mut c_void, shift: *mut c_int) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            if shift.is_null() {
                return Err(ApiError::null());
            }
            let pressed = c.read(|v| v.get_status())? & status::BUTTON_1 != 0;
            let forced = c.state().shift_forced();
            put(shift, (pressed || forced) as c_int)
        })
    }
}

/// 1: the application holds the shift (indexing) button down, 0: releases
/// it. The controller does not know of it: the library indexes. While
/// forced the avatar stays where it was (its position; in INDEXING_ALL*
/// its orientation too) and the controller is uncoupled (command type
/// NONE, force feedback inhibited); on release the offset between the
/// avatar and the handle is kept, so the avatar moves on from where it
/// stayed (virtGetPosition, virtGetAvatarPosition, and virtSetPosition's
/// poses back). In INDEXING_NONE it only shows in virtIsInShiftPosition.
///
/// # Safety
/// None: `vc` may be any value (a handle is looked up, never dereferenced).
#[no_mangle]
pub unsafe extern "C" fn virtForceShiftButton(vc: *mut c_void, force_shift: c_int) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            let (shift, indexing, command, enabled) = {
                let st = c.state();
                (st.shift, st.indexing, st.command, st.force_feedback)
            };
            let moves = indexing != 2;
            match (force_shift != 0, shift) {
                (true, Shift::Released) => {
                    let frozen = if moves { Some(c.avatar()?) } else { None };
                    if moves && enabled {
                        c.session().set_command_type(CommandType::None)?;
                    }
                    c.state().shift = Shift::Forced { frozen };
                }
                (false, Shift::Forced { frozen }) => {
                    if let Some(frozen) = frozen {
                        let handle = c.read(|v| v.get_position())?;
                        if enabled {
                            c.session().set_command_type(hap_command(command)?)?;
                        }
                        let mut st = c.state();
                        let rot = st.indexes_rotation();
                        let shown = st.shift_offset.apply(&handle);
                        // In the translation-only modes the orientation
                        // followed the handle: only the position offset moves.
                        let avatar = if rot {
                            frozen
                        } else {
                            let mut a = shown;
                            a[..3].copy_from_slice(&frozen[..3]);
                            a
                        };
                        st.shift_offset = st.shift_offset.between(&avatar, &handle, rot);
                    }
                    c.state().shift = Shift::Released;
                }
                _ => {}
            }
            Ok(())
        })
    }
}

/// Block until button `n` (numbered as in virtGetButton) is pressed; a
/// button the handle does not have is an error (VIRT_E_INCORRECT_VALUE). Fails with VIRT_E_TIME_OUT if the
/// controller stops answering for the time-out value.
///
/// # Safety
/// None: `vc` may be any value (a handle is looked up, never dereferenced).
#[no_mangle]
pub unsafe extern "C" fn virtWaitPressButton(vc: *mut c_void, n: c_int) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            let bit = button_bit(n).ok_or_else(|| {
                ApiError::new(
                    VIRT_E_INCORRECT_VALUE,
                    format!("button {n}: the handle has buttons 1 and 2 (0: the first)"),
                )
            })?;
            let timeout = Duration::from_secs_f32(c.state().timeout_s);
            loop {
                let s = c.read(|v| v.get_status())?;
                if s & bit != 0 {
                    return Ok(());
                }
                // Wait for the next answer without holding the session
                // (the periodic loop and other threads keep using it).
                let w = c.session().answer_waiter();
                if w.wait_newer(w.current().0, timeout).is_none() {
                    return Err(ApiError::new(
                        VIRT_E_TIME_OUT,
                        "controller silent while waiting for the button",
                    ));
                }
            }
        })
    }
}

// ---- virtual object and cartesian streams --------------------------------------------

/// Attach a virtual object: mass (kg) and `float[3]` principal inertia.
///
/// # Safety
/// `mxmymz` is NULL or points to 3 floats.
#[no_mangle]
pub unsafe extern "C" fn virtAttachVO(
    vc: *mut c_void,
    mass: c_float,
    mxmymz: *const c_float,
) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            let i = read_arr::<3>(mxmymz)?;
            c.session().attach_vo(mass, i)?;
            c.state().attachment = Attachment::Object { mass };
            Ok(())
        })
    }
}

/// Attach a quasi-static virtual object: an object without dynamics that
/// the application places (VIRTMECH: virtSetPosition, virtSetSpeed) and
/// the handle is coupled to as to an impedance set-point, with the
/// stiffnesses `Ks` and dampings `Bs` (`float[6]` each, rotations then
/// translations as in Haption's applications: N·m/rad, N·m·s/rad, N/m,
/// N·s/m, client units). The controller's spring and damper do the
/// coupling: the library streams the set-point between the handle and
/// the object that makes them apply `Ks·(object − handle)` and
/// `Bs·(object speed − handle speed)` per axis (`kin::qsvo_setpoint`),
/// each at most the controller's own gain for its servo period (its
/// limits, saturation and passivity observer act as on any coupling).
/// Outside the callback loop virtSetPosition streams it at once; in the
/// loop it is streamed after each call. virtGetForce reads the coupling
/// wrench on the object, virtGetPosition the object's pose.
///
/// # Safety
/// `ks` and `bs` are NULL or point to 6 floats.
#[no_mangle]
pub unsafe extern "C" fn virtAttachQSVO(
    vc: *mut c_void,
    ks: *const c_float,
    bs: *const c_float,
) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            let ks = read_arr::<6>(ks)?;
            let bs = read_arr::<6>(bs)?;
            finite("stiffness", &ks)?;
            finite("damping", &bs)?;
            if ks.iter().chain(bs.iter()).any(|v| *v < 0.0) {
                return Err(ApiError::new(
                    VIRT_E_INCORRECT_VALUE,
                    "stiffness and damping must be >= 0",
                ));
            }
            let ts = c.state().time_step;
            let vc = c.session();
            // A mass whose VIRTMECH cap (m / ts²) stays above the
            // controller's stiffness: the object has no dynamics.
            let k = VirtContextS::period_gains(&vc).k_lin.to_f64();
            let mass = (2.0 * k * (ts as f64) * (ts as f64)).max(1e-6) as f32;
            vc.attach_vo(mass, [0.0; 3])?;
            drop(vc);
            c.state().attachment = Attachment::QuasiStatic { ks, bs };
            Ok(())
        })
    }
}

/// Same as virtAttachVO (the controller has one virtual object).
///
/// # Safety
/// `mxmymz` is NULL or points to 3 floats.
#[no_mangle]
pub unsafe extern "C" fn virtAttachVOAvatar(
    vc: *mut c_void,
    mass: c_float,
    mxmymz: *const c_float,
) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe { virtAttachVO(vc, mass, mxmymz) }
}

/// # Safety
/// None: `vc` may be any value (a handle is looked up, never dereferenced).
#[no_mangle]
pub unsafe extern "C" fn virtDetachVO(vc: *mut c_void) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            c.session().detach_vo()?;
            let mut st = c.state();
            st.attachment = Attachment::None;
            st.object_pose = None;
            Ok(())
        })
    }
}

/// Same as virtDetachVO.
///
/// # Safety
/// None: `vc` may be any value (a handle is looked up, never dereferenced).
#[no_mangle]
pub unsafe extern "C" fn virtDetachVOAvatar(vc: *mut c_void) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe { virtDetachVO(vc) }
}

/// Stream the virtual object's pose (one frame with the last speed); the
/// force of virtAddForce, if any, is added to the coupling. With a
/// quasi-static object (virtAttachQSVO), its set-point instead (from the
/// callback loop: after the call). The pose is the application's (the
/// offset of forced shifts is taken off before it is sent).
///
/// # Safety
/// `pos` is NULL or points to 7 floats.
#[no_mangle]
pub unsafe extern "C" fn virtSetPosition(vc: *mut c_void, pos: *const c_float) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            let given = read_arr::<7>(pos)?;
            finite("position", &given)?;
            let (frames, added, sat, mass, ts, quasi_static, p) = {
                let mut st = c.state();
                st.object_pose = Some(given);
                (
                    st.frames,
                    st.added_force,
                    st.saturation,
                    st.vo_mass(),
                    st.time_step,
                    matches!(st.attachment, Attachment::QuasiStatic { .. }),
                    st.shift_offset.remove(&given),
                )
            };
            if quasi_static {
                return if c.loop_running() {
                    Ok(())
                } else {
                    c.stream_qsvo()
                };
            }
            let vc = c.session();
            let target = if added.iter().any(|v| *v != 0.0) {
                let (k_lin, k_rot) = c.gains(&vc, mass, ts);
                let w = kin::saturate(&added, sat.0, sat.1);
                kin::force_setpoint(&frames, &normalized(p), &w, k_lin, k_rot)
            } else {
                p
            };
            Ok(vc.set_position(&target)?)
        })
    }
}

/// Set the virtual object's twist (sent with the next virtSetPosition).
///
/// # Safety
/// `speed` is NULL or points to 6 floats.
#[no_mangle]
pub unsafe extern "C" fn virtSetSpeed(vc: *mut c_void, speed: *const c_float) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            let v = read_arr::<6>(speed)?;
            c.session().set_speed(&v)?;
            c.state().object_speed = v;
            Ok(())
        })
    }
}

/// COMMAND_TYPE_IMPEDANCE: the wrench (world frame, N and N·m) the arm
/// applies to the user's hand, saturated by virtSaturateTorque. Sent at
/// once, or after the callback when called from the periodic loop.
///
/// # Safety
/// `force` is NULL or points to 6 floats.
#[no_mangle]
pub unsafe extern "C" fn virtSetForce(vc: *mut c_void, force: *const c_float) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            let f = read_arr::<6>(force)?;
            finite("force", &f)?;
            {
                let mut st = c.state();
                if st.command != COMMAND_TYPE_IMPEDANCE {
                    return Err(ApiError::new(
                        VIRT_E_WRONG_MODE,
                        "virtSetForce needs COMMAND_TYPE_IMPEDANCE",
                    ));
                }
                st.force_cmd = f;
            }
            if c.loop_running() {
                Ok(())
            } else {
                c.stream_force()
            }
        })
    }
}

/// A wrench added to the coupling in every command type (it replaces the
/// previous one; zeros remove it).
///
/// # Safety
/// `force` is NULL or points to 6 floats.
#[no_mangle]
pub unsafe extern "C" fn virtAddForce(vc: *mut c_void, force: *const c_float) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            let f = read_arr::<6>(force)?;
            finite("force", &f)?;
            let impedance = {
                let mut st = c.state();
                st.added_force = f;
                st.command == COMMAND_TYPE_IMPEDANCE
            };
            if impedance && !c.loop_running() {
                c.stream_force()
            } else {
                Ok(())
            }
        })
    }
}

/// Limits of the norms of the force (N) and torque (N·m) sent by
/// virtSetForce/virtAddForce (both > 0).
///
/// # Safety
/// None: `vc` may be any value (a handle is looked up, never dereferenced).
#[no_mangle]
pub unsafe extern "C" fn virtSaturateTorque(
    vc: *mut c_void,
    force: c_float,
    torque: c_float,
) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            if !(force > 0.0 && torque > 0.0 && force.is_finite() && torque.is_finite()) {
                return Err(ApiError::new(
                    VIRT_E_INCORRECT_VALUE,
                    format!("saturation {force} N, {torque} N.m: both must be > 0"),
                ));
            }
            c.state().saturation = (force, torque);
            Ok(())
        })
    }
}

/// 0: the controller uncouples the arm (command type NONE); 1: the command
/// type set by virtSetCommandType again.
///
/// # Safety
/// None: `vc` may be any value (a handle is looked up, never dereferenced).
#[no_mangle]
pub unsafe extern "C" fn virtEnableForceFeedback(vc: *mut c_void, enable: c_int) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            let (cmd, forced) = {
                let st = c.state();
                (st.command, st.shift_forced())
            };
            let t = if enable != 0 {
                hap_command(cmd)?
            } else {
                CommandType::None
            };
            // (A forced shift keeps the controller uncoupled until released.)
            if !forced {
                c.session().set_command_type(t)?;
            }
            c.state().force_feedback = enable != 0;
            Ok(())
        })
    }
}

/// Stiffness (N/m, client units: × force factor ÷ speed factor) of the
/// coupling between the handle and the virtual object: the controller's
/// translational gain for its servo period, capped at `m / ts²` in VIRTMECH
/// with an attached object of mass `m`.
///
/// # Safety
/// `stiffness` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn virtGetSimulationStiffness(
    vc: *mut c_void,
    stiffness: *mut c_float,
) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe { run(vc, |c| put(stiffness, c.simulation_coupling().0 as f32)) }
}

/// Damping (N·s/m, client units) of the coupling (see
/// virtGetSimulationStiffness).
///
/// # Safety
/// `damping` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn virtGetSimulationDamping(vc: *mut c_void, damping: *mut c_float) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe { run(vc, |c| put(damping, c.simulation_coupling().1 as f32)) }
}

/// The pose of the Virtuose or of the object attached to it, `float[7]`,
/// world frame: in VIRTMECH with an object attached (virtAttachVO,
/// virtAttachQSVO), the object's pose as last given by virtSetPosition;
/// otherwise the avatar (virtGetAvatarPosition).
///
/// # Safety
/// `pos` is NULL or points to 7 writable floats.
#[no_mangle]
pub unsafe extern "C" fn virtGetPosition(vc: *mut c_void, pos: *mut c_float) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            if pos.is_null() {
                return Err(ApiError::null());
            }
            let object = {
                let st = c.state();
                match (st.command, st.attachment, st.object_pose) {
                    (
                        COMMAND_TYPE_VIRTMECH,
                        Attachment::Object { .. } | Attachment::QuasiStatic { .. },
                        Some(p),
                    ) => Some(p),
                    _ => None,
                }
            };
            match object {
                Some(p) => write_arr(pos, p),
                None => write_arr(pos, c.avatar()?),
            }
        })
    }
}

/// The handle (the end-effector, never the attached object) as the
/// application sees it, `float[7]`, world frame: the indexing offset and
/// the speed (motor scale) factor applied, with the offset of forced
/// shifts (virtForceShiftButton).
///
/// # Safety
/// `pos` is NULL or points to 7 writable floats.
#[no_mangle]
pub unsafe extern "C" fn virtGetAvatarPosition(vc: *mut c_void, pos: *mut c_float) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            if pos.is_null() {
                return Err(ApiError::null());
            }
            write_arr(pos, c.avatar()?)
        })
    }
}

/// Handle pose in the arm base frame, arm units.
///
/// # Safety
/// `pos` is NULL or points to 7 writable floats.
#[no_mangle]
pub unsafe extern "C" fn virtGetPhysicalPosition(vc: *mut c_void, pos: *mut c_float) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe { run(vc, |c| write_arr(pos, c.physical_pose()?)) }
}

/// Handle twist, `float[6]`, world frame.
///
/// # Safety
/// `speed` is NULL or points to 6 writable floats.
#[no_mangle]
pub unsafe extern "C" fn virtGetSpeed(vc: *mut c_void, speed: *mut c_float) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe { run(vc, |c| write_arr(speed, c.read(|v| v.get_speed())?)) }
}

/// Handle twist in the arm base frame, arm units.
///
/// # Safety
/// `speed` is NULL or points to 6 writable floats.
#[no_mangle]
pub unsafe extern "C" fn virtGetPhysicalSpeed(vc: *mut c_void, speed: *mut c_float) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            let w = c.read(|v| v.get_speed())?;
            let t = c.state().frames.physical_twist(&w);
            write_arr(speed, t)
        })
    }
}

/// Coupling wrench to apply to the virtual object, `float[6]`.
///
/// # Safety
/// `force` is NULL or points to 6 writable floats.
#[no_mangle]
pub unsafe extern "C" fn virtGetForce(vc: *mut c_void, force: *mut c_float) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe { run(vc, |c| write_arr(force, c.read(|v| v.get_force())?)) }
}

/// The controller's servo cycle counter of the last answer.
///
/// # Safety
/// `time` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn virtGetTimeLastUpdate(vc: *mut c_void, time: *mut c_uint) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe { run(vc, |c| put(time, c.read(|v| v.get_cycle())?)) }
}

// ---- joint space --------------------------------------------------------------

/// The 6 joint angles (rad), from the handle pose and the arm model.
///
/// # Safety
/// `pos` is NULL or points to 6 writable floats.
#[no_mangle]
pub unsafe extern "C" fn virtGetArticularPosition(vc: *mut c_void, pos: *mut c_float) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            let q = c.joints()?;
            write_arr(pos, q.map(|v| v as f32))
        })
    }
}

/// The 6 joint speeds (rad/s), from the handle twist and the arm's Jacobian.
///
/// # Safety
/// `speed` is NULL or points to 6 writable floats.
#[no_mangle]
pub unsafe extern "C" fn virtGetArticularSpeed(vc: *mut c_void, speed: *mut c_float) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            let q = c.joints()?;
            let w = c.read(|v| v.get_speed())?;
            let t = c.state().frames.physical_twist(&w);
            write_arr(speed, kin::joint_speeds(&q, &t).map(|v| v as f32))
        })
    }
}

// ---- periodic callback ----------------------------------------------------------

/// Register `f(vc, arg)`, called every `*period` seconds of the controller's
/// clock by virtStartLoop (see `periodic_loop`).
///
/// # Safety
/// `period` is NULL or readable; `f` stays callable
/// and `arg` valid until virtStopLoop/virtClose.
#[no_mangle]
pub unsafe extern "C" fn virtSetPeriodicFunction(
    vc: *mut c_void,
    f: Option<PeriodicFn>,
    period: *const c_float,
    arg: *mut c_void,
) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            let f = f.ok_or_else(ApiError::null)?;
            let p = *period.as_ref().ok_or_else(ApiError::null)?;
            if !(1e-4..=1.0).contains(&p) {
                return Err(ApiError::new(
                    VIRT_E_INCORRECT_VALUE,
                    format!("period {p} not in [0.0001, 1] s"),
                ));
            }
            if c.loop_running() {
                return Err(ApiError::new(
                    VIRT_E_ALREADY_CALLED,
                    "the loop is running: virtStopLoop first",
                ));
            }
            c.state().periodic = Some((f, arg as usize, p));
            Ok(())
        })
    }
}

struct LoopArgs {
    /// The handle the callback receives.
    handle: usize,
    ctx: Arc<VirtContextS>,
    f: PeriodicFn,
    arg: usize,
    period: Duration,
}

/// Cycles of the controller's servo between two calls of a periodic
/// function of `period` (at least 1; 1 when the controller announced no
/// period).
fn cycles_per_call(period: Duration, servo_period_us: u32) -> u32 {
    if servo_period_us == 0 {
        return 1;
    }
    let servo = u128::from(servo_period_us);
    let n = (period.as_micros() + servo / 2) / servo;
    u32::try_from(n).unwrap_or(u32::MAX).max(1)
}

/// `a` is at or after `b` on the controller's wrapping 32-bit cycle counter.
fn cycle_reached(a: u32, b: u32) -> bool {
    (a.wrapping_sub(b) as i32) >= 0
}

/// The callback loop, on the controller's clock: the function is called
/// when an answer shows that one period of servo cycles has passed since
/// the previous call (every answer when the period is the servo period), so
/// the application runs, and sends its set-points, at the rate the
/// controller serves, not faster: a controller slower than its nominal
/// period (emulation, a loaded host) is not flooded with set-points it
/// cannot use. After each call, in COMMAND_TYPE_IMPEDANCE, the force command
/// is streamed, and with a quasi-static object in VIRTMECH its set-point. A call (with the streaming) that ends when the controller
/// has already reached the next call's cycle is an overrun: latched in
/// `VIRT_ALARM_CALLBACK_OVERRUN`, counted, and the missed periods skipped.
/// Without answers (link lost), the function is not called.
fn periodic_loop(a: LoopArgs, stop: Arc<AtomicBool>) {
    let c = &a.ctx;
    let (waiter, servo_us) = {
        let vc = c.session();
        (vc.answer_waiter(), vc.link_stats().period_us)
    };
    let step = cycles_per_call(a.period, servo_us);
    // Each wait is bounded so that a stop request is seen promptly.
    let slice = Duration::from_millis(20);
    let (mut gen, _) = waiter.current();
    let mut due: Option<u32> = None;
    while !stop.load(Ordering::SeqCst) {
        let Some((g, cycle)) = waiter.wait_newer(gen, slice) else {
            continue;
        };
        gen = g;
        if let Some(d) = due {
            if !cycle_reached(cycle, d) {
                continue;
            }
        }
        if stop.load(Ordering::SeqCst) {
            break;
        }
        // SAFETY: f and arg are the application's, valid per
        // virtSetPeriodicFunction's contract.
        unsafe { (a.f)(a.handle as *mut c_void, a.arg as *mut c_void) };
        if let Err(e) = c.stream_after_callback() {
            c.last_error.store(e.code, Ordering::SeqCst);
            set_error(&e);
        }
        let mut next = cycle.wrapping_add(step);
        let (g_now, now) = waiter.current();
        if let Some(now) = now {
            if g_now != gen && cycle_reached(now, next) {
                c.overrun_latched.store(true, Ordering::SeqCst);
                c.overruns.fetch_add(1, Ordering::SeqCst);
                while cycle_reached(now, next) {
                    next = next.wrapping_add(step);
                }
            }
        }
        due = Some(next);
    }
}

/// Start calling the periodic function.
///
/// # Safety
/// None: `vc` may be any value (a handle is looked up, never dereferenced).
#[no_mangle]
pub unsafe extern "C" fn virtStartLoop(vc: *mut c_void) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            let (f, arg, p) = c.state().periodic.ok_or_else(|| {
                ApiError::new(
                    VIRT_E_PERIODIC_FUNCTION,
                    "no periodic function: call virtSetPeriodicFunction first",
                )
            })?;
            let mut slot = lock(&c.periodic_loop);
            if slot.as_ref().map(|w| w.running()).unwrap_or(false) {
                return Err(ApiError::new(VIRT_E_ALREADY_CALLED, "the loop is running"));
            }
            if let Some(old) = slot.take() {
                old.stop();
            }
            c.overruns.store(0, Ordering::SeqCst);
            let stop = Arc::new(AtomicBool::new(false));
            let args = LoopArgs {
                handle: vc as usize,
                ctx: Arc::clone(c),
                f,
                arg,
                period: Duration::from_secs_f32(p),
            };
            let s2 = stop.clone();
            let h = std::thread::Builder::new()
                .name("virt_loop".into())
                .spawn(move || periodic_loop(args, s2))
                .map_err(|e| ApiError::new(VIRT_E_PERIODIC_FUNCTION, e.to_string()))?;
            let id = h.thread().id();
            *slot = Some(Worker {
                stop,
                handle: Some(h),
                id,
            });
            Ok(())
        })
    }
}

/// Stop the loop: returns after the last call ended (at once when called
/// from the callback itself, which then is the last).
///
/// # Safety
/// None: `vc` may be any value (a handle is looked up, never dereferenced).
#[no_mangle]
pub unsafe extern "C" fn virtStopLoop(vc: *mut c_void) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            let w = lock(&c.periodic_loop).take();
            match w {
                Some(w) => {
                    w.stop();
                    Ok(())
                }
                None => Err(ApiError::new(
                    VIRT_E_PERIODIC_FUNCTION,
                    "the loop is not running",
                )),
            }
        })
    }
}

/// hapticctrl extension: overruns since virtStartLoop.
///
/// # Safety
/// `n` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn virtGetCallbackOverruns(vc: *mut c_void, n: *mut c_uint) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe { run(vc, |c| put(n, c.overruns.load(Ordering::SeqCst))) }
}

// ---- trajectory recording ---------------------------------------------------------

/// Sampling period of the recorder (s, > 0); `*record_time` receives the
/// longest recording, s.
///
/// # Safety
/// `record_time` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn virtTrajSetSamplingTimeStep(
    vc: *mut c_void,
    step: c_float,
    record_time: *mut c_uint,
) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            if !(step > 0.0 && step <= 10.0) {
                return Err(ApiError::new(
                    VIRT_E_INCORRECT_VALUE,
                    format!("sampling step {step} not in (0, 10] s"),
                ));
            }
            put(
                record_time,
                (TRAJ_MAX_SAMPLES as f64 * step as f64)
                    .round()
                    .min(u32::MAX as f64) as c_uint,
            )?;
            c.state().traj_step = step;
            Ok(())
        })
    }
}

/// Record the handle pose every sampling step of the controller's clock
/// into the file of virtSetOutputFile: one line per sample,
/// `t x y z qx qy qz qw cycle` (t in s of controller time from the first
/// sample, world frame, the answer's servo cycle).
///
/// # Safety
/// None: `vc` may be any value (a handle is looked up, never dereferenced).
#[no_mangle]
pub unsafe extern "C" fn virtTrajRecordStart(vc: *mut c_void) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            let (path, step) = {
                let st = c.state();
                (st.output_file.clone(), st.traj_step)
            };
            let path = path.ok_or_else(|| {
                ApiError::new(
                    VIRT_E_FILE_NOT_FOUND,
                    "no output file: call virtSetOutputFile first",
                )
            })?;
            let mut slot = lock(&c.recorder);
            if slot.as_ref().map(|w| w.running()).unwrap_or(false) {
                return Err(ApiError::new(VIRT_E_ALREADY_CALLED, "already recording"));
            }
            let file = std::fs::File::create(&path).map_err(|e| {
                ApiError::new(VIRT_E_FILE_NOT_FOUND, format!("{}: {e}", path.display()))
            })?;
            let stop = Arc::new(AtomicBool::new(false));
            let s2 = stop.clone();
            let ctx = Arc::clone(c);
            let period = Duration::from_secs_f32(step);
            let h = std::thread::Builder::new()
                .name("virt_traj".into())
                .spawn(move || record(&ctx, file, period, s2))
                .map_err(|e| ApiError::new(VIRT_E_OUT_OF_MEMORY, e.to_string()))?;
            let id = h.thread().id();
            *slot = Some(Worker {
                stop,
                handle: Some(h),
                id,
            });
            Ok(())
        })
    }
}

/// The recorder, on the controller's clock like the callback loop: a sample
/// when an answer reaches the next point of the sampling grid (every
/// `period` of servo cycles from the first answer after the start); its
/// time is the controller's, `(cycle - first cycle) × servo period`.
/// Without answers, no samples.
fn record(c: &VirtContextS, file: std::fs::File, period: Duration, stop: Arc<AtomicBool>) {
    let mut out = std::io::BufWriter::new(file);
    let (waiter, servo_us) = {
        let vc = c.session();
        (vc.answer_waiter(), vc.link_stats().period_us.max(1))
    };
    let step = cycles_per_call(period, servo_us);
    let (mut gen, _) = waiter.current();
    let mut first: Option<u32> = None;
    let mut due = 0u32;
    let mut n: u64 = 0;
    while !stop.load(Ordering::SeqCst) && n < TRAJ_MAX_SAMPLES {
        let Some((g, _)) = waiter.wait_newer(gen, Duration::from_millis(20)) else {
            continue;
        };
        gen = g;
        let sample = {
            let vc = c.session();
            vc.get_position().and_then(|p| Ok((p, vc.get_cycle()?)))
        };
        let Ok((p, cycle)) = sample else { continue };
        let c0 = *first.get_or_insert(cycle);
        if n > 0 && !cycle_reached(cycle, due) {
            continue;
        }
        let t = f64::from(cycle.wrapping_sub(c0)) * f64::from(servo_us) * 1e-6;
        if writeln!(
            out,
            "{t:.6} {} {} {} {} {} {} {} {cycle}",
            p[0], p[1], p[2], p[3], p[4], p[5], p[6]
        )
        .is_err()
        {
            break;
        }
        n += 1;
        // Next point of the grid (a late sample skips grid points).
        if n == 1 {
            due = c0;
        }
        while cycle_reached(cycle, due) {
            due = due.wrapping_add(step);
        }
    }
    let _ = out.flush();
}

/// Stop recording and close the file.
///
/// # Safety
/// None: `vc` may be any value (a handle is looked up, never dereferenced).
#[no_mangle]
pub unsafe extern "C" fn virtTrajRecordStop(vc: *mut c_void) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| match lock(&c.recorder).take() {
            Some(w) => {
                w.stop();
                Ok(())
            }
            None => Err(ApiError::new(VIRT_E_WRONG_MODE, "not recording")),
        })
    }
}

// ---- conversions ----------------------------------------------------------------

/// The conversions need no context: NULL, or an open one; any other value
/// is a closed or never-opened context.
fn no_context_or_open(vc: *mut c_void) -> R<()> {
    if vc.is_null() {
        Ok(())
    } else {
        ctx(vc).map(|_| ())
    }
}

/// `d` `float[7]` → `m` `float[16]` row-major homogeneous matrix
/// (translation in m[3], m[7], m[11]).
///
/// # Safety
/// `d` is NULL or points to 7 floats; `m` is NULL or to 16 writable floats.
#[no_mangle]
pub unsafe extern "C" fn virtConvertDeplToHomogeneMatrix(
    vc: *mut c_void,
    d: *const c_float,
    m: *mut c_float,
) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    status_of(no_context_or_open(vc).and_then(|_| unsafe {
        read_arr::<7>(d).and_then(|d| {
            finite("displacement", &d)?;
            write_arr(m, kin::pose_to_matrix(&d))
        })
    }))
}

/// `m` `float[16]` row-major homogeneous matrix → `d` `float[7]`.
///
/// # Safety
/// `d` is NULL or points to 7 writable floats; `m` is NULL or to 16 floats.
#[no_mangle]
pub unsafe extern "C" fn virtConvertHomogeneMatrixToDepl(
    vc: *mut c_void,
    d: *mut c_float,
    m: *const c_float,
) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    status_of(no_context_or_open(vc).and_then(|_| unsafe {
        read_arr::<16>(m).and_then(|m| {
            finite("matrix", &m)?;
            write_arr(d, kin::matrix_to_pose(&m))
        })
    }))
}

/// Luma of an RGB colour: `0.299 r + 0.587 g + 0.114 b`.
///
/// # Safety
/// `rgb` is NULL or points to 3 floats; `gray` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn virtConvertRGBToGrayscale(
    vc: *mut c_void,
    rgb: *const c_float,
    gray: *mut c_float,
) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    status_of(no_context_or_open(vc).and_then(|_| unsafe {
        read_arr::<3>(rgb).and_then(|c| put(gray, 0.299 * c[0] + 0.587 * c[1] + 0.114 * c[2]))
    }))
}

// ---- hapticctrl extension ------------------------------------------------------------

/// Link quality: answers per second, loss ratio (0..1), last RTT (ms).
/// Any pointer may be NULL.
///
/// # Safety
/// Each pointer is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn virtGetLinkStats(
    vc: *mut c_void,
    rate_hz: *mut c_float,
    loss_ratio: *mut c_float,
    rtt_ms: *mut c_float,
) -> c_int {
    // SAFETY: the pointers are as this function's `# Safety` requires.
    unsafe {
        run(vc, |c| {
            let s = c.session().link_stats();
            if let Some(p) = rate_hz.as_mut() {
                *p = s.rate_hz as f32;
            }
            if let Some(p) = loss_ratio.as_mut() {
                *p = s.loss_ratio as f32;
            }
            if let Some(p) = rtt_ms.as_mut() {
                *p = s.rtt_ms_last as f32;
            }
            Ok(())
        })
    }
}

// ---- what has no meaning on hapticctrl -------------------------------------------------

macro_rules! not_implemented {
    ($( $name:ident ( $($arg:ident : $ty:ty),* ) ; )*) => {
        $(
            /// Not implemented by hapticctrl: fails with VIRT_E_NOT_IMPLEMENTED
            /// (the context's code too, when `vc` is an open context; any other
            /// non-NULL `vc` is VIRT_E_INVALID_CONTEXT).
            ///
            /// # Safety
            /// None: `vc` may be any value (a handle is looked up, never dereferenced).
            #[no_mangle]
            pub unsafe extern "C" fn $name(vc: *mut c_void $(, $arg: $ty)*) -> c_int {
                $( let _ = $arg; )*
                let e = ApiError::not_implemented(stringify!($name));
                match ctx(vc) {
                    Ok(c) => c.last_error.store(e.code, Ordering::SeqCst),
                    // A context that is not open: that is the error.
                    Err(invalid) if !vc.is_null() => return status_of(Err(invalid)),
                    Err(_) => {}
                }
                status_of(Err(e))
            }
        )*
    };
}

not_implemented! {
    virtDisableControlConnexion(disable: c_int);
    virtSetCatchFrame(frame: *const c_float);
    virtGetCatchFrame(frame: *mut c_float);
    virtSetArticularPosition(pos: *const c_float);
    virtSetArticularSpeed(speed: *const c_float);
    virtSetArticularForce(force: *const c_float);
    virtGetArticularPositionOfAdditionalAxe(pos: *mut c_float);
    virtGetArticularSpeedOfAdditionalAxe(speed: *mut c_float);
    virtSetArticularPositionOfAdditionalAxe(pos: *const c_float);
    virtSetArticularSpeedOfAdditionalAxe(speed: *const c_float);
    virtSetArticularForceOfAdditionalAxe(effort: *const c_float);
    virtActiveSpeedControl(radius: c_float, speed_factor: c_float);
    virtDeactiveSpeedControl();
    virtActiveRotationSpeedControl(angle: c_float, speed_factor: c_float);
    virtDeactiveRotationSpeedControl();
    virtIsInSpeedControl(translation: *mut c_int, rotation: *mut c_int);
    virtSetForceInSpeedControl(force: c_float);
    virtSetTorqueInSpeedControl(torque: c_float);
    virtGetCenterSphere(pos: *mut c_float);
    virtGetAxisOfRotation(axe: *mut c_float);
    virtSetTexture(position: *const c_float, intensity: *const c_float, reinit: c_int);
    virtSetTextureForce(texture_force: *const c_float);
    virtSetGripperCommandType(ty: c_int);
    virtSetFingerTipSpeed(speed: *const c_float);
    virtGetADC(line: c_int, adc: *mut c_float);
    virtGetAnalogicInputs(inputs: *mut c_float);
    virtGetTorInputs(tor_in: *mut c_uint);
    virtOutputsSetting(outputs: c_uint);
    virtSetPwmOutput(pwm: *const c_float);
    virtGetMouseState(active: *mut c_int, left: *mut c_int, right: *mut c_int);
    virtGetTrackball(x_move: *mut c_int, y_move: *mut c_int);
    virtGetTrackballButton(active: *mut c_int, left: *mut c_int, middle: *mut c_int, right: *mut c_int);
    virtVmActivate();
    virtVmDeactivate();
    virtVmSetType(ty: c_int);
    virtVmSetBaseFrame(base: *const c_float);
    virtVmGetBaseFrame(base: *mut c_float);
    virtVmSetBaseFrameToCurrentFrame();
    virtVmSetDefaultToCartesianPosition();
    virtVmSetDefaultToTransparentMode();
    virtVmSetRobotMode(on_off: c_int);
    virtVmStartTrajSampling(nb_samples: c_uint);
    virtVmGetTrajSamples(samples: *mut c_float);
    virtVmWaitUpperBound();
    virtVmLoadSpline(file_name: *const c_char);
    virtVmSaveCurrentSpline(file_name: *const c_char);
    virtVmDeleteSpline(file_name: *const c_char);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_code_has_a_message() {
        for code in 0..=22 {
            assert_ne!(generic(code).to_str().unwrap(), "unknown error code");
        }
        assert_eq!(generic(23).to_str().unwrap(), "unknown error code");
    }

    #[test]
    fn null_pointers_are_errors_not_crashes() {
        // SAFETY: the pointers are as this function's `# Safety` requires.
        unsafe {
            assert!(virtOpen(std::ptr::null()).is_null());
            assert_eq!(virtGetErrorCode(std::ptr::null_mut()), VIRT_E_SYNTAX_ERROR);
            assert_eq!(virtSetTimeStep(std::ptr::null_mut(), 0.001), -1);
            assert_eq!(
                virtGetErrorCode(std::ptr::null_mut()),
                VIRT_E_INVALID_CONTEXT
            );
            assert_eq!(
                virtGetPosition(std::ptr::null_mut(), std::ptr::null_mut()),
                -1
            );
            assert_eq!(virtStartLoop(std::ptr::null_mut()), -1);
            assert_eq!(
                virtAPIVersion(std::ptr::null_mut(), std::ptr::null_mut()),
                -1
            );
            let bad = c"no-such-host.invalid#x";
            assert!(virtOpen(bad.as_ptr()).is_null());
            assert_eq!(virtGetErrorCode(std::ptr::null_mut()), VIRT_E_SYNTAX_ERROR);
            let msg = CStr::from_ptr(virtGetErrorMessage(VIRT_E_SYNTAX_ERROR))
                .to_str()
                .unwrap();
            assert!(msg.contains("bad port"), "{msg}");
            let mut e = -1;
            assert_eq!(virtGetError(std::ptr::null_mut(), &mut e), 0);
            assert_eq!(e, VIRT_E_SYNTAX_ERROR);
        }
    }

    fn open_fake() -> (crate::fake_peer::FakePeer, *mut c_void) {
        let p = crate::fake_peer::FakePeer::start(crate::fake_peer::FakePeerConfig {
            answer_every_period: true,
            ..Default::default()
        })
        .unwrap();
        let addr = CString::new(p.address()).unwrap();
        // SAFETY: a NUL-terminated string.
        let vc = unsafe { virtOpen(addr.as_ptr()) };
        assert!(!vc.is_null());
        (p, vc)
    }

    /// Every function of the dispatch that takes a context, called on `vc`
    /// with pointers to a scratch buffer: each must fail with
    /// VIRT_E_INVALID_CONTEXT (the calling thread's code and the handle's).
    /// The calls run on another thread; one that does not come back within
    /// 20 s is a hang (the figure printed is the slowest call).
    fn every_call_refuses(vc: *mut c_void, what: &str) {
        let handle = vc as usize;
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let mut buf = [0f32; 16];
            let p = buf.as_mut_ptr() as usize;
            let mut failures = Vec::new();
            let mut slowest = Duration::ZERO;
            for f in DllFunction::ALL {
                use DllFunction::*;
                if matches!(f, APIVERSION | OPEN | GETERRORMESSAGE) {
                    continue; // no context
                }
                // SETPERIODICFUNCTION's function pointer: NULL (None).
                let b = if *f == SETPERIODICFUNCTION { 0 } else { p };
                let t = Instant::now();
                // SAFETY: every pointer argument points to `buf` (16 floats,
                // as much as any function reads or writes).
                let r = unsafe { call_dll(*f as c_uint, [handle, b, p, p, p]) } as isize as c_int;
                slowest = slowest.max(t.elapsed());
                let thread_code = LAST.with(|l| l.borrow().0);
                // SAFETY: any handle value may be passed.
                let code = unsafe { virtGetErrorCode(handle as *mut c_void) };
                let expect = if *f == GETERRORCODE {
                    VIRT_E_INVALID_CONTEXT
                } else {
                    -1
                };
                if r != expect
                    || (*f != GETERRORCODE && thread_code != VIRT_E_INVALID_CONTEXT)
                    || code != VIRT_E_INVALID_CONTEXT
                {
                    failures.push(format!(
                        "{}: {r} (thread {thread_code}, handle {code})",
                        f.name()
                    ));
                }
            }
            let _ = tx.send((failures, slowest));
        });
        let (failures, slowest) = rx
            .recv_timeout(Duration::from_secs(20))
            .unwrap_or_else(|_| panic!("{what}: a call did not return within 20 s"));
        println!("{what}: slowest refused call {slowest:?}");
        assert!(failures.is_empty(), "{what}: {failures:#?}");
    }

    #[test]
    fn calls_on_a_closed_or_never_opened_context_fail_at_once() {
        let (_p, vc) = open_fake();
        // SAFETY: vc is the handle virtOpen returned.
        unsafe {
            let mut pos = [0f32; 7];
            assert_eq!(virtGetPosition(vc, pos.as_mut_ptr()), 0);
            assert_eq!(virtClose(vc), 0);
            // A second close is refused, not a double free.
            assert_eq!(virtClose(vc), -1);
            assert_eq!(
                virtGetErrorCode(std::ptr::null_mut()),
                VIRT_E_INVALID_CONTEXT
            );
            let mut e = 0;
            assert_eq!(virtGetError(vc, &mut e), -1);
            assert_eq!(e, VIRT_E_INVALID_CONTEXT);
            // The conversions need no context, but not a closed one.
            let mut m = [0f32; 16];
            assert_eq!(
                virtConvertDeplToHomogeneMatrix(vc, pos.as_ptr(), m.as_mut_ptr()),
                -1
            );
        }
        every_call_refuses(vc, "closed");
        // Values virtOpen never returned: an address, a small number, the
        // handle before the first one.
        let mut local = [0u8; 64];
        every_call_refuses(local.as_mut_ptr() as *mut c_void, "an address");
        every_call_refuses(7 as *mut c_void, "7");
        every_call_refuses((HANDLE_BASE - 1) as *mut c_void, "below the first handle");
    }

    #[test]
    fn handles_are_never_reused_and_fit_an_int() {
        let (_p, a) = open_fake();
        // SAFETY: handles from virtOpen.
        unsafe {
            assert_eq!(virtClose(a), 0);
            let (_q, b) = open_fake();
            assert_ne!(a, b, "a closed handle came back");
            assert!((b as usize) <= i32::MAX as usize);
            let mut t = 0f32;
            assert_eq!(virtGetTimeStep(a, &mut t), -1);
            assert_eq!(virtGetTimeStep(b, &mut t), 0);
            assert_eq!(virtClose(b), 0);
        }
    }

    #[test]
    fn call_dll_dispatches_as_haptions_older_headers_call() {
        use DllFunction::*;
        assert_eq!(DllFunction::ALL.len(), 129);
        for (i, f) in DllFunction::ALL.iter().enumerate() {
            assert_eq!(*f as usize, i);
            assert_eq!(DllFunction::from_u32(i as u32), Some(*f));
        }
        // Positions that fix the numbering (first, middle, last).
        assert_eq!(OPEN as u32, 28);
        assert_eq!(DEVICEID as u32, 121);
        assert_eq!(GETSIMULATIONDAMPING as u32, 128);
        let p = crate::fake_peer::FakePeer::start(crate::fake_peer::FakePeerConfig {
            answer_every_period: true,
            ..Default::default()
        })
        .unwrap();
        let addr = CString::new(p.address()).unwrap();
        let i = |r: usize| r as isize as c_int;
        // SAFETY: the arguments are what each wrapper passes: the context,
        // pointers, and scalars by address.
        unsafe {
            let vc = call_dll(OPEN as c_uint, [addr.as_ptr() as usize, 0, 0, 0, 0]);
            assert_ne!(vc, 0);
            let (mut maj, mut min) = (0, 0);
            let r = call_dll(
                APIVERSION as c_uint,
                [
                    &mut maj as *mut c_int as usize,
                    &mut min as *mut c_int as usize,
                    0,
                    0,
                    0,
                ],
            );
            assert_eq!((i(r), maj, min), (0, 4, 4));
            let step = 0.004f32;
            let r = call_dll(
                SETTIMESTEP as c_uint,
                [vc, &step as *const f32 as usize, 0, 0, 0],
            );
            assert_eq!(i(r), 0);
            let mut got = 0f32;
            let r = call_dll(
                GETTIMESTEP as c_uint,
                [vc, &mut got as *mut f32 as usize, 0, 0, 0],
            );
            assert_eq!((i(r), got), (0, 0.004));
            let ty = COMMAND_TYPE_IMPEDANCE;
            let r = call_dll(
                SETCOMMANDTYPE as c_uint,
                [vc, &ty as *const c_int as usize, 0, 0, 0],
            );
            assert_eq!(i(r), 0);
            let mut t = 0;
            let r = call_dll(
                GETCOMMANDTYPE as c_uint,
                [vc, &mut t as *mut c_int as usize, 0, 0, 0],
            );
            assert_eq!((i(r), t), (0, COMMAND_TYPE_IMPEDANCE));
            let mut pos = [0f32; 7];
            let r = call_dll(
                GETPOSITION as c_uint,
                [vc, pos.as_mut_ptr() as usize, 0, 0, 0],
            );
            assert_eq!(i(r), 0);
            assert!(
                (pos[3] * pos[3] + pos[4] * pos[4] + pos[5] * pos[5] + pos[6] * pos[6] - 1.0).abs()
                    < 1e-3
            );
            // A refused value: -1 through the uintptr_t, the code on the context.
            let bad = -1.0f32;
            let r = call_dll(
                SETTIMESTEP as c_uint,
                [vc, &bad as *const f32 as usize, 0, 0, 0],
            );
            assert_eq!(r, usize::MAX);
            assert_eq!(
                i(call_dll(GETERRORCODE as c_uint, [vc, 0, 0, 0, 0])),
                VIRT_E_INCORRECT_VALUE
            );
            let code = VIRT_E_INCORRECT_VALUE;
            let msg = call_dll(
                GETERRORMESSAGE as c_uint,
                [&code as *const c_int as usize, 0, 0, 0, 0],
            );
            assert!(!CStr::from_ptr(msg as *const c_char)
                .to_str()
                .unwrap()
                .is_empty());
            // A scalar passed by a NULL address: an error, not a crash.
            assert_eq!(
                call_dll(SETTIMESTEP as c_uint, [vc, 0, 0, 0, 0]),
                usize::MAX
            );
            assert_eq!(
                i(call_dll(GETERRORCODE as c_uint, [vc, 0, 0, 0, 0])),
                VIRT_E_INCORRECT_VALUE
            );
            // Numbered, without a wrapper: not implemented.
            assert_eq!(call_dll(FRICTION as c_uint, [vc, 0, 0, 0, 0]), usize::MAX);
            assert_eq!(
                i(call_dll(GETERRORCODE as c_uint, [vc, 0, 0, 0, 0])),
                VIRT_E_NOT_IMPLEMENTED
            );
            // A number no header has.
            assert_eq!(call_dll(129, [vc, 0, 0, 0, 0]), usize::MAX);
            assert_eq!(
                i(call_dll(GETERRORCODE as c_uint, [vc, 0, 0, 0, 0])),
                VIRT_E_INCORRECT_VALUE
            );
            assert_eq!(i(call_dll(CLOSE as c_uint, [vc, 0, 0, 0, 0])), 0);
            assert_eq!(call_dll(CLOSE as c_uint, [vc, 0, 0, 0, 0]), usize::MAX);
        }
    }

    #[test]
    fn calls_follow_the_servo_period() {
        let ms = Duration::from_millis;
        assert_eq!(cycles_per_call(ms(1), 1000), 1);
        assert_eq!(cycles_per_call(ms(1), 4000), 1);
        assert_eq!(cycles_per_call(ms(8), 4000), 2);
        assert_eq!(cycles_per_call(ms(10), 1000), 10);
        assert_eq!(cycles_per_call(Duration::from_micros(1500), 1000), 2);
        assert_eq!(cycles_per_call(ms(5), 0), 1);
        assert!(cycle_reached(5, 5) && cycle_reached(6, 5) && !cycle_reached(4, 5));
        // Across the 32-bit wrap of the controller's counter.
        assert!(cycle_reached(2, u32::MAX - 1) && !cycle_reached(u32::MAX - 1, 2));
    }

    #[test]
    fn not_implemented_functions_say_so() {
        // SAFETY: NULL contexts.
        unsafe {
            assert_eq!(virtVmActivate(std::ptr::null_mut()), -1);
            assert_eq!(
                virtGetErrorCode(std::ptr::null_mut()),
                VIRT_E_NOT_IMPLEMENTED
            );
        }
        // SAFETY: the pointers are as this function's `# Safety` requires.
        let msg = unsafe { CStr::from_ptr(virtGetErrorMessage(VIRT_E_NOT_IMPLEMENTED)) };
        assert!(msg.to_str().unwrap().contains("virtVmActivate"));
    }

    #[test]
    fn conversions_work_without_a_context() {
        let s = std::f32::consts::FRAC_1_SQRT_2;
        let d = [0.1f32, 0.2, 0.3, 0.0, s, 0.0, s];
        let mut m = [0f32; 16];
        let mut back = [0f32; 7];
        // SAFETY: the pointers are as this function's `# Safety` requires.
        unsafe {
            assert_eq!(
                virtConvertDeplToHomogeneMatrix(std::ptr::null_mut(), d.as_ptr(), m.as_mut_ptr()),
                0
            );
            assert_eq!(
                virtConvertHomogeneMatrixToDepl(
                    std::ptr::null_mut(),
                    back.as_mut_ptr(),
                    m.as_ptr()
                ),
                0
            );
        }
        for i in 0..7 {
            assert!((back[i] - d[i]).abs() < 1e-6, "{back:?}");
        }
        // 90° about y: z axis → x axis (m[2] = R[0][2] = 1).
        assert!((m[2] - 1.0).abs() < 1e-6 && m[3] == 0.1);
        let mut g = 0.0;
        // SAFETY: the pointers are as this function's `# Safety` requires.
        unsafe {
            assert_eq!(
                virtConvertRGBToGrayscale(
                    std::ptr::null_mut(),
                    [1.0f32, 1.0, 1.0].as_ptr(),
                    &mut g
                ),
                0
            );
        }
        assert!((g - 1.0).abs() < 1e-6);
    }
}
