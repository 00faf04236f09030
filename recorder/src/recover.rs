//! Salvaging an MCAP file whose writer died (`kill -9`, power loss): every record up to the
//! first damaged one is copied into a new, properly indexed and summarized file.

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use chaoscope_schemas::names::metadata;
use mcap::read::{ChunkReader, LinearReader, Options};
use mcap::records::{Metadata, Record};

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
    #[error("{path} already exists (pass --force to replace it)")]
    Exists { path: PathBuf },
    #[error("{path}: MCAP: {source}")]
    Mcap {
        path: PathBuf,
        source: mcap::McapError,
    },
}

/// Copies the readable records of `input` into a new file at `output`.
pub fn recover(input: &Path, output: &Path, force: bool) -> Result<RecoverReport, RecoverError> {
    let bytes = std::fs::read(input).map_err(|source| RecoverError::Io {
        path: input.into(),
        source,
    })?;
    if !bytes.starts_with(mcap::MAGIC) {
        return Err(RecoverError::NotMcap { path: input.into() });
    }
    if output.exists() && !force {
        return Err(RecoverError::Exists {
            path: output.into(),
        });
    }
    let out = File::create(output).map_err(|source| RecoverError::Io {
        path: output.into(),
        source,
    })?;
    let mcap_err = |source| RecoverError::Mcap {
        path: output.into(),
        source,
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
    let records =
        LinearReader::new_with_options(&bytes, Options::IgnoreEndMagic.into()).map_err(mcap_err)?;
    for (index, record) in records.enumerate() {
        let result = record.and_then(|r| copier.copy(r));
        if let Err(e) = result {
            copier.report.stopped_at = Some(format!("record {index}: {e}"));
            break;
        }
    }
    let report = copier.report;
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
            Record::Chunk { header, data } => {
                // Decompress and validate the whole chunk before copying any of it, so a damaged
                // chunk is dropped whole rather than half copied.
                let records =
                    ChunkReader::new(header, &data)?.collect::<mcap::McapResult<Vec<_>>>()?;
                for r in records {
                    self.copy(r)?;
                }
                self.report.chunks += 1;
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
            // Indexes, statistics and the summary are rebuilt by the writer.
            _ => {}
        }
        Ok(())
    }
}
