"""Files that are not regular files: `open`, `open_map` and `run` given a FIFO (as the file, or
as a table the config names) raise `ChaoscopeError` at once, in one line naming the path and
saying it is a FIFO, instead of waiting for a writer that never comes (deaf to Ctrl-C). Each
case runs in a fresh interpreter under a watchdog, so a regression fails instead of hanging."""

import os
import subprocess
import sys
import textwrap

import pytest

SCRIPT = textwrap.dedent(
    """
    import sys
    import chaoscope
    call, fifo, out = sys.argv[1], sys.argv[2], sys.argv[3]
    try:
        if call == "open":
            chaoscope.open(fifo)
        elif call == "open_map":
            chaoscope.open_map(fifo)
        elif call == "run":
            chaoscope.run(fifo, out=out)
        elif call == "table":
            chaoscope.run(
                {
                    "model": {
                        "name": "potential",
                        "n": 3,
                        "boundary": "fixed",
                        "potential": "sum(i = 0..N, U(q[i+1] - q[i]))",
                        "tables": {"U": {"file": fifo}},
                    },
                    "orbit": {"q": [0.1, 0.0, -0.1], "p": [0.0, 0.0, 0.0]},
                    "integrator": {"method": "aba864", "h": 0.01, "t_final": 1.0},
                    "deviations": {"k": 2, "sets": 1, "seed": 1},
                    "scheme": [{"name": "mpm", "method": "mpm", "d0": 1e-8, "tau": 1.0}],
                },
                out=out,
            )
    except chaoscope.ChaoscopeError as e:
        print(e)
        sys.exit(3)
    sys.exit(0)
    """
)


@pytest.mark.parametrize("call", ["open", "open_map", "run", "table"])
def test_a_fifo_is_refused_at_once(tmp_path, call):
    fifo = tmp_path / ("table.csv" if call == "table" else "input")
    os.mkfifo(fifo)
    out = tmp_path / "out.mcap"
    # No writer ever opens the FIFO: a blocking open would never return.
    done = subprocess.run(
        [sys.executable, "-c", SCRIPT, call, str(fifo), str(out)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 3, done.stdout + done.stderr
    lines = done.stdout.strip().splitlines()
    assert len(lines) == 1 and str(fifo) in lines[0] and "a FIFO" in lines[0], done.stdout
    assert not out.exists() and not (tmp_path / "out.mcap.partial").exists()
