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

/// Where a configuration was read from and its text: what places the key a validation error
/// names in the file, as a TOML error is placed.
#[derive(Debug, Clone)]
pub struct ConfigSource {
    /// The file's name as the user gave it (or `stdin`).
    pub name: String,
    pub text: String,
}

impl ConfigSource {
    /// `in NAME: invalid run configuration: KEY (line L, column C): MESSAGE`, as a TOML error
    /// of the same file reads (`what` is `run` or `map`); without the position where the key is
    /// not written in the file.
    pub fn describe(&self, what: &str, key: &str, message: &str) -> String {
        format!(
            "in {}: invalid {what} configuration: {}",
            self.name,
            super::locate::describe_key(&self.text, key, message)
        )
    }
}

/// Parses configuration bytes read from `name`; relative table paths are taken from `path`'s
/// directory (see [`RunConfig::from_file_text`]).
pub fn parse_config_bytes(
    name: &str,
    bytes: Vec<u8>,
    path: &Path,
) -> Result<RunConfig, ConfigLoadError> {
    parse_config_source(name, bytes, path).map(|(config, _)| config)
}

/// [`parse_config_bytes`], keeping the text (see [`ConfigSource`]).
pub fn parse_config_source(
    name: &str,
    bytes: Vec<u8>,
    path: &Path,
) -> Result<(RunConfig, ConfigSource), ConfigLoadError> {
    if bytes.len() as u64 > MAX_CONFIG_BYTES {
        return Err(ConfigLoadError::TooLarge {
            name: name.to_string(),
        });
    }
    let text = String::from_utf8(bytes).map_err(|e| ConfigLoadError::NotText {
        name: name.to_string(),
        at: e.utf8_error().valid_up_to(),
    })?;
    let config =
        RunConfig::from_file_text(&text, path).map_err(|error| ConfigLoadError::Parse {
            name: name.to_string(),
            error,
        })?;
    let source = ConfigSource {
        name: name.to_string(),
        text,
    };
    Ok((config, source))
}

/// Reads and parses the configuration file at `path`.
pub fn read_config_file(path: &Path) -> Result<RunConfig, ConfigLoadError> {
    read_config_source(path).map(|(config, _)| config)
}

/// [`read_config_file`], keeping the text (see [`ConfigSource`]).
pub fn read_config_source(path: &Path) -> Result<(RunConfig, ConfigSource), ConfigLoadError> {
    let read_error = |error| ConfigLoadError::Read {
        path: path.display().to_string(),
        error,
    };
    let file = chaoscope_os::open_regular(path).map_err(read_error)?;
    let bytes = read_bounded(file).map_err(read_error)?;
    parse_config_source(&path.display().to_string(), bytes, path)
}
