//! `plane-t<T>.png` of `analyze --plot` for runs on a square lattice: the norm (or energy)
//! distribution and the deviation vector distribution over the plane at one time, side by side,
//! as the 2-D papers draw them (Many Manda, Senyange and Skokos, PRE 101, 032206 (2020)): column
//! `j` across, row `i` up, `log10` of the weight in colour (viridis, one scale for both, six
//! decades below the largest weight, as `distributions.png`). Where chaos lives in the packet
//! shows as the DVD's bright cells inside the norm's.

use std::path::{Path, PathBuf};

use plotters::prelude::*;

use crate::analysis::Analysis;
use crate::map_png::{FONT, colour, font_available};
use crate::site_png::two_panels_and_bar;
use crate::site_profiles::SiteProfile;

/// Decades of weight the colour scale spans below the largest weight.
const DECADES: f64 = 6.0;

/// Most cells a panel draws per side: a larger lattice is drawn in blocks of `b x b` sites
/// (their weights summed, said in the title), a cell never narrower than a pixel or two.
const MAX_CELLS: usize = 200;

/// A picture over the plane to draw: the time asked, the time of the renormalization drawn
/// (the latest at or before it) and its distributions.
pub struct Plane<'a> {
    pub asked: f64,
    pub t: f64,
    pub profile: &'a SiteProfile,
}

/// The pictures over the plane `analysis` can draw, and one line per time asked that it
/// cannot (after the recording's last sample, or before its first renormalization of the first
/// set), for the caller to say.
pub fn planes(analysis: &Analysis) -> (Vec<Plane<'_>>, Vec<String>) {
    let Some(profiles) = analysis.site_profiles() else {
        return (Vec::new(), Vec::new());
    };
    let end = analysis.t();
    let (mut drawn, mut skipped) = (Vec::new(), Vec::new());
    for plane in profiles.planes() {
        let asked = plane.asked;
        match &plane.taken {
            _ if asked > end + 1e-9 * end.abs().max(1.0) => skipped.push(format!(
                "plane at t = {asked} skipped: the recording ends at t = {end}"
            )),
            None => skipped.push(format!(
                "plane at t = {asked} skipped: no renormalization of the first set at or before it"
            )),
            Some((t, profile)) => drawn.push(Plane {
                asked,
                t: *t,
                profile,
            }),
        }
    }
    (drawn, skipped)
}

/// The file a picture of time `asked` goes to in `dir`.
pub fn plane_path(dir: &Path, asked: f64) -> PathBuf {
    dir.join(format!("plane-t{asked}.png"))
}

/// Draws `plane` of a `side x side` lattice to the PNG `path` (through `chaoscope_os::output`,
/// never one of `inputs`).
pub fn render_png(
    plane: &Plane<'_>,
    side: usize,
    path: &Path,
    inputs: &[PathBuf],
) -> Result<(), String> {
    let (pixels, size, _) =
        render_pixels(plane, side).map_err(|e| format!("{}: {e}", path.display()))?;
    crate::chart::save_png(path, inputs, &pixels, size)
        .map(drop)
        .map_err(|e| e.to_string())
}

/// `weights` of a `side x side` lattice summed over blocks of `b x b` sites: `cells x cells`
/// values, row by row.
fn blocks(weights: &[f64], side: usize, b: usize) -> (usize, Vec<f64>) {
    let cells = side.div_ceil(b);
    let mut out = vec![0.0; cells * cells];
    for (l, w) in weights.iter().enumerate() {
        let (i, j) = (l / side, l % side);
        out[(i / b) * cells + j / b] += w;
    }
    (cells, out)
}

/// The picture drawn in memory as RGB pixels of the returned size, with where it put the two
/// panels' plotting areas (the norm's or energy's, then the DVD's) and the colour bar's.
pub fn render_pixels(
    plane: &Plane<'_>,
    side: usize,
) -> Result<crate::chart::Drawn<[crate::chart::PixelRect; 3]>, String> {
    let p = plane.profile;
    if side == 0 || side.checked_mul(side) != Some(p.dvd.len()) {
        return Err(format!(
            "{} weights do not fill a {side} x {side} lattice",
            p.dvd.len()
        ));
    }
    let b = side.div_ceil(MAX_CELLS);
    let (carrier_name, carrier) = p.carrier();
    let (cells, dvd) = blocks(&p.dvd, side, b);
    let carrier = carrier.map(|w| blocks(w, side, b).1);
    let lg = |x: f64| {
        if x > 0.0 {
            x.log10()
        } else {
            f64::NEG_INFINITY
        }
    };
    let hi = dvd
        .iter()
        .chain(carrier.as_deref().unwrap_or(&[]))
        .copied()
        .fold(f64::NEG_INFINITY, f64::max);
    let hi = if hi > 0.0 { lg(hi).min(0.0) } else { 0.0 };
    let lo = hi - DECADES;
    let text = font_available();
    let (panel_w, panel_h, bar_w) = (
        420u32,
        if text { 470 } else { 420 },
        if text { 130 } else { 40 },
    );
    let err = |e: &dyn std::fmt::Display| e.to_string();
    let blocked = if b > 1 {
        format!(", {b} x {b} blocks")
    } else {
        String::new()
    };
    let range = 0.5..side as f64 + 0.5;
    two_panels_and_bar((panel_w, panel_h, bar_w), text, (lo, hi), |area, panel| {
        let (title, weights) = if panel == 0 {
            let title = match &carrier {
                Ok(_) => format!("{carrier_name}, t = {}{blocked}", plane.t),
                Err(why) => format!("{carrier_name}: {why}"),
            };
            (title, carrier.as_deref().ok())
        } else {
            (
                format!("deviation vector ξ_l, t = {}{blocked}", plane.t),
                Some(&dvd[..]),
            )
        };
        let mut builder = ChartBuilder::on(area);
        builder.margin(10);
        if text {
            builder
                .caption(title, (FONT, 15))
                .x_label_area_size(40)
                .y_label_area_size(50);
        }
        let mut chart = builder
            .build_cartesian_2d(range.clone(), range.clone())
            .map_err(|e| err(&e))?;
        let pixels = chart.plotting_area().get_pixel_range();
        if text {
            chart
                .configure_mesh()
                .disable_mesh()
                .x_desc("column j")
                .y_desc("row i")
                .x_labels(6)
                .y_labels(6)
                .x_label_formatter(&|v| format!("{v:.0}"))
                .y_label_formatter(&|v| format!("{v:.0}"))
                .label_style((FONT, 13))
                .draw()
                .map_err(|e| err(&e))?;
        }
        let Some(weights) = weights else {
            return Ok(pixels);
        };
        // Cell (ci, cj) covers sites ci b + 1 ..= (ci + 1) b of the rows (clipped).
        let edge = |c: usize| ((c * b) as f64 + 0.5, (((c + 1) * b).min(side)) as f64 + 0.5);
        chart
            .draw_series(weights.iter().enumerate().map(|(c, &x)| {
                let ((i0, i1), (j0, j1)) = (edge(c / cells), edge(c % cells));
                Rectangle::new(
                    [(j0, i0), (j1, i1)],
                    colour(lg(x).clamp(lo, hi), lo, hi).filled(),
                )
            }))
            .map_err(|e| err(&e))?;
        Ok(pixels)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A profile of a `side x side` lattice whose norm sits on one site and whose DVD decays
    /// away from another, spanning more decades than the colour scale.
    fn profile(side: usize) -> SiteProfile {
        let n = side * side;
        let dvd: Vec<f64> = (0..n)
            .map(|l| 10f64.powf(-(((l / side) as f64 - 3.0).abs() + (l % side) as f64)))
            .collect();
        let total: f64 = dvd.iter().sum();
        let mut norm = vec![0.0; n];
        norm[n / 2] = 1.0;
        SiteProfile {
            energy: Err("not a distribution".into()),
            norm: Some(norm),
            dvd: dvd.iter().map(|x| x / total).collect(),
        }
    }

    #[test]
    fn the_plane_stays_in_its_panels_and_a_large_one_is_blocked() {
        for side in [12, 450] {
            let p = profile(side);
            let plane = Plane {
                asked: 10.0,
                t: 9.5,
                profile: &p,
            };
            let (pixels, (w, _), areas) = render_pixels(&plane, side).unwrap();
            let out = crate::chart::stray_pixels(&pixels, w, &areas, crate::chart::coloured);
            assert!(out.is_empty(), "{side}: {} coloured pixels out", out.len());
            // The DVD's panel is coloured at its centre (a weight within the scale or clamped to
            // its bottom: viridis has no white).
            let (xs, ys) = &areas[1];
            let mid = ((ys.start + ys.end) / 2 * w as i32 + (xs.start + xs.end) / 2) as usize;
            assert!(crate::chart::coloured([
                pixels[3 * mid],
                pixels[3 * mid + 1],
                pixels[3 * mid + 2]
            ]));
        }
        // Weights that do not fill the square are an error, not a panic.
        let p = profile(5);
        let plane = Plane {
            asked: 1.0,
            t: 1.0,
            profile: &p,
        };
        assert!(render_pixels(&plane, 6).unwrap_err().contains("6 x 6"));
        assert!(render_pixels(&plane, 0).is_err());
    }

    #[test]
    fn blocks_keep_the_total_weight() {
        // 5 x 5 sites in 2 x 2 blocks: 3 x 3 cells, the last row and column half blocks.
        let w: Vec<f64> = (0..25).map(|l| l as f64).collect();
        let (cells, b) = blocks(&w, 5, 2);
        assert_eq!(cells, 3);
        assert_eq!(b.iter().sum::<f64>(), 300.0);
        // Cell (0, 0) holds sites (0,0), (0,1), (1,0), (1,1): 0 + 1 + 5 + 6; cell (2, 2) site 24.
        assert_eq!((b[0], b[8]), (12.0, 24.0));
    }
}
