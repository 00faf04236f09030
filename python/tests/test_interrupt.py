"""Signals during a long call: Ctrl-C, or SIGTERM with a handler that raises, stops
`chaoscope.run`, `chaoscope.map`, `chaoscope.resume` and `Recording.replay` within a second, with a valid file at
its name that says it was interrupted (as `chaoscope run` leaves on SIGINT) and no in-progress
file (`NAME.partial`) left behind. Each case runs in a fresh interpreter; the configs are small
per renormalization window so that a loaded machine still answers within the bound."""

import pathlib
import subprocess
import sys
import textwrap

import pytest

# Runs CALL (one of the long calls below) and sends SIGNAL to itself once the call's
# in-progress file has data; prints how long the exception took after the signal, then what
# the file says.
SCRIPT = textwrap.dedent(
    """
    import os, pathlib, signal, sys, threading, time
    import chaoscope
    call, sig, out = sys.argv[1], getattr(signal, sys.argv[2]), pathlib.Path(sys.argv[3])
    if sig == signal.SIGTERM:
        # Python's default SIGTERM ends the interpreter at once; a handler that raises stops
        # the call as Ctrl-C does.
        def on_term(*_):
            raise SystemExit(143)
        signal.signal(signal.SIGTERM, on_term)
    run_config = {
        "model": {"name": "henon-heiles"},
        "orbit": {"q": [0.0, -0.25], "p": [0.0, 0.0], "energy": 0.125, "solve_for": "p1"},
        "integrator": {"method": "aba864", "h": 0.01, "t_final": 1e7},
        "deviations": {"k": 2, "sets": 2, "seed": 1},
        "scheme": [{"name": "vm", "method": "vm", "d0": 1e-8, "tau": 1.0}],
    }
    map_config = dict(run_config)
    map_config["integrator"] = {"method": "aba864", "h": 0.01, "t_final": 40000.0}
    map_config["deviations"] = {"k": 2, "sets": 2, "seed": 1}
    map_config["map"] = {
        "x": {"coord": "q2", "min": -0.4, "max": 0.6, "n": 12},
        "y": {"coord": "p2", "min": -0.4, "max": 0.4, "n": 12},
        "indicator": "gali",
        "k": 2,
    }
    partial = pathlib.Path(str(out) + ".partial")
    sent = []

    def send_once_written():
        while not (partial.exists() and partial.stat().st_size > 0):
            time.sleep(0.005)
        time.sleep(0.2)
        sent.append(time.monotonic())
        os.kill(os.getpid(), sig)

    if call == "replay":
        short = dict(run_config)
        short["integrator"] = {"method": "aba864", "h": 0.01, "t_final": 3000.0}
        source = chaoscope.run(short, out=str(out.with_name("source.mcap")))
    if call == "resume":
        short = dict(run_config)
        short["integrator"] = {"method": "aba864", "h": 0.01, "t_final": 300.0}
        source = chaoscope.run(short, out=str(out.with_name("source.mcap")))
    threading.Thread(target=send_once_written, daemon=True).start()
    try:
        if call == "run":
            chaoscope.run(run_config, out=str(out))
        elif call == "map":
            chaoscope.map(map_config, out=str(out))
        elif call == "resume":
            chaoscope.resume(source.path, t_final=1e7, out=str(out))
        else:
            source.replay(tau=[2.0, 5.0], out=str(out))
        print("not interrupted")
    except (KeyboardInterrupt, SystemExit) as e:
        print("stopped", type(e).__name__, round(time.monotonic() - sent[0], 3))
    print("partial left", partial.exists())
    if call == "map":
        m = chaoscope.open_map(str(out))
        print("map points", 0 < m.points < 144)
    else:
        rec = chaoscope.open(str(out))
        print(rec.status, rec.finalized_by)
    """
)


@pytest.mark.parametrize("call", ["run", "map", "replay", "resume"])
@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
def test_a_signal_stops_a_long_call_with_a_valid_file(tmp_path, call, sig):
    out = tmp_path / f"{call}.mcap"
    done = subprocess.run(
        [sys.executable, "-c", SCRIPT, call, sig, str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    expected = "KeyboardInterrupt" if sig == "SIGINT" else "SystemExit"
    assert lines[0].startswith(f"stopped {expected}"), done.stdout
    # Within one second of the signal (every renormalization window here is far shorter).
    assert float(lines[0].split()[-1]) < 1.0, done.stdout
    assert lines[1] == "partial left False", done.stdout
    if call == "map":
        assert lines[2] == "map points True", done.stdout
    elif call == "resume":
        assert lines[2] == "interrupted resume", done.stdout
    else:
        assert lines[2] == "interrupted signal", done.stdout
    assert not list(pathlib.Path(tmp_path).glob("*.partial*"))
