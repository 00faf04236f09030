"""Recording.indicators() equals `chaoscope analyze --json` to the last bit.

Both run the recording through the same reader and analysis core, so every number must be
bit-identical (the JSON is written with shortest round-trip floats, so parsing it gives back the
same double). Compared at the end and at times inside the run (`--at T`), for VM, MPM and a QR
scheme (whose `lyapunov` is the whole spectrum), on the chaotic and the regular HH orbit.
"""

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
