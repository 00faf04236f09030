//! `chaoscope._chaoscope`: the Python module, a thin layer over the workspace crates. Every
//! number comes from the same library functions the `chaoscope` command calls (the engine, the
//! recorder's file layout, the analysis core, replay, the map scheduler, the live reader); this
//! crate only converts arguments and results and keeps Python responsive: long calls run on a
//! worker thread with the GIL released while the calling thread watches for Ctrl-C
//! ([`interrupt`]).

mod clv;
mod config;
mod interrupt;
mod map;
mod monitor;
mod recording;
mod signals;

use pyo3::prelude::*;

pyo3::create_exception!(
    _chaoscope,
    ChaoscopeError,
    pyo3::exceptions::PyException,
    "An error reported by chaoscope, with the same one-line message as the `chaoscope` command."
);

/// A Python exception carrying `error` and its sources joined by ": ", as the command prints it.
pub(crate) fn error(e: &(dyn std::error::Error + 'static)) -> PyErr {
    ChaoscopeError::new_err(chaoscope_files::file::error_chain(e))
}

/// A Python exception with a message.
pub(crate) fn message(text: impl Into<String>) -> PyErr {
    ChaoscopeError::new_err(text.into())
}

/// A message of the command's crates in this package's words: the command's flags, where they
/// stand as words (never inside a path), as the keyword arguments that set them.
pub(crate) fn keyword_arguments(text: &str) -> String {
    const FLAGS: [(&str, &str); 3] = [
        ("--t-final", "t_final"),
        ("--force", "force=True"),
        ("--out", "out="),
    ];
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    'scan: while !rest.is_empty() {
        let at_word_start = out
            .chars()
            .next_back()
            .is_none_or(|c| c.is_whitespace() || "(`'\"".contains(c));
        if at_word_start {
            for (flag, keyword) in FLAGS {
                let Some(after) = rest.strip_prefix(flag) else {
                    continue;
                };
                if after
                    .chars()
                    .next()
                    .is_some_and(|c| c.is_alphanumeric() || c == '-' || c == '_' || c == '/')
                {
                    continue;
                }
                out.push_str(keyword);
                rest = after;
                // `--t-final 1e12` -> `t_final=1e12`.
                if flag == "--t-final"
                    && let Some(value) = rest.strip_prefix(' ')
                    && value
                        .chars()
                        .next()
                        .is_some_and(|c| c.is_ascii_digit() || "+-.Ni".contains(c))
                {
                    out.push('=');
                    rest = value;
                }
                continue 'scan;
            }
        }
        let c = rest.chars().next().expect("not empty");
        out.push(c);
        rest = &rest[c.len_utf8()..];
    }
    out
}

/// An existing regular file at `path` (not a link, device or directory: those get the output
/// layer's own words), which an output refuses to replace without `force=True`.
pub(crate) fn is_regular_file(path: &std::path::Path) -> bool {
    path.symlink_metadata()
        .is_ok_and(|m| m.file_type().is_file())
}

#[pymodule]
fn _chaoscope(m: &Bound<'_, PyModule>) -> PyResult<()> {
    signals::keep_python_handlers();
    // NumPy's C API is imported on the first array a call makes. Made here, at import, it
    // cannot be made while a KeyboardInterrupt is pending (a long call stopped by Ctrl-C
    // returning its first array), where the import fails and rust-numpy panics.
    // Importing NumPy first turns its absence into this import's ImportError, not a panic.
    numpy::get_array_module(m.py())?;
    numpy::PyArray1::<f64>::zeros(m.py(), 0, false);
    m.add("ChaoscopeError", m.py().get_type::<ChaoscopeError>())?;
    m.add_class::<recording::Recording>()?;
    m.add_class::<recording::Indicators>()?;
    m.add_class::<recording::Orbit>()?;
    m.add_class::<clv::Clv>()?;
    m.add_class::<map::Map>()?;
    m.add_class::<monitor::Monitor>()?;
    m.add_class::<monitor::LiveSample>()?;
    m.add_function(wrap_pyfunction!(recording::run, m)?)?;
    m.add_function(wrap_pyfunction!(recording::open, m)?)?;
    m.add_function(wrap_pyfunction!(recording::resume, m)?)?;
    m.add_function(wrap_pyfunction!(map::map, m)?)?;
    m.add_function(wrap_pyfunction!(map::open_map, m)?)?;
    m.add_function(wrap_pyfunction!(monitor::monitor, m)?)?;
    Ok(())
}
