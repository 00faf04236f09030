//! `chaoscope monitor --foxglove [ADDR]`: the live run served over the Foxglove WebSocket
//! protocol (the `foxglove` crate's server), so Foxglove or Lichtblick plot it while it runs.
//!
//! Channels: `/chaoscope/reference` (the reference state and energy at each renormalization) and
//! `/chaoscope/indicators/<scheme>` (GALI, SALI, exponents averaged over the sets), the same
//! protobuf messages a recording holds, each advertised with the FileDescriptorSet as its schema.
//! The indicators come from the recorder's indicator stream (the tracker `analyze` reports
//! from), fed the monitor's lossy copy of the run. Log times are simulation time in ns, as in
//! files.

use std::net::SocketAddr;
use std::sync::Arc;

use anyhow::Context as _;
use chaoscope_files::file::log_time_of;
use chaoscope_files::indicators::IndicatorStream;
use chaoscope_schemas::names::topic;
use chaoscope_schemas::proto::DataMessage;
use chaoscope_schemas::proto::{self, RunHeader, schema_name};
use foxglove::{Context, PartialMetadata, RawChannel, Schema, WebSocketServerHandle};
use prost::Message;

/// Where `--foxglove` without an address serves (Foxglove's default port, this machine only).
pub const DEFAULT_ADDR: &str = "127.0.0.1:8765";

/// Who can read the run once the server listens on `addr`. The server (Foxglove's protocol)
/// has no authentication and a TCP connection does not say which local user made it, so the
/// bus's privacy ends here; the user is told so where they turn it on.
pub fn who_can_read(addr: SocketAddr) -> String {
    let who = if addr.ip().is_loopback() {
        "any user of this machine"
    } else {
        "anyone who can reach this address over the network, and any user of this machine"
    };
    format!(
        "the Foxglove server has no access control: {who} can connect to it and read this run \
         while it is served"
    )
}

/// The WebSocket server, running on its own threads until [`FoxgloveServer::stop`].
pub struct FoxgloveServer {
    context: Arc<Context>,
    handle: WebSocketServerHandle,
}

impl FoxgloveServer {
    /// Starts serving on `addr` (port 0: any free port) and says where on stderr.
    pub fn start(addr: SocketAddr) -> anyhow::Result<Self> {
        let context = Context::new();
        let handle = context
            .websocket_server()
            .name("chaoscope")
            .bind(addr.ip().to_string(), addr.port())
            .start_blocking()
            .with_context(|| format!("starting the Foxglove WebSocket server on {addr}"))?;
        chaoscope_os::errln!(
            "chaoscope monitor: serving the run to Foxglove on ws://{}:{}",
            addr.ip(),
            handle.port()
        );
        eprintln!("chaoscope monitor: warning: {}", who_can_read(addr));
        Ok(Self { context, handle })
    }

    /// The channels of `header`'s run, advertised to connected and future clients.
    pub fn channels(&self, header: &RunHeader) -> anyhow::Result<LiveChannels> {
        let channel = |schema: &str, topic: &str| -> anyhow::Result<Arc<RawChannel>> {
            self.context
                .channel_builder(topic)
                .message_encoding(proto::MESSAGE_ENCODING)
                .schema(Schema::new(
                    schema,
                    proto::SCHEMA_ENCODING,
                    proto::FILE_DESCRIPTOR_SET,
                ))
                .build_raw()
                .with_context(|| format!("Foxglove channel {topic}"))
        };
        Ok(LiveChannels {
            reference: channel(schema_name::REFERENCE_STATE, topic::REFERENCE)?,
            indicators: header
                .schemes
                .iter()
                .map(|s| channel(schema_name::INDICATORS, &topic::indicators(&s.name)))
                .collect::<anyhow::Result<_>>()?,
            stream: IndicatorStream::new(header),
            encoded: Vec::new(),
        })
    }

    /// Closes the connections and waits for the server's tasks.
    pub fn stop(self) {
        self.handle.stop().wait_blocking();
    }
}

/// The channels of one run and the indicator state behind them.
pub struct LiveChannels {
    reference: Arc<RawChannel>,
    indicators: Vec<Arc<RawChannel>>,
    stream: IndicatorStream,
    encoded: Vec<u8>,
}

impl LiveChannels {
    /// Publishes what a message of the run brings: a reference state at once; a scheme's
    /// indicators once its sample is complete (the next reference state or the end of the run).
    pub fn on_message(&mut self, message: &DataMessage) {
        match message {
            DataMessage::Reference(r) => {
                self.publish_indicators();
                log(&self.reference, &mut self.encoded, r, r.t);
            }
            DataMessage::Separations(s) => self.stream.observe(s),
            DataMessage::End(_) => self.publish_indicators(),
        }
    }

    /// Publishes the indicators still due (at the end of the stream).
    pub fn finish(&mut self) {
        self.publish_indicators();
    }

    fn publish_indicators(&mut self) {
        for m in self.stream.take() {
            log(
                &self.indicators[m.scheme as usize],
                &mut self.encoded,
                &m,
                m.t,
            );
        }
    }
}

fn log(channel: &RawChannel, encoded: &mut Vec<u8>, message: &impl Message, t: f64) {
    encoded.clear();
    message.encode(encoded).expect("a Vec grows as needed");
    channel.log_with_meta(
        encoded,
        PartialMetadata {
            log_time: Some(log_time_of(t)),
        },
    );
}
