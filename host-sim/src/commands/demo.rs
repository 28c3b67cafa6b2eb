//! `dncal demo`: the whole DN-error chain on the default camera, with a report.
//!
//! 1. simulate the paper's calibration: per-ADC histograms of ramps of 130..139 levels;
//! 2. flatten them and build the LUTs in the core (LUT FITS and device image);
//! 3. stream frames through the core and check them bit for bit against the float
//!    reference;
//! 4. measure how well the LUTs recover the ADCs' true code centers;
//! 5. write PNG figures and an HTML report.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::Serialize;

use crate::camera::calibration::RampParams;
use crate::camera::Camera;
use crate::commands::lut::{build_luts, AdcLutSummary, BuiltLuts};
use crate::commands::progress::bar;
use crate::fits::{write_atomically, write_histograms, write_lut, AdcHistograms, LutTables};
use crate::flatten::FlattenParams;
use crate::plots::{line_plot, Series};
use crate::streaming::{run_stream, StreamParams, StreamReport};
use crate::HostError;

/// How well one ADC's code-to-DN mapping matches its true code centers, over the codes
/// the flattening calibrates (from `fixed_low_codes` to the code below the top), after
/// removing the best straight line (an offset and a gain, which dark and flat
/// corrections remove anyway).
#[derive(Debug, Clone, Serialize)]
pub struct CorrectionSummary {
    /// ADC index.
    pub adc: usize,
    /// Rms error of the raw code as a DN value, DN.
    pub rms_raw_dn: f64,
    /// Largest |error| of the raw code, DN.
    pub max_raw_dn: f64,
    /// Rms error of the LUT value, DN.
    pub rms_lut_dn: f64,
    /// Largest |error| of the LUT value, DN.
    pub max_lut_dn: f64,
}

/// What the demo did and measured.
#[derive(Debug, Serialize)]
pub struct DemoSummary {
    /// Output folder.
    pub out_dir: PathBuf,
    /// The HTML report.
    pub report: PathBuf,
    /// Camera name.
    pub camera: String,
    /// Ramp levels summed into the histograms.
    pub ramp_levels: usize,
    /// Per-ADC LUT summaries.
    pub luts: Vec<AdcLutSummary>,
    /// Code-center errors without and with the LUT.
    pub correction: Vec<CorrectionSummary>,
    /// The streaming check.
    pub stream: StreamReport,
    /// Wall time, s.
    pub seconds: f64,
}

/// The least-squares line `y = c0 + c1 x`, as `(c0, c1)`.
pub fn line_fit(x: &[f64], y: &[f64]) -> (f64, f64) {
    let n = x.len().max(1) as f64;
    let (mx, my) = (x.iter().sum::<f64>() / n, y.iter().sum::<f64>() / n);
    let sxy: f64 = x.iter().zip(y).map(|(a, b)| (a - mx) * (b - my)).sum();
    let sxx: f64 = x.iter().map(|a| (a - mx).powi(2)).sum();
    let slope = if sxx > 0.0 { sxy / sxx } else { 0.0 };
    (my - slope * mx, slope)
}

/// Residuals of `y` after the least-squares line through `(x, y)`.
pub fn detrend(x: &[f64], y: &[f64]) -> Vec<f64> {
    let (c0, c1) = line_fit(x, y);
    x.iter().zip(y).map(|(a, b)| b - c0 - c1 * a).collect()
}

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|e| e * e).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

fn max_abs(v: &[f64]) -> f64 {
    v.iter().fold(0.0, |m: f64, e| m.max(e.abs()))
}

/// Errors of the raw and corrected code values against the true centers, detrended,
/// over `codes`.
pub fn correction_errors(camera: &Camera, luts: &BuiltLuts, codes: std::ops::Range<usize>) -> Vec<(Vec<f64>, Vec<f64>)> {
    camera
        .adcs
        .iter()
        .zip(&luts.tables)
        .map(|(adc, table)| {
            let truth = adc.centers();
            let x: Vec<f64> = codes.clone().map(|k| truth[k]).collect();
            let raw: Vec<f64> = codes.clone().map(|k| k as f64).collect();
            let lut: Vec<f64> = codes.clone().map(|k| table[k] as f64 / 2048.0).collect();
            // The error of a mapping m is m(k) - truth(k) after matching offset and gain:
            // fit m against the truth and keep the residuals.
            (detrend(&x, &raw), detrend(&x, &lut))
        })
        .collect()
}

/// Runs the demo into `out_dir` with `frames` streamed frames.
pub fn demo(camera: &Camera, out_dir: &Path, ramp: &RampParams, flatten: &FlattenParams, frames: u32) -> Result<DemoSummary, HostError> {
    let start = Instant::now();
    std::fs::create_dir_all(out_dir).map_err(|e| HostError::io(out_dir, e))?;
    let at = |name: &str| out_dir.join(name);

    // 1. Calibration histograms.
    let levels: usize = ramp.ramp_levels.iter().sum();
    let pb = bar(levels as u64, "1/4 ADC ramp histograms");
    let counts = camera.ramp_histograms(ramp, |n| pb.set_position(n));
    pb.finish_and_clear();
    let hist = AdcHistograms { bit_depth: camera.config.bits, counts };
    write_histograms(&at("histograms.fits"), &hist)?;

    // 2. LUTs.
    let luts = build_luts(&hist, flatten, &at("histograms.fits"))?;
    write_lut(&at("lut.fits"), &LutTables { frac_bits: dncal_core::FRAC_BITS, tables: luts.tables.clone() })?;
    write_atomically(&at("lut.bin"), |tmp| std::fs::write(tmp, &luts.image).map_err(|e| HostError::io(tmp, e)))?;
    let lut_summaries: Vec<AdcLutSummary> = luts.flattened.iter().zip(&luts.tables).enumerate().map(|(a, (f, t))| crate::commands::lut::summarize(a, f, t)).collect();

    // 3. Streaming check.
    let pb = bar(frames as u64, "2/4 streaming frames");
    let params = StreamParams::full_frame(camera, frames);
    let stream = run_stream(camera, &luts.weights, &params, |n| pb.set_position(n))?;
    pb.finish_and_clear();

    // 4. Correction error.
    let codes = camera.config.codes();
    let range = flatten.fixed_low_codes.min(codes - 2)..codes - 1;
    let errors = correction_errors(camera, &luts, range.clone());
    let correction: Vec<CorrectionSummary> = errors
        .iter()
        .enumerate()
        .map(|(adc, (raw, lut))| CorrectionSummary { adc, rms_raw_dn: rms(raw), max_raw_dn: max_abs(raw), rms_lut_dn: rms(lut), max_lut_dn: max_abs(lut) })
        .collect();

    // 5. Figures and report.
    let pb = bar(4, "3/4 figures");
    let n_adc = camera.adcs.len();
    let inner = 1..codes - 1;
    let mut hist_series = Vec::new();
    for (a, f) in luts.flattened.iter().enumerate() {
        hist_series.push(Series { label: format!("ADC {a}: flattened histogram"), points: inner.clone().map(|k| (k as f64, f.weights[k])).collect() });
    }
    for (a, adc) in camera.adcs.iter().enumerate() {
        let w = adc.normalized_widths();
        hist_series.push(Series { label: format!("ADC {a}: true code width"), points: inner.clone().map(|k| (k as f64, w[k])).collect() });
    }
    line_plot(&at("histograms.png"), "Normalized histograms (weights) per ADC", "code (DN)", "relative code width", &hist_series, n_adc)?;
    // The same around the major transition at 1024, where single codes can be seen.
    let zoom = 992.0..1056.0;
    let zoomed: Vec<Series> = hist_series.iter().map(|s| Series { label: s.label.clone(), points: s.points.iter().filter(|(k, _)| zoom.contains(k)).copied().collect() }).collect();
    line_plot(&at("histograms_zoom.png"), "Normalized histograms around code 1024", "code (DN)", "relative code width", &zoomed, n_adc)?;
    pb.inc(1);
    let mut offset_series = Vec::new();
    let mut truth_series = Vec::new();
    for (a, (t, adc)) in luts.tables.iter().zip(&camera.adcs).enumerate() {
        // Cumulative offset of the LUT from a perfect ADC (entry minus code center), and
        // the true one aligned to it: the LUT fixes no absolute offset or gain, so the
        // truth gets the best-fit line of their difference over the calibrated codes.
        let lut_offset: Vec<f64> = (0..codes).map(|k| t[k] as f64 / 2048.0 - (k as f64 + 0.5)).collect();
        let true_offset: Vec<f64> = adc.centers().iter().enumerate().map(|(k, c)| c - (k as f64 + 0.5)).collect();
        let x: Vec<f64> = range.clone().map(|k| k as f64).collect();
        let diff: Vec<f64> = range.clone().map(|k| lut_offset[k] - true_offset[k]).collect();
        let (c0, c1) = line_fit(&x, &diff);
        offset_series.push(Series { label: format!("ADC {a}: LUT"), points: range.clone().map(|k| (k as f64, lut_offset[k])).collect() });
        truth_series.push(Series { label: format!("ADC {a}: truth (aligned)"), points: range.clone().map(|k| (k as f64, true_offset[k] + c0 + c1 * k as f64)).collect() });
    }
    offset_series.extend(truth_series);
    line_plot(&at("offsets.png"), "Cumulative offset from a perfect ADC", "code (DN)", "offset (DN)", &offset_series, n_adc)?;
    pb.inc(1);
    let mut err_series = Vec::new();
    for (a, (raw, _)) in errors.iter().enumerate() {
        err_series.push(Series { label: format!("ADC {a}: raw code"), points: range.clone().zip(raw).map(|(k, &e)| (k as f64, e)).collect() });
    }
    for (a, (_, lut)) in errors.iter().enumerate() {
        err_series.push(Series { label: format!("ADC {a}: with LUT"), points: range.clone().zip(lut).map(|(k, &e)| (k as f64, e)).collect() });
    }
    line_plot(&at("correction_error.png"), "Error against the true code centers (offset and gain removed)", "code (DN)", "error (DN)", &err_series, n_adc)?;
    pb.finish_and_clear();

    let summary = DemoSummary {
        out_dir: out_dir.into(),
        report: at("report.html"),
        camera: camera.config.name.clone(),
        ramp_levels: levels,
        luts: lut_summaries,
        correction,
        stream,
        seconds: start.elapsed().as_secs_f64(),
    };
    let json = serde_json::to_string_pretty(&summary).map_err(|e| HostError::Format { path: at("summary.json"), message: e.to_string() })?;
    write_atomically(&at("summary.json"), |tmp| std::fs::write(tmp, &json).map_err(|e| HostError::io(tmp, e)))?;
    let html = report_html(&summary, camera, ramp, flatten);
    write_atomically(&summary.report, |tmp| std::fs::write(tmp, &html).map_err(|e| HostError::io(tmp, e)))?;
    Ok(summary)
}

fn report_html(s: &DemoSummary, camera: &Camera, ramp: &RampParams, flat: &FlattenParams) -> String {
    let c = &camera.config;
    let mut h = String::new();
    let _ = write!(
        h,
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>dncal demo</title>\
         <style>body{{font-family:sans-serif;max-width:1050px;margin:2em auto}}td,th{{padding:2px 10px;text-align:right}}</style></head><body>\
         <h1>dncal demo: DN-error correction</h1>\
         <p>Camera: {} ({}x{}, {} bits, {} ADCs, {} e-/DN, {} e- read noise, {} e- full well). Calibration: {} ramp levels \
         (ramps of {}..{} levels, dark to {:.0}% of saturation, {} pixels per ADC, {} frames per level, signal spread {:.0}% rms across the region), \
         flattened with a {}-point spline and a {}-code running median, the first {} codes {}set to 1 (de Wijn 2018, section 4). Files: <a href=\"histograms.fits\">histograms.fits</a>, <a href=\"lut.fits\">lut.fits</a>, \
         <a href=\"lut.bin\">lut.bin</a> (device image), <a href=\"summary.json\">summary.json</a>.</p>",
        c.name,
        c.width,
        c.height,
        c.bits,
        c.n_adc,
        c.gain_e_per_dn,
        c.read_noise_e,
        c.full_well_e,
        s.ramp_levels,
        ramp.ramp_levels.first().copied().unwrap_or(0),
        ramp.ramp_levels.last().copied().unwrap_or(0),
        100.0 * ramp.overshoot,
        ramp.pixels_per_adc,
        ramp.frames_per_level,
        100.0 * ramp.field_spread,
        flat.spline_points,
        flat.median_window,
        flat.fixed_low_codes,
        if flat.set_last_to_one { "and the last " } else { "" },
    );
    let st = &s.stream;
    let _ = write!(
        h,
        "<h2>Streaming through the core</h2><p>{} frames, {} pixels through the core in {} modulation states: <b>{} mismatches</b> against the float \
         reference quantized by the core's rule; largest deviation from the f64 sums {:.3e} DN (bound {:.3e} DN); core throughput {:.3e} pixels/s.</p>",
        st.frames, st.pixels, 4, st.mismatches, st.max_abs_err_dn, st.bound_dn, st.pixels_per_s
    );
    h.push_str("<h2>LUTs and correction error</h2><table><tr><th>ADC</th><th>top offset before normalization (DN)</th><th>after (DN)</th><th>max |cumulative offset| (DN)</th><th>rms error raw (DN)</th><th>rms error with LUT (DN)</th><th>max raw (DN)</th><th>max with LUT (DN)</th></tr>");
    for (l, e) in s.luts.iter().zip(&s.correction) {
        let _ = write!(
            h,
            "<tr><td>{}</td><td>{:.4}</td><td>{:.2e}</td><td>{:.3}</td><td>{:.4}</td><td>{:.4}</td><td>{:.4}</td><td>{:.4}</td></tr>",
            l.adc, l.top_offset_before_dn, l.top_offset_dn, l.max_abs_offset_dn, e.rms_raw_dn, e.rms_lut_dn, e.max_raw_dn, e.max_lut_dn
        );
    }
    h.push_str("</table><p>Errors are against the simulated ADCs' true code centers after removing a best-fit offset and gain, over the calibrated codes.</p>");
    for (img, caption) in [
        ("histograms.png", "Flattened histograms (the LUT weights) and the true code widths, per ADC."),
        ("histograms_zoom.png", "The same around the major transition at code 1024."),
        ("offsets.png", "Cumulative offset of the LUT from a perfect ADC, and the true offsets aligned to it (best-fit offset and gain of the difference removed)."),
        ("correction_error.png", "Error of the raw code and of the LUT value against the true code centers."),
    ] {
        let _ = write!(h, "<figure><img src=\"{img}\" width=\"1000\"><figcaption>{caption}</figcaption></figure>");
    }
    let _ = write!(h, "<p>Run time {:.1} s.</p></body></html>", s.seconds);
    h
}
