#!/usr/bin/env python3
"""Weak chaos of the disordered Klein-Gordon chain and of the disordered discrete nonlinear
Schroedinger equation (Skokos, Gkolias and Flach, PRL 111, 064101, 2013; Senyange, Many Manda and
Skokos, PRE 98, 052229, 2018): the finite-time maximal Lyapunov exponent averaged over disorder
realizations decays as t^alpha with alpha near -1/4, and the wave packet's second moment (of the
energy for the DKG, of the norm for the DDNLS) grows as t^(1/3).

    examples/weak-chaos/run.py [--model dkg|ddnls] [--excitation site|block] [--realizations 20]
                               [--first-seed 1 | --seeds 1-11,16] [--sites N] [--t-final T]
                               [--jobs 2]
                               [--chaoscope PATH] [--out DIR]

Each realization is `examples/models/dkg-single-site.toml` with its own disorder seed (1, 2,
...): W = 4, eps_l uniform in [1/2, 3/2], fixed ends, a single site in the middle excited with
E = 0.4, ABA864 with h = 0.2 (relative energy error ~2e-7), one VM vector renormalized and
recorded every 100 time units. `chaoscope run` records each (recordings already in DIR are
kept, so an interrupted campaign goes on where it stopped), `chaoscope analyze --csv` gives the
curves, and `chaoscope chart` draws the averages. Prints the fitted exponents and the total CPU
time as JSON; exits non-zero when alpha is outside [-0.30, -0.20] or the second moment's
exponent is more than 0.08 from 1/3. Standard library only.

With --model ddnls (defaults N = 200, t_final = 1e5) each realization is
`examples/models/ddnls-block.toml` with its own disorder seed: W = 4 (eps_l uniform in [-2, 2]),
fixed ends, a single site in the middle excited with norm 1 (psi_100 = 1), beta = 1 (the
weak-chaos case W = 4, L = 1, beta = 1 of Flach, Krimer and Skokos, PRL 102, 024101 (2009), and
of the two papers above), s11abc6 with h = 0.1 (relative energy and norm errors ~1e-8), one VM
vector renormalized and recorded every 10 time units. The analyzer's energy distribution is not
defined for the DDNLS (its site energies are not positive shares), and the papers' distribution
is the norm's, z_l = |psi_l|^2 / S: its second moment is computed here from the recorded
reference states, read with the `chaoscope` Python package (numpy). With --excitation block the
DDNLS starts instead from 21 central sites with norm 1 each and phases drawn from the
realization's seed, at beta = 0.04 (the weak-chaos case W = 4, L = 21 of Laptyeva et al., EPL 91,
30001 (2010)).

With --keep-curves each realization's curves (t, Lambda, m2) are also written to
`DIR/rSEED.curve.csv`, thinned to 200 samples per decade of t (every sample below t = 100), and a
realization whose curve file was made from the same configuration is not run again, its
recording no longer needed: a campaign longer than one machine's day is carried from machine to
machine in those small files (committed beside RESULTS.md). Every realization's curve is then
the thinned one, so fresh and carried ones average alike; the fit's points (20 per decade from a
decade boundary) are samples the thinning keeps.
"""

import argparse
import bisect
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
EXAMPLE = HERE.parent / "models" / "dkg-single-site.toml"
DDNLS_EXAMPLE = HERE.parent / "models" / "ddnls-block.toml"
# The fit range starts one decade after the peak of <log10 Lambda>. A single excited site is
# first nearly regular: the exponent grows while chaos builds up inside the initial packet and
# peaks (near t = 5000 for this setting); the decay that follows is the crossover to the
# spreading regime, whose local slope settles within about a decade. The range then ends at
# t_final, at least a decade later.
PEAK_TO_FIT = 10.0
# The DDNLS's single site reaches its linear localization volume (about 20 sites at W = 4) by
# t ~ 100, where m2 pauses before the nonlinear spreading takes over; its MLE peaks earlier than
# the DKG's (its fastest frequencies are ~5 against ~1.5). The fit therefore starts no earlier
# than t = 1000, a decade after that pause: [max(10 t_peak, 1000), t_final].
DDNLS_FIT_NOT_BEFORE = 1000.0
# A longer run fits its last two decades only (--fit-decades): the 10^5 campaign's local slopes
# of <log10 Lambda> were -0.10 over 10^3..10^4 and -0.17 over 10^4..10^5, a crossover still
# under way in the first of those decades. Fixed before the 10^6 campaign was run. The 10^6
# campaigns (single site and block) then showed the crossover lasting to about 3 10^5 in both
# settings (single site: -0.13 over 10^4..10^5, -0.21 over 3 10^5..10^6; block: -0.15 over
# 10^5..3 10^5, -0.20 over 3 10^5..10^6, -0.23 over the last quarter decade): a 10^7 campaign
# fits its last decade (--fit-decades 1), fixed before it was run.
DDNLS_FIT_DECADES = 2.0
# The block excitation of Laptyeva et al. (EPL 91, 30001, 2010): L = 21 sites with norm 1 each
# and random phases, W = 4; beta = 0.04 is their weak-chaos case (beta = 0.72 strong chaos).
BLOCK = 21
BLOCK_BETA = 0.04
# Defaults of (sites, t_final) per model. The DDNLS's norm second moment reaches ~10^2 at
# t = 10^5 (Flach, Krimer and Skokos 2009), far below N^2 / 12 = 3333 for N = 200.
DEFAULTS = {"dkg": (300, 1e6), "ddnls": (200, 1e5)}


def config(sites, t_final, seed):
    text = EXAMPLE.read_text()
    subs = [
        (r"(?m)^n = \d+$", f"n = {sites}"),
        (r"sites = \d+,", f"sites = {sites // 2},"),
        (r"(?m)^h = .*$", "h = 0.2"),
        (r"(?m)^t_final = .*$", f"t_final = {t_final!r}"),
        (r"(?m)^k = \d+$", "k = 1"),
        (r"(?m)^tau = .*$", "tau = 100.0"),
        (r"seed = 1 \}", f"seed = {seed} }}"),
        (r'(?m)^name = "dkg-single-site"$', f'name = "weak-chaos-{seed}"'),
    ]
    for pattern, new in subs:
        text, count = re.subn(pattern, new, text, count=1)
        if count != 1:
            sys.exit(f"the example changed shape: {pattern!r} not found in {EXAMPLE}")
    return text


def ddnls_config(sites, t_final, seed, h=0.1, tau=10.0, excitation="site"):
    text = DDNLS_EXAMPLE.read_text()
    if excitation == "site":
        beta, excite = 1.0, f"{{ sites = {sites // 2}, norm = 1.0 }}"
    else:
        # BLOCK central sites with norm 1 each and random phases drawn from the realization's
        # seed, so that disorder and phases change together from one realization to the next.
        # The phases and the disorder come from the same stream: the phases of the block repeat
        # the draws of the disorder at sites 1..BLOCK, a fixed end the packet never reaches
        # (the scripts check the norm near the ends), independent of the disorder under it.
        first = sites // 2 - BLOCK // 2
        beta = BLOCK_BETA
        excite = f"{{ sites = [{first}, {first + BLOCK - 1}], norm = {float(BLOCK)!r}, seed = {seed} }}"
    subs = [
        (r"(?m)^n = \d+$", f"n = {sites}"),
        (r"(?m)^beta = .*$", f"beta = {beta!r}"),
        (r"(?m)^seed = 1$", f"seed = {seed}"),
        (r"(?m)^excite = .*$", f"excite = {excite}"),
        (r"(?m)^h = .*$", f"h = {h!r}"),
        (r"(?m)^t_final = .*$", f"t_final = {t_final!r}"),
        (r"(?m)^k = \d+$", "k = 1"),
        (r"(?m)^tau = .*$", f"tau = {tau!r}"),
        (r'(?m)^name = "ddnls-block"$', f'name = "weak-chaos-ddnls-{seed}"'),
    ]
    for pattern, new in subs:
        text, count = re.subn(pattern, new, text, count=1)
        if count != 1:
            sys.exit(f"the example changed shape: {pattern!r} not found in {DDNLS_EXAMPLE}")
    # One VM scheme only: the example's MPM scheme is cut.
    return text[:text.index("[[scheme]]\nname = \"mpm\"")]


def norm_m2(mcap, times):
    """The norm distribution's second moment at `times`, from the recorded reference states."""
    import chaoscope  # the Python package: numpy arrays of the recorded states
    import numpy as np
    orbit = chaoscope.open(str(mcap)).orbit()
    at = {float(t): i for i, t in enumerate(orbit.t)}
    x = orbit.states[[at[t] for t in times]]
    n = x.shape[1] // 2
    z = (x[:, :n] ** 2 + x[:, n:] ** 2) / 2
    z = z / z.sum(axis=1, keepdims=True)
    l = np.arange(1, n + 1)
    mean = z @ l
    return list((z * (l[None, :] - mean[:, None]) ** 2).sum(axis=1))


def recording_status(mcap):
    """The recording's run status ("completed", "interrupted", ...), read with the `chaoscope`
    Python package; None where the package is not installed (the DKG path needs only the
    standard library)."""
    try:
        import chaoscope
    except ImportError:
        return None
    return chaoscope.open(str(mcap)).status


# --keep-curves: samples kept per decade of t, and below which t every sample is kept.
CURVE_PER_DECADE = 200
CURVE_ALL_BELOW = 100.0


def thinned(rows):
    """The rows nearest to t = 10^(j / CURVE_PER_DECADE), and every row below CURVE_ALL_BELOW."""
    keep = {i for i, r in enumerate(rows) if r[0] < CURVE_ALL_BELOW}
    if rows:
        lo, hi = math.log10(max(rows[0][0], CURVE_ALL_BELOW)), math.log10(rows[-1][0])
        ts = [r[0] for r in rows]
        for j in range(math.floor(lo * CURVE_PER_DECADE), math.ceil(hi * CURVE_PER_DECADE) + 1):
            want = 10 ** (j / CURVE_PER_DECADE)
            keep.add(nearest(ts, want))
    return [rows[i] for i in sorted(keep)]


def nearest(ts, want):
    """The index of the time in the sorted `ts` nearest to `want`."""
    k = bisect.bisect_left(ts, want)
    if k == 0:
        return 0
    if k == len(ts):
        return len(ts) - 1
    return k if ts[k] - want < want - ts[k - 1] else k - 1


def read_curve(path):
    with open(path) as f:
        return [(float(r["t"]), float(r["lyapunov1"]), float(r["m2"])) for r in csv.DictReader(f)]


def write_curve(path, rows):
    tmp = path.with_suffix(".tmp")
    with open(tmp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["t", "lyapunov1", "m2"])
        # repr of a Python float: the shortest text that reads back to the same double (numpy's
        # floats would print as `np.float64(...)`).
        w.writerows([repr(float(v)) for v in row] for row in rows)
    tmp.replace(path)


def realization(chaoscope, out, model, sites, t_final, seed, h, tau, excitation,
                keep_curves=False):
    """Record realization `seed` (unless its recording, or with `keep_curves` its curve, exists)
    and read its curves."""
    mcap = out / f"r{seed}.mcap"
    cfg = out / f"r{seed}.toml"
    curve = out / f"r{seed}.curve.csv"
    text = (config(sites, t_final, seed) if model == "dkg"
            else ddnls_config(sites, t_final, seed, h, tau, excitation))
    if keep_curves and curve.exists():
        if not cfg.exists() or cfg.read_text() != text:
            sys.exit(f"run.py: {curve} was made with other settings than these "
                     f"({cfg} differs); choose another --out")
        return read_curve(curve)
    if mcap.exists():
        # A recording is reused only if it was made from the configuration this run would write.
        if not cfg.exists() or cfg.read_text() != text:
            sys.exit(f"run.py: {mcap} was recorded with other settings than these "
                     f"({cfg} differs); choose another --out")
        # An interrupted or failed run is finalized too: only a completed one is reused.
        status = recording_status(mcap)
        if status not in (None, "completed"):
            sys.exit(f"run.py: {mcap} holds a run that ended {status}, not completed; delete it to run "
                     f"that realization again")
    else:
        cfg.write_text(text)
        subprocess.run([chaoscope, "run", cfg, "--out", mcap], check=True,
                       stdout=subprocess.DEVNULL)
    csv_dir = out / f"r{seed}.csv"
    shutil.rmtree(csv_dir, ignore_errors=True)
    subprocess.run([chaoscope, "analyze", mcap, "--csv", csv_dir], check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    with open(csv_dir / "vm.csv") as f:
        rows = [r for r in csv.DictReader(f) if float(r["t"]) > 0]
    if model == "ddnls":
        m2 = norm_m2(mcap, [float(r["t"]) for r in rows])
        rows = [(float(r["t"]), float(r["lyapunov1"]), m) for r, m in zip(rows, m2)]
    else:
        rows = [(float(r["t"]), float(r["lyapunov1"]), float(r["energy_m2"])) for r in rows]
    if keep_curves:
        rows = thinned(rows)
        write_curve(curve, rows)
    return rows


def slope(xs, ys):
    mx, my = sum(xs) / len(xs), sum(ys) / len(ys)
    return sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sum((x - mx) ** 2 for x in xs)


def seed_list(text):
    """`1-11,16` -> [1, ..., 11, 16]: distinct non-negative seeds, in the order given."""
    seeds = []
    try:
        for part in text.split(","):
            first, _, last = part.partition("-")
            seeds += range(int(first), int(last or first) + 1)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected seeds such as 1-11,16")
    if not seeds or min(seeds) < 0 or len(set(seeds)) != len(seeds):
        raise argparse.ArgumentTypeError(f"{text!r}: distinct seeds of at least 0 expected")
    return seeds


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", choices=["dkg", "ddnls"], default="dkg")
    ap.add_argument("--realizations", type=int, default=20)
    ap.add_argument("--sites", type=int, help="default 300 (dkg), 200 (ddnls)")
    ap.add_argument("--t-final", type=float, help="default 1e6 (dkg), 1e5 (ddnls)")
    ap.add_argument("--h", type=float, default=0.1,
                    help="ddnls: the s11abc6 step (default 0.1; 0.2 keeps both errors ~1e-6)")
    ap.add_argument("--tau", type=float, default=10.0,
                    help="ddnls: renormalization and sampling interval (default 10)")
    ap.add_argument("--excitation", choices=["site", "block"], default="site",
                    help="ddnls: one site with norm 1 and beta = 1 (default), or a block of 21 "
                         "sites with norm 1 each, random phases and beta = 0.04")
    ap.add_argument("--first-seed", type=int, default=1,
                    help="disorder seed of the first realization (default 1; a pilot uses others)")
    ap.add_argument("--seeds", type=seed_list,
                    help="the disorder seeds, e.g. 1-11,16 (instead of --first-seed and "
                         "--realizations: a campaign run on several machines at once)")
    ap.add_argument("--fit-decades", type=float, default=DDNLS_FIT_DECADES,
                    help="ddnls: the fit covers at most this many decades before t_final "
                         "(default 2)")
    ap.add_argument("--keep-curves", action="store_true",
                    help="write each realization's thinned curves to DIR/rSEED.curve.csv and "
                         "reuse them instead of running it again (a campaign carried across "
                         "machines)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--chaoscope", default="chaoscope")
    ap.add_argument("--out", type=Path, default=Path("weak-chaos"))
    a = ap.parse_args()
    a.sites = a.sites or DEFAULTS[a.model][0]
    a.t_final = a.t_final or DEFAULTS[a.model][1]
    # What chaoscope would refuse anyway, said before any run starts.
    least_sites = BLOCK + 1 if a.model == "ddnls" and a.excitation == "block" else 3
    if a.sites < least_sites:
        ap.error(f"--sites {a.sites}: at least {least_sites} for this excitation")
    if a.first_seed < 0 or a.realizations < 1 or a.jobs < 1:
        ap.error("--first-seed must be at least 0, --realizations and --jobs at least 1")
    if not a.fit_decades > 0:
        ap.error(f"--fit-decades {a.fit_decades}: must be positive")
    seeds = a.seeds or list(range(a.first_seed, a.first_seed + a.realizations))
    a.out.mkdir(parents=True, exist_ok=True)
    try:
        with concurrent.futures.ThreadPoolExecutor(a.jobs) as pool:
            curves = list(pool.map(lambda s: realization(a.chaoscope, a.out, a.model, a.sites,
                                                         a.t_final, s, a.h, a.tau,
                                                         a.excitation, a.keep_curves),
                                   seeds))
    except subprocess.CalledProcessError as e:
        # `chaoscope run` has said why on standard error; name the command that failed.
        sys.exit(f"run.py: {' '.join(map(str, e.cmd))} failed with status {e.returncode}")
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    times = [t for t, _, _ in curves[0]]
    if any([t for t, _, _ in c] != times for c in curves):
        sys.exit("the realizations were not sampled at the same times")
    n = len(curves)
    # Averages of the logarithms over the realizations (the paper's <log10 Lambda>).
    log_mle = [sum(math.log10(c[i][1]) for c in curves) / n for i in range(len(times))]
    log_m2 = [sum(math.log10(c[i][2]) for c in curves) / n for i in range(len(times))]
    fit_from = PEAK_TO_FIT * times[max(range(len(times)), key=lambda i: log_mle[i])]
    if a.model == "ddnls":
        fit_from = max(fit_from, DDNLS_FIT_NOT_BEFORE, a.t_final / 10 ** a.fit_decades)
    if fit_from * 10 > times[-1] * (1 + 1e-9):
        sys.exit(f"the fit would start at t = {fit_from:g}, less than a decade before "
                 f"t_final: raise --t-final")
    # Samples come every 100 time units; a fit over all of them would weigh the last decade
    # ten times the one before. 20 points per decade, evenly spaced in log t, weigh each alike.
    first = next(i for i, t in enumerate(times) if t >= fit_from)
    decades = math.log10(times[-1] / times[first])
    wanted = [times[first] * 10 ** (j / 20) for j in range(int(decades * 20) + 1)]
    fit = sorted({min(range(first, len(times)), key=lambda i: abs(times[i] - w)) for w in wanted})
    lt = [math.log10(times[i]) for i in fit]
    alpha = slope(lt, [log_mle[i] for i in fit])
    alpha_m = slope(lt, [log_m2[i] for i in fit])
    # The spread: each realization's own exponent over the same range.
    own = [slope(lt, [math.log10(c[i][1]) for i in fit]) for c in curves]
    mean_own = sum(own) / n
    sd_own = math.sqrt(sum((x - mean_own) ** 2 for x in own) / (n - 1)) if n > 1 else float("nan")
    lg_t = [math.log10(t) for t in times]
    for what, ys, law, label in (("mle", log_mle, alpha, "log10 <Lambda>"),
                                 ("m2", log_m2, alpha_m, "log10 <m2>")):
        # The least-squares line itself (through the fitted points' centre).
        mx = sum(lt) / len(lt)
        my = sum(ys[i] for i in fit) / len(fit)
        title = (f"DKG weak chaos, W = 4, E = 0.4, N = {a.sites}, {n} realizations"
                 if a.model == "dkg" else
                 f"DDNLS weak chaos, W = 4, beta = 1, norm 1 on one site, N = {a.sites}, "
                 f"{n} realizations" if a.excitation == "site" else
                 f"DDNLS weak chaos, W = 4, beta = {BLOCK_BETA}, norm 1 on {BLOCK} sites, "
                 f"N = {a.sites}, {n} realizations")
        spec = {"title": title,
                "x_label": "log10 t", "y_label": label,
                "lines": [{"label": "chaoscope (mean of the logs)", "color": 2, "stroke": "solid",
                           "points": [[x, y] for x, y in zip(lg_t, ys)]},
                          {"label": f"fit from t = {fit_from:.3g}: slope {law:.3f}", "color": 0,
                           "stroke": "dashed",
                           "points": [[x, my + law * (x - mx)] for x in (lt[0], lt[-1])]}]}
        spec_path = a.out / f"{what}.json"
        spec_path.write_text(json.dumps(spec))
        subprocess.run([a.chaoscope, "chart", spec_path, "--out", a.out / what], check=True)
    report = {
        "realizations": n, "sites": a.sites, "t_final": a.t_final, "fit_from": fit_from,
        "alpha_mle": alpha, "alpha_mle_per_realization_mean": mean_own,
        "alpha_mle_per_realization_sd": sd_own, "alpha_m2": alpha_m,
        "mle_at_t_final": 10 ** log_mle[-1], "m2_at_t_final": 10 ** log_m2[-1],
        "cpu_seconds_of_runs_done_now": usage.ru_utime + usage.ru_stime,
    }
    if a.model == "ddnls":
        own_m = [slope(lt, [math.log10(c[i][2]) for i in fit]) for c in curves]
        mean_m = sum(own_m) / n
        report.update({
            "model": "ddnls", "fit_to": times[-1], "h": a.h, "tau": a.tau,
            "excitation": a.excitation, "first_seed": seeds[0], "seeds": seeds,
            "fit_decades": a.fit_decades,
            "alpha_mle_per_realization_standard_error": sd_own / math.sqrt(n),
            "alpha_m2_per_realization_mean": mean_m,
            "alpha_m2_per_realization_sd":
                math.sqrt(sum((x - mean_m) ** 2 for x in own_m) / (n - 1)) if n > 1
                else float("nan"),
            # The packet must stay well inside the chain: compare with a uniform spread.
            "m2_max_at_t_final": max(c[-1][2] for c in curves),
            "m2_of_uniform_chain": a.sites ** 2 / 12,
        })
    # A spread of one realization is undefined: null, never a NaN (which is not JSON).
    print(json.dumps({k: None if isinstance(v, float) and math.isnan(v) else v
                      for k, v in report.items()}, indent=1, allow_nan=False))
    ok = -0.30 <= alpha <= -0.20 and abs(alpha_m - 1 / 3) <= 0.08
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
