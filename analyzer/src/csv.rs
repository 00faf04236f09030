//! The stored curves as CSV, one file per scheme plus the energy error (for other tools).
//!
//! Finite-time exponents: `lyapunov1..k` (kept for existing readers) are the mean over sets
//! of each vector's `(1/t) sum ln stretch`, whatever the scheme. Only a QR scheme's are the
//! Lyapunov spectrum; a rescale scheme's are per-vector growth rates, each an estimate of the
//! MLE. So the same values are written again under their name: `spectrum1..k` for a QR scheme,
//! `growth_rate1..k` for a rescale scheme (the other set of columns is empty). With a discarded
//! transient (`analyze --from T`) all of these are averaged from T on.
//!
//! Then one column per output of every registered set indicator, under its report name (`fli`,
//! `ofli`, `megno`, `megno_mean`, ...: `set_output_names()`), the mean over the sets, empty where
//! the run cannot give it (OFLI without the system's vector field). A new indicator adds its
//! columns here without a change to this file. The 0-1 test is one value of the whole sampled
//! orbit, not a time series: it is in `--json` and the table.

use std::io::Write;
use std::path::{Path, PathBuf};

use chaoscope_schemas::run::Orthonormalization;

use crate::analysis::Analysis;

/// Writes `<dir>/<scheme>.csv` and, for Hamiltonians, `<dir>/energy.csv` (each complete or not
/// at all, replacing an earlier table of the same name, never one of `inputs`:
/// `chaoscope_os::output`); returns the files written.
pub fn write_csv(
    analysis: &Analysis,
    dir: &Path,
    inputs: &[PathBuf],
) -> std::io::Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir)?;
    let options = table_options(inputs);
    let create = |path: &Path| chaoscope_os::Output::create(path, &options).map_err(io);
    let run = analysis.run();
    let k = run.k;
    let mut files = Vec::new();
    for (si, s) in run.schemes.iter().enumerate() {
        let path = dir.join(format!("{}.csv", s.name));
        let output = create(&path)?;
        let mut f = std::io::BufWriter::new(output.file().map_err(io)?);
        let mut head = vec!["t".to_string()];
        for j in 2..=k {
            head.push(format!("gali{j}_log10_mean"));
        }
        for j in 2..=k {
            head.push(format!("gali{j}_log10_of_mean"));
        }
        head.push("sali_log10_mean".into());
        for i in 1..=k {
            head.push(format!("lyapunov{i}"));
        }
        for j in 2..=k {
            head.push(format!("gali{j}_vs_vm_mean_abs_delta_log10"));
        }
        let qr = s.orthonormalize == Orthonormalization::Qr;
        for i in 1..=k {
            head.push(format!("spectrum{i}"));
        }
        for i in 1..=k {
            head.push(format!("growth_rate{i}"));
        }
        let named = chaoscope_indicators::indicator::set_output_names();
        head.extend(named.iter().map(|n| n.to_string()));
        writeln!(f, "{}", head.join(","))?;
        for (t, p) in analysis.series(si) {
            let mut row = vec![cell(t)];
            row.extend(p.gali_log10_mean.iter().copied().map(cell));
            row.extend(p.gali_log10_of_mean.iter().copied().map(cell));
            row.push(p.sali_log10_mean.map_or(String::new(), cell));
            row.extend(p.exponents().iter().copied().map(cell));
            match &p.vs_vm_abs_delta {
                Some(d) => row.extend(d.iter().copied().map(cell)),
                None => row.extend((2..=k).map(|_| String::new())),
            }
            let rates =
                || (0..k).map(|i| p.exponents().get(i).copied().map_or(String::new(), cell));
            let empty = || (0..k).map(|_| String::new());
            if qr {
                row.extend(rates());
                row.extend(empty());
            } else {
                row.extend(empty());
                row.extend(rates());
            }
            row.extend((0..named.len()).map(|i| {
                p.named
                    .get(i)
                    .copied()
                    .flatten()
                    .filter(|v| v.is_finite())
                    .map_or(String::new(), cell)
            }));
            writeln!(f, "{}", row.join(","))?;
        }
        f.flush()?;
        drop(f);
        files.push(output.commit().map_err(io)?);
    }
    if analysis.run().kind != chaoscope_schemas::run::SystemClass::Hamiltonian {
        // No energy to follow.
        return Ok(files);
    }
    let path = dir.join("energy.csv");
    let output = create(&path)?;
    let mut f = std::io::BufWriter::new(output.file().map_err(io)?);
    writeln!(f, "t,relative_energy_error")?;
    for (t, e) in analysis.energy_series() {
        writeln!(f, "{},{}", cell(t), cell(e))?;
    }
    f.flush()?;
    drop(f);
    files.push(output.commit().map_err(io)?);
    Ok(files)
}

/// A CSV cell: the shortest digits that read back as exactly `v`, plain between 1e-5 and 1e16
/// (`0.25`, `3000`: at most 5 leading zeros) and in scientific notation outside
/// (`1e-300`, `-4.8e-17`, not hundreds of digits).
pub fn cell(v: f64) -> String {
    if v == 0.0 || !v.is_finite() || (1e-5..1e16).contains(&v.abs()) {
        v.to_string()
    } else {
        format!("{v:e}")
    }
}

/// How a table for other tools is written: it replaces an earlier table of the same name, is
/// never one of `inputs`, and an unfinished one is removed (it is computed again).
pub(crate) fn table_options(inputs: &[PathBuf]) -> chaoscope_os::OutputOptions {
    chaoscope_os::OutputOptions {
        replace: true,
        inputs: inputs.to_vec(),
        leftover: chaoscope_os::Leftover::Discard,
        ..Default::default()
    }
}

/// An output refused or failed, as the I/O error this module returns (its message names the
/// file and the cause).
pub(crate) fn io(e: chaoscope_os::OutputError) -> std::io::Error {
    std::io::Error::other(e.to_string())
}

#[cfg(test)]
mod tests {
    use super::cell;

    #[test]
    fn cells_are_short_and_exact() {
        for (v, text) in [
            (1e-300, "1e-300"),
            (-4.8e-17, "-4.8e-17"),
            (0.25, "0.25"),
            (3000.0, "3000"),
            (-0.0, "-0"),
            (1.5e300, "1.5e300"),
            (0.001, "0.001"),
        ] {
            assert_eq!(cell(v), text);
        }
        // Every cell reads back as the value it was written from.
        for v in [
            std::f64::consts::PI * 1e-20,
            -2.0f64.sqrt() * 1e15,
            f64::MIN_POSITIVE,
        ] {
            assert_eq!(cell(v).parse::<f64>().unwrap(), v);
        }
    }
}
