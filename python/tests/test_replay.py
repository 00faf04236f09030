"""Recording.replay(): other tau / d0 on the bit-identical orbit, as `chaoscope replay`."""

import numpy as np
import pytest

import chaoscope
from conftest import hh_config


def test_replay_keeps_the_orbit_and_adds_schemes(tmp_path, cli):
    rec = chaoscope.run(hh_config(t_final=100.0), out=tmp_path / "hh.mcap")
    rep = rec.replay(tau=[0.5, 2.0], d0=1e-7)
    assert rep.path == tmp_path / "hh-replay.mcap"
    assert rep.finalized_by == "replay" and rep.status == "completed"
    assert rep.schemes[:3] == ["vm", "mpm", "qr"]
    # MPM schemes are copied per tau and d0; VM ones per tau only (d0 only scales their
    # linearly evolving tangent vectors).
    assert "mpm-tau0.5-d01e-7" in rep.schemes and "vm-tau2" in rep.schemes
    assert not [s for s in rep.schemes if s.startswith(("vm-", "qr-")) and "-d0" in s]
    # The original schemes are re-run: same bits.
    for scheme in ("vm", "mpm", "qr"):
        a, b = rec.indicators(scheme), rep.indicators(scheme)
        assert a.gali.tobytes() == b.gali.tobytes()
        assert a.exponents_sets.tobytes() == b.exponents_sets.tobytes()
    fast = rep.indicators("vm-tau0.5")
    assert fast.tau == 0.5 and fast.d0 == 1e-8
    assert rep.indicators("mpm-tau0.5-d01e-7").d0 == 1e-7
    assert np.allclose(np.diff(fast.t), 0.5, rtol=0, atol=1e-9)
    # The command's replay of the same file gives the same numbers.
    done = cli("replay", tmp_path / "hh.mcap", "--tau", 0.5, "--tau", 2.0, "--d0", 1e-7,
               "--out", tmp_path / "cli.mcap")
    assert done.returncode == 0, done.stderr
    theirs = chaoscope.open(tmp_path / "cli.mcap")
    assert theirs.schemes == rep.schemes
    for scheme in rep.schemes:
        assert rep.indicators(scheme).gali_log10_sets.tobytes() == \
            theirs.indicators(scheme).gali_log10_sets.tobytes()


def test_replay_errors(tmp_path):
    rec = chaoscope.run(hh_config(t_final=5.0), out=tmp_path / "hh.mcap")
    with pytest.raises(chaoscope.ChaoscopeError, match="nothing to replay"):
        rec.replay()
    rec.replay(tau=0.5)
    with pytest.raises(chaoscope.ChaoscopeError, match="already exists"):
        rec.replay(tau=0.5)
    with pytest.raises(chaoscope.ChaoscopeError, match="tau"):
        rec.replay(tau=0.013, out=tmp_path / "odd.mcap", force=True)
    assert not (tmp_path / "odd.mcap").exists()
