//! `virtCallDLL`: the one entry point of Haption's 3.x headers.
//!
//! In those headers (3.80 to 3.98) every `virt*` function is an inline
//! wrapper (in C, `inline` is defined as `extern`, so each is defined in
//! the application itself) that calls
//! `virtCallDLL(function, args...)`: `function` numbers the call (the
//! order of `DllFunction` below, which is the ABI), the context comes
//! first where there is one, every pointer is passed as it is and every
//! scalar by its address (`&mass`, `&power`, `&type`). The result is an
//! `int` in 3.80's header and a `uintptr_t` in 3.98's (the context of
//! `OPEN`, the message of `GETERRORMESSAGE`, else the function's `int`,
//! sign-extended so that both casts read -1).
//!
//! An application that ships such a header with its sources links against
//! this library unchanged: its own `virt*` definitions reach the
//! implementations here through `virtCallDLL`. (The installed shared
//! objects bind their internal calls to their own definitions, so the
//! application's same-named wrappers do not intercept them:
//! `scripts/install-virtuose-api.sh` links them with
//! `-Bsymbolic-functions`.)

use std::ffi::{c_char, c_float, c_int, c_uint, c_ushort, c_void};

use super::*;

macro_rules! dll_functions {
    ($($name:ident),* $(,)?) => {
        /// The functions of `virtCallDLL`, in the order of Haption's 3.x
        /// headers (the value of each is its position).
        #[allow(non_camel_case_types, clippy::upper_case_acronyms)]
        #[derive(Clone, Copy, Debug, PartialEq, Eq)]
        pub enum DllFunction {
            $($name),*
        }

        impl DllFunction {
            /// Every function, by value.
            pub const ALL: &'static [DllFunction] = &[$(DllFunction::$name),*];

            /// The name in Haption's headers.
            pub fn name(self) -> &'static str {
                match self {
                    $(DllFunction::$name => stringify!($name)),*
                }
            }

            /// The function numbered `n`, if there is one.
            pub fn from_u32(n: u32) -> Option<DllFunction> {
                Self::ALL.get(usize::try_from(n).ok()?).copied()
            }
        }
    };
}

dll_functions! {
    APIVERSION, ATTACHVO, ATTACHQSVO, ATTACHVOAVATAR, CLOSE, DETACHVO,
    DETACHVOAVATAR, DISPLAYHARDWARESTATUS, GETCATCHFRAME, GETBASEFRAME,
    GETBUTTON, GETCOMMANDTYPE, GETDEADMAN, GETEMERGENCYSTOP, GETERROR,
    GETERRORCODE, GETERRORMESSAGE, GETFORCE, GETFORCEFACTOR, GETINDEXINGMODE,
    GETLIMITTORQUE, GETOBSERVATIONFRAME, GETPOSITION, GETPOWERON, GETSPEED,
    GETSPEEDFACTOR, GETTIMELASTUPDATE, GETTIMEOUTVALUE, OPEN, SETCATCHFRAME,
    SETBASEFRAME, SETCOMMANDTYPE, SETDEBUGFLAGS, SETFORCE, SETFORCEFACTOR,
    SETINDEXINGMODE, SETLIMITTORQUE, SETOBSERVATIONFRAME,
    SETOBSERVATIONFRAMESPEED, SETOUTPUTFILE, SETPERIODICFUNCTION, SETPOSITION,
    SETPOWERON, SETSPEED, SETSPEEDFACTOR, SETTEXTURE, SETTEXTUREFORCE,
    SETTIMEOUTVALUE, SETTIMESTEP, STARTLOOP, STOPLOOP, WAITFORSYNCH,
    TRAJRECORDSTART, TRAJRECORDSTOP, TRAJSAMPLES, TRAJTIMESTEP, VMSETTYPE,
    VMPARAMETERTYPE, VMACTIVATE, VMDEACTIVATE, VMSETMAXBOUNDS, VMSETMINBOUNDS,
    VMSETBASEFRAME, STARTTRAJSAMPLING, SATURATETORQUE, PHYSICALPOSITION,
    AVATARPOSITION, VMSETTRANSPARENTMODE, VMSETCARTESIANPOSITION,
    VMSETBASEFRAMETOCURRENTFRAME, RGBTOGRAYSCALE, VMGETBASEFRAME, WAITBUTTON,
    GETTIMESTEP, VMSETROBOTMODE, VMSAVESPLINE, VMLOADSPLINE, VMDELETESPLINE,
    VMUPPERBOUND, DISABLECONTROLCONNEXION, BOUNDS, ALARM, SETTACTEL,
    ACTIVESPEEDCONTROL, DESACTIVESPEEDCONTROL, SHIFTPOSITION, FRICTION, MOUSE,
    DEBUGFILE, CENTERSPEEDCONTROL, DEPLTOMATRIX, MATRIXTODEPL, AXEROTATION,
    GETADC, GETTRACKBALL, GETTRACKBALLBUTTON, SETABSOLUTEPOSITION, BEEPONLIMIT,
    ENABLEFORCEFEEDBACK, PHYSICALSPEED, FORCESHIFTBUTTON, ADDPHYSICALFORCE,
    BREAKDOWN, SETARTICULARPOSITIONOFADDITIONALAXE,
    GETARTICULARPOSITIONOFADDITIONALAXE, SETARTICULARSPEEDOFADDITIONALAXE,
    GETARTICULARSPEEDOFADDITIONALAXE, SETARTICULARFORCEOFADDITIONALAXE,
    SETARTICULARPOSITION, GETARTICULARPOSITION, SETARTICULARSPEED,
    GETARTICULARSPEED, SETARTICULARFORCE, ACTIVEROTATIONSPEEDCONTROL,
    DESACTIVEROTATIONSPEEDCONTROL, CONTROLERVERSION, ISINSPEEDCONTROL,
    FORCEINSPEEDCONTROL, TORQUEINSPEEDCONTROL, SETGRIPPERCOMMANDTYPE,
    OUTPUTSSETTING, DEVICEID, SETPWM, ANA_INPUTS, TOR_INPUTS, GETNBAXES,
    FINGERTIPSPEED, GETSIMULATIONSTIFFNESS, GETSIMULATIONDAMPING,
}

/// An `int` result as `virtCallDLL` returns it: sign-extended, so that the
/// caller's `(int)` cast (3.98) or its `int` return register (3.80) reads
/// it unchanged.
fn int(r: c_int) -> usize {
    r as isize as usize
}

/// A failure of a call that did not reach a function: the calling thread's
/// code, and the context's when `vc` is an open one.
fn fail(vc: usize, e: ApiError) -> usize {
    if let Ok(c) = ctx(vc as *mut c_void) {
        c.last_error.store(e.code, Ordering::SeqCst);
    }
    int(status_of(Err(e)))
}

/// The scalar a 3.x wrapper passes by its address.
///
/// # Safety
/// `p` is 0 or the address of a readable `T`.
unsafe fn scalar<T: Copy>(p: usize) -> Option<T> {
    // SAFETY: per the contract.
    unsafe { (p as *const T).as_ref().copied() }
}

/// Haption's 3.x dispatch: call function `f` with the arguments its header
/// wrapper passes (at most five: the context and four more).
///
/// The C declaration is variadic, `uintptr_t virtCallDLL(virtDLLFunction,
/// ...)`. Every argument after `f` is a pointer (scalars go by address),
/// and on the Linux calling conventions this library is built for (System V
/// x86-64: six integer registers; AAPCS64: eight) variadic integer-class
/// arguments travel exactly as named ones do, so this definition with five
/// pointer-sized parameters receives them; it reads only as many as `f`
/// takes (the others hold whatever the caller's registers held).
///
/// # Safety
/// The arguments are those of the wrapper of `f` in Haption's 3.x header,
/// each pointer as that function's own `# Safety` requires.
#[cfg(all(
    target_os = "linux",
    any(target_arch = "x86_64", target_arch = "aarch64")
))]
#[no_mangle]
pub unsafe extern "C" fn virtCallDLL(
    f: c_uint,
    a: usize,
    b: usize,
    c: usize,
    d: usize,
    e: usize,
) -> usize {
    // SAFETY: per this function's contract, the arguments are the
    // wrapper's, as each called function requires.
    unsafe { dispatch(f, [a, b, c, d, e]) }
}

/// `virtCallDLL`'s work (what a test can call).
///
/// # Safety
/// As `virtCallDLL`.
pub unsafe fn dispatch(f: c_uint, args: [usize; 5]) -> usize {
    use DllFunction::*;
    let [a, b, c, d, e] = args;
    let vc = a as *mut c_void;
    let Some(func) = DllFunction::from_u32(f) else {
        return fail(
            a,
            ApiError::new(
                VIRT_E_INCORRECT_VALUE,
                format!(
                    "virtCallDLL: no function {f} (Haption's 3.x headers number 0..={})",
                    DllFunction::ALL.len() - 1
                ),
            ),
        );
    };
    // The scalars the wrapper passed by address (a NULL address is the
    // caller's error, reported as a NULL argument). Used only inside the
    // `unsafe` block below: the wrapper passes the address of its own
    // parameter.
    macro_rules! by_ref {
        ($t:ty, $p:expr) => {
            match scalar::<$t>($p) {
                Some(v) => v,
                None => return fail(a, ApiError::null()),
            }
        };
    }
    // SAFETY (every call below): the arguments are the wrapper's, of the
    // types and sizes the called function's `# Safety` requires.
    unsafe {
        match func {
            APIVERSION => int(virtAPIVersion(a as *mut c_int, b as *mut c_int)),
            OPEN => virtOpen(a as *const c_char) as usize,
            CLOSE => int(virtClose(vc)),
            GETERRORCODE => int(virtGetErrorCode(vc)),
            GETERROR => int(virtGetError(vc, b as *mut c_int)),
            GETERRORMESSAGE => virtGetErrorMessage(by_ref!(c_int, a)) as usize,
            CONTROLERVERSION => int(virtGetControlerVersion(
                vc,
                b as *mut c_int,
                c as *mut c_int,
            )),
            DEVICEID => int(virtGetDeviceID(vc, b as *mut c_int, c as *mut c_int)),
            SETTIMEOUTVALUE => int(virtSetTimeoutValue(vc, by_ref!(c_float, b))),
            GETTIMEOUTVALUE => int(virtGetTimeoutValue(vc, b as *mut c_float)),
            SETDEBUGFLAGS => int(virtSetDebugFlags(vc, by_ref!(c_ushort, b))),
            SETOUTPUTFILE => int(virtSetOutputFile(vc, b as *mut c_char)),
            DISPLAYHARDWARESTATUS => int(virtDisplayHardwareStatus(vc, b as *mut c_void)),
            DISABLECONTROLCONNEXION => int(virtDisableControlConnexion(vc, by_ref!(c_int, b))),
            SETTIMESTEP => int(virtSetTimeStep(vc, by_ref!(c_float, b))),
            GETTIMESTEP => int(virtGetTimeStep(vc, b as *mut c_float)),
            SETCOMMANDTYPE => int(virtSetCommandType(vc, by_ref!(c_int, b))),
            GETCOMMANDTYPE => int(virtGetCommandType(vc, b as *mut c_int)),
            SETINDEXINGMODE => int(virtSetIndexingMode(vc, by_ref!(c_int, b))),
            GETINDEXINGMODE => int(virtGetIndexingMode(vc, b as *mut c_int)),
            SETFORCEFACTOR => int(virtSetForceFactor(vc, by_ref!(c_float, b))),
            GETFORCEFACTOR => int(virtGetForceFactor(vc, b as *mut c_float)),
            SETSPEEDFACTOR => int(virtSetSpeedFactor(vc, by_ref!(c_float, b))),
            GETSPEEDFACTOR => int(virtGetSpeedFactor(vc, b as *mut c_float)),
            SETBASEFRAME => int(virtSetBaseFrame(vc, b as *const c_float)),
            GETBASEFRAME => int(virtGetBaseFrame(vc, b as *mut c_float)),
            SETOBSERVATIONFRAME => int(virtSetObservationFrame(vc, b as *const c_float)),
            GETOBSERVATIONFRAME => int(virtGetObservationFrame(vc, b as *mut c_float)),
            SETOBSERVATIONFRAMESPEED => int(virtSetObservationFrameSpeed(vc, b as *const c_float)),
            SETCATCHFRAME => int(virtSetCatchFrame(vc, b as *const c_float)),
            GETCATCHFRAME => int(virtGetCatchFrame(vc, b as *mut c_float)),
            GETNBAXES => int(virtGetNbAxes(vc, b as *mut c_int)),
            SETPOWERON => int(virtSetPowerOn(vc, by_ref!(c_int, b))),
            GETPOWERON => int(virtGetPowerOn(vc, b as *mut c_int)),
            GETDEADMAN => int(virtGetDeadMan(vc, b as *mut c_int)),
            GETEMERGENCYSTOP => int(virtGetEmergencyStop(vc, b as *mut c_int)),
            ALARM => int(virtGetAlarm(vc, b as *mut c_uint)),
            BREAKDOWN => int(virtGetFailure(vc, b as *mut c_uint)),
            BOUNDS => int(virtIsInBounds(vc, b as *mut c_uint)),
            GETBUTTON => int(virtGetButton(vc, by_ref!(c_int, b), c as *mut c_int)),
            WAITBUTTON => int(virtWaitPressButton(vc, by_ref!(c_int, b))),
            SHIFTPOSITION => int(virtIsInShiftPosition(vc, b as *mut c_int)),
            FORCESHIFTBUTTON => int(virtForceShiftButton(vc, by_ref!(c_int, b))),
            ATTACHVO => int(virtAttachVO(vc, by_ref!(c_float, b), c as *const c_float)),
            ATTACHVOAVATAR => int(virtAttachVOAvatar(
                vc,
                by_ref!(c_float, b),
                c as *const c_float,
            )),
            ATTACHQSVO => int(virtAttachQSVO(vc, b as *const c_float, c as *const c_float)),
            DETACHVO => int(virtDetachVO(vc)),
            DETACHVOAVATAR => int(virtDetachVOAvatar(vc)),
            SETPOSITION => int(virtSetPosition(vc, b as *const c_float)),
            SETSPEED => int(virtSetSpeed(vc, b as *const c_float)),
            SETFORCE => int(virtSetForce(vc, b as *const c_float)),
            ADDPHYSICALFORCE => int(virtAddForce(vc, b as *const c_float)),
            GETPOSITION => int(virtGetPosition(vc, b as *mut c_float)),
            GETSPEED => int(virtGetSpeed(vc, b as *mut c_float)),
            GETFORCE => int(virtGetForce(vc, b as *mut c_float)),
            AVATARPOSITION => int(virtGetAvatarPosition(vc, b as *mut c_float)),
            PHYSICALPOSITION => int(virtGetPhysicalPosition(vc, b as *mut c_float)),
            PHYSICALSPEED => int(virtGetPhysicalSpeed(vc, b as *mut c_float)),
            GETTIMELASTUPDATE => int(virtGetTimeLastUpdate(vc, b as *mut c_uint)),
            SATURATETORQUE => int(virtSaturateTorque(
                vc,
                by_ref!(c_float, b),
                by_ref!(c_float, c),
            )),
            ENABLEFORCEFEEDBACK => int(virtEnableForceFeedback(vc, by_ref!(c_int, b))),
            GETSIMULATIONSTIFFNESS => int(virtGetSimulationStiffness(vc, b as *mut c_float)),
            GETSIMULATIONDAMPING => int(virtGetSimulationDamping(vc, b as *mut c_float)),
            GETARTICULARPOSITION => int(virtGetArticularPosition(vc, b as *mut c_float)),
            GETARTICULARSPEED => int(virtGetArticularSpeed(vc, b as *mut c_float)),
            SETARTICULARPOSITION => int(virtSetArticularPosition(vc, b as *const c_float)),
            SETARTICULARSPEED => int(virtSetArticularSpeed(vc, b as *const c_float)),
            SETARTICULARFORCE => int(virtSetArticularForce(vc, b as *const c_float)),
            GETARTICULARPOSITIONOFADDITIONALAXE => int(virtGetArticularPositionOfAdditionalAxe(
                vc,
                b as *mut c_float,
            )),
            GETARTICULARSPEEDOFADDITIONALAXE => {
                int(virtGetArticularSpeedOfAdditionalAxe(vc, b as *mut c_float))
            }
            SETARTICULARPOSITIONOFADDITIONALAXE => int(virtSetArticularPositionOfAdditionalAxe(
                vc,
                b as *const c_float,
            )),
            SETARTICULARSPEEDOFADDITIONALAXE => int(virtSetArticularSpeedOfAdditionalAxe(
                vc,
                b as *const c_float,
            )),
            SETARTICULARFORCEOFADDITIONALAXE => int(virtSetArticularForceOfAdditionalAxe(
                vc,
                b as *const c_float,
            )),
            SETPERIODICFUNCTION => {
                // SAFETY: `Option<fn>` has the layout of a pointer (NULL is None).
                let func = std::mem::transmute::<usize, Option<PeriodicFn>>(b);
                int(virtSetPeriodicFunction(
                    vc,
                    func,
                    c as *const c_float,
                    d as *mut c_void,
                ))
            }
            STARTLOOP => int(virtStartLoop(vc)),
            STOPLOOP => int(virtStopLoop(vc)),
            TRAJRECORDSTART => int(virtTrajRecordStart(vc)),
            TRAJRECORDSTOP => int(virtTrajRecordStop(vc)),
            TRAJTIMESTEP => int(virtTrajSetSamplingTimeStep(
                vc,
                by_ref!(c_float, b),
                c as *mut c_uint,
            )),
            DEPLTOMATRIX => int(virtConvertDeplToHomogeneMatrix(
                vc,
                b as *const c_float,
                c as *mut c_float,
            )),
            MATRIXTODEPL => int(virtConvertHomogeneMatrixToDepl(
                vc,
                b as *mut c_float,
                c as *const c_float,
            )),
            RGBTOGRAYSCALE => int(virtConvertRGBToGrayscale(
                vc,
                b as *const c_float,
                c as *mut c_float,
            )),
            ACTIVESPEEDCONTROL => int(virtActiveSpeedControl(
                vc,
                by_ref!(c_float, b),
                by_ref!(c_float, c),
            )),
            DESACTIVESPEEDCONTROL => int(virtDeactiveSpeedControl(vc)),
            ACTIVEROTATIONSPEEDCONTROL => int(virtActiveRotationSpeedControl(
                vc,
                by_ref!(c_float, b),
                by_ref!(c_float, c),
            )),
            DESACTIVEROTATIONSPEEDCONTROL => int(virtDeactiveRotationSpeedControl(vc)),
            ISINSPEEDCONTROL => int(virtIsInSpeedControl(vc, b as *mut c_int, c as *mut c_int)),
            FORCEINSPEEDCONTROL => int(virtSetForceInSpeedControl(vc, by_ref!(c_float, b))),
            TORQUEINSPEEDCONTROL => int(virtSetTorqueInSpeedControl(vc, by_ref!(c_float, b))),
            CENTERSPEEDCONTROL => int(virtGetCenterSphere(vc, b as *mut c_float)),
            AXEROTATION => int(virtGetAxisOfRotation(vc, b as *mut c_float)),
            SETTEXTURE => int(virtSetTexture(
                vc,
                b as *const c_float,
                c as *const c_float,
                by_ref!(c_int, d),
            )),
            SETTEXTUREFORCE => int(virtSetTextureForce(vc, b as *const c_float)),
            SETGRIPPERCOMMANDTYPE => int(virtSetGripperCommandType(vc, by_ref!(c_int, b))),
            FINGERTIPSPEED => int(virtSetFingerTipSpeed(vc, b as *const c_float)),
            GETADC => int(virtGetADC(vc, by_ref!(c_int, b), c as *mut c_float)),
            ANA_INPUTS => int(virtGetAnalogicInputs(vc, b as *mut c_float)),
            TOR_INPUTS => int(virtGetTorInputs(vc, b as *mut c_uint)),
            OUTPUTSSETTING => int(virtOutputsSetting(vc, by_ref!(c_uint, b))),
            SETPWM => int(virtSetPwmOutput(vc, b as *const c_float)),
            MOUSE => int(virtGetMouseState(
                vc,
                b as *mut c_int,
                c as *mut c_int,
                d as *mut c_int,
            )),
            GETTRACKBALL => int(virtGetTrackball(vc, b as *mut c_int, c as *mut c_int)),
            GETTRACKBALLBUTTON => int(virtGetTrackballButton(
                vc,
                b as *mut c_int,
                c as *mut c_int,
                d as *mut c_int,
                e as *mut c_int,
            )),
            VMACTIVATE => int(virtVmActivate(vc)),
            VMDEACTIVATE => int(virtVmDeactivate(vc)),
            VMSETTYPE => int(virtVmSetType(vc, by_ref!(c_int, b))),
            VMSETBASEFRAME => int(virtVmSetBaseFrame(vc, b as *const c_float)),
            VMGETBASEFRAME => int(virtVmGetBaseFrame(vc, b as *mut c_float)),
            VMSETBASEFRAMETOCURRENTFRAME => int(virtVmSetBaseFrameToCurrentFrame(vc)),
            VMSETCARTESIANPOSITION => int(virtVmSetDefaultToCartesianPosition(vc)),
            VMSETTRANSPARENTMODE => int(virtVmSetDefaultToTransparentMode(vc)),
            VMSETROBOTMODE => int(virtVmSetRobotMode(vc, by_ref!(c_int, b))),
            STARTTRAJSAMPLING => int(virtVmStartTrajSampling(vc, by_ref!(c_uint, b))),
            TRAJSAMPLES => int(virtVmGetTrajSamples(vc, b as *mut c_float)),
            VMUPPERBOUND => int(virtVmWaitUpperBound(vc)),
            VMLOADSPLINE => int(virtVmLoadSpline(vc, b as *const c_char)),
            VMSAVESPLINE => int(virtVmSaveCurrentSpline(vc, b as *const c_char)),
            VMDELETESPLINE => int(virtVmDeleteSpline(vc, b as *const c_char)),
            // Numbered in the headers but with no wrapper there (internal
            // to Haption's library or withdrawn): nothing to call.
            GETLIMITTORQUE | SETLIMITTORQUE | WAITFORSYNCH | VMPARAMETERTYPE | VMSETMAXBOUNDS
            | VMSETMINBOUNDS | SETTACTEL | FRICTION | DEBUGFILE | SETABSOLUTEPOSITION
            | BEEPONLIMIT => {
                if !vc.is_null() {
                    if let Err(e) = ctx(vc) {
                        return fail(a, e);
                    }
                }
                fail(a, ApiError::not_implemented(func.name()))
            }
        }
    }
}

/// Haption's 3.x headers declare it to load the library from a path at
/// run time; here the library is the one already linked, so there is
/// nothing to load: 0 (success), whatever the path.
///
/// # Safety
/// None: `path` is not read.
#[no_mangle]
pub unsafe extern "C" fn virtLoadDLL(_path: *const c_char) -> c_int {
    clear_error();
    0
}
