/*
 * VirtuoseAPI.h - hapticctrl's drop-in declaration of Haption's VirtuoseAPI
 * (4.x): the same names, types, enum and macro values, so an application
 * written for Haption's library recompiles unchanged and links against
 * hapticctrl's libvirtuose_api (userspace/virtuose_api), also installed
 * under Haption's names (scripts/install-virtuose-api.sh: libvirtuose,
 * libVirtuoseAPI, libvirtuoseDLL, virtuoseAPI.so; this header also as
 * virtuoseAPI.h):
 *
 *   cc -I include app.c userspace/target/release/libvirtuose_api.a \
 *      -lpthread -ldl -lm
 *   cc app.c -lvirtuose          (installed)
 *
 * Every function returns 0 on success and -1 on error (virtOpen: NULL);
 * virtGetErrorCode(VC) then gives the code of the last call on the context
 * (virtGetErrorCode(NULL): of the calling thread's last call, e.g. a failed
 * virtOpen), explained by virtGetErrorMessage(). Functions that have no meaning on
 * hapticctrl (gloves, trackball, PWM and analog outputs, virtual-mechanism
 * splines, speed control, textures, articular commands) fail with
 * VIRT_E_NOT_IMPLEMENTED. Documentation/userguide.md lists the status of
 * every function and hapticctrl's conventions (frames, units, matrices).
 *
 * hapticctrl's own extensions are in virtuose_api.h (which includes this file).
 */
#ifndef _VirtuoseAPI_h
#define _VirtuoseAPI_h

#include <stdio.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef void *VirtContext;
typedef void (*VirtPeriodicFunction)(VirtContext, void *);

typedef enum {
    COMMAND_TYPE_NONE = 0,                /* no coupling */
    COMMAND_TYPE_IMPEDANCE = 3,           /* application sends forces, reads positions */
    COMMAND_TYPE_VIRTMECH = 5,            /* application sends positions, reads forces */
    COMMAND_TYPE_ARTICULAR = 6,           /* joint position control */
    COMMAND_TYPE_ARTICULAR_IMPEDANCE = 7  /* joint force control */
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
    VM_TYPE_CartMotion = 0,
    VM_TYPE_Spline = 1,
    VM_TYPE_Rx = 2,
    VM_TYPE_Tx = 3,
    VM_TYPE_TxRx = 4,
    VM_TYPE_TxTyTz = 5,
    VM_TYPE_RxRyRz = 6,
    VM_TYPE_TxTy = 7,
    VM_TYPE_Crank = 8
} VirtVmType;

/* virtSetDebugFlags */
#define DEBUG_SERVO 0x0001
#define DEBUG_LOOP  0x0002

/* Error codes (virtGetErrorCode) */
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
#define VIRT_E_ALREADY_CALLED         22

/* Joint bounds (virtIsInBounds) */
#define VIRT_BOUND_LEFT_AXE_1   0x0001
#define VIRT_BOUND_RIGHT_AXE_1  0x0002
#define VIRT_BOUND_SUP_AXE_2    0x0004
#define VIRT_BOUND_INF_AXE_2    0x0008
#define VIRT_BOUND_SUP_AXE_3    0x0010
#define VIRT_BOUND_INF_AXE_3    0x0020
#define VIRT_BOUND_RIGHT_AXE_4  0x0040
#define VIRT_BOUND_LEFT_AXE_4   0x0080
#define VIRT_BOUND_SUP_AXE_5    0x0100
#define VIRT_BOUND_INF_AXE_5    0x0200
#define VIRT_BOUND_LEFT_AXE_6   0x0400
#define VIRT_BOUND_RIGHT_AXE_6  0x0800
#define VIRT_BOUND_INF_AXE_2_3  0x1000
#define VIRT_BOUND_SUP_AXE_2_3  0x2000

/* Alarms (virtGetAlarm) */
#define VIRT_ALARM_OVERHEAT          0x00004000
#define VIRT_ALARM_SATURATE          0x00008000
#define VIRT_ALARM_CALLBACK_OVERRUN  0x00020000
#define VIRT_ALARM_ERROR_POSITION    0x00040000
#define VIRT_ALARM_LOW_BATTERY       0x00100000

/* Failures (virtGetFailure) */
#define VIRT_BREAKDOWN_MOTOR_1 0x0001
#define VIRT_BREAKDOWN_MOTOR_2 0x0002
#define VIRT_BREAKDOWN_MOTOR_3 0x0004
#define VIRT_BREAKDOWN_MOTOR_4 0x0008
#define VIRT_BREAKDOWN_MOTOR_5 0x0010
#define VIRT_BREAKDOWN_MOTOR_6 0x0020
#define VIRT_BREAKDOWN_MOTOR_7 0x0040
#define VIRT_BREAKDOWN_MOTOR_8 0x0080

/* Aliases of the 4.x header */
#define virtConvertDisplToTransformationMatrix virtConvertDeplToHomogeneMatrix
#define virtConvertTransformationMatrixToDispl virtConvertHomogeneMatrixToDepl
#define virtGetDigitalInputs virtGetTorInputs

/* Session */
extern VirtContext virtOpen(const char *nom);
extern int virtClose(VirtContext VC);
extern int virtAPIVersion(int *major, int *minor);
extern int virtGetControlerVersion(VirtContext VC, int *major, int *minor);
extern int virtGetDeviceID(VirtContext VC, int *device_type, int *serial_number);
extern int virtGetErrorCode(VirtContext VC);
extern char *virtGetErrorMessage(int code);
extern int virtGetError(VirtContext VC, int *error);
extern int virtSetTimeoutValue(VirtContext VC, float time_value);
extern int virtGetTimeoutValue(VirtContext VC, float *time_value);
extern int virtSetDebugFlags(VirtContext VC, unsigned short flag);
extern int virtSetOutputFile(VirtContext VC, char *name);
extern int virtDisplayHardwareStatus(VirtContext VC, FILE *fichier);
extern int virtDisableControlConnexion(VirtContext VC, int disable);

/* Configuration and its getters */
extern int virtSetTimeStep(VirtContext VC, float step);
extern int virtGetTimeStep(VirtContext VC, float *step);
extern int virtSetCommandType(VirtContext VC, VirtCommandType type);
extern int virtGetCommandType(VirtContext VC, VirtCommandType *type);
extern int virtSetIndexingMode(VirtContext VC, VirtIndexingType indexing_mode);
extern int virtGetIndexingMode(VirtContext VC, VirtIndexingType *indexing_mode);
extern int virtSetForceFactor(VirtContext VC, float force_factor);
extern int virtGetForceFactor(VirtContext VC, float *force_factor);
extern int virtSetSpeedFactor(VirtContext VC, float speed_factor);
extern int virtGetSpeedFactor(VirtContext VC, float *speed_factor);
extern int virtSetBaseFrame(VirtContext VC, float *base);
extern int virtGetBaseFrame(VirtContext VC, float *base);
extern int virtSetObservationFrame(VirtContext VC, float *obs);
extern int virtGetObservationFrame(VirtContext VC, float *obs);
extern int virtSetObservationFrameSpeed(VirtContext VC, float *speed);
extern int virtSetCatchFrame(VirtContext VC, float *frame);
extern int virtGetCatchFrame(VirtContext VC, float *frame);
extern int virtGetNbAxes(VirtContext VC, int *nbAxes);

/* Power, safety, buttons */
extern int virtSetPowerOn(VirtContext VC, int power);
extern int virtGetPowerOn(VirtContext VC, int *power);
extern int virtGetDeadMan(VirtContext VC, int *dead_man);
extern int virtGetEmergencyStop(VirtContext VC, int *emergency_stop);
extern int virtGetAlarm(VirtContext VC, unsigned int *alarm);
extern int virtGetFailure(VirtContext VC, unsigned int *error);
extern int virtIsInBounds(VirtContext VC, unsigned int *bounds);
extern int virtGetButton(VirtContext VC, int button_number, int *state);
extern int virtWaitPressButton(VirtContext VC, int button_number);
extern int virtForceShiftButton(VirtContext VC, int forceShiftButton);
extern int virtIsInShiftPosition(VirtContext VC, int *decalage);

/* Virtual object and cartesian streams */
extern int virtAttachVO(VirtContext VC, float mass, float *mxmymz);
extern int virtAttachVOAvatar(VirtContext VC, float mass, float *mxmymz);
extern int virtAttachQSVO(VirtContext VC, float *Ks, float *Bs);
extern int virtDetachVO(VirtContext VC);
extern int virtDetachVOAvatar(VirtContext VC);
extern int virtSetPosition(VirtContext VC, float *pos);
extern int virtSetSpeed(VirtContext VC, float *speed);
extern int virtSetForce(VirtContext VC, float *force);
extern int virtAddForce(VirtContext VC, float *force);
extern int virtGetPosition(VirtContext VC, float *pos);
extern int virtGetSpeed(VirtContext VC, float *speed);
extern int virtGetForce(VirtContext VC, float *force);
extern int virtGetAvatarPosition(VirtContext VC, float *pos);
extern int virtGetPhysicalPosition(VirtContext VC, float *pos);
extern int virtGetPhysicalSpeed(VirtContext VC, float *speed);
extern int virtGetTimeLastUpdate(VirtContext VC, unsigned int *time);
extern int virtSaturateTorque(VirtContext VC, float forceThreshold, float momentThreshold);
extern int virtEnableForceFeedback(VirtContext VC, int enable);
extern int virtGetSimulationStiffness(VirtContext VC, float *stiffness);
extern int virtGetSimulationDamping(VirtContext VC, float *damping);

/* Joint space */
extern int virtGetArticularPosition(VirtContext VC, float *pos);
extern int virtGetArticularSpeed(VirtContext VC, float *speed);
extern int virtSetArticularPosition(VirtContext VC, float *pos);
extern int virtSetArticularSpeed(VirtContext VC, float *speed);
extern int virtSetArticularForce(VirtContext VC, float *force);
extern int virtGetArticularPositionOfAdditionalAxe(VirtContext VC, float *pos);
extern int virtGetArticularSpeedOfAdditionalAxe(VirtContext VC, float *speed);
extern int virtSetArticularPositionOfAdditionalAxe(VirtContext VC, float *pos);
extern int virtSetArticularSpeedOfAdditionalAxe(VirtContext VC, float *speed);
extern int virtSetArticularForceOfAdditionalAxe(VirtContext VC, float *effort);

/* Periodic callback */
extern int virtSetPeriodicFunction(VirtContext VC, void (*fn)(VirtContext, void *), float *period, void *arg);
extern int virtStartLoop(VirtContext VC);
extern int virtStopLoop(VirtContext VC);

/* Trajectory recording */
extern int virtTrajRecordStart(VirtContext VC);
extern int virtTrajRecordStop(VirtContext VC);
extern int virtTrajSetSamplingTimeStep(VirtContext VC, float timeStep, unsigned int *recordTime);

/* Conversions */
extern int virtConvertDeplToHomogeneMatrix(VirtContext VC, float *d, float *m);
extern int virtConvertHomogeneMatrixToDepl(VirtContext VC, float *d, float *m);
extern int virtConvertRGBToGrayscale(VirtContext VC, float *rgb, float *gray);

/* Speed control, textures, gripper */
extern int virtActiveSpeedControl(VirtContext VC, float radius, float speedFactor);
extern int virtDeactiveSpeedControl(VirtContext VC);
extern int virtActiveRotationSpeedControl(VirtContext VC, float angle, float speedFactor);
extern int virtDeactiveRotationSpeedControl(VirtContext VC);
extern int virtIsInSpeedControl(VirtContext VC, int *translation, int *rotation);
extern int virtSetForceInSpeedControl(VirtContext VC, float force);
extern int virtSetTorqueInSpeedControl(VirtContext VC, float torque);
extern int virtGetCenterSphere(VirtContext VC, float *pos);
extern int virtGetAxisOfRotation(VirtContext VC, float *axe);
extern int virtSetTexture(VirtContext VC, float *position, float *intensite, int reinit);
extern int virtSetTextureForce(VirtContext VC, float *texture_force);
extern int virtSetGripperCommandType(VirtContext VC, VirtGripperCommandType type);
extern int virtSetFingerTipSpeed(VirtContext VC, float *speed);

/* Inputs and outputs */
extern int virtGetADC(VirtContext VC, int line, float *adc);
extern int virtGetAnalogicInputs(VirtContext VC, float *inputs);
extern int virtGetTorInputs(VirtContext VC, unsigned int *tor_in);
extern int virtOutputsSetting(VirtContext VC, unsigned int outputs);
extern int virtSetPwmOutput(VirtContext VC, float *pwm);
extern int virtGetMouseState(VirtContext VC, int *actif, int *clic_gauche, int *clic_droit);
extern int virtGetTrackball(VirtContext VC, int *x_move, int *y_move);
extern int virtGetTrackballButton(VirtContext VC, int *actif, int *btn_gauche, int *btn_milieu, int *btn_droit);

/* Virtual mechanisms */
extern int virtVmActivate(VirtContext VC);
extern int virtVmDeactivate(VirtContext VC);
extern int virtVmSetType(VirtContext VC, VirtVmType type);
extern int virtVmSetBaseFrame(VirtContext VC, float *base);
extern int virtVmGetBaseFrame(VirtContext VC, float *base);
extern int virtVmSetBaseFrameToCurrentFrame(VirtContext VC);
extern int virtVmSetDefaultToCartesianPosition(VirtContext VC);
extern int virtVmSetDefaultToTransparentMode(VirtContext VC);
extern int virtVmSetRobotMode(VirtContext VC, int OnOff);
extern int virtVmStartTrajSampling(VirtContext VC, unsigned int nbSamples);
extern int virtVmGetTrajSamples(VirtContext VC, float *samples);
extern int virtVmWaitUpperBound(VirtContext VC);
extern int virtVmLoadSpline(VirtContext VC, char *file_name);
extern int virtVmSaveCurrentSpline(VirtContext VC, char *file_name);
extern int virtVmDeleteSpline(VirtContext VC, char *file_name);

#ifdef __cplusplus
}
#endif

#endif /* _VirtuoseAPI_h */
