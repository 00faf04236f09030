#!/usr/bin/env python3
"""Regenerate the figures of Many Manda, Hillebrand & Skokos, "GALI by the multi-particle
method", with the chaoscope binary, and check the key numbers.

    examples/paper/run.py [--reduced] [--chaoscope PATH] [--out DIR]

Every figure is produced by `chaoscope` itself: `run` (producer and recorder processes, MCAP),
`analyze --plot/--json/--csv`, `section`, and `chart` for figures derived from several runs.
The configs are in examples/paper/configs/. `--reduced` (CI) uses fewer sets and shorter times
and skips the N = 11 and N = 101 sweeps; both modes check the key numbers (V-shape minima, MLE
band, GALI slopes, energy-error order, tau flatness) and exit non-zero when one is off.
The full mode also copies the PNGs shown in RESULTS.md into examples/paper/figures/.
Standard library only.
"""

import argparse
import json
import math
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
CONFIGS = HERE / "configs"
FIGURES = HERE / "figures"

FAILURES = []
NUMBERS = {}


def check(name, ok, detail):
    status = "ok  " if ok else "FAIL"
    print(f"[{status}] {name}: {detail}", flush=True)
    if not ok:
        FAILURES.append(f"{name}: {detail}")


class Paper:
    def __init__(self, binary, out, reduced):
        self.bin = binary
        self.out = out
        self.reduced = reduced
        self.suffix = f"-{os.getpid()}"

    def sh(self, *args, capture=True):
        cmd = [str(self.bin), *map(str, args)]
        print("$ chaoscope " + " ".join(map(str, args)), flush=True)
        r = subprocess.run(cmd, stdout=subprocess.PIPE if capture else subprocess.DEVNULL,
                           text=True)
        if r.returncode != 0:
            sys.exit(f"command failed ({r.returncode}): {' '.join(cmd)}")
        return r.stdout if capture else ""

    def config(self, name, subs=None, tag=None):
        """Config `name` with regex substitutions, written into the output directory."""
        text = (CONFIGS / name).read_text()
        for pattern, value in (subs or {}).items():
            text, n = re.subn(pattern, value, text, flags=re.M)
            if n == 0:
                sys.exit(f"{name}: substitution {pattern!r} matched nothing")
        path = self.out / "configs" / (tag or name)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
        return path

    def record(self, config, stem):
        mcap = self.out / f"{stem}.mcap"
        run_name = re.sub(r"[^A-Za-z0-9_-]", "-", stem) + self.suffix
        self.sh("run", config, "--out", mcap, "--force", "--run", run_name, capture=False)
        return mcap

    def analyze(self, mcap, *extra):
        return json.loads(self.sh("analyze", mcap, "--json", *extra).strip().splitlines()[-1])

    def chart(self, spec, stem):
        path = self.out / f"{stem}.json"
        path.write_text(json.dumps(spec))
        self.sh("chart", path, "--out", self.out / stem)


def scheme(report, name):
    return next(s for s in report["schemes"] if s["name"] == name)


def lg(x):
    return math.log10(x)


def read_csv(path):
    with open(path) as f:
        head = f.readline().strip().split(",")
        rows = []
        for line in f:
            vals = line.strip().split(",")
            rows.append({h: (float(v) if v else None) for h, v in zip(head, vals)})
    return rows


def slope(xs, ys):
    n = len(xs)
    mx, my = sum(xs) / n, sum(ys) / n
    sxy = sum((a - mx) * (b - my) for a, b in zip(xs, ys))
    sxx = sum((a - mx) ** 2 for a in xs)
    return sxy / sxx


def v_shape(report, t_label):
    """Per GALI order, the MPM d0 closest to VM (mean over sets of |delta log10 GALI|)."""
    mpm = sorted((s for s in report["schemes"] if s["method"] == "mpm" and "vs_vm" in s),
                 key=lambda s: s["d0"])
    k = mpm[0]["k"]
    best = {}
    for j in range(2, k + 1):
        d = [(s["d0"], s["vs_vm"]["gali"][str(j)]["mean_abs_delta_log10"]) for s in mpm]
        best[j] = min(d, key=lambda p: p[1])[0]
    print(f"  V-shape minima at t = {t_label}: " +
          ", ".join(f"GALI_{j}: {d:.0e}" for j, d in best.items()))
    return best


def departure(csv_rows, j, threshold=0.3):
    """First t at which MPM GALI_j differs from VM by more than `threshold` decades."""
    col = f"gali{j}_vs_vm_mean_abs_delta_log10"
    for r in csv_rows:
        if r.get(col) is not None and r["t"] > 0 and r[col] > threshold:
            return r["t"]
    return None


def fig_pss(p):
    cfg = p.config("hh_pss.toml", {r"^t_final = .*": "t_final = 1000.0"} if p.reduced else None)
    count, cross = (12, 150) if p.reduced else (40, 500)
    p.sh("section", cfg, "--vary", "q2", "--from", "-0.42", "--to", "0.66", "--count", count,
         "--crossings", cross, "--plot", p.out / "pss")
    return {"pss": p.out / "pss" / "section.png"}


def fig_hh_regular(p):
    subs = {r"^sets = .*": "sets = 4"} if p.reduced else None
    mcap = p.record(p.config("hh_regular.toml", subs), "hh_regular")
    r = p.analyze(mcap, "--plot", p.out / "hh_regular", "--csv", p.out / "hh_regular_csv")
    t_end = r["run"]["t"]
    # The power laws are asymptotic (the orbit lies near the edge of its island: long
    # transient); fit the last decade.
    all_rows = read_csv(p.out / "hh_regular_csv" / "vm.csv")
    rows = [x for x in all_rows if x["t"] >= t_end / 10]
    t = [lg(x["t"]) for x in rows]
    slopes = {j: slope(t, [x[f"gali{j}_log10_mean"] for x in rows]) for j in (2, 3, 4)}
    # A regular orbit's finite-time MLE falls like ln(t)/t: log-log slope 1/ln(t) - 1, i.e.
    # -0.85 ... -0.9 over [1e2, 1e4].
    mle = [x for x in all_rows if x["t"] >= t_end / 100]
    mle_slope = slope([lg(x["t"]) for x in mle], [lg(x["lyapunov1"]) for x in mle])
    print(f"  regular HH: log-log slopes GALI_2 {slopes[2]:.2f}, GALI_3 {slopes[3]:.2f}, "
          f"GALI_4 {slopes[4]:.2f}; MLE {mle_slope:.2f}")
    # GALI_2 oscillates on a torus; "constant" means far from the next law (t^-2).
    check("HH regular GALI_2 constant", abs(slopes[2]) < 0.4, f"slope {slopes[2]:.3f}")
    check("HH regular GALI_3 ~ t^-2", abs(slopes[3] + 2) < 0.3, f"slope {slopes[3]:.3f}")
    check("HH regular GALI_4 ~ t^-4", abs(slopes[4] + 4) < 0.4, f"slope {slopes[4]:.3f}")
    check("HH regular MLE ~ ln(t)/t", -1.1 <= mle_slope <= -0.75, f"slope {mle_slope:.3f}")
    dep = {}
    for s in ("mpm-d0-1e-5", "mpm", "mpm-d0-1e-11"):
        rows = read_csv(p.out / "hh_regular_csv" / f"{s}.csv")
        dep[s] = {j: departure(rows, j) for j in (2, 3, 4)}
    print(f"  MPM departs from VM (|dlog10 GALI| > 0.3) at: {dep}")
    NUMBERS["hh_regular"] = {"slopes": slopes, "mle_slope": mle_slope, "mpm_departure": dep,
                             "t": r["run"]["t"]}
    return {"hh_regular_gali_vm": p.out / "hh_regular" / "gali_vm.png",
            "hh_regular_gali_mpm": p.out / "hh_regular" / "gali_mpm.png",
            "hh_regular_mle": p.out / "hh_regular" / "mle.png"}


def fig_hh_chaotic(p):
    subs = {r"^sets = .*": "sets = 4"} if p.reduced else None
    mcap = p.record(p.config("hh_chaotic.toml", subs), "hh_chaotic")
    r = p.analyze(mcap, "--plot", p.out / "hh_chaotic", "--csv", p.out / "hh_chaotic_csv")
    mle = scheme(r, "vm")["mle"]
    spectrum = scheme(r, "qr")["lyapunov"]
    print(f"  chaotic HH at t = {r['run']['t']}: MLE {mle:.4f}, spectrum {spectrum}")
    # numerics.md: independent runs give 0.038 ... 0.066 at t = 1e3.
    check("HH chaotic MLE band at t = 1000", 0.035 <= mle <= 0.07, f"{mle:.4f}")
    vm = read_csv(p.out / "hh_chaotic_csv" / "vm.csv")
    qr = {x["t"]: x for x in read_csv(p.out / "hh_chaotic_csv" / "qr.csv")}
    rates = {}
    # Fit ln GALI_j from past the l2 transient to where it nears the double-precision floor,
    # against sum_{i<=j}(l1 - l_i) = (1, 2, 4) l1 with l1 measured on the same window (QR).
    for j, factor, start, stop in ((2, 1, 200, -10), (3, 2, 50, -20), (4, 4, 50, -22)):
        win = []
        for x in vm:
            if x["t"] < start:
                continue
            if x[f"gali{j}_log10_mean"] < stop:
                break
            win.append(x)
        win = [x for x in win if x["t"] in qr]
        ts = [x["t"] for x in win]
        rate = -slope(ts, [x[f"gali{j}_log10_mean"] * math.log(10) for x in win])
        a, b = ts[0], ts[-1]
        l1 = (qr[b]["lyapunov1"] * b - qr[a]["lyapunov1"] * a) / (b - a)
        rates[j] = (rate, factor * l1, a, b)
        check(f"HH chaotic GALI_{j} rate ~ {factor} l1", abs(rate / (factor * l1) - 1) < 0.25,
              f"{rate:.4f} vs {factor * l1:.4f} on t in [{a}, {b}]")
    mpm = read_csv(p.out / "hh_chaotic_csv" / "mpm.csv")
    dep = {j: departure(mpm, j) for j in (2, 3, 4)}
    print(f"  MPM (d0 = 1e-8) departs from VM at t = {dep}")
    at200 = p.analyze(mcap, "--at", "200")
    g200 = {j: scheme(at200, "vm")["gali"][str(j)] for j in (2, 3, 4)}
    NUMBERS["hh_chaotic"] = {"mle": mle, "spectrum": spectrum, "rates": rates,
                             "mpm_departure": dep,
                             "vm_gali_t200": {j: (g["mean"], g["log10_mean"])
                                              for j, g in g200.items()}}
    return {"hh_chaotic_gali_vm": p.out / "hh_chaotic" / "gali_vm.png",
            "hh_chaotic_gali_mpm": p.out / "hh_chaotic" / "gali_mpm.png",
            "hh_chaotic_mle": p.out / "hh_chaotic" / "mle.png",
            "hh_chaotic_spectrum": p.out / "hh_chaotic" / "spectrum_qr.png"}


def fig_hh_d0(p):
    subs = {r"^sets = .*": "sets = 20"} if p.reduced else None
    mcap = p.record(p.config("hh_d0_sweep.toml", subs), "hh_d0")
    r = p.analyze(mcap, "--plot", p.out / "hh_d0")
    best = v_shape(r, 200)
    check("HH V-shape: GALI_2 closest to VM at 1e-8 +- 1 decade",
          abs(lg(best[2]) + 8) <= 1.01, f"{best[2]:.0e}")
    NUMBERS["hh_d0_best"] = best
    return {"hh_d0": p.out / "hh_d0" / "sweep_gali_vs_d0_tau1e0.png"}


def fig_hh_tau(p):
    subs = {r"^sets = .*": "sets = 10", r"^tau = \[.*": "tau = [0.1, 1.0, 10.0, 100.0]"} \
        if p.reduced else None
    mcap = p.record(p.config("hh_tau_sweep.toml", subs), "hh_tau")
    r = p.analyze(mcap, "--plot", p.out / "hh_tau")
    mpm = sorted((s for s in r["schemes"] if s["method"] == "mpm"), key=lambda s: s["tau"])
    table = {s["tau"]: {j: s["gali"][str(j)]["log10_mean"] for j in (2, 3, 4)} for s in mpm}
    for tau, g in table.items():
        print(f"  tau = {tau}: log10 geometric mean GALI_2,3,4 = "
              + ", ".join(f"{v:.3f}" for v in g.values()))
    low = [g[2] for tau, g in table.items() if tau <= 1]
    check("HH tau <= 1: GALI_2 flat", max(low) - min(low) < 0.15,
          f"spread {max(low) - min(low):.3f} decades")
    NUMBERS["hh_tau"] = table
    return {"hh_tau": p.out / "hh_tau" / "sweep_gali_vs_tau_d01e-9.png"}


def fig_hh_h(p):
    hs = [0.025, 0.05, 0.1, 0.2] if p.reduced else \
        [0.005, 0.01, 0.02, 0.025, 0.05, 0.1, 0.125, 0.2, 0.25, 0.5]
    sets = "sets = 5" if p.reduced else "sets = 100"
    rows = []
    for h in hs:
        cfg = p.config("hh_h.toml", {r"^h = .*": f"h = {h}", r"^sets = .*": sets},
                       tag=f"hh_h_{h}.toml")
        r = p.analyze(p.record(cfg, f"hh_h_{h}"))
        rows.append((h, r["run"]["energy_error_max"],
                     {j: scheme(r, "mpm")["gali"][str(j)]["mean"] for j in (2, 3, 4)},
                     {j: scheme(r, "vm")["gali"][str(j)]["mean"] for j in (2, 3, 4)}))
    for h, er, g, gv in rows:
        print(f"  h = {h}: E_r = {er:.2e}; MPM GALI_2,3,4 = "
              + ", ".join(f"{v:.2e}" for v in g.values()))
    fit = [(lg(h), lg(er)) for h, er, _, _ in rows if 0.02 <= h <= 0.2]
    order = slope([a for a, _ in fit], [b for _, b in fit])
    check("E_r ~ h^4 (ABA864)", abs(order - 4) < 0.5, f"slope {order:.2f}")
    p.chart({"title": "HH chaotic orbit: maximum relative energy error up to t = 200",
             "x_label": "log10 h", "y_label": "log10 E_r",
             "lines": [{"label": "ABA864", "points": [[lg(h), lg(er)] for h, er, _, _ in rows],
                        "stroke": "solid", "color": 2},
                       {"label": "slope 4", "stroke": "dashed", "color": 0,
                        "points": [[lg(hs[0]), lg(rows[0][1])],
                                   [lg(hs[-1]), lg(rows[0][1]) + 4 * (lg(hs[-1]) - lg(hs[0]))]]}]},
            "er_vs_h")
    lines = []
    for j in (2, 3, 4):
        lines.append({"label": f"GALI_{j} MPM", "color": j - 1, "stroke": "solid",
                      "points": [[lg(h), lg(g[j])] for h, _, g, _ in rows]})
        lines.append({"label": f"GALI_{j} VM" if j == 2 else "", "color": j - 1,
                      "stroke": "dashed", "points": [[lg(h), lg(gv[j])] for h, _, _, gv in rows]})
    p.chart({"title": "HH chaotic orbit: GALI_k at t = 200 against h (d0 = 1e-9, tau = 1)",
             "x_label": "log10 h", "y_label": "log10 GALI_k (arithmetic mean)", "lines": lines},
            "gali_vs_h")
    NUMBERS["hh_h"] = {"order": order, "rows": rows}
    return {"er_vs_h": p.out / "er_vs_h.png", "gali_vs_h": p.out / "gali_vs_h.png"}


def fig_fput5_regular(p):
    subs = {r"^sets = .*": "sets = 1"} if p.reduced else None
    mcap = p.record(p.config("fput5_regular.toml", subs), "fput5_regular")
    r = p.analyze(mcap, "--plot", p.out / "fput5_regular", "--csv", p.out / "fput5_regular_csv")
    t_end = r["run"]["t"]
    rows = [x for x in read_csv(p.out / "fput5_regular_csv" / "vm.csv") if x["t"] >= t_end / 10]
    t = [lg(x["t"]) for x in rows]
    slopes = {j: slope(t, [x[f"gali{j}_log10_mean"] for x in rows]) for j in (2, 4, 6, 8, 10)}
    print("  FPUT N=5 regular VM log-log slopes: " +
          ", ".join(f"GALI_{j} {s:.2f}" for j, s in slopes.items()))
    # GALI_8 and GALI_10 reach their laws within t = 1e4; GALI_4 (constant) and GALI_6 (t^-2)
    # are still in their transient on this orbit near SPO1 (slopes ~ -1 and ~ -2.8 over
    # [1e3, 1e4]; see RESULTS.md), so they are reported, not checked.
    for j, want in ((8, -6), (10, -10)):
        check(f"FPUT5 regular GALI_{j} ~ t^{want}", abs(slopes[j] / want - 1) < 0.2,
              f"slope {slopes[j]:.2f}")
    dep = {}
    for s in ("mpm", "mpm-d0-1e-11"):
        mrows = read_csv(p.out / "fput5_regular_csv" / f"{s}.csv")
        dep[s] = {j: departure(mrows, j) for j in (2, 4, 6, 8, 10)}
    print(f"  MPM departs from VM at: {dep}")
    NUMBERS["fput5_regular"] = {"slopes": slopes, "mpm_departure": dep, "t": r["run"]["t"]}
    return {"fput5_regular_gali_vm": p.out / "fput5_regular" / "gali_vm.png",
            "fput5_regular_gali_mpm": p.out / "fput5_regular" / "gali_mpm.png"}


def fig_fput5_chaotic(p):
    subs = {r"^sets = .*": "sets = 2"} if p.reduced else None
    mcap = p.record(p.config("fput5_chaotic.toml", subs), "fput5_chaotic")
    r = p.analyze(mcap, "--plot", p.out / "fput5_chaotic", "--csv", p.out / "fput5_chaotic_csv")
    mrows = read_csv(p.out / "fput5_chaotic_csv" / "mpm.csv")
    dep = {j: departure(mrows, j) for j in (2, 4, 6, 8, 10)}
    mle = scheme(r, "vm")["mle"]
    print(f"  FPUT N=5 chaotic: MLE(t = 200) {mle:.4f}; MPM (1e-8) departs at {dep}")
    NUMBERS["fput5_chaotic"] = {"mle_t200": mle, "mpm_departure": dep}
    return {"fput5_chaotic_gali_vm": p.out / "fput5_chaotic" / "gali_vm.png",
            "fput5_chaotic_gali_mpm": p.out / "fput5_chaotic" / "gali_mpm.png"}


def fig_fput5_d0(p):
    subs = {r"^sets = .*": "sets = 20", r"^t_final = .*": "t_final = 50.0"} if p.reduced else None
    mcap = p.record(p.config("fput5_d0_sweep.toml", subs), "fput5_d0")
    best50 = v_shape(p.analyze(mcap, "--at", "50"), 50)
    check("FPUT5 V-shape at t = 50: GALI_2 closest to VM at 1e-8 +- 1 decade",
          abs(lg(best50[2]) + 8) <= 1.01, f"{best50[2]:.0e}")
    NUMBERS["fput5_d0_best_t50"] = best50
    figs = {}
    p.analyze(mcap, "--at", "50", "--plot", p.out / "fput5_d0_t50")
    figs["fput5_d0_t50"] = p.out / "fput5_d0_t50" / "sweep_gali_vs_d0_tau1e0.png"
    if not p.reduced:
        for t in (80, 100):
            NUMBERS[f"fput5_d0_best_t{t}"] = v_shape(p.analyze(mcap, "--at", str(t)), t)
        r = p.analyze(mcap, "--plot", p.out / "fput5_d0")
        NUMBERS["fput5_d0_best_t200"] = v_shape(r, 200)
        figs["fput5_d0_t200"] = p.out / "fput5_d0" / "sweep_gali_vs_d0_tau1e0.png"
    return figs


def fig_fput_large(p, n):
    mcap = p.record(p.config(f"fput{n}_d0_sweep.toml"), f"fput{n}_d0")
    r = p.analyze(mcap, "--plot", p.out / f"fput{n}_d0")
    best = v_shape(r, r["run"]["t"])
    NUMBERS[f"fput{n}_d0_best"] = best
    NUMBERS[f"fput{n}_mle"] = scheme(r, "vm")["mle"]
    return {f"fput{n}_d0": p.out / f"fput{n}_d0" / "sweep_gali_vs_d0_tau1e0.png"}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--reduced", action="store_true", help="CI mode: small and quick")
    ap.add_argument("--chaoscope", default=os.environ.get("CHAOSCOPE"),
                    help="chaoscope binary (default: $CHAOSCOPE or target/release/chaoscope)")
    ap.add_argument("--out", default=None, help="work directory (default: examples/paper/out)")
    args = ap.parse_args()
    binary = Path(args.chaoscope) if args.chaoscope else None
    if binary is None:
        target = Path(os.environ.get("CARGO_TARGET_DIR", HERE.parent.parent / "target"))
        binary = target / "release" / "chaoscope"
    if not binary.exists():
        sys.exit(f"no chaoscope binary at {binary}: build with `cargo build --release` "
                 "or pass --chaoscope")
    out = Path(args.out) if args.out else HERE / ("out-reduced" if args.reduced else "out")
    out.mkdir(parents=True, exist_ok=True)
    p = Paper(binary.resolve(), out.resolve(), args.reduced)

    figures = {}
    steps = [fig_pss, fig_hh_regular, fig_hh_chaotic, fig_hh_d0, fig_hh_tau, fig_hh_h,
             fig_fput5_regular, fig_fput5_chaotic, fig_fput5_d0]
    for step in steps:
        print(f"== {step.__name__[4:]}", flush=True)
        figures.update(step(p))
    if not args.reduced:
        for n in (11, 101):
            print(f"== fput{n}_d0", flush=True)
            figures.update(fig_fput_large(p, n))
    (out / "numbers.json").write_text(json.dumps(NUMBERS, indent=1, default=str))
    missing = [str(f) for f in figures.values() if not Path(f).exists()]
    check("every figure was drawn", not missing, ", ".join(missing) or f"{len(figures)} PNGs")
    if not args.reduced:
        FIGURES.mkdir(exist_ok=True)
        for name, path in figures.items():
            shutil.copyfile(path, FIGURES / f"{name}.png")
        print(f"copied {len(figures)} figures to {FIGURES}")
    if FAILURES:
        print(f"{len(FAILURES)} check(s) failed:\n  " + "\n  ".join(FAILURES))
        sys.exit(1)
    print("all checks passed")


if __name__ == "__main__":
    main()
