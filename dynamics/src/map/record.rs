//! Map results as the protobuf messages of the recording contract.

use chaoscope_schemas::FORMAT_VERSION;
use chaoscope_schemas::proto::{self, MapHeader, MapPoint, map_point};

use super::point::{PointResult, PointStatus};
use super::spec::{Axis, MapSpec, Shard};

fn axis(a: &Axis) -> proto::MapAxis {
    // A parameter axis names its parameter, never a coordinate.
    let (coord, param) = if a.is_param {
        (String::new(), a.name.clone())
    } else {
        (a.name.clone(), String::new())
    };
    proto::MapAxis {
        coord,
        param,
        min: a.min,
        max: a.max,
        n: a.n as u32,
    }
}

impl MapSpec {
    /// The header of a recording of `shard` of this map.
    pub fn header(&self, shard: Shard) -> MapHeader {
        MapHeader {
            format_version: FORMAT_VERSION,
            config_toml: self.config_toml.clone(),
            model: self.run.system().name().to_string(),
            indicator: self.indicator.name().to_string(),
            k: self.run.k() as u32,
            threshold: self.indicator.threshold(),
            method: self.run.schemes()[0].method.name().to_string(),
            x: Some(axis(&self.x)),
            y: Some(axis(&self.y)),
            sets: self.sets() as u32,
            t_final: self.run.t_final(),
            shard_index: shard.index,
            shard_count: shard.count,
            grid_points: self.grid_points(),
            producer_version: env!("CARGO_PKG_VERSION").to_string(),
        }
    }
}

impl From<&PointResult> for MapPoint {
    fn from(r: &PointResult) -> Self {
        let status = match r.status {
            PointStatus::Ok => map_point::Status::Ok,
            PointStatus::OutsideEnergySurface => map_point::Status::OutsideEnergySurface,
            PointStatus::Escaped => map_point::Status::Escaped,
        };
        MapPoint {
            index: r.index,
            ix: r.ix,
            iy: r.iy,
            x: r.x,
            y: r.y,
            status: status as i32,
            value: r.value,
            per_set: r.per_set.clone(),
            mean_log10: r.mean_log10,
            spectrum: r.spectrum.clone(),
            t_end: r.t_end,
            orbit_steps: r.orbit_steps,
            reason: r.reason.clone(),
            x0: r.x0.clone(),
        }
    }
}
