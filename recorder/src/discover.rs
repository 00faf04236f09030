//! Finding a run to record when none is named.

use std::time::{Duration, Instant};

use chaoscope_bus::{self as bus, BusError, Liveness};
use chaoscope_schemas::names;

/// Outcome of waiting for a run.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Discovery {
    Found(String),
    /// SIGINT or SIGTERM arrived while waiting.
    Signal,
    TimedOut,
}

/// The first run on the bus whose producer is alive; waits for one to appear if there is none.
/// Runs left behind by dead producers are cleaned up, not recorded.
pub fn wait_for_run(timeout: Option<Duration>) -> Result<Discovery, BusError> {
    let node = bus::create_node("chaoscope-recorder/discovery")?;
    let start = Instant::now();
    loop {
        let live = bus::list_runs()
            .into_iter()
            .find(|run| bus::node_liveness(&names::producer_node_name(run)) == Liveness::Alive);
        if let Some(run) = live {
            return Ok(Discovery::Found(run));
        }
        if timeout.is_some_and(|t| start.elapsed() > t) {
            return Ok(Discovery::TimedOut);
        }
        if !bus::poll_wait(&node) {
            return Ok(Discovery::Signal);
        }
    }
}
