//! Reading a run configuration from a file (or bytes from another source) with the checks every
//! front end applies: a size bound, UTF-8, then the TOML parse with its one-line message.

use std::io::Read;
use std::path::Path;

use super::{ConfigParseError, RunConfig};

/// Largest configuration read: far above any real config (a 10000-scheme config is about
/// 1 MiB), far below what would strain memory when a wrong file is given by mistake.
pub const MAX_CONFIG_BYTES: u64 = 16 << 20;

/// Why a configuration could not be loaded. The messages are complete (no error source), so an
/// error chain printer does not repeat them.
#[derive(Debug, thiserror::Error)]
pub enum ConfigLoadError {
    #[error("reading run configuration {path}: {error}")]
    Read { path: String, error: std::io::Error },
    #[error(
        "{name}: larger than {} MiB, which no run configuration is (is it the right file?)",
        MAX_CONFIG_BYTES >> 20
    )]
    TooLarge { name: String },
    #[error("{name}: not a text file (invalid UTF-8 at byte {at}); a run configuration is TOML")]
    NotText { name: String, at: usize },
    #[error("in {name}: {error}")]
    Parse {
        name: String,
        error: ConfigParseError,
    },
}

/// Reads at most `MAX_CONFIG_BYTES + 1` bytes of `source` (one more than allowed, so that
/// [`parse_config_bytes`] can tell a file that is too large).
pub fn read_bounded(mut source: impl Read) -> std::io::Result<Vec<u8>> {
    let mut bytes = Vec::new();
    source
        .by_ref()
        .take(MAX_CONFIG_BYTES + 1)
        .read_to_end(&mut bytes)?;
    Ok(bytes)
}

/// Parses configuration bytes read from `name`; relative table paths are taken from `path`'s
/// directory (see [`RunConfig::from_file_text`]).
pub fn parse_config_bytes(
    name: &str,
    bytes: Vec<u8>,
    path: &Path,
) -> Result<RunConfig, ConfigLoadError> {
    if bytes.len() as u64 > MAX_CONFIG_BYTES {
        return Err(ConfigLoadError::TooLarge {
            name: name.to_string(),
        });
    }
    let text = String::from_utf8(bytes).map_err(|e| ConfigLoadError::NotText {
        name: name.to_string(),
        at: e.utf8_error().valid_up_to(),
    })?;
    RunConfig::from_file_text(&text, path).map_err(|error| ConfigLoadError::Parse {
        name: name.to_string(),
        error,
    })
}

/// Reads and parses the configuration file at `path`.
pub fn read_config_file(path: &Path) -> Result<RunConfig, ConfigLoadError> {
    let read_error = |error| ConfigLoadError::Read {
        path: path.display().to_string(),
        error,
    };
    let file = std::fs::File::open(path).map_err(read_error)?;
    let bytes = read_bounded(file).map_err(read_error)?;
    parse_config_bytes(&path.display().to_string(), bytes, path)
}
