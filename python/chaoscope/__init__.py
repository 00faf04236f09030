"""chaoscope: tell chaotic orbits from regular ones with GALI, SALI and Lyapunov exponents.

A thin layer over the chaoscope Rust crates (the same engine, file format and analysis as the
``chaoscope`` command):

- ``run(config, out=...)`` integrates a run and records it to an MCAP file -> ``Recording``
- ``open(path)`` opens a recording -> ``Recording``
- ``Recording.indicators(scheme)`` -> ``Indicators`` (numpy arrays of t, GALI_2..k per set and
  averaged, SALI, the finite-time exponents, the energy error, and every registered indicator
  by its name: ``fli``, ``ofli``, ``megno``, ``megno_mean``, ``dvd_m2``, ...), equal to
  ``chaoscope analyze --json`` to the last bit and to the columns of ``analyze --csv``
- ``Recording.clv(scheme=None, ...)`` -> ``Clv`` (the covariant Lyapunov vectors as
  ``analyze --clv`` computes them: growth rates, angles between subspaces over time, and the
  vectors, shape (m, k, dim))
- ``Recording.report(at=None, from_t=None)`` (also ``Recording.analyze``) -> the dict
  ``chaoscope analyze --json [--at T] [--from T0]`` prints (with the verdict); ``from_t``
  discards a transient from the finite-time exponents
- ``Recording.orbit(scheme=None)`` -> ``Orbit`` (numpy arrays: times and reference states, and
  an MPM scheme's nearby orbits)
- ``Recording.replay(tau=..., d0=...)`` -> a new ``Recording`` on the bit-identical orbit
- ``resume(path, t_final=None, out=None)`` -> the ``Recording`` of a killed, interrupted or
  finished run continued (or extended to a later ``t_final``), as ``chaoscope resume`` does
- ``map(config, out=...)`` / ``open_map(path)`` -> ``Map`` (numpy grids of a phase-space map)
- ``monitor(run)`` -> an iterator of ``LiveSample`` from a running producer (lossy, with its
  gap count)

Configurations are a dict, a TOML string or a path, exactly as the ``chaoscope`` command reads
them (the guide: docs/src/configuration.md, every key in docs/src/reference.md). Errors raise
``ChaoscopeError`` with the command's message (one line; an expression error adds its source
line and a caret on lines of their own); long calls release the GIL and stop on Ctrl-C (``KeyboardInterrupt``).
"""

from ._chaoscope import (
    ChaoscopeError,
    Clv,
    Indicators,
    LiveSample,
    Map,
    Monitor,
    Orbit,
    Recording,
    map,
    monitor,
    open,
    open_map,
    resume,
    run,
)

__all__ = [
    "ChaoscopeError",
    "Clv",
    "Indicators",
    "LiveSample",
    "Map",
    "Orbit",
    "Monitor",
    "Recording",
    "map",
    "monitor",
    "open",
    "open_map",
    "resume",
    "run",
]
