#!/usr/bin/env python3
"""GALI_k against t for the regular and the chaotic Henon-Heiles orbit, by the variational
method (VM) and the multi-particle method (MPM): the paper's Figs. 3 and 4 (Many Manda,
Hillebrand & Skokos, "GALI by the multi-particle method").

A notebook-style script: each step is a cell. Needs `pip install ./python matplotlib`.

    python3 examples/python/hh_gali.py                  # t = 1e4 (regular), 1e3 (chaotic)
    python3 examples/python/hh_gali.py --quick          # shorter, fewer sets (a few seconds)
    python3 examples/python/hh_gali.py --out fig.png
"""

# %% Setup
import argparse
import pathlib
import tempfile

import matplotlib

matplotlib.use("Agg")  # files only, no display needed
import matplotlib.pyplot as plt
import numpy as np

import chaoscope

parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
parser.add_argument("--out", default="hh_gali.png", help="PNG file to write")
parser.add_argument("--quick", action="store_true", help="short runs, 3 sets")
parser.add_argument("--runs", default=None, help="directory for the recordings (default: temporary)")
args = parser.parse_args()

T_REGULAR, T_CHAOTIC, SETS = (1e3, 400.0, 3) if args.quick else (1e4, 1e3, 10)
runs = pathlib.Path(args.runs or tempfile.mkdtemp(prefix="chaoscope-"))

# %% The two orbits of the paper: Henon-Heiles at H = 1/8 on the x1 = 0 section, p1 > 0 solved
# from the energy; x2 = 0.558 is regular (a 2-torus), x2 = -0.25 chaotic. k = 4 deviation
# vectors (all of phase space), random orthonormal sets, ABA864 with h = 0.01, tau = 1 and the
# paper's d0 = 1e-8 for MPM; a QR scheme gives the Lyapunov spectrum for the reference rates.


def config(x2, t_final):
    return {
        "model": {"name": "henon-heiles"},
        "orbit": {"q": [0.0, x2], "p": [0.0, 0.0], "energy": 0.125, "solve_for": "p1"},
        "integrator": {"method": "aba864", "h": 0.01, "t_final": t_final},
        "deviations": {"k": 4, "sets": SETS, "seed": 1},
        "scheme": [
            {"name": "vm", "method": "vm", "d0": 1e-8, "tau": 1.0},
            {"name": "mpm", "method": "mpm", "d0": 1e-8, "tau": 1.0},
            {"name": "qr", "method": "vm", "d0": 1.0, "tau": 1.0, "orthonormalize": "qr"},
        ],
    }


regular = chaoscope.run(config(0.558, T_REGULAR), out=runs / "hh_regular.mcap", force=True)
chaotic = chaoscope.run(config(-0.25, T_CHAOTIC), out=runs / "hh_chaotic.mcap", force=True)

# %% The indicators: geometric means over the sets (mean of log10), which the paper's curves
# are; arithmetic means are dominated by a few sets (numerics.md).
ind = {
    (orbit, scheme): rec.indicators(scheme)
    for orbit, rec in (("regular", regular), ("chaotic", chaotic))
    for scheme in ("vm", "mpm", "qr")
}


def slope(t, log10_y, start, stop):
    """Least-squares slope of log10 y against log10 t over [start, stop]."""
    keep = (t >= start) & (t <= stop)
    return np.polyfit(np.log10(t[keep]), log10_y[keep], 1)[0]


# %% Regular orbit: on a 2-torus GALI_2 stays constant, GALI_3 ~ t^-2 and GALI_4 ~ t^-4.
vm = ind["regular", "vm"]
last_decade = (T_REGULAR / 10, T_REGULAR)
slopes = [slope(vm.t, vm.gali_log10_mean[:, j], *last_decade) for j in range(3)]
print("regular orbit, log-log slopes of GALI_2, 3, 4 over the last decade:",
      ", ".join(f"{s:.2f}" for s in slopes), "(paper: 0, -2, -4)")

# %% Chaotic orbit: GALI_k ~ exp(-t sum_{i=2..k} (l1 - l_i)); with l = (l1, 0, 0, -l1) the
# rates are l1, 2 l1, 4 l1 (in log10: divided by ln 10).
l1 = ind["chaotic", "qr"].exponents[-1, 0]
vm = ind["chaotic", "vm"]
print(f"chaotic orbit: finite-time l1 = {l1:.4f} at t = {vm.t[-1]:.0f} (paper: ~0.045); "
      f"GALI_2, 3, 4 at t = {vm.t[-1]:.0f}: "
      + ", ".join(f"{10 ** g:.1e}" for g in vm.gali_log10_mean[-1]))

# %% The figure: the paper's panels, VM on the left, MPM on the right.
fig, axes = plt.subplots(2, 2, figsize=(11, 8), constrained_layout=True)
colors = ["tab:blue", "tab:orange", "tab:green"]
for row, orbit in enumerate(("regular", "chaotic")):
    for col, scheme in enumerate(("vm", "mpm")):
        ax = axes[row, col]
        data = ind[orbit, scheme]
        for j, color in zip(range(3), colors):
            ax.plot(data.t[1:], 10 ** data.gali_log10_mean[1:, j], color=color,
                    label=f"GALI$_{j + 2}$")
        if orbit == "regular":
            t = np.array(last_decade) if not args.quick else np.array([T_REGULAR / 10, T_REGULAR])
            for power, j in ((2, 1), (4, 2)):
                anchor = 10 ** data.gali_log10_mean[-1, j] * 3
                ax.plot(t, anchor * (t / t[-1]) ** -power, "k--", lw=0.8)
                ax.annotate(f"$t^{{-{power}}}$", (t[0], anchor * (t[0] / t[-1]) ** -power))
            ax.set_xscale("log")
        else:
            t = data.t[1:]
            for rate, j in ((l1, 0), (2 * l1, 1), (4 * l1, 2)):
                ax.plot(t, np.exp(-rate * t), ":", color=colors[j], lw=0.8)
        ax.set_yscale("log")
        ax.set_ylim(1e-17, 3)
        ax.set_xlabel("t")
        ax.set_ylabel("GALI$_k$ (geometric mean over sets)")
        method = "VM" if scheme == "vm" else "MPM, $d_0 = 10^{-8}$"
        ax.set_title(f"Henon-Heiles {orbit} orbit, {method}")
        ax.legend(loc="lower left")
fig.suptitle("GALI by the variational and multi-particle methods (paper Figs. 3 and 4)")
fig.savefig(args.out, dpi=110)
print(f"figure: {args.out}")
