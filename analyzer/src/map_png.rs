//! PNG colour maps of a map recording, in the style of the paper's Fig. 9: one cell per grid
//! point, viridis colours rising with the plotted value for every indicator (purple = low,
//! yellow = high, as the colour bar beside it reads upwards), GALI, SALI and MLE on a log10
//! scale. Which end is chaos depends on the indicator (low GALI, SALI and `gali-time`; high
//! MLE, FLI and MEGNO: the paper's GALI maps have the chaotic sea purple, MLE and MEGNO maps
//! conventionally yellow), so the bar says it: "chaotic" at that end, "regular" at the other.
//! Points outside the energy surface are white, escaped ones grey.
//!
//! Text needs a TrueType font, looked up at run time (`CHAOSCOPE_FONT`, then DejaVu Sans /
//! Liberation Sans in the usual places); without one the image is drawn without labels.

use std::path::{Path, PathBuf};

use chaoscope_schemas::proto::{MapHeader, MapPoint, map_point};
use plotters::prelude::*;
use plotters::style::colors::colormaps::ViridisRGB;

pub(crate) use crate::chart::{FONT, font_available};

/// How a point's value is coloured.
struct Scale {
    label: String,
    /// Map a value to the plotted number (e.g. log10); `None` for unplottable values.
    transform: fn(f64) -> Option<f64>,
    /// Large plotted numbers mean chaos (the top of the colour bar, yellow).
    chaotic_high: bool,
}

fn scale_of(h: &MapHeader) -> Scale {
    let log = |v: f64| (v > 0.0 && v.is_finite()).then(|| v.log10());
    let lin = |v: f64| v.is_finite().then_some(v);
    match h.indicator.as_str() {
        "gali" => Scale {
            label: format!("log10 GALI_{} (t = {})", h.k, h.t_final),
            transform: log,
            chaotic_high: false,
        },
        "sali" => Scale {
            label: format!("log10 SALI (t = {})", h.t_final),
            transform: log,
            chaotic_high: false,
        },
        "gali-time" => Scale {
            label: format!("t (GALI_{} < {:e})", h.k, h.threshold),
            transform: lin,
            chaotic_high: false,
        },
        // lambda_1 of the spectrum (the other exponents are layers of the file): it can be
        // zero or negative, so on a linear scale.
        "spectrum" => Scale {
            label: format!("λ_1 of {} exponents (t = {})", h.k, h.t_final),
            transform: lin,
            chaotic_high: true,
        },
        "mle" => Scale {
            label: format!("log10 λ_1 (t = {})", h.t_final),
            transform: log,
            chaotic_high: true,
        },
        // A registered set indicator's output (`fli`, `megno`, `megno_mean`): they grow with
        // chaos, linearly in time (FLI, MEGNO), so a linear scale keeps the regular values
        // (MEGNO near 2, FLI near ln t) apart from one another.
        name => Scale {
            label: format!("{} (t = {})", crate::plot::indicator_label(name), h.t_final),
            transform: lin,
            chaotic_high: true,
        },
    }
}

/// The colour of a plotted number on the scale `lo..hi`: viridis rising with the number, the
/// same way for every indicator, so the bar beside the map reads like its axis.
pub(crate) fn colour(v: f64, lo: f64, hi: f64) -> RGBColor {
    // The fraction of the way up the scale, in f64 and clamped to [0, 1] (0 where it is not a
    // number): plotters normalizes in f32, where ends beyond 3.4e38 (a gali-time map of
    // t_final 1e308) are infinite, the fraction NaN, and its index `unwrap()`s a `None`.
    let t = (v - lo) / (hi - lo);
    let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) };
    ViridisRGB.get_color_normalized(t as f32, 0.0, 1.0)
}

/// The words at the top and the bottom of the colour bar: which end is chaos.
fn bar_ends(scale: &Scale) -> [&'static str; 2] {
    if scale.chaotic_high {
        ["chaotic", "regular"]
    } else {
        ["regular", "chaotic"]
    }
}

/// Largest side of the image in pixels: grids of more points per axis get cells narrower than a
/// pixel (an image of at most 4096 x 4096 x 3 bytes, whatever the grid claims).
const MAX_SIDE: u32 = 4096;

/// `lo..hi`, or, if it is not a finite range of finite width, the finite range plotters can
/// draw around the same ends ([`crate::chart::padded_range`]).
fn drawable(lo: f64, hi: f64, ends: [f64; 2]) -> std::ops::Range<f64> {
    if lo.is_finite() && hi.is_finite() && (hi - lo).is_finite() && hi > lo {
        lo..hi
    } else {
        let (lo, hi) = crate::chart::padded_range(ends.into_iter());
        lo..hi
    }
}

/// Renders `points` of the map described by `header` to a PNG file. The header and points are
/// checked first ([`chaoscope_files::map_file::check_header`], [`check_point`]): a value
/// no map writes is an error naming it, never an image of absurd size or a hang.
///
/// [`check_point`]: chaoscope_files::map_file::check_point
pub fn render_png(
    header: &MapHeader,
    points: &[MapPoint],
    path: &Path,
    inputs: &[PathBuf],
) -> Result<(), String> {
    let (pixels, size, _) =
        render_pixels(header, points).map_err(|e| format!("{}: {e}", path.display()))?;
    crate::chart::save_png(path, inputs, &pixels, size)
        .map(drop)
        .map_err(|e| e.to_string())
}

/// The map drawn in memory as RGB pixels of the returned size, with where it put the map (the
/// plotting area) and the colour bar (in [`Layout::legend`]): checked as [`render_png`] says.
///
/// [`Layout::legend`]: crate::chart::Layout
pub fn render_pixels(
    header: &MapHeader,
    points: &[MapPoint],
) -> Result<crate::chart::Drawn<crate::chart::Layout>, String> {
    use chaoscope_files::map_file::{check_header, check_point};
    check_header(header).map_err(|e| format!("map header: {e}"))?;
    points.iter().try_for_each(|p| check_point(header, p))?;
    let (xa, ya) = match (&header.x, &header.y) {
        (Some(x), Some(y)) => (x.clone(), y.clone()),
        _ => return Err("map header without axes".into()),
    };
    // At most 100 000 each (checked).
    let (nx, ny) = (xa.n as i32, ya.n as i32);
    let scale = scale_of(header);
    let values: Vec<f64> = points
        .iter()
        .filter(|p| p.status() == map_point::Status::Ok)
        .filter_map(|p| (scale.transform)(p.value))
        .collect();
    let (mut lo, mut hi) = values
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(*v), b.max(*v))
        });
    if header.indicator == "gali-time" {
        (lo, hi) = (0.0, header.t_final);
    }
    if !(lo.is_finite() && hi.is_finite()) {
        (lo, hi) = (0.0, 1.0);
    }
    if hi <= lo {
        hi = lo + 1.0;
    }
    // A colour scale of finite width (values near +-1e308 would make it infinite).
    let scale_range = drawable(lo, hi, [lo, hi]);
    (lo, hi) = (scale_range.start, scale_range.end);
    let cell = (600 / nx.max(ny)).clamp(1, 16) as u32;
    let (pw, ph) = (
        (cell * nx as u32).min(MAX_SIDE),
        (cell * ny as u32).min(MAX_SIDE),
    );
    let text = font_available();
    let (margin, bar) = (if text { 70 } else { 10 }, if text { 130 } else { 40 });
    let (w, h) = (
        pw + margin + bar + 20,
        ph + margin + if text { 40 } else { 10 },
    );
    let err = |e: &dyn std::fmt::Display| e.to_string();

    // Drawn in memory, then written as one output (`chaoscope_os::output`).
    let mut pixels = vec![0u8; w as usize * h as usize * 3];
    let root = BitMapBackend::with_buffer(&mut pixels, (w, h)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    // The title across the whole image (set smaller where a small grid leaves it narrow).
    let body = if text {
        crate::chart::titled(
            &root,
            &format!("{} over a grid of initial conditions", scale.label),
        )?
    } else {
        root.clone()
    };
    let (plot_area, bar_area) = body.split_horizontally(pw + margin + 20);
    let (x0, x1) = (xa.min, xa.max.max(xa.min + f64::EPSILON));
    let (y0, y1) = (ya.min, ya.max.max(ya.min + f64::EPSILON));
    let dx = if nx > 1 {
        (x1 - x0) / (nx - 1) as f64
    } else {
        1.0
    };
    let dy = if ny > 1 {
        (y1 - y0) / (ny - 1) as f64
    } else {
        1.0
    };
    let (xr, yr) = (
        drawable(x0 - dx / 2.0, x0 + dx * (nx as f64 - 0.5), [x0, x1]),
        drawable(y0 - dy / 2.0, y0 + dy * (ny as f64 - 0.5), [y0, y1]),
    );
    let (xb, yb) = ((xr.start, xr.end), (yr.start, yr.end));
    let mut builder = ChartBuilder::on(&plot_area);
    builder.margin(10);
    if text {
        builder.x_label_area_size(40).y_label_area_size(55);
    }
    let mut chart = builder.build_cartesian_2d(xr, yr).map_err(|e| err(&e))?;
    if text {
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc(xa.name())
            .y_desc(ya.name())
            .x_label_formatter(&|v| crate::chart::tick_label(*v, xb))
            .y_label_formatter(&|v| crate::chart::tick_label(*v, yb))
            .label_style((FONT, 14))
            .draw()
            .map_err(|e| err(&e))?;
    }
    chart
        .draw_series(points.iter().map(|p| {
            let fill = match p.status() {
                map_point::Status::Ok => match (scale.transform)(p.value) {
                    Some(v) => colour(v.clamp(lo, hi), lo, hi),
                    None => colour(lo, lo, hi),
                },
                map_point::Status::Escaped => RGBColor(140, 140, 140),
                _ => WHITE,
            };
            // The cell of its grid position (checked to be where its coordinates are), kept
            // inside the drawn range.
            let (cx, cy) = (x0 + dx * f64::from(p.ix), y0 + dy * f64::from(p.iy));
            let x = |v: f64| v.clamp(xb.0, xb.1);
            let y = |v: f64| v.clamp(yb.0, yb.1);
            Rectangle::new(
                [
                    (x(cx - dx / 2.0), y(cy - dy / 2.0)),
                    (x(cx + dx / 2.0), y(cy + dy / 2.0)),
                ],
                fill.filled(),
            )
        }))
        .map_err(|e| err(&e))?;

    // The colour bar.
    let mut bar_builder = ChartBuilder::on(&bar_area);
    bar_builder
        .margin_top(if text { 28 } else { 10 })
        .margin_bottom(if text { 50 } else { 10 });
    bar_builder.margin_right(if text { 60 } else { 10 });
    if text {
        bar_builder.y_label_area_size(0).right_y_label_area_size(50);
    }
    let mut bar_chart = bar_builder
        .build_cartesian_2d(0.0..1.0, lo..hi)
        .map_err(|e| err(&e))?;
    if text {
        bar_chart
            .configure_mesh()
            .disable_mesh()
            .disable_x_axis()
            .y_label_formatter(&|v| crate::chart::tick_label(*v, (lo, hi)))
            .label_style((FONT, 13))
            .draw()
            .map_err(|e| err(&e))?;
    }
    let steps = 200;
    bar_chart
        .draw_series((0..steps).map(|i| {
            let a = lo + (hi - lo) * i as f64 / steps as f64;
            let b = lo + (hi - lo) * (i + 1) as f64 / steps as f64;
            Rectangle::new([(0.0, a), (1.0, b)], colour((a + b) / 2.0, lo, hi).filled())
        }))
        .map_err(|e| err(&e))?;
    if text {
        // Which end is chaos, above and below the bar (in the margins left for them).
        let [top, bottom] = bar_ends(&scale);
        let style = (FONT, 13).into_font().color(&BLACK);
        bar_area
            .draw(&Text::new(top, (0, 8), style.clone()))
            .map_err(|e| err(&e))?;
        bar_area
            .draw(&Text::new(
                bottom,
                (0, bar_area.dim_in_pixel().1 as i32 - 44),
                style,
            ))
            .map_err(|e| err(&e))?;
    }
    root.present().map_err(|e| err(&e))?;
    let layout = crate::chart::Layout {
        plot: chart.plotting_area().get_pixel_range(),
        legend: Some(bar_chart.plotting_area().get_pixel_range()),
    };
    drop((bar_chart, chart, plot_area, bar_area, body, root));
    Ok((pixels, (w, h), layout))
}

#[cfg(test)]
mod tests {
    use chaoscope_schemas::proto::MapHeader;

    use chaoscope_schemas::proto::{MapAxis, MapPoint, map_point};

    use super::{bar_ends, colour, render_pixels, scale_of};

    #[test]
    fn the_cells_stay_in_the_map_and_the_bar_beside_it() {
        // A 7 x 5 grid whose edge cells reach half a cell beyond the grid's extreme points, with
        // values over many decades: every coloured pixel is a cell's or the bar's.
        let axis = |coord: &str, n: u32| MapAxis {
            coord: coord.into(),
            min: -1.0,
            max: 1.0,
            n,
            ..Default::default()
        };
        let header = MapHeader {
            indicator: "gali".into(),
            k: 2,
            t_final: 1000.0,
            sets: 1,
            x: Some(axis("q2", 7)),
            y: Some(axis("p2", 5)),
            grid_points: 35,
            shard_count: 1,
            ..Default::default()
        };
        let points: Vec<MapPoint> = (0..35u32)
            .map(|i| {
                let (ix, iy) = (i % 7, i / 7);
                MapPoint {
                    index: u64::from(i),
                    ix,
                    iy,
                    x: -1.0 + 2.0 * f64::from(ix) / 6.0,
                    y: -1.0 + 2.0 * f64::from(iy) / 4.0,
                    value: 10f64.powi(-(i as i32 % 17)),
                    per_set: vec![10f64.powi(-(i as i32 % 17))],
                    mean_log10: -f64::from(i % 17),
                    status: map_point::Status::Ok as i32,
                    ..Default::default()
                }
            })
            .collect();
        let (pixels, (w, _), layout) = match render_pixels(&header, &points) {
            Ok(drawn) => drawn,
            Err(e) => panic!("{e}"),
        };
        let out = crate::chart::stray_pixels(&pixels, w, &layout.areas(), crate::chart::coloured);
        assert!(
            out.is_empty(),
            "{} coloured pixels outside the map and its bar {layout:?}, e.g. {:?}",
            out.len(),
            &out[..out.len().min(5)]
        );
    }

    /// Near the two ends of viridis: purple (68, 1, 84) and yellow (253, 231, 37; 0.9 of the
    /// way up it is still (189, 223, 38)).
    fn is_purple(c: plotters::style::RGBColor) -> bool {
        c.0 < 100 && c.1 < 50 && c.2 > 60
    }
    fn is_yellow(c: plotters::style::RGBColor) -> bool {
        c.0 > 150 && c.1 > 180 && c.2 < 100
    }

    #[test]
    fn the_bar_says_which_end_is_chaos_and_colours_rise_with_the_value() {
        let header = |indicator: &str| MapHeader {
            indicator: indicator.to_string(),
            k: 2,
            t_final: 1000.0,
            ..Default::default()
        };
        // Where chaos lies for each indicator: a large MLE, FLI or MEGNO; a small GALI, SALI
        // or time for GALI to fall under its threshold.
        for (indicator, chaotic_high) in [
            ("mle", true),
            ("fli", true),
            ("megno", true),
            ("megno_mean", true),
            ("gali", false),
            ("sali", false),
            ("gali-time", false),
        ] {
            let scale = scale_of(&header(indicator));
            assert_eq!(scale.chaotic_high, chaotic_high, "{indicator}");
            let [top, bottom] = bar_ends(&scale);
            let (chaotic, regular) = if chaotic_high {
                (top, bottom)
            } else {
                (bottom, top)
            };
            assert_eq!((chaotic, regular), ("chaotic", "regular"), "{indicator}");
        }
        // The same colours for the same place on the scale, whatever the indicator: the bottom
        // purple, the top yellow. A chaotic MLE of 0.4 on a scale from 1e-4 (log10 -4) to 1
        // is yellow, a regular one of 1e-4 purple.
        let mle = scale_of(&header("mle"));
        let (lo, hi) = (-4.0, 0.0);
        let chaotic = (mle.transform)(0.4).unwrap();
        let regular = (mle.transform)(1e-4).unwrap();
        assert!(
            is_yellow(colour(chaotic, lo, hi)),
            "{:?}",
            colour(chaotic, lo, hi)
        );
        assert!(
            is_purple(colour(regular, lo, hi)),
            "{:?}",
            colour(regular, lo, hi)
        );
        // GALI: a chaotic 1e-16 at the bottom is purple, a regular 1e-2 at the top yellow.
        let gali = scale_of(&header("gali"));
        let (lo, hi) = (-16.0, -2.0);
        assert!(is_purple(colour((gali.transform)(1e-16).unwrap(), lo, hi)));
        assert!(is_yellow(colour((gali.transform)(1e-2).unwrap(), lo, hi)));
    }
}
