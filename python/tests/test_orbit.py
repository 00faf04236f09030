"""Recording.orbit(), report(from_t=...) and errors with real line breaks."""

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

import chaoscope
from conftest import hh_config


def third_party_reference(path):
    """The /chaoscope/reference channel read with the `mcap` package and its protobuf decoder
    (the schema records carry the FileDescriptorSet): times and states, nothing of chaoscope."""
    t, states = [], []
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, _, _, m in reader.iter_decoded_messages(topics=["/chaoscope/reference"]):
            t.append(m.t)
            states.append(list(m.state))
    return np.array(t), np.array(states)


def test_orbit_is_the_recorded_reference_bit_for_bit(tmp_path):
    rec = chaoscope.run(hh_config(t_final=50.0), out=tmp_path / "hh.mcap")
    orbit = rec.orbit()
    t, states = third_party_reference(tmp_path / "hh.mcap")
    assert orbit.t.shape == (51,) and orbit.states.shape == (51, 4)
    assert orbit.t.tobytes() == t.tobytes()
    assert orbit.states.tobytes() == states.tobytes()
    assert orbit.nearby is None and orbit.scheme is None
    # The orbit stays on its energy surface H = 1/8 (ABA864 at h = 0.01: error ~1e-12).
    q1, q2, p1, p2 = orbit.states.T
    energy = (p1**2 + p2**2 + q1**2 + q2**2) / 2 + q1**2 * q2 - q2**3 / 3
    assert np.max(np.abs(energy - 0.125)) < 1e-9


def test_the_nearby_orbits_of_an_mpm_scheme(tmp_path):
    rec = chaoscope.run(hh_config(t_final=20.0), out=tmp_path / "hh.mcap")
    orbit = rec.orbit("mpm")
    assert orbit.scheme == "mpm"
    # tau = 1: t = 0, 1, ..., 20; 3 sets of k = 4 nearby orbits in 4 dimensions.
    assert orbit.nearby_t.tolist() == [float(i) for i in range(21)]
    assert orbit.nearby.shape == (21, 3, 4, 4)
    # Each nearby orbit is the reference plus its separation: at distance d0 = 1e-8 at t = 0,
    # and a chaotic orbit's stretching over tau = 1 (factor ~ e^0.05 .. e^1) keeps it within
    # 1e-9 .. 1e-6 of the reference before it is pulled back.
    states = orbit.states[np.searchsorted(orbit.t, orbit.nearby_t)]
    distance = np.linalg.norm(orbit.nearby - states[:, None, None, :], axis=-1)
    assert np.allclose(distance[0], 1e-8, rtol=1e-6)
    assert np.all((distance > 1e-9) & (distance < 1e-6))
    with pytest.raises(chaoscope.ChaoscopeError, match="tangent vectors"):
        rec.orbit("vm")
    with pytest.raises(chaoscope.ChaoscopeError, match="no scheme 'nope'"):
        rec.orbit("nope")


def test_from_t_changes_the_exponents_and_nothing_else(tmp_path, analyze_json):
    rec = chaoscope.run(hh_config(t_final=100.0), out=tmp_path / "hh.mcap")
    whole, late = rec.report(), rec.analyze(from_t=20.0)
    assert late == analyze_json(tmp_path / "hh.mcap", from_t=20.0)
    assert late["run"]["exponents_from"] == 20.0 and "exponents_from" not in whole["run"]
    for a, b in zip(whole["schemes"], late["schemes"]):
        for key in a:
            if key in ("mle", "lyapunov", "lyapunov_std", "lyapunov_sum", "vs_vm"):
                continue
            assert a[key] == b[key], (a["name"], key)
        assert a["mle"] != b["mle"]
    with pytest.raises(chaoscope.ChaoscopeError, match="not before the run's end"):
        rec.report(from_t=100.0)


def test_an_expression_error_has_real_line_breaks(tmp_path):
    config = {
        "model": {"name": "ode", "rhs": ["x2", "-x1 +* x2"]},
        "orbit": {"x": [1.0, 0.0]},
        "integrator": {"method": "rk4", "h": 0.01, "t_final": 1.0},
        "deviations": {"k": 2, "sets": 1},
        "scheme": [{"name": "vm", "method": "vm", "d0": 1e-8, "tau": 1.0}],
    }
    with pytest.raises(chaoscope.ChaoscopeError) as e:
        chaoscope.run(config, out=tmp_path / "x.mcap")
    lines = str(e.value).split("\n")
    assert "\\n" not in str(e.value)
    assert len(lines) == 3 and "unexpected '*'" in lines[0], lines
    assert lines[1] == "  -x1 +* x2" and lines[2].rstrip().endswith("^"), lines
