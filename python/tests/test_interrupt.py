"""Ctrl-C during a long call: KeyboardInterrupt within a moment, and a valid file that says it
was interrupted (as `chaoscope run` leaves on SIGINT)."""

import subprocess
import sys
import textwrap


SCRIPT = textwrap.dedent(
    """
    import os, signal, sys, threading, time
    import chaoscope
    config = {
        "model": {"name": "henon-heiles"},
        "orbit": {"q": [0.0, -0.25], "p": [0.0, 0.0], "energy": 0.125, "solve_for": "p1"},
        "integrator": {"method": "aba864", "h": 0.01, "t_final": 1e6},
        "deviations": {"k": 4, "sets": 20, "seed": 1},
        "scheme": [{"name": "vm", "method": "vm", "d0": 1e-8, "tau": 1.0}],
    }
    out = sys.argv[1]
    threading.Timer(1.0, lambda: os.kill(os.getpid(), signal.SIGINT)).start()
    start = time.monotonic()
    try:
        chaoscope.run(config, out=out)
    except KeyboardInterrupt:
        print("interrupted after", round(time.monotonic() - start, 2))
    rec = chaoscope.open(out)
    print(rec.status, rec.finalized_by, rec.indicators("vm").t[-1] > 0)
    """
)


def test_ctrl_c_stops_a_run_with_a_valid_file(tmp_path):
    # 1e8 steps x 20 sets would take many minutes: only an honoured SIGINT ends it in time.
    done = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(tmp_path / "long.mcap")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].startswith("interrupted after"), done.stdout
    assert float(lines[0].split()[-1]) < 10
    assert lines[1] == "interrupted signal True"
