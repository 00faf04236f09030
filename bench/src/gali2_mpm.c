/* The scalar yardstick of `chaoscope bench`'s map workload: the paper's pseudo-code for GALI_k by
 * the multi-particle method (Appendix A), k = 2, for the Henon-Heiles system, one initial
 * condition and one set of deviation vectors at a time. For every set the reference orbit is
 * integrated again beside its k nearby orbits (as the pseudo-code does), every orbit by the
 * splitting whose coefficients are read below, each separation rescaled to d0 every tau and
 * GALI_2 formed from the unit separations.
 *
 * stdin (whitespace-separated numbers):
 *   S, then S + 1 drift coefficients a_i h and S kick coefficients b_i h;
 *   steps per renormalization, renormalizations, d0;
 *   number of sets, then per set k = 2 unit vectors of 4 numbers;
 *   number of initial conditions, then per initial condition q1 q2 p1 p2.
 * stdout: one line per initial condition, the mean over the sets of log10 GALI_2 at the final
 * time, then `cpu_seconds <CPU time of the integration, input parsing excluded>`. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#define K 2
#define DIM 4
#define MAX_STAGES 16

static int stages;
static double drift[MAX_STAGES + 1], kick[MAX_STAGES];

/* One step of the splitting for one orbit x = (q1, q2, p1, p2). */
static void step(double *x) {
    for (int s = 0; s < stages; s++) {
        x[0] += drift[s] * x[2];
        x[1] += drift[s] * x[3];
        double a = x[0], b = x[1];
        double g0 = a + 2.0 * a * b;
        double g1 = b + a * a - b * b;
        x[2] -= kick[s] * g0;
        x[3] -= kick[s] * g1;
    }
    x[0] += drift[stages] * x[2];
    x[1] += drift[stages] * x[3];
}

static double cpu_now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static double read_number(void) {
    double v;
    if (scanf("%lf", &v) != 1) {
        fprintf(stderr, "gali2_mpm: malformed input\n");
        exit(2);
    }
    return v;
}

int main(void) {
    stages = (int)read_number();
    if (stages < 1 || stages > MAX_STAGES) {
        fprintf(stderr, "gali2_mpm: bad stage count\n");
        return 2;
    }
    for (int i = 0; i <= stages; i++) drift[i] = read_number();
    for (int i = 0; i < stages; i++) kick[i] = read_number();
    long steps_per_tau = (long)read_number();
    long renormalizations = (long)read_number();
    double d0 = read_number();
    int sets = (int)read_number();
    double *w = malloc(sizeof(double) * sets * K * DIM);
    for (int i = 0; i < sets * K * DIM; i++) w[i] = read_number();
    int ics = (int)read_number();
    double *x0 = malloc(sizeof(double) * ics * DIM);
    for (int i = 0; i < ics * DIM; i++) x0[i] = read_number();
    double *result = malloc(sizeof(double) * ics);

    double start = cpu_now();
    for (int c = 0; c < ics; c++) {
        double sum_log_gali = 0.0;
        for (int s = 0; s < sets; s++) {
            double x[DIM], xn[K][DIM], gali = 1.0;
            for (int j = 0; j < DIM; j++) x[j] = x0[c * DIM + j];
            /* xn_i = x + w_i, w_i of size d0. */
            for (int i = 0; i < K; i++)
                for (int j = 0; j < DIM; j++) xn[i][j] = x[j] + d0 * w[(s * K + i) * DIM + j];
            for (long r = 0; r < renormalizations; r++) {
                for (long n = 0; n < steps_per_tau; n++) {
                    step(x);
                    for (int i = 0; i < K; i++) step(xn[i]);
                }
                /* Rescale every separation to d0; A_i = (xn_i - x) / d0 are unit vectors. */
                double a[K][DIM];
                for (int i = 0; i < K; i++) {
                    double norm = 0.0;
                    for (int j = 0; j < DIM; j++) {
                        double d = xn[i][j] - x[j];
                        norm += d * d;
                    }
                    norm = sqrt(norm);
                    for (int j = 0; j < DIM; j++) {
                        double d = (xn[i][j] - x[j]) / norm;
                        a[i][j] = d;
                        xn[i][j] = x[j] + d0 * d;
                    }
                }
                /* GALI_2 = product of the two singular values of A = sqrt(det(A A^T)). */
                double g11 = 0.0, g12 = 0.0, g22 = 0.0;
                for (int j = 0; j < DIM; j++) {
                    g11 += a[0][j] * a[0][j];
                    g12 += a[0][j] * a[1][j];
                    g22 += a[1][j] * a[1][j];
                }
                double det = g11 * g22 - g12 * g12;
                gali = sqrt(det > 0.0 ? det : 0.0);
            }
            /* Floored at machine epsilon, as chaoscope's GALI is. */
            sum_log_gali += log10(gali > 2.220446049250313e-16 ? gali : 2.220446049250313e-16);
        }
        result[c] = sum_log_gali / sets;
    }
    double cpu = cpu_now() - start;
    for (int c = 0; c < ics; c++) printf("%.17g\n", result[c]);
    printf("cpu_seconds %.9f\n", cpu);
    free(w);
    free(x0);
    free(result);
    return 0;
}
