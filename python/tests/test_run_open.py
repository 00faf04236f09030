"""run() and open(): a recording made through the bindings is the command's recording."""

import numpy as np
import pytest

import chaoscope
from conftest import hh_config, to_toml


def same_bits(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.tobytes() == b.tobytes()


def test_run_records_and_open_reads_it(tmp_path):
    out = tmp_path / "hh.mcap"
    rec = chaoscope.run(hh_config(), out=out)
    assert isinstance(rec, chaoscope.Recording)
    assert rec.schemes == ["vm", "mpm", "qr"]
    assert (rec.status, rec.finalized_by, rec.frames_missing) == ("completed", "end-of-run", 0)
    assert (rec.model, rec.n, rec.k, rec.sets, rec.t_final) == ("henon-heiles", 2, 4, 3, 200.0)
    again = chaoscope.open(str(out))
    assert again.run_name == rec.run_name == "py-hh"
    assert again.config == rec.config
    ind = again.indicators("vm")
    # tau = 1 over t = 200: the renormalizations at t = 1, 2, ..., 200 (and t = 0).
    assert ind.t[-1] == 200.0 and len(ind.t) in (200, 201)
    assert ind.gali.shape == (len(ind.t), 3) and ind.gali_log10_sets.shape == (len(ind.t), 3, 3)


def test_dict_toml_string_and_path_give_the_same_bits(tmp_path):
    config = hh_config(t_final=50.0)
    path = tmp_path / "hh.toml"
    path.write_text(to_toml(config))
    recs = [
        chaoscope.run(config, out=tmp_path / "a.mcap"),
        chaoscope.run(to_toml(config), out=tmp_path / "b.mcap"),
        chaoscope.run(path, out=tmp_path / "c.mcap"),
        chaoscope.run(str(path), out=tmp_path / "d.mcap"),
    ]
    first = recs[0].indicators("mpm")
    for rec in recs[1:]:
        other = rec.indicators("mpm")
        for field in ("t", "gali", "gali_log10_sets", "sali", "exponents", "energy_error"):
            assert same_bits(getattr(first, field), getattr(other, field)), field


def test_run_equals_the_command_bit_for_bit(tmp_path, cli):
    # Same engine, same config and seed: the numbers cannot differ by one bit (determinism),
    # although the command integrates in a producer process and records over the bus.
    config = hh_config(t_final=100.0)
    path = tmp_path / "hh.toml"
    path.write_text(to_toml(config))
    done = cli("run", path, "--out", tmp_path / "cli.mcap", "--run", "py-hh-cli")
    assert done.returncode == 0, done.stderr
    ours = chaoscope.run(path, out=tmp_path / "py.mcap")
    theirs = chaoscope.open(tmp_path / "cli.mcap")
    for scheme in ours.schemes:
        a, b = ours.indicators(scheme), theirs.indicators(scheme)
        for field in ("t", "gali", "gali_log10_sets", "sali_sets", "exponents_sets", "energy_error"):
            assert same_bits(getattr(a, field), getattr(b, field)), (scheme, field)


def test_errors_carry_the_commands_message(tmp_path, cli):
    bad = to_toml(hh_config()).replace("h = 0.01", 'h = "0.01"')
    path = tmp_path / "bad.toml"
    path.write_text(bad)
    done = cli("run", path, "--out", tmp_path / "x.mcap")
    assert done.returncode == 1
    line = done.stderr.strip().splitlines()[-1]
    assert line.startswith("chaoscope: error: ")
    with pytest.raises(chaoscope.ChaoscopeError) as e:
        chaoscope.run(path, out=tmp_path / "y.mcap")
    assert str(e.value) == line.removeprefix("chaoscope: error: ")
    assert "integrator.h" in str(e.value)
    assert not (tmp_path / "y.mcap").exists()

    config = hh_config()
    config["integrator"]["h"] = "0.01"
    with pytest.raises(chaoscope.ChaoscopeError, match=r"integrator\.h .*expected f64"):
        chaoscope.run(config, out=tmp_path / "z.mcap")
    config = hh_config()
    config["deviations"]["typo"] = 1
    with pytest.raises(chaoscope.ChaoscopeError, match="typo"):
        chaoscope.run(config, out=tmp_path / "z.mcap")
    with pytest.raises(chaoscope.ChaoscopeError, match="reading run configuration"):
        chaoscope.run(tmp_path / "missing.toml", out=tmp_path / "z.mcap")
    assert not (tmp_path / "z.mcap").exists()

    rec = chaoscope.run(hh_config(t_final=5.0), out=tmp_path / "ok.mcap")
    with pytest.raises(chaoscope.ChaoscopeError, match="already exists"):
        chaoscope.run(hh_config(t_final=5.0), out=tmp_path / "ok.mcap")
    with pytest.raises(chaoscope.ChaoscopeError, match="no scheme 'nope'"):
        rec.indicators("nope")
    (tmp_path / "junk.mcap").write_bytes(b"not an mcap file")
    with pytest.raises(chaoscope.ChaoscopeError, match="junk.mcap"):
        chaoscope.open(tmp_path / "junk.mcap")


def test_resume_extends_a_run_to_the_uninterrupted_runs_bits(tmp_path, cli):
    """A run to t = 60 resumed to t = 120 is the run to t = 120, bit for bit (the engine is
    restarted from the recorded state and deviation vectors); the command's resume of the same
    recording gives the same file contents; a failed resume names the file."""
    short = hh_config(t_final=60.0)
    full = hh_config(t_final=120.0)
    whole = chaoscope.run(full, out=tmp_path / "whole.mcap")
    part = tmp_path / "part.mcap"
    chaoscope.run(short, out=part)
    # Into another file: the recording itself stays as it was.
    resumed = chaoscope.resume(part, t_final=120.0, out=tmp_path / "resumed.mcap")
    assert resumed.path == tmp_path / "resumed.mcap"
    assert (resumed.status, resumed.t_final) == ("completed", 120.0)
    assert chaoscope.open(part).t_final == 60.0
    for scheme in whole.schemes:
        a, b = whole.indicators(scheme), resumed.indicators(scheme)
        for field in ("t", "gali", "gali_log10_sets", "sali_sets", "exponents_sets", "energy_error"):
            assert same_bits(getattr(a, field), getattr(b, field)), (scheme, field)
    assert same_bits(whole.orbit().states, resumed.orbit().states)

    # In place, as the command does it.
    done = cli("resume", part, "--t-final", 120)
    assert done.returncode == 0, done.stderr
    by_command = chaoscope.open(part)
    assert same_bits(by_command.orbit().states, resumed.orbit().states)

    with pytest.raises(chaoscope.ChaoscopeError, match="no such recording"):
        chaoscope.resume(tmp_path / "missing.mcap")
    with pytest.raises(chaoscope.ChaoscopeError, match="already exists"):
        chaoscope.resume(part, t_final=180.0, out=tmp_path / "whole.mcap")


def test_resume_errors_name_the_keyword_arguments(tmp_path):
    part = tmp_path / "part.mcap"
    chaoscope.run(hh_config(t_final=20.0), out=part)
    for t_final, words in [
        (float("nan"), "t_final=NaN"),
        (10.0, "t_final=10"),
        # A huge time is written as the user wrote it, not in 300 digits.
        (1e300, "t_final=1e300:"),
    ]:
        with pytest.raises(chaoscope.ChaoscopeError) as e:
            chaoscope.resume(part, t_final=t_final)
        assert words in str(e.value) and "--" not in str(e.value), str(e.value)
    chaoscope.run(hh_config(t_final=20.0), out=tmp_path / "other.mcap")
    with pytest.raises(chaoscope.ChaoscopeError, match=r"force=True") as e:
        chaoscope.resume(part, t_final=40.0, out=tmp_path / "other.mcap")
    assert "--" not in str(e.value)
    # Flags are words: a path that holds one is named as it is.
    odd = tmp_path / "a--out--force.mcap"
    with pytest.raises(chaoscope.ChaoscopeError) as e:
        chaoscope.resume(odd)
    assert str(odd) in str(e.value), str(e.value)


def test_a_killed_run_leaves_what_resume_continues(tmp_path, cli):
    """`run` puts its samples on disk every few seconds (as the recorder does), not only when
    a chunk fills: a run killed outright (SIGKILL, nothing of it runs again) leaves
    `NAME.partial` holding them, and `resume` continues it from the last one."""
    import signal
    import subprocess
    import sys
    import time

    config = hh_config(t_final=1e6)
    config["deviations"] = {"k": 2, "sets": 1, "seed": 1}
    config["scheme"] = [{"name": "vm", "method": "vm", "d0": 1e-8, "tau": 100.0}]
    config["integrator"]["h"] = 0.001  # minutes of run, a few hundred bytes per 100 time units
    out = tmp_path / "killed.mcap"
    partial = tmp_path / "killed.mcap.partial"
    child = subprocess.Popen(
        [sys.executable, "-c", f"import chaoscope; chaoscope.run({config!r}, out={str(out)!r})"]
    )
    try:
        started = time.monotonic()
        while not (partial.exists() and partial.stat().st_size > 20_000):
            # A chunk of 1 MiB fills in about half a minute here: the checkpoints come first.
            assert time.monotonic() - started < 20, "nothing put on disk after 20 s"
            assert child.poll() is None
            time.sleep(0.05)
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait()
    assert partial.exists() and not out.exists()
    with pytest.raises(chaoscope.ChaoscopeError, match=r"chaoscope\.resume\(.*continues it"):
        chaoscope.run(config, out=out)
    done = cli("recover", partial, "--out", tmp_path / "salvaged.mcap")
    assert done.returncode == 0, done.stderr
    reached = chaoscope.open(tmp_path / "salvaged.mcap").indicators("vm").t[-1]
    assert reached >= 100.0
    cont = chaoscope.resume(out, t_final=reached + 500.0, out=tmp_path / "cont.mcap")
    assert (cont.status, cont.t_final) == ("completed", reached + 500.0)
    assert cont.indicators("vm").t[-1] == reached + 500.0


def test_outputs_that_are_not_files_are_named_as_such(tmp_path):
    with pytest.raises(chaoscope.ChaoscopeError, match="not a regular file") as e:
        chaoscope.run(hh_config(t_final=5.0), out="/dev/null")
    assert "--" not in str(e.value)
