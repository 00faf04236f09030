//! Salvaging an MCAP file whose writer died (`kill -9`, power loss): every record up to the
//! first damaged one is copied into a new, properly indexed and summarized file.
//!
//! The input is streamed ([`crate::scan`]): memory stays at about one chunk whatever the size of
//! the file, and a damaged chunk is dropped whole.

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{BufReader, BufWriter};
use std::path::{Path, PathBuf};

use chaoscope_schemas::names::metadata;
use mcap::records::{Metadata, Record};

use crate::scan::{Entry, FileError, Scanner};

/// What a recovery salvaged.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct RecoverReport {
    pub messages: u64,
    pub chunks: u64,
    pub metadata: u64,
    pub attachments: u64,
    /// Where and why reading stopped, if the input is damaged; `None` if it was complete.
    pub stopped_at: Option<String>,
}

#[derive(Debug, thiserror::Error)]
pub enum RecoverError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path} is not an MCAP file (no MCAP magic at the start)")]
    NotMcap { path: PathBuf },
    #[error(
        "{path} is the input file: recover never writes over its input (choose another output)"
    )]
    SameFile { path: PathBuf },
    #[error(transparent)]
    Output(#[from] chaoscope_os::OutputError),
    /// The whole cause in the message (`...: File too large`) and no error source, so that a
    /// chain printer does not repeat it.
    #[error("{path}: MCAP: {}", crate::file::error_chain(error))]
    Mcap {
        path: PathBuf,
        error: mcap::McapError,
    },
}

/// Copies the readable records of `input` into a new file at `output` (through
/// [`chaoscope_os::output`]: complete or not at all). `input` may be the in-progress file a
/// killed writer left for `output` (`NAME.partial` recovered into `NAME`): it is left as it is.
pub fn recover(input: &Path, output: &Path, force: bool) -> Result<RecoverReport, RecoverError> {
    let (scanner, identity) = Scanner::open_file(input).map_err(|e| match e {
        FileError::Io { path, source } => RecoverError::Io { path, source },
        FileError::NotMcap { path } => RecoverError::NotMcap { path },
    })?;
    if same_file(&identity, input, output) {
        return Err(RecoverError::SameFile {
            path: output.into(),
        });
    }
    let options = chaoscope_os::OutputOptions {
        replace: force,
        create_dir: false,
        inputs: vec![input.to_path_buf()],
        // Another killed writer's file for this name is not ours to discard.
        leftover: chaoscope_os::Leftover::Resume,
        keep_failed: false,
    };
    let mut out = chaoscope_os::Output::create(output, &options)?;
    let file = out.start_fresh()?;
    // A half-written salvage is no use: on an error it is removed (dropping `out`), and the
    // error says what went wrong.
    let report = salvage(scanner, file, input, output)?;
    out.commit()?;
    Ok(report)
}

/// Whether `output` is the file `input` is (opened, with metadata `identity`): the same path
/// spelled otherwise, a symbolic or a hard link.
#[cfg(unix)]
fn same_file(identity: &std::fs::Metadata, _input: &Path, output: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    std::fs::metadata(output)
        .is_ok_and(|out| (out.dev(), out.ino()) == (identity.dev(), identity.ino()))
}

/// Whether `output` is the file `input` is: the same canonical path.
#[cfg(not(unix))]
fn same_file(_identity: &std::fs::Metadata, input: &Path, output: &Path) -> bool {
    matches!(
        (std::fs::canonicalize(input), std::fs::canonicalize(output)),
        (Ok(a), Ok(b)) if a == b
    )
}

/// Streams the records `scanner` reads into a new MCAP file on `out`.
fn salvage(
    mut scanner: Scanner<BufReader<File>>,
    out: File,
    input: &Path,
    output: &Path,
) -> Result<RecoverReport, RecoverError> {
    let mcap_err = |error| RecoverError::Mcap {
        path: output.into(),
        error,
    };
    let mut writer = mcap::WriteOptions::new()
        .library(format!("chaoscope recover {}", env!("CARGO_PKG_VERSION")))
        .compression_threads(0)
        .create(BufWriter::new(out))
        .map_err(mcap_err)?;

    let mut copier = Copier {
        writer: &mut writer,
        schemas: HashMap::new(),
        channels: HashMap::new(),
        report: RecoverReport::default(),
    };
    let input_err = |source| RecoverError::Io {
        path: input.into(),
        source,
    };
    while let Some(entry) = scanner.next().map_err(input_err)? {
        let copied = match entry {
            Entry::Record(record) => copier.copy(record),
            Entry::Chunk(records) => records
                .into_iter()
                .try_for_each(|record| copier.copy(record))
                .map(|()| copier.report.chunks += 1),
        };
        // The writer failed: the output, not the input (the caller removes the output).
        copied.map_err(mcap_err)?;
    }
    let mut report = copier.report;
    report.stopped_at = scanner.scan().stopped_at.clone();
    writer
        .write_metadata(&Metadata {
            name: metadata::RECOVERY.into(),
            metadata: BTreeMap::from([
                ("source".to_string(), input.display().to_string()),
                ("messages_salvaged".to_string(), report.messages.to_string()),
                (
                    "stopped_at".to_string(),
                    report
                        .stopped_at
                        .clone()
                        .unwrap_or_else(|| "end of file".into()),
                ),
            ]),
        })
        .map_err(mcap_err)?;
    writer.finish().map_err(mcap_err)?;
    let out = writer
        .into_inner()
        .into_inner()
        .map_err(|e| RecoverError::Io {
            path: output.into(),
            source: e.into_error(),
        })?;
    out.sync_all().map_err(|source| RecoverError::Io {
        path: output.into(),
        source,
    })?;
    Ok(report)
}

/// Re-emits records, mapping the input's schema and channel ids to the output's.
struct Copier<'w, W: std::io::Write + std::io::Seek> {
    writer: &'w mut mcap::Writer<W>,
    schemas: HashMap<u16, u16>,
    channels: HashMap<u16, u16>,
    report: RecoverReport,
}

impl<W: std::io::Write + std::io::Seek> Copier<'_, W> {
    /// Copies one record; chunks come as their records, and indexes, statistics and the summary
    /// are rebuilt by the writer.
    fn copy(&mut self, record: Record<'_>) -> mcap::McapResult<()> {
        match record {
            Record::Schema { header, data } => {
                let id = self
                    .writer
                    .add_schema(&header.name, &header.encoding, &data)?;
                self.schemas.insert(header.id, id);
            }
            Record::Channel(c) => {
                let schema = if c.schema_id == 0 {
                    0
                } else {
                    self.schemas.get(&c.schema_id).copied().unwrap_or(0)
                };
                let id =
                    self.writer
                        .add_channel(schema, &c.topic, &c.message_encoding, &c.metadata)?;
                self.channels.insert(c.id, id);
            }
            Record::Message { mut header, data } => {
                if let Some(&id) = self.channels.get(&header.channel_id) {
                    header.channel_id = id;
                    self.writer.write_to_known_channel(&header, &data)?;
                    self.report.messages += 1;
                }
            }
            Record::Metadata(m) => {
                self.writer.write_metadata(&m)?;
                self.report.metadata += 1;
            }
            Record::Attachment { header, data, .. } => {
                self.writer.attach(&mcap::Attachment {
                    log_time: header.log_time,
                    create_time: header.create_time,
                    name: header.name,
                    media_type: header.media_type,
                    data,
                })?;
                self.report.attachments += 1;
            }
            _ => {}
        }
        Ok(())
    }
}
