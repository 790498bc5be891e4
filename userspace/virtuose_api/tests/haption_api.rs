//! The VirtuoseAPI C ABI (`include/VirtuoseAPI.h`) against the fake
//! controller: getters of the setters, impedance forces as coupling
//! set-points, saturation, force-feedback switch, the periodic callback loop
//! and its overrun alarm, physical and articular reads, bounds, trajectory
//! recording and the functions that are not implemented.

use std::ffi::{c_int, c_uint, c_void, CString};
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::time::Duration;

use hap_core::control::Gains;
use hap_core::fixed::{Fx, Joints};
use virtuose_api::fake_peer::{FakePeer, FakePeerConfig};
use virtuose_api::ffi::*;

fn peer(center: [f64; 3], amplitude: [f64; 3]) -> FakePeer {
    FakePeer::start(FakePeerConfig {
        center,
        amplitude,
        answer_every_period: true,
        twist_every: 4,
        ..Default::default()
    })
    .unwrap()
}

fn open(p: &FakePeer) -> *mut c_void {
    let addr = CString::new(p.address()).unwrap();
    // SAFETY: a NUL-terminated string.
    let vc = unsafe { virtOpen(addr.as_ptr()) };
    assert!(!vc.is_null(), "virtOpen failed: {}", code());
    vc
}

fn k_lin() -> f64 {
    Gains::for_period(Fx::from_ratio(1000, 1_000_000))
        .k_lin
        .to_f64()
}

/// The calling thread's last error code.
fn code() -> c_int {
    // SAFETY: NULL asks for the calling thread's code.
    unsafe { virtGetErrorCode(std::ptr::null_mut()) }
}

#[test]
fn getters_return_what_the_setters_set() {
    let p = peer([0.4, 0.0, 0.3], [0.0; 3]);
    let vc = open(&p);
    let s = std::f32::consts::FRAC_1_SQRT_2;
    let base = [0.1f32, 0.2, 0.3, 0.0, 0.0, s, s];
    let obs = [1.0f32, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0];
    // SAFETY: vc is live; the arrays have the sizes the functions need.
    unsafe {
        assert_eq!(virtSetTimeStep(vc, 0.002), 0);
        assert_eq!(virtSetCommandType(vc, COMMAND_TYPE_VIRTMECH), 0);
        assert_eq!(virtSetIndexingMode(vc, 1), 0);
        assert_eq!(virtSetForceFactor(vc, 0.5), 0);
        assert_eq!(virtSetSpeedFactor(vc, 2.0), 0);
        assert_eq!(virtSetBaseFrame(vc, base.as_ptr()), 0);
        assert_eq!(virtSetObservationFrame(vc, obs.as_ptr()), 0);
        assert_eq!(virtSetTimeoutValue(vc, 0.6), 0);
        let (mut f, mut ty, mut im) = (0f32, 0, 0);
        assert_eq!(virtGetTimeStep(vc, &mut f), 0);
        assert_eq!(f, 0.002);
        assert_eq!(virtGetCommandType(vc, &mut ty), 0);
        assert_eq!(ty, COMMAND_TYPE_VIRTMECH);
        assert_eq!(virtGetIndexingMode(vc, &mut im), 0);
        assert_eq!(im, 1);
        assert_eq!(virtGetForceFactor(vc, &mut f), 0);
        assert_eq!(f, 0.5);
        assert_eq!(virtGetSpeedFactor(vc, &mut f), 0);
        assert_eq!(f, 2.0);
        assert_eq!(virtGetTimeoutValue(vc, &mut f), 0);
        assert_eq!(f, 0.6);
        let mut got = [0f32; 7];
        assert_eq!(virtGetBaseFrame(vc, got.as_mut_ptr()), 0);
        assert_eq!(got, base);
        assert_eq!(virtGetObservationFrame(vc, got.as_mut_ptr()), 0);
        assert_eq!(got, obs);
        // Rejected values leave the state as it was.
        assert_eq!(virtSetCommandType(vc, 4), -1);
        assert_eq!(code(), VIRT_E_INCORRECT_VALUE);
        assert_eq!(virtSetCommandType(vc, COMMAND_TYPE_ARTICULAR), -1);
        assert_eq!(code(), VIRT_E_NOT_IMPLEMENTED);
        assert_eq!(virtSetIndexingMode(vc, 7), -1);
        assert_eq!(code(), VIRT_E_NOT_IMPLEMENTED);
        assert_eq!(virtGetCommandType(vc, &mut ty), 0);
        assert_eq!(ty, COMMAND_TYPE_VIRTMECH);
        assert_eq!(virtSetTimeoutValue(vc, -1.0), -1);
        assert_eq!(code(), VIRT_E_INCORRECT_VALUE);
        // Versions, axes, device id.
        let (mut a, mut b) = (0, 0);
        assert_eq!(virtAPIVersion(&mut a, &mut b), 0);
        assert_eq!((a, b), (4, 4));
        assert_eq!(virtGetControlerVersion(vc, &mut a, &mut b), 0);
        assert_eq!((a, b), (1, 0));
        assert_eq!(virtGetNbAxes(vc, &mut a), 0);
        assert_eq!(a, 6);
        assert_eq!(virtGetDeviceID(vc, &mut a, &mut b), 0);
        assert_eq!(a, 0x4843);
        assert!(b > 0, "session id {b}");
        assert_eq!(virtClose(vc), 0);
    }
    assert_eq!(p.stats().command_type, Some(2)); // hapticctrl's VirtMech
}

#[test]
fn physical_position_undoes_the_base_frame_and_speed_factor() {
    // The fake reports the handle at `center` in the world frame.
    let p = peer([0.5, 0.2, 0.3], [0.0; 3]);
    let vc = open(&p);
    let s = std::f32::consts::FRAC_1_SQRT_2;
    // Base: 90° about z, at (0.1, 0, 0); speed factor 2.
    let base = [0.1f32, 0.0, 0.0, 0.0, 0.0, s, s];
    // SAFETY: vc is live; the arrays have the sizes the functions need.
    unsafe {
        assert_eq!(virtSetBaseFrame(vc, base.as_ptr()), 0);
        assert_eq!(virtSetSpeedFactor(vc, 2.0), 0);
        let mut world = [0f32; 7];
        let mut phys = [0f32; 7];
        let mut avatar = [0f32; 7];
        assert_eq!(virtGetPosition(vc, world.as_mut_ptr()), 0);
        assert_eq!(virtGetAvatarPosition(vc, avatar.as_mut_ptr()), 0);
        assert_eq!(virtGetPhysicalPosition(vc, phys.as_mut_ptr()), 0);
        assert_eq!(world, avatar);
        assert!((world[0] - 0.5).abs() < 1e-6);
        // world − base = (0.4, 0.2, 0); rotated by −90° about z: (0.2, −0.4, 0); / 2
        let want = [0.1f32, -0.2, 0.15];
        for i in 0..3 {
            assert!((phys[i] - want[i]).abs() < 1e-5, "{phys:?}");
        }
        // orientation: base⁻¹ ⊗ identity = −90° about z
        assert!(
            (phys[5] + s).abs() < 1e-5 && (phys[6] - s).abs() < 1e-5,
            "{phys:?}"
        );
        assert_eq!(virtClose(vc), 0);
    }
}

fn fk(q: &[f64; 6]) -> [f32; 7] {
    let mut qj: Joints = [Fx::ZERO; 6];
    for (d, s) in qj.iter_mut().zip(q.iter()) {
        *d = Fx::from_f64(*s);
    }
    let k = hap_core::arm::kinematics(&qj);
    let p = k.handle.position.to_f64();
    let o = k.handle.orientation.to_f64();
    [
        p[0] as f32,
        p[1] as f32,
        p[2] as f32,
        o[0] as f32,
        o[1] as f32,
        o[2] as f32,
        o[3] as f32,
    ]
}

#[test]
fn articular_reads_and_bounds_follow_the_arm_model() {
    // The fake's handle has the identity orientation: place it where the
    // arm reaches with that orientation, and check the joints reproduce it.
    let p = peer([0.6, 0.1, 0.35], [0.0; 3]);
    let vc = open(&p);
    // SAFETY: vc is live; the arrays have the sizes the functions need.
    unsafe {
        let mut q = [0f32; 20];
        assert_eq!(virtGetArticularPosition(vc, q.as_mut_ptr()), 0);
        // Six values written, nothing beyond (ViSP counts the non-zero ones).
        assert!(q[6..].iter().all(|v| *v == 0.0), "{q:?}");
        let qd: [f64; 6] = std::array::from_fn(|i| q[i] as f64);
        let back = fk(&qd);
        for (i, want) in [0.6f32, 0.1, 0.35].iter().enumerate() {
            assert!((back[i] - want).abs() < 1e-3, "{q:?} → {back:?}");
        }
        assert!(back[6].abs() > 0.999, "{back:?}");
        let mut b: c_uint = 99;
        assert_eq!(virtIsInBounds(vc, &mut b), 0);
        let lo_hi = (0..6).any(|i| {
            let lo = hap_core::arm::Q_MIN[i].to_f64();
            let hi = hap_core::arm::Q_MAX[i].to_f64();
            qd[i] <= lo + 0.02 || qd[i] >= hi - 0.02
        });
        assert_eq!(b != 0, lo_hi, "bounds {b:#x} for {qd:?}");
        let mut v = [0f32; 6];
        assert_eq!(virtGetArticularSpeed(vc, v.as_mut_ptr()), 0);
        assert!(v.iter().all(|x| x.is_finite()));
        assert_eq!(virtClose(vc), 0);
    }
    // Out of reach: an error, not garbage.
    let far = peer([3.0, 0.0, 0.0], [0.0; 3]);
    let vc = open(&far);
    // SAFETY: as above.
    unsafe {
        let mut q = [0f32; 6];
        assert_eq!(virtGetArticularPosition(vc, q.as_mut_ptr()), -1);
        assert_eq!(code(), VIRT_E_VARIABLE_NOT_AVAILABLE);
        assert_eq!(virtClose(vc), 0);
    }
}

fn offset(p: &FakePeer, center: [f64; 3]) -> [f64; 3] {
    let s = p.stats();
    std::array::from_fn(|i| s.last_vo_pose[i] - center[i])
}

#[test]
fn impedance_forces_become_coupling_setpoints() {
    let c = [0.45, 0.05, 0.25];
    let p = peer(c, [0.0; 3]);
    let vc = open(&p);
    let k = k_lin();
    // SAFETY: vc is live; the arrays have the sizes the functions need.
    unsafe {
        let f = [3.0f32, 0.0, -1.5, 0.0, 0.0, 0.0];
        // Not in impedance mode: refused.
        assert_eq!(virtSetForce(vc, f.as_ptr()), -1);
        assert_eq!(code(), VIRT_E_WRONG_MODE);
        assert_eq!(virtSetCommandType(vc, COMMAND_TYPE_IMPEDANCE), 0);
        assert_eq!(virtSetPowerOn(vc, 1), 0);
        assert_eq!(virtSetForce(vc, f.as_ptr()), 0);
        std::thread::sleep(Duration::from_millis(50));
        let o = offset(&p, c);
        assert!((o[0] - 3.0 / k).abs() < 1e-6, "{o:?}, k {k}");
        assert!((o[2] + 1.5 / k).abs() < 1e-6, "{o:?}");
        // virtAddForce adds to it.
        let a = [0.0f32, 1.0, 0.0, 0.0, 0.0, 0.0];
        assert_eq!(virtAddForce(vc, a.as_ptr()), 0);
        std::thread::sleep(Duration::from_millis(50));
        let o = offset(&p, c);
        assert!((o[1] - 1.0 / k).abs() < 1e-6, "{o:?}");
        assert!((o[0] - 3.0 / k).abs() < 1e-6, "{o:?}");
        // Saturation: the force sent has norm 1 N at most.
        assert_eq!(virtSaturateTorque(vc, 1.0, 0.1), 0);
        let big = [30.0f32, 40.0, 0.0, 0.0, 0.0, 0.0];
        let zero = [0f32; 6];
        assert_eq!(virtAddForce(vc, zero.as_ptr()), 0);
        assert_eq!(virtSetForce(vc, big.as_ptr()), 0);
        std::thread::sleep(Duration::from_millis(50));
        let o = offset(&p, c);
        let n = (o[0] * o[0] + o[1] * o[1] + o[2] * o[2]).sqrt();
        assert!((n * k - 1.0).abs() < 1e-4, "{o:?}: {} N", n * k);
        assert!((o[0] / o[1] - 0.75).abs() < 1e-3, "direction kept: {o:?}");
        assert_eq!(virtSaturateTorque(vc, 0.0, 1.0), -1);
        assert_eq!(code(), VIRT_E_INCORRECT_VALUE);
        let nan = [f32::NAN, 0.0, 0.0, 0.0, 0.0, 0.0];
        assert_eq!(virtSetForce(vc, nan.as_ptr()), -1);
        assert_eq!(code(), VIRT_E_INCORRECT_VALUE);
        // Force feedback off: the controller uncouples (command type none).
        assert_eq!(virtEnableForceFeedback(vc, 0), 0);
        assert_eq!(p.stats().command_type, Some(0));
        let mut ty = 0;
        assert_eq!(virtGetCommandType(vc, &mut ty), 0);
        assert_eq!(ty, COMMAND_TYPE_IMPEDANCE);
        assert_eq!(virtEnableForceFeedback(vc, 1), 0);
        assert_eq!(p.stats().command_type, Some(1));
        assert_eq!(virtClose(vc), 0);
    }
}

struct Counter {
    vc: *mut c_void,
    calls: AtomicU32,
    errors: AtomicU32,
    sleep_us: u64,
    stop_after: u32,
    /// Set by the call that stopped the loop, once it has.
    stopped: AtomicBool,
}

unsafe extern "C" fn callback(vc: *mut c_void, arg: *mut c_void) {
    // SAFETY: arg is the &Counter the test passed, alive while the loop runs.
    let c = unsafe { &*(arg as *const Counter) };
    assert_eq!(vc, c.vc);
    let mut pos = [0f32; 7];
    let mut speed = [0f32; 6];
    let f = [0.0f32, 0.0, 2.0, 0.0, 0.0, 0.0];
    // SAFETY: vc is live; arrays sized as needed.
    let r = unsafe {
        virtGetPhysicalPosition(vc, pos.as_mut_ptr())
            | virtGetPhysicalSpeed(vc, speed.as_mut_ptr())
            | virtSetForce(vc, f.as_ptr())
    };
    if r != 0 {
        c.errors.fetch_add(1, Ordering::SeqCst);
    }
    let n = c.calls.fetch_add(1, Ordering::SeqCst) + 1;
    if c.sleep_us > 0 {
        std::thread::sleep(Duration::from_micros(c.sleep_us));
    }
    if c.stop_after > 0 && n == c.stop_after {
        // SAFETY: vc is live; closing from the callback is refused,
        // stopping is allowed.
        unsafe {
            assert_eq!(virtClose(vc), -1);
            assert_eq!(virtGetErrorCode(vc), 19); // VIRT_E_CALL_TIME
            assert_eq!(virtStopLoop(vc), 0);
        }
        c.stopped.store(true, Ordering::SeqCst);
    }
}

#[test]
fn periodic_loop_calls_back_streams_and_stops() {
    let c = [0.45, 0.05, 0.25];
    let p = peer(c, [0.0; 3]);
    let vc = open(&p);
    let counter = Counter {
        vc,
        calls: AtomicU32::new(0),
        errors: AtomicU32::new(0),
        sleep_us: 0,
        stop_after: 0,
        stopped: AtomicBool::new(false),
    };
    let period = 0.002f32;
    // SAFETY: vc is live; counter outlives the loop (stopped below).
    unsafe {
        assert_eq!(virtStartLoop(vc), -1);
        assert_eq!(code(), VIRT_E_PERIODIC_FUNCTION);
        assert_eq!(virtSetCommandType(vc, COMMAND_TYPE_IMPEDANCE), 0);
        let tiny = 1e-6f32;
        let arg = &counter as *const Counter as *mut c_void;
        assert_eq!(virtSetPeriodicFunction(vc, Some(callback), &tiny, arg), -1);
        assert_eq!(code(), VIRT_E_INCORRECT_VALUE);
        assert_eq!(virtSetPeriodicFunction(vc, None, &period, arg), -1);
        let arg = &counter as *const Counter as *mut c_void;
        assert_eq!(virtSetPeriodicFunction(vc, Some(callback), &period, arg), 0);
        let before = p.stats().frames.get("vpr_stream").copied().unwrap_or(0);
        assert_eq!(virtStartLoop(vc), 0);
        assert_eq!(virtStartLoop(vc), -1);
        assert_eq!(code(), VIRT_E_ALREADY_CALLED);
        std::thread::sleep(Duration::from_millis(300));
        assert_eq!(virtStopLoop(vc), 0);
        let calls = counter.calls.load(Ordering::SeqCst);
        assert!(calls >= 10, "{calls} calls in 300 ms at 2 ms");
        assert_eq!(counter.errors.load(Ordering::SeqCst), 0);
        // Once stopped, no more calls.
        std::thread::sleep(Duration::from_millis(50));
        assert_eq!(counter.calls.load(Ordering::SeqCst), calls);
        assert_eq!(virtStopLoop(vc), -1);
        // One set-point per call, carrying the callback's force.
        let sent = p.stats().frames.get("vpr_stream").copied().unwrap_or(0) - before;
        assert!(sent >= calls as u64, "{sent} frames for {calls} calls");
        let o = offset(&p, c);
        assert!((o[2] - 2.0 / k_lin()).abs() < 1e-6, "{o:?}");
        assert_eq!(virtClose(vc), 0);
    }
}

/// Run the loop at `period` for `ms` milliseconds; (calls, answers sent by
/// the controller meanwhile).
fn loop_for(p: &FakePeer, vc: *mut c_void, period: f32, ms: u64) -> (u32, u64) {
    let counter = Counter {
        vc,
        calls: AtomicU32::new(0),
        errors: AtomicU32::new(0),
        sleep_us: 0,
        stop_after: 0,
        stopped: AtomicBool::new(false),
    };
    let arg = &counter as *const Counter as *mut c_void;
    // SAFETY: vc is live; counter outlives the loop (stopped below).
    unsafe {
        assert_eq!(virtSetPeriodicFunction(vc, Some(callback), &period, arg), 0);
        let a0 = p.stats().answers_sent;
        assert_eq!(virtStartLoop(vc), 0);
        std::thread::sleep(Duration::from_millis(ms));
        assert_eq!(virtStopLoop(vc), 0);
        let answers = p.stats().answers_sent - a0;
        assert_eq!(counter.errors.load(Ordering::SeqCst), 0);
        (counter.calls.load(Ordering::SeqCst), answers)
    }
}

#[test]
fn the_periodic_loop_follows_the_controllers_answers() {
    // A controller with a 4 ms servo period; the application asks for 1 ms.
    let mut p = FakePeer::start(FakePeerConfig {
        center: [0.45, 0.05, 0.25],
        amplitude: [0.0; 3],
        answer_every_period: true,
        period_us: 4000,
        twist_every: 4,
        ..Default::default()
    })
    .unwrap();
    let vc = open(&p);
    // SAFETY: vc is live.
    unsafe { assert_eq!(virtSetCommandType(vc, COMMAND_TYPE_IMPEDANCE), 0) };
    // At most one call (and one set-point) per answer, not one per host
    // millisecond: ~100 answers in 400 ms.
    let v0 = p.stats().frames.get("vpr_stream").copied().unwrap_or(0);
    let (calls, answers) = loop_for(&p, vc, 0.001, 400);
    let sent = p.stats().frames.get("vpr_stream").copied().unwrap_or(0) - v0;
    assert!(calls >= 20, "{calls} calls for {answers} answers");
    assert!(
        calls as u64 <= answers,
        "{calls} calls for {answers} answers"
    );
    assert!(
        sent <= answers + 1,
        "{sent} set-points for {answers} answers"
    );
    // A period of two servo cycles: every other answer.
    let (calls, answers) = loop_for(&p, vc, 0.008, 400);
    assert!(calls >= 10, "{calls} calls for {answers} answers");
    assert!(
        2 * calls as u64 <= answers + 2,
        "{calls} calls for {answers} answers"
    );
    // No answers (the controller is gone): no calls.
    let counter = Counter {
        vc,
        calls: AtomicU32::new(0),
        errors: AtomicU32::new(0),
        sleep_us: 0,
        stop_after: 0,
        stopped: AtomicBool::new(false),
    };
    let period = 0.004f32;
    let arg = &counter as *const Counter as *mut c_void;
    // SAFETY: vc is live; counter outlives the loop.
    unsafe {
        assert_eq!(virtSetPeriodicFunction(vc, Some(callback), &period, arg), 0);
        assert_eq!(virtStartLoop(vc), 0);
        std::thread::sleep(Duration::from_millis(100));
        p.stop();
        std::thread::sleep(Duration::from_millis(20));
        let before = counter.calls.load(Ordering::SeqCst);
        assert!(before >= 5, "{before} calls");
        std::thread::sleep(Duration::from_millis(200));
        assert_eq!(counter.calls.load(Ordering::SeqCst), before);
        assert_eq!(virtStopLoop(vc), 0);
        let _ = virtClose(vc);
    }
}

#[test]
fn the_loop_runs_while_another_thread_waits_for_a_button() {
    let mut p = peer([0.45, 0.05, 0.25], [0.0; 3]);
    let vc = open(&p);
    let counter = Counter {
        vc,
        calls: AtomicU32::new(0),
        errors: AtomicU32::new(0),
        sleep_us: 0,
        stop_after: 0,
        stopped: AtomicBool::new(false),
    };
    let period = 0.001f32;
    let addr = vc as usize;
    // SAFETY: vc is live until virtClose below, after the waiting thread
    // and the loop have ended; counter outlives the loop.
    unsafe {
        assert_eq!(virtSetCommandType(vc, COMMAND_TYPE_IMPEDANCE), 0);
        assert_eq!(virtSetTimeoutValue(vc, 0.3), 0);
        let arg = &counter as *const Counter as *mut c_void;
        assert_eq!(virtSetPeriodicFunction(vc, Some(callback), &period, arg), 0);
        assert_eq!(virtStartLoop(vc), 0);
        // No button is pressed: the waiting thread blocks while the
        // controller answers.
        // (The context outlives this thread: joined below.)
        let waiter = std::thread::spawn(move || {
            let r = virtWaitPressButton(addr as *mut c_void, 0);
            // The thread's own code: the callback loop makes calls on the
            // context meanwhile (the context's code is its last call's).
            (r, code())
        });
        std::thread::sleep(Duration::from_millis(100));
        let (c0, a0) = (counter.calls.load(Ordering::SeqCst), p.stats().answers_sent);
        std::thread::sleep(Duration::from_millis(300));
        let (c1, a1) = (counter.calls.load(Ordering::SeqCst), p.stats().answers_sent);
        assert!(!waiter.is_finished(), "returned without a press");
        // The loop kept its pace: a call for (nearly) every answer.
        let (calls, answers) = (u64::from(c1 - c0), a1 - a0);
        assert!(answers >= 50, "{answers} answers");
        assert!(2 * calls >= answers, "{calls} calls for {answers} answers");
        // The controller goes silent: the wait ends with a time-out.
        p.stop();
        let (r, code) = waiter.join().unwrap();
        assert_eq!((r, code), (-1, VIRT_E_TIME_OUT));
        assert_eq!(virtStopLoop(vc), 0);
        assert_eq!(counter.errors.load(Ordering::SeqCst), 0);
        let _ = virtClose(vc);
    }
}

#[test]
fn simulation_stiffness_and_damping_are_the_controllers_coupling() {
    let p = peer([0.45, 0.05, 0.25], [0.0; 3]);
    let vc = open(&p);
    let g = Gains::for_period(Fx::from_ratio(1000, 1_000_000));
    let (k, b) = (g.k_lin.to_f64(), g.b_lin.to_f64());
    let close = |a: f32, e: f64| ((a as f64) - e).abs() <= 1e-4 * e.abs().max(1.0);
    let (mut ks, mut bs) = (0f32, 0f32);
    // SAFETY: vc is live; the outputs are writable.
    unsafe {
        assert_eq!(virtGetSimulationStiffness(vc, &mut ks), 0);
        assert_eq!(virtGetSimulationDamping(vc, &mut bs), 0);
        assert!(close(ks, k) && close(bs, b), "{ks} {bs} vs {k} {b}");
        assert_eq!(virtGetSimulationStiffness(vc, std::ptr::null_mut()), -1);
        // Client units: force × 0.5, displacement × 2.
        assert_eq!(virtSetForceFactor(vc, 0.5), 0);
        assert_eq!(virtSetSpeedFactor(vc, 2.0), 0);
        assert_eq!(virtGetSimulationStiffness(vc, &mut ks), 0);
        assert_eq!(virtGetSimulationDamping(vc, &mut bs), 0);
        assert!(close(ks, k * 0.25) && close(bs, b * 0.25), "{ks} {bs}");
        // VIRTMECH with a light object and a long time step: the controller
        // caps the stiffness at m / ts² (0.01 kg / (0.01 s)² = 100 N/m).
        assert_eq!(virtSetForceFactor(vc, 1.0), 0);
        assert_eq!(virtSetSpeedFactor(vc, 1.0), 0);
        assert_eq!(virtSetTimeStep(vc, 0.01), 0);
        assert_eq!(virtSetCommandType(vc, COMMAND_TYPE_VIRTMECH), 0);
        let inertia = [1e-4f32; 3];
        assert_eq!(virtAttachVO(vc, 0.01, inertia.as_ptr()), 0);
        assert!(k > 100.0);
        assert_eq!(virtGetSimulationStiffness(vc, &mut ks), 0);
        assert!(close(ks, 100.0), "{ks}");
        assert_eq!(virtGetSimulationDamping(vc, &mut bs), 0);
        assert!(close(bs, b), "{bs}");
        // The cap is VIRTMECH's: in IMPEDANCE the full stiffness.
        assert_eq!(virtSetCommandType(vc, COMMAND_TYPE_IMPEDANCE), 0);
        assert_eq!(virtGetSimulationStiffness(vc, &mut ks), 0);
        assert!(close(ks, k), "{ks}");
        assert_eq!(virtClose(vc), 0);
    }
}

#[test]
fn a_request_round_trip_does_not_stall_the_loop() {
    // A controller that never acknowledges a power request: the request
    // waits for its retries while the loop runs on.
    let p = FakePeer::start(FakePeerConfig {
        center: [0.45, 0.05, 0.25],
        amplitude: [0.0; 3],
        answer_every_period: true,
        twist_every: 4,
        ignore_power_requests: true,
        ..Default::default()
    })
    .unwrap();
    let vc = open(&p);
    let counter = Counter {
        vc,
        calls: AtomicU32::new(0),
        errors: AtomicU32::new(0),
        sleep_us: 0,
        stop_after: 0,
        stopped: AtomicBool::new(false),
    };
    let period = 0.001f32;
    let addr = vc as usize;
    // SAFETY: vc is live until virtClose below, after the requesting thread
    // and the loop have ended; counter outlives the loop.
    unsafe {
        assert_eq!(virtSetCommandType(vc, COMMAND_TYPE_IMPEDANCE), 0);
        // 4 attempts of 0.15 s.
        assert_eq!(virtSetTimeoutValue(vc, 0.6), 0);
        let arg = &counter as *const Counter as *mut c_void;
        assert_eq!(virtSetPeriodicFunction(vc, Some(callback), &period, arg), 0);
        assert_eq!(virtStartLoop(vc), 0);
        std::thread::sleep(Duration::from_millis(50));
        // (The context outlives this thread: joined below.)
        let requester = std::thread::spawn(move || {
            let r = virtSetPowerOn(addr as *mut c_void, 1);
            // The thread's own code: the callback loop makes calls on the
            // context meanwhile (the context's code is its last call's).
            (r, code())
        });
        std::thread::sleep(Duration::from_millis(100));
        let (c0, a0) = (counter.calls.load(Ordering::SeqCst), p.stats().answers_sent);
        std::thread::sleep(Duration::from_millis(300));
        let (c1, a1) = (counter.calls.load(Ordering::SeqCst), p.stats().answers_sent);
        assert!(!requester.is_finished(), "the request ended early");
        let (calls, answers) = (u64::from(c1 - c0), a1 - a0);
        assert!(answers >= 50, "{answers} answers");
        assert!(2 * calls >= answers, "{calls} calls for {answers} answers");
        let (r, code) = requester.join().unwrap();
        assert_eq!((r, code), (-1, VIRT_E_TIME_OUT));
        assert_eq!(virtStopLoop(vc), 0);
        assert_eq!(counter.errors.load(Ordering::SeqCst), 0);
        assert_eq!(virtClose(vc), 0);
    }
}

#[test]
fn a_callback_that_overruns_raises_the_alarm() {
    let p = peer([0.45, 0.05, 0.25], [0.0; 3]);
    let vc = open(&p);
    // A callback that takes 20 periods, stopping itself after 10 calls (an
    // overrun is measured on the controller's clock: the fake must have
    // answered past the next call's cycle meanwhile, which a loaded host
    // could delay for a few ms, not for 20).
    let counter = Counter {
        vc,
        calls: AtomicU32::new(0),
        errors: AtomicU32::new(0),
        sleep_us: 20_000,
        stop_after: 10,
        stopped: AtomicBool::new(false),
    };
    let period = 0.001f32;
    // SAFETY: vc is live; counter outlives the loop.
    unsafe {
        assert_eq!(virtSetCommandType(vc, COMMAND_TYPE_IMPEDANCE), 0);
        let arg = &counter as *const Counter as *mut c_void;
        assert_eq!(virtSetPeriodicFunction(vc, Some(callback), &period, arg), 0);
        let mut a: c_uint = 0;
        assert_eq!(virtGetAlarm(vc, &mut a), 0);
        assert_eq!(a & VIRT_ALARM_CALLBACK_OVERRUN, 0);
        assert_eq!(virtStartLoop(vc), 0);
        // Until the 10th call has stopped the loop (it sleeps 20 ms first).
        for _ in 0..500 {
            if counter.stopped.load(Ordering::SeqCst) {
                break;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        assert!(counter.stopped.load(Ordering::SeqCst), "stopped itself");
        std::thread::sleep(Duration::from_millis(20));
        assert_eq!(
            counter.calls.load(Ordering::SeqCst),
            10,
            "no call after the stop"
        );
        let mut n: c_uint = 0;
        assert_eq!(virtGetCallbackOverruns(vc, &mut n), 0);
        assert!(n >= 9, "{n} overruns");
        assert_eq!(virtGetAlarm(vc, &mut a), 0);
        assert_ne!(a & VIRT_ALARM_CALLBACK_OVERRUN, 0, "{a:#x}");
        // Latched until read.
        assert_eq!(virtGetAlarm(vc, &mut a), 0);
        assert_eq!(a & VIRT_ALARM_CALLBACK_OVERRUN, 0, "{a:#x}");
        assert_eq!(virtClose(vc), 0);
    }
}

#[test]
fn close_stops_a_running_loop() {
    let p = peer([0.45, 0.05, 0.25], [0.0; 3]);
    let vc = open(&p);
    let counter = Box::new(Counter {
        vc,
        calls: AtomicU32::new(0),
        errors: AtomicU32::new(0),
        sleep_us: 0,
        stop_after: 0,
        stopped: AtomicBool::new(false),
    });
    let period = 0.001f32;
    // SAFETY: vc is live; counter outlives the loop (virtClose joins it).
    unsafe {
        assert_eq!(virtSetCommandType(vc, COMMAND_TYPE_IMPEDANCE), 0);
        let arg = &*counter as *const Counter as *mut c_void;
        assert_eq!(virtSetPeriodicFunction(vc, Some(callback), &period, arg), 0);
        assert_eq!(virtStartLoop(vc), 0);
        std::thread::sleep(Duration::from_millis(50));
        assert_eq!(virtClose(vc), 0);
    }
    let calls = counter.calls.load(Ordering::SeqCst);
    assert!(calls > 0);
    std::thread::sleep(Duration::from_millis(30));
    assert_eq!(counter.calls.load(Ordering::SeqCst), calls);
    assert_eq!(p.stats().frames.get("close_session"), Some(&1));
}

/// What the callback of `close_from_another_thread_waits_for_the_running_callback` saw.
struct Racer {
    calls: AtomicU32,
    entered: AtomicBool,
    close_result: std::sync::atomic::AtomicI32,
    close_code: std::sync::atomic::AtomicI32,
    read_result: std::sync::atomic::AtomicI32,
}

unsafe extern "C" fn close_racer(vc: *mut c_void, arg: *mut c_void) {
    // SAFETY: arg is the &Racer the test passed, alive until virtClose
    // returned (it joins this loop).
    let r = unsafe { &*(arg as *const Racer) };
    if r.calls.fetch_add(1, Ordering::SeqCst) > 0 {
        return;
    }
    r.entered.store(true, Ordering::SeqCst);
    // The other thread's virtClose starts meanwhile and waits for this call.
    std::thread::sleep(Duration::from_millis(100));
    let mut pos = [0f32; 7];
    // SAFETY: vc is live until this call returns (virtClose joins first).
    unsafe {
        r.close_result.store(virtClose(vc), Ordering::SeqCst);
        r.close_code.store(virtGetErrorCode(vc), Ordering::SeqCst);
        r.read_result.store(
            virtGetPhysicalPosition(vc, pos.as_mut_ptr()),
            Ordering::SeqCst,
        );
    }
}

#[test]
fn close_from_another_thread_waits_for_the_running_callback() {
    // A callback still running when another thread closes the context may
    // use it until it returns (virtClose joins it first, without holding a
    // lock the API takes), and its own virtClose is refused rather than
    // freeing the context twice.
    let p = peer([0.45, 0.05, 0.25], [0.0; 3]);
    let vc = open(&p);
    let racer = Box::new(Racer {
        calls: AtomicU32::new(0),
        entered: AtomicBool::new(false),
        close_result: std::sync::atomic::AtomicI32::new(1),
        close_code: std::sync::atomic::AtomicI32::new(0),
        read_result: std::sync::atomic::AtomicI32::new(1),
    });
    let period = 0.001f32;
    // SAFETY: vc is live; racer outlives the loop (virtClose joins it).
    unsafe {
        assert_eq!(virtSetCommandType(vc, COMMAND_TYPE_IMPEDANCE), 0);
        let arg = &*racer as *const Racer as *mut c_void;
        assert_eq!(
            virtSetPeriodicFunction(vc, Some(close_racer), &period, arg),
            0
        );
        assert_eq!(virtStartLoop(vc), 0);
    }
    for _ in 0..500 {
        if racer.entered.load(Ordering::SeqCst) {
            break;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    assert!(racer.entered.load(Ordering::SeqCst), "the callback ran");
    let (tx, rx) = std::sync::mpsc::channel();
    let addr = vc as usize;
    std::thread::spawn(move || {
        // SAFETY: vc is live; this is the one virtClose of the test thread.
        let r = unsafe { virtClose(addr as *mut c_void) };
        let _ = tx.send(r);
    });
    let closed = rx
        .recv_timeout(Duration::from_secs(10))
        .expect("virtClose returned (no deadlock with the running callback)");
    assert_eq!(closed, 0);
    assert_eq!(racer.close_result.load(Ordering::SeqCst), -1);
    assert_eq!(racer.close_code.load(Ordering::SeqCst), 19); // VIRT_E_CALL_TIME
    assert_eq!(racer.read_result.load(Ordering::SeqCst), 0);
    assert_eq!(
        racer.calls.load(Ordering::SeqCst),
        1,
        "no call after the close"
    );
    assert_eq!(p.stats().frames.get("close_session"), Some(&1));
}

#[test]
fn trajectory_recording_writes_the_handle_poses() {
    let p = peer([0.45, 0.05, 0.25], [0.05, 0.0, 0.0]);
    let vc = open(&p);
    let path = std::env::temp_dir().join(format!("virt_traj_{}.txt", std::process::id()));
    let name = CString::new(path.to_str().unwrap()).unwrap();
    // SAFETY: vc is live; name is NUL-terminated.
    unsafe {
        assert_eq!(virtTrajRecordStart(vc), -1);
        assert_eq!(code(), VIRT_E_FILE_NOT_FOUND);
        assert_eq!(virtSetOutputFile(vc, name.as_ptr() as *mut _), 0);
        let mut max_s: c_uint = 0;
        assert_eq!(virtTrajSetSamplingTimeStep(vc, 0.005, &mut max_s), 0);
        assert_eq!(max_s, 5000);
        assert_eq!(virtTrajRecordStart(vc), 0);
        assert_eq!(virtTrajRecordStart(vc), -1);
        assert_eq!(code(), VIRT_E_ALREADY_CALLED);
        std::thread::sleep(Duration::from_millis(200));
        assert_eq!(virtTrajRecordStop(vc), 0);
        assert_eq!(virtTrajRecordStop(vc), -1);
        assert_eq!(virtClose(vc), 0);
    }
    let text = std::fs::read_to_string(&path).unwrap();
    let _ = std::fs::remove_file(&path);
    let rows: Vec<Vec<f64>> = text
        .lines()
        .map(|l| l.split_whitespace().map(|v| v.parse().unwrap()).collect())
        .collect();
    assert!(rows.len() >= 5, "{} samples", rows.len());
    for (i, r) in rows.iter().enumerate() {
        assert_eq!(r.len(), 9, "{r:?}");
        assert!((r[1] - 0.45).abs() <= 0.05 + 1e-6 && (r[2] - 0.05).abs() < 1e-6);
        // Controller time: the cycles since the first sample × 1 ms.
        assert!(
            (r[0] - (r[8] - rows[0][8]) * 0.001).abs() < 1e-6,
            "{:?} {r:?}",
            rows[0]
        );
        if i > 0 {
            // One sample per grid point of 5 cycles reached, the grid
            // starting at the first sample: never two in one interval.
            let prev = &rows[i - 1];
            let (k_prev, k) = ((prev[8] - rows[0][8]) / 5.0, (r[8] - rows[0][8]) / 5.0);
            assert!(k.floor() > k_prev.floor(), "{prev:?} {r:?}");
        }
    }
    // The handle moves: the samples differ.
    assert!(rows.iter().any(|r| (r[1] - rows[0][1]).abs() > 1e-5));
}

#[test]
fn status_reads_and_what_is_not_implemented() {
    let p = peer([0.45, 0.05, 0.25], [0.0; 3]);
    let vc = open(&p);
    // SAFETY: vc is live; pointers valid.
    unsafe {
        let (mut dm, mut es, mut pw) = (0, 0, 0);
        assert_eq!(virtSetPowerOn(vc, 1), 0);
        std::thread::sleep(Duration::from_millis(20));
        assert_eq!(virtGetPowerOn(vc, &mut pw), 0);
        assert_eq!(pw, 1);
        assert_eq!(virtGetDeadMan(vc, &mut dm), 0);
        assert_eq!(dm, 1);
        // VirtuoseAPI's meaning: 1 = operational (emergency stop released).
        assert_eq!(virtGetEmergencyStop(vc, &mut es), 0);
        assert_eq!(es, 1);
        for n in [-1, 0, 1, 2, 3, 5, 1000] {
            let mut b = 7;
            assert_eq!(virtGetButton(vc, n, &mut b), 0, "button {n}");
            assert_eq!(b, 0, "button {n}");
        }
        assert_eq!(virtWaitPressButton(vc, 3), -1);
        assert_eq!(code(), VIRT_E_INCORRECT_VALUE);
        let mut fail: c_uint = 9;
        assert_eq!(virtGetFailure(vc, &mut fail), 0);
        assert_eq!(fail, 0);
        let mut t: c_uint = 0;
        assert_eq!(virtGetTimeLastUpdate(vc, &mut t), 0);
        assert!(t > 0);
        let mut x = [0f32; 7];
        assert_eq!(virtSetArticularPosition(vc, x.as_ptr()), -1);
        assert_eq!(code(), VIRT_E_NOT_IMPLEMENTED);
        assert_eq!(virtVmSetType(vc, 1), -1);
        assert_eq!(code(), VIRT_E_NOT_IMPLEMENTED);
        assert_eq!(virtGetCatchFrame(vc, x.as_mut_ptr()), -1);
        assert_eq!(code(), VIRT_E_NOT_IMPLEMENTED);
        assert_eq!(virtSetPwmOutput(vc, x.as_ptr()), -1);
        assert_eq!(code(), VIRT_E_NOT_IMPLEMENTED);
        assert_eq!(virtClose(vc), 0);
    }
}

#[test]
fn reads_before_the_first_answer_wait_then_time_out() {
    // A controller that grants the session but never answers.
    let p = FakePeer::start(FakePeerConfig::default()).unwrap();
    let vc = open(&p);
    // SAFETY: vc is live.
    unsafe {
        assert_eq!(virtSetTimeoutValue(vc, 0.2), 0);
        let mut pos = [0f32; 7];
        let t = std::time::Instant::now();
        assert_eq!(virtGetPosition(vc, pos.as_mut_ptr()), -1);
        assert_eq!(code(), VIRT_E_TIME_OUT);
        assert!(t.elapsed() >= Duration::from_millis(200));
        assert_eq!(virtClose(vc), 0);
    }
}

#[test]
fn buttons_emergency_stop_and_failures_from_the_answers() {
    use hap_core::vp::{alarm, status};
    let p = FakePeer::start(FakePeerConfig {
        center: [0.45, 0.05, 0.25],
        amplitude: [0.0; 3],
        answer_every_period: true,
        extra_status: status::BUTTON_2 | status::EMERGENCY_STOP,
        alarms: alarm::FAIL_SAFE | alarm::TORQUE_SATURATED,
        ..Default::default()
    })
    .unwrap();
    let vc = open(&p);
    // SAFETY: vc is live; pointers valid.
    unsafe {
        // The second button (hapticctrl's BUTTON_2) is pressed: Haption's
        // button 2; 1 (and 0) are the first.
        let (mut b0, mut b1, mut b2, mut b3, mut es) = (7, 7, 7, 7, 7);
        assert_eq!(virtGetButton(vc, 0, &mut b0), 0);
        assert_eq!(virtGetButton(vc, 1, &mut b1), 0);
        assert_eq!(virtGetButton(vc, 2, &mut b2), 0);
        assert_eq!(virtGetButton(vc, 3, &mut b3), 0);
        assert_eq!((b0, b1, b2, b3), (0, 0, 1, 0));
        let mut shift = 7;
        assert_eq!(virtIsInShiftPosition(vc, &mut shift), 0);
        assert_eq!(shift, 0);
        // Button 2 is pressed: returns at once.
        assert_eq!(virtWaitPressButton(vc, 2), 0);
        assert_eq!(virtGetEmergencyStop(vc, &mut es), 0);
        assert_eq!(es, 0, "pressed: not operational");
        let (mut fail, mut a): (c_uint, c_uint) = (0, 0);
        assert_eq!(virtGetFailure(vc, &mut fail), 0);
        assert_eq!(fail, 0x3f);
        assert_eq!(virtGetAlarm(vc, &mut a), 0);
        assert_ne!(a & VIRT_ALARM_SATURATE, 0, "{a:#x}");
        assert_ne!(a & alarm::FAIL_SAFE, 0, "{a:#x}");
        assert_eq!(virtClose(vc), 0);
    }
    // A controller that stops answering: the wait fails instead of hanging.
    let silent = FakePeer::start(FakePeerConfig::default()).unwrap();
    let vc = open(&silent);
    // SAFETY: vc is live.
    unsafe {
        assert_eq!(virtSetTimeoutValue(vc, 0.2), 0);
        assert_eq!(virtWaitPressButton(vc, 0), -1);
        assert_eq!(code(), VIRT_E_TIME_OUT);
        assert_eq!(virtClose(vc), 0);
    }
}

#[test]
fn power_reads_what_was_set_while_the_answers_lag() {
    // Answers report the old power state for 300 answers (0.3 s) after the
    // request was applied and acknowledged.
    let p = FakePeer::start(FakePeerConfig {
        center: [0.45, 0.05, 0.25],
        amplitude: [0.0; 3],
        answer_every_period: true,
        power_lag_answers: 300,
        ..Default::default()
    })
    .unwrap();
    let vc = open(&p);
    // SAFETY: vc is live; pointers valid.
    unsafe {
        let mut pw = 7;
        assert_eq!(virtGetPowerOn(vc, &mut pw), 0);
        assert_eq!(pw, 0);
        assert_eq!(virtSetPowerOn(vc, 1), 0);
        for _ in 0..20 {
            assert_eq!(virtGetPowerOn(vc, &mut pw), 0);
            assert_eq!(pw, 1, "right after virtSetPowerOn(1)");
            std::thread::sleep(Duration::from_millis(5));
        }
        assert_eq!(virtSetPowerOn(vc, 0), 0);
        assert_eq!(virtGetPowerOn(vc, &mut pw), 0);
        assert_eq!(pw, 0, "right after virtSetPowerOn(0)");
        assert_eq!(virtClose(vc), 0);
    }
}

#[test]
fn the_rust_api_reads_its_power_writes_and_falls_back_to_the_answers() {
    use hap_core::vp::status;
    use virtuose_api::{Options, VirtContext};
    // A controller whose answers never show the power coming on (within
    // this test): the value set, then, after the time a request may take,
    // the answers' bit.
    let p = FakePeer::start(FakePeerConfig {
        answer_every_period: true,
        power_lag_answers: 1_000_000,
        ..Default::default()
    })
    .unwrap();
    let opts = Options {
        reply_timeout: Duration::from_millis(60),
        attempts: 2,
        ..Default::default()
    };
    let mut vc = VirtContext::open_with(&p.address(), opts).unwrap();
    assert!(vc.wait_answer(Duration::from_secs(1)));
    vc.set_power_on(true).unwrap();
    assert!(p.stats().powered, "the fake applied it");
    assert_eq!(
        vc.get_status().unwrap() & status::POWER_ON,
        0,
        "answers lag"
    );
    assert!(vc.get_power_on().unwrap());
    std::thread::sleep(Duration::from_millis(200));
    assert!(
        !vc.get_power_on().unwrap(),
        "not confirmed: the answers' bit"
    );
    vc.close().unwrap();
}

#[test]
fn the_error_code_is_per_context() {
    let (p1, p2) = (
        peer([0.45, 0.05, 0.25], [0.0; 3]),
        peer([0.45, 0.05, 0.25], [0.0; 3]),
    );
    let (vc1, vc2) = (open(&p1), open(&p2));
    // SAFETY: both contexts are live until closed below.
    unsafe {
        assert_eq!(virtSetTimeStep(vc1, -1.0), -1);
        assert_eq!(virtSetTimeStep(vc2, 0.002), 0);
        assert_eq!(virtGetErrorCode(vc1), VIRT_E_INCORRECT_VALUE);
        assert_eq!(virtGetErrorCode(vc2), 0);
        let mut e = -1;
        assert_eq!(virtGetError(vc1, &mut e), 0);
        assert_eq!(e, VIRT_E_INCORRECT_VALUE);
        // From another thread: the context's code, not that thread's.
        let a = vc1 as usize;
        let other = std::thread::spawn(move || virtGetErrorCode(a as *mut c_void));
        assert_eq!(other.join().unwrap(), VIRT_E_INCORRECT_VALUE);
        // A not-implemented call sets the context's code too; a success clears it.
        assert_eq!(virtVmActivate(vc2), -1);
        assert_eq!(virtGetErrorCode(vc2), VIRT_E_NOT_IMPLEMENTED);
        assert_eq!(virtSetTimeStep(vc1, 0.002), 0);
        assert_eq!(virtGetErrorCode(vc1), 0);
        assert_eq!(virtClose(vc1), 0);
        assert_eq!(virtClose(vc2), 0);
    }
}

#[test]
fn a_quasi_static_object_couples_the_handle_to_its_pose() {
    let center = [0.45, 0.05, 0.25];
    let p = peer(center, [0.0; 3]);
    let vc = open(&p);
    let k = k_lin() as f32;
    // SAFETY: vc is live; arrays of the sizes the functions need.
    unsafe {
        assert_eq!(virtSetCommandType(vc, COMMAND_TYPE_VIRTMECH), 0);
        // Rotations: 0 (the orientation is free); translations: a quarter
        // of the controller's stiffness on x, twice it on y (capped), 0 on z.
        let ks = [0.0f32, 0.0, 0.0, k / 4.0, 2.0 * k, 0.0];
        let bs = [0.0f32; 6];
        assert_eq!(virtAttachQSVO(vc, ks.as_ptr(), bs.as_ptr()), 0);
        assert!(p.stats().attached);
        assert_eq!(virtSetPowerOn(vc, 1), 0);
        let mut handle = [0f32; 7];
        assert_eq!(virtGetAvatarPosition(vc, handle.as_mut_ptr()), 0);
        let target = [
            handle[0] + 0.04,
            handle[1] + 0.02,
            handle[2] + 0.03,
            0.0,
            0.0,
            0.0,
            1.0,
        ];
        assert_eq!(virtSetPosition(vc, target.as_ptr()), 0);
        std::thread::sleep(Duration::from_millis(30));
        let sp = p.stats().last_vo_pose;
        assert!((sp[0] - (center[0] + 0.01)).abs() < 1e-4, "{sp:?}");
        assert!((sp[1] - (center[1] + 0.02)).abs() < 1e-4, "{sp:?}");
        assert!((sp[2] - center[2]).abs() < 1e-4, "{sp:?}");
        // The object's pose vs the handle's.
        let (mut pos, mut avatar) = ([0f32; 7], [0f32; 7]);
        assert_eq!(virtGetPosition(vc, pos.as_mut_ptr()), 0);
        assert_eq!(virtGetAvatarPosition(vc, avatar.as_mut_ptr()), 0);
        assert_eq!(pos, target);
        assert!((avatar[0] as f64 - center[0]).abs() < 1e-6, "{avatar:?}");
        // Stiffness: the mean of the translational ones, each capped.
        let mut st = 0f32;
        assert_eq!(virtGetSimulationStiffness(vc, &mut st), 0);
        let want = (k / 4.0 + k + 0.0) / 3.0;
        assert!((st - want).abs() < 1e-3 * k, "{st} vs {want}");
        // The coupling wrench on the object: towards the handle.
        let mut f = [0f32; 6];
        assert_eq!(virtGetForce(vc, f.as_mut_ptr()), 0);
        assert!(f[0] < 0.0, "{f:?}");
        // Bad gains are refused.
        let bad = [-1.0f32; 6];
        assert_eq!(virtAttachQSVO(vc, bad.as_ptr(), bs.as_ptr()), -1);
        assert_eq!(virtGetErrorCode(vc), VIRT_E_INCORRECT_VALUE);
        // Detached: virtGetPosition is the handle again.
        assert_eq!(virtDetachVO(vc), 0);
        assert_eq!(virtGetPosition(vc, pos.as_mut_ptr()), 0);
        assert!((pos[0] as f64 - center[0]).abs() < 1e-6, "{pos:?}");
        assert_eq!(virtClose(vc), 0);
    }
}

#[test]
fn a_forced_shift_holds_the_avatar_and_keeps_the_offset() {
    // The handle moves 5 cm along x at 2 Hz.
    let p = FakePeer::start(FakePeerConfig {
        center: [0.45, 0.05, 0.25],
        amplitude: [0.05, 0.0, 0.0],
        freq_hz: 2.0,
        answer_every_period: true,
        twist_every: 4,
        ..Default::default()
    })
    .unwrap();
    let vc = open(&p);
    let avatar = |vc| {
        let mut a = [0f32; 7];
        // SAFETY: vc is live.
        assert_eq!(unsafe { virtGetAvatarPosition(vc, a.as_mut_ptr()) }, 0);
        a
    };
    // SAFETY: vc is live; pointers valid.
    unsafe {
        assert_eq!(virtSetIndexingMode(vc, 0), 0); // INDEXING_ALL
        assert_eq!(virtSetCommandType(vc, COMMAND_TYPE_VIRTMECH), 0);
        let mut shift = 7;
        assert_eq!(virtIsInShiftPosition(vc, &mut shift), 0);
        assert_eq!(shift, 0);
        assert_eq!(virtForceShiftButton(vc, 1), 0);
        assert_eq!(p.stats().command_type, Some(0), "uncoupled while shifting");
        assert_eq!(virtIsInShiftPosition(vc, &mut shift), 0);
        assert_eq!(shift, 1);
        let held = avatar(vc);
        std::thread::sleep(Duration::from_millis(80));
        assert_eq!(avatar(vc), held, "the avatar stays while shifting");
        let moved = p.stats().last_handle_position;
        assert!(
            (moved[0] - held[0] as f64).abs() > 0.005,
            "{moved:?} {held:?}"
        );
        assert_eq!(virtForceShiftButton(vc, 0), 0);
        assert_eq!(p.stats().command_type, Some(2), "VIRTMECH again");
        assert_eq!(virtIsInShiftPosition(vc, &mut shift), 0);
        assert_eq!(shift, 0);
        // The avatar moves on from where it stayed: avatar − handle is the
        // offset gathered while shifting.
        let after = avatar(vc);
        assert!((after[0] - held[0]).abs() < 0.003, "{after:?} {held:?}");
        std::thread::sleep(Duration::from_millis(50));
        let a = avatar(vc);
        let h = p.stats().last_handle_position;
        let off = a[0] as f64 - h[0];
        assert!((off - (held[0] as f64 - moved[0])).abs() < 0.01, "{off}");
        // Poses the application sends get the offset taken off.
        assert_eq!(virtSetPosition(vc, a.as_ptr()), 0);
        std::thread::sleep(Duration::from_millis(20));
        let sent = p.stats().last_vo_pose;
        assert!((sent[0] - (a[0] as f64 - off)).abs() < 1e-3, "{sent:?}");
        assert_eq!(virtClose(vc), 0);
    }
}

#[test]
fn observation_frame_speed_and_frames_read_back_as_set() {
    let p = peer([0.45, 0.05, 0.25], [0.0; 3]);
    let vc = open(&p);
    // SAFETY: vc is live; arrays of the sizes the functions need.
    unsafe {
        let v = [0.1f32, 0.0, 0.0, 0.0, 0.0, 0.2];
        assert_eq!(virtSetObservationFrameSpeed(vc, v.as_ptr()), 0);
        let nan = [f32::NAN; 6];
        assert_eq!(virtSetObservationFrameSpeed(vc, nan.as_ptr()), -1);
        assert_eq!(virtGetErrorCode(vc), VIRT_E_INCORRECT_VALUE);
        assert_eq!(virtSetObservationFrameSpeed(vc, std::ptr::null()), -1);
        // A quaternion off unit length (float rounding of an application's
        // double) reads back as given.
        let base = [0.01f32, 0.02, 0.03, 0.1, 0.2, 0.3, 0.9273618];
        let mut got = [0f32; 7];
        assert_eq!(virtSetBaseFrame(vc, base.as_ptr()), 0);
        assert_eq!(virtGetBaseFrame(vc, got.as_mut_ptr()), 0);
        assert_eq!(got, base);
        assert_eq!(virtSetObservationFrame(vc, base.as_ptr()), 0);
        assert_eq!(virtGetObservationFrame(vc, got.as_mut_ptr()), 0);
        assert_eq!(got, base);
        assert_eq!(virtClose(vc), 0);
    }
}
