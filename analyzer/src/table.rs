//! The human-readable table of a report (`chaoscope analyze` without `--json`), as text: one
//! line for the run, one per scheme, then each scheme's verdict, its other indicators (every
//! output of the indicator interface, by name) and its warnings. A value that is absent (no set
//! has reached a renormalization yet, a GALI order the scheme lacks) is `-`, an indicator this
//! run cannot give is `n/a`; never `NaN`.

use std::fmt::Write as _;

use chaoscope_indicators::Named;

use crate::report::Report;

/// `v` in `format`'s style, right-aligned in `width`; `-` when absent or not finite.
fn cell(v: Option<f64>, width: usize, format: impl Fn(f64) -> String) -> String {
    let text = v.filter(|v| v.is_finite()).map_or("-".to_string(), format);
    format!("{text:>width$}")
}

/// A time for reading: at most 10 significant digits, trailing zeros dropped, so a time on the
/// grid `n * tau` reads as written (`11439.3`, not the sum's `11439.300000000001`); the JSON
/// keeps every bit.
fn time(t: f64) -> String {
    if !t.is_finite() {
        return "-".to_string();
    }
    if t != 0.0 && !(1e-4..1e10).contains(&t.abs()) {
        return format!("{t:e}");
    }
    let integer_digits = (t.abs().log10().floor() as i32 + 1).max(1);
    let decimals = (10 - integer_digits).max(0) as usize;
    let text = format!("{t:.decimals$}");
    if text.contains('.') {
        text.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        text
    }
}

/// The report as the table `chaoscope analyze` prints.
pub fn table(report: &Report) -> String {
    let mut out = String::new();
    let r = &report.run;
    let size = if r.kind == "hamiltonian" {
        format!("N = {}", r.n)
    } else {
        format!("{}, D = {}", r.kind, r.dim)
    };
    // What applies: the energy error of a Hamiltonian, the contraction rate of anything else.
    let conserved = match (r.energy_error_max, r.mean_divergence) {
        (Some(e), _) => {
            let norm = r
                .norm_error_max
                .map(|s| {
                    format!(
                        ", max norm error {}",
                        cell(Some(s), 0, |s| format!("{s:.2e}"))
                    )
                })
                .unwrap_or_default();
            // A relative error of an energy that starts near zero is no measure: said against
            // the norm beside it.
            let of_norm = r
                .energy_error_of_norm
                .map(|f| format!(" (E0 = {:.1e} near 0: {f:.2e} of the norm)", r.energy0))
                .unwrap_or_default();
            format!(
                "max energy error {}{of_norm}{norm}",
                cell(Some(e), 0, |e| format!("{e:.2e}"))
            )
        }
        (None, Some(d)) => format!(
            "mean divergence {}",
            cell(Some(d), 0, |d| format!("{d:.6}"))
        ),
        (None, None) => String::new(),
    };
    let _ = writeln!(
        out,
        "run {} ({}, {size}, {} with h = {}): t = {} of {}, {} samples, k = {}, {} sets, \
         {conserved}{}",
        r.name,
        r.model,
        r.integrator,
        r.h,
        time(r.t),
        time(r.t_final),
        r.samples,
        r.k,
        r.sets,
        if r.complete {
            ""
        } else {
            " (INCOMPLETE: frames missing)"
        }
    );
    if let Some(from) = r.exponents_from {
        let _ = writeln!(
            out,
            "exponents (MLE, l_i) averaged from t = {from} on (--from); everything else over the whole run"
        );
    }
    if let Some(end) = r.end.as_ref().filter(|e| e.status != "completed") {
        let _ = writeln!(
            out,
            "the run did not complete ({}): {}",
            end.status, end.reason
        );
    }
    let k = r.k;
    let mut head = format!(
        "{:<22} {:>4} {:>8} {:>7} {:>5} {:>9}",
        "scheme", "meth", "d0", "tau", "sets", "t"
    );
    for j in 2..=k {
        head += &format!(" {:>9}", format!("lgGALI{j}"));
    }
    head += &format!(" {:>9} {:>10}  {}", "lgSALI", "MLE", "MPM-VM |dlg GALI_j|");
    let _ = writeln!(out, "{head}");
    for s in &report.schemes {
        let mut line = format!(
            "{:<22} {:>4} {} {:>7} {:>5} {:>9}",
            s.name,
            s.method,
            cell(Some(s.d0), 8, |v| format!("{v:.0e}")),
            s.tau,
            s.sets,
            time(s.t)
        );
        for j in 2..=k {
            // A QR scheme's vectors are re-orthonormalized at every renormalization: its GALI
            // is 1 by construction and says nothing about the orbit, so it is not printed.
            let gali = s
                .gali
                .get(j)
                .map(|g| g.log10_mean)
                .filter(|_| s.orthonormalize != "qr");
            line += &format!(" {}", cell(gali, 9, |v| format!("{v:.3}")));
        }
        line += &format!(
            " {} {}",
            // Nor its SALI (sqrt 2 for orthonormal vectors).
            cell(
                s.sali
                    .map(|v| v.log10_mean)
                    .filter(|_| s.orthonormalize != "qr"),
                9,
                |v| format!("{v:.3}")
            ),
            cell(Some(s.mle), 10, |v| format!("{v:.6}"))
        );
        if let Some(v) = s.vs_vm.as_ref().filter(|v| !v.gali.0.is_empty()) {
            let d: Vec<String> = v
                .gali
                .0
                .iter()
                .map(|(_, d)| cell(Some(d.mean_abs_delta_log10), 0, |v| format!("{v:.1e}")))
                .collect();
            line += &format!("  vs {}: {}", v.scheme, d.join(" "));
        }
        if s.lyapunov.len() > 1 {
            let l: Vec<String> = s
                .lyapunov
                .iter()
                .map(|&l| cell(Some(l), 0, |v| format!("{v:.6}")))
                .collect();
            line += &format!("  spectrum: {}", l.join(" "));
        }
        if let Some(sum) = s.lyapunov_sum {
            line += &format!(" (sum {})", cell(Some(sum), 0, |v| format!("{v:.6}")));
        }
        let _ = writeln!(out, "{line}");
    }
    for s in &report.schemes {
        let v = &s.verdict;
        let class = match (v.torus_dimension, v.time) {
            (Some(d), _) => format!("{} (on a {d}-torus)", v.class.word()),
            (None, Some(t)) => format!("{} (t = {t})", v.class.word()),
            (None, None) => v.class.word().to_string(),
        };
        let _ = writeln!(
            out,
            "{}: {class}, confidence {}: {}",
            s.name,
            cell(Some(v.confidence), 0, |v| format!("{v:.2}")),
            v.criterion
        );
        // Every registered indicator under its own name: the table needs no change for a new one.
        let named: Vec<String> = s
            .indicators
            .0
            .iter()
            .map(|(name, value)| {
                let v = match value {
                    Named::OverSets(stat) => cell(Some(stat.mean), 0, |v| format!("{v:.4}")),
                    Named::Value(v) => cell(Some(*v), 0, |v| format!("{v:.4}")),
                    Named::Unavailable(_) => "n/a".to_string(),
                };
                format!("{name} {v}")
            })
            .collect();
        if !named.is_empty() {
            let _ = writeln!(out, "{}: {}", s.name, named.join(", "));
        }
        // A 0-1 test without a value says why: most often a series too short to mean
        // something, with the length it would need.
        if let Some(Named::Unavailable(why)) = s.indicators.get("zero_one_k") {
            let _ = writeln!(out, "{}: zero_one_k n/a: {why}", s.name);
        }
        for w in &s.warnings {
            let _ = writeln!(out, "{}: warning {}: {}", s.name, w.code, w.message);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::time;

    #[test]
    fn times_read_as_written_without_the_sums_last_bits() {
        assert_eq!(time(11439.300000000001), "11439.3");
        assert_eq!(time(0.1 + 0.2), "0.3");
        assert_eq!(time(200.0), "200");
        assert_eq!(time(0.0), "0");
        assert_eq!(time(-2.5), "-2.5");
        // Ten significant digits survive: a time that differs in them is not rounded away.
        assert_eq!(time(1234.567891), "1234.567891");
        assert_eq!(time(1e12), "1e12");
        assert_eq!(time(3e-7), "3e-7");
        assert_eq!(time(f64::NAN), "-");
    }
}
