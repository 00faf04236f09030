"""The peer's side of `chaoscope bench --peer heyoka`: the Lorenz spectrum by heyoka.

Prints one JSON object on stdout. With `--reference-only` (or when heyoka cannot be imported)
it still computes the reference state at t = 10 that both sides' errors are measured against,
and says whether heyoka is there.

The workload is chaoscope's (`examples/models/lorenz.toml`): sigma = 10, rho = 28, beta = the
double nearest 8/3, x0 = (1, 1, 1), three tangent vectors starting as the identity's columns,
QR re-orthonormalization every tau = 1, the spectrum the mean of log |R_ii| to `--t-final`.
heyoka integrates the variational equations (`var_ode_sys`, first order in the initial state)
with its adaptive Taylor method at `--tol` in double precision, on one thread.

The reference at t = 10 is neither program's: a Taylor series integrator written here in
multiple precision (mpmath) with the same parameters (the doubles, exactly). The Taylor
coefficients of Lorenz follow from the Cauchy products x z and x y; a step of h = 1/64 with
order 36 at 36 significant digits truncates below 1e-26 per step (the series of Lorenz on its
attractor converges for |h| up to about 0.1), and the run is repeated at order 44 and 44
digits: the two agree to the `reference_self_difference` printed, the reference's own error
(it must be far below the 1e-12 the two programs are held to).
"""

import argparse
import json
import sys
import time

SIGMA, RHO, BETA = 10.0, 28.0, 2.6666666666666665
X0 = (1.0, 1.0, 1.0)


def reference_state(t_end, order, digits):
    """The Lorenz state at `t_end` from X0 by a fixed-step Taylor method in mpmath."""
    import mpmath

    mp = mpmath.mp
    mp.dps = digits
    s, r, b = mpmath.mpf(SIGMA), mpmath.mpf(RHO), mpmath.mpf(BETA)
    x, y, z = (mpmath.mpf(v) for v in X0)
    h = mpmath.mpf(1) / 64
    steps = int(round(t_end * 64))
    assert abs(steps / 64 - t_end) < 1e-15, "t_end must be a multiple of 1/64"
    for _ in range(steps):
        cx, cy, cz = [x], [y], [z]
        for k in range(order):
            xz = mpmath.fsum(cx[j] * cz[k - j] for j in range(k + 1))
            xy = mpmath.fsum(cx[j] * cy[k - j] for j in range(k + 1))
            cx.append(s * (cy[k] - cx[k]) / (k + 1))
            cy.append((r * cx[k] - xz - cy[k]) / (k + 1))
            cz.append((xy - b * cz[k]) / (k + 1))
        # Horner in h.
        x, y, z = (
            mpmath.polyval(c[::-1], h) for c in (cx, cy, cz)
        )
    return [x, y, z]


def reference():
    a = reference_state(10.0, 36, 36)
    b = reference_state(10.0, 44, 44)
    diff = max(abs(u - v) for u, v in zip(a, b))
    return [float(v) for v in b], float(diff)


def heyoka_run(t_final, tol):
    import heyoka as hy
    import numpy as np

    cpu0 = time.process_time()
    x, y, z = hy.make_vars("x", "y", "z")
    system = [
        (x, SIGMA * (y - x)),
        (y, x * (RHO - z) - y),
        (z, x * y - BETA * z),
    ]
    vsys = hy.var_ode_sys(system, hy.var_args.vars, order=1)
    # The variational part starts as the identity: column j the image of e_j.
    ta = hy.taylor_adaptive(vsys, list(X0), tol=tol)
    compile_cpu = time.process_time() - cpu0
    cpu1 = time.process_time()
    logs = np.zeros(3)
    state_t10 = None
    windows = int(round(t_final))
    for w in range(1, windows + 1):
        # Land exactly on t = w (propagate_until), as chaoscope's grid does.
        ta.propagate_until(float(w))
        if w == 10:
            state_t10 = ta.state[:3].tolist()
        m = ta.state[3:].reshape(3, 3)
        q, r = np.linalg.qr(m)
        logs += np.log(np.abs(np.diag(r)))
        ta.state[3:] = q.reshape(-1)
    run_cpu = time.process_time() - cpu1
    return {
        "version": hy.__version__,
        "tol": tol,
        "order": ta.order,
        "compile_cpu_seconds": compile_cpu,
        "run_cpu_seconds": run_cpu,
        "cpu_seconds": compile_cpu + run_cpu,
        "spectrum": (logs / windows).tolist(),
        "state_t10": state_t10,
        "t_final": float(windows),
    }


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--t-final", type=float, default=1e5)
    p.add_argument("--tol", type=float, default=2.220446049250313e-16)
    p.add_argument("--reference-only", action="store_true")
    args = p.parse_args()
    out = {}
    try:
        ref, self_diff = reference()
        out["reference_state_t10"] = ref
        out["reference_self_difference"] = self_diff
        out["reference"] = "mpmath Taylor series, h = 1/64, order 44, 44 digits"
    except ImportError as e:
        out["reference_state_t10"] = None
        out["reference_unavailable"] = f"mpmath is not installed ({e})"
    try:
        import heyoka  # noqa: F401

        out["heyoka_available"] = True
    except ImportError as e:
        out["heyoka_available"] = False
        out["heyoka_unavailable"] = f"the Python package heyoka cannot be imported ({e}); pip install heyoka"
    if out["heyoka_available"] and not args.reference_only:
        out["heyoka"] = heyoka_run(args.t_final, args.tol)
    json.dump(out, sys.stdout)
    print()


if __name__ == "__main__":
    main()
