/* Two lattice chains, hand-written scalar C: the yardsticks of `chaoscope bench --dkg-only` and
 * `--lattice-only`. Fixed ends (q_0 = q_{N+1} = 0), unit masses.
 *   model 0, the disordered Klein-Gordon chain:
 *     H = sum p_l^2/2 + eps_l q_l^2/2 + q_l^4/4 + (q_{l+1} - q_l)^2/(2W);
 *   model 1, the beta-FPUT chain:
 *     H = sum p_l^2/2 + sum_{l=0}^{N} r_l^2/2 + beta r_l^4/4, r_l = q_{l+1} - q_l.
 * The splitting given on stdin (drift and kick coefficients already times h), its tangent map
 * for k deviation vectors (drift dq += a dp, kick dp -= b Hess V(q) dq at the stage's q), every
 * vector renormalized every `tau` steps and its log stretch summed: the finite-time exponent of
 * vector 1 is the maximal Lyapunov exponent, as in chaoscope's VM. Each stage is the textbook
 * loops (drifts, force and kick, tangent kick), which gcc vectorizes along the chain.
 *
 * stdin: model, N, then for model 0 W and eps[N], for model 1 beta; then m (kicks), drift[m+1],
 * kick[m], tau (steps), windows, h, k, x0[2N], vectors[k][2N].
 * stdout: "cpu_seconds S" (of the loop), "mle X". */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

static double rd(void) {
    double v;
    if (scanf("%lf", &v) != 1) { fprintf(stderr, "chains: short input\n"); exit(2); }
    return v;
}

int main(void) {
    int model = (int)rd();
    int n = (int)rd();
    double w_inv = 0.0, beta = 0.0;
    double *eps = malloc(sizeof(double) * n);
    if (model == 0) {
        w_inv = 1.0 / rd();
        for (int l = 0; l < n; l++) eps[l] = rd();
    } else {
        beta = rd();
    }
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
    /* DKG: each site's curvature; FPUT: each bond's force and stiffness (bond l joins sites
     * l-1 and l, 0..N). */
    double *curv = malloc(sizeof(double) * n);
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
                if (model == 0) {
                    for (int l = 0; l < n; l++) {
                        double left = l > 0 ? q[l - 1] : 0.0, right = l + 1 < n ? q[l + 1] : 0.0;
                        curv[l] = eps[l] + 3.0 * q[l] * q[l];
                        double force = eps[l] * q[l] + q[l] * q[l] * q[l]
                                     + (2.0 * q[l] - left - right) * w_inv;
                        p[l] -= bi * force;
                    }
                    for (int j = 0; j < k; j++) {
                        double *x = dq + j * n, *y = dp + j * n;
                        for (int l = 0; l < n; l++) {
                            double left = l > 0 ? x[l - 1] : 0.0, right = l + 1 < n ? x[l + 1] : 0.0;
                            y[l] -= bi * (curv[l] * x[l] + (2.0 * x[l] - left - right) * w_inv);
                        }
                    }
                } else {
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
            }
            double al = a[m];
            for (int l = 0; l < n; l++) q[l] += al * p[l];
            for (int j = 0; j < k; j++)
                for (int l = 0; l < n; l++) dq[j * n + l] += al * dp[j * n + l];
        }
        /* Renormalize every vector (the MLE reads vector 1's stretch). */
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
