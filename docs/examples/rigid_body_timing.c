/* Evaluate the exported rigid-body codebook in a loop and print the time per call.
 *   pgd export codebooks/rigid_body.h5 --to c -o pgd_rigid_body.h
 *   cc -O2 -std=c99 -I. docs/examples/rigid_body_timing.c -o rigid_body_timing && ./rigid_body_timing
 * Only this program uses POSIX (clock_gettime); the header itself needs libc only. */
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <time.h>
#include "pgd_rigid_body.h"

#ifndef PGD_CALLS
#define PGD_CALLS 200000 /* calls per timing loop (-DPGD_CALLS=N to change) */
#endif

int main(void)
{
    enum { CALLS = PGD_CALLS };
    double x[PGD_RIGID_BODY_NCOORDS] = {0.5, 0.8, 1.3, 0.6, 1.1, 0.7, 1.4};  /* t, u10..w30 */
    double out[PGD_RIGID_BODY_NOUT], sum = 0.0;
    float xf[PGD_RIGID_BODY_NCOORDS], outf[PGD_RIGID_BODY_NOUT];
    struct timespec t0, t1;
    int i, j, status = pgd_rigid_body_eval(x, out);
    printf("status %d at t = %g: u = (%.9f, %.9f, %.9f), w = (%.9f, %.9f, %.9f)\n", status, x[0],
           out[0], out[1], out[2], out[3], out[4], out[5]);
    clock_gettime(CLOCK_MONOTONIC, &t0);
    for (i = 0; i < CALLS; ++i) {
        x[0] = (double)i / CALLS;  /* sweep the time coordinate so no call can be hoisted */
        pgd_rigid_body_eval(x, out);
        sum += out[0];
    }
    clock_gettime(CLOCK_MONOTONIC, &t1);
    printf("double: %.2f us per call (checksum %.6f)\n",
           ((t1.tv_sec - t0.tv_sec) * 1e9 + (t1.tv_nsec - t0.tv_nsec)) / CALLS / 1e3, sum);
    for (j = 0; j < PGD_RIGID_BODY_NCOORDS; ++j) xf[j] = (float)x[j];
    sum = 0.0;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    for (i = 0; i < CALLS; ++i) {
        xf[0] = (float)i / CALLS;
        pgd_rigid_body_eval_f(xf, outf);
        sum += outf[0];
    }
    clock_gettime(CLOCK_MONOTONIC, &t1);
    printf("float:  %.2f us per call (checksum %.6f)\n",
           ((t1.tv_sec - t0.tv_sec) * 1e9 + (t1.tv_nsec - t0.tv_nsec)) / CALLS / 1e3, sum);
    return 0;
}
