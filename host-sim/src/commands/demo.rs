//! `dncal demo`: the whole DN-error chain on the default camera, with a report.
//!
//! 1. simulate the paper's calibration: per-ADC histograms of ramps of 130..139 levels;
//! 2. flatten them and build the LUTs in the core (LUT FITS and device image);
//! 3. stream frames through the core and check them bit for bit against the float
//!    reference;
//! 4. measure how well the LUTs recover the ADCs' true code centers ([`super::adc`]);
//! 5. write PNG figures and an HTML report.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::Serialize;

use crate::camera::calibration::RampParams;
use crate::camera::Camera;
use crate::commands::adc::AdcReport;
use crate::commands::progress::bar;
use crate::fits::write_atomically;
use crate::flatten::FlattenParams;
use crate::streaming::{run_stream, StreamParams, StreamReport};
use crate::HostError;

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
    /// The ADC characterization: per-ADC LUT summaries, DN error, errors against the
    /// true code centers without and with the LUT.
    pub adc: AdcReport,
    /// The streaming check.
    pub stream: StreamReport,
    /// Wall time, s.
    pub seconds: f64,
}

/// Runs the demo into `out_dir` with `frames` streamed frames.
pub fn demo(camera: &Camera, out_dir: &Path, ramp: &RampParams, flatten: &FlattenParams, frames: u32) -> Result<DemoSummary, HostError> {
    let start = Instant::now();
    std::fs::create_dir_all(out_dir).map_err(|e| HostError::io(out_dir, e))?;
    let at = |name: &str| out_dir.join(name);

    // 1-2. Calibration histograms, LUTs, characterization and its figures.
    let (adc, luts) = crate::commands::adc::run(camera, None, ramp, flatten, out_dir)?;
    let levels: usize = ramp.ramp_levels.iter().sum();

    // 3. Streaming check.
    let pb = bar(frames as u64, "streaming frames");
    let params = StreamParams::full_frame(camera, frames);
    let stream = run_stream(camera, &luts.weights, &params, |n| pb.set_position(n))?;
    pb.finish_and_clear();

    let summary = DemoSummary {
        out_dir: out_dir.into(),
        report: at("report.html"),
        camera: camera.config.name.clone(),
        ramp_levels: levels,
        adc,
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
    for a in &s.adc.adcs {
        let (l, e) = (&a.lut, a.truth.as_ref());
        let f = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.4}"));
        let _ = write!(
            h,
            "<tr><td>{}</td><td>{:.4}</td><td>{:.2e}</td><td>{:.3}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            l.adc,
            l.top_offset_before_dn,
            l.top_offset_dn,
            l.max_abs_offset_dn,
            f(e.map(|e| e.rms_raw_dn)),
            f(e.map(|e| e.rms_lut_dn)),
            f(e.map(|e| e.max_raw_dn)),
            f(e.map(|e| e.max_lut_dn))
        );
    }
    h.push_str("</table><p>Errors are against the simulated ADCs' true code centers after removing a best-fit offset and gain, over the calibrated codes.</p>");
    for (img, caption) in [
        ("histograms.png", "Flattened histograms (the LUT weights) and the true code widths, per ADC."),
        ("histograms_zoom.png", "The same around the major transition at half scale."),
        ("offsets.png", "Cumulative offset of the LUT from a perfect ADC, and the true offsets aligned to it (best-fit offset and gain of the difference removed)."),
        ("correction_error.png", "Error of the raw code and of the LUT value against the true code centers."),
    ] {
        let _ = write!(h, "<figure><img src=\"{img}\" width=\"1000\"><figcaption>{caption}</figcaption></figure>");
    }
    let _ = write!(h, "<p>Run time {:.1} s.</p></body></html>", s.seconds);
    h
}
