//! C ABI, Haption VirtuoseAPI style (see `include/virtuose_api.h`).
//!
//! Every function returns 0 on success and -1 on error (virtOpen: NULL);
//! the error is then available from `virtGetErrorCode` and
//! `virtGetErrorMessage`. Errors are kept per calling thread. Float arrays:
//! position `float[7]` (x, y, z, qx, qy, qz, qw), speed and force `float[6]`.

use std::cell::RefCell;
use std::ffi::{c_char, c_float, c_int, c_uint, c_ushort, CStr, CString};

use crate::{CommandType, IndexingMode, VirtContext, VirtError};

/// Opaque handle given to C.
pub struct VirtContextS {
    vc: VirtContext,
}

thread_local! {
    static LAST: RefCell<(c_int, CString)> = RefCell::new((0, CString::default()));
}

fn set_error(e: &VirtError) {
    let msg = CString::new(e.to_string().replace('\0', " ")).unwrap_or_default();
    LAST.with(|l| *l.borrow_mut() = (e.code(), msg));
}

fn clear_error() {
    LAST.with(|l| *l.borrow_mut() = (0, CString::default()));
}

fn status(r: Result<(), VirtError>) -> c_int {
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

/// # Safety
/// `vc` is NULL or a pointer returned by `virtOpen` and not yet closed.
unsafe fn ctx<'a>(vc: *mut VirtContextS) -> Result<&'a mut VirtContext, VirtError> {
    // SAFETY: per the caller's contract.
    unsafe { vc.as_mut() }
        .map(|c| &mut c.vc)
        .ok_or(VirtError::NullPointer)
}

/// # Safety
/// `p` is NULL or points to `N` readable floats.
unsafe fn read_arr<const N: usize>(p: *const c_float) -> Result<[f32; N], VirtError> {
    if p.is_null() {
        return Err(VirtError::NullPointer);
    }
    let mut a = [0f32; N];
    // SAFETY: p points to N floats per the caller's contract.
    unsafe { std::ptr::copy_nonoverlapping(p, a.as_mut_ptr(), N) };
    Ok(a)
}

/// # Safety
/// `p` is NULL or points to `N` writable floats.
unsafe fn write_arr<const N: usize>(p: *mut c_float, a: [f32; N]) -> Result<(), VirtError> {
    if p.is_null() {
        return Err(VirtError::NullPointer);
    }
    // SAFETY: p points to N floats per the caller's contract.
    unsafe { std::ptr::copy_nonoverlapping(a.as_ptr(), p, N) };
    Ok(())
}

/// Open a session with the controller at `"host#port"`. NULL on error.
///
/// # Safety
/// `name` is NULL or a NUL-terminated string.
#[no_mangle]
pub unsafe extern "C" fn virtOpen(name: *const c_char) -> *mut VirtContextS {
    if name.is_null() {
        set_error(&VirtError::NullPointer);
        return std::ptr::null_mut();
    }
    // SAFETY: NUL-terminated per the contract.
    let s = match unsafe { CStr::from_ptr(name) }.to_str() {
        Ok(s) => s,
        Err(_) => {
            set_error(&VirtError::InvalidAddress("not UTF-8".into()));
            return std::ptr::null_mut();
        }
    };
    match VirtContext::open(s) {
        Ok(vc) => {
            clear_error();
            Box::into_raw(Box::new(VirtContextS { vc }))
        }
        Err(e) => {
            set_error(&e);
            std::ptr::null_mut()
        }
    }
}

/// Close the session and free the context (the pointer becomes invalid).
///
/// # Safety
/// `vc` is NULL or a live pointer from `virtOpen`.
#[no_mangle]
pub unsafe extern "C" fn virtClose(vc: *mut VirtContextS) -> c_int {
    if vc.is_null() {
        return status(Err(VirtError::NullPointer));
    }
    // SAFETY: live pointer from Box::into_raw, per the contract.
    let mut b = unsafe { Box::from_raw(vc) };
    status(b.vc.close())
}

macro_rules! with_ctx {
    ($vc:expr, |$c:ident| $body:expr) => {{
        // SAFETY: per the function's contract.
        let r = match unsafe { ctx($vc) } {
            Ok($c) => $body,
            Err(e) => Err(e),
        };
        status(r)
    }};
}

/// # Safety
/// `vc` is NULL or a live pointer from `virtOpen`.
#[no_mangle]
pub unsafe extern "C" fn virtSetTimeStep(vc: *mut VirtContextS, step: c_float) -> c_int {
    with_ctx!(vc, |c| c.set_time_step(step))
}

/// 0 all, 1 translations, 2 none, 3/4 with force-feedback inhibition.
///
/// # Safety
/// `vc` is NULL or a live pointer from `virtOpen`.
#[no_mangle]
pub unsafe extern "C" fn virtSetIndexingMode(vc: *mut VirtContextS, mode: c_ushort) -> c_int {
    with_ctx!(vc, |c| match IndexingMode::from_u32(mode as u32) {
        Some(m) => c.set_indexing_mode(m),
        None => Err(VirtError::InvalidArgument(format!("indexing mode {mode}"))),
    })
}

/// # Safety
/// `vc` is NULL or a live pointer from `virtOpen`.
#[no_mangle]
pub unsafe extern "C" fn virtSetForceFactor(vc: *mut VirtContextS, k: c_float) -> c_int {
    with_ctx!(vc, |c| c.set_force_factor(k))
}

/// # Safety
/// `vc` is NULL or a live pointer from `virtOpen`.
#[no_mangle]
pub unsafe extern "C" fn virtSetSpeedFactor(vc: *mut VirtContextS, k: c_float) -> c_int {
    with_ctx!(vc, |c| c.set_speed_factor(k))
}

/// # Safety
/// `vc` is NULL or live; `pos` is NULL or points to 7 floats.
#[no_mangle]
pub unsafe extern "C" fn virtSetBaseFrame(vc: *mut VirtContextS, pos: *const c_float) -> c_int {
    with_ctx!(vc, |c| unsafe { read_arr::<7>(pos) }
        .and_then(|p| c.set_base_frame(&p)))
}

/// # Safety
/// `vc` is NULL or live; `pos` is NULL or points to 7 floats.
#[no_mangle]
pub unsafe extern "C" fn virtSetObservationFrame(
    vc: *mut VirtContextS,
    pos: *const c_float,
) -> c_int {
    with_ctx!(vc, |c| unsafe { read_arr::<7>(pos) }
        .and_then(|p| c.set_observation_frame(&p)))
}

/// 0 none, 1 impedance, 2 virtual mechanism.
///
/// # Safety
/// `vc` is NULL or a live pointer from `virtOpen`.
#[no_mangle]
pub unsafe extern "C" fn virtSetCommandType(vc: *mut VirtContextS, ty: c_ushort) -> c_int {
    with_ctx!(vc, |c| match CommandType::from_u32(ty as u32) {
        Some(t) => c.set_command_type(t),
        None => Err(VirtError::InvalidArgument(format!("command type {ty}"))),
    })
}

/// Attach a virtual object: mass (kg) and `float[3]` principal inertia.
///
/// # Safety
/// `vc` is NULL or live; `mxmymz` is NULL or points to 3 floats.
#[no_mangle]
pub unsafe extern "C" fn virtAttachVO(
    vc: *mut VirtContextS,
    mass: c_float,
    mxmymz: *const c_float,
) -> c_int {
    with_ctx!(vc, |c| unsafe { read_arr::<3>(mxmymz) }
        .and_then(|i| c.attach_vo(mass, i)))
}

/// # Safety
/// `vc` is NULL or a live pointer from `virtOpen`.
#[no_mangle]
pub unsafe extern "C" fn virtDetachVO(vc: *mut VirtContextS) -> c_int {
    with_ctx!(vc, |c| c.detach_vo())
}

/// Stream the virtual object's pose (sends one frame with the last speed).
///
/// # Safety
/// `vc` is NULL or live; `pos` is NULL or points to 7 floats.
#[no_mangle]
pub unsafe extern "C" fn virtSetPosition(vc: *mut VirtContextS, pos: *const c_float) -> c_int {
    with_ctx!(vc, |c| unsafe { read_arr::<7>(pos) }
        .and_then(|p| c.set_position(&p)))
}

/// Set the virtual object's twist (sent with the next virtSetPosition).
///
/// # Safety
/// `vc` is NULL or live; `speed` is NULL or points to 6 floats.
#[no_mangle]
pub unsafe extern "C" fn virtSetSpeed(vc: *mut VirtContextS, speed: *const c_float) -> c_int {
    with_ctx!(vc, |c| unsafe { read_arr::<6>(speed) }
        .and_then(|s| c.set_speed(&s)))
}

/// Handle pose, `float[7]`.
///
/// # Safety
/// `vc` is NULL or live; `pos` is NULL or points to 7 writable floats.
#[no_mangle]
pub unsafe extern "C" fn virtGetPosition(vc: *mut VirtContextS, pos: *mut c_float) -> c_int {
    with_ctx!(vc, |c| c
        .get_position()
        .and_then(|p| unsafe { write_arr(pos, p) }))
}

/// Handle twist, `float[6]`.
///
/// # Safety
/// `vc` is NULL or live; `speed` is NULL or points to 6 writable floats.
#[no_mangle]
pub unsafe extern "C" fn virtGetSpeed(vc: *mut VirtContextS, speed: *mut c_float) -> c_int {
    with_ctx!(vc, |c| c
        .get_speed()
        .and_then(|s| unsafe { write_arr(speed, s) }))
}

/// Wrench to apply to the virtual object, `float[6]`.
///
/// # Safety
/// `vc` is NULL or live; `force` is NULL or points to 6 writable floats.
#[no_mangle]
pub unsafe extern "C" fn virtGetForce(vc: *mut VirtContextS, force: *mut c_float) -> c_int {
    with_ctx!(vc, |c| c
        .get_force()
        .and_then(|f| unsafe { write_arr(force, f) }))
}

/// # Safety
/// `p` is NULL or points to a writable int.
unsafe fn put_int(p: *mut c_int, v: bool) -> Result<(), VirtError> {
    // SAFETY: per the contract.
    match unsafe { p.as_mut() } {
        Some(p) => {
            *p = v as c_int;
            Ok(())
        }
        None => Err(VirtError::NullPointer),
    }
}

/// # Safety
/// `vc` is NULL or live; `power` is NULL or points to a writable int.
#[no_mangle]
pub unsafe extern "C" fn virtGetPowerOn(vc: *mut VirtContextS, power: *mut c_int) -> c_int {
    with_ctx!(vc, |c| c
        .get_power_on()
        .and_then(|v| unsafe { put_int(power, v) }))
}

/// # Safety
/// `vc` is NULL or a live pointer from `virtOpen`.
#[no_mangle]
pub unsafe extern "C" fn virtSetPowerOn(vc: *mut VirtContextS, power: c_int) -> c_int {
    with_ctx!(vc, |c| c.set_power_on(power != 0))
}

/// # Safety
/// `vc` is NULL or live; `dead_man` is NULL or points to a writable int.
#[no_mangle]
pub unsafe extern "C" fn virtGetDeadMan(vc: *mut VirtContextS, dead_man: *mut c_int) -> c_int {
    with_ctx!(vc, |c| c
        .get_dead_man()
        .and_then(|v| unsafe { put_int(dead_man, v) }))
}

/// # Safety
/// `vc` is NULL or live; `estop` is NULL or points to a writable int.
#[no_mangle]
pub unsafe extern "C" fn virtGetEmergencyStop(vc: *mut VirtContextS, estop: *mut c_int) -> c_int {
    with_ctx!(vc, |c| c
        .get_emergency_stop()
        .and_then(|v| unsafe { put_int(estop, v) }))
}

/// Alarm bits (hap_core::vp::alarm).
///
/// # Safety
/// `vc` is NULL or live; `alarm` is NULL or points to a writable unsigned int.
#[no_mangle]
pub unsafe extern "C" fn virtGetAlarm(vc: *mut VirtContextS, alarm: *mut c_uint) -> c_int {
    with_ctx!(vc, |c| c.get_alarm().and_then(|a| {
        match unsafe { alarm.as_mut() } {
            Some(p) => {
                *p = a;
                Ok(())
            }
            None => Err(VirtError::NullPointer),
        }
    }))
}

/// Link quality: answers per second, loss ratio (0..1), last RTT (ms).
/// Any pointer may be NULL.
///
/// # Safety
/// `vc` is NULL or live; each pointer is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn virtGetLinkStats(
    vc: *mut VirtContextS,
    rate_hz: *mut c_float,
    loss_ratio: *mut c_float,
    rtt_ms: *mut c_float,
) -> c_int {
    with_ctx!(vc, |c| {
        let s = c.link_stats();
        // SAFETY: per the contract.
        unsafe {
            if let Some(p) = rate_hz.as_mut() {
                *p = s.rate_hz as f32;
            }
            if let Some(p) = loss_ratio.as_mut() {
                *p = s.loss_ratio as f32;
            }
            if let Some(p) = rtt_ms.as_mut() {
                *p = s.rtt_ms_last as f32;
            }
        }
        Ok(())
    })
}

/// Code of the last error of the calling thread (0: none). `vc` may be NULL
/// (needed after a failed virtOpen).
#[no_mangle]
pub extern "C" fn virtGetErrorCode(_vc: *mut VirtContextS) -> c_int {
    LAST.with(|l| l.borrow().0)
}

/// Message for `code`: the detailed message of the calling thread's last
/// error if it has that code, else a generic one. The pointer stays valid
/// until the thread's next virt* call.
#[no_mangle]
pub extern "C" fn virtGetErrorMessage(code: c_int) -> *const c_char {
    LAST.with(|l| {
        let l = l.borrow();
        if l.0 == code && code != 0 {
            l.1.as_ptr()
        } else {
            generic(code).as_ptr()
        }
    })
}

fn generic(code: c_int) -> &'static CStr {
    match code {
        0 => c"no error",
        1 => c"invalid address (expected \"host#port\" or \"host\")",
        2 => c"socket error",
        3 => c"timeout: no reply from the controller",
        4 => c"request refused by the controller",
        5 => c"invalid argument",
        6 => c"no data received from the controller yet",
        7 => c"context closed",
        8 => c"null pointer or invalid context",
        _ => c"unknown error code",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn generic_messages_match_rust_ones() {
        for code in 0..10 {
            assert_eq!(
                generic(code).to_str().unwrap(),
                VirtError::code_message(code)
            );
        }
    }

    #[test]
    fn null_pointers_are_errors_not_crashes() {
        unsafe {
            assert!(virtOpen(std::ptr::null()).is_null());
            assert_eq!(virtGetErrorCode(std::ptr::null_mut()), 8);
            assert_eq!(virtSetTimeStep(std::ptr::null_mut(), 0.001), -1);
            assert_eq!(
                virtGetPosition(std::ptr::null_mut(), std::ptr::null_mut()),
                -1
            );
            let bad = c"no-such-host.invalid#x";
            assert!(virtOpen(bad.as_ptr()).is_null());
            assert_eq!(virtGetErrorCode(std::ptr::null_mut()), 1);
            let msg = CStr::from_ptr(virtGetErrorMessage(1)).to_str().unwrap();
            assert!(msg.contains("bad port"), "{msg}");
        }
    }
}
