#!/usr/bin/env python3
"""Independent check of GALI_k on the paper's regular beta-FPUT N = 5 orbit, without chaoscope's
numerics: numpy + scipy only, and a different integrator (adaptive Dormand-Prince DOP853 on the
equations of motion and the variational equations, instead of the tangent map of ABA864).

    examples/paper/independent/fput5_regular_scipy.py [--t-final T] [--reduced]
        [--directions random[:SEED]|canonical|chaoscope:SEED:SET]
        [--chaoscope PATH | --scipy-only] [--out DIR]

Orbit (paper, Appendix B): beta = 1, fixed ends, q = (1.03003, 0, -1.04003, 0, 1.04003),
p = (0.29284, 0, 0, 0, 0), H = 4.9999777565. Ten deviation vectors are evolved with the
variational equations d(dq)/dt = dp, d(dp)/dt = -Hess V(q) dq (Hessian derived by hand below and
checked against finite differences at start-up) and renormalized to unit length every tau = 1
(GALI is scale invariant and the variational equations are linear, so this changes nothing but
the size of the numbers). GALI_j is the product of the singular values of the 2N x j matrix of
the first j unit vectors, a singular value below machine epsilon counted as epsilon: chaoscope's
definition (dynamics/src/indicators.rs).

The initial directions are one orthonormal set, handed to chaoscope verbatim through
`[deviations] vectors` so that both codes start from the same directions: by default a numpy
Haar-random set (PCG64 seed 1, QR of a Gaussian 10 x 10 matrix with R_ii > 0); `canonical` is
the basis q1..q5, p1..p5; `chaoscope:SEED:SET` is set SET of chaoscope's own seeded random
directions, read from the t = 0 sample of a one-step recording (needs the `mcap` and
`mcap-protobuf-support` packages; the only input taken from chaoscope).
Unless --scipy-only, the script then runs `chaoscope run` (VM, ABA864, h = 0.01, tau = 1,
d0 = 1e-8) on the same orbit and directions, reads `chaoscope analyze --csv`, and compares
log10 GALI_j at the same times (integers, ~20 log-spaced per decade).

Output: a markdown table on stdout (and DIR/fput5_regular_table.md) and DIR/comparison.json with
every number (used by tests/independent_fput5.rs). --reduced stops at t = 300 (CI, a few seconds).
Exits non-zero if the Hessian check fails.
"""

import argparse
import json
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

N = 5
DIM = 2 * N
BETA = 1.0
Q0 = np.array([1.03003, 0.0, -1.04003, 0.0, 1.04003])
P0 = np.array([0.29284, 0.0, 0.0, 0.0, 0.0])
H_PAPER = 4.9999777565  # numerics.md, to 1e-10 relative
RTOL = 1e-12
ATOL = 1e-14
TAU = 1.0
SEED = 1  # default numpy seed of --directions random
ORDERS = list(range(2, DIM + 1))
SHOWN = [2, 4, 6, 8, 10]
REPO = Path(__file__).resolve().parents[3]


# --- the model: V = sum_{i=0}^{N} [ r_i^2/2 + beta r_i^4/4 ], r_i = x_{i+1} - x_i,
#     x_0 = x_{N+1} = 0


def bonds(q):
    """r_0 .. r_N (N + 1 bond stretches, fixed ends)."""
    return np.diff(np.concatenate(([0.0], q, [0.0])))


def potential(q):
    r = bonds(q)
    return float(np.sum(r**2 / 2 + BETA * r**4 / 4))


def energy(q, p):
    return float(np.dot(p, p) / 2) + potential(q)


def gradient(q):
    """dV/dx_j = V'(r_{j-1}) - V'(r_j), with V'(r) = r + beta r^3 (site j touches bonds j-1, j)."""
    f = bonds(q)
    f = f + BETA * f**3
    return f[:-1] - f[1:]


def hessian(q):
    """Tridiagonal: H_jj = c_{j-1} + c_j, H_{j,j+1} = H_{j+1,j} = -c_j,
    with c = V''(r) = 1 + 3 beta r^2 on each bond."""
    c = 1.0 + 3.0 * BETA * bonds(q) ** 2
    return np.diag(c[:-1] + c[1:]) - np.diag(c[1:-1], 1) - np.diag(c[1:-1], -1)


def check_derivatives():
    """Gradient against central differences of V, Hessian against central differences of the
    gradient, at the initial point and at a generic random point, and the right-hand side's
    force and Hessian product against them. Returns the worst errors."""
    rng = np.random.default_rng(1)
    worst_g, worst_h = 0.0, 0.0
    for q in (Q0, rng.normal(size=N)):
        eps = 1e-6
        g_fd = np.array([(potential(q + eps * e) - potential(q - eps * e)) / (2 * eps)
                         for e in np.eye(N)])
        h_fd = np.array([(gradient(q + eps * e) - gradient(q - eps * e)) / (2 * eps)
                         for e in np.eye(N)]).T
        worst_g = max(worst_g, float(np.max(np.abs(g_fd - gradient(q)))))
        worst_h = max(worst_h, float(np.max(np.abs(h_fd - hessian(q)))))
        # rhs() applies the Hessian bond by bond: the same matrix, to rounding.
        w = np.concatenate((rng.normal(size=(3, N)), np.zeros((3, N))), axis=1)
        y = np.concatenate((q, rng.normal(size=N), w.ravel()))
        dp = rhs(0.0, y)[DIM:].reshape(-1, DIM)[:, N:]
        worst_h = max(worst_h, float(np.max(np.abs(dp + w[:, :N] @ hessian(q)))))
        worst_g = max(worst_g, float(np.max(np.abs(rhs(0.0, y)[N:DIM] + gradient(q)))))
    return worst_g, worst_h


# --- the flow: state y = [q (N), p (N), W (k x 2N, row i = vector i = (dq, dp))]


def rhs(_t, y):
    """Equations of motion and variational equations. The Hessian product is applied bond by
    bond (the same tridiagonal matrix as hessian(), checked against it at start-up): with
    s = the bond stretches of dq, (H dq)_j = c_{j-1} s_{j-1} - c_j s_j."""
    q = y[:N]
    r = np.empty(N + 1)
    r[0], r[1:N], r[N] = q[0], q[1:] - q[:-1], -q[-1]
    dy = np.empty_like(y)
    dy[:N] = y[N:DIM]
    f = r + BETA * r**3
    dy[N:DIM] = f[1:] - f[:-1]
    dy[DIM:] = variational(r, y[DIM:].reshape(-1, DIM)).ravel()
    return dy


def variational(r, w):
    """d/dt of the rows w = (dq, dp) given the bond stretches r of the orbit."""
    c = 1.0 + 3.0 * BETA * r**2
    dq = w[:, :N]
    s = np.empty((w.shape[0], N + 1))
    s[:, 0], s[:, 1:N], s[:, N] = dq[:, 0], dq[:, 1:] - dq[:, :-1], -dq[:, -1]
    cs = c * s
    dw = np.empty_like(w)
    dw[:, :N] = w[:, N:]
    dw[:, N:] = cs[:, 1:] - cs[:, :-1]  # -H dq
    return dw


def gali_log10(w):
    """log10 GALI_j, j = 2..k, of the rows of w (normalized to unit length first)."""
    u = (w / np.linalg.norm(w, axis=1, keepdims=True)).T  # 2N x k, columns = unit vectors
    out = {}
    for j in range(2, u.shape[1] + 1):
        s = np.linalg.svd(u[:, :j], compute_uv=False)
        out[j] = float(np.sum(np.log10(np.maximum(s, np.finfo(float).eps))))
    return out


def sample_times(t_final):
    """Integer times (multiples of tau = 1), ~20 log-spaced per decade from 1 to t_final."""
    decades = math.log10(t_final)
    ts = {int(round(10 ** (i / 20))) for i in range(int(math.floor(20 * decades)) + 1)}
    ts.add(int(round(t_final)))
    return sorted(t for t in ts if 1 <= t <= t_final)


def directions(kind, binary=None, out=None):
    """Rows = unit vectors (order q1..q5, p1..p5)."""
    if kind.startswith("chaoscope:"):
        _, seed, index = kind.split(":")
        return chaoscope_random_set(binary, int(seed), int(index), out)
    if kind == "canonical":
        return np.eye(DIM)
    seed = int(kind.split(":")[1]) if ":" in kind else SEED
    a = np.random.default_rng(seed).standard_normal((DIM, DIM))
    q, r = np.linalg.qr(a)
    q = q * np.sign(np.diag(r))  # R_ii > 0: each vector keeps the orientation of its draw
    return q.T  # rows = vectors


def integrate_scipy(w0, t_final, progress=True):
    steps = int(round(t_final / TAU))
    keep = set(sample_times(t_final))
    y = np.concatenate((Q0, P0, w0.ravel()))
    e0 = energy(Q0, P0)
    out = {"t": [], "gali": {j: [] for j in ORDERS}, "energy_rel_error": []}
    max_err = 0.0
    nfev = 0
    clock = time.process_time()
    for n in range(steps):
        t0, t1 = n * TAU, (n + 1) * TAU
        sol = solve_ivp(rhs, (t0, t1), y, method="DOP853", rtol=RTOL, atol=ATOL)
        if sol.status != 0:
            sys.exit(f"DOP853 failed on [{t0}, {t1}]: {sol.message}")
        nfev += sol.nfev
        y = sol.y[:, -1].copy()
        err = abs(energy(y[:N], y[N:DIM]) / e0 - 1.0)
        max_err = max(max_err, err)
        w = y[DIM:].reshape(-1, DIM)
        t = n + 1
        if t in keep:
            out["t"].append(t)
            for j, v in gali_log10(w).items():
                out["gali"][j].append(v)
            out["energy_rel_error"].append(err)
            if progress and t >= 1000 and math.log10(t) % 1 == 0:
                print(f"  scipy t = {t}: log10 GALI_10 = {out['gali'][10][-1]:.3f}, "
                      f"{time.process_time() - clock:.0f} s CPU", file=sys.stderr, flush=True)
        w /= np.linalg.norm(w, axis=1, keepdims=True)  # renormalize every tau (in place in y)
    out["energy_rel_error_max"] = max_err
    out["nfev"] = nfev
    out["cpu_seconds"] = time.process_time() - clock
    out["e0"] = e0
    return out


# --- chaoscope on the same orbit and directions


def chaoscope_config(w0, t_final, h, deviations=None):
    """A VM run on the orbit; `deviations` replaces the explicit vectors w0 (rows)."""
    if deviations is None:
        rows = ",\n  ".join("[" + ", ".join(repr(float(x)) for x in row) + "]" for row in w0)
        deviations = f"k = {DIM}\nvectors = [\n  {rows}\n]"
    return f"""# Generated by examples/paper/independent/fput5_regular_scipy.py
[model]
name = "fput-beta"
n = {N}
beta = {BETA!r}
[orbit]
q = [{", ".join(repr(float(x)) for x in Q0)}]
p = [{", ".join(repr(float(x)) for x in P0)}]
[integrator]
method = "aba864"
h = {h!r}
t_final = {float(t_final)!r}
[deviations]
{deviations}
[[scheme]]
name = "vm"
method = "vm"
d0 = 1e-8
tau = {TAU!r}
"""


def chaoscope_random_set(binary, seed, index, out):
    """Set `index` of chaoscope's Haar-random directions for `seed` (k = 10): read from the
    t = 0 sample of a one-step recording (the separations are d0 times the unit directions).
    Needs the `mcap` and `mcap-protobuf-support` packages (tests/python/requirements.txt)."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    cfg = out / f"directions-seed{seed}.toml"
    cfg.write_text(chaoscope_config(None, 1.0, 0.01,
                                    f"k = {DIM}\nsets = {index + 1}\nseed = {seed}"))
    mcap = out / f"directions-seed{seed}.mcap"
    subprocess.run([str(binary), "run", str(cfg), "--out", str(mcap), "--force",
                    "--run", f"independent-dirs-{os.getpid()}"], check=True,
                   stdout=subprocess.DEVNULL)
    with open(mcap, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _s, _c, _m, msg in reader.iter_decoded_messages(topics=["/chaoscope/separations/vm"]):
            if msg.t == 0.0 and msg.set == index:
                w = np.array(msg.separations).reshape(msg.k, msg.dim)
                return w / np.linalg.norm(w, axis=1, keepdims=True)
    sys.exit(f"no t = 0 sample of set {index} in {mcap}")


def find_chaoscope():
    candidates = []
    if os.environ.get("CARGO_TARGET_DIR"):
        candidates.append(Path(os.environ["CARGO_TARGET_DIR"]) / "release" / "chaoscope")
    candidates.append(REPO / "target" / "release" / "chaoscope")
    for c in candidates:
        if c.is_file():
            return c
    found = shutil.which("chaoscope")
    if found:
        return Path(found)
    sys.exit("chaoscope binary not found: pass --chaoscope PATH (cargo build --release) "
             "or --scipy-only")


def run_chaoscope(binary, w0, t_final, h, out):
    cfg = out / "fput5_regular_chaoscope.toml"
    cfg.write_text(chaoscope_config(w0, t_final, h))
    mcap = out / "fput5_regular_chaoscope.mcap"
    csv_dir = out / "chaoscope_csv"
    run_name = f"independent-fput5-{os.getpid()}"
    clock = time.time()
    subprocess.run([str(binary), "run", str(cfg), "--out", str(mcap), "--force",
                    "--run", run_name], check=True, stdout=subprocess.DEVNULL)
    points = int(t_final / TAU) + 10  # keep every sample: the comparison times are all there
    subprocess.run([str(binary), "analyze", str(mcap), "--csv", str(csv_dir),
                    "--points", str(points)], check=True, stdout=subprocess.DEVNULL)
    wall = time.time() - clock
    rows = {}
    with open(csv_dir / "vm.csv") as f:
        head = f.readline().strip().split(",")
        for line in f:
            vals = dict(zip(head, line.strip().split(",")))
            rows[round(float(vals["t"]))] = vals
    times = sample_times(t_final)
    missing = [t for t in times if t not in rows]
    if missing:
        sys.exit(f"chaoscope's CSV lacks times {missing[:5]}...")
    gali = {j: [float(rows[t][f"gali{j}_log10_mean"]) for t in times] for j in ORDERS}
    with open(csv_dir / "energy.csv") as f:
        f.readline()
        e_err = max(abs(float(line.split(",")[1])) for line in f)
    return {"t": times, "gali": gali, "energy_rel_error_max": e_err, "wall_seconds": wall,
            "config": str(cfg)}


# --- comparison


def slope(ts, ys, a, b):
    pts = [(math.log10(t), y) for t, y in zip(ts, ys) if a <= t <= b]
    if len(pts) < 3:
        return None
    x = np.array([p[0] for p in pts])
    y = np.array([p[1] for p in pts])
    return float(np.polyfit(x, y, 1)[0])


def windows(t_final):
    w = [(1e2, 1e4), (1e3, 1e4), (1e4, 1e5)]
    return [(a, b) for a, b in w if b <= t_final * (1 + 1e-9)] or [(10.0, t_final)]


def fmt(v, digits=3):
    return "-" if v is None else f"{v:.{digits}f}"


def report(sp, cs, t_final, args):
    """Markdown tables; with chaoscope, each cell reads "scipy / chaoscope"."""
    lines = []
    ts = sp["t"]
    marks = [t for t in (10, 100, 1000, 10000, 100000) if t in ts]
    if ts[-1] not in marks:
        marks.append(ts[-1])

    def cell(vals, digits):
        return " / ".join(fmt(v, digits) for v in vals)

    codes = [sp] + ([cs] if cs else [])
    who = "scipy / chaoscope" if cs else "scipy"
    lines.append(f"log10 GALI_k ({who}); directions {args.directions}; scipy DOP853 rtol "
                 f"{RTOL:g} atol {ATOL:g}" + (f"; chaoscope VM ABA864 h = {args.h:g}" if cs else "")
                 + "; tau = 1:")
    lines.append("")
    lines.append("| t | " + " | ".join(f"GALI_{k}" for k in SHOWN) + " |")
    lines.append("|" + "---|" * (1 + len(SHOWN)))
    for t in marks:
        i = ts.index(t)
        lines.append(f"| {t:g} | " +
                     " | ".join(cell([c["gali"][k][i] for c in codes], 3) for k in SHOWN) + " |")
    lines.append("")
    lines.append(f"Least-squares log-log slopes over the log-spaced sample times ({who}):")
    lines.append("")
    lines.append("| window | " + " | ".join(f"GALI_{k}" for k in SHOWN) + " |")
    lines.append("|" + "---|" * (1 + len(SHOWN)))
    slopes = {}
    for a, b in windows(t_final):
        key = f"[{a:g}, {b:g}]"
        slopes[key] = {name: {k: slope(ts, c["gali"][k], a, b) for k in ORDERS}
                       for name, c in zip(("scipy", "chaoscope"), codes)}
        lines.append(f"| {key} | " + " | ".join(
            cell([slopes[key][name][k] for name in slopes[key]], 2) for k in SHOWN) + " |")
    diffs = None
    if cs:
        delta = {k: np.abs(np.array(sp["gali"][k]) - np.array(cs["gali"][k])) for k in ORDERS}
        diffs = {k: float(np.max(d)) for k, d in delta.items()}
        lines.append("")
        lines.append("max over t in [1, T] of |log10 GALI_k(scipy) - log10 GALI_k(chaoscope)|:")
        lines.append("")
        lines.append("| T | " + " | ".join(f"k = {k}" for k in ORDERS) + " |")
        lines.append("|" + "---|" * (1 + len(ORDERS)))
        for t_max in sorted({t for t in (300, 1000, 10000, 100000) if t <= ts[-1]} | {ts[-1]}):
            upto = np.array(ts) <= t_max
            lines.append(f"| {t_max:g} | " + " | ".join(
                f"{np.max(delta[k][upto]):.1e}" for k in ORDERS) + " |")
    lines.append("")
    lines.append(f"Energy: H(0) = {sp['e0']:.10f}; max relative error, scipy "
                 f"{sp['energy_rel_error_max']:.1e}" +
                 (f", chaoscope {cs['energy_rel_error_max']:.1e}" if cs else "") + ".")
    lines.append(f"scipy: {sp['nfev']} right-hand-side evaluations, {sp['cpu_seconds']:.0f} s CPU.")
    return "\n".join(lines), slopes, diffs


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--t-final", type=float, default=1e4)
    ap.add_argument("--reduced", action="store_true", help="t_final = 300 (CI, a few seconds)")
    ap.add_argument("--directions", default="random",
                    help="random[:SEED] (numpy Haar-random set, default seed 1), canonical, or "
                         "chaoscope:SEED:SET (set SET of chaoscope's seeded random directions)")
    ap.add_argument("--h", type=float, default=0.01, help="chaoscope's ABA864 step")
    ap.add_argument("--chaoscope", type=Path, help="chaoscope binary (default: target/release)")
    ap.add_argument("--scipy-only", action="store_true")
    ap.add_argument("--out", type=Path, help="output directory (default: a temporary one)")
    args = ap.parse_args()
    t_final = 300.0 if args.reduced else args.t_final
    if abs(t_final - round(t_final)) > 0 or t_final < 10:
        sys.exit("--t-final must be an integer >= 10 (multiple of tau = 1)")
    out = args.out or Path(tempfile.mkdtemp(prefix="fput5-independent-"))
    out.mkdir(parents=True, exist_ok=True)

    g_err, h_err = check_derivatives()
    print(f"finite differences: gradient max error {g_err:.1e}, Hessian max error {h_err:.1e}")
    if g_err > 1e-7 or h_err > 1e-7:
        sys.exit("the hand-derived gradient or Hessian disagrees with finite differences")
    e0 = energy(Q0, P0)
    if abs(e0 / H_PAPER - 1) > 1e-10:
        sys.exit(f"H(0) = {e0!r}, expected {H_PAPER}")

    if not re.fullmatch(r"random(:\d+)?|canonical|chaoscope:\d+:\d+", args.directions):
        sys.exit(f"--directions {args.directions!r}: random[:SEED], canonical or "
                 "chaoscope:SEED:SET")
    if args.directions == "random":
        args.directions = f"random:{SEED}"
    binary = None
    if not args.scipy_only or args.directions.startswith("chaoscope:"):
        binary = args.chaoscope or find_chaoscope()
    w0 = directions(args.directions, binary, out)
    assert np.allclose(w0 @ w0.T, np.eye(DIM), atol=1e-14)
    cs = None
    if not args.scipy_only:
        cs = run_chaoscope(binary, w0, t_final, args.h, out)
        print(f"chaoscope: {cs['wall_seconds']:.1f} s wall", flush=True)
    sp = integrate_scipy(w0, t_final)
    if cs:
        assert cs["t"] == sp["t"]
    text, slopes, diffs = report(sp, cs, t_final, args)
    print(text)
    (out / "fput5_regular_table.md").write_text(text + "\n")
    result = {
        "t_final": t_final,
        "directions": args.directions,
        "initial_vectors": w0.tolist(),
        "derivative_check": {"gradient": g_err, "hessian": h_err},
        "t": sp["t"],
        "e0": sp["e0"],
        "scipy": {"gali_log10": {str(k): v for k, v in sp["gali"].items()},
                  "energy_rel_error_max": sp["energy_rel_error_max"], "nfev": sp["nfev"],
                  "cpu_seconds": sp["cpu_seconds"]},
        "slopes": {w: {c: {str(k): v for k, v in s.items()} for c, s in d.items()}
                   for w, d in slopes.items()},
    }
    if cs:
        result["chaoscope"] = {"gali_log10": {str(k): v for k, v in cs["gali"].items()},
                               "energy_rel_error_max": cs["energy_rel_error_max"], "h": args.h}
        result["max_abs_diff_log10"] = {str(k): v for k, v in diffs.items()}
    (out / "comparison.json").write_text(json.dumps(result, indent=1))
    print(f"wrote {out / 'comparison.json'}")


if __name__ == "__main__":
    main()
