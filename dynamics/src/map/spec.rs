//! The validated map: grid (coordinate and parameter axes), indicator, the run every point
//! shares, shards.

use chaoscope_schemas::config::{MapAxis, MapConfig, RunConfig};
use chaoscope_schemas::run::{Method, Orthonormalization, SystemClass};

use super::indicator::{Indicator, PointAccumulator, failed};
use super::point::{PointResult, PointStatus};
use crate::batch::Isa;
use crate::model::{ExpressionModel, WithParams};
use crate::spec::{
    LaneParam, RunSpec, SpecError, parse_coordinate, solve_momentum, state_coordinate,
};

/// One grid axis.
#[derive(Debug, Clone, PartialEq)]
pub struct Axis {
    /// What it varies: the coordinate's or the parameter's name.
    pub name: String,
    /// A parameter axis (`param = "K"`) rather than a coordinate axis.
    pub is_param: bool,
    /// Index into a point's state: a coordinate's in `(q, p)` or `x`; a parameter's after the
    /// `D` coordinates (`D + j` for the `j`-th parameter axis, see [`LaneParam`]).
    pub slot: usize,
    pub min: f64,
    pub max: f64,
    pub n: usize,
}

impl Axis {
    /// Value of grid line `i` (computed, never accumulated).
    pub fn value(&self, i: usize) -> f64 {
        grid_line(self.min, self.max, self.n, i)
    }

    /// The grid of `min`, `max` and `n` (at `key.min`, `key.n`).
    fn grid(key: &str, a: &MapAxis) -> Result<(), SpecError> {
        if !(a.min.is_finite() && a.max.is_finite() && a.min <= a.max) {
            return Err(SpecError::new(
                format!("{key}.min"),
                format!("need finite min <= max, got {} .. {}", a.min, a.max),
            ));
        }
        if a.n == 0 || a.n > 100_000 {
            return Err(SpecError::new(
                format!("{key}.n"),
                format!("must be between 1 and 100000, got {}", a.n),
            ));
        }
        // Finite ends may still be too far apart for the grid's arithmetic: the width
        // `max - min`, or `(max - min) * i` on the way to a line, overflows, and the points
        // there would start at infinity or NaN.
        if let Some(i) = (0..a.n).find(|&i| !grid_line(a.min, a.max, a.n, i).is_finite()) {
            return Err(SpecError::new(
                format!("{key}.max"),
                format!(
                    "min = {:?} and max = {:?} are too far apart for a grid of n = {}: the \
                     width max - min = {:?} and (max - min) x (n - 1) = {:?} must be finite \
                     for every grid line to be (line {i}, from 0, would be at {:?})",
                    a.min,
                    a.max,
                    a.n,
                    a.max - a.min,
                    (a.max - a.min) * (a.n.max(2) - 1) as f64,
                    grid_line(a.min, a.max, a.n, i)
                ),
            ));
        }
        Ok(())
    }

    /// `hamiltonian`: coordinates are `q1..qN` / `p1..pN` of `dim = 2N`; otherwise `x1..xD`.
    /// `lanes`: the parameter axes in order, whose slots follow the `dim` coordinates.
    fn from_config(
        key: &str,
        a: &MapAxis,
        dim: usize,
        hamiltonian: bool,
        lanes: &[LaneParam],
    ) -> Result<Self, SpecError> {
        if let Some(name) = &a.param {
            let j = lanes
                .iter()
                .position(|l| &l.name == name)
                .expect("every parameter axis is a lane parameter");
            return Ok(Self {
                name: name.clone(),
                is_param: true,
                slot: dim + j,
                min: a.min,
                max: a.max,
                n: a.n,
            });
        }
        let slot = if hamiltonian {
            let n_dof = dim / 2;
            let (momentum, i) = parse_coordinate(&a.coord, n_dof).ok_or_else(|| {
                SpecError::new(
                    format!("{key}.coord"),
                    format!(
                        "'{}' is not a coordinate q1..q{n_dof} / p1..p{n_dof}",
                        a.coord
                    ),
                )
            })?;
            if momentum { n_dof + i } else { i }
        } else {
            state_coordinate(&a.coord, dim).ok_or_else(|| {
                SpecError::new(
                    format!("{key}.coord"),
                    format!("'{}' is not a coordinate x1..x{dim}", a.coord),
                )
            })?
        };
        Ok(Self {
            name: a.coord.clone(),
            is_param: false,
            slot,
            min: a.min,
            max: a.max,
            n: a.n,
        })
    }
}

/// Value of grid line `i` of `n` from `min` to `max` (computed, never accumulated).
fn grid_line(min: f64, max: f64, n: usize, i: usize) -> f64 {
    if n == 1 {
        min
    } else {
        min + (max - min) * i as f64 / (n - 1) as f64
    }
}

/// The parameter axes of `[map]` (x first) as the run's lane parameters, after the checks
/// that need only the config: every axis names a coordinate or a parameter, not both; a
/// parameter is a scalar of `[model] params` of a kind that takes parameter axes; the two axes
/// are not the same parameter.
fn lane_params(cfg: &RunConfig, map: &MapConfig) -> Result<Vec<LaneParam>, SpecError> {
    use chaoscope_schemas::config::ParamValue;
    let params = cfg.model.params();
    let mut lanes: Vec<LaneParam> = Vec::new();
    for (key, axis) in [("map.x", &map.x), ("map.y", &map.y)] {
        Axis::grid(key, axis)?;
        let Some(name) = &axis.param else {
            if axis.coord.is_empty() {
                return Err(SpecError::new(
                    format!("{key}.coord"),
                    "an axis needs coord = \"x1\" (a coordinate) or param = \"K\" (a \
                     parameter of [model] params)",
                ));
            }
            // A parameter may not have a variable's name, so this names no coordinate.
            if params.is_some_and(|p| p.contains_key(&axis.coord)) {
                return Err(SpecError::new(
                    format!("{key}.coord"),
                    format!(
                        "'{0}' is a parameter, not a coordinate: a parameter axis is written \
                         param = \"{0}\"",
                        axis.coord
                    ),
                ));
            }
            continue;
        };
        let key = format!("{key}.param");
        if !axis.coord.is_empty() {
            return Err(SpecError::new(
                key,
                format!(
                    "an axis is a coordinate or a parameter: coord = \"{}\" and param = \
                     \"{name}\" both given",
                    axis.coord
                ),
            ));
        }
        let Some(params) = params else {
            let message = crate::spec::why_no_parameter_axes(&cfg.model);
            return Err(SpecError::new(key, message));
        };
        match params.get(name) {
            Some(ParamValue::Scalar(_)) => {}
            Some(ParamValue::Array(_) | ParamValue::Drawn(_)) => {
                return Err(SpecError::new(
                    key,
                    format!(
                        "'{name}' is an array parameter (one entry per site); an axis sets a \
                         scalar parameter"
                    ),
                ));
            }
            None => {
                let known: Vec<&str> = params
                    .iter()
                    .filter(|(_, v)| matches!(v, ParamValue::Scalar(_)))
                    .map(|(n, _)| n.as_str())
                    .collect();
                return Err(SpecError::new(
                    key,
                    format!(
                        "'{name}' is not a parameter of [model] params (scalars: {})",
                        if known.is_empty() {
                            "none".to_string()
                        } else {
                            known.join(", ")
                        }
                    ),
                ));
            }
        }
        if lanes.iter().any(|l| &l.name == name) {
            return Err(SpecError::new(key, "x and y are the same parameter"));
        }
        lanes.push(LaneParam {
            name: name.clone(),
            min: axis.min,
            max: axis.max,
        });
    }
    Ok(lanes)
}

/// Grid axes of a valid map config over a periodic coordinate (the model's `modulo`: a map's,
/// a flow's, a Hamiltonian's) whose `max - min` is a whole number of periods: their last line
/// is their first one again, a row or column of orbits computed twice. Each is said as a
/// warning naming the axis, with the `max` that grids one period without repeating it. Not
/// refused: the grid is what was asked (and every point stays a function of the config and its
/// index), only wasteful.
pub fn repeated_grid_lines(cfg: &RunConfig) -> Vec<String> {
    let (Some(map), Some(modulo)) = (&cfg.map, cfg.model.modulo()) else {
        return Vec::new();
    };
    // Hamiltonians name their axes q1..qN / p1..pN (`modulo` has 2N entries), the others
    // x1..xD.
    let canonical = cfg.model.kind().is_some_and(|k| k.canonical());
    let slot = |coord: &str| {
        if canonical {
            let n = modulo.len() / 2;
            parse_coordinate(coord, n).map(|(momentum, i)| if momentum { n + i } else { i })
        } else {
            state_coordinate(coord, modulo.len())
        }
    };
    let mut warnings = Vec::new();
    for (key, axis) in [("map.x", &map.x), ("map.y", &map.y)] {
        let Some(period) = slot(&axis.coord).map(|i| modulo[i]) else {
            continue;
        };
        if period <= 0.0 || axis.n < 2 {
            continue;
        }
        let periods = (axis.max - axis.min) / period;
        // Written as the same decimal (2 pi as 6.283185307179586, or -pi .. pi) the quotient
        // is a whole number to within a few roundings.
        if periods < 0.5 || (periods - periods.round()).abs() > 1e-12 * periods {
            continue;
        }
        let n = axis.n;
        let end = axis.min + period * (n - 1) as f64 / n as f64;
        warnings.push(format!(
            "{key}: min = {} and max = {} are the same point of {} (period {period}): the \
             last of its {n} grid lines repeats the first, computed twice; max = {end} grids \
             one period in {n} distinct lines",
            axis.min, axis.max, axis.coord
        ));
    }
    warnings
}

/// `--shard i/n`: the points with `index % n == i`. Interleaved rather than contiguous so every
/// shard gets a fair share of regular (slow) and chaotic (fast-stopping) regions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Shard {
    pub index: u32,
    pub count: u32,
}

impl Shard {
    pub const WHOLE: Shard = Shard { index: 0, count: 1 };

    pub fn contains(&self, point: u64) -> bool {
        point % self.count as u64 == self.index as u64
    }
}

impl std::str::FromStr for Shard {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let (i, n) = s
            .split_once('/')
            .ok_or_else(|| format!("{s:?} is not of the form i/n"))?;
        let index: u32 = i
            .trim()
            .parse()
            .map_err(|_| format!("bad shard index {i:?}"))?;
        let count: u32 = n
            .trim()
            .parse()
            .map_err(|_| format!("bad shard count {n:?}"))?;
        if count == 0 || index >= count {
            return Err(format!("shard {index}/{count}: need 0 <= i < n"));
        }
        Ok(Self { index, count })
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

/// How a map evolves every point's deviation sets (`[map] route`). Not a run's route
/// (`chaoscope_schemas::run::Route`): a map's basis is accumulated over the whole orbit, for
/// either method.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MapRoute {
    /// `"per-set"`: every set's own `k` tangent vectors or nearby orbits (the reference).
    PerSet,
    /// `"basis"` (`"propagator"`, its former name, is read too): one basis of `D` lanes per
    /// point, tangent vectors (VM) or nearby orbits at `d0` (MPM: a finite-difference
    /// propagator), QR-renormalized every window and accumulated as the scaled QR propagator
    /// ([`crate::propagator`]); every set's vectors formed from it ([`super::basis`]).
    Basis,
}

impl MapRoute {
    /// As configs write it.
    pub fn name(self) -> &'static str {
        match self {
            MapRoute::PerSet => "per-set",
            MapRoute::Basis => "basis",
        }
    }

    /// `[map] route` (absent: per-set).
    fn from_config(value: Option<&str>) -> Result<Self, SpecError> {
        match value {
            None | Some("per-set") => Ok(MapRoute::PerSet),
            Some("basis" | "propagator") => Ok(MapRoute::Basis),
            Some(other) => Err(SpecError::new(
                "map.route",
                format!("'{other}' is not per-set or basis"),
            )),
        }
    }
}

/// The `d0` range of the MPM basis route: there its maps agree with per-set MPM within the
/// per-set MPM-VM distance (`chaoscope bench --routes`, examples/paper/RESULTS.md). Outside it
/// the finite-difference basis carries the nonlinear terms (large `d0`) or the rounding of
/// `x + d0 q` (small `d0`) into every set at once.
pub const MPM_BASIS_D0: (f64, f64) = (1e-10, 1e-6);

/// A validated map.
#[derive(Clone)]
pub struct MapSpec {
    /// The run shared by every point; its `x0` is the base state the grid coordinates overwrite.
    pub run: RunSpec,
    pub x: Axis,
    pub y: Axis,
    pub indicator: Indicator,
    pub route: MapRoute,
    /// Whether the configuration names the route (`[map] route`): a named route is kept; an
    /// unnamed one is per-set until the estimate chooses the cheaper of two routes that give
    /// the same numbers ([`Self::routes_agree`], `estimate::map_choosing_route`).
    pub route_named: bool,
    /// Momentum index solved from `energy` per point, if any.
    pub solve_for: Option<usize>,
    pub energy: Option<f64>,
    /// The canonical configuration text (stored in recordings; resume and merge compare it).
    pub config_toml: String,
}

impl MapSpec {
    pub fn from_config(cfg: &RunConfig) -> Result<Self, SpecError> {
        let map = cfg
            .map
            .as_ref()
            .ok_or_else(|| SpecError::new("map", "a map needs a [map] section"))?;
        // Each point's state is built here; the shared run is validated with the base state
        // taken as given (it may well lie outside the energy surface itself).
        let mut base = cfg.clone();
        base.map = None;
        base.orbit.solve_for = None;
        base.orbit.energy = None;
        if cfg.run.sample_every.is_some() {
            return Err(SpecError::new(
                "run.sample_every",
                "a map records one result per point, accumulated over every renormalization; \
                 sampling applies to runs",
            ));
        }
        for (key, present) in [
            ("orbit.preset", cfg.orbit.preset.is_some()),
            ("orbit.excite", cfg.orbit.excite.is_some()),
        ] {
            if present {
                return Err(SpecError::new(
                    key,
                    "a map takes its fixed coordinates from [orbit] q and p (or x)",
                ));
            }
        }
        let k = map.k.unwrap_or(cfg.deviations.k);
        base.deviations.k = k;
        if cfg.schemes.len() != 1 {
            return Err(SpecError::new(
                "scheme",
                format!(
                    "a map uses exactly one [[scheme]], got {}",
                    cfg.schemes.len()
                ),
            ));
        }
        let lanes = lane_params(cfg, map)?;
        let run = RunSpec::from_config_with_lanes(&base, &lanes).map_err(|e| match map.k {
            // The order the user wrote is [map] k, which overrides [deviations] k.
            Some(_) if e.key == "deviations.k" => SpecError::new("map.k", e.message),
            _ => e,
        })?;
        let separable = run.system().separable().is_some();
        let n = run.dim() / 2;
        let indicator = Indicator::from_config(map, k)?;
        // The exponents beyond the first come from QR's |R_jj|; every other indicator reads
        // each vector's own growth or the directions, which QR would change.
        match (indicator.needs_qr(), run.schemes()[0].orthonormalize) {
            (true, Orthonormalization::Rescale) => {
                return Err(SpecError::new(
                    "scheme[0].orthonormalize",
                    "the spectrum is measured with QR renormalization: write \
                     orthonormalize = \"qr\" in the [[scheme]]",
                ));
            }
            (true, _) | (_, Orthonormalization::Rescale) => {}
            _ => {
                return Err(SpecError::new(
                    "scheme[0].orthonormalize",
                    "maps renormalize each vector separately (only indicator = \"spectrum\" \
                     uses QR): use \"rescale\"",
                ));
            }
        }
        let route = MapRoute::from_config(map.route.as_deref())?;
        if route == MapRoute::Basis {
            if run.system().batched(Isa::detect()).is_none() {
                return Err(SpecError::new(
                    "map.route",
                    "the basis route runs on the batched kernel (separable Hamiltonians whose \
                     potential does not read t, discrete maps, fixed-step explicit Runge-Kutta \
                     flows); use \"per-set\"",
                ));
            }
            let d0 = run.schemes()[0].d0;
            let (lo, hi) = MPM_BASIS_D0;
            if run.schemes()[0].method == Method::Mpm && !(lo..=hi).contains(&d0) {
                return Err(SpecError::new(
                    "map.route",
                    format!(
                        "the MPM basis route is valid for {lo:e} <= d0 <= {hi:e} \
                         (scheme d0 = {d0:e}); use \"per-set\""
                    ),
                ));
            }
        }
        // Any Hamiltonian (separable or written as `H(q, p)`) names its axes q1..qN / p1..pN.
        let canonical = run.system().kind() == SystemClass::Hamiltonian;
        let x = Axis::from_config("map.x", &map.x, run.dim(), canonical, &lanes)?;
        let y = Axis::from_config("map.y", &map.y, run.dim(), canonical, &lanes)?;
        if x.slot == y.slot {
            return Err(SpecError::new(
                "map.y.coord",
                "x and y are the same coordinate",
            ));
        }
        if !lanes.is_empty() && run.system().batched(Isa::detect()).is_none() {
            let key = if x.is_param {
                "map.x.param"
            } else {
                "map.y.param"
            };
            return Err(SpecError::new(
                key,
                "a parameter axis runs on the batched kernel (its points carry their parameter \
                 as a lane value): use a fixed-step explicit method (rk4, or dop853 without \
                 rtol/atol)",
            ));
        }
        if !separable {
            for (key, present) in [
                ("orbit.solve_for", cfg.orbit.solve_for.is_some()),
                ("orbit.energy", cfg.orbit.energy.is_some()),
            ] {
                if present {
                    return Err(SpecError::new(key, "applies to Hamiltonians"));
                }
            }
        }
        let solve_for = match (&cfg.orbit.solve_for, cfg.orbit.energy) {
            (Some(name), Some(e)) => {
                // Every point solves 2 (E - V) for its momentum: an energy whose double
                // overflows puts no point on the surface (and a near one, a momentum at
                // infinity).
                if !(2.0 * e).is_finite() {
                    return Err(SpecError::new(
                        "orbit.energy",
                        format!("must be finite, and twice it too, got {e:?}"),
                    ));
                }
                match parse_coordinate(name, n) {
                    Some((true, j)) if n + j == x.slot || n + j == y.slot => {
                        return Err(SpecError::new(
                            "orbit.solve_for",
                            format!("{name} is a grid axis; it cannot also be solved for"),
                        ));
                    }
                    Some((true, j)) => Some(j),
                    _ => {
                        return Err(SpecError::new(
                            "orbit.solve_for",
                            format!("'{name}' is not a momentum p1..p{n}"),
                        ));
                    }
                }
            }
            (None, None) => None,
            (Some(_), None) => {
                return Err(SpecError::new("orbit.energy", "solve_for needs an energy"));
            }
            (None, Some(_)) => {
                return Err(SpecError::new("orbit.solve_for", "energy needs solve_for"));
            }
        };
        let config_toml = run.pinned_config(cfg).to_toml();
        Ok(Self {
            x,
            y,
            indicator,
            route,
            route_named: map.route.is_some(),
            solve_for,
            energy: cfg.orbit.energy,
            run,
            config_toml,
        })
    }

    /// Whether the points run on the system's batched form (`DynamicalSystem::batched`):
    /// separable Hamiltonians, discrete maps and fixed-step explicit Runge-Kutta flows of
    /// compiled expressions; every other system runs through the one-orbit engine.
    pub fn has_batched_kernel(&self) -> bool {
        self.run.system().batched(Isa::detect()).is_some()
    }

    /// Whether the basis route gives this map's numbers as the per-set route does, to the
    /// rounding of forming each set from the basis (tests/map_routes.rs): VM, whose tangent
    /// dynamics is linear, so every set's vectors are exactly the propagator's image of its
    /// directions; on the batched kernel (the basis route's). Not MPM (the basis of nearby
    /// orbits differs by terms of order `d0`), not `spectrum` (the basis route's exponents
    /// start from the coordinate axes, each set's from its own directions), not `gali-time`
    /// (a rounding at a threshold crossing moves a set's time by a whole window).
    pub fn routes_agree(&self) -> bool {
        self.run.schemes()[0].method == Method::Vm
            && !self.indicator.needs_qr()
            && !matches!(self.indicator, Indicator::GaliTime { .. })
            && self.has_batched_kernel()
    }

    /// Whether the system's batched form advances many points' orbits and tangent bases in one
    /// fused pass (`PointKernel::fuses_orbits_and_tangents`).
    pub fn fuses_orbits_and_tangents(&self) -> bool {
        self.run
            .system()
            .batched(Isa::detect())
            .is_some_and(|k| k.fuses_orbits_and_tangents())
    }

    /// Whether the kernel's fused pass also pays for a point's few vectors (the per-set route).
    pub fn fuses_few_vectors(&self) -> bool {
        self.run
            .system()
            .batched(Isa::detect())
            .is_some_and(|k| k.fuses_few_vectors())
    }

    /// The compiled model of a `potential` (whose C step kernels' state a map reports), if
    /// this is one.
    pub fn expression_model(&self) -> Option<&ExpressionModel> {
        let model: &dyn std::any::Any = self.run.system().separable()?.model().as_ref();
        model.downcast_ref()
    }

    pub fn grid_points(&self) -> u64 {
        (self.x.n * self.y.n) as u64
    }

    pub fn sets(&self) -> usize {
        self.run.sets()
    }

    /// `(ix, iy)` of a point index.
    pub fn cell(&self, index: u64) -> (usize, usize) {
        let i = index as usize;
        (i % self.x.n, i / self.x.n)
    }

    /// `D + P`: a point's state, its `D` coordinates then the values of its parameter axes.
    pub fn state_len(&self) -> usize {
        self.run.x0().len()
    }

    /// The length of a lane of the scheme's method: a state (orbits, MPM) or a deviation
    /// vector (tangent vectors, VM: the `D` coordinates only).
    pub fn lane_len(&self, lanes_are_orbits: bool) -> usize {
        if lanes_are_orbits {
            self.state_len()
        } else {
            self.run.dim()
        }
    }

    /// The initial condition of a point, or why it has none (outside the energy surface): its
    /// `D` coordinates, then its parameters when the map has parameter axes.
    pub fn initial_state(&self, index: u64) -> Result<Vec<f64>, String> {
        let (ix, iy) = self.cell(index);
        let mut x = self.run.x0().to_vec();
        x[self.x.slot] = self.x.value(ix);
        x[self.y.slot] = self.y.value(iy);
        if let (Some(j), Some(e), Some(separable)) =
            (self.solve_for, self.energy, self.run.system().separable())
        {
            let model = separable.model();
            if model.lane_params() > 0 {
                // The energy at the point's own parameters.
                let (coordinates, params) = x.split_at_mut(self.run.dim());
                solve_momentum(&WithParams::new(model, params), coordinates, j, e)
            } else {
                solve_momentum(model.as_ref(), &mut x, j, e)
            }
            .map_err(|e| e.message)?;
        }
        Ok(x)
    }

    /// The one-orbit run of a point (what the [`crate::engine::Engine`] integrates).
    pub fn point_run(&self, x0: &[f64]) -> RunSpec {
        self.run.starting_at(x0)
    }

    /// Points of `shard`, in index order.
    pub fn shard_points(&self, shard: Shard) -> impl Iterator<Item = u64> + '_ {
        (0..self.grid_points()).filter(move |&i| shard.contains(i))
    }
}

impl MapSpec {
    /// A point's identity, before any number is known.
    /// Where every way of computing point `index` starts: its result so far (grid cell, `x0`)
    /// and its initial state, or, for a point outside the energy surface, its final result
    /// (boxed: the rare path).
    pub fn start_point(&self, index: u64) -> Result<(PointResult, Vec<f64>), Box<PointResult>> {
        let base = self.base_result(index);
        match self.initial_state(index) {
            Ok(x0) => Ok((
                PointResult {
                    // The coordinates: a parameter is the point's x or y already.
                    x0: x0[..self.run.dim()].to_vec(),
                    ..base
                },
                x0,
            )),
            Err(reason) => Err(Box::new(failed(
                base,
                PointStatus::OutsideEnergySurface,
                0.0,
                reason,
            ))),
        }
    }

    /// A point's accumulator of the indicator over its sets.
    pub fn accumulator(&self) -> PointAccumulator {
        PointAccumulator::new(
            self.indicator,
            self.run.dim(),
            self.run.sets(),
            self.run.t_final(),
        )
    }

    pub fn base_result(&self, index: u64) -> super::PointResult {
        let (ix, iy) = self.cell(index);
        super::PointResult {
            index,
            ix: ix as u32,
            iy: iy as u32,
            x: self.x.value(ix),
            y: self.y.value(iy),
            status: super::PointStatus::Ok,
            value: f64::NAN,
            per_set: Vec::new(),
            mean_log10: 0.0,
            spectrum: Vec::new(),
            t_end: 0.0,
            orbit_steps: 0,
            reason: String::new(),
            x0: Vec::new(),
        }
    }
}
