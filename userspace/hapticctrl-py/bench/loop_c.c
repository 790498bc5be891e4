/*
 * loop_c.c - the C counterpart of the Python loop in loop_py.py, for
 * scripts/bench-python.sh: a VirtuoseAPI client (include/VirtuoseAPI.h,
 * libvirtuose_api) that, every period on CLOCK_MONOTONIC (absolute
 * deadlines), reads the handle's pose and the coupling wrench and streams a
 * virtual object's pose and twist (virtSetSpeed, virtSetPosition), the same
 * work as the Python callback. Measures the achieved period, the wake-up's
 * lateness and the work time (wake-up to set-point sent) per cycle.
 *
 *   loop_c ADDRESS SECONDS [PERIOD_US]   (ADDRESS: "HOST#PORT?key=FILE")
 *
 * Prints one line: "c: cycles=N rate_hz=R period_mean_us=M period_std_us=S
 * period_max_us=X lateness_max_us=L work_mean_us=W work_p50_us=M work_p99_us=P work_max_us=Y
 * overruns=O"
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "VirtuoseAPI.h"

static double now_us(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec * 1e6 + t.tv_nsec / 1e3;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static int fail(const char *what)
{
    int code = virtGetErrorCode(NULL);
    fprintf(stderr, "loop_c: %s failed: %s (code %d)\n", what, virtGetErrorMessage(code), code);
    return 1;
}

int main(int argc, char **argv)
{
    if (argc < 3) {
        fprintf(stderr, "usage: loop_c ADDRESS SECONDS [PERIOD_US]\n");
        return 2;
    }
    double seconds = atof(argv[2]);
    long period_us = argc > 3 ? atol(argv[3]) : 1000;
    if (!(seconds > 0) || period_us < 100) {
        fprintf(stderr, "loop_c: SECONDS > 0, PERIOD_US >= 100\n");
        return 2;
    }
    long n = (long)(seconds * 1e6 / period_us);
    double *period = calloc(n, sizeof *period), *work = calloc(n, sizeof *work);
    if (!period || !work)
        return 1;
    float inertia[3] = { 1e-3f, 1e-3f, 1e-3f };
    VirtContext vc = virtOpen(argv[1]);
    if (!vc)
        return fail("virtOpen");
    if (virtSetTimeStep(vc, period_us * 1e-6f) || virtSetCommandType(vc, COMMAND_TYPE_VIRTMECH) ||
        virtAttachVO(vc, 0.5f, inertia) || virtSetPowerOn(vc, 1))
        return fail("configuration");
    struct timespec due;
    clock_gettime(CLOCK_MONOTONIC, &due);
    double due_us = due.tv_sec * 1e6 + due.tv_nsec / 1e3, prev = 0, late_max = 0, sink = 0;
    long overruns = 0, cycles = 0;
    for (long i = 0; i < n; i++) {
        clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &due, NULL);
        double wake = now_us();
        float pos[7], force[6], speed[6] = { 0, 0, 0, 0, 0, 0 };
        if (virtGetPosition(vc, pos) == 0 && virtGetForce(vc, force) == 0) {
            pos[2] += 0.001f;
            sink += force[2];
            if (virtSetSpeed(vc, speed) || virtSetPosition(vc, pos))
                return fail("virtSetPosition");
        }
        double done = now_us();
        if (wake - due_us > late_max)
            late_max = wake - due_us;
        if (i > 0)
            period[cycles - 1] = wake - prev;
        work[cycles] = done - wake;
        prev = wake;
        cycles++;
        due_us += period_us;
        if (due_us <= done) {
            overruns++;
            due_us = done + period_us;
        }
        due.tv_sec = (time_t)(due_us / 1e6);
        due.tv_nsec = (long)((due_us - due.tv_sec * 1e6) * 1e3);
    }
    virtSetPowerOn(vc, 0);
    virtClose(vc);
    long np = cycles - 1;
    double sum = 0, sq = 0, pmax = 0, wsum = 0, wmax = 0;
    for (long i = 0; i < np; i++) {
        sum += period[i];
        sq += period[i] * period[i];
        if (period[i] > pmax)
            pmax = period[i];
    }
    for (long i = 0; i < cycles; i++) {
        wsum += work[i];
        if (work[i] > wmax)
            wmax = work[i];
    }
    double mean = sum / np, std = sqrt(fmax(0, sq / np - mean * mean));
    qsort(work, cycles, sizeof *work, cmp_double);
    printf("c: cycles=%ld rate_hz=%.1f period_mean_us=%.1f period_std_us=%.1f period_max_us=%.1f "
           "lateness_max_us=%.1f work_mean_us=%.2f work_p50_us=%.2f work_p99_us=%.2f work_max_us=%.1f overruns=%ld\n",
           cycles, 1e6 / mean, mean, std, pmax, late_max, wsum / cycles, work[cycles / 2], work[(long)(cycles * 0.99)], wmax,
           overruns);
    (void)sink;
    return 0;
}
