//! The streaming check: frames from the camera model, sampled line by line with cycling
//! modulation states (or replayed from a recording), pushed through the core's
//! `Corrector` exactly as the datapath would (a frame in bands of rows on every thread,
//! [`crate::infra::parallel`], bit for bit one corrector's), and compared with the independent
//! float reference ([`crate::model::reference`]).
//!
//! Two comparisons per sum pixel:
//! - the core's `u32` sum equals the sum of the reference entries quantized by the
//!   core's rounding rule (a *mismatch* otherwise; the expected count is zero);
//! - the core's sum, in DN, lies within `F 2^-12` DN of the f64 sum of the reference
//!   centers, `F` the frames in that state (each entry is within half a unit, 2^-12 DN).

use std::time::Instant;

use dncal_core::driver::Datapath;
use dncal_core::{encode_image, image_len, Geometry, LutSet, Status, Weight};
use rayon::prelude::*;
use serde::Serialize;

use crate::model::camera::Camera;
use crate::infra::parallel::Bands;
use crate::model::reference::ReferenceLut;
use crate::{HostError, Subject};

/// Which datapath sums the frames.
#[derive(Debug, Clone, Default)]
pub enum Engine {
    /// The core's corrector (what the MCU firmware runs).
    #[default]
    Core,
    /// The cycle-level FPGA model, configured over SPI by the core's driver; the core
    /// runs alongside and the two are compared sum by sum.
    Fpga(dncal_fpga_model::Config),
}

/// What to stream.
#[derive(Debug, Clone, Serialize)]
pub struct StreamParams {
    /// Frames in all (frame f has state f mod states).
    pub frames: u32,
    /// Modulation states.
    pub states: u8,
    /// Pixels per line (a ROI starting at `first_column`).
    pub width: u16,
    /// Lines per frame (starting at `first_row`).
    pub height: u16,
    /// Sensor column of the first pixel.
    pub first_column: u16,
    /// Sensor row of the first line.
    pub first_row: u16,
    /// Brightest illumination as a fraction of the ADC's full scale.
    pub peak_fraction: f64,
    /// Intensity modulation between states, relative (0.2: +-20%).
    pub modulation_depth: f64,
    /// Seed of the frames.
    pub seed: u64,
    /// The datapath.
    #[serde(skip)]
    pub engine: Engine,
    /// Recorded frames to replay instead of sampling the camera model (what a DAQ
    /// streams): their size is the ROI's, at `first_column` and `first_row`; every frame
    /// of the cube is streamed, frame f in state f mod `states`.
    #[serde(skip)]
    pub recorded: Option<std::sync::Arc<crate::formats::fits::FrameCube>>,
}

impl StreamParams {
    /// The whole sensor of `camera`, 4 states, `frames` frames.
    pub fn full_frame(camera: &Camera, frames: u32) -> Self {
        StreamParams {
            frames,
            states: 4,
            width: camera.config.width as u16,
            height: camera.config.height as u16,
            first_column: 0,
            first_row: 0,
            peak_fraction: 0.9,
            modulation_depth: 0.2,
            seed: 735,
            engine: Engine::Core,
            recorded: None,
        }
    }
}

/// The outcome.
#[derive(Debug, Clone, Serialize)]
pub struct StreamReport {
    /// Frames streamed.
    pub frames: u32,
    /// Pixels pushed through the core (frames x width x height).
    pub pixels: u64,
    /// Sum pixels compared.
    pub sum_pixels: u64,
    /// Sums that differ from the quantized reference.
    pub mismatches: u64,
    /// Largest |core sum - f64 reference sum|, DN.
    pub max_abs_err_dn: f64,
    /// The bound it must respect: max frames per state x 2^-12 DN.
    pub bound_dn: f64,
    /// Sums outside the bound.
    pub out_of_bound: u64,
    /// Core throughput: pixels / time spent in the core (its bands of rows on every
    /// thread).
    pub pixels_per_s: f64,
    /// Wall time of the whole run, s (sampling included).
    pub wall_s: f64,
    /// The datapath's counters.
    pub status: StatusReport,
    /// `core` or `fpga`.
    pub engine: String,
    /// With the FPGA engine: its comparison with the core and its timing.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fpga: Option<FpgaReport>,
}

impl StreamReport {
    /// Whether the run passed: no sum off the float reference or beyond its bound, and
    /// with the FPGA model none off the core or the reference and no pixel dropped.
    pub fn passed(&self) -> bool {
        self.mismatches == 0 && self.out_of_bound == 0 && self.fpga.as_ref().is_none_or(|f| f.mismatches_vs_core == 0 && f.mismatches_vs_reference == 0 && f.fifo_overflows == 0)
    }
}

impl crate::formats::report::Report for StreamReport {
    fn text(&self) -> String {
        let r = self;
        let mut t = format!(
            "{} frames, {} pixels through the core: {} mismatches against the float reference, max |error| {:.3e} DN (bound {:.3e} DN), core {:.3e} pixels/s, {:.1} s\n",
            r.frames, r.pixels, r.mismatches, r.max_abs_err_dn, r.bound_dn, r.pixels_per_s, r.wall_s
        );
        if let Some(f) = &r.fpga {
            t += &format!(
                "fpga model ({} taps): {} mismatches against the core, {} against the float reference; {} cycles, {:.3} pixels per clock, FIFO high water {} pixels, {} dropped, latency up to {} cycles, {} read-modify-write hazards\n",
                f.taps, f.mismatches_vs_core, f.mismatches_vs_reference, f.cycles, f.pixels_per_clock, f.fifo_high_water, f.fifo_overflows, f.max_latency_cycles, f.rmw_hazards
            );
        }
        t
    }
}

/// The FPGA engine's run.
#[derive(Debug, Clone, Serialize)]
pub struct FpgaReport {
    /// Pixels per clock delivered by the camera link.
    pub taps: usize,
    /// Sums that differ from the core's (expected 0).
    pub mismatches_vs_core: u64,
    /// Sums that differ from the quantized float reference (expected 0).
    pub mismatches_vs_reference: u64,
    /// Pixel clocks for the whole stream, blanking included.
    pub cycles: u64,
    /// Pixels summed per clock over the stream.
    pub pixels_per_clock: f64,
    /// Largest input FIFO occupancy, pixels.
    pub fifo_high_water: usize,
    /// Pixels dropped by a full FIFO (expected 0; the sums then differ).
    pub fifo_overflows: u32,
    /// Largest cycles from a pixel's arrival to its write-back.
    pub max_latency_cycles: u64,
    /// Largest read-modify-writes in flight.
    pub inflight_high_water: usize,
    /// Read-modify-writes that would need forwarding in hardware (expected 0).
    pub rmw_hazards: u32,
}

/// [`Status`] for JSON.
#[derive(Debug, Clone, Serialize)]
pub struct StatusReport {
    /// Codes above the top code.
    pub out_of_range_codes: u32,
    /// Clipped additions.
    pub saturated_additions: u32,
    /// Rejected lines.
    pub rejected_lines: u32,
    /// Frames completed.
    pub frames: u32,
}

impl From<Status> for StatusReport {
    fn from(s: Status) -> Self {
        StatusReport { out_of_range_codes: s.out_of_range_codes, saturated_additions: s.saturated_additions, rejected_lines: s.rejected_lines, frames: s.frames }
    }
}

/// Mean photons reaching pixel (row, column) in a frame of state `state`: a ramp across
/// the columns from 5% to 95% of `peak`, modulated by state.
pub fn illumination(p: &StreamParams, peak_photons: f64, column: usize, state: u8) -> f64 {
    let x = (column - p.first_column as usize) as f64 / (p.width.max(2) - 1) as f64;
    let m = 1.0 + p.modulation_depth * (std::f64::consts::TAU * state as f64 / p.states as f64).cos();
    peak_photons * (0.05 + 0.9 * x) * m / (1.0 + p.modulation_depth)
}

/// Streams `p` through a core loaded with `weights` (one vector per ADC, on the core's
/// 2^-24 grid) and checks it against the float reference of the same weights.
/// `progress` is called with the frames done.
pub fn run_stream(camera: &Camera, weights: &[Vec<Weight>], p: &StreamParams, progress: impl Fn(u64) + Sync) -> Result<StreamReport, HostError> {
    let reference: Vec<Vec<f64>> = weights.iter().map(|w| w.iter().map(|x| x.to_num::<f64>()).collect()).collect();
    run_stream_against(camera, weights, &reference, p, progress)
}

/// As [`run_stream`], with the reference built from `reference_weights` (f64, one vector
/// per ADC). Different weights must produce mismatches: that is how the check is tested.
pub fn run_stream_against(
    camera: &Camera,
    weights: &[Vec<Weight>],
    reference_weights: &[Vec<f64>],
    p: &StreamParams,
    progress: impl Fn(u64) + Sync,
) -> Result<StreamReport, HostError> {
    crate::dispatch_lut_dims!(camera.config.n_adc, camera.config.codes(), crate::Subject::CameraConfig, run_typed(camera, weights, reference_weights, p, progress))
}

/// The fewest pixels a band of the core takes in `stream`: a smaller frame (an ROI) is
/// one band on the calling thread, since handing a band to another thread and waiting
/// for it costs about what the core takes for 64 K pixels (512 frames of a 256 x 256
/// ROI in two bands took 1.7x the time per pixel of full frames).
const MIN_BAND_PIXELS: usize = 1 << 18;

/// The run asked for fits the sensor, and recorded frames are the run's size and count.
fn check_params(camera: &Camera, p: &StreamParams) -> Result<(), HostError> {
    if p.first_column as usize + p.width as usize > camera.config.width || p.first_row as usize + p.height as usize > camera.config.height {
        return Err(HostError::invalid(Subject::StreamParameters, format!("ROI {}x{} at ({}, {}) exceeds the {}x{} sensor", p.width, p.height, p.first_column, p.first_row, camera.config.width, camera.config.height)));
    }
    if let Some(cube) = &p.recorded {
        if (cube.width, cube.height) != (p.width as usize, p.height as usize) || cube.frames != p.frames as usize {
            return Err(HostError::invalid(Subject::StreamParameters, format!("{} frames of {}x{} recorded, {} of {}x{} asked", cube.frames, cube.width, cube.height, p.frames, p.width, p.height)));
        }
    }
    Ok(())
}

/// The FPGA model for `geometry`, identified and configured over SPI by the core's driver,
/// with `luts` uploaded as a device image.
fn fpga_datapath<const N: usize, const CODES: usize>(config: &dncal_fpga_model::Config, geometry: Geometry, luts: &LutSet<N, CODES>) -> Result<Datapath<dncal_fpga_model::Fpga>, HostError> {
    let ctx = |what: &str| format!("stream: {what}");
    let model = dncal_fpga_model::Fpga::new(config.clone(), geometry).map_err(|source| HostError::Fpga { source })?;
    let mut dp = Datapath::new(model);
    dp.identify().map_err(|e| HostError::core(ctx("fpga identify"), e))?;
    dp.configure(geometry).map_err(|e| HostError::core(ctx("fpga configure"), e))?;
    let mut image = vec![0u8; image_len::<N, CODES>()];
    encode_image(luts, &mut image).map_err(|e| HostError::core(ctx("LUT image"), e))?;
    dp.upload_lut_image(&image).map_err(|e| HostError::core(ctx("fpga LUT upload (the model is built for 4 ADCs of 12 bits)"), e))?;
    Ok(dp)
}

/// The FPGA model's run, drained: its sums against the core's `sums` and the exact
/// reference `ref_q`, and its timing.
fn fpga_report(model: &mut dncal_fpga_model::Fpga, states: u8, sums: &[u32], ref_q: &[u64]) -> FpgaReport {
    model.drain();
    let stats = model.stats();
    let fpga_sums: Vec<u32> = (0..states).flat_map(|s| model.sums(s).unwrap_or(&[]).to_vec()).collect();
    FpgaReport {
        taps: model.config().taps,
        mismatches_vs_core: fpga_sums.iter().zip(sums).filter(|(a, b)| a != b).count() as u64 + sums.len().abs_diff(fpga_sums.len()) as u64,
        mismatches_vs_reference: fpga_sums.iter().zip(ref_q).filter(|(&s, &q)| s as u64 != q).count() as u64,
        cycles: stats.cycles,
        pixels_per_clock: stats.pixels as f64 / stats.cycles.max(1) as f64,
        fifo_high_water: stats.fifo_high_water,
        fifo_overflows: stats.fifo_overflows,
        max_latency_cycles: stats.max_latency,
        inflight_high_water: stats.inflight_high_water,
        rmw_hazards: stats.rmw_hazards,
    }
}

fn run_typed<const N: usize, const CODES: usize>(
    camera: &Camera,
    weights: &[Vec<Weight>],
    reference_weights: &[Vec<f64>],
    p: &StreamParams,
    progress: impl Fn(u64) + Sync,
) -> Result<StreamReport, HostError> {
    let start = Instant::now();
    let ctx = |what: &str| format!("stream: {what}");
    let geometry = Geometry::new(p.width, p.height, p.states, p.first_column).map_err(|e| HostError::core(ctx("geometry"), e))?;
    check_params(camera, p)?;
    let slices: Vec<&[Weight]> = weights.iter().map(|w| w.as_slice()).collect();
    let slices: &[&[Weight]; N] = slices.as_slice().try_into().map_err(|_| HostError::invalid(Subject::Weights, format!("{} weight vectors for {N} ADCs", weights.len())))?;
    let luts = Box::new(LutSet::<N, CODES>::from_weights(slices).map_err(|e| HostError::core(ctx("LUT from weights"), e))?);
    let reference = ReferenceLut::from_weights(reference_weights);
    if reference.centers.len() != N || reference.centers.iter().any(|t| t.len() != CODES) {
        return Err(HostError::invalid(Subject::ReferenceWeights, format!("need {N} vectors of {CODES} weights")));
    }
    let reference = reference.tables()?;

    // The core in bands of rows, one per thread; the references written first on every
    // thread (a fresh page read before its first write costs a copy-on-write fault and a
    // TLB shootdown across the threads: that was a third of a replay's time).
    let bands_count = rayon::current_num_threads().min(geometry.pixels() / MIN_BAND_PIXELS).max(1);
    let mut bands = Bands::new(&luts, geometry, bands_count).map_err(|e| HostError::core(ctx("bands"), e))?;
    let mut ref_q: Vec<u64> = (0..geometry.sum_len()).into_par_iter().map(|_| 0).collect();
    let mut ref_f: Vec<f64> = (0..geometry.sum_len()).into_par_iter().map(|_| 0.0).collect();
    let mut core = bands.correctors().map_err(|e| HostError::core(ctx("corrector"), e))?;
    let mut fpga = match &p.engine {
        Engine::Core => None,
        Engine::Fpga(config) => Some(fpga_datapath(config, geometry, &luts)?),
    };
    let cfg = &camera.config;
    let full_scale_photons = ((cfg.codes() - 1) as f64 - cfg.offset_dn) * cfg.gain_e_per_dn / cfg.qe;
    let peak = p.peak_fraction * full_scale_photons;
    let (w, h) = (p.width as usize, p.height as usize);
    let mut core_s = 0.0;
    let x0 = p.first_column as usize;
    let mut sampled = vec![0u16; if p.recorded.is_some() { 0 } else { w * h }];
    let sampler = camera.sampler();
    for frame in 0..p.frames {
        let state = (frame % p.states as u32) as u8;
        let frame_seed = crate::model::camera::sample::frame_seed(p.seed, frame as u64);
        let base = state as usize * w * h;
        let refs = ref_q[base..base + w * h].par_chunks_mut(w).zip(ref_f[base..base + w * h].par_chunks_mut(w));
        let codes: &[u16] = match &p.recorded {
            Some(cube) => {
                let codes = cube.frame(frame as usize);
                codes.par_chunks_exact(w).zip(refs).for_each(|(line, (q, f))| {
                    reference.add_line::<N>(x0, line, q, f);
                });
                codes
            }
            None => {
                // The light is the same on every row of a frame: once per column, not per pixel.
                let light: Vec<f64> = (x0..x0 + w).map(|c| illumination(p, peak, c, state)).collect();
                sampled.par_chunks_mut(w).zip(refs).enumerate().for_each(|(y, (line, (q, f)))| {
                    sampler.sample_span_into(p.first_row as usize + y, x0..x0 + w, frame_seed, |c| light[c - x0], line);
                    // One pass over each line while it is in cache: drawn, then added
                    // to the float and quantized references.
                    reference.add_line::<N>(x0, line, q, f);
                });
                &sampled
            }
        };
        let t = Instant::now();
        core.add_frame(state, codes).map_err(|e| HostError::core(ctx("frame"), e))?;
        core_s += t.elapsed().as_secs_f64();
        if let Some(dp) = fpga.as_mut() {
            let lines: Vec<&[u16]> = codes.chunks_exact(w).collect();
            dp.device_mut().stream_frame(state, &lines).map_err(|source| HostError::Fpga { source })?;
        }
        progress(frame as u64 + 1);
    }
    let status = core.status();
    let frames_max = (0..p.states).map(|s| core.frames(s).get()).max().unwrap_or(0);
    let bound_dn = frames_max as f64 * LutSet::<N, CODES>::HALF_UNIT_DN;
    let check = core
        .spans()
        .into_par_iter()
        .flat_map(|(at, sums)| sums.par_iter().zip(&ref_q[at..at + sums.len()]).zip(&ref_f[at..at + sums.len()]))
        .fold(Check::default, |c, ((&s, &q), &f)| c.with(s, q, (LutSet::<N, CODES>::units_to_dn(s.into()) - f).abs(), bound_dn))
        .reduce(Check::default, Check::merge);
    drop(core);
    let pixels = p.frames as u64 * (w * h) as u64;
    let fpga = fpga.map(|mut dp| fpga_report(dp.device_mut(), p.states, &bands.sums(), &ref_q));
    Ok(StreamReport {
        engine: if fpga.is_some() { "fpga" } else { "core" }.into(),
        fpga,
        frames: p.frames,
        pixels,
        sum_pixels: geometry.sum_len() as u64,
        mismatches: check.mismatches,
        max_abs_err_dn: check.max_abs_err_dn,
        bound_dn,
        out_of_bound: check.out_of_bound,
        pixels_per_s: if core_s > 0.0 { pixels as f64 / core_s } else { 0.0 },
        wall_s: start.elapsed().as_secs_f64(),
        status: status.into(),
    })
}

/// The comparison of the core's sums with the references, summed over sum pixels.
#[derive(Debug, Clone, Copy, Default)]
struct Check {
    mismatches: u64,
    max_abs_err_dn: f64,
    out_of_bound: u64,
}

impl Check {
    /// With one more sum: the core's `sum`, the quantized reference `q`, the error
    /// against the float reference `err_dn` and its bound.
    fn with(self, sum: u32, q: u64, err_dn: f64, bound_dn: f64) -> Self {
        Check {
            mismatches: self.mismatches + (sum as u64 != q) as u64,
            max_abs_err_dn: self.max_abs_err_dn.max(err_dn),
            out_of_bound: self.out_of_bound + (err_dn > bound_dn) as u64,
        }
    }
    fn merge(a: Self, b: Self) -> Self {
        Check { mismatches: a.mismatches + b.mismatches, max_abs_err_dn: a.max_abs_err_dn.max(b.max_abs_err_dn), out_of_bound: a.out_of_bound + b.out_of_bound }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::camera::CameraConfig;

    fn oracle(camera: &Camera) -> Vec<Vec<Weight>> {
        camera.adcs.iter().map(|a| a.normalized_widths().iter().map(|&w| Weight::from_num(w)).collect()).collect()
    }

    #[test]
    fn streaming_has_no_mismatches_and_respects_the_bound() {
        let cam = Camera::new(CameraConfig { width: 96, height: 24, ..Default::default() }).unwrap();
        let w = oracle(&cam);
        let p = StreamParams { frames: 12, states: 4, width: 90, height: 20, first_column: 3, first_row: 2, ..StreamParams::full_frame(&cam, 12) };
        let r = run_stream(&cam, &w, &p, |_| {}).unwrap();
        assert_eq!(r.pixels, 12 * 90 * 20);
        assert_eq!(r.mismatches, 0);
        assert_eq!(r.out_of_bound, 0);
        assert!(r.max_abs_err_dn <= 3.0 * dncal_core::LutSet::<4, 4096>::HALF_UNIT_DN, "{}", r.max_abs_err_dn);
        assert!(r.max_abs_err_dn > 0.0, "entries are rounded, so some error must show");
    }

    #[test]
    fn a_different_reference_is_caught() {
        let cam = Camera::new(CameraConfig { width: 64, height: 8, ..Default::default() }).unwrap();
        let w = oracle(&cam);
        let mut reference: Vec<Vec<f64>> = w.iter().map(|t| t.iter().map(|x| x.to_num::<f64>()).collect()).collect();
        // One code of one ADC 0.001 DN wider shifts every center above it by 0.0005 DN
        // or more: about one LUT unit.
        reference[2][1500] += 0.001;
        let p = StreamParams { frames: 4, states: 2, width: 64, height: 8, first_column: 0, first_row: 0, ..StreamParams::full_frame(&cam, 4) };
        let r = run_stream_against(&cam, &w, &reference, &p, |_| {}).unwrap();
        assert!(r.mismatches > 0);
    }
}
