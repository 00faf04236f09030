//! What a chaoscope process asks of the operating system, decided once for every command and
//! the Python package:
//!
//! - [`cpu_time`]: CPU time of this thread, this process and its waited-for children.
//! - [`input`]: the one way a file a user names is opened for reading: a regular file, never a
//!   FIFO, device, socket or directory, and never a wait to find out.
//! - [`output`]: the one way a file is written (a locked in-progress file beside the target,
//!   created exclusively and never through a link, renamed into place only when complete; a
//!   second writer of the same file refused; inputs never overwritten; nothing unlinked that
//!   is not ours).
//! - [`signals`]: SIGINT/SIGTERM latched once, so no library can swallow them, with the exit
//!   status each means (130, 143); commands that have nothing to finalize end at once instead,
//!   removing their unfinished outputs.
//! - [`termination`]: a stop flag shared by a command's loops: a latched signal, or a request
//!   of the caller (Python's Ctrl-C).
//! - [`stdout`]: standard output written with its errors seen: a closed pipe ends a command
//!   quietly, a full disk is an error.
//!
//! No numerics, no file format, no bus: every other crate may depend on this one.

pub mod cpu_time;
pub(crate) mod input;
pub mod output;
pub mod signals;
pub mod stdout;
pub mod termination;

pub use input::{NotRegularFile, open_regular, read_regular};
pub use output::{Leftover, Output, OutputError, OutputOptions};
