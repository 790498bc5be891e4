/*
 * first.c - a newcomer's first VirtuoseAPI program: open a session, read
 * the handle's pose and the power state, close. tests/vapi/run.sh builds it
 * after the default install with nothing but `cc first.c -lvirtuose` (and
 * the variants a real application's build uses: <virtuose/virtuoseAPI.h>
 * with -DVIRTUOSE_SUBDIR, C++, CHAI3D's VIRTUOSE_DIR flags) and runs it
 * with no LD_LIBRARY_PATH.
 *
 *   first HOST#PORT
 *
 * Prints the pose; exit status 0 when every call succeeded.
 */
#ifdef VIRTUOSE_SUBDIR
#include <virtuose/virtuoseAPI.h>
#else
#include "virtuoseAPI.h"
#endif

#include <stdio.h>

int main(int argc, char **argv)
{
    VirtContext vc;
    float pose[7];
    int power = -1;

    if (argc != 2) {
        fprintf(stderr, "usage: %s HOST#PORT\n", argv[0]);
        return 2;
    }
    vc = virtOpen(argv[1]);
    if (!vc) {
        fprintf(stderr, "virtOpen: %s\n", virtGetErrorMessage(virtGetErrorCode(NULL)));
        return 1;
    }
    if (virtGetPosition(vc, pose) || virtGetPowerOn(vc, &power)) {
        fprintf(stderr, "%s\n", virtGetErrorMessage(virtGetErrorCode(vc)));
        virtClose(vc);
        return 1;
    }
    printf("handle at %.4f %.4f %.4f, power %d\n", pose[0], pose[1], pose[2], power);
    return virtClose(vc) != 0;
}
