/* Two kernels that bound what a second vCPU can add on this host:
 *   fp:    CH (default 64) independent chains of double multiply-adds (no FMA), enough to keep
 *          the FP units busy (on the 2026-11-26 EPYC the rate stops growing at 32-64 chains);
 *   chase: a dependent pointer chase through 64 MiB: latency-bound, IPC far below 1.
 * Each prints its rate; run one alone, then one per vCPU at once (bench/smt/run.sh). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#ifndef CH
#define CH 64
#endif
static double now(void) { struct timespec t; clock_gettime(CLOCK_MONOTONIC, &t); return t.tv_sec + 1e-9 * t.tv_nsec; }
int main(int argc, char **argv) {
    const char *kind = argc > 1 ? argv[1] : "fp";
    double secs = argc > 2 ? atof(argv[2]) : 5.0;
    if (!strcmp(kind, "fp")) {
        volatile double seed = 1.0000001;
        double a[CH], m = seed, c = 1e-9;
        for (int k = 0; k < CH; k++) a[k] = k;
        long iters = 0; double t0 = now();
        while (now() - t0 < secs) {
            for (int r = 0; r < 1000000; r++)
                for (int k = 0; k < CH; k++) a[k] = a[k] * m + c;
            iters += 1000000;
        }
        double s = 0; for (int k = 0; k < CH; k++) s += a[k];
        printf("fp %.1f M mul-add/s (%g)\n", (double)CH * iters / (now() - t0) / 1e6, s);
    } else {
        size_t n = (64u << 20) / sizeof(size_t);
        size_t *next = malloc(n * sizeof(size_t));
        for (size_t k = 0; k < n; k++) next[k] = k;
        srand(1);
        for (size_t k = n - 1; k > 0; k--) { size_t j = ((size_t)rand() * RAND_MAX + rand()) % k; size_t t = next[k]; next[k] = next[j]; next[j] = t; }
        size_t p = 0; long steps = 0; double t0 = now();
        while (now() - t0 < secs) { for (int r = 0; r < 1000000; r++) p = next[p]; steps += 1000000; }
        printf("chase %.1f M loads/s (%zu)\n", steps / (now() - t0) / 1e6, p);
    }
    return 0;
}
