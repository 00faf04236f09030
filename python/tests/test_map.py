"""map() and open_map(): the grid of `chaoscope map`, as numpy arrays."""

import numpy as np
import pytest

import chaoscope
from conftest import to_toml


def hh_map(n=(9, 7), t_final=200.0):
    """The paper's Fig. 9(b) map of the HH section (GALI_2, MPM d0 = 1e-8), coarse and short."""
    return {
        "model": {"name": "henon-heiles"},
        "orbit": {"q": [0.0, 0.0], "p": [0.0, 0.0], "energy": 0.125, "solve_for": "p1"},
        "integrator": {"method": "aba864", "h": 0.01, "t_final": t_final},
        "deviations": {"k": 2, "sets": 2, "seed": 1},
        "scheme": [{"name": "mpm", "method": "mpm", "d0": 1e-8, "tau": 1.0}],
        "map": {
            "x": {"coord": "q2", "min": -0.45, "max": 0.65, "n": n[0]},
            "y": {"coord": "p2", "min": -0.45, "max": 0.45, "n": n[1]},
            "indicator": "gali",
            "k": 2,
        },
    }


def test_map_grid_equals_the_command(tmp_path, cli):
    config = hh_map()
    m = chaoscope.map(config, out=tmp_path / "py.mcap", threads=2)
    assert (m.indicator, m.method, m.k, m.sets, m.x_coord, m.y_coord) == \
        ("gali", "mpm", 2, 2, "q2", "p2")
    assert m.x.shape == (9,) and m.y.shape == (7,)
    assert m.value.shape == (7, 9) and m.per_set.shape == (7, 9, 2) and m.points == 63
    assert np.allclose(m.x, np.linspace(-0.45, 0.65, 9)) and np.allclose(m.y, np.linspace(-0.45, 0.45, 7))
    ok, outside = m.status == 1, m.status == 2
    assert ok.any() and outside.any() and np.all(ok | outside)
    # Outside the energy surface nothing is integrated; inside GALI_2 is in (0, 1].
    assert np.all(np.isnan(m.value[outside]))
    assert np.all((m.value[ok] > 0) & (m.value[ok] <= 1))
    # Physics: the corners (q2, p2) = (+-0.45, +-0.45) need H > 1/8 already, so they are
    # outside; the point q2 = p2 = 0 has the most kinetic energy and is inside.
    assert outside[0, 0] and outside[-1, -1] and ok[3, np.argmin(abs(m.x))]

    path = tmp_path / "map.toml"
    path.write_text(to_toml(config))
    done = cli("map", path, "--out", tmp_path / "cli.mcap", "--threads", 1, "--no-progress")
    assert done.returncode == 0, done.stderr
    theirs = chaoscope.open_map(tmp_path / "cli.mcap")
    # Same scheduler and kernel on 2 threads and on 1: bit-identical (determinism).
    assert m.value.tobytes() == theirs.value.tobytes()
    assert m.per_set.tobytes() == theirs.per_set.tobytes()
    assert m.status.tobytes() == theirs.status.tobytes()
    again = chaoscope.open_map(m.path)
    assert again.value.tobytes() == m.value.tobytes()


def test_parameter_axis_map_equals_the_command(tmp_path, cli):
    """A map over a parameter of the model (the standard map's SALI over K and p0): x_coord
    names the parameter, the grid holds its values, and the points equal the command's."""
    config = {
        "model": {
            "name": "map",
            "next": ["x1 + x2 + K*sin(x1)", "x2 + K*sin(x1)"],
            "params": {"K": 1.0},
            "modulo": [6.283185307179586, 6.283185307179586],
        },
        "orbit": {"x": [2.0, 0.0]},
        "integrator": {"t_final": 200},
        "deviations": {"k": 2, "sets": 1, "seed": 1},
        "scheme": [{"name": "vm", "method": "vm", "d0": 1e-8, "tau": 1}],
        "map": {
            "x": {"param": "K", "min": 0.0, "max": 3.0, "n": 7},
            "y": {"coord": "x2", "min": -3.0, "max": 3.0, "n": 5},
            "indicator": "sali",
        },
    }
    m = chaoscope.map(config, out=tmp_path / "py.mcap", threads=2)
    assert (m.x_coord, m.y_coord) == ("K", "x2")
    assert np.allclose(m.x, np.linspace(0.0, 3.0, 7)) and m.value.shape == (5, 7)
    # K = 0 is the free rotation p' = p: every orbit regular, SALI far above the chaotic floor;
    # at K = 3 most of the column is the chaotic sea.
    assert np.all(m.value[:, 0] > 1e-8) and np.sum(m.value[:, -1] < 1e-12) >= 3
    path = tmp_path / "map.toml"
    path.write_text(to_toml(config))
    done = cli("map", path, "--out", tmp_path / "cli.mcap", "--threads", 1, "--no-progress")
    assert done.returncode == 0, done.stderr
    assert chaoscope.open_map(tmp_path / "cli.mcap").value.tobytes() == m.value.tobytes()


def test_map_errors(tmp_path):
    config = hh_map()
    del config["map"]
    with pytest.raises(chaoscope.ChaoscopeError, match=r"invalid map configuration: .*\[map\]"):
        chaoscope.map(config, out=tmp_path / "x.mcap")
    assert not (tmp_path / "x.mcap").exists()
    chaoscope.map(hh_map(n=(2, 2), t_final=2.0), out=tmp_path / "y.mcap")
    with pytest.raises(chaoscope.ChaoscopeError, match="already exists"):
        chaoscope.map(hh_map(n=(2, 2), t_final=2.0), out=tmp_path / "y.mcap")


def test_spectrum_map_has_one_layer_per_exponent(tmp_path, cli):
    """`indicator = "spectrum"`: lambda_1..lambda_k per point as `Map.spectrum` (ny, nx, k);
    `value` is lambda_1; for the Hamiltonian flow (VM, k = 2N) the exponents sum to 0 (the
    tangent map has determinant 1: only the QR's rounding, a few ulps a window, remains)."""
    config = hh_map(n=(5, 4), t_final=20.0)
    config["scheme"] = [{"name": "vm", "method": "vm", "d0": 1e-8, "tau": 1.0, "orthonormalize": "qr"}]
    config["map"]["indicator"] = "spectrum"
    config["map"]["k"] = 4
    m = chaoscope.map(config, out=tmp_path / "spectrum.mcap")
    assert m.indicator == "spectrum" and m.k == 4
    assert m.spectrum.shape == (4, 5, 4)
    ok = m.status == 1
    assert ok.any() and (~ok).any()
    assert np.array_equal(m.value[ok], m.spectrum[ok][:, 0])
    assert np.all(np.isnan(m.spectrum[~ok]))
    assert np.all(np.abs(m.spectrum[ok].sum(axis=1)) < 1e-12)
    # Other maps have no layers.
    assert chaoscope.open_map(tmp_path / "spectrum.mcap").spectrum.shape == (4, 5, 4)
    gali = chaoscope.map(hh_map(n=(2, 2), t_final=2.0), out=tmp_path / "gali.mcap")
    assert gali.spectrum.shape == (2, 2, 0)
    # The command draws lambda_1.
    done = cli("merge", tmp_path / "spectrum.mcap", "--out", tmp_path / "merged.mcap",
               "--png", tmp_path / "spectrum.png")
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "spectrum.png").stat().st_size > 1000


def test_map_resumes_what_a_killed_map_left(tmp_path, cli):
    """The in-progress file of a map that died (here: a stopped map's points moved to
    `NAME.partial`, unlocked) is resumed by `map`, as by `chaoscope map`: its points are kept
    and only the missing ones computed, bit for bit the map computed whole; a leftover of
    another map is refused and left untouched."""
    config = hh_map()
    path = tmp_path / "map.toml"
    path.write_text(to_toml(config))
    whole = chaoscope.map(config, out=tmp_path / "whole.mcap", threads=1)
    stopped = tmp_path / "stopped.mcap"
    done = cli("map", path, "--out", stopped, "--threads", 1, "--no-progress",
               "--stop-after", 20, "--flush-interval", 0)
    assert done.returncode != 0 and "interrupted" in done.stderr, done.stderr
    out = tmp_path / "resumed.mcap"
    partial = tmp_path / "resumed.mcap.partial"
    stopped.rename(partial)
    m = chaoscope.map(config, out=out, threads=1)
    assert not partial.exists()
    assert m.value.tobytes() == whole.value.tobytes()
    assert m.status.tobytes() == whole.status.tobytes()
    assert chaoscope.open_map(out).per_set.tobytes() == whole.per_set.tobytes()

    # A map stopped at `out` itself: refused as it is, completed with resume=True.
    stopped = tmp_path / "stopped2.mcap"
    done = cli("map", path, "--out", stopped, "--threads", 1, "--no-progress",
               "--stop-after", 20, "--flush-interval", 0)
    assert done.returncode != 0, done.stderr
    with pytest.raises(chaoscope.ChaoscopeError, match="resume=True"):
        chaoscope.map(config, out=stopped)
    completed = chaoscope.map(config, out=stopped, resume=True, threads=1)
    assert completed.value.tobytes() == whole.value.tobytes()
    assert completed.per_set.tobytes() == whole.per_set.tobytes()
    # With resume=True, force=True only overrides the estimate: the points are kept.
    again = chaoscope.map(config, out=stopped, resume=True, force=True, threads=1)
    assert again.value.tobytes() == whole.value.tobytes()

    # Another map's leftover: refused, named, untouched.
    other = tmp_path / "other.mcap"
    (tmp_path / "other.mcap.partial").write_bytes(out.read_bytes())
    before = (tmp_path / "other.mcap.partial").read_bytes()
    with pytest.raises(chaoscope.ChaoscopeError, match=r"holds a different map.*force=True"):
        chaoscope.map(hh_map(n=(3, 3)), out=other, threads=1)
    assert (tmp_path / "other.mcap.partial").read_bytes() == before
    assert not other.exists()


def test_map_keeps_what_it_cannot_read_as_its_own(tmp_path):
    """`out.partial` that holds anything but this map's points (a run recording, a map with a
    damaged first chunk) is refused and left as it is; only a leftover cut before its first
    chunk (nothing in it) is discarded. Without force, nothing at `out` is replaced (a dangling
    link) and the configuration file is never the output."""
    config = hh_map(n=(3, 3), t_final=20.0)
    rec = chaoscope.run({k: v for k, v in config.items() if k != "map"}, out=tmp_path / "run.mcap")
    out = tmp_path / "m.mcap"
    partial = tmp_path / "m.mcap.partial"
    partial.write_bytes(rec.path.read_bytes())
    with pytest.raises(chaoscope.ChaoscopeError, match=r"no readable map header.*force=True"):
        chaoscope.map(config, out=out)
    assert partial.read_bytes() == rec.path.read_bytes() and not out.exists()

    whole = chaoscope.map(config, out=tmp_path / "whole.mcap")
    flipped = bytearray(whole.path.read_bytes())
    flipped[60] ^= 0x10  # inside the first chunk, which holds the header
    partial.write_bytes(bytes(flipped))
    with pytest.raises(chaoscope.ChaoscopeError, match="no readable map header"):
        chaoscope.map(config, out=out)
    assert partial.read_bytes() == bytes(flipped)

    # A damaged length that runs past the end reads like a cut; in a file longer than a first
    # chunk can be, it is damage: refused.
    import struct
    long = bytearray(whole.path.read_bytes() + bytes(3 << 20))
    second = 8 + 9 + struct.unpack_from("<Q", long, 9)[0]  # the record after the header's
    struct.pack_into("<Q", long, second + 1, len(long))
    partial.write_bytes(bytes(long))
    with pytest.raises(chaoscope.ChaoscopeError, match="no readable map header"):
        chaoscope.map(config, out=out)
    assert partial.read_bytes() == bytes(long)

    partial.write_bytes(whole.path.read_bytes()[:40])  # killed before its first chunk
    m = chaoscope.map(config, out=out)
    assert m.value.tobytes() == whole.value.tobytes() and not partial.exists()

    link = tmp_path / "link.mcap"
    link.symlink_to(tmp_path / "nowhere.mcap")
    with pytest.raises(chaoscope.ChaoscopeError, match="already exists"):
        chaoscope.map(config, out=link)
    assert link.is_symlink() and not (tmp_path / "nowhere.mcap").exists()

    path = tmp_path / "map.toml"
    path.write_text(to_toml(config))
    with pytest.raises(chaoscope.ChaoscopeError, match="input"):
        chaoscope.map(path, out=path, force=True)
    with pytest.raises(chaoscope.ChaoscopeError, match="input"):
        chaoscope.run(path, out=path, force=True)
    assert path.read_text() == to_toml(config)
    # A map is not a run: resume says so instead of calling it a run killed early.
    with pytest.raises(chaoscope.ChaoscopeError, match="a map file, not a run's recording"):
        chaoscope.resume(whole.path)
    # So is a killed map's leftover cut inside its first chunk, with no header read: what the
    # file is, it says before that chunk.
    b = whole.path.read_bytes()
    pos = 8
    while b[pos] != 0x06:  # the first chunk record
        pos += 9 + struct.unpack_from("<Q", b, pos + 1)[0]
    killed = tmp_path / "killed.mcap.partial"
    killed.write_bytes(b[: pos + 20])
    with pytest.raises(chaoscope.ChaoscopeError, match="a map file, not a run's recording"):
        chaoscope.resume(tmp_path / "killed.mcap")
    assert killed.read_bytes() == b[: pos + 20]
