//! A bimanual VirtuoseAPI application: one process opens two arms, each by
//! its own address (`virtOpen` twice, one controller port per arm), runs a
//! periodic loop on each at once, and every context reads and drives only
//! its own arm: its handle, its session, its set-points. Closing one arm's
//! context leaves the other streaming.

use std::ffi::{c_void, CString};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Duration;

use hap_core::control::Gains;
use hap_core::fixed::Fx;
use virtuose_api::fake_peer::{FakePeer, FakePeerConfig};
use virtuose_api::ffi::*;

/// One arm's fake controller, its handle held still at `center`.
fn arm(center: [f64; 3]) -> FakePeer {
    FakePeer::start(FakePeerConfig {
        center,
        amplitude: [0.0; 3],
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
    // SAFETY: NULL asks for the calling thread's code.
    assert!(
        !vc.is_null(),
        "virtOpen({}) failed: {}",
        p.address(),
        unsafe { virtGetErrorCode(std::ptr::null_mut()) }
    );
    vc
}

fn k_lin() -> f64 {
    Gains::for_period(Fx::from_ratio(1000, 1_000_000))
        .k_lin
        .to_f64()
}

fn vpr_frames(p: &FakePeer) -> u64 {
    p.stats().frames.get("vpr_stream").copied().unwrap_or(0)
}

/// What one arm's periodic callback needs: its context, the force it
/// applies, and what it saw.
struct Hand {
    vc: *mut c_void,
    force: [f32; 6],
    calls: AtomicU32,
    errors: AtomicU32,
    /// The handle's x, y (µm) the last callback read.
    last_x_um: AtomicU32,
    last_y_um: AtomicU32,
}

unsafe extern "C" fn hand_callback(vc: *mut c_void, arg: *mut c_void) {
    // SAFETY: arg is the test's &Hand, alive while the loop runs.
    let h = unsafe { &*(arg as *const Hand) };
    if vc != h.vc {
        h.errors.fetch_add(1, Ordering::SeqCst);
    }
    let mut pos = [0f32; 7];
    // SAFETY: vc is live; the arrays have the sizes the functions need.
    let r = unsafe { virtGetPosition(vc, pos.as_mut_ptr()) | virtSetForce(vc, h.force.as_ptr()) };
    if r != 0 {
        h.errors.fetch_add(1, Ordering::SeqCst);
    }
    // Offset by 1 m so that a negative coordinate fits the unsigned store.
    h.last_x_um
        .store(((pos[0] as f64 + 1.0) * 1e6) as u32, Ordering::SeqCst);
    h.last_y_um
        .store(((pos[1] as f64 + 1.0) * 1e6) as u32, Ordering::SeqCst);
    h.calls.fetch_add(1, Ordering::SeqCst);
}

fn um(v: &AtomicU32) -> f64 {
    v.load(Ordering::SeqCst) as f64 / 1e6 - 1.0
}

#[test]
fn virt_open_twice_drives_each_arm_by_its_address() {
    let (cl, cr) = ([0.45, 0.2, 0.25], [0.45, -0.2, 0.25]);
    let (left, right) = (arm(cl), arm(cr));
    assert_ne!(left.address(), right.address());
    let (vl, vr) = (open(&left), open(&right));
    assert_ne!(vl, vr);
    let hand = |vc, force| Hand {
        vc,
        force,
        calls: AtomicU32::new(0),
        errors: AtomicU32::new(0),
        last_x_um: AtomicU32::new(0),
        last_y_um: AtomicU32::new(0),
    };
    let hl = hand(vl, [0.0, 0.0, 2.0, 0.0, 0.0, 0.0]);
    let hr = hand(vr, [-3.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    let period = 0.001f32;
    let k = k_lin();
    // SAFETY: both contexts are live until closed below; hl and hr outlive
    // their loops (virtClose joins them).
    unsafe {
        // Each context names its own arm's session.
        let (mut ty, mut sl, mut sr) = (0, 0, 0);
        assert_eq!(virtGetDeviceID(vl, &mut ty, &mut sl), 0);
        assert_eq!(virtGetDeviceID(vr, &mut ty, &mut sr), 0);
        assert!(sl > 0 && sr > 0, "sessions {sl}, {sr}");
        for (vc, h) in [(vl, &hl), (vr, &hr)] {
            assert_eq!(virtSetCommandType(vc, COMMAND_TYPE_IMPEDANCE), 0);
            assert_eq!(virtSetPowerOn(vc, 1), 0);
            let arg = h as *const Hand as *mut c_void;
            assert_eq!(
                virtSetPeriodicFunction(vc, Some(hand_callback), &period, arg),
                0
            );
        }
        // Both loops at once.
        assert_eq!(virtStartLoop(vl), 0);
        assert_eq!(virtStartLoop(vr), 0);
        std::thread::sleep(Duration::from_millis(300));
        for (h, c, name) in [(&hl, cl, "left"), (&hr, cr, "right")] {
            let calls = h.calls.load(Ordering::SeqCst);
            assert!(calls >= 10, "{name}: {calls} calls in 300 ms at 1 ms");
            assert_eq!(h.errors.load(Ordering::SeqCst), 0, "{name}");
            // Each loop reads its own arm's handle.
            assert!((um(&h.last_x_um) - c[0]).abs() < 1e-5, "{name}");
            assert!((um(&h.last_y_um) - c[1]).abs() < 1e-5, "{name}");
        }
        // Each controller got its own context's set-points only: the
        // virtual object offset from its handle by its own force over K.
        for (p, c, f, name) in [
            (&left, cl, hl.force, "left"),
            (&right, cr, hr.force, "right"),
        ] {
            let s = p.stats();
            assert!(s.powered, "{name} powered");
            assert_eq!(s.command_type, Some(1), "{name}: impedance");
            assert_eq!(s.stray, 0, "{name}: no frame from another source");
            for i in 0..3 {
                let o = s.last_vo_pose[i] - c[i];
                assert!((o - f[i] as f64 / k).abs() < 1e-6, "{name} axis {i}: {o}");
            }
        }
        let (cl_addr, cr_addr) = (left.stats().client, right.stats().client);
        assert!(cl_addr.is_some() && cr_addr.is_some());
        assert_ne!(cl_addr, cr_addr, "one socket per context");
        // Closing the left arm leaves the right one streaming.
        assert_eq!(virtClose(vl), 0);
        let (l0, r0) = (vpr_frames(&left), vpr_frames(&right));
        let calls_r = hr.calls.load(Ordering::SeqCst);
        std::thread::sleep(Duration::from_millis(100));
        assert_eq!(vpr_frames(&left), l0, "the closed arm gets nothing more");
        assert!(vpr_frames(&right) > r0, "the right arm still streams");
        assert!(hr.calls.load(Ordering::SeqCst) > calls_r);
        let mut pos = [0f32; 7];
        assert_eq!(virtGetPosition(vr, pos.as_mut_ptr()), 0);
        assert!((pos[1] as f64 - cr[1]).abs() < 1e-5);
        assert_eq!(left.stats().frames.get("close_session"), Some(&1));
        assert_eq!(right.stats().frames.get("close_session"), None);
        assert_eq!(virtClose(vr), 0);
        assert_eq!(right.stats().frames.get("close_session"), Some(&1));
    }
}
