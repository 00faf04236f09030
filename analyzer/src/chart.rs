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
    "C:\\Windows\\Fonts\\arial.ttf",
];

/// Registers a system font once (plotters' pure-Rust text rendering needs one).
fn ensure_font() -> Result<(), ChartError> {
    font_available().then_some(()).ok_or(ChartError::NoFont)
}

pub(crate) fn font_available() -> bool {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    *REGISTERED.get_or_init(|| {
        let env = std::env::var("CHAOSCOPE_FONT").ok();
        let bytes = env
            .iter()
            .map(String::as_str)
            .chain(FONT_CANDIDATES.iter().copied())
            .find_map(|p| chaoscope_os::read_regular(p.as_ref()).ok());
        let Some(bytes) = bytes else { return false };
        // The registry wants 'static bytes: a font is loaded once per process.
        let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
        plotters::style::register_font(FONT, FontStyle::Normal, bytes).is_ok()
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

/// The colour of series colour index `i` (black, then the Okabe-Ito colours, then grey).
pub fn palette(i: usize) -> RGBColor {
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

/// A drawing in memory: RGB pixels, their size, and where the drawing put its areas.
pub type Drawn<L> = (Vec<u8>, (u32, u32), L);

/// Pixel rectangle `(x range, y range)` of a drawing, ends exclusive.
pub type PixelRect = (std::ops::Range<i32>, std::ops::Range<i32>);

/// Where a drawn chart put things: the plotting area, inside which every series stays (cut at
/// its border), and the legend strip beside it (outside the data), if the chart has one.
#[derive(Debug, Clone, PartialEq)]
pub struct Layout {
    pub plot: PixelRect,
    pub legend: Option<PixelRect>,
}

/// Width of the legend strip to the right of the plotting area.
pub const LEGEND_WIDTH: u32 = 190;

/// The face every chart's text is set in (registered once from a system font, [`font_available`]).
pub(crate) const FONT: &str = "sans-serif";

/// A tick label for `v` on an axis spanning `(lo, hi)`: as many digits as the tick spacing
/// needs (about a tenth of the span) and no more (`1000`, not `1000.0`; `0.3`, not
/// `0.30000000000000004`), zero as `0` (never `-0` nor a rounding residue like `1e-17`), and
/// scientific notation where plain digits would be long (`2.5e5`, `1e-4`). One formatter for
/// every chart's axes and colour bars.
pub fn tick_label(v: f64, (lo, hi): (f64, f64)) -> String {
    if !v.is_finite() {
        return String::new();
    }
    let width = (hi - lo).abs();
    let width = if width.is_finite() && width > 0.0 {
        width
    } else {
        v.abs().max(1.0)
    };
    // Ticks are placed at multiples of a spacing near width / 10: anything finer than a
    // thousandth of the width is rounding.
    if v.abs() < 1e-6 * width {
        return "0".into();
    }
    let spacing_exponent = (width / 10.0).log10().floor() as i32;
    let magnitude = lo.abs().max(hi.abs()).max(v.abs());
    let trim = |text: String| -> String {
        let (mantissa, exponent) = match text.split_once('e') {
            Some((m, e)) => (m.to_string(), Some(e.to_string())),
            None => (text, None),
        };
        let mantissa = if mantissa.contains('.') {
            mantissa
                .trim_end_matches('0')
                .trim_end_matches('.')
                .to_string()
        } else {
            mantissa
        };
        match exponent {
            Some(e) => format!("{mantissa}e{e}"),
            None => mantissa,
        }
    };
    let text = if !(1e-3..1e5).contains(&magnitude) {
        // Significant digits down to one below the spacing's.
        let digits = (v.abs().log10().floor() as i32 - spacing_exponent + 1).clamp(0, 15);
        trim(format!("{:.*e}", digits as usize, v))
    } else {
        let decimals = (1 - spacing_exponent).clamp(0, 15) as usize;
        trim(format!("{v:.decimals$}"))
    };
    if text.parse::<f64>().is_ok_and(|x| x == 0.0) {
        "0".into()
    } else {
        text
    }
}

/// The part of the segment `a`-`b` inside the rectangle `xr` x `yr` (Liang-Barsky), or `None`
/// where it misses it (or is not a finite segment).
pub fn clip_segment(
    a: (f64, f64),
    b: (f64, f64),
    (x0, x1): (f64, f64),
    (y0, y1): (f64, f64),
) -> Option<((f64, f64), (f64, f64))> {
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    if !(dx.is_finite() && dy.is_finite() && a.0.is_finite() && a.1.is_finite()) {
        return None;
    }
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for (p, q) in [
        (-dx, a.0 - x0),
        (dx, x1 - a.0),
        (-dy, a.1 - y0),
        (dy, y1 - a.1),
    ] {
        if p == 0.0 {
            if q < 0.0 {
                return None;
            }
        } else {
            let r = q / p;
            if p < 0.0 {
                t0 = t0.max(r);
            } else {
                t1 = t1.min(r);
            }
        }
    }
    if t0 > t1 {
        return None;
    }
    // Kept inside the rectangle against the rounding of `a + t d`.
    let at = |t: f64| ((a.0 + t * dx).clamp(x0, x1), (a.1 + t * dy).clamp(y0, y1));
    Some((at(t0), at(t1)))
}

/// A polyline cut at the border of the rectangle `xr` x `yr`: the runs of it inside, each a
/// polyline of its own. A non-finite point breaks the line.
pub fn clip_polyline(
    points: &[(f64, f64)],
    xr: (f64, f64),
    yr: (f64, f64),
) -> Vec<Vec<(f64, f64)>> {
    let mut runs: Vec<Vec<(f64, f64)>> = Vec::new();
    let mut open = false;
    for pair in points.windows(2) {
        match clip_segment(pair[0], pair[1], xr, yr) {
            Some((a, b)) => {
                // The run goes on where the segment starts where the last one ended inside.
                let continues = open && a == pair[0];
                if !continues {
                    runs.push(vec![a]);
                }
                runs.last_mut().expect("a run was started").push(b);
                open = b == pair[1];
            }
            None => open = false,
        }
    }
    if points.len() == 1 && inside(points[0], xr, yr) {
        runs.push(vec![points[0]]);
    }
    runs
}

/// `p` lies in the rectangle `xr` x `yr` (border included).
pub fn inside(p: (f64, f64), (x0, x1): (f64, f64), (y0, y1): (f64, f64)) -> bool {
    (x0..=x1).contains(&p.0) && (y0..=y1).contains(&p.1)
}

/// One entry of a legend: a sample of the stroke in its colour, and the words.
#[derive(Debug, Clone)]
pub struct LegendEntry {
    pub label: String,
    pub color: RGBColor,
    pub stroke: Stroke,
}

/// Draws `entries` down the strip `area` (beside the plotting area, never over the data), as
/// many as fit.
pub fn draw_legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    entries: &[LegendEntry],
) -> Result<(), String> {
    let (width, height) = area.dim_in_pixel();
    let style = (FONT, 13).into_font().color(&BLACK);
    let row = 20;
    for (i, entry) in entries.iter().enumerate() {
        let y = 16 + row * i as i32;
        if y + row > height as i32 {
            break;
        }
        let c = entry.color;
        let e = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
        match entry.stroke {
            Stroke::Solid => area
                .draw(&PathElement::new(vec![(6, y), (30, y)], c.stroke_width(2)))
                .map_err(e)?,
            Stroke::Dashed => {
                for x in [6, 20] {
                    area.draw(&PathElement::new(
                        vec![(x, y), (x + 8, y)],
                        c.stroke_width(1),
                    ))
                    .map_err(e)?;
                }
            }
            Stroke::Dots => area.draw(&Circle::new((18, y), 2, c.filled())).map_err(e)?,
        }
        // Long labels are cut to the strip.
        let max_chars = (width as usize).saturating_sub(40) / 7;
        let label: String = if entry.label.chars().count() > max_chars {
            let mut s: String = entry
                .label
                .chars()
                .take(max_chars.saturating_sub(1))
                .collect();
            s.push('…');
            s
        } else {
            entry.label.clone()
        };
        area.draw(&Text::new(label, (38, y - 7), style.clone()))
            .map_err(e)?;
    }
    Ok(())
}

/// `area` below its title: the first line of `title` in 18 px, further lines (split at `\n`)
/// in 14 px, each set smaller where it would not fit the width.
pub fn titled<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    title: &str,
) -> Result<DrawingArea<DB, Shift>, String> {
    let mut body = area.clone();
    let (width, _) = area.dim_in_pixel();
    for (i, line) in title.lines().enumerate() {
        let size = if i == 0 { 18.0 } else { 14.0 };
        let wide = area
            .estimate_text_size(line, &TextStyle::from((FONT, size).into_font()))
            .map_err(|e| e.to_string())?
            .0;
        let room = f64::from(width.saturating_sub(16));
        let size = if f64::from(wide) > room {
            (size * room / f64::from(wide)).floor().max(9.0)
        } else {
            size
        };
        body = body.titled(line, (FONT, size)).map_err(|e| e.to_string())?;
    }
    Ok(body)
}

/// The axis ranges of `chart`: the fixed ones, else from the data ([`padded_range`]).
fn ranges(chart: &Chart) -> ((f64, f64), (f64, f64)) {
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
    (xr, yr)
}

/// Draws `chart`: its title across the top, the axes with clean ticks, every series cut at the
/// border of the plotting area, and the labelled series' legend in a strip to the right. Without
/// a font (`text` false) the curves and frame are drawn without any text (and no legend).
/// `raster`: the backend is a bitmap (thick lines drawn without joins, see below).
fn draw<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    chart: &Chart,
    text: bool,
    raster: bool,
) -> Result<Layout, String>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    chart.check()?;
    let (xr, yr) = ranges(chart);
    let entries: Vec<LegendEntry> = chart
        .lines
        .iter()
        .filter(|l| !l.label.is_empty())
        .map(|l| LegendEntry {
            label: l.label.clone(),
            color: palette(l.color),
            stroke: l.stroke,
        })
        .collect();
    let body = if text {
        titled(&root, &chart.title)?
    } else {
        root.clone()
    };
    let legend_shown = text && !entries.is_empty();
    let (plot_side, legend_side) = if legend_shown {
        let (w, _) = body.dim_in_pixel();
        let (a, b) = body.split_horizontally(w.saturating_sub(LEGEND_WIDTH));
        (a, Some(b))
    } else {
        (body, None)
    };
    let mut builder = ChartBuilder::on(&plot_side);
    builder.margin(12);
    if text {
        builder.x_label_area_size(44).y_label_area_size(64);
    }
    let mut ctx = builder
        .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)
        .map_err(|e| e.to_string())?;
    let x_ticks = |v: &f64| tick_label(*v, xr);
    let y_ticks = |v: &f64| tick_label(*v, yr);
    let mut mesh = ctx.configure_mesh();
    mesh.light_line_style(WHITE.mix(0.0));
    if text {
        mesh.x_desc(&chart.x_label)
            .y_desc(&chart.y_label)
            .x_labels(8)
            .y_labels(8)
            .x_label_formatter(&x_ticks)
            .y_label_formatter(&y_ticks)
            .label_style((FONT, 14))
            .axis_desc_style((FONT, 15));
    } else {
        mesh.x_labels(0).y_labels(0);
    }
    mesh.draw().map_err(|e| e.to_string())?;
    for line in &chart.lines {
        let color = palette(line.color);
        match line.stroke {
            Stroke::Solid => {
                for run in clip_polyline(&line.points, xr, yr) {
                    if raster {
                        // Segment by segment: the rasterizer joins a thick polyline's segments
                        // with unlimited miters, whose spikes at a noisy curve's sharp turns
                        // reach far beyond the data (over the title and the ticks).
                        let style = color.stroke_width(2);
                        ctx.draw_series(
                            run.windows(2)
                                .map(|w| PathElement::new(vec![w[0], w[1]], style)),
                        )
                    } else {
                        ctx.draw_series(LineSeries::new(run, color.stroke_width(2)))
                    }
                    .map_err(|e| e.to_string())?;
                }
            }
            Stroke::Dashed => {
                for run in clip_polyline(&line.points, xr, yr) {
                    ctx.draw_series(DashedLineSeries::new(run, 8, 6, color.stroke_width(1)))
                        .map_err(|e| e.to_string())?;
                }
            }
            Stroke::Dots => {
                let dots: Vec<_> = line
                    .points
                    .iter()
                    .filter(|p| inside(**p, xr, yr))
                    .map(|p| Circle::new(*p, 1, color.filled()))
                    .collect();
                ctx.draw_series(dots).map_err(|e| e.to_string())?;
            }
        }
    }
    let plot = ctx.plotting_area().get_pixel_range();
    let legend = match &legend_side {
        Some(area) => {
            draw_legend(area, &entries)?;
            Some(area.get_pixel_range())
        }
        None => None,
    };
    root.present().map_err(|e| e.to_string())?;
    Ok(Layout { plot, legend })
}

impl Layout {
    /// The rectangles that may hold a series' colour: the plotting area and the legend.
    pub fn areas(&self) -> Vec<PixelRect> {
        std::iter::once(self.plot.clone())
            .chain(self.legend.clone())
            .collect()
    }
}

/// The pixels of `pixels` (RGB rows `width` wide) that `is_series` takes for a series' colour
/// and that lie outside every rectangle of `areas` (the plotting areas, legends and colour
/// bars of a drawing): a series leaking over titles, ticks and margins. Each area is widened
/// by one pixel: a stroke two pixels wide ends half its width beyond where it is cut, and a
/// dot of radius one at the border reaches one pixel over. Frames and text are black and
/// greys, so a colour no frame or text uses is a series'.
pub fn stray_pixels(
    pixels: &[u8],
    width: u32,
    areas: &[PixelRect],
    is_series: impl Fn([u8; 3]) -> bool,
) -> Vec<(i32, i32)> {
    let within = |(xs, ys): &PixelRect, x: i32, y: i32| {
        x >= xs.start - 1 && x < xs.end + 1 && y >= ys.start - 1 && y < ys.end + 1
    };
    let mut out = Vec::new();
    for (i, px) in pixels.chunks(3).enumerate() {
        let (x, y) = ((i % width as usize) as i32, (i / width as usize) as i32);
        if areas.iter().any(|a| within(a, x, y)) {
            continue;
        }
        if is_series([px[0], px[1], px[2]]) {
            out.push((x, y));
        }
    }
    out
}

/// A colour that is neither black, white nor a grey (a frame's, a text's antialiasing): one of
/// a series, a colour map's cells or its bar.
pub fn coloured([r, g, b]: [u8; 3]) -> bool {
    r != g || g != b
}

/// The words of an SVG drawing's `<text>` elements (trimmed, the XML escapes undone): what a
/// reader of the figure sees written.
pub fn svg_texts(svg: &str) -> Vec<String> {
    svg.split("<text")
        .skip(1)
        .filter_map(|t| {
            let inner = t.split_once('>')?.1.split_once("</text>")?.0;
            Some(
                inner
                    .trim()
                    .replace("&lt;", "<")
                    .replace("&gt;", ">")
                    .replace("&quot;", "\"")
                    .replace("&apos;", "'")
                    .replace("&amp;", "&"),
            )
        })
        .collect()
}

/// `chart` drawn in memory as RGB pixels of [`SIZE`], with where it put the plotting area and
/// the legend (what [`render`] writes to `<stem>.png`).
pub fn render_pixels(chart: &Chart) -> Result<Drawn<Layout>, String> {
    let text = ensure_font().is_ok();
    let mut pixels = vec![0u8; SIZE.0 as usize * SIZE.1 as usize * 3];
    let layout = draw(
        BitMapBackend::with_buffer(&mut pixels, SIZE).into_drawing_area(),
        chart,
        text,
        true,
    )?;
    Ok((pixels, SIZE, layout))
}

/// The SVG of `chart` as text (what [`render`] writes to `<stem>.svg`), drawn in memory.
pub fn render_svg(chart: &Chart) -> Result<String, String> {
    let text = ensure_font().is_ok();
    let mut svg = String::new();
    draw(
        SVGBackend::with_string(&mut svg, SIZE).into_drawing_area(),
        chart,
        text,
        false,
    )?;
    Ok(svg)
}

/// Size of every chart in pixels.
pub const SIZE: (u32, u32) = (800, 560);

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
    let (pixels, _, _) = render_pixels(chart).map_err(|m| err(&png, m))?;
    save_png(&png, inputs, &pixels, size)?;
    let vector = render_svg(chart).map_err(|m| err(&svg, m))?;
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
        draw(root, &chart(), false, true).unwrap();
        // Something other than white was drawn.
        assert!(buf.iter().any(|&b| b != 255));
    }

    #[test]
    fn every_series_is_clipped_to_the_plotting_area() {
        // Series reaching far beyond fixed axis ranges, one of each stroke, each in a colour of
        // its own that no frame, tick or text uses (those are black and greys).
        let wild = |c: usize, stroke: Stroke| Line {
            label: String::new(),
            points: (0..=40)
                .map(|i| {
                    let x = -3.0 + 0.2 * i as f64;
                    (x, 4.0 * (3.0 * x).sin() + c as f64 * 0.3)
                })
                .collect(),
            stroke,
            color: c,
        };
        let chart = Chart {
            title: "clipping".into(),
            x_label: "t".into(),
            y_label: "log10 GALI_k".into(),
            lines: vec![
                Line {
                    label: "GALI_2".into(),
                    ..wild(1, Stroke::Solid)
                },
                wild(2, Stroke::Dashed),
                wild(3, Stroke::Dots),
                // A noisy curve inside the axes: sharp turns, where joined thick strokes spike.
                Line {
                    label: String::new(),
                    points: {
                        // Deterministic noise (a linear congruential sequence) in [-0.97, 0.97].
                        let mut state = 1u64;
                        (0..1500)
                            .map(|i| {
                                state = state
                                    .wrapping_mul(6364136223846793005)
                                    .wrapping_add(1442695040888963407);
                                let u = (state >> 11) as f64 / (1u64 << 53) as f64;
                                (-0.99 + 0.00132 * i as f64, 0.97 * (2.0 * u - 1.0))
                            })
                            .collect()
                    },
                    stroke: Stroke::Solid,
                    color: 4,
                },
            ],
            x_range: Some((-1.0, 1.0)),
            y_range: Some((-1.0, 1.0)),
        };
        let (pixels, (w, _), layout) = render_pixels(&chart).unwrap();
        let colours = [palette(1), palette(2), palette(3), palette(4)];
        let out = stray_pixels(&pixels, w, &layout.areas(), |p| {
            colours.iter().any(|c| p == [c.0, c.1, c.2])
        });
        assert!(
            out.is_empty(),
            "{} series pixels outside the plotting area {:?}, e.g. {:?}",
            out.len(),
            layout.plot,
            &out[..out.len().min(5)]
        );
        // The series were drawn (inside).
        assert!(
            pixels
                .chunks(3)
                .any(|p| p == [colours[0].0, colours[0].1, colours[0].2])
        );
    }

    #[test]
    fn ticks_are_clean_numbers() {
        for (v, range, text) in [
            (1000.0, (0.0, 2000.0), "1000"),
            (-0.0, (-1.0, 1.0), "0"),
            // A rounding residue of a tick at zero.
            (1.3e-17, (-1.0, 1.0), "0"),
            (0.30000000000000004, (0.0, 1.0), "0.3"),
            (-2.5, (-5.0, 0.0), "-2.5"),
            (12.0, (10.0, 20.0), "12"),
            (250000.0, (0.0, 1e6), "2.5e5"),
            (1e6, (0.0, 1e6), "1e6"),
            (1e-4, (0.0, 5e-4), "1e-4"),
            (-12.0, (-12.5, 0.2), "-12"),
        ] {
            assert_eq!(tick_label(v, range), text, "{v} on {range:?}");
        }
    }

    #[test]
    fn the_svg_carries_the_title_axis_labels_and_legend() {
        if !font_available() {
            // Without a font a chart has no text at all (drawn and said so by `render`).
            return;
        }
        let svg = render_svg(&chart()).unwrap();
        let texts = svg_texts(&svg);
        for want in ["t", "x", "y", "a"] {
            assert!(texts.iter().any(|t| t == want), "{want} not in {texts:?}");
        }
        // Ticks, clean: -3..1 padded, in steps of 0.5 or 1, never "-0" or "1.0".
        assert!(texts.iter().any(|t| t == "0"), "{texts:?}");
        assert!(
            !texts.iter().any(|t| t == "-0" || t.ends_with(".0")),
            "{texts:?}"
        );
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
