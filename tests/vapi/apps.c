/*
 * apps.c - what applications written for Haption's VirtuoseAPI rely on,
 * against hapticctrl's library and a controller (tests/vapi/run.sh runs it
 * against the fake controller, built with each of the library's names).
 *
 *   apps HOST#PORT MS FIRST SECOND
 *
 * FIRST and SECOND: the states (0/1) the controller reports for the
 * handle's first and second buttons. For MS ms of callback loop
 * (IMPEDANCE), then of a quasi-static object (VIRTMECH), every cycle reads
 * buttons 1 and 2 (and 0, and one the handle does not have), the shift
 * state and the poses; getters are read right after their setters. After
 * virtClose, calls on the closed context and on two values virtOpen never
 * returned each fail with VIRT_E_INVALID_CONTEXT, within a second (they do
 * no I/O: a slower one is a hang, not noise; the slowest is printed).
 * Prints "ok - ..." / "not ok - ..." per check and "apps: N passed, N
 * failed".
 * Exit status 0 when every check passed. Valid C99 and C++. With
 * VIRTUOSE_SUBDIR defined it includes <virtuose/virtuoseAPI.h>.
 */
#ifdef VIRTUOSE_SUBDIR
#include <virtuose/virtuoseAPI.h>
#else
#include "virtuoseAPI.h"
#endif

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static int passed, failed;

static void check(int cond, const char *what)
{
    if (cond) {
        passed++;
        printf("ok - %s\n", what);
    } else {
        failed++;
        printf("not ok - %s\n", what);
    }
}

static void sleep_ms(long ms)
{
    struct timespec t;
    t.tv_sec = ms / 1000;
    t.tv_nsec = (ms % 1000) * 1000000L;
    nanosleep(&t, NULL);
}

/* What the callback saw, cycle after cycle. */
struct loop_state {
    int first, second;      /* expected button states */
    long calls;
    long call_failures;     /* a VirtuoseAPI call of the callback returned -1 */
    long state_unwritten;   /* a button state left as the callback set it */
    long button_mismatch;   /* a state other than the controller's */
    long shift_mismatch;
    long quasi_static;      /* the loop streams a quasi-static object's pose */
    float target[7];
};

static void callback(VirtContext vc, void *arg)
{
    struct loop_state *s = (struct loop_state *)arg;
    int b0 = -1, b1 = -1, b2 = -1, b7 = -1, shift = -1;
    float avatar[7], phys[7], force[6];
    s->calls++;
    /* Buttons as most applications read them: 1 and 2 every cycle. */
    if (virtGetButton(vc, 0, &b0) || virtGetButton(vc, 1, &b1) || virtGetButton(vc, 2, &b2) ||
        virtGetButton(vc, 7, &b7) || virtIsInShiftPosition(vc, &shift))
        s->call_failures++;
    if (b0 < 0 || b1 < 0 || b2 < 0 || b7 < 0 || shift < 0)
        s->state_unwritten++;
    if (b1 != s->first || b2 != s->second || b0 != s->first || b7 != 0)
        s->button_mismatch++;
    if (shift != s->first)
        s->shift_mismatch++;
    if (virtGetAvatarPosition(vc, avatar) || virtGetPhysicalPosition(vc, phys))
        s->call_failures++;
    if (s->quasi_static) {
        if (virtSetPosition(vc, s->target) || virtGetForce(vc, force))
            s->call_failures++;
    } else {
        /* A spring holding the handle 1 cm further along x. */
        float f[6] = { 0 };
        f[0] = 100.0f * 0.01f;
        if (virtSetForce(vc, f))
            s->call_failures++;
    }
}

static double now_s(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + (double)t.tv_nsec * 1e-9;
}

/* Calls on a context that is not open: each must return -1 with
 * VIRT_E_INVALID_CONTEXT, within a second. */
static void refused(VirtContext c, const char *what, struct loop_state *s)
{
    char line[256];
    float pose[7] = { 0, 0, 0, 0, 0, 0, 1 }, wrench[6] = { 0 }, ks[6] = { 0 }, dt = 0.001f;
    int v = 0, n = 0, wrong = 0;
    unsigned int bits = 0;
    double worst = 0.0;
#define REFUSED(call)                                                                   \
    do {                                                                                \
        double t0_ = now_s();                                                           \
        int r_ = (call);                                                                \
        double dt_ = now_s() - t0_;                                                     \
        int code_ = virtGetErrorCode(NULL);                                             \
        n++;                                                                            \
        if (dt_ > worst)                                                                \
            worst = dt_;                                                                \
        if (r_ != -1 || code_ != VIRT_E_INVALID_CONTEXT) {                              \
            wrong++;                                                                    \
            printf("# %s: %s returned %d, code %d\n", what, #call, r_, code_);         \
        }                                                                               \
    } while (0)
    REFUSED(virtGetPosition(c, pose));
    REFUSED(virtSetPosition(c, pose));
    REFUSED(virtGetAvatarPosition(c, pose));
    REFUSED(virtSetForce(c, wrench));
    REFUSED(virtGetButton(c, 1, &v));
    REFUSED(virtIsInShiftPosition(c, &v));
    REFUSED(virtForceShiftButton(c, 1));
    REFUSED(virtWaitPressButton(c, 1));
    REFUSED(virtSetPowerOn(c, 1));
    REFUSED(virtGetPowerOn(c, &v));
    REFUSED(virtGetAlarm(c, &bits));
    REFUSED(virtSetCommandType(c, COMMAND_TYPE_IMPEDANCE));
    REFUSED(virtSetIndexingMode(c, INDEXING_ALL));
    REFUSED(virtSetTimeStep(c, dt));
    REFUSED(virtAttachQSVO(c, ks, ks));
    REFUSED(virtDetachVO(c));
    REFUSED(virtSetPeriodicFunction(c, callback, &dt, s));
    REFUSED(virtStartLoop(c));
    REFUSED(virtStopLoop(c));
    REFUSED(virtClose(c));
#undef REFUSED
    snprintf(line, sizeof line, "%s: %d calls each return -1 with VIRT_E_INVALID_CONTEXT (%d not)", what, n, wrong);
    check(wrong == 0, line);
    snprintf(line, sizeof line, "%s: virtGetErrorCode reads VIRT_E_INVALID_CONTEXT", what);
    check(virtGetErrorCode(c) == VIRT_E_INVALID_CONTEXT, line);
    snprintf(line, sizeof line, "%s: every call returned within a second (slowest %.6f s)", what, worst);
    check(worst < 1.0, line);
}

static int same7(const float *a, const float *b)
{
    return memcmp(a, b, 7 * sizeof(float)) == 0;
}

int main(int argc, char **argv)
{
    char what[256];
    struct loop_state s;
    VirtContext vc;
    int major = 0, minor = 0, i, v = -1, ms;
    float f = 0.0f, dt = 0.002f, got[7], pos[7], avatar[7], force[6];
    /* Frames with a quaternion that is not exactly unit in float. */
    float base[7] = { 0.01f, 0.02f, 0.03f, 0.1f, 0.2f, 0.3f, 0.9273618f };
    float obs[7] = { 0.0f, 0.0f, 0.1f, 0.0f, 0.0f, 0.0f, 1.0f };
    float obs_speed[6] = { 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f };
    float ks[6] = { 1.0f, 1.0f, 1.0f, 100.0f, 100.0f, 100.0f };
    float bs[6] = { 0.01f, 0.01f, 0.01f, 1.0f, 1.0f, 1.0f };
    float identity[7] = { 0, 0, 0, 0, 0, 0, 1 };

    if (argc != 5) {
        fprintf(stderr, "usage: %s HOST#PORT MS FIRST SECOND\n", argv[0]);
        return 2;
    }
    ms = atoi(argv[2]);
    memset(&s, 0, sizeof s);
    s.first = atoi(argv[3]) != 0;
    s.second = atoi(argv[4]) != 0;

    check(virtAPIVersion(&major, &minor) == 0 && major == 4, "virtAPIVersion: 4.x");
    vc = virtOpen(argv[1]);
    if (!vc) {
        printf("not ok - virtOpen(%s): %s\n", argv[1], virtGetErrorMessage(virtGetErrorCode(NULL)));
        printf("apps: %d passed, %d failed\n", passed, failed + 1);
        return 1;
    }
    check(1, "virtOpen");

    /* Set-up as the applications do it, each getter right after its setter. */
    check(virtSetIndexingMode(vc, INDEXING_ALL) == 0, "virtSetIndexingMode(INDEXING_ALL)");
    {
        VirtIndexingType m = INDEXING_NONE;
        check(virtGetIndexingMode(vc, &m) == 0 && m == INDEXING_ALL, "virtGetIndexingMode reads INDEXING_ALL");
    }
    check(virtSetSpeedFactor(vc, 1.0f) == 0 && virtGetSpeedFactor(vc, &f) == 0 && f == 1.0f,
          "virtGetSpeedFactor reads what virtSetSpeedFactor set");
    check(virtSetForceFactor(vc, 1.0f) == 0 && virtGetForceFactor(vc, &f) == 0 && f == 1.0f,
          "virtGetForceFactor reads what virtSetForceFactor set");
    check(virtSetTimeStep(vc, dt) == 0 && virtGetTimeStep(vc, &f) == 0 && f == dt,
          "virtGetTimeStep reads what virtSetTimeStep set");
    check(virtSetBaseFrame(vc, base) == 0 && virtGetBaseFrame(vc, got) == 0 && same7(got, base),
          "virtGetBaseFrame reads the frame virtSetBaseFrame set");
    check(virtSetBaseFrame(vc, identity) == 0, "virtSetBaseFrame(identity)");
    check(virtSetObservationFrame(vc, obs) == 0 && virtGetObservationFrame(vc, got) == 0 && same7(got, obs),
          "virtGetObservationFrame reads the frame virtSetObservationFrame set");
    check(virtSetObservationFrameSpeed(vc, obs_speed) == 0, "virtSetObservationFrameSpeed");
    check(virtSetTimeoutValue(vc, 1.5f) == 0 && virtGetTimeoutValue(vc, &f) == 0 && f == 1.5f,
          "virtGetTimeoutValue reads what virtSetTimeoutValue set");
    check(virtSetCommandType(vc, COMMAND_TYPE_IMPEDANCE) == 0, "virtSetCommandType(COMMAND_TYPE_IMPEDANCE)");
    {
        VirtCommandType t = COMMAND_TYPE_NONE;
        check(virtGetCommandType(vc, &t) == 0 && t == COMMAND_TYPE_IMPEDANCE, "virtGetCommandType reads IMPEDANCE");
    }
    /* The error code belongs to the context. */
    check(virtSetTimeStep(vc, -1.0f) == -1 && virtGetErrorCode(vc) == VIRT_E_INCORRECT_VALUE,
          "a refused value: virtGetErrorCode(vc) is VIRT_E_INCORRECT_VALUE");
    check(virtGetTimeStep(vc, &f) == 0 && f == dt && virtGetErrorCode(vc) == 0,
          "the refused value left the time step; a success clears the context's code");

    /* Power: read right after it was set (the controller's answers lag). */
    check(virtSetPowerOn(vc, 1) == 0, "virtSetPowerOn(1)");
    v = -1;
    check(virtGetPowerOn(vc, &v) == 0 && v == 1, "virtGetPowerOn reads 1 right after virtSetPowerOn(1)");
    check(virtSaturateTorque(vc, 15.0f, 0.7f) == 0, "virtSaturateTorque");

    /* The callback loop (IMPEDANCE). */
    check(virtSetPeriodicFunction(vc, callback, &dt, &s) == 0, "virtSetPeriodicFunction");
    check(virtStartLoop(vc) == 0, "virtStartLoop");
    sleep_ms(ms);
    check(virtStopLoop(vc) == 0, "virtStopLoop");
    snprintf(what, sizeof what, "the callback ran (%ld calls)", s.calls);
    check(s.calls >= ms / 20, what);
    snprintf(what, sizeof what, "no VirtuoseAPI call of the callback failed (%ld failures)", s.call_failures);
    check(s.call_failures == 0, what);
    snprintf(what, sizeof what, "buttons 0, 1, 2, 7 wrote their state every cycle (%ld cycles not)", s.state_unwritten);
    check(s.state_unwritten == 0, what);
    snprintf(what, sizeof what, "buttons 1 and 2 read the handle's first and second (%d, %d; 0: the first, 7: 0) every cycle (%ld cycles not)",
             s.first, s.second, s.button_mismatch);
    check(s.button_mismatch == 0, what);
    snprintf(what, sizeof what, "virtIsInShiftPosition follows the first button (%ld cycles not)", s.shift_mismatch);
    check(s.shift_mismatch == 0, what);

    /* Forced shift. */
    v = -1;
    check(virtForceShiftButton(vc, 1) == 0 && virtIsInShiftPosition(vc, &v) == 0 && v == 1,
          "virtForceShiftButton(1): virtIsInShiftPosition reads 1");
    check(virtForceShiftButton(vc, 0) == 0 && virtIsInShiftPosition(vc, &v) == 0 && v == s.first,
          "virtForceShiftButton(0): virtIsInShiftPosition reads the button again");

    /* A quasi-static object (VIRTMECH), streamed from the loop. */
    check(virtSetCommandType(vc, COMMAND_TYPE_VIRTMECH) == 0, "virtSetCommandType(COMMAND_TYPE_VIRTMECH)");
    check(virtGetAvatarPosition(vc, avatar) == 0, "virtGetAvatarPosition");
    for (i = 0; i < 7; i++)
        s.target[i] = avatar[i];
    s.target[0] += 0.02f;
    s.quasi_static = 1;
    check(virtAttachQSVO(vc, ks, bs) == 0, "virtAttachQSVO");
    check(virtSetPosition(vc, s.target) == 0, "virtSetPosition (the object's pose)");
    s.calls = 0;
    s.call_failures = 0;
    check(virtStartLoop(vc) == 0, "virtStartLoop (quasi-static object)");
    sleep_ms(ms);
    check(virtStopLoop(vc) == 0, "virtStopLoop");
    snprintf(what, sizeof what, "the quasi-static loop ran without a failing call (%ld calls, %ld failures)", s.calls, s.call_failures);
    check(s.calls >= ms / 20 && s.call_failures == 0, what);
    check(virtGetPosition(vc, pos) == 0 && same7(pos, s.target), "virtGetPosition reads the attached object's pose");
    check(virtGetAvatarPosition(vc, avatar) == 0 && fabsf(avatar[0] - s.target[0]) > 0.01f,
          "virtGetAvatarPosition reads the handle, not the object");
    check(virtGetForce(vc, force) == 0 && force[0] < 0.0f, "virtGetForce: the coupling pulls the object back to the handle");
    check(virtGetSimulationStiffness(vc, &f) == 0 && fabsf(f - 100.0f) < 0.5f,
          "virtGetSimulationStiffness reads the object's stiffness");
    check(virtDetachVO(vc) == 0, "virtDetachVO");

    check(virtSetPowerOn(vc, 0) == 0, "virtSetPowerOn(0)");
    v = -1;
    check(virtGetPowerOn(vc, &v) == 0 && v == 0, "virtGetPowerOn reads 0 right after virtSetPowerOn(0)");
    check(virtClose(vc) == 0, "virtClose");

    /* The closed context, an address and a number virtOpen never returned. */
    refused(vc, "the closed context", &s);
    refused((VirtContext)&s, "a never-opened context (an address)", &s);
    refused((VirtContext)(size_t)12345, "a never-opened context (12345)", &s);
    printf("apps: %d passed, %d failed\n", passed, failed);
    return failed != 0;
}
