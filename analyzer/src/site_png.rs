//! `distributions.png` of `analyze --plot` for runs over a lattice: the energy distribution and
//! the deviation vector distribution over the sites against time, side by side, as the DVD papers
//! draw them (Senyange, Many Manda and Skokos, PRE 98, 052229 (2018), Fig. 1): site `l`
//! across, time up, `log10` of the weight in colour (viridis, one scale for both, six decades
//! below the largest weight). Where chaos lives in the chain shows as the DVD's bright cells
//! sitting on the energy's.

use std::path::{Path, PathBuf};

use plotters::prelude::*;

use crate::map_png::{FONT, colour, font_available};
use crate::site_profiles::SiteProfiles;

/// Fewest sites a space-time picture of the distributions is drawn for: over two sites each
/// distribution is one number (the other site's weight is its complement), which says nothing
/// a curve would not; a two-degree-of-freedom system is no lattice.
pub const MIN_SITES: usize = 3;

/// Decades of weight the colour scale spans below the largest weight.
const DECADES: f64 = 6.0;

/// Draws `profiles` to the PNG `path` (through `chaoscope_os::output`, never one of `inputs`).
/// An error naming the file, or saying that there is nothing to draw (fewer than two times).
pub fn render_png(profiles: &SiteProfiles, path: &Path, inputs: &[PathBuf]) -> Result<(), String> {
    let (pixels, size, _) =
        render_pixels(profiles).map_err(|e| format!("{}: {e}", path.display()))?;
    crate::chart::save_png(path, inputs, &pixels, size)
        .map(drop)
        .map_err(|e| e.to_string())
}

/// The picture drawn in memory as RGB pixels of the returned size, with where it put the two
/// panels' plotting areas (the energy's in [`Layout::plot`], the deviation vector's in
/// [`Layout::legend`]) and the colour bar's.
///
/// [`Layout::plot`]: crate::chart::Layout
/// [`Layout::legend`]: crate::chart::Layout
pub fn render_pixels(
    profiles: &SiteProfiles,
) -> Result<crate::chart::Drawn<[crate::chart::PixelRect; 3]>, String> {
    let points = profiles.points();
    if points.len() < 2 {
        return Err("fewer than two renormalizations of the first set to draw".into());
    }
    let n = profiles.sites();
    let lg = |x: f64| {
        if x > 0.0 {
            x.log10()
        } else {
            f64::NEG_INFINITY
        }
    };
    let hi = points
        .iter()
        .flat_map(|(_, p)| p.dvd.iter().chain(p.carrier().1.unwrap_or(&[])).copied())
        .fold(f64::NEG_INFINITY, f64::max);
    let hi = if hi > 0.0 { lg(hi).min(0.0) } else { 0.0 };
    let lo = hi - DECADES;
    let (t0, t_last) = (points[0].0, points[points.len() - 1].0);
    // Each kept time's row reaches to the next one's; the last one a mean interval up.
    let t_end = t_last + (t_last - t0) / (points.len() - 1) as f64;
    let text = font_available();
    let (panel_w, panel_h, bar_w) = (440u32, 520u32, if text { 110 } else { 40 });
    let err = |e: &dyn std::fmt::Display| e.to_string();
    let x_range = 0.5..n as f64 + 0.5;
    // The norm's distribution beside the DVD where the model conserves one (the DDNLS, whose
    // site energies are no distribution), else the energy's.
    let carrier_name = points[0].1.carrier().0;
    two_panels_and_bar((panel_w, panel_h, bar_w), text, (lo, hi), |area, panel| {
        let (title, energy) = if panel == 0 {
            (carrier_name, true)
        } else {
            ("deviation vector distribution ξ_l", false)
        };
        let mut builder = ChartBuilder::on(area);
        builder.margin(10);
        if text {
            builder
                .caption(title, (FONT, 18))
                .x_label_area_size(40)
                .y_label_area_size(60);
        }
        let mut chart = builder
            .build_cartesian_2d(x_range.clone(), t0..t_end)
            .map_err(|e| err(&e))?;
        let pixels = chart.plotting_area().get_pixel_range();
        if text {
            chart
                .configure_mesh()
                .disable_mesh()
                .x_desc("site l")
                .y_desc("t")
                // Sites are whole numbers; six labels keep four-digit ones apart.
                .x_labels(6)
                .x_label_formatter(&|v| format!("{v:.0}"))
                .y_label_formatter(&|v| crate::chart::tick_label(*v, (t0, t_end)))
                .label_style((FONT, 14))
                .draw()
                .map_err(|e| err(&e))?;
        }
        for (i, (t, p)) in points.iter().enumerate() {
            let t_next = points.get(i + 1).map_or(t_end, |q| q.0);
            let weights: Option<&[f64]> = if energy {
                p.carrier().1.ok()
            } else {
                Some(&p.dvd)
            };
            let Some(weights) = weights else {
                continue;
            };
            chart
                .draw_series(weights.iter().enumerate().map(|(l, &x)| {
                    let site = (l + 1) as f64;
                    Rectangle::new(
                        [(site - 0.5, *t), (site + 0.5, t_next)],
                        colour(lg(x).clamp(lo, hi), lo, hi).filled(),
                    )
                }))
                .map_err(|e| err(&e))?;
        }
        Ok(pixels)
    })
}

/// A picture of two panels side by side, `panel_w` x `panel_h` pixels each, and a colour bar
/// of `bar_w` over `lo..hi` at their right, on white: `panel` draws panel 0 (left) and 1 into
/// the area it is given and returns its plotting area's pixels. The pixels, the size, and the
/// panels' and the bar's plotting areas.
pub(crate) fn two_panels_and_bar(
    (panel_w, panel_h, bar_w): (u32, u32, u32),
    text: bool,
    (lo, hi): (f64, f64),
    mut panel: impl FnMut(
        &DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>,
        usize,
    ) -> Result<crate::chart::PixelRect, String>,
) -> Result<crate::chart::Drawn<[crate::chart::PixelRect; 3]>, String> {
    let (w, h) = (2 * panel_w + bar_w, panel_h);
    let err = |e: &dyn std::fmt::Display| e.to_string();
    let mut areas = Vec::new();
    let mut pixels = vec![0u8; w as usize * h as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| err(&e))?;
        let (panels, bar_area) = root.split_horizontally(2 * panel_w);
        let (left, right) = panels.split_horizontally(panel_w);
        for (i, area) in [&left, &right].into_iter().enumerate() {
            areas.push(panel(area, i)?);
        }
        areas.push(colour_bar(&bar_area, text, (lo, hi))?);
        root.present().map_err(|e| err(&e))?;
    }
    let areas: [crate::chart::PixelRect; 3] = areas
        .try_into()
        .map_err(|_| "two panels and a bar".to_string())?;
    Ok((pixels, (w, h), areas))
}

/// The colour bar beside two panels of `log10` weights over `lo..hi` (its caption and ticks
/// when `text`), drawn into `area`; its plotting area's pixels.
pub(crate) fn colour_bar<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    text: bool,
    (lo, hi): (f64, f64),
) -> Result<crate::chart::PixelRect, String> {
    let err = |e: &dyn std::fmt::Display| e.to_string();
    // The caption over the whole strip, not over the bar and its tick labels alone: those are
    // narrower than the words, which were cut at the left ("og10 weight").
    let body = if text {
        area.titled("log10 weight", (FONT, 14))
            .map_err(|e| err(&e))?
    } else {
        area.clone()
    };
    let mut bar_builder = ChartBuilder::on(&body);
    bar_builder
        .margin_top(if text { 20 } else { 10 })
        .margin_bottom(if text { 50 } else { 10 })
        .margin_right(if text { 55 } else { 10 });
    if text {
        bar_builder.y_label_area_size(0).right_y_label_area_size(45);
    }
    let mut bar = bar_builder
        .build_cartesian_2d(0.0..1.0, lo..hi)
        .map_err(|e| err(&e))?;
    if text {
        bar.configure_mesh()
            .disable_mesh()
            .disable_x_axis()
            .y_label_formatter(&|v| crate::chart::tick_label(*v, (lo, hi)))
            .label_style((FONT, 13))
            .draw()
            .map_err(|e| err(&e))?;
    }
    let pixels = bar.plotting_area().get_pixel_range();
    let steps = 120;
    bar.draw_series((0..steps).map(|i| {
        let a = lo + (hi - lo) * i as f64 / steps as f64;
        let b = lo + (hi - lo) * (i + 1) as f64 / steps as f64;
        Rectangle::new([(0.0, a), (1.0, b)], colour((a + b) / 2.0, lo, hi).filled())
    }))
    .map_err(|e| err(&e))?;
    Ok(pixels)
}

#[cfg(test)]
mod tests {
    use chaoscope_schemas::run::{Sample, SchemeSample};

    use super::*;

    #[test]
    fn the_distributions_stay_in_their_panels() {
        // Eight sites over 40 renormalizations, the weight wandering along the chain, and
        // energies spanning more decades than the colour scale (clamped to it, never drawn
        // beyond the panels).
        let n = 8;
        let mut profiles = SiteProfiles::new(n);
        for step in 0..40u64 {
            let t = step as f64;
            let weight = |l: usize| 10f64.powf(-((l as f64 - 0.2 * t).abs() * 2.0));
            let separations: Vec<f64> = (0..2 * n)
                .map(|i| weight(i % n).sqrt())
                .chain(std::iter::repeat_n(0.5, 2 * n))
                .collect();
            let sample = Sample {
                seq: step,
                step,
                t,
                state: vec![0.1; 2 * n],
                energy: 1.0,
                mean_divergence: 0.0,
                divergence_sum: 0.0,
                schemes: vec![SchemeSample {
                    scheme: 0,
                    set: 0,
                    separations,
                    stretch: vec![1.0, 1.0],
                    earlier_stretch: Vec::new(),
                }],
            };
            profiles.offer(&sample, || Some(Ok((0..n).map(weight).collect())));
        }
        let (pixels, (w, _), areas) = render_pixels(&profiles).unwrap();
        let out = crate::chart::stray_pixels(&pixels, w, &areas, crate::chart::coloured);
        assert!(
            out.is_empty(),
            "{} coloured pixels outside the panels {areas:?}, e.g. {:?}",
            out.len(),
            &out[..out.len().min(5)]
        );
        // Both panels were drawn.
        for (xs, ys) in &areas[..2] {
            let mid = ((ys.start + ys.end) / 2 * w as i32 + (xs.start + xs.end) / 2) as usize;
            assert!(crate::chart::coloured([
                pixels[3 * mid],
                pixels[3 * mid + 1],
                pixels[3 * mid + 2]
            ]));
        }
    }
}
