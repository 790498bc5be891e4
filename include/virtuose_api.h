/*
 * virtuose_api.h - C interface of the hapticctrl client library
 * (Rust crate userspace/virtuose_api): Haption's VirtuoseAPI (VirtuoseAPI.h,
 * included here) plus hapticctrl's extensions and the names of its first
 * header.
 *
 * Link with the static library (userspace/target/<profile>/libvirtuose_api.a,
 * plus -lpthread -ldl -lm) or the shared one (libvirtuose_api.so).
 *
 * Conventions:
 *  - every function returns 0 on success and -1 on error (virtOpen: NULL);
 *    the error is then given by virtGetErrorCode() / virtGetErrorMessage()
 *    (kept per context; with a NULL context, per calling thread; VIRT_E_*
 *    codes of VirtuoseAPI.h);
 *  - position float[7] = x, y, z (m), qx, qy, qz, qw (unit quaternion,
 *    scalar last); speed float[6] = vx, vy, vz (m/s), wx, wy, wz (rad/s);
 *    force float[6] = fx, fy, fz (N), tx, ty, tz (N.m);
 *  - virtSetSpeed() stores the virtual object's twist, virtSetPosition()
 *    sends one frame with the pose and that twist: call virtSetSpeed first.
 */
#ifndef VIRTUOSE_API_H
#define VIRTUOSE_API_H

#include "VirtuoseAPI.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Names of hapticctrl's first header, as aliases of VirtuoseAPI's codes. */
#define VIRT_E_INVALID_ADDRESS   VIRT_E_SYNTAX_ERROR
#define VIRT_E_SOCKET            VIRT_E_COMMUNICATION_FAILURE
#define VIRT_E_TIMEOUT           VIRT_E_TIME_OUT
#define VIRT_E_REFUSED           VIRT_E_WRONG_MODE
#define VIRT_E_INVALID_ARGUMENT  VIRT_E_INCORRECT_VALUE
#define VIRT_E_NO_DATA           VIRT_E_VARIABLE_NOT_AVAILABLE
#define VIRT_E_CLOSED            VIRT_E_INVALID_CONTEXT
#define VIRT_E_NULL_POINTER      VIRT_E_INVALID_CONTEXT

/* virtOpen (declared in VirtuoseAPI.h): "host#port" (port defaults to 5000).
 * Authenticated (protocol v2) with a pre-shared key file (hapctl keygen,
 * mode 0600): "host#port?key=/path/to/key", or the file named by the
 * environment variable HAP_KEY_FILE. Without a key: unauthenticated v1,
 * which the bridge refuses unless it runs with --insecure. */

/* hapticctrl extension: answers/s, loss ratio (0..1), last round trip (ms). */
int virtGetLinkStats(VirtContext vc, float *rate_hz, float *loss_ratio, float *rtt_ms);

/* hapticctrl extension: periods of the callback loop that overran since the
 * loop started (the VIRT_ALARM_CALLBACK_OVERRUN events). */
int virtGetCallbackOverruns(VirtContext vc, unsigned int *overruns);

#ifdef __cplusplus
}
#endif

#endif /* VIRTUOSE_API_H */
