"""The example script reproduces the paper's figure (in its --quick form: shorter runs)."""

import pathlib
import subprocess
import sys

REPO = pathlib.Path(__file__).resolve().parents[2]


def test_example_writes_the_figure(tmp_path):
    png = tmp_path / "hh_gali.png"
    done = subprocess.run(
        [sys.executable, str(REPO / "examples" / "python" / "hh_gali.py"), "--quick",
         "--out", str(png), "--runs", str(tmp_path)],
        capture_output=True, text=True, timeout=300,
    )
    assert done.returncode == 0, done.stderr
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000
    # The printed fits are the paper's laws: on the regular orbit GALI_3 ~ t^-2 and
    # GALI_4 ~ t^-4 over [100, 1000] (the orbit settles on its torus after t ~ 100, so the
    # short run's slopes are within 0.3 of the laws; the full run's within 0.05).
    line = next(l for l in done.stdout.splitlines() if l.startswith("regular orbit"))
    g2, g3, g4 = (float(x) for x in line.split(":")[1].split("(")[0].split(","))
    assert abs(g2) < 0.5 and abs(g3 + 2) < 0.3 and abs(g4 + 4) < 0.3
