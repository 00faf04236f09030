//! Periodic coordinates (angles): the one definition of a coordinate's wrap into `[0, P)`,
//! shared by the producer (a map's iteration wraps its angles), the analysis (the extent of
//! the reference orbit and the orbit indicators read the wrapped state of a flow, whose
//! integration never wraps it) and the sections (their points and plots).
//!
//! `periods` has one entry per coordinate of the state: a finite period `P > 0`, or `0` for a
//! coordinate that is not wrapped; an empty `periods` wraps nothing.

/// `x` into `[0, p)`: the remainder, shifted up by `p` when negative. A tiny negative `x` gives
/// `r + p == p` in floating point; that is `0` on the circle. A non-finite `x` stays non-finite.
#[inline]
pub fn wrap_coordinate(x: f64, p: f64) -> f64 {
    let mut r = x % p;
    if r < 0.0 {
        r += p;
    }
    if r >= p { r - p } else { r }
}

/// Every coordinate of `x` with a period `periods[i] > 0` into `[0, P)`, in place.
#[inline]
pub fn wrap(periods: &[f64], x: &mut [f64]) {
    for (xi, &p) in x.iter_mut().zip(periods) {
        if p > 0.0 {
            *xi = wrap_coordinate(*xi, p);
        }
    }
}

/// `x` with its periodic coordinates wrapped (a copy; `x` as it is when nothing wraps).
pub fn wrap_state(periods: &[f64], x: &[f64]) -> Vec<f64> {
    let mut out = x.to_vec();
    wrap(periods, &mut out);
    out
}

/// Whether any coordinate has a period.
pub fn any_periodic(periods: &[f64]) -> bool {
    periods.iter().any(|&p| p > 0.0)
}

/// Checks periods declared for a state of dimension `dim`: one entry per coordinate, each a
/// finite period `> 0` or `0` for none (an empty list declares none). The problem in one line,
/// without the key (the caller names it).
pub fn check_periods(periods: &[f64], dim: usize) -> Result<(), String> {
    if periods.is_empty() {
        return Ok(());
    }
    if periods.len() != dim {
        return Err(format!(
            "has {} entries but the state has dimension {dim} (one period per coordinate, 0 \
             for a coordinate that is not periodic)",
            periods.len()
        ));
    }
    if let Some(i) = periods.iter().position(|p| !(p.is_finite() && *p >= 0.0)) {
        return Err(format!(
            "entry {} must be a period > 0 or 0 for none, got {}",
            i + 1,
            periods[i]
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wraps_into_one_period() {
        let tau = std::f64::consts::TAU;
        // -250 rad is 40 turns and 1.327... below a multiple: its remainder shifted by 2 pi.
        let w = wrap_coordinate(-250.0, tau);
        assert!((0.0..tau).contains(&w));
        assert!(((w - -250.0) / tau - ((w - -250.0) / tau).round()).abs() < 1e-12);
        assert_eq!(wrap_coordinate(-1e-300, 1.0), 0.0);
        assert_eq!(wrap_state(&[tau, 0.0], &[7.0, -3.0]), vec![7.0 - tau, -3.0]);
        assert_eq!(wrap_state(&[], &[7.0, -3.0]), vec![7.0, -3.0]);
        assert!(wrap_coordinate(f64::NAN, tau).is_nan());
    }

    #[test]
    fn bad_periods_are_refused() {
        assert!(check_periods(&[], 3).is_ok());
        assert!(check_periods(&[1.0, 0.0], 2).is_ok());
        assert!(
            check_periods(&[1.0], 2)
                .unwrap_err()
                .contains("dimension 2")
        );
        assert!(
            check_periods(&[1.0, -1.0], 2)
                .unwrap_err()
                .contains("entry 2")
        );
        assert!(check_periods(&[f64::INFINITY, 0.0], 2).is_err());
    }
}
