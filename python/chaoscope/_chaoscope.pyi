"""Type stubs of the compiled module chaoscope._chaoscope (see chaoscope/__init__.py)."""

import os
import pathlib
from types import TracebackType
from typing import Any, Dict, Iterator, List, Mapping, Optional, Sequence, Union

import numpy as np
import numpy.typing as npt

Config = Union[Mapping[str, Any], str, "os.PathLike[str]"]
FloatArray = npt.NDArray[np.float64]

class ChaoscopeError(Exception):
    """An error reported by chaoscope, with the same one-line message as the command."""

class Orbit:
    """The recorded orbit: `t` (n,), `states` (n, dim); with an MPM scheme, `nearby_t` (m,)
    and `nearby` (m, sets, k, dim), the reference plus each separation before renormalization."""

    scheme: Optional[str]
    t: np.ndarray
    states: np.ndarray
    nearby_t: Optional[np.ndarray]
    nearby: Optional[np.ndarray]

class Indicators:
    """One scheme's indicators, one row per renormalization; column j - 2 is GALI_j."""

    scheme: str
    method: str
    orthonormalize: str
    d0: float
    tau: float
    orders: List[int]
    t: FloatArray
    """Times, shape (n,)."""
    sets: npt.NDArray[np.uint64]
    """Sets contributing at each time, shape (n,)."""
    gali: FloatArray
    """Arithmetic mean over the sets of GALI_j, shape (n, k - 1)."""
    gali_log10_mean: FloatArray
    """Mean over the sets of log10 GALI_j, shape (n, k - 1)."""
    gali_log10_sets: FloatArray
    """log10 GALI_j of each set, shape (n, sets, k - 1)."""
    sali: FloatArray
    """Mean SALI, shape (n,)."""
    sali_log10_mean: FloatArray
    sali_sets: FloatArray
    """SALI of each set, shape (n, sets)."""
    exponents: FloatArray
    """Finite-time exponent of each vector, mean over the sets, shape (n, k): the Lyapunov
    spectrum for a QR scheme; for a rescale scheme each vector's growth rate, an estimate of the
    MLE each (not a spectrum)."""
    exponents_sets: FloatArray
    """The same per set, shape (n, sets, k)."""
    mle: FloatArray
    """Finite-time maximal Lyapunov exponent, shape (n,)."""
    energy_error: FloatArray
    """Relative energy error of the reference orbit, shape (n,)."""
    names: List[str]
    """Every registered set indicator's output, in report order (the `analyze --csv` columns)."""
    named: Dict[str, FloatArray]
    """Each output's mean over the sets by name, shape (n,); NaN where unavailable."""
    named_sets: Dict[str, FloatArray]
    """Each output of each set by name, shape (n, sets)."""
    unavailable: Dict[str, str]
    """The outputs this run cannot give, with the reason."""
    gali_vs_vm_mean_abs_delta_log10: Optional[FloatArray]
    """MPM schemes: mean over the sets of |log10 GALI_j - log10 GALI_j(VM)|, shape (n, k - 1)."""
    fli: FloatArray
    """Fast Lyapunov indicator, mean over the sets, shape (n,) (as every name of `names`)."""
    ofli: FloatArray
    megno: FloatArray
    megno_mean: FloatArray
    dvd_m2: FloatArray
    dvd_participation: FloatArray
    energy_m2: FloatArray
    energy_participation: FloatArray

class Clv:
    """Covariant Lyapunov vectors of one VM QR scheme's set (`chaoscope analyze --clv`)."""

    scheme: str
    set: int
    k: int
    dim: int
    forward_transient: float
    backward_transient: float
    t_start: float
    t_end: float
    renormalizations: int
    growth_rates: FloatArray
    """Each CLV's growth rate over the window, shape (k,)."""
    qr_spectrum: FloatArray
    """The QR spectrum over the window, shape (k,)."""
    qr_spectrum_run: FloatArray
    classes: List[str]
    """"unstable", "neutral" or "stable" per CLV."""
    neutral: int
    stretch_max_relative_difference: float
    spilled_bytes: int
    report: Dict[str, Any]
    """What `analyze --clv --json` prints under "clv"."""
    t: FloatArray
    """Times of the window's renormalizations, shape (m,)."""
    angles: Dict[str, FloatArray]
    """Smallest principal angle between subspaces by name, radians, shape (m,) each."""
    vectors: Optional[FloatArray]
    """The CLVs, shape (m, k, dim); None with vectors=False."""

class Recording:
    """A chaoscope recording (MCAP file)."""

    @property
    def path(self) -> pathlib.Path: ...
    @property
    def run_name(self) -> str: ...
    @property
    def config(self) -> str:
        """The run configuration as canonical TOML."""
    @property
    def schemes(self) -> List[str]: ...
    @property
    def model(self) -> str: ...
    @property
    def n(self) -> int:
        """Degrees of freedom."""
    @property
    def k(self) -> int: ...
    @property
    def sets(self) -> int: ...
    @property
    def t_final(self) -> float: ...
    @property
    def energy0(self) -> float: ...
    @property
    def status(self) -> str:
        """"completed", "interrupted", "failed" or "unknown"."""
    @property
    def finalized_by(self) -> str: ...
    @property
    def frames_missing(self) -> int: ...
    def report(
        self, at: Optional[float] = None, from_t: Optional[float] = None
    ) -> Dict[str, Any]:
        """What `chaoscope analyze --json [--at T] [--from T0]` prints, as a dict."""
    def analyze(
        self, at: Optional[float] = None, from_t: Optional[float] = None
    ) -> Dict[str, Any]:
        """The same as `report`, under the command's name."""
    def orbit(self, scheme: Optional[str] = None) -> Orbit:
        """The recorded reference orbit, and an MPM scheme's nearby orbits."""
    def indicators(self, scheme: str) -> Indicators:
        """The indicators of `scheme` at each of its renormalizations."""
    def clv(
        self,
        scheme: Optional[str] = None,
        *,
        set: int = 0,
        forward_transient: Optional[float] = None,
        backward_transient: Optional[float] = None,
        neutral: Optional[int] = None,
        memory: int = 256,
        vectors: bool = True,
    ) -> Clv:
        """The covariant Lyapunov vectors, as `chaoscope analyze --clv` computes them."""
    def replay(
        self,
        *,
        tau: Union[float, Sequence[float], None] = None,
        d0: Union[float, Sequence[float], None] = None,
        out: Union[str, "os.PathLike[str]", None] = None,
        without_original: bool = False,
        force: bool = False,
    ) -> "Recording":
        """Re-run with other tau / d0 on the bit-identical reference orbit."""

class Map:
    """A phase-space map; grids are indexed [iy, ix]."""

    path: pathlib.Path
    indicator: str
    method: str
    k: int
    sets: int
    t_final: float
    x_coord: str
    """What the x axis varies: a coordinate ("q2"), or a parameter of a parameter axis ("K")."""
    y_coord: str
    x: FloatArray
    y: FloatArray
    value: FloatArray
    mean_log10: FloatArray
    status: npt.NDArray[np.int32]
    """1 integrated, 2 outside the energy surface, 3 escaped, 0 not computed."""
    per_set: FloatArray
    spectrum: FloatArray
    """"spectrum" maps: lambda_1..lambda_k per point, shape (ny, nx, k); (ny, nx, 0) otherwise."""
    points: int

class LiveSample:
    """One renormalization received live."""

    t: float
    step: int
    energy: Optional[float]
    state: FloatArray
    frames_received: int
    frames_lost: int
    indicators: Dict[str, Dict[str, Any]]

class Monitor(Iterator[LiveSample]):
    """Live samples of a running producer."""

    def __iter__(self) -> "Monitor": ...
    def __next__(self) -> LiveSample: ...
    def close(self) -> None: ...
    def __enter__(self) -> "Monitor": ...
    def __exit__(
        self,
        exc_type: Optional[type],
        exc: Optional[BaseException],
        tb: Optional[TracebackType],
    ) -> None: ...
    @property
    def run(self) -> str: ...
    @property
    def status(self) -> Optional[str]: ...
    @property
    def frames_received(self) -> int: ...
    @property
    def frames_lost(self) -> int: ...
    def report(self) -> Optional[Dict[str, Any]]: ...

def run(
    config: Config,
    *,
    out: Union[str, "os.PathLike[str]", None] = None,
    run: Optional[str] = None,
    force: bool = False,
) -> Recording:
    """Integrate and record a run (like `chaoscope run`)."""

def open(path: Union[str, "os.PathLike[str]"]) -> Recording:
    """Open a recording."""

def resume(
    path: Union[str, "os.PathLike[str]"],
    *,
    t_final: Optional[float] = None,
    out: Union[str, "os.PathLike[str]", None] = None,
    force: bool = False,
) -> Recording:
    """Continue a killed, interrupted or finished run from its recording (like `chaoscope resume`)."""

def map(
    config: Config,
    *,
    out: Union[str, "os.PathLike[str]", None] = None,
    threads: Optional[int] = None,
    force: bool = False,
    resume: bool = False,
) -> Map:
    """Compute and record a phase-space map (like `chaoscope map`); `resume=True` completes
    a stopped map at `out` (with it, `force=True` only overrides the estimate)."""

def open_map(path: Union[str, "os.PathLike[str]"]) -> Map:
    """Read a map file."""

def monitor(run: str, *, timeout: float = 30.0) -> Monitor:
    """Follow a running producer live from the bus."""
