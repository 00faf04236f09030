"""Recording.clv() equals `chaoscope analyze --clv`: the report (`--json`), the angle series
(`--csv`: clv-angles.csv) and the vectors (`--clv-vectors`: clv-vectors.npy, clv-times.npy),
to the last bit, since both run the same analysis over the same file; with the same options
meaning the same."""

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import chaoscope
from conftest import hh_config


def bits(x):
    return float(x).hex()


def cli_clv(cli, path, out, *flags):
    done = cli(
        "analyze", path, "--clv", "--json", "--csv", out, "--clv-vectors", out, *flags
    )
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)["clv"]
    with open(out / "clv-angles.csv") as f:
        head = f.readline().strip().split(",")
        rows = [[float(c) for c in line.split(",")] for line in f]
    angles = np.array(rows).reshape(len(rows), len(head))
    return report, head, angles, np.load(out / "clv-vectors.npy"), np.load(out / "clv-times.npy")


@pytest.mark.parametrize(
    "kwargs,flags",
    [
        ({}, []),
        (
            {"set": 1, "forward_transient": 40.0, "backward_transient": 60.0, "neutral": 0},
            [
                "--clv-set",
                "1",
                "--clv-forward-transient",
                "40",
                "--clv-backward-transient",
                "60",
                "--clv-neutral",
                "0",
            ],
        ),
    ],
    ids=["defaults", "options"],
)
def test_clv_equals_analyze_clv_and_its_exports(tmp_path, cli, kwargs, flags):
    path = tmp_path / "hh.mcap"
    rec = chaoscope.run(hh_config(t_final=300.0), out=path)
    clv = rec.clv(**kwargs)
    report, head, angles, vectors, times = cli_clv(cli, path, tmp_path / "cli", *flags)
    # The JSON (shortest round-trip floats) parses back to the same doubles.
    assert clv.report == report
    assert clv.scheme == report["scheme"] == "qr"
    assert clv.set == kwargs.get("set", 0)
    assert (clv.k, clv.dim) == (4, 4)
    assert clv.classes == report["classes"]
    assert clv.renormalizations == report["renormalizations"] == len(clv.t)
    for name in ["growth_rates", "qr_spectrum", "qr_spectrum_run"]:
        assert [bits(v) for v in getattr(clv, name)] == [bits(v) for v in report[name]]
    assert (clv.t_start, clv.t_end) == (report["t_start"], report["t_end"])
    # The angle series: the CSV's columns by name, row for row.
    assert head[0] == "t" and sorted(head[1:]) == sorted(clv.angles)
    assert np.array_equal(clv.t, angles[:, 0])
    for i, name in enumerate(head[1:], start=1):
        assert np.array_equal(clv.angles[name], angles[:, i]), name
    # The vectors: the .npy the command writes, at the same times.
    assert clv.vectors.shape == vectors.shape == (len(clv.t), 4, 4)
    assert np.array_equal(clv.vectors, vectors)
    assert np.array_equal(clv.t, times)
    # Unit vectors (V = Q C, Q orthonormal, C's columns normalized: a few roundings).
    assert np.allclose(np.linalg.norm(clv.vectors, axis=2), 1.0, rtol=0, atol=1e-14)


def test_clv_is_the_physics_and_refuses_what_it_cannot_take(tmp_path):
    rec = chaoscope.run(hh_config(t_final=300.0), out=tmp_path / "hh.mcap")
    clv = rec.clv(vectors=False)
    assert clv.vectors is None
    # A Hamiltonian's CLVs: an unstable, two neutral (the flow and its symplectic partner)
    # and a stable one, their rates pairing to zero within the finite-time spread (0.02 at
    # these times, as the QR spectrum of test_indicators_are_the_physics), and each on the
    # QR spectrum of the same window (the CLVs' rates are the exponents; their difference is
    # boundary terms over 240 time units, below 0.02).
    assert clv.classes == ["unstable", "neutral", "neutral", "stable"]
    g = clv.growth_rates
    assert abs(g[0] + g[3]) < 0.02 and abs(g[1]) < 0.02 and abs(g[2]) < 0.02, g
    assert np.all(np.abs(g - clv.qr_spectrum) < 0.02), (g, clv.qr_spectrum)
    # The unstable direction is never inside the rest: angles in (0, pi/2].
    a = clv.angles["unstable_vs_rest"]
    assert np.all((a > 0) & (a <= np.pi / 2))
    with pytest.raises(chaoscope.ChaoscopeError, match="scheme 'mpm' is mpm"):
        rec.clv("mpm")
    with pytest.raises(chaoscope.ChaoscopeError, match="the run has 3 sets"):
        rec.clv(set=3)


# Sends SIGINT to itself shortly after Recording.clv starts on a recording whose CLVs take
# seconds; prints whether the call raised KeyboardInterrupt or returned.
SCRIPT = textwrap.dedent(
    """
    import os, signal, sys, threading, time
    import chaoscope
    rec = chaoscope.run({
        "model": {"name": "map", "next": ["1 - 1.4*x1^2 + x2", "0.3*x1"]},
        "orbit": {"x": [0.0, 0.0]},
        "integrator": {"t_final": 200000},
        "deviations": {"k": 2, "sets": 1, "seed": 1},
        "scheme": [{"name": "vm", "method": "vm", "d0": 1e-8, "tau": 1,
                    "orthonormalize": "qr"}],
    }, out=sys.argv[1])

    def interrupt():
        time.sleep(0.05)
        os.kill(os.getpid(), signal.SIGINT)

    threading.Thread(target=interrupt, daemon=True).start()
    try:
        rec.clv()
        print("not interrupted")
    except KeyboardInterrupt:
        print("stopped KeyboardInterrupt")
    """
)


def test_ctrl_c_stops_clv(tmp_path):
    done = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(tmp_path / "henon.mcap")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "stopped KeyboardInterrupt", done.stdout
