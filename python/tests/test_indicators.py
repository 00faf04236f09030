"""Recording.indicators() equals `chaoscope analyze --json` to the last bit.

Both run the recording through the same reader and analysis core, so every number must be
bit-identical (the JSON is written with shortest round-trip floats, so parsing it gives back the
same double). Compared at the end and at times inside the run (`--at T`), for VM, MPM and a QR
scheme (whose `lyapunov` is the whole spectrum), on the chaotic and the regular HH orbit.
"""

import csv
import math

import numpy as np
import pytest

import chaoscope
from conftest import hh_config


def bits(x):
    return float(x).hex()


def check_row(ind, row, report_scheme, energy_error_max):
    s = report_scheme
    assert bits(ind.t[row]) == bits(s["t"])
    assert int(ind.sets[row]) == s["sets"]
    for col, j in enumerate(ind.orders):
        g = s["gali"][str(j)]
        assert bits(ind.gali[row, col]) == bits(g["mean"]), (s["name"], j)
        assert bits(ind.gali_log10_mean[row, col]) == bits(g["log10_mean"]), (s["name"], j)
    assert bits(ind.sali[row]) == bits(s["sali"]["mean"])
    assert bits(ind.sali_log10_mean[row]) == bits(s["sali"]["log10_mean"])
    assert bits(ind.mle[row]) == bits(s["mle"])
    n = len(s["lyapunov"])
    # Rescaled schemes report the first vector's exponent, QR schemes the spectrum.
    assert [bits(v) for v in ind.exponents[row, :n]] == [bits(v) for v in s["lyapunov"]]
    # The report's energy error is the largest so far.
    assert bits(np.max(ind.energy_error[: row + 1])) == bits(energy_error_max)


@pytest.mark.parametrize("x2", [-0.25, 0.558], ids=["chaotic", "regular"])
def test_indicators_equal_analyze_json(tmp_path, analyze_json, x2):
    out = tmp_path / "hh.mcap"
    rec = chaoscope.run(hh_config(t_final=300.0, x2=x2), out=out)
    final = analyze_json(out)
    times = [37.0, 150.0]
    at = {t: analyze_json(out, at=t) for t in times}
    for report_scheme in final["schemes"]:
        ind = rec.indicators(report_scheme["name"])
        assert ind.method == report_scheme["method"]
        check_row(ind, len(ind.t) - 1, report_scheme, final["run"]["energy_error_max"])
        for t, report in at.items():
            row = int(np.searchsorted(ind.t, t, side="right")) - 1
            scheme = next(s for s in report["schemes"] if s["name"] == report_scheme["name"])
            check_row(ind, row, scheme, report["run"]["energy_error_max"])
    # And the dict of report() is that JSON.
    assert rec.report() == final
    assert rec.report(at=37.0) == at[37.0]


def test_indicators_are_the_physics(tmp_path):
    # Not only equal to the command: sane against the paper (numerics.md). Chaotic HH orbit,
    # t = 300: GALI_2 decays like exp(-(l1 - l2) t) with l1 ~ 0.04-0.07, so by t = 300 it is
    # far below its start (< 1e-3); the QR spectrum is Hamiltonian: pairs sum to zero within
    # the finite-time spread (0.02 at these times), two exponents near zero.
    rec = chaoscope.run(hh_config(t_final=300.0), out=tmp_path / "c.mcap")
    ind = rec.indicators("vm")
    assert ind.gali[-1, 0] < 1e-3
    assert 0.03 < ind.mle[-1] < 0.08
    qr = rec.indicators("qr").exponents[-1]
    assert abs(qr[0] + qr[3]) < 0.02 and abs(qr[1]) < 0.02 and abs(qr[2]) < 0.02
    # Symplectic integrator with h = 0.01: the energy error stays bounded and small.
    assert np.all(ind.energy_error < 1e-8)
    # Per-set values average to the reported means.
    geometric = ind.gali_log10_sets.mean(axis=1)
    assert np.allclose(geometric, ind.gali_log10_mean, rtol=0, atol=1e-12)
    assert not any(math.isnan(v) for v in ind.gali.ravel())


def fput_config(name="py-fput", t_final=100.0):
    """A small beta-FPUT chain as a lattice potential (8 sites between fixed walls, the lowest
    normal mode at amplitude 1): a Hamiltonian with sites, so the deviation vector and energy
    distributions are defined, and an MPM scheme beside its VM partner."""
    n = 8
    q = [math.sin(math.pi * (i + 1) / (n + 1)) for i in range(n)]
    return {
        "run": {"name": name},
        "model": {
            "name": "potential",
            "n": n,
            "boundary": "fixed",
            "params": {"beta": 1.0},
            "potential": "sum(i = 0..N, (q[i+1] - q[i])^2/2 + beta/4*(q[i+1] - q[i])^4)",
        },
        "orbit": {"q": q, "p": [0.0] * n},
        "integrator": {"method": "aba864", "h": 0.02, "t_final": t_final},
        "deviations": {"k": 3, "sets": 2, "seed": 3},
        "scheme": [
            {"name": "vm", "method": "vm", "d0": 1e-8, "tau": 1.0},
            {"name": "mpm", "method": "mpm", "d0": 1e-8, "tau": 1.0},
        ],
    }


def read_csv(path):
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    return rows[0], rows[1:]


def same(value, cell):
    """A CSV cell (shortest round-trip digits, empty for a value that is unavailable or not
    finite) against the double Python gives."""
    if cell == "":
        return not math.isfinite(value)
    return bits(value) == bits(float(cell))


@pytest.mark.parametrize("system", ["hh", "fput"])
def test_every_named_series_equals_analyze_csv(tmp_path, cli, system):
    # Both run the recording through the same analysis core with the same system rebuilt from
    # its config (OFLI's flow direction, the site energies), so every cell of `analyze --csv`
    # is the double Python gives at that time, to the last bit.
    out = tmp_path / f"{system}.mcap"
    config = hh_config(t_final=300.0) if system == "hh" else fput_config()
    rec = chaoscope.run(config, out=out)
    done = cli("analyze", out, "--csv", tmp_path / "csv")
    assert done.returncode == 0, done.stderr
    for scheme in rec.schemes:
        ind = rec.indicators(scheme)
        assert ind.names == [
            "fli",
            "ofli",
            "megno",
            "megno_mean",
            "dvd_m2",
            "dvd_participation",
            "energy_m2",
            "energy_participation",
            "norm_m2",
            "norm_participation",
        ]
        head, rows = read_csv(tmp_path / "csv" / f"{scheme}.csv")
        # A few hundred renormalizations: the CSV keeps every one (2000 points a curve).
        assert len(rows) == len(ind.t), scheme
        col = {name: i for i, name in enumerate(head)}
        for i, row in enumerate(rows):
            assert bits(ind.t[i]) == bits(float(row[col["t"]]))
            for name in ind.names:
                assert same(ind.named[name][i], row[col[name]]), (scheme, name, row[0])
            for o, j in enumerate(ind.orders):
                delta = row[col[f"gali{j}_vs_vm_mean_abs_delta_log10"]]
                if ind.gali_vs_vm_mean_abs_delta_log10 is None:
                    assert delta == "", (scheme, row[0])
                else:
                    assert same(ind.gali_vs_vm_mean_abs_delta_log10[i, o], delta)
        # Every output is also an attribute, and the per-set values average to the mean.
        for name in ind.names:
            assert getattr(ind, name) is ind.named[name]
            available = np.isfinite(ind.named[name])
            assert (name in ind.unavailable) == (not available[-1]), (name, ind.unavailable)
            if available.any():
                per_set = ind.named_sets[name][available].mean(axis=1)
                assert np.allclose(per_set, ind.named[name][available], rtol=1e-14, atol=0)
        # The flow for OFLI and the sites for the DVD come with every Hamiltonian; the energy
        # distribution needs a potential split over sites, which the lattice potential has and
        # the built-in Henon-Heiles model does not say (so the run says why).
        # The norm distribution is the DDNLS's (a model that conserves the norm): neither has one.
        energy = set() if system == "fput" else {"energy_m2", "energy_participation"}
        expected = energy | {"norm_m2", "norm_participation"}
        assert set(ind.unavailable) == expected, ind.unavailable
        for name in ("norm_m2", "norm_participation"):
            assert "conserves the norm" in ind.unavailable[name]
        for name in energy:
            assert "which part of its potential belongs to which site" in ind.unavailable[name]
            assert np.all(np.isnan(ind.named[name]))
        assert (ind.gali_vs_vm_mean_abs_delta_log10 is None) == (ind.method == "vm")
        with pytest.raises(AttributeError):
            ind.no_such_indicator
        # The energy error at every time the energy table has.
        _, energy = read_csv(tmp_path / "csv" / "energy.csv")
        at = {float(t): e for t, e in energy}
        for t, e in zip(ind.t, ind.energy_error):
            if t in at:
                assert bits(e) == bits(float(at[t]))
        assert sum(1 for t in ind.t if t in at) == len(ind.t)


def test_named_indicators_are_the_physics(tmp_path):
    chaotic = chaoscope.run(hh_config(t_final=300.0), out=tmp_path / "c.mcap").indicators("vm")
    regular = chaoscope.run(
        hh_config(t_final=300.0, x2=0.558), out=tmp_path / "r.mcap"
    ).indicators("vm")
    for ind in [chaotic, regular]:
        # FLI is the sup over time of ln |w| of each set's first vector, whose latest value is
        # t times its finite-time MLE: never below it (to the rounding of a sum of 300 logs).
        # OFLI is the same sup of the part orthogonal to the flow: never above FLI.
        assert np.all(ind.fli >= ind.mle * ind.t - 1e-12 * np.maximum(1.0, ind.fli))
        assert np.all(ind.ofli <= ind.fli + 1e-12 * np.maximum(1.0, ind.fli))
        # A participation number over HH's 2 sites lies in [1, 2].
        assert np.all((ind.dvd_participation >= 1.0) & (ind.dvd_participation <= 2.0))
    # MEGNO's running mean grows like lambda t / 2 on a chaotic orbit (Cincotta & Simo): 8.0
    # with the finite-time lambda = 0.053 at t = 300; the offset of the asymptotic law is
    # O(1), well inside 25 %. On a torus it tends to 2 from below (tangent vectors grow
    # linearly): far below the chaotic value.
    expected = chaotic.mle[-1] * chaotic.t[-1] / 2
    assert abs(chaotic.megno_mean[-1] - expected) < 0.25 * expected, (
        chaotic.megno_mean[-1],
        expected,
    )
    assert regular.megno_mean[-1] < 2.5, regular.megno_mean[-1]
    # FLI: lambda t = 16 when chaotic; the logarithm of a linear growth when regular
    # (ln 300 = 5.7 for a unit prefactor).
    assert chaotic.fli[-1] > 14.0 and regular.fli[-1] < 8.0, (chaotic.fli[-1], regular.fli[-1])
