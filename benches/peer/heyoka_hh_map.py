"""The peer's side of `chaoscope bench --peer heyoka`: the Henon-Heiles MLE map by heyoka.

Reads the map's points as JSON (`--points FILE`: a list of {"index", "x0"}, x0 = (x, y, px, py)
taken from the map file `chaoscope map` wrote, so both programs start from the same doubles)
and prints one JSON object on stdout: per-point MLE, the largest relative energy error, and
the CPU seconds of the whole computation (compilation included) by `time.process_time()`.

The system is H = (px^2 + py^2)/2 + (x^2 + y^2)/2 + x^2 y - y^3/3 with its tangent system
written out (one tangent vector, four more variables: what a VM run with k = 1 integrates),
integrated by heyoka's adaptive Taylor method in batch mode (`taylor_adaptive_batch`, lanes of
the machine's recommended SIMD width, one thread) at `--tol`. The tangent vector starts as
`--vector` (chaoscope's `[deviations] vectors`, normalized). Each batch is one call of
`propagate_grid` over t = 0, 1, ..., t_final (the states at every tau = 1, computed inside heyoka
by its dense output, with no Python between the steps). The tangent system is linear, so the
vector needs no rescaling for the MLE: ln |v(t_final)| / t_final equals the mean of the
logarithms of the norms renormalized every tau = 1 that chaoscope's VM scheme with k = 1 sums
(up to rounding); at t_final = 1000 the largest growth, about e^100, is far from overflow, which
is checked. The energy error is read on the same grid, relative to the starting energy of each
point.
"""

import argparse
import json
import sys
import time


def energy(s):
    x, y, px, py = s[0], s[1], s[2], s[3]
    return 0.5 * (px * px + py * py) + 0.5 * (x * x + y * y) + x * x * y - y * y * y / 3.0


def run(points, t_final, tol, vector):
    import heyoka as hy
    import numpy as np

    cpu0 = time.process_time()
    x, y, px, py, dx, dy, dpx, dpy = hy.make_vars("x", "y", "px", "py", "dx", "dy", "dpx", "dpy")
    system = [
        (x, px),
        (y, py),
        (px, -x - 2.0 * x * y),
        (py, -y - x * x + y * y),
        (dx, dpx),
        (dy, dpy),
        (dpx, -(1.0 + 2.0 * y) * dx - 2.0 * x * dy),
        (dpy, -2.0 * x * dx - (1.0 - 2.0 * y) * dy),
    ]
    lanes = hy.recommended_simd_size()
    v = np.array(vector, dtype=float)
    v /= np.linalg.norm(v)
    x0 = np.array([p["x0"] for p in points], dtype=float).reshape(-1, 4)
    n = len(x0)
    # The last batch is filled with copies of its first point; their results are dropped.
    batches = max(1, -(-n // lanes))
    padded = np.concatenate([x0, np.repeat(x0[-1:], batches * lanes - n, axis=0)]) if n else x0
    state = np.zeros((8, lanes))
    ta = None
    windows = int(round(t_final))
    grid = np.repeat(np.arange(windows + 1, dtype=float)[:, None], lanes, axis=1)
    mle = np.zeros(batches * lanes)
    energy_error = 0.0
    compile_cpu = 0.0
    # The time inside heyoka's propagate_grid alone: the rest is this script's numpy, reported
    # apart so the JSON shows what it costs.
    propagate_cpu = 0.0
    for b in range(batches):
        block = padded[b * lanes:(b + 1) * lanes].T
        state[:4] = block
        state[4:] = v[:, None]
        if ta is None:
            ta = hy.taylor_adaptive_batch(system, state, tol=tol)
            compile_cpu = time.process_time() - cpu0
        else:
            ta.set_time(0.0)
            ta.state[:] = state
        c = time.process_time()
        _, out = ta.propagate_grid(grid)
        propagate_cpu += time.process_time() - c
        t_end = out[-1, 4:]
        log_norm = np.log(np.sqrt(np.einsum("ij,ij->j", t_end, t_end)))
        if not np.all(np.isfinite(log_norm)) or log_norm.max() > 700.0:
            sys.exit("the tangent vector's growth nears overflow: t_final too long for one "
                     "propagation without renormalization")
        e0 = energy(block)
        err = np.abs((energy(out[1:, :4].transpose(1, 0, 2)) - e0) / e0)
        energy_error = max(energy_error, float(err.max()))
        mle[b * lanes:(b + 1) * lanes] = log_norm / windows
    cpu = time.process_time() - cpu0
    return {
        "version": hy.__version__,
        "method": "taylor_adaptive_batch, tangent system written out, one thread",
        "tol": tol,
        "order": ta.order if ta is not None else None,
        "batch_size": lanes,
        "compile_cpu_seconds": compile_cpu,
        "cpu_seconds": cpu,
        "propagate_cpu_seconds": propagate_cpu,
        "max_relative_energy_error": energy_error,
        "mle": {str(p["index"]): float(m) for p, m in zip(points, mle[:n])},
    }


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--points", required=True)
    p.add_argument("--t-final", type=float, default=1000.0)
    p.add_argument("--tol", type=float, default=1e-11)
    p.add_argument("--vector", type=float, nargs=4, default=[0.5, 0.5, 0.5, 0.5])
    args = p.parse_args()
    with open(args.points) as f:
        points = json.load(f)
    out = {}
    try:
        import heyoka  # noqa: F401

        out["heyoka_available"] = True
    except ImportError as e:
        out["heyoka_available"] = False
        out["heyoka_unavailable"] = f"the Python package heyoka cannot be imported ({e}); pip install heyoka"
    if out["heyoka_available"]:
        out["heyoka"] = run(points, args.t_final, args.tol, args.vector)
    json.dump(out, sys.stdout, allow_nan=False)
    print()


if __name__ == "__main__":
    main()
