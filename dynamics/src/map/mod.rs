//! Phase-space maps: a grid of initial conditions over two coordinates or parameters of the
//! model, one chaos indicator per point (`chaoscope map`).
//!
//! A parameter axis makes the parameter an input of the compiled functions
//! ([`crate::spec::LaneParam`]): a point's state is its coordinates followed by its parameters,
//! orbit lanes carry them as rows the kernels read and never write, tangent lanes (deviation
//! vectors) hold the coordinates only.
//!
//! - [`spec`]: the validated `[map]` section, the grid, shards, each point's initial condition.
//! - [`indicator`]: what is accumulated per deviation set and how a point's value is formed.
//! - [`point`]: a point's result.
//! - [`per_set`]: the per-set route, every set's `k` lanes; [`basis`]: the basis route, every
//!   set formed from one evolved basis per point. Both drive the scheme's method
//!   ([`crate::method`]) over the system's batched form (`DynamicalSystem::batched`, a
//!   [`crate::batch::PointKernel`]).
//! - [`one_orbit`]: the same point computed by the one-orbit [`crate::engine::Engine`]; the
//!   batched path must agree with it bit for bit (tests).
//! - [`schedule`]: rayon across points, results streamed to a sink as they complete.
//!
//! Every point is a deterministic function of the configuration and its grid index alone, so
//! results are identical for any thread count, batch grouping, shard split or resumption.

pub mod basis;
pub mod indicator;
pub mod one_orbit;
pub mod per_set;
pub mod point;
pub mod record;
pub mod schedule;
pub mod spec;
mod window;

pub use indicator::Indicator;
pub use point::{PointResult, PointStatus};
pub use schedule::{Batching, MapOptions, run_map};
pub use spec::{MapRoute, MapSpec, Shard};
