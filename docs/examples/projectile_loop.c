/* A game loop that flies 64 projectiles for 3 seconds at 60 frames per second, every position
 * read from the exported codebook (docs/examples/projectile.yaml), and prints where two shots
 * are at t = 1.5 s, when each lands, and the time per call.
 *   pgd solve docs/examples/projectile.yaml -o codebooks/projectile.h5
 *   pgd export codebooks/projectile.h5 --to c -o pgd_projectile.h
 *   cc -O3 -std=c99 -I. docs/examples/projectile_loop.c -o projectile_loop && ./projectile_loop
 * Only this program uses POSIX (clock_gettime); the header itself needs libc only. */
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <time.h>
#include "pgd_projectile.h"

enum { SHOTS = 64, FPS = 60, FRAMES = 3 * FPS };

int main(void)
{
    double coords[PGD_PROJECTILE_NCOORDS], out[PGD_PROJECTILE_NOUT];  /* (t, v0, a, k) -> (x, y, vx, vy) */
    double shot[SHOTS][3], landed[SHOTS], checksum = 0.0;
    struct timespec t0, t1;
    int i, frame, clamped = 0;

    for (i = 0; i < SHOTS; ++i) {  /* launch speed (m/s), angle (rad) and drag (1/m) of each shot */
        shot[i][0] = 10.0 + 20.0 * i / (SHOTS - 1);
        shot[i][1] = 0.1 + 1.4 * ((i * 37) % SHOTS) / (SHOTS - 1);
        shot[i][2] = 0.05 * ((i * 11) % SHOTS) / (SHOTS - 1);
        landed[i] = -1.0;
    }
    for (i = 0; i < 2; ++i) {
        double where[PGD_PROJECTILE_NCOORDS] = {1.5, shot[i + 40][0], shot[i + 40][1], shot[i + 40][2]};
        int status = pgd_projectile_eval(where, out);
        printf("shot %d (v0 %.17g, a %.17g, k %.17g) at t = 1.5: x = %.17g, y = %.17g (status %d)\n", i + 40,
               where[1], where[2], where[3], out[0], out[1], status);
    }
    clock_gettime(CLOCK_MONOTONIC, &t0);
    for (frame = 0; frame <= FRAMES; ++frame) {
        coords[0] = (double)frame / FPS;
        for (i = 0; i < SHOTS; ++i) {
            coords[1] = shot[i][0];
            coords[2] = shot[i][1];
            coords[3] = shot[i][2];
            clamped |= pgd_projectile_eval(coords, out);  /* 0 inside the codebook's domain */
            checksum += out[0] + out[1];
            if (landed[i] < 0.0 && frame > 0 && out[1] < 0.0)
                landed[i] = coords[0];  /* first frame below the ground */
        }
    }
    clock_gettime(CLOCK_MONOTONIC, &t1);
    for (i = 0; i < 4; ++i)
        printf("shot %d lands at t = %.4f s\n", i, landed[i]);
    printf("%d calls, %.2f us per call (checksum %.6f, status bits %d)\n", SHOTS * (FRAMES + 1),
           ((t1.tv_sec - t0.tv_sec) * 1e9 + (t1.tv_nsec - t0.tv_nsec)) / (SHOTS * (FRAMES + 1)) / 1e3,
           checksum, clamped);
    return 0;
}
