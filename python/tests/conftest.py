"""Shared fixtures: the `chaoscope` command the bindings are compared with, and small configs.

The bindings must give what the command gives, so the tests run the real binary (built by
`cargo test --release --workspace` or `cargo build --release` into `$CARGO_TARGET_DIR` or
`target/`; `CHAOSCOPE_BIN` overrides).
"""

import json
import os
import pathlib
import signal
import subprocess

import pytest

# The interrupt tests signal the processes they start with SIGINT. A pytest started with SIGINT
# ignored (the background job of a shell without job control) passes that on, and they keep
# ignoring it: each such test fails as a process that never stopped. A handler here makes every
# child start with SIGINT's default action (exec resets handlers; it keeps what is ignored).
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

REPO = pathlib.Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def chaoscope_bin():
    # Where cargo put the build: its target directory, as cargo itself chooses it.
    target = pathlib.Path(os.environ.get("CARGO_TARGET_DIR", REPO / "target"))
    path = pathlib.Path(os.environ.get("CHAOSCOPE_BIN", target / "release" / "chaoscope"))
    if not path.is_file():
        pytest.fail(f"{path} not found: build it first with `cargo build --release`")
    return str(path)


@pytest.fixture
def cli(chaoscope_bin):
    """Runs `chaoscope ARGS...`; returns the completed process (check=False)."""

    def run(*args, timeout=120):
        return subprocess.run(
            [chaoscope_bin, *map(str, args)],
            capture_output=True,
            text=True,
            timeout=timeout,
        )

    return run


@pytest.fixture
def analyze_json(cli):
    def analyze(path, at=None, from_t=None):
        args = ["analyze", path, "--json"] + ([] if at is None else ["--at", repr(at)])
        args += [] if from_t is None else ["--from", repr(from_t)]
        done = cli(*args)
        assert done.returncode == 0, done.stderr
        return json.loads(done.stdout)

    return analyze


def hh_config(name="py-hh", t_final=200.0, sets=3, x2=-0.25):
    """The paper's Henon-Heiles orbit (x2 = -0.25 chaotic, 0.558 regular) at H = 1/8, VM and
    MPM with the paper's d0 = 1e-8, tau = 1, plus a QR scheme for the spectrum."""
    return {
        "run": {"name": name},
        "model": {"name": "henon-heiles"},
        "orbit": {"q": [0.0, x2], "p": [0.0, 0.0], "energy": 0.125, "solve_for": "p1"},
        "integrator": {"method": "aba864", "h": 0.01, "t_final": t_final},
        "deviations": {"k": 4, "sets": sets, "seed": 1},
        "scheme": [
            {"name": "vm", "method": "vm", "d0": 1e-8, "tau": 1.0},
            {"name": "mpm", "method": "mpm", "d0": 1e-8, "tau": 1.0},
            {"name": "qr", "method": "vm", "d0": 1.0, "tau": 1.0, "orthonormalize": "qr"},
        ],
    }


def to_toml(config):
    """A minimal TOML writer for the configs of these tests (the stdlib reads TOML, not writes)."""

    def value(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + " }"
        return repr(v)

    lines = []
    for section, body in config.items():
        if isinstance(body, list):
            for item in body:
                lines.append(f"[[{section}]]")
                lines += [f"{k} = {value(v)}" for k, v in item.items()]
        else:
            lines.append(f"[{section}]")
            lines += [f"{k} = {value(v)}" for k, v in body.items()]
    return "\n".join(lines) + "\n"
