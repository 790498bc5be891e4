/*
 * coupling.c - minimal C client of virtuose_api: opens a session, performs
 * the initialisation (time step, frames, factors, command type, virtual
 * object, power), then runs a 1 kHz loop integrating a 1-D...3-D point mass
 * coupled to the handle, and prints what it saw.
 *
 *   cc -I include coupling.c libvirtuose_api.a -lpthread -ldl -lm -o coupling
 *   ./coupling 127.0.0.1#5000 [steps]
 *
 * Exit status 0 when the virtual object followed the handle.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "virtuose_api.h"

static int check(int rc, const char *what)
{
    if (rc != 0) {
        int code = virtGetErrorCode(NULL);
        fprintf(stderr, "%s failed: %s (code %d)\n", what, virtGetErrorMessage(code), code);
    }
    return rc;
}

int main(int argc, char **argv)
{
    const char *addr = argc > 1 ? argv[1] : "127.0.0.1#5000";
    int steps = argc > 2 ? atoi(argv[2]) : 2000;
    const float dt = 0.001f, mass = 0.2f;
    float identity[7] = { 0, 0, 0, 0, 0, 0, 1 };
    float inertia[3] = { 1e-3f, 1e-3f, 1e-3f };
    float pos[7] = { 0, 0, 0, 0, 0, 0, 1 }, speed[6] = { 0 };
    float handle[7], force[6];
    float rate = 0, loss = 0, rtt = 0;
    double max_err = 0, last_err = 0;
    int got = 0, power = 0;
    struct timespec tick = { 0, 1000000 };

    VirtContext vc = virtOpen(addr);
    if (!vc) {
        int code = virtGetErrorCode(NULL);
        fprintf(stderr, "virtOpen(%s) failed: %s (code %d)\n", addr, virtGetErrorMessage(code), code);
        return 2;
    }
    if (check(virtSetTimeStep(vc, dt), "virtSetTimeStep") ||
        check(virtSetBaseFrame(vc, identity), "virtSetBaseFrame") ||
        check(virtSetObservationFrame(vc, identity), "virtSetObservationFrame") ||
        check(virtSetForceFactor(vc, 1.0f), "virtSetForceFactor") ||
        check(virtSetSpeedFactor(vc, 1.0f), "virtSetSpeedFactor") ||
        check(virtSetIndexingMode(vc, INDEXING_ALL), "virtSetIndexingMode") ||
        check(virtSetCommandType(vc, COMMAND_TYPE_VIRTMECH), "virtSetCommandType") ||
        check(virtAttachVO(vc, mass, inertia), "virtAttachVO") ||
        check(virtSetPowerOn(vc, 1), "virtSetPowerOn")) {
        virtClose(vc);
        return 3;
    }
    /* A deliberate error: the message must explain it. */
    if (virtSetTimeStep(vc, -1.0f) == 0) {
        fprintf(stderr, "negative time step accepted\n");
        return 4;
    }
    printf("expected error: %s\n", virtGetErrorMessage(virtGetErrorCode(vc)));

    for (int i = 0; i < steps; i++) {
        virtSetSpeed(vc, speed);
        virtSetPosition(vc, pos);
        nanosleep(&tick, NULL);
        if (virtGetAvatarPosition(vc, handle) != 0 || virtGetForce(vc, force) != 0)
            continue;
        got++;
        /* semi-implicit Euler of the point mass under the coupling force */
        for (int k = 0; k < 3; k++) {
            speed[k] += force[k] / mass * dt;
            speed[k] *= 0.995f; /* a little viscous damping */
            pos[k] += speed[k] * dt;
        }
        last_err = sqrt(pow(handle[0] - pos[0], 2) + pow(handle[1] - pos[1], 2) + pow(handle[2] - pos[2], 2));
        if (i > steps / 2 && last_err > max_err)
            max_err = last_err;
    }
    virtGetPowerOn(vc, &power);
    virtGetLinkStats(vc, &rate, &loss, &rtt);
    printf("answers=%d power=%d handle=(%.4f %.4f %.4f) object=(%.4f %.4f %.4f) err=%.4f max_err=%.4f\n",
           got, power, handle[0], handle[1], handle[2], pos[0], pos[1], pos[2], last_err, max_err);
    printf("link: rate=%.0f Hz loss=%.3f%% rtt=%.3f ms\n", rate, loss * 100.0f, rtt);
    if (check(virtClose(vc), "virtClose"))
        return 5;
    if (got < steps / 2 || max_err > 0.02) {
        fprintf(stderr, "coupling failed\n");
        return 1;
    }
    printf("OK\n");
    return 0;
}
