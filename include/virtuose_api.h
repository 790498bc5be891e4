/*
 * virtuose_api.h - C interface of the hapticctrl client library
 * (Rust crate userspace/virtuose_api), modelled on Haption's VirtuoseAPI.
 *
 * Link with the static library (userspace/target/<profile>/libvirtuose_api.a,
 * plus -lpthread -ldl -lm) or the shared one (libvirtuose_api.so).
 *
 * Conventions:
 *  - every function returns 0 on success and -1 on error (virtOpen: NULL);
 *    the error is then given by virtGetErrorCode() / virtGetErrorMessage()
 *    (kept per calling thread);
 *  - position float[7] = x, y, z (m), qx, qy, qz, qw (unit quaternion,
 *    scalar last); speed float[6] = vx, vy, vz (m/s), wx, wy, wz (rad/s);
 *    force float[6] = fx, fy, fz (N), tx, ty, tz (N.m);
 *  - virtSetSpeed() stores the virtual object's twist, virtSetPosition()
 *    sends one frame with the pose and that twist: call virtSetSpeed first.
 */
#ifndef VIRTUOSE_API_H
#define VIRTUOSE_API_H

#ifdef __cplusplus
extern "C" {
#endif

typedef struct VirtContextS *VirtContext;

/* Error codes (virtGetErrorCode). */
#define VIRT_E_NO_ERROR          0
#define VIRT_E_INVALID_ADDRESS   1
#define VIRT_E_SOCKET            2
#define VIRT_E_TIMEOUT           3
#define VIRT_E_REFUSED           4
#define VIRT_E_INVALID_ARGUMENT  5
#define VIRT_E_NO_DATA           6
#define VIRT_E_CLOSED            7
#define VIRT_E_NULL_POINTER      8

/* virtSetCommandType */
#define COMMAND_TYPE_NONE       0
#define COMMAND_TYPE_IMPEDANCE  1
#define COMMAND_TYPE_VIRTMECH   2

/* virtSetIndexingMode */
#define INDEXING_ALL                             0
#define INDEXING_TRANS                           1
#define INDEXING_NONE                            2
#define INDEXING_ALL_FORCE_FEEDBACK_INHIBITION   3
#define INDEXING_TRANS_FORCE_FEEDBACK_INHIBITION 4

/* Open a session with the controller: "host#port" (port defaults to 5000).
 * Authenticated (protocol v2) with a pre-shared key file (hapctl keygen,
 * mode 0600): "host#port?key=/path/to/key", or the file named by the
 * environment variable HAP_KEY_FILE. Without a key: unauthenticated v1,
 * which the bridge refuses unless it runs with --insecure. */
VirtContext virtOpen(const char *name);
/* Close the session and free the context. */
int virtClose(VirtContext vc);

int virtSetTimeStep(VirtContext vc, float step);
int virtSetIndexingMode(VirtContext vc, unsigned short indexing_mode);
int virtSetForceFactor(VirtContext vc, float force_factor);
int virtSetSpeedFactor(VirtContext vc, float speed_factor);
int virtSetBaseFrame(VirtContext vc, const float *pos /* [7] */);
int virtSetObservationFrame(VirtContext vc, const float *pos /* [7] */);
int virtSetCommandType(VirtContext vc, unsigned short type);

int virtAttachVO(VirtContext vc, float mass, const float *mxmymz /* [3] */);
int virtDetachVO(VirtContext vc);

int virtSetPosition(VirtContext vc, const float *pos /* [7] */);
int virtSetSpeed(VirtContext vc, const float *speed /* [6] */);

int virtGetPosition(VirtContext vc, float *pos /* [7] */);
int virtGetSpeed(VirtContext vc, float *speed /* [6] */);
int virtGetForce(VirtContext vc, float *force /* [6] */);

int virtGetPowerOn(VirtContext vc, int *power);
int virtSetPowerOn(VirtContext vc, int power);
int virtGetDeadMan(VirtContext vc, int *dead_man);
int virtGetEmergencyStop(VirtContext vc, int *emergency_stop);
int virtGetAlarm(VirtContext vc, unsigned int *alarm);

/* hapticctrl extension: answers/s, loss ratio (0..1), last round trip (ms). */
int virtGetLinkStats(VirtContext vc, float *rate_hz, float *loss_ratio, float *rtt_ms);

/* Last error of the calling thread (vc may be NULL). */
int virtGetErrorCode(VirtContext vc);
/* Message for an error code; valid until the thread's next virt* call. */
const char *virtGetErrorMessage(int code);

#ifdef __cplusplus
}
#endif

#endif /* VIRTUOSE_API_H */
