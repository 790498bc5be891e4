/*
 * virtuoseAPI.h - a VirtuoseAPI header of the form Haption shipped with its
 * 3.x releases (3.80 to 3.98), written for hapticctrl's tests (not
 * Haption's file): tests/vapi/run.sh builds tests/vapi/apps.c, unchanged,
 * with this directory first on the include path, as an application that
 * ships such a header next to its sources does, and links it against the
 * installed library.
 *
 * What makes the form: no virt* function is declared for the library to
 * define. Each is an inline wrapper that calls the library's one entry
 * point, virtCallDLL(function, ...), with the function's number (the order
 * of virtDLLFunction: the ABI), the context first, pointers as they are
 * and scalars by their address. In C, `inline` is defined as `extern`, so
 * the application itself defines every wrapper (external linkage, the same
 * names as the library's own functions); in C++ they are inline functions.
 *
 * The result of virtCallDLL is a uintptr_t (3.98); with VIRTUOSE_API_380
 * defined it is an int, as in 3.80 (on a 64-bit machine the context then
 * passes through an int, and virtGetErrorMessage's pointer does not
 * survive the int: do not call it in that mode).
 */
#ifndef HAPTICCTRL_TEST_VIRTUOSE3_H
#define HAPTICCTRL_TEST_VIRTUOSE3_H

#include <stdint.h>
#include <stdio.h>

#ifndef __cplusplus
#define inline extern
#endif

#ifdef __cplusplus
extern "C" {
#endif

typedef void *VirtContext;
typedef void (*VirtPeriodicFunction)(VirtContext, void *);

typedef enum {
    COMMAND_TYPE_NONE = 0,
    COMMAND_TYPE_JOINT = 1,
    COMMAND_TYPE_CARTESIAN = 2,
    COMMAND_TYPE_IMPEDANCE = 3,
    COMMAND_TYPE_ADMITTANCE = 4,
    COMMAND_TYPE_VIRTMECH = 5,
    COMMAND_TYPE_ARTICULAR = 6,
    COMMAND_TYPE_ARTICULAR_IMPEDANCE = 7
} VirtCommandType;

typedef enum {
    GRIPPER_COMMAND_TYPE_NONE = 0,
    GRIPPER_COMMAND_TYPE_POSITION = 1,
    GRIPPER_COMMAND_TYPE_IMPEDANCE = 2
} VirtGripperCommandType;

typedef enum {
    INDEXING_ALL = 0,
    INDEXING_TRANS = 1,
    INDEXING_NONE = 2,
    INDEXING_ALL_FORCE_FEEDBACK_INHIBITION = 3,
    INDEXING_TRANS_FORCE_FEEDBACK_INHIBITION = 4,
    INDEXING_ROT_FORCE_FEEDBACK_INHIBITION = 6,
    INDEXING_ROT = 7
} VirtIndexingType;

typedef enum {
    VM_TYPE_CartMotion = 0, VM_TYPE_Spline, VM_TYPE_Rx, VM_TYPE_Tx, VM_TYPE_TxRx,
    VM_TYPE_TxTyTz, VM_TYPE_RxRyRz, VM_TYPE_TxTy, VM_TYPE_Crank
} VirtVmType;

#define DEBUG_SERVO 0x0001
#define DEBUG_LOOP  0x0002

/* The functions of virtCallDLL, numbered from 0 in this order. */
typedef enum {
    APIVERSION, ATTACHVO, ATTACHQSVO, ATTACHVOAVATAR,
    CLOSE, DETACHVO, DETACHVOAVATAR, DISPLAYHARDWARESTATUS,
    GETCATCHFRAME, GETBASEFRAME, GETBUTTON, GETCOMMANDTYPE,
    GETDEADMAN, GETEMERGENCYSTOP, GETERROR, GETERRORCODE,
    GETERRORMESSAGE, GETFORCE, GETFORCEFACTOR, GETINDEXINGMODE,
    GETLIMITTORQUE, GETOBSERVATIONFRAME, GETPOSITION, GETPOWERON,
    GETSPEED, GETSPEEDFACTOR, GETTIMELASTUPDATE, GETTIMEOUTVALUE,
    OPEN, SETCATCHFRAME, SETBASEFRAME, SETCOMMANDTYPE,
    SETDEBUGFLAGS, SETFORCE, SETFORCEFACTOR, SETINDEXINGMODE,
    SETLIMITTORQUE, SETOBSERVATIONFRAME, SETOBSERVATIONFRAMESPEED, SETOUTPUTFILE,
    SETPERIODICFUNCTION, SETPOSITION, SETPOWERON, SETSPEED,
    SETSPEEDFACTOR, SETTEXTURE, SETTEXTUREFORCE, SETTIMEOUTVALUE,
    SETTIMESTEP, STARTLOOP, STOPLOOP, WAITFORSYNCH,
    TRAJRECORDSTART, TRAJRECORDSTOP, TRAJSAMPLES, TRAJTIMESTEP,
    VMSETTYPE, VMPARAMETERTYPE, VMACTIVATE, VMDEACTIVATE,
    VMSETMAXBOUNDS, VMSETMINBOUNDS, VMSETBASEFRAME, STARTTRAJSAMPLING,
    SATURATETORQUE, PHYSICALPOSITION, AVATARPOSITION, VMSETTRANSPARENTMODE,
    VMSETCARTESIANPOSITION, VMSETBASEFRAMETOCURRENTFRAME, RGBTOGRAYSCALE, VMGETBASEFRAME,
    WAITBUTTON, GETTIMESTEP, VMSETROBOTMODE, VMSAVESPLINE,
    VMLOADSPLINE, VMDELETESPLINE, VMUPPERBOUND, DISABLECONTROLCONNEXION,
    BOUNDS, ALARM, SETTACTEL, ACTIVESPEEDCONTROL,
    DESACTIVESPEEDCONTROL, SHIFTPOSITION, FRICTION, MOUSE,
    DEBUGFILE, CENTERSPEEDCONTROL, DEPLTOMATRIX, MATRIXTODEPL,
    AXEROTATION, GETADC, GETTRACKBALL, GETTRACKBALLBUTTON,
    SETABSOLUTEPOSITION, BEEPONLIMIT, ENABLEFORCEFEEDBACK, PHYSICALSPEED,
    FORCESHIFTBUTTON, ADDPHYSICALFORCE, BREAKDOWN, SETARTICULARPOSITIONOFADDITIONALAXE,
    GETARTICULARPOSITIONOFADDITIONALAXE, SETARTICULARSPEEDOFADDITIONALAXE, GETARTICULARSPEEDOFADDITIONALAXE, SETARTICULARFORCEOFADDITIONALAXE,
    SETARTICULARPOSITION, GETARTICULARPOSITION, SETARTICULARSPEED, GETARTICULARSPEED,
    SETARTICULARFORCE, ACTIVEROTATIONSPEEDCONTROL, DESACTIVEROTATIONSPEEDCONTROL, CONTROLERVERSION,
    ISINSPEEDCONTROL, FORCEINSPEEDCONTROL, TORQUEINSPEEDCONTROL, SETGRIPPERCOMMANDTYPE,
    OUTPUTSSETTING, DEVICEID, SETPWM, ANA_INPUTS,
    TOR_INPUTS, GETNBAXES, FINGERTIPSPEED, GETSIMULATIONSTIFFNESS,
    GETSIMULATIONDAMPING,
} virtDLLFunction;

#ifdef VIRTUOSE_API_380
extern int virtCallDLL(virtDLLFunction, ...);
#else
extern uintptr_t virtCallDLL(virtDLLFunction, ...);
#endif
extern int virtLoadDLL(char *path);

/* Session */
inline VirtContext virtOpen(const char *address) { return (VirtContext)(intptr_t)virtCallDLL(OPEN, address); }
inline int virtClose(VirtContext vc) { return (int)virtCallDLL(CLOSE, vc); }
inline int virtAPIVersion(int *major, int *minor) { return (int)virtCallDLL(APIVERSION, major, minor); }
inline int virtGetControlerVersion(VirtContext vc, int *major, int *minor) { return (int)virtCallDLL(CONTROLERVERSION, vc, major, minor); }
inline int virtGetDeviceID(VirtContext vc, int *type, int *serial) { return (int)virtCallDLL(DEVICEID, vc, type, serial); }
inline int virtGetErrorCode(VirtContext vc) { return (int)virtCallDLL(GETERRORCODE, vc); }
inline int virtGetError(VirtContext vc, int *code) { return (int)virtCallDLL(GETERROR, vc, code); }
inline char *virtGetErrorMessage(int code) { return (char *)(intptr_t)virtCallDLL(GETERRORMESSAGE, &code); }
inline int virtSetTimeoutValue(VirtContext vc, float seconds) { return (int)virtCallDLL(SETTIMEOUTVALUE, vc, &seconds); }
inline int virtGetTimeoutValue(VirtContext vc, float *seconds) { return (int)virtCallDLL(GETTIMEOUTVALUE, vc, seconds); }
inline int virtSetDebugFlags(VirtContext vc, unsigned short flags) { return (int)virtCallDLL(SETDEBUGFLAGS, vc, &flags); }
inline int virtSetOutputFile(VirtContext vc, char *path) { return (int)virtCallDLL(SETOUTPUTFILE, vc, path); }
inline int virtDisplayHardwareStatus(VirtContext vc, FILE *out) { return (int)virtCallDLL(DISPLAYHARDWARESTATUS, vc, out); }
inline int virtDisableControlConnexion(VirtContext vc, int disable) { return (int)virtCallDLL(DISABLECONTROLCONNEXION, vc, &disable); }

/* Configuration */
inline int virtSetTimeStep(VirtContext vc, float step) { return (int)virtCallDLL(SETTIMESTEP, vc, &step); }
inline int virtGetTimeStep(VirtContext vc, float *step) { return (int)virtCallDLL(GETTIMESTEP, vc, step); }
inline int virtSetCommandType(VirtContext vc, VirtCommandType type) { return (int)virtCallDLL(SETCOMMANDTYPE, vc, &type); }
inline int virtGetCommandType(VirtContext vc, VirtCommandType *type) { return (int)virtCallDLL(GETCOMMANDTYPE, vc, type); }
inline int virtSetIndexingMode(VirtContext vc, VirtIndexingType mode) { return (int)virtCallDLL(SETINDEXINGMODE, vc, &mode); }
inline int virtGetIndexingMode(VirtContext vc, VirtIndexingType *mode) { return (int)virtCallDLL(GETINDEXINGMODE, vc, mode); }
inline int virtSetForceFactor(VirtContext vc, float factor) { return (int)virtCallDLL(SETFORCEFACTOR, vc, &factor); }
inline int virtGetForceFactor(VirtContext vc, float *factor) { return (int)virtCallDLL(GETFORCEFACTOR, vc, factor); }
inline int virtSetSpeedFactor(VirtContext vc, float factor) { return (int)virtCallDLL(SETSPEEDFACTOR, vc, &factor); }
inline int virtGetSpeedFactor(VirtContext vc, float *factor) { return (int)virtCallDLL(GETSPEEDFACTOR, vc, factor); }
inline int virtSetBaseFrame(VirtContext vc, float *frame) { return (int)virtCallDLL(SETBASEFRAME, vc, frame); }
inline int virtGetBaseFrame(VirtContext vc, float *frame) { return (int)virtCallDLL(GETBASEFRAME, vc, frame); }
inline int virtSetObservationFrame(VirtContext vc, float *frame) { return (int)virtCallDLL(SETOBSERVATIONFRAME, vc, frame); }
inline int virtGetObservationFrame(VirtContext vc, float *frame) { return (int)virtCallDLL(GETOBSERVATIONFRAME, vc, frame); }
inline int virtSetObservationFrameSpeed(VirtContext vc, float *twist) { return (int)virtCallDLL(SETOBSERVATIONFRAMESPEED, vc, twist); }
inline int virtSetCatchFrame(VirtContext vc, float *frame) { return (int)virtCallDLL(SETCATCHFRAME, vc, frame); }
inline int virtGetCatchFrame(VirtContext vc, float *frame) { return (int)virtCallDLL(GETCATCHFRAME, vc, frame); }
inline int virtGetNbAxes(VirtContext vc, int *axes) { return (int)virtCallDLL(GETNBAXES, vc, axes); }

/* Power, safety, buttons */
inline int virtSetPowerOn(VirtContext vc, int on) { return (int)virtCallDLL(SETPOWERON, vc, &on); }
inline int virtGetPowerOn(VirtContext vc, int *on) { return (int)virtCallDLL(GETPOWERON, vc, on); }
inline int virtGetDeadMan(VirtContext vc, int *held) { return (int)virtCallDLL(GETDEADMAN, vc, held); }
inline int virtGetEmergencyStop(VirtContext vc, int *released) { return (int)virtCallDLL(GETEMERGENCYSTOP, vc, released); }
inline int virtGetAlarm(VirtContext vc, unsigned int *alarms) { return (int)virtCallDLL(ALARM, vc, alarms); }
inline int virtGetFailure(VirtContext vc, unsigned int *failures) { return (int)virtCallDLL(BREAKDOWN, vc, failures); }
inline int virtIsInBounds(VirtContext vc, unsigned int *bounds) { return (int)virtCallDLL(BOUNDS, vc, bounds); }
inline int virtGetButton(VirtContext vc, int button, int *pressed) { return (int)virtCallDLL(GETBUTTON, vc, &button, pressed); }
inline int virtWaitPressButton(VirtContext vc, int button) { return (int)virtCallDLL(WAITBUTTON, vc, &button); }
inline int virtIsInShiftPosition(VirtContext vc, int *shift) { return (int)virtCallDLL(SHIFTPOSITION, vc, shift); }
inline int virtForceShiftButton(VirtContext vc, int shift) { return (int)virtCallDLL(FORCESHIFTBUTTON, vc, &shift); }

/* Virtual object, Cartesian streams */
inline int virtAttachVO(VirtContext vc, float mass, float *inertia) { return (int)virtCallDLL(ATTACHVO, vc, &mass, inertia); }
inline int virtAttachVOAvatar(VirtContext vc, float mass, float *inertia) { return (int)virtCallDLL(ATTACHVOAVATAR, vc, &mass, inertia); }
inline int virtAttachQSVO(VirtContext vc, float *stiffness, float *damping) { return (int)virtCallDLL(ATTACHQSVO, vc, stiffness, damping); }
inline int virtDetachVO(VirtContext vc) { return (int)virtCallDLL(DETACHVO, vc); }
inline int virtDetachVOAvatar(VirtContext vc) { return (int)virtCallDLL(DETACHVOAVATAR, vc); }
inline int virtSetPosition(VirtContext vc, float *pose) { return (int)virtCallDLL(SETPOSITION, vc, pose); }
inline int virtSetSpeed(VirtContext vc, float *twist) { return (int)virtCallDLL(SETSPEED, vc, twist); }
inline int virtSetForce(VirtContext vc, float *wrench) { return (int)virtCallDLL(SETFORCE, vc, wrench); }
inline int virtAddForce(VirtContext vc, float *wrench) { return (int)virtCallDLL(ADDPHYSICALFORCE, vc, wrench); }
inline int virtGetPosition(VirtContext vc, float *pose) { return (int)virtCallDLL(GETPOSITION, vc, pose); }
inline int virtGetSpeed(VirtContext vc, float *twist) { return (int)virtCallDLL(GETSPEED, vc, twist); }
inline int virtGetForce(VirtContext vc, float *wrench) { return (int)virtCallDLL(GETFORCE, vc, wrench); }
inline int virtGetAvatarPosition(VirtContext vc, float *pose) { return (int)virtCallDLL(AVATARPOSITION, vc, pose); }
inline int virtGetPhysicalPosition(VirtContext vc, float *pose) { return (int)virtCallDLL(PHYSICALPOSITION, vc, pose); }
inline int virtGetPhysicalSpeed(VirtContext vc, float *twist) { return (int)virtCallDLL(PHYSICALSPEED, vc, twist); }
inline int virtGetTimeLastUpdate(VirtContext vc, unsigned int *time) { return (int)virtCallDLL(GETTIMELASTUPDATE, vc, time); }
inline int virtSaturateTorque(VirtContext vc, float force, float torque) { return (int)virtCallDLL(SATURATETORQUE, vc, &force, &torque); }
inline int virtEnableForceFeedback(VirtContext vc, int enable) { return (int)virtCallDLL(ENABLEFORCEFEEDBACK, vc, &enable); }
inline int virtGetSimulationStiffness(VirtContext vc, float *stiffness) { return (int)virtCallDLL(GETSIMULATIONSTIFFNESS, vc, stiffness); }
inline int virtGetSimulationDamping(VirtContext vc, float *damping) { return (int)virtCallDLL(GETSIMULATIONDAMPING, vc, damping); }

/* Joint space */
inline int virtGetArticularPosition(VirtContext vc, float *q) { return (int)virtCallDLL(GETARTICULARPOSITION, vc, q); }
inline int virtGetArticularSpeed(VirtContext vc, float *dq) { return (int)virtCallDLL(GETARTICULARSPEED, vc, dq); }
inline int virtSetArticularPosition(VirtContext vc, float *q) { return (int)virtCallDLL(SETARTICULARPOSITION, vc, q); }
inline int virtSetArticularSpeed(VirtContext vc, float *dq) { return (int)virtCallDLL(SETARTICULARSPEED, vc, dq); }
inline int virtSetArticularForce(VirtContext vc, float *torques) { return (int)virtCallDLL(SETARTICULARFORCE, vc, torques); }
inline int virtGetArticularPositionOfAdditionalAxe(VirtContext vc, float *q) { return (int)virtCallDLL(GETARTICULARPOSITIONOFADDITIONALAXE, vc, q); }
inline int virtGetArticularSpeedOfAdditionalAxe(VirtContext vc, float *dq) { return (int)virtCallDLL(GETARTICULARSPEEDOFADDITIONALAXE, vc, dq); }
inline int virtSetArticularPositionOfAdditionalAxe(VirtContext vc, float *q) { return (int)virtCallDLL(SETARTICULARPOSITIONOFADDITIONALAXE, vc, q); }
inline int virtSetArticularSpeedOfAdditionalAxe(VirtContext vc, float *dq) { return (int)virtCallDLL(SETARTICULARSPEEDOFADDITIONALAXE, vc, dq); }
inline int virtSetArticularForceOfAdditionalAxe(VirtContext vc, float *torque) { return (int)virtCallDLL(SETARTICULARFORCEOFADDITIONALAXE, vc, torque); }

/* Periodic callback, trajectory recording */
inline int virtSetPeriodicFunction(VirtContext vc, void (*fn)(VirtContext, void *), float *period, void *arg) { return (int)virtCallDLL(SETPERIODICFUNCTION, vc, fn, period, arg); }
inline int virtStartLoop(VirtContext vc) { return (int)virtCallDLL(STARTLOOP, vc); }
inline int virtStopLoop(VirtContext vc) { return (int)virtCallDLL(STOPLOOP, vc); }
inline int virtTrajRecordStart(VirtContext vc) { return (int)virtCallDLL(TRAJRECORDSTART, vc); }
inline int virtTrajRecordStop(VirtContext vc) { return (int)virtCallDLL(TRAJRECORDSTOP, vc); }
inline int virtTrajSetSamplingTimeStep(VirtContext vc, float step, unsigned int *duration) { return (int)virtCallDLL(TRAJTIMESTEP, vc, &step, duration); }

/* Conversions */
inline int virtConvertDeplToHomogeneMatrix(VirtContext vc, float *displacement, float *matrix) { return (int)virtCallDLL(DEPLTOMATRIX, vc, displacement, matrix); }
inline int virtConvertHomogeneMatrixToDepl(VirtContext vc, float *displacement, float *matrix) { return (int)virtCallDLL(MATRIXTODEPL, vc, displacement, matrix); }
inline int virtConvertRGBToGrayscale(VirtContext vc, float *rgb, float *gray) { return (int)virtCallDLL(RGBTOGRAYSCALE, vc, rgb, gray); }

/* Speed control, textures, gripper */
inline int virtActiveSpeedControl(VirtContext vc, float radius, float factor) { return (int)virtCallDLL(ACTIVESPEEDCONTROL, vc, &radius, &factor); }
inline int virtDeactiveSpeedControl(VirtContext vc) { return (int)virtCallDLL(DESACTIVESPEEDCONTROL, vc); }
inline int virtActiveRotationSpeedControl(VirtContext vc, float angle, float factor) { return (int)virtCallDLL(ACTIVEROTATIONSPEEDCONTROL, vc, &angle, &factor); }
inline int virtDeactiveRotationSpeedControl(VirtContext vc) { return (int)virtCallDLL(DESACTIVEROTATIONSPEEDCONTROL, vc); }
inline int virtIsInSpeedControl(VirtContext vc, int *translation, int *rotation) { return (int)virtCallDLL(ISINSPEEDCONTROL, vc, translation, rotation); }
inline int virtSetForceInSpeedControl(VirtContext vc, float force) { return (int)virtCallDLL(FORCEINSPEEDCONTROL, vc, &force); }
inline int virtSetTorqueInSpeedControl(VirtContext vc, float torque) { return (int)virtCallDLL(TORQUEINSPEEDCONTROL, vc, &torque); }
inline int virtGetCenterSphere(VirtContext vc, float *center) { return (int)virtCallDLL(CENTERSPEEDCONTROL, vc, center); }
inline int virtGetAxisOfRotation(VirtContext vc, float *axis) { return (int)virtCallDLL(AXEROTATION, vc, axis); }
inline int virtSetTexture(VirtContext vc, float *pose, float *intensity, int reset) { return (int)virtCallDLL(SETTEXTURE, vc, pose, intensity, &reset); }
inline int virtSetTextureForce(VirtContext vc, float *wrench) { return (int)virtCallDLL(SETTEXTUREFORCE, vc, wrench); }
inline int virtSetGripperCommandType(VirtContext vc, VirtGripperCommandType type) { return (int)virtCallDLL(SETGRIPPERCOMMANDTYPE, vc, &type); }
inline int virtSetFingerTipSpeed(VirtContext vc, float *speed) { return (int)virtCallDLL(FINGERTIPSPEED, vc, speed); }

/* Inputs and outputs */
inline int virtGetADC(VirtContext vc, int line, float *value) { return (int)virtCallDLL(GETADC, vc, &line, value); }
inline int virtGetAnalogicInputs(VirtContext vc, float *values) { return (int)virtCallDLL(ANA_INPUTS, vc, values); }
inline int virtGetTorInputs(VirtContext vc, unsigned int *bits) { return (int)virtCallDLL(TOR_INPUTS, vc, bits); }
inline int virtOutputsSetting(VirtContext vc, unsigned int bits) { return (int)virtCallDLL(OUTPUTSSETTING, vc, &bits); }
inline int virtSetPwmOutput(VirtContext vc, float *duty) { return (int)virtCallDLL(SETPWM, vc, duty); }
inline int virtGetMouseState(VirtContext vc, int *active, int *left, int *right) { return (int)virtCallDLL(MOUSE, vc, active, left, right); }
inline int virtGetTrackball(VirtContext vc, int *dx, int *dy) { return (int)virtCallDLL(GETTRACKBALL, vc, dx, dy); }
inline int virtGetTrackballButton(VirtContext vc, int *active, int *left, int *middle, int *right) { return (int)virtCallDLL(GETTRACKBALLBUTTON, vc, active, left, middle, right); }

/* Virtual mechanisms */
inline int virtVmActivate(VirtContext vc) { return (int)virtCallDLL(VMACTIVATE, vc); }
inline int virtVmDeactivate(VirtContext vc) { return (int)virtCallDLL(VMDEACTIVATE, vc); }
inline int virtVmSetType(VirtContext vc, VirtVmType type) { return (int)virtCallDLL(VMSETTYPE, vc, &type); }
inline int virtVmSetBaseFrame(VirtContext vc, float *frame) { return (int)virtCallDLL(VMSETBASEFRAME, vc, frame); }
inline int virtVmGetBaseFrame(VirtContext vc, float *frame) { return (int)virtCallDLL(VMGETBASEFRAME, vc, frame); }
inline int virtVmSetBaseFrameToCurrentFrame(VirtContext vc) { return (int)virtCallDLL(VMSETBASEFRAMETOCURRENTFRAME, vc); }
inline int virtVmSetDefaultToCartesianPosition(VirtContext vc) { return (int)virtCallDLL(VMSETCARTESIANPOSITION, vc); }
inline int virtVmSetDefaultToTransparentMode(VirtContext vc) { return (int)virtCallDLL(VMSETTRANSPARENTMODE, vc); }
inline int virtVmSetRobotMode(VirtContext vc, int on) { return (int)virtCallDLL(VMSETROBOTMODE, vc, &on); }
inline int virtVmStartTrajSampling(VirtContext vc, unsigned int samples) { return (int)virtCallDLL(STARTTRAJSAMPLING, vc, &samples); }
inline int virtVmGetTrajSamples(VirtContext vc, float *samples) { return (int)virtCallDLL(TRAJSAMPLES, vc, samples); }
inline int virtVmWaitUpperBound(VirtContext vc) { return (int)virtCallDLL(VMUPPERBOUND, vc); }
inline int virtVmLoadSpline(VirtContext vc, char *path) { return (int)virtCallDLL(VMLOADSPLINE, vc, path); }
inline int virtVmSaveCurrentSpline(VirtContext vc, char *path) { return (int)virtCallDLL(VMSAVESPLINE, vc, path); }
inline int virtVmDeleteSpline(VirtContext vc, char *path) { return (int)virtCallDLL(VMDELETESPLINE, vc, path); }

/* Codes of virtGetErrorCode (3.x has no 22, VIRT_E_ALREADY_CALLED). */
#define VIRT_E_NO_ERROR               0
#define VIRT_E_OUT_OF_MEMORY          1
#define VIRT_E_COMMUNICATION_FAILURE  2
#define VIRT_E_INVALID_CONTEXT        3
#define VIRT_E_FILE_NOT_FOUND         4
#define VIRT_E_WRONG_FORMAT           5
#define VIRT_E_TIME_OUT               6
#define VIRT_E_NOT_IMPLEMENTED        7
#define VIRT_E_VARIABLE_NOT_AVAILABLE 8
#define VIRT_E_INCORRECT_VALUE        9
#define VIRT_E_SYNTAX_ERROR           10
#define VIRT_E_HARDWARE_ERROR         11
#define VIRT_E_POSITION_DISCONTINUITY 12
#define VIRT_E_VIRTUOSE_DLL_NOT_FOUND 13
#define VIRT_E_PERIODIC_FUNCTION      14
#define VIRT_E_PERFORMANCE_COUNTER    15
#define VIRT_E_MAJOR_MINOR_VERSION    16
#define VIRT_E_WRONG_MODE             17
#define VIRT_E_MODE_NOT_SUPPORTED     18
#define VIRT_E_CALL_TIME              19
#define VIRT_E_INCOMPATIBLE_VERSION   20
#define VIRT_E_INCORRECT_VM_TYPE      21

#define VIRT_ALARM_OVERHEAT          0x00004000
#define VIRT_ALARM_SATURATE          0x00008000
#define VIRT_ALARM_CALLBACK_OVERRUN  0x00020000
#define VIRT_ALARM_ERROR_POSITION    0x00040000
#define VIRT_ALARM_LOW_BATTERY       0x00100000

#ifdef __cplusplus
}
#endif

#endif /* HAPTICCTRL_TEST_VIRTUOSE3_H */
