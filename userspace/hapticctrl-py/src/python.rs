//! `hapticctrl._native`: the Python face of `virtuose_api::VirtContext`.
//! Every call goes through the Rust API (one protocol implementation);
//! calls that wait for the network release the GIL. Errors become the
//! exception classes of `hapticctrl._errors`, carrying VirtuoseAPI's code
//! (`virtuose_api::ffi::haption_code`) and the library's message.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

use numpy::{AllowTypeChange, PyArray1, PyArrayLike1, PyArrayMethods};
use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyTuple};

use hap_auth::Psk;
use hap_core::vp::status;
use virtuose_api::ffi::{haption_code, VIRT_E_FILE_NOT_FOUND, VIRT_E_INCORRECT_VALUE};
use virtuose_api::{
    split_options, AnswerWaiter, CommandType, IndexingMode, LinkStats, Options, VirtContext,
    VirtError, KEY_ENV,
};

use crate::pacing::{next_due, LinkFade, LoopTiming};

/// Python exception class name of a crate error.
fn class_of(e: &VirtError) -> &'static str {
    match e {
        VirtError::InvalidAddress(_) => "AddressError",
        VirtError::Io(_) => "CommunicationError",
        VirtError::Timeout(_) => "ControllerTimeoutError",
        VirtError::Refused { .. } => "RefusedError",
        VirtError::InvalidArgument(_) => "InvalidArgumentError",
        VirtError::NoData => "NoDataError",
        VirtError::Closed | VirtError::NullPointer => "ClosedError",
        VirtError::SessionEnded { .. } => "SessionEndedError",
    }
}

/// Build `hapticctrl._errors.<class>(code, message, **extra)`.
fn raise(
    py: Python<'_>,
    class: &str,
    code: i32,
    message: String,
    extra: &[(&str, Py<PyAny>)],
) -> PyErr {
    let build = || -> PyResult<PyErr> {
        let cls = py.import("hapticctrl._errors")?.getattr(class)?;
        let kw = PyDict::new(py);
        for (k, v) in extra {
            kw.set_item(*k, v)?;
        }
        let exc = cls.call((code, message.clone()), Some(&kw))?;
        Ok(PyErr::from_value(exc))
    };
    build().unwrap_or_else(|e| e)
}

fn to_py(py: Python<'_>, e: VirtError) -> PyErr {
    let code = haption_code(&e);
    let mut extra: Vec<(&str, Py<PyAny>)> = Vec::new();
    if let VirtError::SessionEnded { reason, name } = &e {
        extra.push((
            "reason",
            reason
                .into_pyobject(py)
                .map(|o| o.into_any().unbind())
                .unwrap_or_else(|_| py.None()),
        ));
        extra.push((
            "reason_name",
            name.into_pyobject(py)
                .map(|o| o.into_any().unbind())
                .unwrap_or_else(|_| py.None()),
        ));
    }
    if let VirtError::Refused {
        request,
        reason,
        name,
    } = &e
    {
        extra.push((
            "request",
            request
                .into_pyobject(py)
                .map(|o| o.into_any().unbind())
                .unwrap_or_else(|_| py.None()),
        ));
        extra.push((
            "reason",
            reason
                .into_pyobject(py)
                .map(|o| o.into_any().unbind())
                .unwrap_or_else(|_| py.None()),
        ));
        extra.push((
            "reason_name",
            name.into_pyobject(py)
                .map(|o| o.into_any().unbind())
                .unwrap_or_else(|_| py.None()),
        ));
    }
    raise(py, class_of(&e), code, e.to_string(), &extra)
}

fn invalid(py: Python<'_>, msg: String) -> PyErr {
    raise(py, "InvalidArgumentError", VIRT_E_INCORRECT_VALUE, msg, &[])
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    match m.lock() {
        Ok(g) => g,
        Err(p) => p.into_inner(),
    }
}

fn command_type(py: Python<'_>, s: &str) -> PyResult<CommandType> {
    match s.to_ascii_lowercase().as_str() {
        "none" => Ok(CommandType::None),
        "impedance" => Ok(CommandType::Impedance),
        "virtmech" => Ok(CommandType::VirtMech),
        _ => Err(invalid(
            py,
            format!("command type '{s}': none, impedance or virtmech"),
        )),
    }
}

fn indexing_mode(py: Python<'_>, s: &str) -> PyResult<IndexingMode> {
    match s.to_ascii_lowercase().as_str() {
        "all" => Ok(IndexingMode::All),
        "trans" => Ok(IndexingMode::Trans),
        "none" => Ok(IndexingMode::None),
        "all_force_feedback_inhibition" => Ok(IndexingMode::AllForceFeedbackInhibition),
        "trans_force_feedback_inhibition" => Ok(IndexingMode::TransForceFeedbackInhibition),
        _ => Err(invalid(
            py,
            format!("indexing mode '{s}': all, trans, none, all_force_feedback_inhibition or trans_force_feedback_inhibition"),
        )),
    }
}

/// A vector of exactly `N` finite numbers from any array-like.
fn vector<const N: usize>(
    py: Python<'_>,
    what: &str,
    v: &PyArrayLike1<'_, f64, AllowTypeChange>,
) -> PyResult<[f32; N]> {
    let a = v.as_array();
    if a.len() != N {
        return Err(invalid(
            py,
            format!("{what}: {} values, expected {N} (shape ({N},))", a.len()),
        ));
    }
    let mut out = [0f32; N];
    for (o, x) in out.iter_mut().zip(a.iter()) {
        if !x.is_finite() {
            return Err(invalid(py, format!("{what}: {x} is not finite")));
        }
        *o = *x as f32;
    }
    Ok(out)
}

/// `vector` of any object: a float64 numpy array is read in place, anything
/// else goes through numpy's conversion.
fn vector_of<const N: usize>(
    py: Python<'_>,
    what: &str,
    v: &Bound<'_, PyAny>,
) -> PyResult<[f32; N]> {
    if let Ok(a) = v.cast::<PyArray1<f64>>() {
        let r = a.readonly();
        if let Ok(sl) = r.as_slice() {
            if sl.len() != N {
                return Err(invalid(
                    py,
                    format!("{what}: {} values, expected {N} (shape ({N},))", sl.len()),
                ));
            }
            let mut out = [0f32; N];
            for (o, x) in out.iter_mut().zip(sl) {
                if !x.is_finite() {
                    return Err(invalid(py, format!("{what}: {x} is not finite")));
                }
                *o = *x as f32;
            }
            return Ok(out);
        }
    }
    let like: PyArrayLike1<'_, f64, AllowTypeChange> = v
        .extract()
        .map_err(|e| invalid(py, format!("{what}: {e}")))?;
    vector::<N>(py, what, &like)
}

fn array<'py, const N: usize>(py: Python<'py>, v: [f32; N]) -> Bound<'py, PyArray1<f64>> {
    let d: [f64; N] = v.map(f64::from);
    PyArray1::from_slice(py, &d)
}

/// One cycle of [`Session::run_loop`], given to the callback.
#[pyclass(module = "hapticctrl._native", frozen, get_all)]
pub struct Tick {
    /// Cycle number since the loop started (0, 1, ...).
    index: u64,
    /// Time since the loop started, s (host monotonic clock).
    t: f64,
    /// Time since the previous cycle's wake-up, s (the period at index 0).
    dt: f64,
    /// Handle pose `[x, y, z, qx, qy, qz, qw]` (m, unit quaternion), world frame.
    position: Py<PyArray1<f64>>,
    /// Handle twist `[vx, vy, vz, wx, wy, wz]` (m/s, rad/s), world frame.
    speed: Py<PyArray1<f64>>,
    /// Coupling wrench on the virtual object `[fx, fy, fz, tx, ty, tz]` (N,
    /// N·m), world frame, multiplied by `fade`.
    force: Py<PyArray1<f64>>,
    /// The controller's wrench as received (not faded).
    raw_force: Py<PyArray1<f64>>,
    /// 1 while the link is up; falls to 0 after a loss (`link_timeout`, `fade`).
    fade: f64,
    /// An answer arrived less than `link_timeout` ago.
    link_ok: bool,
    /// Age of the last answer, s.
    answer_age: f64,
    /// The last answer's servo cycle counter.
    cycle: u32,
    /// The last answer's `hap_core::vp::status` bits.
    status: u32,
}

/// Figures of a finished [`Session::run_loop`].
#[pyclass(module = "hapticctrl._native", frozen, get_all)]
pub struct LoopStats {
    cycles: u64,
    /// Cycles whose wake-up was more than a period late (periods skipped).
    overruns: u64,
    /// Mean achieved rate, Hz, and the period's mean, deviation (jitter),
    /// minimum and maximum, µs.
    rate_hz: f64,
    period_mean_us: f64,
    period_std_us: f64,
    period_min_us: f64,
    period_max_us: f64,
    /// Wake-up after the deadline, µs.
    lateness_mean_us: f64,
    lateness_max_us: f64,
    /// Wake-up to set-point sent (the callback and the streaming), µs.
    work_mean_us: f64,
    work_max_us: f64,
    /// Cycles with the link lost (`link_ok` false).
    link_lost_cycles: u64,
    /// With `record=True`: every period and every work time, µs (float32).
    periods_us: Option<Py<PyArray1<f32>>>,
    work_us: Option<Py<PyArray1<f32>>>,
}

#[pymethods]
impl LoopStats {
    fn __repr__(&self) -> String {
        format!(
            "LoopStats(cycles={}, rate_hz={:.1}, period_std_us={:.1}, lateness_max_us={:.1}, work_mean_us={:.1}, overruns={}, link_lost_cycles={})",
            self.cycles, self.rate_hz, self.period_std_us, self.lateness_max_us, self.work_mean_us, self.overruns, self.link_lost_cycles
        )
    }
}

/// A session with a hapticctrl controller (VirtuoseAPI's `VirtContext`).
#[pyclass(module = "hapticctrl._native")]
pub struct Session {
    ctx: Mutex<Option<VirtContext>>,
    waiter: AnswerWaiter,
    address: String,
    in_loop: AtomicBool,
}

impl Session {
    fn with<T>(
        &self,
        py: Python<'_>,
        f: impl FnOnce(&mut VirtContext) -> virtuose_api::Result<T>,
    ) -> PyResult<T> {
        let mut g = lock(&self.ctx);
        match g.as_mut() {
            Some(c) => f(c).map_err(|e| to_py(py, e)),
            None => Err(to_py(py, VirtError::Closed)),
        }
    }

    /// `with`, the GIL released (requests wait for acknowledgements).
    fn with_detached<T: Send>(
        &self,
        py: Python<'_>,
        f: impl FnOnce(&mut VirtContext) -> virtuose_api::Result<T> + Send,
    ) -> PyResult<T> {
        let r = py.detach(|| {
            let mut g = lock(&self.ctx);
            g.as_mut().map(f)
        });
        match r {
            Some(r) => r.map_err(|e| to_py(py, e)),
            None => Err(to_py(py, VirtError::Closed)),
        }
    }
}

fn stats_dict<'py>(py: Python<'py>, s: &LinkStats) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("sent", s.sent)?;
    d.set_item("vpr_sent", s.vpr_sent)?;
    d.set_item("answers", s.answers)?;
    d.set_item("lost", s.lost)?;
    d.set_item("duplicates", s.duplicates)?;
    d.set_item("stale", s.stale)?;
    d.set_item("decode_errors", s.decode_errors)?;
    d.set_item("rate_hz", s.rate_hz)?;
    d.set_item("loss_ratio", s.loss_ratio)?;
    d.set_item("rtt_ms_last", s.rtt_ms_last)?;
    d.set_item("rtt_ms_mean", s.rtt_ms_mean)?;
    d.set_item("rtt_ms_max", s.rtt_ms_max)?;
    d.set_item("period_us", s.period_us)?;
    Ok(d)
}

#[pymethods]
impl Session {
    /// Open a session. `address`: `"HOST#PORT"` (VirtuoseAPI's syntax; port
    /// 5000 if omitted), optionally `"HOST#PORT?key=FILE"`. The key (protocol
    /// v2): `key`, else the address's, else the file named by `HAP_KEY_FILE`;
    /// none of them raises `NoKeyError` unless `insecure=True` (protocol v1,
    /// which a bridge refuses unless it runs `--insecure`).
    #[new]
    #[pyo3(signature = (address, *, key=None, insecure=false, reply_timeout=0.25, attempts=4, link_passivity=false))]
    fn new(
        py: Python<'_>,
        address: &str,
        key: Option<std::path::PathBuf>,
        insecure: bool,
        reply_timeout: f64,
        attempts: u32,
        link_passivity: bool,
    ) -> PyResult<Session> {
        if !(reply_timeout > 0.0 && reply_timeout <= 60.0) {
            return Err(invalid(
                py,
                format!("reply_timeout {reply_timeout} not in (0, 60] s"),
            ));
        }
        if attempts == 0 {
            return Err(invalid(py, "attempts must be >= 1".into()));
        }
        let in_address = split_options(address.trim())
            .map_err(|e| to_py(py, e))?
            .1
            .key
            .is_some();
        let in_env = std::env::var_os(KEY_ENV).is_some_and(|v| !v.is_empty());
        let psk = match &key {
            Some(p) => {
                Some(Psk::load(p).map_err(|e| invalid(py, format!("key {}: {e}", p.display())))?)
            }
            None => None,
        };
        let keyed = psk.is_some() || in_address || in_env;
        match (keyed, insecure) {
            (false, false) => {
                return Err(raise(
                    py,
                    "NoKeyError",
                    VIRT_E_FILE_NOT_FOUND,
                    format!("no key for {address}: give key=FILE, \"HOST#PORT?key=FILE\" or {KEY_ENV}=FILE (insecure=True speaks the unauthenticated protocol v1)"),
                    &[],
                ))
            }
            (true, true) => {
                return Err(invalid(py, format!("insecure=True but a key is given (key=, ?key= or {KEY_ENV})")))
            }
            _ => {}
        }
        let opts = Options {
            reply_timeout: Duration::from_secs_f64(reply_timeout),
            attempts,
            key: psk,
            link_passivity,
        };
        let addr = address.to_string();
        let vc = py
            .detach(move || VirtContext::open_with(&addr, opts))
            .map_err(|e| to_py(py, e))?;
        Ok(Session {
            waiter: vc.answer_waiter(),
            ctx: Mutex::new(Some(vc)),
            address: address.to_string(),
            in_loop: AtomicBool::new(false),
        })
    }

    fn __enter__(slf: Py<Self>) -> Py<Self> {
        slf
    }

    #[pyo3(signature = (*_exc))]
    fn __exit__(&self, py: Python<'_>, _exc: &Bound<'_, PyTuple>) -> PyResult<bool> {
        self.close(py)?;
        Ok(false)
    }

    fn __repr__(&self) -> String {
        let g = lock(&self.ctx);
        match g.as_ref() {
            Some(c) => format!(
                "Session('{}', session_id={}, authenticated={})",
                self.address,
                c.session_id(),
                c.authenticated()
            ),
            None => format!("Session('{}', closed)", self.address),
        }
    }

    /// Close the session (acknowledged if the controller answers in time).
    /// Idempotent.
    fn close(&self, py: Python<'_>) -> PyResult<()> {
        if self.in_loop.load(Ordering::SeqCst) {
            return Err(PyRuntimeError::new_err(
                "close() from inside run_loop's callback: return False to end the loop first",
            ));
        }
        let taken = lock(&self.ctx).take();
        if let Some(mut c) = taken {
            py.detach(move || c.close()).map_err(|e| to_py(py, e))?;
        }
        Ok(())
    }

    #[getter]
    fn closed(&self) -> bool {
        lock(&self.ctx).is_none()
    }

    /// True for protocol v2 (authenticated).
    #[getter]
    fn authenticated(&self, py: Python<'_>) -> PyResult<bool> {
        self.with(py, |c| Ok(c.authenticated()))
    }

    #[getter]
    fn session_id(&self, py: Python<'_>) -> PyResult<u16> {
        self.with(py, |c| Ok(c.session_id()))
    }

    /// The controller's servo period announced at open, µs.
    #[getter]
    fn period_us(&self, py: Python<'_>) -> PyResult<u32> {
        self.with(py, |c| Ok(c.link_stats().period_us))
    }

    #[getter]
    fn address(&self) -> String {
        self.address.clone()
    }

    /// The simulation's time step, s (0 < dt <= 1).
    fn set_time_step(&self, py: Python<'_>, dt: f32) -> PyResult<()> {
        self.with_detached(py, |c| c.set_time_step(dt))
    }

    /// `"none"`, `"impedance"` or `"virtmech"`.
    fn set_command_type(&self, py: Python<'_>, command: &str) -> PyResult<()> {
        let t = command_type(py, command)?;
        self.with_detached(py, |c| c.set_command_type(t))
    }

    fn set_indexing_mode(&self, py: Python<'_>, mode: &str) -> PyResult<()> {
        let m = indexing_mode(py, mode)?;
        self.with_detached(py, |c| c.set_indexing_mode(m))
    }

    fn set_force_factor(&self, py: Python<'_>, k: f32) -> PyResult<()> {
        self.with_detached(py, |c| c.set_force_factor(k))
    }

    fn set_speed_factor(&self, py: Python<'_>, k: f32) -> PyResult<()> {
        self.with_detached(py, |c| c.set_speed_factor(k))
    }

    /// World → arm base, `[x, y, z, qx, qy, qz, qw]`.
    fn set_base_frame(
        &self,
        py: Python<'_>,
        pose: PyArrayLike1<'_, f64, AllowTypeChange>,
    ) -> PyResult<()> {
        let p = vector::<7>(py, "base frame", &pose)?;
        self.with_detached(py, |c| c.set_base_frame(&p))
    }

    /// World → observer, `[x, y, z, qx, qy, qz, qw]`.
    fn set_observation_frame(
        &self,
        py: Python<'_>,
        pose: PyArrayLike1<'_, f64, AllowTypeChange>,
    ) -> PyResult<()> {
        let p = vector::<7>(py, "observation frame", &pose)?;
        self.with_detached(py, |c| c.set_observation_frame(&p))
    }

    /// Attach a virtual object of `mass` kg and principal `inertia` (kg·m²).
    fn attach_vo(
        &self,
        py: Python<'_>,
        mass: f32,
        inertia: PyArrayLike1<'_, f64, AllowTypeChange>,
    ) -> PyResult<()> {
        let i = vector::<3>(py, "inertia", &inertia)?;
        self.with_detached(py, |c| c.attach_vo(mass, i))
    }

    fn detach_vo(&self, py: Python<'_>) -> PyResult<()> {
        self.with_detached(py, |c| c.detach_vo())
    }

    /// The arm's supply power request.
    fn set_power_on(&self, py: Python<'_>, on: bool) -> PyResult<()> {
        self.with_detached(py, |c| c.set_power_on(on))
    }

    /// Twist of the virtual object `[vx, vy, vz, wx, wy, wz]` (m/s, rad/s),
    /// sent with the next `set_position`.
    fn set_speed(
        &self,
        py: Python<'_>,
        twist: PyArrayLike1<'_, f64, AllowTypeChange>,
    ) -> PyResult<()> {
        let t = vector::<6>(py, "speed", &twist)?;
        self.with(py, |c| c.set_speed(&t))
    }

    /// Pose of the virtual object `[x, y, z, qx, qy, qz, qw]` (m, unit
    /// quaternion): streams one set-point (with the last speed given).
    fn set_position(
        &self,
        py: Python<'_>,
        pose: PyArrayLike1<'_, f64, AllowTypeChange>,
    ) -> PyResult<()> {
        let p = vector::<7>(py, "position", &pose)?;
        self.with(py, |c| c.set_position(&p))
    }

    /// Handle pose, shape (7,), float64.
    fn get_position<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        self.with(py, |c| c.get_position()).map(|v| array(py, v))
    }

    /// Handle twist, shape (6,), float64.
    fn get_speed<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        self.with(py, |c| c.get_speed()).map(|v| array(py, v))
    }

    /// Coupling wrench on the virtual object, shape (6,), float64.
    fn get_force<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        self.with(py, |c| c.get_force()).map(|v| array(py, v))
    }

    /// `hap_core::vp::status` bits of the last answer.
    #[getter]
    fn status(&self, py: Python<'_>) -> PyResult<u32> {
        self.with(py, |c| c.get_status())
    }

    #[getter]
    fn power_on(&self, py: Python<'_>) -> PyResult<bool> {
        self.with(py, |c| c.get_power_on())
    }

    #[getter]
    fn dead_man(&self, py: Python<'_>) -> PyResult<bool> {
        self.with(py, |c| c.get_dead_man())
    }

    #[getter]
    fn emergency_stop(&self, py: Python<'_>) -> PyResult<bool> {
        self.with(py, |c| c.get_emergency_stop())
    }

    /// `hap_core::vp::alarm` bits of the last answer.
    #[getter]
    fn alarms(&self, py: Python<'_>) -> PyResult<u32> {
        self.with(py, |c| c.get_alarm())
    }

    /// The last answer's servo cycle counter.
    #[getter]
    fn cycle(&self, py: Python<'_>) -> PyResult<u32> {
        self.with(py, |c| c.get_cycle())
    }

    /// Wait (GIL released) until an answer newer than the current one
    /// arrives; False on timeout.
    #[pyo3(signature = (timeout=1.0))]
    fn wait_answer(&self, py: Python<'_>, timeout: f64) -> PyResult<bool> {
        if !(timeout >= 0.0 && timeout.is_finite()) {
            return Err(invalid(
                py,
                format!("timeout {timeout} must be finite and >= 0"),
            ));
        }
        self.with(py, |_| Ok(()))?;
        let w = self.waiter.clone();
        let (gen, _) = w.current();
        Ok(py
            .detach(|| w.wait_newer(gen, Duration::from_secs_f64(timeout)))
            .is_some())
    }

    /// Rate, loss and round-trip time measured so far (a dict).
    fn link_stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let s = self.with(py, |c| Ok(c.link_stats()))?;
        stats_dict(py, &s)
    }

    /// Call `callback(tick)` every `period` s on the host's monotonic clock,
    /// the GIL released while waiting for the next deadline. `tick` holds
    /// the last answer (handle pose and twist, the coupling wrench scaled by
    /// the link fade). The callback returns None (nothing streamed), a pair
    /// `(pose, twist)` (streamed: `set_speed(twist)`, `set_position(pose)`),
    /// or False to end the loop; an exception it raises ends the loop and
    /// propagates. Ends after `duration` s or `cycles` cycles (whichever
    /// comes first; at least one must be given) and returns `LoopStats`.
    /// The link is lost when no answer arrived for `link_timeout` s; the
    /// wrench then fades to 0 over `fade` s (and back when answers return).
    #[pyo3(signature = (callback, *, period=0.001, duration=None, cycles=None, link_timeout=0.05, fade=0.1, record=false))]
    #[allow(clippy::too_many_arguments)]
    fn run_loop(
        &self,
        py: Python<'_>,
        callback: Bound<'_, PyAny>,
        period: f64,
        duration: Option<f64>,
        cycles: Option<u64>,
        link_timeout: f64,
        fade: f64,
        record: bool,
    ) -> PyResult<LoopStats> {
        if !(1e-4..=1.0).contains(&period) {
            return Err(invalid(py, format!("period {period} not in [0.0001, 1] s")));
        }
        if duration.is_none() && cycles.is_none() {
            return Err(invalid(py, "give duration= or cycles=".into()));
        }
        if let Some(d) = duration {
            if !(d > 0.0 && d.is_finite()) {
                return Err(invalid(py, format!("duration {d} must be > 0")));
            }
        }
        if !(link_timeout > 0.0 && link_timeout.is_finite() && fade >= 0.0 && fade.is_finite()) {
            return Err(invalid(
                py,
                format!("link_timeout {link_timeout} must be > 0 and fade {fade} >= 0"),
            ));
        }
        if !callback.is_callable() {
            return Err(invalid(py, "callback is not callable".into()));
        }
        self.with(py, |_| Ok(()))?;
        if self.in_loop.swap(true, Ordering::SeqCst) {
            return Err(PyRuntimeError::new_err(
                "run_loop is already running on this session",
            ));
        }
        let r = self.loop_body(
            py,
            &callback,
            period,
            duration,
            cycles,
            link_timeout,
            fade,
            record,
        );
        self.in_loop.store(false, Ordering::SeqCst);
        r
    }
}

impl Session {
    #[allow(clippy::too_many_arguments)]
    fn loop_body(
        &self,
        py: Python<'_>,
        callback: &Bound<'_, PyAny>,
        period: f64,
        duration: Option<f64>,
        cycles: Option<u64>,
        link_timeout: f64,
        fade: f64,
        record: bool,
    ) -> PyResult<LoopStats> {
        let period = Duration::from_secs_f64(period);
        let end_after = duration.map(Duration::from_secs_f64);
        let mut fader = LinkFade::new(
            Duration::from_secs_f64(link_timeout),
            Duration::from_secs_f64(fade),
        );
        let mut timing = LoopTiming::new(record);
        let mut lost_cycles = 0u64;
        let start = Instant::now();
        let (mut gen, _) = self.waiter.current();
        let mut last_answer_at = start;
        let mut due = start;
        let mut prev_wake: Option<Instant> = None;
        let mut index = 0u64;
        loop {
            if cycles.is_some_and(|n| index >= n)
                || end_after.is_some_and(|d| due.duration_since(start) >= d)
            {
                break;
            }
            py.detach(|| {
                let now = Instant::now();
                if due > now {
                    std::thread::sleep(due - now);
                }
            });
            let wake = Instant::now();
            let (g, _) = self.waiter.current();
            if g != gen {
                gen = g;
                last_answer_at = wake;
            }
            let age = wake.saturating_duration_since(last_answer_at);
            let dt = prev_wake.map_or(period, |p| wake.saturating_duration_since(p));
            let level = fader.step(dt, age);
            let link_ok = fader.link_ok(age);
            if !link_ok {
                lost_cycles += 1;
            }
            let snap = self.with(py, |c| {
                Ok((
                    c.get_position(),
                    c.get_speed(),
                    c.get_force(),
                    c.get_cycle(),
                    c.get_status(),
                ))
            })?;
            let (pose, speed, force, cycle, status) = match snap {
                (Ok(p), Ok(s), Ok(f), Ok(cy), Ok(st)) => (p, s, f, cy, st),
                // No answer yet: nothing to give the application.
                _ => (
                    [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
                    [0.0; 6],
                    [0.0; 6],
                    0,
                    0,
                ),
            };
            let faded = force.map(|x| (f64::from(x) * level) as f32);
            let tick = Tick {
                index,
                t: wake.duration_since(start).as_secs_f64(),
                dt: dt.as_secs_f64(),
                position: array(py, pose).unbind(),
                speed: array(py, speed).unbind(),
                force: array(py, faded).unbind(),
                raw_force: array(py, force).unbind(),
                fade: level,
                link_ok,
                answer_age: age.as_secs_f64(),
                cycle,
                status,
            };
            let ret = callback.call1((tick,))?;
            let mut stop = false;
            // Checked by type, not by trying conversions (a failed one
            // builds an exception: microseconds every cycle).
            if ret.is_none() {
            } else if let Ok(b) = ret.cast::<PyBool>() {
                if b.is_true() {
                    return Err(invalid(
                        py,
                        "the callback returns None, (pose, twist) or False".into(),
                    ));
                }
                stop = true;
            } else if let Some(pair) = ret.cast::<PyTuple>().ok().filter(|t| t.len() == 2) {
                let p = vector_of::<7>(py, "callback's pose", &pair.get_item(0)?)?;
                let t = vector_of::<6>(py, "callback's twist", &pair.get_item(1)?)?;
                self.with(py, |c| {
                    c.set_speed(&t)?;
                    c.set_position(&p)
                })?;
            } else {
                return Err(invalid(
                    py,
                    "the callback returns None, (pose, twist) or False".into(),
                ));
            }
            let done = Instant::now();
            timing.record(due, wake, done);
            py.check_signals()?;
            if stop {
                break;
            }
            let (next, skipped) = next_due(due, period, done);
            if skipped {
                timing.overruns += 1;
            }
            due = next;
            prev_wake = Some(wake);
            index += 1;
        }
        let (periods_us, work_us) = match timing.trace.take() {
            Some((p, w)) => (
                Some(PyArray1::from_vec(py, p).unbind()),
                Some(PyArray1::from_vec(py, w).unbind()),
            ),
            None => (None, None),
        };
        Ok(LoopStats {
            cycles: timing.cycles,
            overruns: timing.overruns,
            rate_hz: timing.rate_hz(),
            period_mean_us: timing.period_mean_us(),
            period_std_us: timing.period_std_us(),
            period_min_us: timing.period_min_us,
            period_max_us: timing.period_max_us,
            lateness_mean_us: timing.lateness_mean_us(),
            lateness_max_us: timing.lateness_max_us,
            work_mean_us: timing.work_mean_us(),
            work_max_us: timing.work_max_us,
            link_lost_cycles: lost_cycles,
            periods_us,
            work_us,
        })
    }
}

/// VirtuoseAPI's generic message of an error code.
#[pyfunction]
fn error_message(code: i32) -> String {
    let p = virtuose_api::ffi::virtGetErrorMessage(code);
    if p.is_null() {
        return String::new();
    }
    // SAFETY: virtGetErrorMessage returns a pointer to a NUL-terminated
    // string that lives as long as the library (a static message, or this
    // thread's last message, which only the C ABI's calls change).
    unsafe { std::ffi::CStr::from_ptr(p) }
        .to_string_lossy()
        .into_owned()
}

#[pymodule]
#[pyo3(name = "_native")]
fn hapticctrl_native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Session>()?;
    m.add_class::<Tick>()?;
    m.add_class::<LoopStats>()?;
    m.add_function(wrap_pyfunction!(error_message, m)?)?;
    m.add("KEY_ENV", KEY_ENV)?;
    m.add("DEFAULT_PORT", virtuose_api::DEFAULT_PORT)?;
    m.add("VERSION", env!("CARGO_PKG_VERSION"))?;
    m.add("STATUS_POWER_ON", status::POWER_ON)?;
    m.add("STATUS_MOTORS_ENABLED", status::MOTORS_ENABLED)?;
    m.add("STATUS_DEAD_MAN", status::DEAD_MAN)?;
    m.add("STATUS_EMERGENCY_STOP", status::EMERGENCY_STOP)?;
    m.add("STATUS_COUPLED", status::COUPLED)?;
    m.add("STATUS_LINK_FADING", status::LINK_FADING)?;
    Ok(())
}
