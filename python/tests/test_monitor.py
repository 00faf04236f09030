"""monitor(): live samples of a run started in the background by the command."""

import subprocess

import numpy as np
import pytest

import chaoscope
from conftest import hh_config, to_toml


def test_monitor_follows_a_live_run(tmp_path, chaoscope_bin):
    name = f"py-monitor-{tmp_path.name[-12:]}".replace("_", "-")
    config = hh_config(name=name, t_final=3000.0, sets=2)
    config["scheme"] = config["scheme"][:1]  # VM alone, tau = 1
    path = tmp_path / "live.toml"
    path.write_text(to_toml(config))
    # The monitor waits for the run's header, so it can start first.
    with chaoscope.monitor(name, timeout=60) as live:
        run = subprocess.Popen(
            [chaoscope_bin, "run", str(path), "--out", str(tmp_path / "live.mcap")],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            samples = list(live)
        finally:
            _, err = run.communicate(timeout=120)
        assert run.returncode == 0, err
        assert live.status == "completed"
        report = live.report()
    assert samples, "no live sample arrived"
    t = np.array([s.t for s in samples])
    assert np.all(np.diff(t) > 0)
    # Renormalizations every tau = 1: every time is a whole number.
    assert np.all(t == np.round(t))
    assert samples[-1].t == 3000.0
    lost = [s.frames_lost for s in samples]
    assert lost == sorted(lost) and lost[-1] <= live.frames_lost
    # The monitor's last sample is the recording's last sample: GALI is a function of the latest
    # vectors only, so it equals the file's value bit for bit whatever was lost before.
    last = samples[-1]
    assert last.state.shape == (4,) and abs(last.energy - 0.125) < 1e-8
    vm = chaoscope.open(tmp_path / "live.mcap").indicators("vm")
    assert [float(x).hex() for x in last.indicators["vm"]["gali"]] == \
        [float(x).hex() for x in vm.gali[-1]]
    assert report["schemes"][0]["name"] == "vm"
    assert report["run"]["complete"] == (live.frames_lost == 0 and len(samples) == len(vm.t))


def test_monitor_of_no_run_says_so():
    live = chaoscope.monitor("py-no-such-run", timeout=0.3)
    with pytest.raises(chaoscope.ChaoscopeError, match="py-no-such-run"):
        next(live)
