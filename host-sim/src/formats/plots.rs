//! PNG figures with plotters. The font (DejaVu Sans, Bitstream Vera license, see
//! `assets/DejaVuSans-LICENSE.txt`) is compiled in, so a machine without system fonts
//! draws the same figures.

use std::path::Path;
use std::sync::Once;

use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::element::DashedPathElement;
use plotters::style::{register_font, FontStyle};

use crate::formats::outputs::Outputs;
use crate::HostError;

static FONT: Once = Once::new();

fn ensure_font() {
    FONT.call_once(|| {
        // The embedded bytes are a valid TTF; a failure here would only lose text.
        let _ = register_font("sans-serif", FontStyle::Normal, include_bytes!("../../assets/DejaVuSans.ttf"));
    });
}

/// One curve of a line plot.
pub struct Series {
    /// Legend label.
    pub label: String,
    /// Points (x, y).
    pub points: Vec<(f64, f64)>,
}

/// Map cells below the color scale (and zero on a log scale): a grey that viridis has not.
const BELOW_SCALE: RGBColor = RGBColor(200, 200, 200);

/// Colors for up to eight series, then repeating.
const COLORS: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
];

fn plot_err(path: &Path, e: impl std::fmt::Display) -> HostError {
    HostError::Format { path: path.to_path_buf(), message: format!("drawing the figure failed: {e}") }
}

/// Tick labels for an axis spanning `lo..hi`: the decimals its tick step needs and no
/// more (`500`, not `500.0`; `0.25`), scientific notation where plain digits would be
/// long (values below 1e-3 or from 1e5 on: `2e-5`, `1.5e6`), and `0` for zero.
pub fn tick_format(lo: f64, hi: f64) -> impl Fn(&f64) -> String {
    let span = (hi - lo).abs();
    let magnitude = lo.abs().max(hi.abs());
    // plotters puts about ten ticks on an axis at round steps; a decimal more than the
    // tenth of the span shows any of them, and trailing zeros are dropped. A single value
    // (`lo == hi`: a label) is shown to a tenth of itself.
    let step = if span > 0.0 && span.is_finite() {
        span / 10.0
    } else if magnitude > 0.0 && magnitude.is_finite() {
        magnitude / 10.0
    } else {
        1.0
    };
    let scientific = magnitude > 0.0 && !(1e-3..1e5).contains(&magnitude);
    let decimals = (1.0 - step.log10().floor()).clamp(0.0, 12.0) as usize;
    let mantissa_digits = ((magnitude / step).log10().ceil() + 1.0).clamp(1.0, 8.0) as usize;
    move |v: &f64| {
        if *v == 0.0 || (v.abs() < step * 1e-9) {
            return "0".into();
        }
        if scientific {
            let text = format!("{:.*e}", mantissa_digits, v);
            let (mantissa, exponent) = text.split_once('e').unwrap_or((&text, "0"));
            format!("{}e{exponent}", trim_zeros(mantissa))
        } else {
            trim_zeros(&format!("{:.*}", decimals, v)).to_string()
        }
    }
}

/// `1.500` -> `1.5`, `500.000` -> `500`, `-0.0` -> `0`.
fn trim_zeros(text: &str) -> &str {
    let t = if text.contains('.') { text.trim_end_matches('0').trim_end_matches('.') } else { text };
    if t == "-0" { "0" } else { t }
}

/// Draws `chart`'s axes: their labels (with units, the caller's) and tick labels
/// formatted for the axis ranges `x` and `y` ([`tick_format`]); grid lines unless `mesh`
/// is false (maps).
fn draw_axes<DB: DrawingBackend>(
    chart: &mut ChartContext<'_, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
    (x_label, x): (&str, std::ops::Range<f64>),
    (y_label, y): (&str, std::ops::Range<f64>),
    font: u32,
    mesh: bool,
    path: &Path,
) -> Result<(), HostError> {
    let (x_ticks, y_ticks) = (tick_format(x.start, x.end), tick_format(y.start, y.end));
    let mut style = chart.configure_mesh();
    if !mesh {
        style.disable_mesh();
    }
    style.x_desc(x_label).y_desc(y_label).x_label_formatter(&x_ticks).y_label_formatter(&y_ticks).label_style(("sans-serif", font)).draw().map_err(|e| plot_err(path, e))
}

/// Width of the legend column right of a line plot's panels, pixels: legends go beside
/// the data, never over it.
const LEGEND_WIDTH: u32 = 250;

/// How a series of a line plot is drawn.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Stroke {
    /// A solid line.
    Line,
    /// Dashes of `dash` pixels `gap` apart, `width` pixels wide.
    Dashed { dash: u32, gap: u32, width: u32 },
    /// A circle at each point, no line: measurements.
    Markers,
    /// A shaded band over an x range (the legend's swatch).
    Band,
}

/// The dashed noise bands of [`dnl_inl_plot`], as their legend shows them.
const NOISE_BAND: Stroke = Stroke::Dashed { dash: 5, gap: 3, width: 2 };

/// The shade of a [`PlotStyle::x_band`]: light enough that lines and markers stay legible.
const BAND: RGBColor = RGBColor(225, 225, 225);

/// Draws a legend entry per `(label, color, stroke)` in `area`, top down; labels wider than
/// the column are wrapped at spaces.
fn draw_legend<DB: DrawingBackend>(area: &DrawingArea<DB, plotters::coord::Shift>, entries: &[(String, RGBColor, Stroke)], path: &Path) -> Result<(), HostError> {
    let font = ("sans-serif", 13).into_font();
    let mut y = 18i32;
    for (label, color, stroke) in entries {
        let style = color.stroke_width(2);
        match *stroke {
            Stroke::Dashed { dash, gap, width } => area.draw(&DashedPathElement::new(vec![(6, y), (30, y)], dash, gap, color.stroke_width(width.max(2)))),
            Stroke::Line => area.draw(&PathElement::new(vec![(6, y), (30, y)], style)),
            Stroke::Markers => area.draw(&Circle::new((18, y), 3, color.filled())),
            Stroke::Band => area.draw(&Rectangle::new([(6, y - 6), (30, y + 6)], BAND.filled())),
        }
        .map_err(|e| plot_err(path, e))?;
        for line in wrap(label, 30) {
            area.draw(&Text::new(line, (36, y - 7), font.clone())).map_err(|e| plot_err(path, e))?;
            y += 16;
        }
        y += 6;
    }
    Ok(())
}

/// `text` in lines of at most about `width` characters, broken at spaces.
fn wrap(text: &str, width: usize) -> Vec<String> {
    let mut lines: Vec<String> = Vec::new();
    for word in text.split(' ') {
        match lines.last_mut() {
            Some(line) if line.len() + 1 + word.len() <= width => {
                line.push(' ');
                line.push_str(word);
            }
            _ => lines.push(word.to_string()),
        }
    }
    lines
}

/// The smallest and largest x and y of the finite `points`, `(x0, x1, y0, y1)`; None
/// when no point is finite.
fn extremes(points: impl Iterator<Item = (f64, f64)>) -> Option<(f64, f64, f64, f64)> {
    let (mut x0, mut x1, mut y0, mut y1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
    for (x, y) in points.filter(|(x, y)| x.is_finite() && y.is_finite()) {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    x0.is_finite().then_some((x0, x1, y0, y1))
}

/// A line plot of `series` (stacked in `panels` vertically when given more than one
/// panel: series `i` goes to panel `i % panels`), staged in `out` as a PNG at `path`.
pub fn line_plot(out: &mut Outputs, path: &Path, title: &str, x_label: &str, y_label: &str, series: &[Series], panels: usize) -> Result<(), HostError> {
    line_plot_paired(out, path, title, x_label, y_label, series, panels, series.len())
}

/// [`line_plot`] where the series from index `dashed_from` on are drawn dashed, in the
/// colors of the first ones (series `dashed_from + i` pairs with series `i`): a quantity
/// and its reference, as the paper's Fig. 8 draws each RMS and its random noise.
#[allow(clippy::too_many_arguments)] // a figure's texts, its data and where it goes
pub fn line_plot_paired(out: &mut Outputs, path: &Path, title: &str, x_label: &str, y_label: &str, series: &[Series], panels: usize, dashed_from: usize) -> Result<(), HostError> {
    line_plot_styled(out, path, title, x_label, y_label, series, &PlotStyle { panels, dashed_from, ..PlotStyle::default() })
}

/// How [`line_plot_styled`] draws its series.
#[derive(Debug, Clone, Default)]
pub struct PlotStyle {
    /// Panels stacked vertically: series `i` goes to panel `i % panels` (0 is taken as 1).
    pub panels: usize,
    /// Series from this index on are references, drawn dashed in the colors of the first
    /// ones ([`line_plot_paired`]); `None` of them when it is at least the series' count
    /// (0 here means none too: [`PlotStyle::default`] has no references).
    pub dashed_from: usize,
    /// Series drawn as markers (measurements), by index.
    pub markers: Vec<usize>,
    /// A shaded x range behind every panel, with its legend label (a fit's range).
    pub x_band: Option<(f64, f64, String)>,
}

/// The dash of reference `k` (0 = the first reference) of `n`: each reference its own
/// pattern, and all but the last drawn wider, so that references that coincide (Fig. 8's
/// random floors of the standard and the pixel-wise correction lie on one curve) stay
/// visible under one another.
pub fn reference_stroke(k: usize, n: usize) -> Stroke {
    const PATTERNS: [(u32, u32); 3] = [(6, 4), (2, 3), (10, 4)];
    let (dash, gap) = PATTERNS[k % PATTERNS.len()];
    Stroke::Dashed { dash, gap, width: if k + 1 < n { 2 } else { 1 } }
}

/// A line plot of `series` drawn as `style` says, staged in `out` as a PNG at `path`: one
/// panel is 480 pixels high (a readable aspect for one curve family), several are 260
/// each.
#[allow(clippy::too_many_arguments)] // a figure's texts, its data and where it goes
pub fn line_plot_styled(out: &mut Outputs, path: &Path, title: &str, x_label: &str, y_label: &str, series: &[Series], style: &PlotStyle) -> Result<(), HostError> {
    ensure_font();
    let panels = style.panels.max(1);
    let dashed_from = if style.dashed_from == 0 { series.len() } else { style.dashed_from };
    let panel_height = if panels == 1 { 480 } else { 260 };
    let (width, height) = (1000u32 + LEGEND_WIDTH, panel_height * panels as u32 + 60);
    let mut rgb = vec![0u8; (width * height * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut rgb, (width, height)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| plot_err(path, e))?;
        let root = root.titled(title, ("sans-serif", 22)).map_err(|e| plot_err(path, e))?;
        for (p, panel) in root.split_evenly((panels, 1)).iter().enumerate() {
            let (area, legend) = panel.split_horizontally(1000);
            let mine: Vec<(usize, &Series)> = series.iter().enumerate().filter(|(i, _)| i % panels == p).collect();
            let Some((x0, x1, y0, y1)) = extremes(mine.iter().flat_map(|(_, s)| s.points.iter().copied())) else {
                continue;
            };
            let pad = ((y1 - y0) * 0.05).max(1e-12);
            let (xr, yr) = (x0..x1.max(x0 + 1e-12), (y0 - pad)..(y1 + pad));
            let mut chart = ChartBuilder::on(&area)
                .margin(8)
                .x_label_area_size(36)
                .y_label_area_size(70)
                .build_cartesian_2d(xr.clone(), yr.clone())
                .map_err(|e| plot_err(path, e))?;
            draw_axes(&mut chart, (x_label, xr.clone()), (y_label, yr.clone()), 14, true, path)?;
            if let Some((a, b, _)) = &style.x_band {
                let (a, b) = (a.max(xr.start), b.min(xr.end));
                if b > a {
                    chart.draw_series(std::iter::once(Rectangle::new([(a, yr.start), (b, yr.end)], BAND.filled()))).map_err(|e| plot_err(path, e))?;
                }
            }
            // References (dashed) first, so that the measured curves are drawn over them;
            // their dashes counted within this panel (the ones that can coincide).
            let panel_refs: Vec<usize> = mine.iter().map(|&(i, _)| i).filter(|&i| i >= dashed_from).collect();
            let color_of = |i: usize| if i >= dashed_from { COLORS[(i - dashed_from) % COLORS.len()] } else { COLORS[i % COLORS.len()] };
            let stroke_of = |i: usize| match () {
                _ if i >= dashed_from => reference_stroke(panel_refs.iter().position(|&r| r == i).unwrap_or(0), panel_refs.len()),
                _ if style.markers.contains(&i) => Stroke::Markers,
                _ => Stroke::Line,
            };
            for &(i, s) in mine.iter().filter(|(i, _)| *i >= dashed_from).chain(mine.iter().filter(|(i, _)| *i < dashed_from)) {
                let points = s.points.iter().copied().filter(|(x, y)| x.is_finite() && y.is_finite());
                let color = color_of(i);
                match stroke_of(i) {
                    Stroke::Dashed { dash, gap, width } => chart.draw_series(DashedLineSeries::new(points, dash, gap, color.stroke_width(width))).map(|_| ()),
                    Stroke::Markers => chart.draw_series(points.map(|p| Circle::new(p, 3, color.filled()))).map(|_| ()),
                    Stroke::Line | Stroke::Band => chart.draw_series(LineSeries::new(points, color.stroke_width(1))).map(|_| ()),
                }
                .map_err(|e| plot_err(path, e))?;
            }
            let mut entries: Vec<(String, RGBColor, Stroke)> = mine.iter().map(|&(i, s)| (s.label.clone(), color_of(i), stroke_of(i))).collect();
            if let Some((_, _, label)) = &style.x_band {
                entries.push((label.clone(), BAND, Stroke::Band));
            }
            draw_legend(&legend, &entries, path)?;
        }
        root.present().map_err(|e| plot_err(path, e))?;
    }
    write_png(out, path, &rgb, width, height)
}

/// One panel of [`level_lines_plot`]: its caption and one line (points (x, y)) per level.
pub type LevelPanel = (String, Vec<Vec<(f64, f64)>>);

/// Panels side by side, each with one line per illumination level (`lines[level]`, points
/// (x, y); NaN breaks a line), colored from dark (viridis purple) to bright (yellow): the
/// paper's Fig. 7. The shared y range is `y_range`.
pub fn level_lines_plot(out: &mut Outputs, path: &Path, title: &str, x_label: &str, y_label: &str, panels: &[LevelPanel], y_range: (f64, f64)) -> Result<(), HostError> {
    use plotters::style::colors::colormaps::{ColorMap, ViridisRGB};
    ensure_font();
    if panels.is_empty() || y_range.1.partial_cmp(&y_range.0) != Some(std::cmp::Ordering::Greater) {
        return Err(plot_err(path, "need at least one panel and a y range"));
    }
    let (width, height) = (520 * panels.len() as u32, 560u32);
    let mut rgb = vec![0u8; (width * height * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut rgb, (width, height)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| plot_err(path, e))?;
        let root = root.titled(title, ("sans-serif", 20)).map_err(|e| plot_err(path, e))?;
        for ((name, lines), area) in panels.iter().zip(root.split_evenly((1, panels.len())).iter()) {
            let xs = lines.iter().flatten().map(|p| p.0).filter(|x| x.is_finite());
            let (x0, x1) = xs.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| (a.min(x), b.max(x)));
            if !x0.is_finite() {
                continue;
            }
            let (xr, yr) = (x0..x1.max(x0 + 1e-12), y_range.0..y_range.1);
            let mut chart = ChartBuilder::on(area)
                .caption(name, ("sans-serif", 16))
                .margin(8)
                .x_label_area_size(36)
                .y_label_area_size(60)
                .build_cartesian_2d(xr.clone(), yr.clone())
                .map_err(|e| plot_err(path, e))?;
            draw_axes(&mut chart, (x_label, xr), (y_label, yr), 13, true, path)?;
            let n = lines.len().max(2);
            for (l, line) in lines.iter().enumerate() {
                let color = ViridisRGB.get_color(l as f32 / (n - 1) as f32);
                // Split at NaN so saturated or masked pixels interrupt the line, and where it
                // leaves the y range (drawn along the border it would look like data there).
                let shown = |p: &(f64, f64)| p.0.is_finite() && p.1.is_finite() && (y_range.0..=y_range.1).contains(&p.1);
                for run in line.split(|p| !shown(p)).filter(|r| !r.is_empty()) {
                    chart.draw_series(LineSeries::new(run.iter().copied(), color.stroke_width(1))).map_err(|e| plot_err(path, e))?;
                }
            }
        }
        root.present().map_err(|e| plot_err(path, e))?;
    }
    write_png(out, path, &rgb, width, height)
}

/// A color map of a grid of values with contour lines, for maps such as the paper's
/// Fig. 1 and Fig. 4.
pub struct Map<'a> {
    /// Figure title.
    pub title: &'a str,
    /// Axis labels.
    pub x_label: &'a str,
    /// Axis labels.
    pub y_label: &'a str,
    /// `values[i][j]` at `y = y_range.0 + (y_range.1 - y_range.0) i / (rows - 1)` and `x`
    /// likewise with `j`: rows along y.
    pub values: &'a [Vec<f64>],
    /// x of the first and last column.
    pub x_range: (f64, f64),
    /// y of the first and last row.
    pub y_range: (f64, f64),
    /// Color scale label.
    pub scale_label: &'a str,
    /// Color the values' log10 (non-positive values take the lowest color).
    pub log: bool,
    /// Contour levels, in the values' units (not log).
    pub contours: &'a [f64],
    /// Fixed color scale (values' units; values outside take the end colors); `None`
    /// spans the data.
    pub range: Option<(f64, f64)>,
}

/// Segments where the bilinear grid `v` (rows along y) crosses `level`: marching
/// squares, in grid coordinates (column, row). Saddle cells join the crossings in order.
pub fn contour_segments(v: &[Vec<f64>], level: f64) -> Vec<[(f64, f64); 2]> {
    let mut out = Vec::new();
    for i in 0..v.len().saturating_sub(1) {
        for j in 0..v[i].len().saturating_sub(1).min(v[i + 1].len().saturating_sub(1)) {
            // Corners counter-clockwise from (j, i).
            let c = [(j, i, v[i][j]), (j + 1, i, v[i][j + 1]), (j + 1, i + 1, v[i + 1][j + 1]), (j, i + 1, v[i + 1][j])];
            let mut pts = Vec::with_capacity(4);
            for e in 0..4 {
                let (x0, y0, a) = c[e];
                let (x1, y1, b) = c[(e + 1) % 4];
                if !(a.is_finite() && b.is_finite()) {
                    continue;
                }
                if (a < level) != (b < level) {
                    let t = (level - a) / (b - a);
                    pts.push((x0 as f64 + t * (x1 as f64 - x0 as f64), y0 as f64 + t * (y1 as f64 - y0 as f64)));
                }
            }
            for pair in pts.chunks_exact(2) {
                out.push([pair[0], pair[1]]);
            }
        }
    }
    out
}

/// The values between `level`'s neighbours among `contours` (open at each end that has
/// no neighbour): where a label of `level` can stand without covering another contour.
pub fn contour_band(contours: &[f64], level: f64) -> (f64, f64) {
    let below = contours.iter().copied().filter(|&c| c < level).fold(f64::NEG_INFINITY, f64::max);
    let above = contours.iter().copied().filter(|&c| c > level).fold(f64::INFINITY, f64::min);
    (below, above)
}

/// Whether a label box centred at grid point `at` (column, row), `half` cells either side,
/// lies on cells that are all drawn (`drawn`) and all strictly inside `band`: every cell
/// the box touches, all inside the grid (a one-cell line of another value, such as the
/// K-Cor maps' Q = 0 row, is never skipped).
pub fn label_fits(values: &[Vec<f64>], at: (f64, f64), half: (f64, f64), (lo, hi): (f64, f64), drawn: impl Fn(f64) -> bool) -> bool {
    // Cell (c, r) covers c - 1/2 .. c + 1/2 (and r likewise): the box touches it when the
    // intervals overlap.
    let span = |centre: f64, half: f64| ((centre - half + 0.5).floor() as i64, (centre + half - 0.5).ceil() as i64);
    let ((c0, c1), (r0, r1)) = (span(at.0, half.0), span(at.1, half.1));
    if c0 < 0 || r0 < 0 || r1 as usize >= values.len() {
        return false;
    }
    (r0..=r1).all(|r| {
        let row = &values[r as usize];
        (c1 as usize) < row.len() && (c0..=c1).all(|c| {
            let x = row[c as usize];
            drawn(x) && x > lo && x < hi
        })
    })
}

/// How a map's cell is drawn.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shade {
    /// No value (NaN): white.
    Missing,
    /// Below the scale: grey. On a log scale only zero and negative values (they have no
    /// logarithm); a positive value below the scale's bottom is drawn at the bottom
    /// (its magnitude is never hidden as "none").
    Below,
    /// The colour at this fraction of the scale, 0 to 1.
    Scale(f64),
}

/// The scale of `map` as drawn, in its units (log10 of them on a log scale): its range,
/// or the values' (on a log scale at most six decades below the top).
pub fn map_scale(map: &Map) -> (f64, f64) {
    let t = |x: f64| if map.log { if x > 0.0 { x.log10() } else { f64::NEG_INFINITY } } else { x };
    let finite: Vec<f64> = map.values.iter().flatten().map(|&x| t(x)).filter(|x| x.is_finite()).collect();
    let (mut lo, hi) = finite.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
    if map.log {
        // Keep six decades below the top: the rest is "negligible".
        lo = lo.max(hi - 6.0);
    }
    let (lo, hi) = match map.range {
        Some((a, b)) if t(a).is_finite() && t(b) > t(a) => (t(a), t(b)),
        _ => (lo, hi),
    };
    span_of(lo, hi)
}

/// `(lo, hi)` as a scale a color can be read from: both finite and `hi > lo` (a constant
/// or huge map has no width of its own: one unit, or enough above `lo` that `hi` differs
/// from it at f64 precision; a map without a finite value gets 0 to 1).
fn span_of(lo: f64, hi: f64) -> (f64, f64) {
    if !(lo.is_finite() && hi.is_finite()) {
        return (0.0, 1.0);
    }
    if hi > lo && (hi - lo).is_finite() {
        return (lo, hi);
    }
    let width = 1f64.max(lo.abs() * 1e-9);
    if (lo + width).is_finite() { (lo, lo + width) } else { (lo - width, lo) }
}

/// How value `x` of `map` is drawn on the scale `(lo, hi)` ([`map_scale`]).
pub fn shade(map: &Map, (lo, hi): (f64, f64), x: f64) -> Shade {
    if x.is_nan() {
        return Shade::Missing;
    }
    let v = if map.log {
        if x > 0.0 {
            x.log10().max(lo)
        } else {
            return Shade::Below;
        }
    } else {
        x
    };
    let f = (v - lo) / (hi - lo);
    match () {
        _ if v < lo => Shade::Below,
        // (A scale not from [`map_scale`] may still be empty: no color to read.)
        _ if f.is_nan() => Shade::Missing,
        _ => Shade::Scale(f.clamp(0.0, 1.0)),
    }
}

/// Draws `map` as a PNG at `path`, staged in `out`: cells colored by value (viridis), contour
/// lines in white, a color bar. About 120 lines of plotters calls in drawing order (the
/// cells, the contours, the bar and its labels), which share the layout's coordinates.
pub fn map_plot(out: &mut Outputs, path: &Path, map: &Map) -> Result<(), HostError> {
    use plotters::style::colors::colormaps::{ColorMap, ViridisRGB};
    ensure_font();
    let rows = map.values.len();
    let cols = map.values.first().map_or(0, Vec::len);
    if rows < 2 || cols < 2 {
        return Err(plot_err(path, "a map needs at least 2 x 2 values"));
    }
    let (lo, hi) = map_scale(map);
    let (width, height) = (1000u32, 760u32);
    let mut rgb = vec![0u8; (width * height * 3) as usize];
    {
        // `full` is drawn on in the bitmap's own pixels (the contour labels).
        let full = BitMapBackend::with_buffer(&mut rgb, (width, height)).into_drawing_area();
        full.fill(&WHITE).map_err(|e| plot_err(path, e))?;
        let root = full.titled(map.title, ("sans-serif", 22)).map_err(|e| plot_err(path, e))?;
        let (main, bar) = root.split_horizontally(840);
        let (x0, x1) = map.x_range;
        let (y0, y1) = map.y_range;
        let dx = (x1 - x0) / (cols - 1) as f64;
        let dy = (y1 - y0) / (rows - 1) as f64;
        let (xr, yr) = ((x0 - dx / 2.0)..(x1 + dx / 2.0), (y0 - dy / 2.0)..(y1 + dy / 2.0));
        let mut chart = ChartBuilder::on(&main)
            .margin(10)
            .x_label_area_size(44)
            .y_label_area_size(70)
            .build_cartesian_2d(xr.clone(), yr.clone())
            .map_err(|e| plot_err(path, e))?;
        draw_axes(&mut chart, (map.x_label, xr), (map.y_label, yr), 15, false, path)?;
        // See [`Shade`]: no value in white, below the scale in grey, neither may pass for
        // the scale's bottom.
        let color = |x: f64| -> RGBColor {
            match shade(map, (lo, hi), x) {
                Shade::Missing => WHITE,
                Shade::Below => BELOW_SCALE,
                Shade::Scale(f) => ViridisRGB.get_color(f as f32),
            }
        };
        chart
            .draw_series(map.values.iter().enumerate().flat_map(|(i, row)| {
                row.iter().enumerate().map(move |(j, &v)| {
                    let (cx, cy) = (x0 + j as f64 * dx, y0 + i as f64 * dy);
                    Rectangle::new([(cx - dx / 2.0, cy - dy / 2.0), (cx + dx / 2.0, cy + dy / 2.0)], color(v).filled())
                })
            }))
            .map_err(|e| plot_err(path, e))?;
        // Contours in white; each labelled once, in a box, the labels spread across the
        // map (contour k of n near x = (k + 1) / (n + 1) of its width) and moved along
        // their line where one would cover another.
        let mut placed: Vec<(i32, i32, i32, i32)> = Vec::new();
        let n_levels = map.contours.len();
        for (k, &level) in map.contours.iter().enumerate() {
            let segs = contour_segments(map.values, level);
            chart
                .draw_series(segs.iter().map(|[a, b]| PathElement::new(vec![(x0 + a.0 * dx, y0 + a.1 * dy), (x0 + b.0 * dx, y0 + b.1 * dy)], WHITE.stroke_width(2))))
                .map_err(|e| plot_err(path, e))?;
            let label = tick_format(level, level)(&level);
            let target = (k + 1) as f64 / (n_levels + 1) as f64 * (cols - 1) as f64;
            let mut candidates: Vec<(f64, f64)> = segs.iter().map(|[a, _]| *a).collect();
            candidates.sort_by(|a, b| (a.0 - target).abs().total_cmp(&(b.0 - target).abs()));
            let (w, h) = (8 * label.len() as i32 + 8, 20);
            // The box's half size in cells, from the chart's pixels per cell.
            let (p0, p1) = (chart.backend_coord(&(x0, y0)), chart.backend_coord(&(x0 + dx, y0 + dy)));
            let half = (f64::from(w) / 2.0 / f64::from((p1.0 - p0.0).abs().max(1)), f64::from(h) / 2.0 / f64::from((p1.1 - p0.1).abs().max(1)));
            let band = contour_band(map.contours, level);
            let drawn = |v: f64| matches!(shade(map, (lo, hi), v), Shade::Scale(_));
            let free = |(px, py): (i32, i32)| {
                let b = (px - w / 2, py - h / 2, px + w / 2, py + h / 2);
                !placed.iter().any(|p| b.0 < p.2 && p.0 < b.2 && b.1 < p.3 && p.1 < b.3)
            };
            // Where it can, a label sits on its own band of values (never across another
            // contour, on missing cells or over the map's edge); else where it is free.
            let on_own_band = candidates.iter().find(|&&at| label_fits(map.values, at, half, band, drawn) && free(chart.backend_coord(&(x0 + at.0 * dx, y0 + at.1 * dy))));
            let spot = on_own_band
                .map(|&(cx, cy)| chart.backend_coord(&(x0 + cx * dx, y0 + cy * dy)))
                .or_else(|| candidates.iter().map(|&(cx, cy)| chart.backend_coord(&(x0 + cx * dx, y0 + cy * dy))).find(|&p| free(p)));
            if let Some((px, py)) = spot {
                let b = (px - w / 2, py - h / 2, px + w / 2, py + h / 2);
                placed.push(b);
                full.draw(&Rectangle::new([(b.0, b.1), (b.2, b.3)], WHITE.mix(0.85).filled())).map_err(|e| plot_err(path, e))?;
                full.draw(&Text::new(label, (b.0 + 4, b.1 + 3), ("sans-serif", 14).into_font())).map_err(|e| plot_err(path, e))?;
            }
        }
        // Color bar, labelled in the values' units (on a log scale, the values, not their
        // log10), with a swatch for what lies below it.
        let (bar, below) = bar.split_vertically(height as i32 - 110);
        let bar_ticks = tick_format(if map.log { 10f64.powf(lo) } else { lo }, if map.log { 10f64.powf(hi) } else { hi });
        let bar_label = |v: &f64| if map.log { tick_format(10f64.powf(*v), 10f64.powf(*v))(&10f64.powf(*v)) } else { bar_ticks(v) };
        let mut cb = ChartBuilder::on(&bar)
            .margin_top(10)
            .margin_bottom(10)
            .margin_right(10)
            .y_label_area_size(80)
            .build_cartesian_2d(0.0..1.0, lo..hi)
            .map_err(|e| plot_err(path, e))?;
        cb.configure_mesh()
            .disable_mesh()
            .disable_x_axis()
            .y_desc(map.scale_label)
            .y_label_formatter(&bar_label)
            .label_style(("sans-serif", 13))
            .draw()
            .map_err(|e| plot_err(path, e))?;
        let n = 200;
        cb.draw_series((0..n).map(|k| {
            let a = lo + (hi - lo) * k as f64 / n as f64;
            let b = lo + (hi - lo) * (k + 1) as f64 / n as f64;
            Rectangle::new([(0.0, a), (1.0, b)], ViridisRGB.get_color(k as f32 / n as f32).filled())
        }))
        .map_err(|e| plot_err(path, e))?;
        let bottom = if map.log { "zero or less" } else { "below" };
        below.draw(&Rectangle::new([(90, 8), (150, 30)], BELOW_SCALE.filled())).map_err(|e| plot_err(path, e))?;
        below.draw(&Text::new(bottom, (90, 36), ("sans-serif", 13).into_font())).map_err(|e| plot_err(path, e))?;
        full.present().map_err(|e| plot_err(path, e))?;
    }
    write_png(out, path, &rgb, width, height)
}

/// Marked codes of a [`dnl_inl_plot`]: (code, value, label) per kind.
pub struct MarkedCodes {
    /// Named wide or narrow codes: red circles with their number.
    pub named: Vec<(f64, f64, String)>,
    /// Missing codes: black crosses at DNL -1 with their number.
    pub missing: Vec<(f64, f64, String)>,
}

/// The IEEE 1241 figure of one ADC: DNL per code (top, with its 3-sigma noise band
/// dashed) and end-point and best-fit INL per transition (bottom), the named codes circled
/// in red and the missing ones crossed in black, each with its number (up to 12 labels a
/// kind), staged in `out` as a PNG at `path`.
#[allow(clippy::too_many_arguments)] // a figure's title, its data and where it goes
pub fn dnl_inl_plot(out: &mut Outputs, path: &Path, title: &str, dnl: &Series, noise: &[Series; 2], inl: &[Series; 2], inl_noise: &[Series; 2], marks: &MarkedCodes) -> Result<(), HostError> {
    ensure_font();
    let (width, height) = (1000u32 + LEGEND_WIDTH, 2 * 300 + 60);
    let mut rgb = vec![0u8; (width * height * 3) as usize];
    let finite = |s: &Series| s.points.iter().copied().filter(|(x, y)| x.is_finite() && y.is_finite()).collect::<Vec<_>>();
    {
        let root = BitMapBackend::with_buffer(&mut rgb, (width, height)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| plot_err(path, e))?;
        let root = root.titled(title, ("sans-serif", 22)).map_err(|e| plot_err(path, e))?;
        let panels = root.split_evenly((2, 1));
        let range = |sets: &[&[(f64, f64)]]| match extremes(sets.iter().flat_map(|s| s.iter().copied())) {
            None => (0.0..1.0, -1.0..1.0),
            Some((x0, x1, y0, y1)) => {
                let pad = ((y1 - y0) * 0.08).max(1e-3);
                (x0..x1.max(x0 + 1.0), (y0 - pad)..(y1 + pad))
            }
        };
        let marked = |v: &[(f64, f64, String)]| v.iter().map(|(x, y, _)| (*x, *y)).collect::<Vec<_>>();
        // Top: DNL, its noise band, the marks.
        let (d, lo, hi) = (finite(dnl), finite(&noise[0]), finite(&noise[1]));
        let (named, missing) = (marked(&marks.named), marked(&marks.missing));
        let (xr, yr) = range(&[&d, &lo, &hi, &named, &missing]);
        let (area, legend) = panels[0].split_horizontally(1000);
        let mut chart = ChartBuilder::on(&area).margin(8).x_label_area_size(36).y_label_area_size(70).build_cartesian_2d(xr.clone(), yr.clone()).map_err(|e| plot_err(path, e))?;
        draw_axes(&mut chart, ("code", xr), ("DNL (LSB)", yr), 14, true, path)?;
        for band in [&lo, &hi] {
            chart.draw_series(DashedLineSeries::new(band.iter().copied(), 6, 4, COLORS[7].stroke_width(1))).map_err(|e| plot_err(path, e))?;
        }
        chart.draw_series(LineSeries::new(d.iter().copied(), COLORS[0].stroke_width(1))).map_err(|e| plot_err(path, e))?;
        let red = RGBColor(214, 39, 40);
        let label_font = ("sans-serif", 13).into_font();
        for (x, y, _) in &marks.named {
            chart.draw_series(std::iter::once(Circle::new((*x, *y), 6, red.stroke_width(2)))).map_err(|e| plot_err(path, e))?;
        }
        // Labels beside their marks, not on them.
        let label_at = |x: f64, y: f64, text: &str, color: RGBColor| EmptyElement::at((x, y)) + Text::new(text.to_string(), (9, -6), label_font.clone().color(&color));
        for (x, y, label) in marks.named.iter().take(12) {
            chart.draw_series(std::iter::once(label_at(*x, *y, label, red))).map_err(|e| plot_err(path, e))?;
        }
        for (x, y, _) in &marks.missing {
            chart.draw_series(std::iter::once(Cross::new((*x, *y), 7, BLACK.stroke_width(2)))).map_err(|e| plot_err(path, e))?;
        }
        for (x, y, label) in marks.missing.iter().take(12) {
            chart.draw_series(std::iter::once(label_at(*x, *y, label, BLACK))).map_err(|e| plot_err(path, e))?;
        }
        let entries = vec![
            (dnl.label.clone(), COLORS[0], Stroke::Line),
            (noise[0].label.clone(), COLORS[7], NOISE_BAND),
            (format!("named codes ({})", marks.named.len()), red, Stroke::Line),
            (format!("missing codes ({}), crossed", marks.missing.len()), BLACK, Stroke::Line),
        ];
        draw_legend(&legend, &entries, path)?;
        // Bottom: INL end-point and best-fit.
        let (a, b) = (finite(&inl[0]), finite(&inl[1]));
        let (na, nb) = (finite(&inl_noise[0]), finite(&inl_noise[1]));
        let (xr, yr) = range(&[&a, &b, &na, &nb]);
        let (area, legend) = panels[1].split_horizontally(1000);
        let mut chart = ChartBuilder::on(&area).margin(8).x_label_area_size(36).y_label_area_size(70).build_cartesian_2d(xr.clone(), yr.clone()).map_err(|e| plot_err(path, e))?;
        draw_axes(&mut chart, ("transition into code", xr), ("INL (LSB)", yr), 14, true, path)?;
        for band in [&na, &nb] {
            chart.draw_series(DashedLineSeries::new(band.iter().copied(), 6, 4, COLORS[7].stroke_width(1))).map_err(|e| plot_err(path, e))?;
        }
        chart.draw_series(LineSeries::new(a.iter().copied(), COLORS[1].stroke_width(1))).map_err(|e| plot_err(path, e))?;
        chart.draw_series(LineSeries::new(b.iter().copied(), COLORS[2].stroke_width(1))).map_err(|e| plot_err(path, e))?;
        draw_legend(&legend, &[(inl[0].label.clone(), COLORS[1], Stroke::Line), (inl[1].label.clone(), COLORS[2], Stroke::Line), (inl_noise[0].label.clone(), COLORS[7], NOISE_BAND)], path)?;
        root.present().map_err(|e| plot_err(path, e))?;
    }
    write_png(out, path, &rgb, width, height)
}

/// Encodes 8-bit RGB pixels as a PNG at `path`, staged in `out`.
pub fn write_png(out: &mut Outputs, path: &Path, rgb: &[u8], width: u32, height: u32) -> Result<(), HostError> {
    let mut bytes = Vec::new();
    {
        let mut encoder = png::Encoder::new(&mut bytes, width, height);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        let mut writer = encoder.write_header().map_err(|e| plot_err(path, e))?;
        writer.write_image_data(rgb).map_err(|e| plot_err(path, e))?;
    }
    out.write_bytes(path, &bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_show_the_digits_their_step_needs() {
        let f = tick_format(0.0, 4095.0);
        assert_eq!([f(&500.0), f(&0.0), f(&4000.0)], ["500", "0", "4000"]);
        let f = tick_format(0.6, 1.4);
        assert_eq!([f(&0.7), f(&1.0), f(&1.25)], ["0.7", "1", "1.25"]);
        // Small and large values in scientific notation, the mantissa trimmed.
        let f = tick_format(-6.5e-5, 6.5e-5);
        assert_eq!([f(&2e-5), f(&-4e-5), f(&1.5e-5), f(&0.0)], ["2e-5", "-4e-5", "1.5e-5", "0"]);
        let f = tick_format(0.0, 3e6);
        assert_eq!([f(&5e5), f(&2.5e6)], ["5e5", "2.5e6"]);
        // One value (a contour's label): itself, not rounded to zero.
        assert_eq!(tick_format(1e-10, 1e-10)(&1e-10), "1e-10");
        assert_eq!(tick_format(3.2e-9, 3.2e-9)(&3.2e-9), "3.2e-9");
        assert_eq!(tick_format(0.05, 0.05)(&0.05), "0.05");
        // Float noise of a tick (0.1 + 0.2) does not show.
        assert_eq!(tick_format(0.0, 1.0)(&(0.1 + 0.2)), "0.3");
    }

    #[test]
    fn legend_labels_wrap_at_spaces() {
        assert_eq!(wrap("ADC 0: baseline (linear pixels): RMS over pixels", 30), ["ADC 0: baseline (linear", "pixels): RMS over pixels"]);
        assert_eq!(wrap("short", 30), ["short"]);
    }

    #[test]
    fn contours_of_a_plane_lie_on_the_level_line() {
        // v = x + 2 y is bilinear, so the crossings are exact: x + 2 y = level.
        let v: Vec<Vec<f64>> = (0..12).map(|i| (0..15).map(|j| j as f64 + 2.0 * i as f64).collect()).collect();
        for level in [3.5, 10.0, 17.25] {
            let segs = contour_segments(&v, level);
            assert!(!segs.is_empty());
            for p in segs.iter().flatten() {
                assert!((p.0 + 2.0 * p.1 - level).abs() < 1e-12, "{p:?}");
            }
            // The line crosses from x = level - 2 y: its length inside the grid, summed.
            let length: f64 = segs.iter().map(|[a, b]| ((a.0 - b.0).powi(2) + (a.1 - b.1).powi(2)).sqrt()).sum();
            let ys = (0.0f64.max((level - 14.0) / 2.0), 11.0f64.min(level / 2.0));
            let want = (ys.1 - ys.0) * 5f64.sqrt();
            assert!((length - want).abs() < 1e-9, "level {level}: {length} vs {want}");
        }
        assert!(contour_segments(&v, -1.0).is_empty());
    }

    #[test]
    fn map_plot_writes_a_png_and_rejects_a_degenerate_grid() {
        let dir = tempfile::tempdir().unwrap();
        let values = vec![vec![1.0, 0.1], vec![0.01, 0.001]];
        let map = Map { title: "t", x_label: "x", y_label: "y", values: &values, x_range: (0.0, 1.0), y_range: (0.0, 1.0), scale_label: "s", log: true, contours: &[0.05], range: None };
        let path = dir.path().join("m.png");
        crate::formats::outputs::write_one(|out| map_plot(out, &path, &map)).unwrap();
        assert_eq!(&std::fs::read(&path).unwrap()[..4], b"\x89PNG");
        let one = vec![vec![1.0]];
        assert!(crate::formats::outputs::write_one(|out| map_plot(out, &dir.path().join("n.png"), &Map { values: &one, ..map })).is_err());
        assert!(!dir.path().join("n.png").exists());
    }

    /// Issue 43's panic: a flat of means near -9.3e18 gave the scale `med +- 10`, which
    /// is one value at f64 precision, and the color map unwrapped a NaN. Any values, any
    /// asked range: a PNG, never a panic; a scale always finite and rising.
    #[test]
    fn a_map_of_huge_constant_or_missing_values_is_drawn_without_a_panic() {
        let dir = tempfile::tempdir().unwrap();
        let huge = vec![vec![-2.27e17, -2.27e17], vec![-2.27e17, -2.27e17 + 1e3]];
        let all_nan = vec![vec![f64::NAN; 2]; 2];
        let infinite = vec![vec![f64::INFINITY, f64::NEG_INFINITY], vec![f64::MAX, -f64::MAX]];
        for (k, (values, range, log)) in [
            (&huge, Some((-2.27e17 - 10.0, -2.27e17 + 10.0)), false),
            (&huge, None, false),
            (&all_nan, None, true),
            (&all_nan, Some((0.0, 0.0)), false),
            (&infinite, None, false),
            (&infinite, None, true),
        ]
        .into_iter()
        .enumerate()
        {
            let map = Map { title: "t", x_label: "x", y_label: "y", values, x_range: (0.0, 1.0), y_range: (0.0, 1.0), scale_label: "s", log, contours: &[], range };
            let (lo, hi) = map_scale(&map);
            assert!(lo.is_finite() && hi.is_finite() && hi > lo, "case {k}: scale {lo} to {hi}");
            let path = dir.path().join(format!("m{k}.png"));
            crate::formats::outputs::write_one(|out| map_plot(out, &path, &map)).unwrap();
            assert_eq!(&std::fs::read(&path).unwrap()[..4], b"\x89PNG");
        }
    }

    /// A label box may stand where every sampled cell is drawn and between the level's
    /// neighbouring contours; not across another contour, on a missing cell or over the edge.
    #[test]
    fn a_contour_label_stands_only_on_its_own_band() {
        // Values rise with the column: 0, 1, ..., 9 in every row.
        let values: Vec<Vec<f64>> = (0..6).map(|_| (0..10).map(f64::from).collect()).collect();
        let band = contour_band(&[2.5, 5.5, 8.5], 5.5);
        assert_eq!(band, (2.5, 8.5));
        let all = |_: f64| true;
        assert!(label_fits(&values, (5.0, 2.5), (2.0, 1.0), band, all), "columns 3..7 lie within 2.5..8.5");
        assert!(!label_fits(&values, (5.0, 2.5), (3.0, 1.0), band, all), "columns 2..8 cross 2.5");
        assert!(!label_fits(&values, (5.0, 0.2), (1.0, 1.0), band, all), "the box reaches below row 0's edge at -0.5");
        assert!(!label_fits(&values, (5.0, 2.5), (1.0, 1.0), band, |v| v != 6.0), "a cell not drawn");
        // One row of zeros (not drawn) inside a tall box: never skipped between samples.
        let mut lined = values.clone();
        lined[2] = vec![0.0; 10];
        assert!(!label_fits(&lined, (5.0, 3.0), (1.0, 1.6), band, |v| v != 0.0));
        assert!(label_fits(&lined, (5.0, 4.0), (1.0, 1.0), band, |v| v != 0.0), "rows 3..5 only");
        assert_eq!(contour_band(&[1e-10, 1e-9, 1e-8], 1e-10), (f64::NEG_INFINITY, 1e-9));
    }

    /// Fig. 8's two random floors coincide: the first one drawn (under the second) must
    /// still show. Pixels of each reference's colour, read back from the PNG, with both
    /// references on one curve against each drawn alone: the one beneath keeps at least
    /// a third of its pixels.
    #[test]
    fn coinciding_references_stay_visible() {
        let dir = tempfile::tempdir().unwrap();
        let line = |y0: f64, slope: f64| Series { label: "s".into(), points: (0..40).map(|i| (f64::from(i) / 39.0, y0 + slope * f64::from(i) / 39.0)).collect() };
        // As Fig. 8: three references, the last two (the standard's and the pixel-wise
        // random floors) on one curve, against the same three lines apart (same slope, same
        // axes: measured series 0 holds the y range). Measured series 1 and 2 have no
        // points, so colours 1 and 2 in the plot are their references' alone.
        let empty = |label: &str| Series { label: label.into(), points: Vec::new() };
        let range = Series { label: "m0".into(), points: vec![(0.0, -3.95), (1.0, -2.95)] };
        let apart = [range, empty("m1"), empty("m2"), line(-3.9, 0.2), line(-3.5, 0.2), line(-3.2, 0.2)];
        let range = Series { label: "m0".into(), points: vec![(0.0, -3.95), (1.0, -2.95)] };
        let on_one_curve = [range, empty("m1"), empty("m2"), line(-3.9, 0.2), line(-3.5, 0.2), line(-3.5, 0.2)];
        let count = |series: &[Series], color: RGBColor| -> usize {
            let path = dir.path().join("f.png");
            crate::formats::outputs::write_one(|out| line_plot_paired(out, &path, "t", "x", "y", series, 1, 3)).unwrap();
            let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&path).unwrap()));
            let mut reader = decoder.read_info().unwrap();
            let mut buf = vec![0; reader.output_buffer_size()];
            let info = reader.next_frame(&mut buf).unwrap();
            // The plotting area only (left of the legend column).
            let w = info.width as usize;
            buf[..info.buffer_size()].chunks(3).enumerate().filter(|(i, p)| i % w < 1000 && p[0] == color.0 && p[1] == color.1 && p[2] == color.2).count()
        };
        let beneath_alone = count(&apart, COLORS[1]);
        let beneath_under = count(&on_one_curve, COLORS[1]);
        assert!(beneath_alone > 100, "{beneath_alone}");
        assert!(beneath_under * 3 >= beneath_alone, "the reference beneath: {beneath_under} pixels of {beneath_alone}");
        assert!(count(&on_one_curve, COLORS[2]) * 3 >= count(&apart, COLORS[2]), "the reference on top");
    }

    #[test]
    fn level_lines_plot_breaks_lines_at_nan_and_rejects_no_panels() {
        let dir = tempfile::tempdir().unwrap();
        let line = |l: usize| (0..10).map(|i| (i as f64, if i == 4 { f64::NAN } else { 1.0 + 0.001 * l as f64 })).collect::<Vec<_>>();
        let panel = ("p".to_string(), (0..5).map(line).collect::<Vec<_>>());
        let path = dir.path().join("l.png");
        crate::formats::outputs::write_one(|out| level_lines_plot(out, &path, "t", "x", "y", &[panel.clone(), panel], (0.99, 1.01))).unwrap();
        assert_eq!(&std::fs::read(&path).unwrap()[..4], b"\x89PNG");
        assert!(crate::formats::outputs::write_one(|out| level_lines_plot(out, &dir.path().join("e.png"), "t", "x", "y", &[], (0.0, 1.0))).is_err());
        assert!(!dir.path().join("e.png").exists());
    }
}
