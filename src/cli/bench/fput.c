/* The beta-FPUT chain, hand-written scalar C: a yardstick of `chaoscope bench --lattice-only`.
 * H = sum p_l^2/2 + sum_{l=0}^{N} r_l^2/2 + beta r_l^4/4, r_l = q_{l+1} - q_l, fixed ends
 * (q_0 = q_{N+1} = 0). The splitting given on stdin (drift and kick coefficients already times
 * h), its tangent map for k deviation vectors (drift dq += a dp, kick dp -= b Hess V(q) dq at
 * the stage's q), every vector renormalized every `tau` steps and its log stretch summed: the
 * finite-time exponent of vector 1 is the maximal Lyapunov exponent, as in chaoscope's VM.
 *
 * stdin: N, beta, m (kicks), drift[m+1], kick[m], tau (steps), windows, h, k, x0[2N],
 * vectors[k][2N]. stdout: "cpu_seconds S", "mle X". */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

static double rd(void) {
    double v;
    if (scanf("%lf", &v) != 1) { fprintf(stderr, "fput: short input\n"); exit(2); }
    return v;
}

int main(void) {
    int n = (int)rd();
    double beta = rd();
    int m = (int)rd();
    double *a = malloc(sizeof(double) * (m + 1)), *b = malloc(sizeof(double) * m);
    for (int i = 0; i <= m; i++) a[i] = rd();
    for (int i = 0; i < m; i++) b[i] = rd();
    long tau = (long)rd(), windows = (long)rd();
    double h = rd();
    int k = (int)rd();
    double *q = malloc(sizeof(double) * n), *p = malloc(sizeof(double) * n);
    for (int l = 0; l < n; l++) q[l] = rd();
    for (int l = 0; l < n; l++) p[l] = rd();
    double *dq = malloc(sizeof(double) * n * k), *dp = malloc(sizeof(double) * n * k);
    for (int j = 0; j < k; j++) {
        for (int l = 0; l < n; l++) dq[j * n + l] = rd();
        for (int l = 0; l < n; l++) dp[j * n + l] = rd();
    }
    /* Bond l joins sites l-1 and l (0..N): its stretch and stiffness. */
    double *f = malloc(sizeof(double) * (n + 1)), *stiff = malloc(sizeof(double) * (n + 1));
    double log_sum = 0.0;
    struct timespec t0, t1;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t0);
    for (long win = 0; win < windows; win++) {
        for (long s = 0; s < tau; s++) {
            for (int i = 0; i < m; i++) {
                double ai = a[i], bi = b[i];
                for (int l = 0; l < n; l++) q[l] += ai * p[l];
                for (int j = 0; j < k; j++)
                    for (int l = 0; l < n; l++) dq[j * n + l] += ai * dp[j * n + l];
                for (int l = 0; l <= n; l++) {
                    double left = l > 0 ? q[l - 1] : 0.0, right = l < n ? q[l] : 0.0;
                    double r = right - left;
                    f[l] = r + beta * r * r * r;
                    stiff[l] = 1.0 + 3.0 * beta * r * r;
                }
                for (int l = 0; l < n; l++) p[l] -= bi * (f[l] - f[l + 1]);
                for (int j = 0; j < k; j++) {
                    double *x = dq + j * n, *y = dp + j * n;
                    for (int l = 0; l < n; l++) {
                        double left = l > 0 ? x[l - 1] : 0.0, right = l + 1 < n ? x[l + 1] : 0.0;
                        y[l] -= bi * (stiff[l] * (x[l] - left) - stiff[l + 1] * (right - x[l]));
                    }
                }
            }
            double al = a[m];
            for (int l = 0; l < n; l++) q[l] += al * p[l];
            for (int j = 0; j < k; j++)
                for (int l = 0; l < n; l++) dq[j * n + l] += al * dp[j * n + l];
        }
        for (int j = 0; j < k; j++) {
            double s2 = 0.0;
            for (int l = 0; l < n; l++) s2 += dq[j * n + l] * dq[j * n + l];
            for (int l = 0; l < n; l++) s2 += dp[j * n + l] * dp[j * n + l];
            double norm = sqrt(s2);
            if (j == 0) log_sum += log(norm);
            for (int l = 0; l < n; l++) { dq[j * n + l] /= norm; dp[j * n + l] /= norm; }
        }
    }
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t1);
    printf("cpu_seconds %.9f\nmle %.17g\n",
           (t1.tv_sec - t0.tv_sec) + 1e-9 * (t1.tv_nsec - t0.tv_nsec),
           log_sum / (h * tau * windows));
    return 0;
}
