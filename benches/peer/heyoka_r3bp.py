"""The peer's side of `chaoscope bench --peer heyoka`: the planar restricted three-body problem.

Prints one JSON object on stdout, or says that heyoka cannot be imported.

The workload is chaoscope's (`examples/models/restricted-three-body.toml`): the circular
restricted problem of the Sun and Jupiter (mu = 9.537e-4) in the rotating frame, the Hamiltonian
H = (px^2 + py^2)/2 + y px - x py - (1 - mu)/r1 - mu/r2 (the Jacobi constant is -2 H), from
`--state` (an orbit that starts at a = 0.86, inside Jupiter's chaotic zone), four tangent
vectors starting as the identity's columns, QR re-orthonormalization every tau = 1, the
spectrum the mean of log |R_ii| to `--t-final`, and the largest relative error of H over the
renormalization times; the whole run `--repeats` times from the same state (the integrator
built once), so that the CPU time is long enough to measure. heyoka integrates the variational equations (`var_ode_sys`, first order
in the initial state) with its adaptive Taylor method at `--tol` in double precision, one thread.
"""

import argparse
import json
import sys
import time


def heyoka_run(t_final, tol, mu, state, repeats):
    import heyoka as hy
    import numpy as np

    cpu0 = time.process_time()
    x, y, px, py = hy.make_vars("x", "y", "px", "py")
    r1_3 = ((x + mu) ** 2 + y**2) ** 1.5
    r2_3 = ((x - 1.0 + mu) ** 2 + y**2) ** 1.5
    system = [
        (x, px + y),
        (y, py - x),
        (px, py - (1.0 - mu) * (x + mu) / r1_3 - mu * (x - 1.0 + mu) / r2_3),
        (py, -px - (1.0 - mu) * y / r1_3 - mu * y / r2_3),
    ]
    vsys = hy.var_ode_sys(system, hy.var_args.vars, order=1)
    ta = hy.taylor_adaptive(vsys, list(state), tol=tol)
    compile_cpu = time.process_time() - cpu0

    def energy(s):
        x, y, px, py = s
        r1 = ((x + mu) ** 2 + y**2) ** 0.5
        r2 = ((x - 1.0 + mu) ** 2 + y**2) ** 0.5
        return (px * px + py * py) / 2 + y * px - x * py - (1.0 - mu) / r1 - mu / r2

    h0 = energy(state)
    start = ta.state.copy()
    cpu1 = time.process_time()
    worst = 0.0
    windows = int(round(t_final))
    for _ in range(repeats):
        ta.time = 0.0
        ta.state[:] = start
        logs = np.zeros(4)
        for w in range(1, windows + 1):
            ta.propagate_until(float(w))
            worst = max(worst, abs((energy(ta.state[:4]) - h0) / h0))
            m = ta.state[4:].reshape(4, 4)
            q, r = np.linalg.qr(m)
            logs += np.log(np.abs(np.diag(r)))
            ta.state[4:] = q.reshape(-1)
    run_cpu = time.process_time() - cpu1
    return {
        "version": hy.__version__,
        "tol": tol,
        "order": ta.order,
        "compile_cpu_seconds": compile_cpu,
        "run_cpu_seconds": run_cpu,
        "cpu_seconds": compile_cpu + run_cpu,
        "spectrum": (logs / windows).tolist(),
        "max_relative_jacobi_error": worst,
        "t_final": float(windows),
        "repeats": repeats,
    }


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--t-final", type=float, default=1e3)
    p.add_argument("--tol", type=float, default=2.220446049250313e-16)
    p.add_argument("--mu", type=float, default=9.537e-4)
    p.add_argument("--state", type=float, nargs=4, required=True)
    p.add_argument("--repeats", type=int, default=1)
    args = p.parse_args()
    out = {}
    try:
        import heyoka  # noqa: F401

        out["heyoka_available"] = True
    except ImportError as e:
        out["heyoka_available"] = False
        out["heyoka_unavailable"] = f"the Python package heyoka cannot be imported ({e}); pip install heyoka"
    if out["heyoka_available"]:
        out["heyoka"] = heyoka_run(args.t_final, args.tol, args.mu, args.state, args.repeats)
    json.dump(out, sys.stdout)
    print()


if __name__ == "__main__":
    main()
