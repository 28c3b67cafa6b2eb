//! PNG figures with plotters. The font (DejaVu Sans, Bitstream Vera license, see
//! `assets/DejaVuSans-LICENSE.txt`) is compiled in, so a machine without system fonts
//! draws the same figures.

use std::path::Path;
use std::sync::Once;

use plotters::prelude::*;
use plotters::style::{register_font, FontStyle};

use crate::fits::write_atomically;
use crate::HostError;

static FONT: Once = Once::new();

fn ensure_font() {
    FONT.call_once(|| {
        // The embedded bytes are a valid TTF; a failure here would only lose text.
        let _ = register_font("sans-serif", FontStyle::Normal, include_bytes!("../assets/DejaVuSans.ttf"));
    });
}

/// One curve of a line plot.
pub struct Series {
    /// Legend label.
    pub label: String,
    /// Points (x, y).
    pub points: Vec<(f64, f64)>,
}

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

/// A line plot of `series` (stacked in `panels` vertically when given more than one
/// panel: series `i` goes to panel `i % panels`), written atomically as a PNG.
pub fn line_plot(path: &Path, title: &str, x_label: &str, y_label: &str, series: &[Series], panels: usize) -> Result<(), HostError> {
    ensure_font();
    let panels = panels.max(1);
    let (width, height) = (1000u32, 260 * panels as u32 + 60);
    let mut rgb = vec![0u8; (width * height * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut rgb, (width, height)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| plot_err(path, e))?;
        let root = root.titled(title, ("sans-serif", 22)).map_err(|e| plot_err(path, e))?;
        for (p, area) in root.split_evenly((panels, 1)).iter().enumerate() {
            let mine: Vec<(usize, &Series)> = series.iter().enumerate().filter(|(i, _)| i % panels == p).collect();
            let pts = || mine.iter().flat_map(|(_, s)| s.points.iter()).filter(|(x, y)| x.is_finite() && y.is_finite());
            let (mut x0, mut x1, mut y0, mut y1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
            for &(x, y) in pts() {
                x0 = x0.min(x);
                x1 = x1.max(x);
                y0 = y0.min(y);
                y1 = y1.max(y);
            }
            if !x0.is_finite() {
                continue;
            }
            let pad = ((y1 - y0) * 0.05).max(1e-12);
            let mut chart = ChartBuilder::on(area)
                .margin(8)
                .x_label_area_size(36)
                .y_label_area_size(70)
                .build_cartesian_2d(x0..x1.max(x0 + 1e-12), (y0 - pad)..(y1 + pad))
                .map_err(|e| plot_err(path, e))?;
            chart
                .configure_mesh()
                .x_desc(x_label)
                .y_desc(y_label)
                .label_style(("sans-serif", 14))
                .draw()
                .map_err(|e| plot_err(path, e))?;
            for (i, s) in mine {
                let color = COLORS[i % COLORS.len()];
                chart
                    .draw_series(LineSeries::new(s.points.iter().copied().filter(|(x, y)| x.is_finite() && y.is_finite()), color.stroke_width(1)))
                    .map_err(|e| plot_err(path, e))?
                    .label(s.label.clone())
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2)));
            }
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .label_font(("sans-serif", 14))
                .draw()
                .map_err(|e| plot_err(path, e))?;
        }
        root.present().map_err(|e| plot_err(path, e))?;
    }
    write_png(path, &rgb, width, height)
}

/// Encodes 8-bit RGB pixels as a PNG at `path`, atomically.
pub fn write_png(path: &Path, rgb: &[u8], width: u32, height: u32) -> Result<(), HostError> {
    let mut bytes = Vec::new();
    {
        let mut encoder = png::Encoder::new(&mut bytes, width, height);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        let mut writer = encoder.write_header().map_err(|e| plot_err(path, e))?;
        writer.write_image_data(rgb).map_err(|e| plot_err(path, e))?;
    }
    write_atomically(path, |tmp| std::fs::write(tmp, &bytes).map_err(|e| HostError::io(tmp, e)))
}
