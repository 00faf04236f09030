//! Standard output with its errors seen.
//!
//! `println!` panics when a write fails (exit status 101 on `| head` or `> /dev/full`), and
//! `let _ = writeln!(..)` hides a full disk (exit 0 with nothing written). Every line a command
//! prints goes through [`line`] instead: a reader that went away ([`StdoutError::Closed`]: the
//! command stops printing and ends quietly with [`CLOSED_STATUS`], as a filter killed by
//! SIGPIPE would) is told apart from a failed write ([`StdoutError::Failed`]: one line naming
//! standard output and the cause, non-zero exit). Messages to standard error go through
//! [`errln!`], which never panics.

use std::io::Write;

/// Exit status of a command whose standard output was closed by its reader: 128 + SIGPIPE,
/// what a shell reports for `cat` in `cat big | head`.
pub const CLOSED_STATUS: u8 = 141;

#[derive(Debug, thiserror::Error)]
pub enum StdoutError {
    /// The reader went away (EPIPE): not worth a message.
    #[error("standard output was closed by its reader")]
    Closed,
    #[error("writing to standard output: {0}")]
    Failed(std::io::Error),
}

impl From<std::io::Error> for StdoutError {
    fn from(e: std::io::Error) -> Self {
        if e.kind() == std::io::ErrorKind::BrokenPipe {
            Self::Closed
        } else {
            Self::Failed(e)
        }
    }
}

/// Writes `args` and a newline to standard output and flushes it, so a failure shows here and
/// not at exit, where nobody sees it.
pub fn line(args: std::fmt::Arguments<'_>) -> Result<(), StdoutError> {
    let mut out = std::io::stdout().lock();
    out.write_fmt(args)?;
    out.write_all(b"\n")?;
    out.flush()?;
    Ok(())
}

/// Writes `text` as it is (no newline added) and flushes.
pub fn text(text: &str) -> Result<(), StdoutError> {
    let mut out = std::io::stdout().lock();
    out.write_all(text.as_bytes())?;
    out.flush()?;
    Ok(())
}

/// Flushes standard output (what `print!` left buffered).
pub fn flush() -> Result<(), StdoutError> {
    std::io::stdout().lock().flush()?;
    Ok(())
}

/// Writes `args` and a newline to standard error, ignoring a failure: a message that cannot be
/// shown (stderr closed or on a full disk) is lost, and the exit status still says what
/// happened. (`eprintln!` panics instead.)
pub fn error_line(args: std::fmt::Arguments<'_>) {
    let mut err = std::io::stderr().lock();
    let _ = err.write_fmt(args);
    let _ = err.write_all(b"\n");
}

/// `errln!("...", args)`: [`error_line`] with `format!` arguments.
#[macro_export]
macro_rules! errln {
    ($($arg:tt)*) => {
        $crate::stdout::error_line(format_args!($($arg)*))
    };
}

/// `outln!("...", args)`: [`line`] with `format!` arguments; evaluates to its `Result`.
#[macro_export]
macro_rules! outln {
    ($($arg:tt)*) => {
        $crate::stdout::line(format_args!($($arg)*))
    };
}
