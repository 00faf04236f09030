//! A recording written on a thread of its own, so that a recorder uses two cores: the bus
//! thread decodes frames, computes the indicators (a detached [`IndicatorStream`]) and encodes
//! the messages for the file (the file's [`Encoder`]), the writer thread compresses and writes
//! them. At every message the two do what [`Recording::on_message`] does on one thread, so the
//! file holds the same messages in the same order (only MCAP's `publish_time`, the wall-clock
//! time of writing, differs, as it does between any two recordings).
//!
//! Why: with a run sampled at every step, a one-threaded recorder spent its core on zstd
//! (about half), the indicators and the bus, and the producer waited for it
//! (`cargo bench --bench pipeline`). With two threads the writer's is the busier (zstd is about
//! three quarters of it), so everything else, protobuf encoding included, is on the bus thread.
//! The queue between the threads is bounded, so a slow disk still holds the producer back
//! (nothing is dropped), and what it holds is at most [`QUEUE_BATCHES`] x [`BATCH`] data
//! messages, which a killed recorder loses like its open chunk.

use std::io::{Seek, Write};
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::thread::JoinHandle;

use chaoscope_schemas::proto::DataMessage;
use chaoscope_schemas::proto::{EndOfRun, RecordingSummary};

use chaoscope_files::file::{EncodedMessages, Encoder};
use chaoscope_files::indicators::IndicatorStream;
use chaoscope_files::recording::{FinalizedBy, Recording};

/// Data messages sent to the writer thread at once (the cost of a hand-over is paid per batch).
pub const BATCH: usize = 256;
/// Batches the queue holds before the bus thread waits for the writer.
pub const QUEUE_BATCHES: usize = 8;

enum Command {
    /// Messages encoded for the file, indicators included, and the run's end-of-run record if
    /// they hold it.
    Messages(EncodedMessages, Option<EndOfRun>),
    CloseChunk,
}

/// What the writer thread hands back: the recording, and the write error that stopped it.
type Outcome<W> = (Recording<W>, Option<mcap::McapError>);

/// A [`Recording`] being written by its own thread.
pub struct WriteThread<W: Write + Seek + Send + 'static> {
    indicators: IndicatorStream,
    encoder: Encoder,
    batch: EncodedMessages,
    /// Data messages in `batch`.
    queued: usize,
    end: Option<EndOfRun>,
    /// A message this side could not encode (a separation set of a scheme the header did not
    /// announce): the recording stops there, as at a write error.
    error: Option<mcap::McapError>,
    queue: Option<SyncSender<Command>>,
    writer: JoinHandle<Outcome<W>>,
}

impl<W: Write + Seek + Send + 'static> WriteThread<W> {
    /// Moves `recording` to a new writer thread; its indicators are computed and its messages
    /// encoded by this side.
    pub fn start(mut recording: Recording<W>) -> std::io::Result<Self> {
        let indicators = recording.detach_indicators();
        let encoder = recording.encoder();
        let (queue, commands) = sync_channel(QUEUE_BATCHES);
        let writer = std::thread::Builder::new()
            .name("recording writer".into())
            .spawn(move || write_all(recording, commands))?;
        Ok(Self {
            indicators,
            encoder,
            batch: EncodedMessages::default(),
            queued: 0,
            end: None,
            error: None,
            queue: Some(queue),
            writer,
        })
    }

    /// Queues one message. `false` once the writer thread has stopped on an error (which
    /// [`Self::finish`] returns): stop feeding it then.
    pub fn push(&mut self, message: DataMessage) -> bool {
        let indicators = self.indicators.before(&message);
        let encoded = self
            .encoder
            .indicators(&indicators, &mut self.batch)
            .and_then(|()| self.encoder.message(&message, &mut self.batch));
        if let Err(e) = encoded {
            // What was encoded before it is written, as a one-thread recording would.
            self.flush();
            self.error = Some(e);
            self.queue = None;
            return false;
        }
        if let DataMessage::End(m) = message {
            self.end = Some(m);
        }
        self.queued += 1;
        self.queued < BATCH || self.flush()
    }

    /// Hands the queued messages to the writer thread (call when the bus is idle, so the file
    /// does not lag behind the run).
    pub fn flush(&mut self) -> bool {
        if self.batch.is_empty() {
            return self.queue.is_some();
        }
        let next = self.batch.empty_like();
        let batch = std::mem::replace(&mut self.batch, next);
        self.queued = 0;
        let end = self.end.take();
        self.send(Command::Messages(batch, end))
    }

    /// Closes the open chunk after everything queued so far (bounds what a crash loses).
    pub fn close_chunk(&mut self) -> bool {
        self.flush() && self.send(Command::CloseChunk)
    }

    fn send(&mut self, command: Command) -> bool {
        let sent = self.queue.as_ref().is_some_and(|q| q.send(command).is_ok());
        if !sent {
            self.queue = None;
        }
        sent
    }

    /// Writes what is queued, the last indicators and the summary, and closes the file. On a
    /// write error the file is still finalized as far as it goes (as interrupted) and the
    /// error returned.
    pub fn finish(mut self, reason: FinalizedBy) -> mcap::McapResult<(W, RecordingSummary)> {
        self.flush();
        self.queue = None;
        let (recording, error) = self.writer.join().map_err(|_| {
            mcap::McapError::Io(std::io::Error::other(
                "the recording writer thread panicked",
            ))
        })?;
        let last = self.indicators.take();
        match error.or(self.error) {
            None => recording.finish_after(&last, reason),
            Some(e) => {
                let _ = recording.finish_after(&last, FinalizedBy::Signal);
                Err(e)
            }
        }
    }
}

/// The writer thread: every command in order, until the queue closes or a write fails.
fn write_all<W: Write + Seek>(
    mut recording: Recording<W>,
    commands: Receiver<Command>,
) -> Outcome<W> {
    for command in commands {
        let result = match command {
            Command::Messages(messages, end) => recording.on_encoded(&messages, end).map(drop),
            Command::CloseChunk => recording.close_chunk(),
        };
        if let Err(e) = result {
            // Dropping the queue's receiver tells the bus thread.
            return (recording, Some(e));
        }
    }
    (recording, None)
}

#[cfg(test)]
mod tests {
    use super::*;
    use chaoscope_files::file::FileOptions;
    use chaoscope_files::testing;
    use chaoscope_schemas::proto::RunHeader;
    use std::io::Cursor;

    /// (topic, sequence, log time, payload) of every message of a file, in file order: all but
    /// the publish time, the wall-clock time of writing.
    fn messages(bytes: &[u8]) -> Vec<(String, u32, u64, Vec<u8>)> {
        testing::mcap_messages(bytes)
            .into_iter()
            .map(|(topic, sequence, log_time, _, data)| (topic, sequence, log_time, data))
            .collect()
    }

    /// A run of a 4-dimensional system with `k` vectors in each of `sets` sets.
    fn run(k: u32, sets: u32, samples: u64) -> (RunHeader, Vec<DataMessage>) {
        let shape = testing::Shape {
            dim: 4,
            k,
            sets,
            samples,
        };
        testing::run_messages(&shape, 11)
    }

    /// The same run written on one thread and on two, with chunk closes and a small queue
    /// hand-over in between: the same messages in the same order, indicators included.
    #[test]
    fn the_file_is_the_one_a_single_thread_writes() {
        let (header, run) = run(3, 2, 500);
        let options = FileOptions {
            chunk_size: 4096,
            ..FileOptions::default()
        };
        let mut one = Recording::start(Cursor::new(Vec::new()), &header, &options).unwrap();
        for m in &run {
            one.on_message(m).unwrap();
        }
        let (one, one_summary) = one.finish(FinalizedBy::EndOfRun).unwrap();

        let two = Recording::start(Cursor::new(Vec::new()), &header, &options).unwrap();
        let mut two = WriteThread::start(two).unwrap();
        for (i, m) in run.iter().enumerate() {
            assert!(two.push(m.clone()));
            if i % 37 == 0 {
                assert!(two.close_chunk());
            }
        }
        let (two, two_summary) = two.finish(FinalizedBy::EndOfRun).unwrap();

        let (one, two) = (messages(one.get_ref()), messages(two.get_ref()));
        assert!(
            one.iter()
                .any(|m| m.0.starts_with("/chaoscope/indicators/")),
            "the run has indicators"
        );
        assert_eq!(one.len(), two.len());
        assert!(one == two, "the messages differ");
        assert_eq!(one_summary, two_summary);
    }

    /// A set of a scheme the header did not announce, caught where messages are encoded (the
    /// bus thread): `push` refuses it and `finish` returns the error, as at a write error; no
    /// panic.
    #[test]
    fn a_set_of_an_unknown_scheme_stops_the_recording_with_an_error() {
        let (header, run) = run(2, 1, 20);
        let recording =
            Recording::start(Cursor::new(Vec::new()), &header, &FileOptions::default()).unwrap();
        let mut thread = WriteThread::start(recording).unwrap();
        let before = 7;
        for m in &run[..before] {
            assert!(thread.push(m.clone()));
        }
        let unknown = chaoscope_schemas::proto::SeparationSet {
            frame: before as u64,
            scheme: header.schemes.len() as u32,
            ..Default::default()
        };
        assert!(!thread.push(DataMessage::Separations(unknown)));
        let Err(error) = thread.finish(FinalizedBy::EndOfRun) else {
            panic!("an unknown scheme must be an error");
        };
        assert!(
            matches!(error, mcap::McapError::UnknownChannel(..)),
            "{error}"
        );
    }
}
