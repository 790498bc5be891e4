/*
 * periodic.c - a VirtuoseAPI client in the periodic-callback style, written
 * against Haption's declarations only (VirtuoseAPI.h): impedance mode, the
 * library calls back every time step of the controller (paced by its
 * answers); the callback reads the handle's physical position and pushes it
 * back toward where it started with a spring (virtSetForce), saturated by
 * virtSaturateTorque.
 *
 *   cc -I include periodic.c libvirtuose_api.a -lpthread -ldl -lm -o periodic
 *   ./periodic 127.0.0.1#5000 [milliseconds]
 *
 * Exit status 0 when the callback ran and no VirtuoseAPI call failed.
 */
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "VirtuoseAPI.h"

struct loop_data {
    int calls;
    int errors;
    int have_anchor;
    float anchor[7];
    float last_force[6];
};

static void on_period(VirtContext vc, void *arg)
{
    struct loop_data *d = (struct loop_data *)arg;
    float pos[7], speed[6], force[6] = { 0, 0, 0, 0, 0, 0 };
    const float k = 200.0f, b = 2.0f; /* N/m, N.s/m */

    d->calls++;
    if (virtGetPhysicalPosition(vc, pos) || virtGetPhysicalSpeed(vc, speed)) {
        d->errors++;
        return;
    }
    if (!d->have_anchor) {
        for (int i = 0; i < 7; i++)
            d->anchor[i] = pos[i];
        d->have_anchor = 1;
    }
    for (int i = 0; i < 3; i++)
        force[i] = -k * (pos[i] - d->anchor[i]) - b * speed[i];
    if (virtSetForce(vc, force))
        d->errors++;
    for (int i = 0; i < 6; i++)
        d->last_force[i] = force[i];
}

static int fail(const char *what)
{
    int code = virtGetErrorCode(NULL);
    fprintf(stderr, "%s failed: %s (code %d)\n", what, virtGetErrorMessage(code), code);
    return 1;
}

int main(int argc, char **argv)
{
    const char *addr = argc > 1 ? argv[1] : "127.0.0.1#5000";
    int ms = argc > 2 ? atoi(argv[2]) : 1000;
    float dt = 0.001f;
    struct loop_data d = { 0 };
    struct timespec run = { ms / 1000, (ms % 1000) * 1000000L };
    int major = 0, minor = 0, axes = 0;
    unsigned int alarm = 0, bounds = 0;
    float q[6];

    virtAPIVersion(&major, &minor);
    printf("VirtuoseAPI %d.%d\n", major, minor);
    VirtContext vc = virtOpen(addr);
    if (!vc)
        return fail("virtOpen");
    if (virtGetControlerVersion(vc, &major, &minor) || virtGetNbAxes(vc, &axes))
        return fail("versions");
    printf("controller %d.%d, %d axes\n", major, minor, axes);
    if (virtSetIndexingMode(vc, INDEXING_ALL) || virtSetTimeStep(vc, dt) ||
        virtSetCommandType(vc, COMMAND_TYPE_IMPEDANCE) || virtSaturateTorque(vc, 5.0f, 0.3f) ||
        virtSetPowerOn(vc, 1))
        return fail("configuration");
    if (virtSetPeriodicFunction(vc, on_period, &dt, &d) || virtStartLoop(vc))
        return fail("starting the loop");
    nanosleep(&run, NULL);
    if (virtStopLoop(vc))
        return fail("virtStopLoop");
    if (virtGetAlarm(vc, &alarm) || virtGetArticularPosition(vc, q) || virtIsInBounds(vc, &bounds))
        return fail("status");
    printf("calls=%d errors=%d overrun=%d last force=(%.2f %.2f %.2f) N\n", d.calls, d.errors,
           (alarm & VIRT_ALARM_CALLBACK_OVERRUN) != 0, d.last_force[0], d.last_force[1], d.last_force[2]);
    printf("joints=(%.3f %.3f %.3f %.3f %.3f %.3f) bounds=0x%x\n", q[0], q[1], q[2], q[3], q[4], q[5],
           bounds);
    if (virtSetPowerOn(vc, 0) || virtClose(vc))
        return fail("power off and close");
    if (d.calls == 0 || d.errors != 0) {
        fprintf(stderr, "the callback did not run cleanly\n");
        return 1;
    }
    printf("OK\n");
    return 0;
}
