//! Names shared by every process: run names, iceoryx2 service and node names, MCAP topics and
//! metadata keys.

/// Prefix of every chaoscope service; discovery looks for `<prefix><run>/<stream>`.
pub const SERVICE_PREFIX: &str = "chaoscope/run/";

/// Longest accepted run name (service names are limited to 255 bytes by iceoryx2).
pub const MAX_RUN_NAME_LEN: usize = 64;

/// The streams of a run on the bus.
pub mod stream {
    /// Run header (protobuf `RunHeader` bytes), kept as history for late subscribers.
    pub const HEADER: &str = "header";
    /// Lossless data stream: reference states, separation sets, end of run.
    pub const DATA: &str = "data";
    /// Event service the producer notifies after publishing data.
    pub const DATA_READY: &str = "data-ready";
    /// Event service on which each lossless receiver holds a listener once its data
    /// connection is up: the producer counts them before streaming (a frame sent before a
    /// receiver is connected could be lost once its buffer is full).
    pub const READY: &str = "ready";
    /// Lossy copy of the data stream for live monitors; never slows the producer.
    pub const MONITOR: &str = "monitor";
}

/// Prefix of the services of a map (`chaoscope map`): `<prefix><map name>/<map_stream>`.
pub const MAP_SERVICE_PREFIX: &str = "chaoscope/map/";

/// The streams of a map on the bus (names follow the run rules, [`validate_run_name`]).
pub mod map_stream {
    /// Map header (protobuf `MapHeader` bytes), kept as history for late subscribers.
    pub const HEADER: &str = "header";
    /// Lossy stream of finished points (protobuf `MapPoint` bytes), then an end record.
    pub const POINTS: &str = "points";
}

/// A run name is a service-name component and a file name (`runs/<name>.mcap`): letters,
/// digits, `-`, `_` and `.` (`h0.01`), 1..=64 bytes, not starting with `.` (no hidden file, no
/// `.` or `..`). iceoryx2 takes any bytes in a service or node name (it hashes them into its
/// own file names), so only `/`, which separates the components, must stay out.
pub fn validate_run_name(name: &str) -> Result<(), String> {
    if name.is_empty() || name.len() > MAX_RUN_NAME_LEN {
        return Err(format!(
            "run name must have 1 to {MAX_RUN_NAME_LEN} characters, got {}",
            name.len()
        ));
    }
    if let Some(c) = name
        .chars()
        .find(|c| !(c.is_ascii_alphanumeric() || "-_.".contains(*c)))
    {
        return Err(format!(
            "run name {name:?} contains {c:?}; use letters, digits, '-', '_' and '.'"
        ));
    }
    if name.starts_with('.') {
        return Err(format!(
            "run name {name:?} starts with '.'; start it with a letter, digit, '-' or '_'"
        ));
    }
    Ok(())
}

/// A scheme name: 1 to [`MAX_SCHEME_NAME_LEN`] letters, digits, `-`, `_` or `.`. It is a topic
/// component (`/chaoscope/separations/<name>`) and part of the file names `analyze --csv` and
/// `--plot` write, so it can hold no `/` and nothing that climbs out of the directory the user
/// gave. Configs are checked with it, and so are the headers of recordings, which may come from
/// anyone.
pub fn validate_scheme_name(name: &str) -> Result<(), String> {
    if name.is_empty()
        || name.len() > MAX_SCHEME_NAME_LEN
        || !name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c))
    {
        // Quoted with escapes and cut short: the name may be anything a file holds.
        let shown: String = name.chars().take(80).collect();
        let more = if shown.len() < name.len() { "..." } else { "" };
        return Err(format!(
            "'{}{more}' must be 1 to {MAX_SCHEME_NAME_LEN} letters, digits, '-', '_' or '.'",
            shown.escape_debug()
        ));
    }
    Ok(())
}

/// Longest scheme name (a file name component of `analyze --csv/--plot`).
pub const MAX_SCHEME_NAME_LEN: usize = 200;

/// iceoryx2 service name of one stream of a run.
pub fn service_name(run: &str, stream: &str) -> String {
    format!("{SERVICE_PREFIX}{run}/{stream}")
}

/// The run of a service name of the form `<prefix><run>/header`, if it is one.
pub fn run_of_header_service(service: &str) -> Option<&str> {
    let run = service
        .strip_prefix(SERVICE_PREFIX)?
        .strip_suffix(&format!("/{}", stream::HEADER))?;
    validate_run_name(run).ok().map(|_| run)
}

/// iceoryx2 service name of one stream of a map.
pub fn map_service_name(map: &str, stream: &str) -> String {
    format!("{MAP_SERVICE_PREFIX}{map}/{stream}")
}

/// The map of a service name of the form `<map prefix><map>/header`, if it is one.
pub fn map_of_header_service(service: &str) -> Option<&str> {
    let map = service
        .strip_prefix(MAP_SERVICE_PREFIX)?
        .strip_suffix(&format!("/{}", map_stream::HEADER))?;
    validate_run_name(map).ok().map(|_| map)
}

/// Node name of the `chaoscope map` process publishing map `map`; watchers watch its liveness.
pub fn map_node_name(map: &str) -> String {
    format!("chaoscope-map/{map}")
}

/// Node name of a map watcher.
pub fn map_watcher_node_name(map: &str) -> String {
    format!("chaoscope-map-watch/{map}")
}

/// Node name of the producer of a run; recorders watch its liveness.
pub fn producer_node_name(run: &str) -> String {
    format!("chaoscope-dynamics/{run}")
}

/// Node name of a recorder of a run.
pub fn recorder_node_name(run: &str) -> String {
    format!("chaoscope-recorder/{run}")
}

/// MCAP topics.
pub mod topic {
    pub const RUN: &str = "/chaoscope/run";
    pub const REFERENCE: &str = "/chaoscope/reference";
    pub const END: &str = "/chaoscope/end";
    pub const RECORDING: &str = "/chaoscope/recording";
    /// Map recordings (`chaoscope map`): the grid description, then one message per point.
    pub const MAP_HEADER: &str = "/chaoscope/map/header";
    pub const MAP_POINTS: &str = "/chaoscope/map/points";

    /// One channel per scheme: `/chaoscope/separations/<scheme name>`.
    pub fn separations(scheme_name: &str) -> String {
        format!("/chaoscope/separations/{scheme_name}")
    }

    /// One channel per scheme: `/chaoscope/indicators/<scheme name>` (GALI, SALI, exponents
    /// averaged over the sets, at each of the scheme's renormalizations).
    pub fn indicators(scheme_name: &str) -> String {
        format!("/chaoscope/indicators/{scheme_name}")
    }
}

/// MCAP metadata record names and keys.
pub mod metadata {
    /// Run description: keys `format_version`, `run_name`, `config_toml`.
    pub const RUN: &str = "chaoscope.run";
    /// How the recording ended: keys `finalized_by`, `run_status`, `frames_received`,
    /// `frames_missing`.
    pub const RECORDING: &str = "chaoscope.recording";
    /// Added by `chaoscope recover`: keys `source`, `messages_salvaged`, `stopped_at`.
    pub const RECOVERY: &str = "chaoscope.recovery";
    /// Map description: keys `format_version`, `config_toml`, `shard`.
    pub const MAP: &str = "chaoscope.map";
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn run_names_are_checked() {
        assert!(validate_run_name("hh-chaotic_1").is_ok());
        assert!(validate_run_name("").is_err());
        assert!(validate_run_name("a/b").unwrap_err().contains("'/'"));
        assert!(validate_run_name("h0.01").is_ok());
        for hidden in [".", "..", ".h"] {
            assert!(
                validate_run_name(hidden)
                    .unwrap_err()
                    .contains("starts with '.'")
            );
        }
        assert!(validate_run_name(&"x".repeat(65)).is_err());
    }

    #[test]
    fn header_service_round_trips_the_run() {
        let s = service_name("r1", stream::HEADER);
        assert_eq!(run_of_header_service(&s), Some("r1"));
        assert_eq!(
            run_of_header_service(&service_name("r1", stream::DATA)),
            None
        );
        assert_eq!(run_of_header_service("other/r1/header"), None);
        let m = map_service_name("m1", map_stream::HEADER);
        assert_eq!(map_of_header_service(&m), Some("m1"));
        assert_eq!(run_of_header_service(&m), None);
        assert_eq!(map_of_header_service(&s), None);
    }
}
