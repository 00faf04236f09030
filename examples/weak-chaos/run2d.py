#!/usr/bin/env python3
"""Weak chaos of the two-dimensional disordered discrete nonlinear Schroedinger lattice (Many
Manda, Senyange and Skokos, PRE 101, 032206, 2020): the finite-time maximal Lyapunov exponent
averaged over disorder realizations decays as t^alpha with alpha near -0.37, and the norm
distribution's second moment over the plane grows as t^(1/5), in the weak-chaos regime, over
the paper's times (10^6 and beyond).

    examples/weak-chaos/run2d.py [--realizations 10] [--side 60] [--t-final 1e4] [--h 0.1]
                                 [--jobs 1] [--chaoscope PATH] [--out DIR]

Each realization is `examples/models/ddnls-square.toml` with its own disorder seed (1, 2, ...,
and the same seed for the block's random phases): a side x side square lattice with fixed edges,
W = 10 (eps_l uniform in [-5, 5]), beta = 1, a 3 x 3 central block with norm 1 per site (S = 9),
s11abc6 at h = 0.1 (relative energy and norm errors ~1e-6), one VM vector renormalized every 10
time units, a sample recorded every 100. `chaoscope run` records each (recordings already in DIR
are kept), `chaoscope analyze --csv` gives `lyapunov1` and `norm_m2` (the norm distribution
z_l = |psi_l|^2 / S, its second moment sum_l z_l |r_l - rbar|^2 over the plane), and
`chaoscope chart` draws the averages; the first realization's DVD and norm over the plane are
drawn by `analyze --plot` (plane-*.png). Prints the fitted exponents and the CPU time of the runs
as JSON. Standard library only.

The 10-realization campaign of RESULTS.md took 896 CPU-seconds (90 per realization); its
6-realization decade to t = 10^5 on an 80 x 80 square (`--side 80 --t-final 1e5`) 9,341
CPU-seconds (about 1,560 per realization). Both ran before the DDNLS's flows were vectorized;
a realization of the first now takes about 28 CPU-seconds.

The paper's exact DDNLS settings are not restated here (not confirmed against the paper's text):
this setting is argued from the regime's conditions. The nonlinear frequency shift
delta = beta |psi|^2 = 1 per excited site is far below the width W + 8 = 18 of the linear
spectrum (no self-trapping) and, for a localization volume V of some ten sites at W = 10, below
or near the level spacing d = (W + 8) / V ~ 2 within it: weak chaos is delta < d, strong chaos
d < delta < W + 8. With delta and d this close, the run may lie on the crossover (the second
moment's exponent measured, 0.27, lies between the regimes' 1/5 and 1/3).
"""

import argparse
import concurrent.futures
import csv
import json
import math
import re
import resource
import shutil
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
EXAMPLE = HERE.parent / "models" / "ddnls-square.toml"
# The fit range, fixed before the campaign was run: the run's last decade, [t_final / 10,
# t_final]. The 3 x 3 block reaches its linear localization within t ~ 10^2 (hopping time 1,
# localization volume of a few sites at W = 10); the subdiffusive spreading the laws describe
# comes after that, and the last decade is the one furthest from the transient.
FIT_DECADES = 10.0


def config(side, t_final, seed, h):
    text = EXAMPLE.read_text()
    mid = (side + 1) // 2
    subs = [
        (r"(?m)^n = \d+$", f"n = {side}"),
        (r"(?m)^seed = 1$", f"seed = {seed}"),
        (r"(?m)^excite = .*$",
         f"excite = {{ sites = [{mid - 1}, {mid + 1}], norm = 9.0, seed = {seed} }}"),
        (r"(?m)^h = .*$", f"h = {h!r}"),
        (r"(?m)^t_final = .*$", f"t_final = {t_final!r}"),
        (r"(?m)^k = \d+$", "k = 1"),
        (r"(?m)^tau = .*$", "tau = 10.0"),
        (r'(?m)^name = "ddnls-square"$',
         f'name = "weak-chaos-2d-{seed}"\nsample_every = 100.0'),
    ]
    for pattern, new in subs:
        text, count = re.subn(pattern, new, text, count=1)
        if count != 1:
            sys.exit(f"the example changed shape: {pattern!r} not found in {EXAMPLE}")
    return text


def realization(chaoscope, out, side, t_final, seed, h):
    """Record realization `seed` (unless its recording exists) and read its curves."""
    mcap = out / f"r{seed}.mcap"
    if not mcap.exists():
        cfg = out / f"r{seed}.toml"
        cfg.write_text(config(side, t_final, seed, h))
        part = out / f"r{seed}.part.mcap"
        subprocess.run([chaoscope, "run", cfg, "--out", part], check=True,
                       stdout=subprocess.DEVNULL)
        part.rename(mcap)
    csv_dir = out / f"r{seed}.csv"
    shutil.rmtree(csv_dir, ignore_errors=True)
    subprocess.run([chaoscope, "analyze", mcap, "--csv", csv_dir], check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    with open(csv_dir / "vm.csv") as f:
        rows = [r for r in csv.DictReader(f) if float(r["t"]) > 0]
    return [(float(r["t"]), float(r["lyapunov1"]), float(r["norm_m2"]),
             float(r["dvd_m2"]), float(r["norm_participation"])) for r in rows]


def slope(xs, ys):
    mx, my = sum(xs) / len(xs), sum(ys) / len(ys)
    return sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sum((x - mx) ** 2 for x in xs)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--realizations", type=int, default=10)
    ap.add_argument("--side", type=int, default=60)
    ap.add_argument("--t-final", type=float, default=1e4)
    ap.add_argument("--h", type=float, default=0.1)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--chaoscope", default="chaoscope")
    ap.add_argument("--out", type=Path, default=Path("weak-chaos-2d"))
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    with concurrent.futures.ThreadPoolExecutor(a.jobs) as pool:
        curves = list(pool.map(lambda s: realization(a.chaoscope, a.out, a.side, a.t_final,
                                                     s, a.h),
                               range(1, a.realizations + 1)))
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    times = [c[0] for c in curves[0]]
    if any([p[0] for p in c] != times for c in curves):
        sys.exit("the realizations were not sampled at the same times")
    n = len(curves)

    def mean_log(k):
        # Averages of the logarithms over the realizations (the paper's <log10 Lambda>).
        return [sum(math.log10(c[i][k]) for c in curves) / n for i in range(len(times))]

    log_mle, log_m2, log_dvd_m2, log_p = mean_log(1), mean_log(2), mean_log(3), mean_log(4)
    fit_from = times[-1] / FIT_DECADES
    first = next(i for i, t in enumerate(times) if t >= fit_from)
    # 20 points per decade, evenly spaced in log t, weigh each part of the range alike.
    decades = math.log10(times[-1] / times[first])
    wanted = [times[first] * 10 ** (j / 20) for j in range(int(decades * 20) + 1)]
    fit = sorted({min(range(first, len(times)), key=lambda i: abs(times[i] - w)) for w in wanted})
    lt = [math.log10(times[i]) for i in fit]
    alpha = slope(lt, [log_mle[i] for i in fit])
    alpha_m = slope(lt, [log_m2[i] for i in fit])
    own = [slope(lt, [math.log10(c[i][1]) for i in fit]) for c in curves]
    own_m = [slope(lt, [math.log10(c[i][2]) for i in fit]) for c in curves]

    def sd(xs):
        m = sum(xs) / len(xs)
        return math.sqrt(sum((x - m) ** 2 for x in xs) / (len(xs) - 1)) if len(xs) > 1 else \
            float("nan")

    lg_t = [math.log10(t) for t in times]
    for what, ys, law, label in (("mle", log_mle, alpha, "log10 <Lambda>"),
                                 ("m2", log_m2, alpha_m, "log10 <m2> (norm, over the plane)")):
        mx = sum(lt) / len(lt)
        my = sum(ys[i] for i in fit) / len(fit)
        spec = {"title": f"2-D DDNLS, W = 10, beta = 1, 3 x 3 block of norm 1, "
                         f"{a.side} x {a.side}, {n} realizations",
                "x_label": "log10 t", "y_label": label,
                "lines": [{"label": "chaoscope (mean of the logs)", "color": 2, "stroke": "solid",
                           "points": [[x, y] for x, y in zip(lg_t, ys)]},
                          {"label": f"fit from t = {fit_from:.3g}: slope {law:.3f}", "color": 0,
                           "stroke": "dashed",
                           "points": [[x, my + law * (x - mx)] for x in (lt[0], lt[-1])]}]}
        spec_path = a.out / f"{what}.json"
        spec_path.write_text(json.dumps(spec))
        subprocess.run([a.chaoscope, "chart", spec_path, "--out", a.out / what], check=True)
    # The first realization's distributions over the plane at four times spread in log t.
    plane_times = ",".join(f"{t:g}" for t in (100.0, 1000.0, a.t_final / 2, a.t_final))
    subprocess.run([a.chaoscope, "analyze", a.out / "r1.mcap", "--plot", a.out / "plots",
                    "--plane-times", plane_times], check=True, stdout=subprocess.DEVNULL)
    report = {
        "realizations": n, "side": a.side, "t_final": a.t_final, "h": a.h,
        "fit_from": fit_from, "fit_to": times[-1],
        "alpha_mle": alpha, "alpha_mle_per_realization_mean": sum(own) / n,
        "alpha_mle_per_realization_standard_error": sd(own) / math.sqrt(n),
        "alpha_m2": alpha_m, "alpha_m2_per_realization_mean": sum(own_m) / n,
        "alpha_m2_per_realization_standard_error": sd(own_m) / math.sqrt(n),
        "alpha_dvd_m2": slope(lt, [log_dvd_m2[i] for i in fit]),
        "alpha_norm_participation": slope(lt, [log_p[i] for i in fit]),
        "mle_at_t_final": 10 ** log_mle[-1], "m2_at_t_final": 10 ** log_m2[-1],
        "norm_participation_at_t_final": 10 ** log_p[-1],
        # The packet must stay well inside the square: compare with a uniform spread,
        # (side^2 - 1) / 6 over the plane.
        "m2_max_at_t_final": max(c[-1][2] for c in curves),
        "m2_of_uniform_square": (a.side ** 2 - 1) / 6,
        "cpu_seconds_of_runs_done_now": usage.ru_utime + usage.ru_stime,
    }
    # A spread of one realization is undefined: null, never a NaN (which is not JSON).
    print(json.dumps({k: None if isinstance(v, float) and math.isnan(v) else v
                      for k, v in report.items()}, indent=1, allow_nan=False))


if __name__ == "__main__":
    main()
