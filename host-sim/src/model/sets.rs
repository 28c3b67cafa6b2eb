//! `dncal simulate`: calibration data sets from the camera model.

use std::path::PathBuf;
use std::time::Instant;

use rayon::prelude::*;
use serde::Serialize;

use crate::model::camera::calibration::{LinearityParams, RampParams};
use crate::model::camera::sample::frame_seed;
use crate::model::camera::{Camera, CameraConfig};
use crate::infra::progress::{bar, stage};
use crate::formats::report::Report;
use crate::formats::fits::{stage_histograms, stage_linearity, AdcHistograms, LinearitySet};
use crate::formats::outputs::Outputs;
use crate::{HostError, Origin};

/// Builds the camera of `config`, naming `origin` (its file, or the built-in camera) in
/// errors.
pub fn camera_from(config: CameraConfig, origin: Origin) -> Result<Camera, HostError> {
    let refused = |e| match &origin {
        Origin::File(path) => HostError::Config { path: path.clone(), source: e },
        other => HostError::BuiltInConfig { origin: other.clone(), source: e },
    };
    // Ranges first (a sensor of 10^6 x 10^6 pixels is out of range, not over budget).
    config.validate().map_err(refused)?;
    // The pixel maps: gain, dark, the nonlinearity terms (f64 each) and a state byte.
    let per_pixel = 17 + 8 * config.nonlinearity.len() as u64;
    let what = format!("the camera model of {} x {} pixels", config.width, config.height);
    crate::infra::budget::check(origin.clone(), &what, crate::infra::budget::bytes_of(config.width as u64 * config.height as u64, per_pixel))?;
    Camera::new(config).map_err(refused)
}

/// What `simulate histograms` wrote.
#[derive(Debug, Serialize)]
pub struct HistogramSummary {
    /// The histogram set.
    pub output: PathBuf,
    /// ADCs.
    pub n_adc: usize,
    /// Bits per code.
    pub bit_depth: u32,
    /// Illumination levels summed (all ramps).
    pub levels: usize,
    /// Total counts per ADC.
    pub counts_per_adc: Vec<u64>,
    /// Wall time, s.
    pub seconds: f64,
}

impl Report for HistogramSummary {
    fn text(&self) -> String {
        format!("wrote {} ({} ADCs x {} codes, {} levels, {:.1} s)\n", self.output.display(), self.n_adc, 1u32 << self.bit_depth, self.levels, self.seconds)
    }
}

/// Simulates the ramps of `ramp` and writes the summed per-ADC histograms (the output
/// checked first).
pub fn simulate_histograms(camera: &Camera, ramp: &RampParams, output: PathBuf) -> Result<HistogramSummary, HostError> {
    let start = Instant::now();
    let mut files = Outputs::new();
    files.expect([&output])?;
    let levels: usize = ramp.ramp_levels.iter().sum();
    stage(&format!("simulating the calibration ramps ({levels} levels)"));
    let pb = bar(levels as u64, "ADC ramp histograms");
    let counts = camera.ramp_histograms(ramp, |n| pb.set_position(n));
    pb.finish_and_clear();
    let set = AdcHistograms { bit_depth: camera.config.bits, counts };
    stage_histograms(&mut files, &output, &set)?;
    files.publish()?;
    Ok(HistogramSummary {
        counts_per_adc: set.counts.iter().map(|c| c.iter().sum()).collect(),
        n_adc: set.counts.len(),
        bit_depth: set.bit_depth,
        output,
        levels,
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// What `simulate linearity` wrote.
#[derive(Debug, Serialize)]
pub struct LinearitySummary {
    /// The linearity set.
    pub output: PathBuf,
    /// ROI width.
    pub width: usize,
    /// ROI height.
    pub height: usize,
    /// Levels.
    pub levels: usize,
    /// Frames per level.
    pub frames: u32,
    /// Pixels flagged in MASK.
    pub masked_pixels: usize,
    /// Wall time, s.
    pub seconds: f64,
}

impl Report for LinearitySummary {
    fn text(&self) -> String {
        format!("wrote {} ({}x{} pixels, {} levels x {} frames, {} masked, {:.1} s)\n", self.output.display(), self.width, self.height, self.levels, self.frames, self.masked_pixels, self.seconds)
    }
}

/// Simulates a linearity set and writes it.
pub fn simulate_linearity(camera: &Camera, p: &LinearityParams, output: PathBuf) -> Result<LinearitySummary, HostError> {
    let mut files = Outputs::new();
    let summary = simulate_linearity_staged(&mut files, camera, p, output)?;
    files.publish()?;
    Ok(summary)
}

/// Simulates a linearity set and stages it in `files` (the caller publishes it).
pub fn simulate_linearity_staged(files: &mut Outputs, camera: &Camera, p: &LinearityParams, output: PathBuf) -> Result<LinearitySummary, HostError> {
    let start = Instant::now();
    check_roi(camera, p)?;
    files.expect([&output])?;
    let set = linearity_set_of(camera, p)?;
    let masked_pixels = set.mask.iter().flatten().filter(|&&m| m != 0).count();
    stage_linearity(files, &output, &set)?;
    Ok(LinearitySummary { output, width: set.width, height: set.height, levels: p.levels, frames: p.frames, masked_pixels, seconds: start.elapsed().as_secs_f64() })
}

/// Whether `len` pixels from `first` fit in `size` (any `usize`: a region from Python
/// may be anything).
fn inside(first: usize, len: usize, size: usize) -> bool {
    first.checked_add(len).is_some_and(|end| end <= size)
}

/// The ROI and the counts of `p` checked against the camera.
fn check_roi(camera: &Camera, p: &LinearityParams) -> Result<(), HostError> {
    let (x0, y0, w, h) = p.roi;
    if w == 0 || h == 0 || !inside(x0, w, camera.config.width) || !inside(y0, h, camera.config.height) || p.levels < 2 || p.frames < 2 {
        return Err(HostError::invalid(
            crate::Subject::SimulateLinearityArguments,
            format!("ROI {w}x{h} at ({x0}, {y0}) must be non-empty and inside the {}x{} sensor, with >= 2 levels and >= 2 frames", camera.config.width, camera.config.height),
        ));
    }
    // The set's column c is read by ADC c mod NADC: fewer columns than ADCs make a set the
    // readers refuse (issue 56), so it is refused here, before the work.
    if w < camera.config.n_adc {
        return Err(HostError::invalid(
            crate::Subject::SimulateLinearityArguments,
            format!("ROI {w}x{h} has {w} columns for the camera's {} ADCs; a linearity set's column c is read by ADC c mod NADC, so it needs at least {} columns", camera.config.n_adc, camera.config.n_adc),
        ));
    }
    // The set records ADCMAP = 'COLMOD' (its column c read by ADC c mod NADC), which
    // holds only if its first column is the sensor's column of ADC 0: from x0 = 5 on a
    // 4-ADC camera, every column would have been credited to the wrong ADC.
    let n = camera.config.n_adc;
    if x0 % n != 0 {
        let below = x0 / n * n;
        return Err(HostError::invalid(
            crate::Subject::SimulateLinearityArguments,
            format!("ROI {w}x{h} at ({x0}, {y0}) starts at column {x0}, which ADC {} reads; a linearity set's column c is read by ADC c mod NADC, so the ROI must start at a multiple of the camera's {n} ADCs ({below} or {})", x0 % n, below + n),
        ));
    }
    Ok(())
}

/// The linearity set of `p` in memory: what `simulate linearity` writes.
pub fn linearity_set_of(camera: &Camera, p: &LinearityParams) -> Result<LinearitySet, HostError> {
    check_roi(camera, p)?;
    let (_, _, w, h) = p.roi;
    stage(&format!("simulating a linearity set: {w} x {h} pixels, {} levels of {} frames", p.levels, p.frames));
    let pb = bar(p.levels as u64, "linearity levels");
    let data = camera.linearity_set(p, |n| pb.set_position(n));
    pb.finish_and_clear();
    Ok(LinearitySet {
        bit_depth: camera.config.bits,
        n_adc: camera.config.n_adc,
        n_frames: p.frames,
        width: w,
        height: h,
        levels: p.levels,
        mean: data.mean,
        std: data.std,
        voltage: data.voltage,
        mask: Some(data.mask),
        keys: crate::formats::fits::SetKeys { bayer: camera.config.cfa.as_ref().and_then(|c| c.bayer).map(|b| b.shifted(p.roi.0, p.roi.1)), reference: camera.config.bench.reference, bayer_unread: false },
    })
}

/// `n` frames of the region `(column, row, width, height)` under uniform light of
/// `photons` per pixel and frame, frame-major then row then column; frame `f` is drawn
/// with [`frame_seed`]`(seed, f)`, as `stream` draws its frames.
pub fn frames_of(camera: &Camera, n: usize, photons: f64, (x0, y0, w, h): (usize, usize, usize, usize), seed: u64) -> Result<Vec<u16>, HostError> {
    if w == 0 || h == 0 || !inside(x0, w, camera.config.width) || !inside(y0, h, camera.config.height) || !(photons.is_finite() && photons >= 0.0) {
        return Err(HostError::invalid(
            crate::Subject::SimulateFramesArguments,
            format!("frames of {w}x{h} at ({x0}, {y0}) under {photons} photons: the region must be non-empty and inside the {}x{} sensor, the light finite and not negative", camera.config.width, camera.config.height),
        ));
    }
    let bytes = (n as u64).saturating_mul((w * h) as u64);
    crate::infra::budget::check(crate::Subject::SimulateFramesArguments, "the simulated frames", crate::infra::budget::bytes_of(bytes, 2))?;
    let mut out = vec![0u16; n * w * h];
    let sampler = camera.sampler();
    out.par_chunks_mut((w * h).max(1)).enumerate().for_each(|(f, frame)| {
        let s = frame_seed(seed, f as u64);
        frame.chunks_mut(w).enumerate().for_each(|(y, line)| sampler.sample_span_into(y0 + y, x0..x0 + w, s, |_| photons, line));
    });
    Ok(out)
}
