//! A small description of a 2-D chart and its rendering to PNG and SVG with `plotters`.
//!
//! Axes are linear in whatever is given; log scales are drawn by passing `log10` values and
//! saying so in the label (as the paper does: "log10 t", "log10 GALI_k"), which keeps values
//! like 1e-300 as plottable as 1.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::FontStyle;

/// How a line is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Stroke {
    Solid,
    /// Reference laws (slopes).
    Dashed,
    /// Unconnected dots (Poincare sections, sweeps).
    Dots,
}

#[derive(Debug, Clone, serde::Deserialize)]
pub struct Line {
    #[serde(default)]
    pub label: String,
    pub points: Vec<(f64, f64)>,
    #[serde(default = "solid")]
    pub stroke: Stroke,
    /// Index into the palette; lines sharing a color belong together.
    #[serde(default)]
    pub color: usize,
}

fn solid() -> Stroke {
    Stroke::Solid
}

/// Also read from JSON by `chaoscope chart` (scripts draw derived figures with it), e.g.
/// `{"title": "...", "x_label": "log10 h", "y_label": "log10 E_r",
///   "lines": [{"label": "ABA864", "points": [[-2, -11.3], [-1, -7.4]], "stroke": "solid", "color": 1}]}`.
#[derive(Debug, Clone, Default, serde::Deserialize)]
#[serde(default)]
pub struct Chart {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub lines: Vec<Line>,
    /// Fixed axis ranges (else from the data).
    pub x_range: Option<(f64, f64)>,
    pub y_range: Option<(f64, f64)>,
}

impl Chart {
    /// The values of a chart description that are checked before drawing (its fixed axis
    /// ranges, [`check_range`]), as `field: problem`.
    pub fn check(&self) -> Result<(), String> {
        for (name, range) in [("x_range", self.x_range), ("y_range", self.y_range)] {
            if let Some(r) = range {
                check_range(name, r)?;
            }
        }
        Ok(())
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ChartError {
    #[error(
        "no TrueType font found for chart text; set CHAOSCOPE_FONT to a .ttf file (e.g. DejaVuSans.ttf)"
    )]
    NoFont,
    #[error("{}: {message}", path.display())]
    Draw { path: PathBuf, message: String },
    #[error(transparent)]
    Output(#[from] chaoscope_os::OutputError),
}

/// How charts, plots and colour maps are written: complete or not at all, replacing an earlier
/// drawing of the same name (never anything but a regular file, never an input).
fn drawing_options(inputs: &[PathBuf]) -> chaoscope_os::OutputOptions {
    chaoscope_os::OutputOptions {
        replace: true,
        inputs: inputs.to_vec(),
        leftover: chaoscope_os::Leftover::Discard,
        ..Default::default()
    }
}

/// Writes RGB `pixels` of `size` as a PNG file at `path`.
pub fn save_png(
    path: &Path,
    inputs: &[PathBuf],
    pixels: &[u8],
    size: (u32, u32),
) -> Result<PathBuf, ChartError> {
    use image::ImageEncoder;
    use std::io::Write;
    Ok(chaoscope_os::output::write_whole(
        path,
        &drawing_options(inputs),
        |file| {
            let mut out = std::io::BufWriter::new(file);
            image::codecs::png::PngEncoder::new(&mut out)
                .write_image(pixels, size.0, size.1, image::ColorType::Rgb8)
                .map_err(std::io::Error::other)?;
            out.flush()
        },
    )?)
}

const FONT_CANDIDATES: &[&str] = &[
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
    "/usr/share/fonts/liberation/LiberationSans-Regular.ttf",
    "/System/Library/Fonts/Supplemental/Arial.ttf",
];

/// Registers a system font once (plotters' pure-Rust text rendering needs one).
fn ensure_font() -> Result<(), ChartError> {
    font_available().then_some(()).ok_or(ChartError::NoFont)
}

fn font_available() -> bool {
    static FONT: OnceLock<bool> = OnceLock::new();
    *FONT.get_or_init(|| {
        let env = std::env::var("CHAOSCOPE_FONT").ok();
        let bytes = env
            .iter()
            .map(String::as_str)
            .chain(FONT_CANDIDATES.iter().copied())
            .find_map(|p| chaoscope_os::read_regular(p.as_ref()).ok());
        let Some(bytes) = bytes else { return false };
        // The registry wants 'static bytes: a font is loaded once per process.
        let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
        plotters::style::register_font("sans-serif", FontStyle::Normal, bytes).is_ok()
    })
}

/// The axis range of `values` (finite ones), padded by 4 % of its width: always finite, wider
/// than rounding at its magnitude, and of finite width (values beyond +-f64::MAX / 4 are
/// clipped), so that plotters can place ticks on it. Data near +-1e308 once made the width
/// infinite and the tick search never end.
pub fn padded_range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        });
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    const LIMIT: f64 = f64::MAX / 4.0;
    let (lo, hi) = (lo.clamp(-LIMIT, LIMIT), hi.clamp(-LIMIT, LIMIT));
    let pad = (0.04 * (hi - lo))
        .max(MIN_RELATIVE_WIDTH * lo.abs().max(hi.abs()))
        .max(MIN_WIDTH);
    (lo - pad, hi + pad)
}

/// Narrowest axis range, relative to the magnitude of its ends: narrower ranges have fewer
/// distinct doubles than an axis needs ticks.
const MIN_RELATIVE_WIDTH: f64 = 1e-9;
/// Narrowest axis range near zero.
const MIN_WIDTH: f64 = 1e-200;

/// A range given for an axis (`x_range`, `y_range` of a chart description), checked as
/// [`padded_range`] makes them: finite ends, `lo < hi`, a finite width not narrower than
/// rounding allows.
pub fn check_range(name: &str, (lo, hi): (f64, f64)) -> Result<(), String> {
    let width = hi - lo;
    let ok = lo.is_finite()
        && hi.is_finite()
        && width.is_finite()
        && width > 0.0
        && width >= MIN_RELATIVE_WIDTH * lo.abs().max(hi.abs())
        && width >= MIN_WIDTH;
    if ok {
        Ok(())
    } else {
        Err(format!(
            "{name} = [{lo}, {hi}]: need finite ends lo < hi, their distance finite and at \
             least {MIN_RELATIVE_WIDTH:e} of their magnitude"
        ))
    }
}

fn palette(i: usize) -> RGBColor {
    const COLORS: [RGBColor; 8] = [
        RGBColor(0, 0, 0),
        RGBColor(213, 94, 0),
        RGBColor(0, 114, 178),
        RGBColor(0, 158, 115),
        RGBColor(204, 121, 167),
        RGBColor(230, 159, 0),
        RGBColor(86, 180, 233),
        RGBColor(120, 120, 120),
    ];
    COLORS[i % COLORS.len()]
}

/// Draws `chart`; without a font (`text` false) the curves and grid are drawn without any text.
fn draw<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    chart: &Chart,
    text: bool,
) -> Result<(), String>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    chart.check()?;
    let xr = chart.x_range.unwrap_or_else(|| {
        padded_range(
            chart
                .lines
                .iter()
                .flat_map(|l| l.points.iter().map(|p| p.0)),
        )
    });
    let yr = chart.y_range.unwrap_or_else(|| {
        padded_range(
            chart
                .lines
                .iter()
                .flat_map(|l| l.points.iter().map(|p| p.1)),
        )
    });
    let mut builder = ChartBuilder::on(&root);
    builder.margin(12);
    if text {
        builder
            .caption(&chart.title, ("sans-serif", 20))
            .x_label_area_size(40)
            .y_label_area_size(60);
    }
    let mut ctx = builder
        .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)
        .map_err(|e| e.to_string())?;
    let mut mesh = ctx.configure_mesh();
    mesh.light_line_style(WHITE.mix(0.0));
    if text {
        mesh.x_desc(&chart.x_label)
            .y_desc(&chart.y_label)
            .label_style(("sans-serif", 14));
    } else {
        mesh.x_labels(0).y_labels(0);
    }
    mesh.draw().map_err(|e| e.to_string())?;
    // Points far outside the axes (a fixed range, or values clipped by `padded_range`) are left
    // out rather than mapped to pixel coordinates beyond i32, whose lines the rasterizer would
    // walk pixel by pixel.
    let near = |v: f64, (lo, hi): (f64, f64)| {
        let w = hi - lo;
        v.is_finite() && v >= lo - 8.0 * w && v <= hi + 8.0 * w
    };
    let in_range = |p: &&(f64, f64)| near(p.0, xr) && near(p.1, yr);
    for line in &chart.lines {
        let color = palette(line.color);
        let pts: Vec<(f64, f64)> = line.points.iter().filter(in_range).copied().collect();
        let series = match line.stroke {
            Stroke::Solid => ctx.draw_series(LineSeries::new(pts, color.stroke_width(2))),
            Stroke::Dashed => {
                ctx.draw_series(DashedLineSeries::new(pts, 8, 6, color.stroke_width(1)))
            }
            Stroke::Dots => ctx.draw_series(
                pts.into_iter()
                    .map(|p| Circle::new(p, 1, color.filled()))
                    .collect::<Vec<_>>(),
            ),
        }
        .map_err(|e| e.to_string())?;
        if !line.label.is_empty() {
            series
                .label(&line.label)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], color));
        }
    }
    if text && chart.lines.iter().any(|l| !l.label.is_empty()) {
        ctx.configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 13))
            .position(SeriesLabelPosition::UpperRight)
            .draw()
            .map_err(|e| e.to_string())?;
    }
    root.present().map_err(|e| e.to_string())
}

/// The SVG of `chart` as text (what [`render`] writes to `<stem>.svg`), drawn in memory.
pub fn render_svg(chart: &Chart) -> Result<String, String> {
    let text = ensure_font().is_ok();
    let mut svg = String::new();
    draw(
        SVGBackend::with_string(&mut svg, SIZE).into_drawing_area(),
        chart,
        text,
    )?;
    Ok(svg)
}

/// Size of every chart in pixels.
const SIZE: (u32, u32) = (800, 560);

/// Writes `<stem>.png` and `<stem>.svg` (each complete or not at all, never one of `inputs`). Without any TrueType font on the machine the charts
/// are drawn without text (a warning says so once) rather than not at all.
pub fn render(chart: &Chart, stem: &Path, inputs: &[PathBuf]) -> Result<Vec<PathBuf>, ChartError> {
    let text = ensure_font().is_ok();
    static WARNED: OnceLock<()> = OnceLock::new();
    if !text {
        WARNED.get_or_init(|| {
            chaoscope_os::errln!(
                "chaoscope: warning: {}; charts have no text",
                ChartError::NoFont
            )
        });
    }
    let size = SIZE;
    // Appended, not `with_extension`: a scheme name may hold dots (`gali_tau0.5` must not
    // become `gali_tau0.png`, nor two schemes share one file).
    let with = |ext: &str| {
        let mut name = stem.as_os_str().to_os_string();
        name.push(ext);
        PathBuf::from(name)
    };
    let (png, svg) = (with(".png"), with(".svg"));
    let err = |path: &Path, message: String| ChartError::Draw {
        path: path.to_path_buf(),
        message,
    };
    // Drawn in memory, then each written as one output (`chaoscope_os::output`).
    let mut pixels = vec![0u8; size.0 as usize * size.1 as usize * 3];
    draw(
        BitMapBackend::with_buffer(&mut pixels, size).into_drawing_area(),
        chart,
        text,
    )
    .map_err(|m| err(&png, m))?;
    save_png(&png, inputs, &pixels, size)?;
    let mut vector = String::new();
    draw(
        SVGBackend::with_string(&mut vector, size).into_drawing_area(),
        chart,
        text,
    )
    .map_err(|m| err(&svg, m))?;
    chaoscope_os::output::write_whole(&svg, &drawing_options(inputs), |file| {
        std::io::Write::write_all(file, vector.as_bytes())
    })?;
    Ok(vec![png, svg])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn chart() -> Chart {
        Chart {
            title: "t".into(),
            x_label: "x".into(),
            y_label: "y".into(),
            lines: vec![
                Line {
                    label: "a".into(),
                    points: vec![(0.0, 1.0), (1.0, f64::NAN), (2.0, -3.0)],
                    stroke: Stroke::Solid,
                    color: 1,
                },
                Line {
                    label: String::new(),
                    points: vec![(0.0, 0.0), (2.0, -2.0)],
                    stroke: Stroke::Dashed,
                    color: 2,
                },
            ],
            ..Default::default()
        }
    }

    #[test]
    fn draws_without_a_font_and_skips_non_finite_points() {
        // Machines without any TrueType font still get the curves (no text at all).
        let mut buf = vec![0u8; 200 * 150 * 3];
        let root = BitMapBackend::with_buffer(&mut buf, (200, 150)).into_drawing_area();
        draw(root, &chart(), false).unwrap();
        // Something other than white was drawn.
        assert!(buf.iter().any(|&b| b != 255));
    }

    #[test]
    fn chart_specs_parse_from_json() {
        let c: Chart = serde_json::from_str(
            r#"{"title": "E", "lines": [{"points": [[1, 2], [3, 4]], "stroke": "dashed"}]}"#,
        )
        .unwrap();
        assert_eq!(c.lines[0].stroke, Stroke::Dashed);
        assert_eq!(c.lines[0].points[1], (3.0, 4.0));
    }
}
