//! The soak (issue 18): a long stream of frames through the core's corrector and the
//! cycle-level FPGA model, every sum checked against the float reference
//! ([`crate::model::reference`]), while
//! - the LUTs change at random moments: staged or uploaded as device images in random
//!   chunks, activation asked between frames or in the middle of one (it must wait for the
//!   frame's end), images corrupted on purpose (they must be refused and change nothing);
//! - some segments pass 512 frames per state at codes near the top, so the sums saturate
//!   (the expected sum is then `min(exact, u32::MAX)` and every clipped addition counted);
//! - codes come uniform over the range, with out-of-range codes (read as the top code and
//!   counted), near the top, or from the camera model;
//! - the ROI, the number of states and the FPGA's build parameters change per segment.
//!
//! Every check is against quantities computed here, independently of the core's
//! arithmetic: the reference's entries are `RNE(2^11 c_k)` of f64 cumulative sums, the
//! counters are recounted from the codes. `scripts/soak.sh` runs 10^9 pixels or more
//! (`cargo run --release --example soak`); the tests run a short soak and one with a
//! planted difference that it must report.

use std::time::Instant;

use dncal_core::driver::Datapath;
use dncal_core::{encode_image, image_len, CoreError, Corrector, Geometry, LutBanks, LutSet, Mvd1024eLuts, Weight};
use dncal_fpga_model::faults::SplitMix64;
use rayon::prelude::*;
use serde::Serialize;

use crate::model::camera::{Camera, CameraConfig, Sampler};
use crate::analyses::flatten::to_core_weights;
use crate::model::reference::{ReferenceLut, ReferenceTables};
use crate::{HostError, Subject};

const N: usize = 4;
const CODES: usize = 4096;
const TOP: u16 = (CODES - 1) as u16;
/// The camera model's sensor side (the MV-D1024E's).
const SENSOR: u16 = 1024;
/// Descriptions of failures kept in the report (the counts are complete).
const KEEP_FAILURES: usize = 20;

/// What to run.
#[derive(Debug, Clone)]
pub struct SoakParams {
    /// Pixels to stream through the core (the last segment may pass it).
    pub pixels: u64,
    /// Seed of everything random.
    pub seed: u64,
    /// Also stream every segment through the FPGA model.
    pub fpga: bool,
    /// Side of the square region the ROIs are cut from, 1 to 1024 pixels (the camera
    /// model's sensor is 1024 x 1024); the tests use a small one to run many segments.
    pub sensor: u16,
}

/// One LUT set of the pool: the core's weights and the reference's, which must be the
/// same numbers (a test plants a difference).
#[derive(Debug, Clone)]
pub struct PoolEntry {
    /// One weight vector per ADC, on the core's 2^-24 grid.
    pub weights: Vec<Vec<Weight>>,
    /// The reference's weights, f64.
    pub reference: Vec<Vec<f64>>,
}

/// Five LUT sets: ideal, the default camera's true code widths, two with random widths
/// (+-5% and 0..2 DN, normalized to 4096 DN), and one with a run of missing codes.
pub fn lut_pool(seed: u64) -> Result<Vec<PoolEntry>, HostError> {
    let mut rng = SplitMix64::new(seed ^ 0x005E_ED0F_1007);
    let unit = |rng: &mut SplitMix64| (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
    let camera = Camera::new(CameraConfig::default()).map_err(|source| HostError::BuiltInConfig { origin: Subject::DefaultCamera.into(), source })?;
    let mut sets: Vec<Vec<Vec<f64>>> = vec![vec![vec![1.0; CODES]; N], camera.adcs.iter().map(|a| a.normalized_widths()).collect()];
    for spread in [0.05, 1.0] {
        sets.push((0..N).map(|_| normalized((0..CODES).map(|_| 1.0 + spread * (2.0 * unit(&mut rng) - 1.0)).collect())).collect());
    }
    sets.push((0..N).map(|adc| normalized((0..CODES).map(|k| if (1000 + 7 * adc..1040 + 7 * adc).contains(&k) { 0.0 } else { 1.0 }).collect())).collect());
    sets.into_iter()
        .map(|set| {
            let weights = set
                .iter()
                .map(|w| to_core_weights(w).map_err(|source| HostError::Weights { subject: Subject::SoakLutPool, source }))
                .collect::<Result<Vec<_>, _>>()?;
            let reference = weights.iter().map(|w| w.iter().map(|x| x.to_num::<f64>()).collect()).collect();
            Ok(PoolEntry { weights, reference })
        })
        .collect()
}

/// `w` scaled to sum to `CODES` DN, so that the top entry stays below 2^23.
fn normalized(w: Vec<f64>) -> Vec<f64> {
    let total: f64 = w.iter().sum();
    w.iter().map(|x| x * CODES as f64 * (1.0 - 1e-9) / total).collect()
}

/// What happened, and every check that failed.
#[derive(Debug, Clone, Default, Serialize)]
pub struct SoakReport {
    /// Seed of the run.
    pub seed: u64,
    /// Segments (a geometry, a code distribution, an FPGA build each).
    pub segments: u64,
    /// Frames streamed through the core.
    pub frames: u64,
    /// Pixels streamed through the core.
    pub pixels_core: u64,
    /// Pixels streamed through the FPGA model.
    pub pixels_fpga: u64,
    /// Sums compared with the reference (each state's image at the end of a segment).
    pub sums_checked: u64,
    /// Core sums unequal to the quantized reference (clipped at `u32::MAX`): expected 0.
    pub mismatches_core: u64,
    /// Unsaturated core sums further than `F 2^-12` DN from the f64 sum of the centers.
    pub out_of_bound: u64,
    /// FPGA sums unequal to the quantized reference: expected 0.
    pub mismatches_fpga: u64,
    /// Counters (out-of-range codes, clipped additions, frames, swaps) unequal to the recount.
    pub counter_mismatches: u64,
    /// LUT changes the core made active.
    pub lut_swaps: u64,
    /// Of those, asked for in the middle of a frame (taking effect at its end).
    pub mid_frame_activations: u64,
    /// LUTs uploaded as device images in chunks (the rest were staged whole).
    pub chunked_uploads: u64,
    /// Corrupted images the core refused (each must be, and must change nothing).
    pub corrupt_images_refused: u64,
    /// LUT images uploaded to the FPGA over SPI.
    pub fpga_uploads: u64,
    /// Corrupted images the FPGA driver refused.
    pub fpga_corrupt_refused: u64,
    /// Additions the core clipped at `u32::MAX`.
    pub saturated_additions: u64,
    /// Sums that ended clipped.
    pub saturated_sums: u64,
    /// Codes above the top code.
    pub out_of_range_codes: u64,
    /// Largest |core sum - f64 reference| over the unsaturated sums, DN.
    pub max_abs_err_dn: f64,
    /// Wall time, s.
    pub wall_s: f64,
    /// The first failures, described.
    pub failures: Vec<String>,
}

impl SoakReport {
    /// Whether every check held.
    pub fn passed(&self) -> bool {
        self.mismatches_core == 0 && self.out_of_bound == 0 && self.mismatches_fpga == 0 && self.counter_mismatches == 0 && self.failures.is_empty()
    }

    fn fail(&mut self, what: String) {
        if self.failures.len() < KEEP_FAILURES {
            self.failures.push(what);
        }
    }
}

/// Where the codes of a segment come from.
#[derive(Debug, Clone, Copy)]
enum Codes {
    /// Uniform over the ADC's codes.
    Uniform,
    /// Uniform, one in eight replaced by a code above the top code.
    OutOfRange,
    /// Within 8 codes of the top, above it too.
    NearTop,
    /// The default camera model under a column ramp peaking at `peak` of full scale.
    Camera { peak: f64 },
}

#[derive(Debug, Clone)]
struct Segment {
    geometry: Geometry,
    first_row: u16,
    frames: u32,
    codes: Codes,
    fpga: Option<dncal_fpga_model::Config>,
}

/// Segment `index`: its class cycles (one in ten saturating, three in ten the whole
/// region, the rest random ROIs), so every run of ten segments has each; the rest is drawn.
fn draw_segment(index: u64, rng: &mut SplitMix64, fpga: bool, sensor: u16) -> Result<Segment, HostError> {
    let (width, height, states, frames, codes);
    match index % 10 {
        // Saturating: a small ROI, more than 512 frames per state near the top code.
        0 => {
            width = 1 + rng.below(64.min(sensor as u64)) as u16;
            height = 1 + rng.below(8.min(sensor as u64)) as u16;
            states = 1 + rng.below(2) as u8;
            frames = states as u32 * (513 + rng.below(300) as u32);
            codes = Codes::NearTop;
        }
        // The whole sensor, a few frames.
        1..=3 => {
            width = sensor;
            height = sensor;
            states = 1 + rng.below(8) as u8;
            frames = 1 + rng.below(12) as u32;
            codes = draw_codes(rng);
        }
        _ => {
            width = 1 + rng.below(sensor as u64) as u16;
            height = 1 + rng.below(sensor as u64) as u16;
            states = 1 + rng.below(8) as u8;
            let most = (16_000_000 / (width as u64 * height as u64)).clamp(1, 64);
            frames = 1 + rng.below(most) as u32;
            codes = draw_codes(rng);
        }
    }
    let first_column = rng.below((sensor - width) as u64 + 1) as u16;
    let first_row = rng.below((sensor - height) as u64 + 1) as u16;
    let geometry = Geometry::new(width, height, states, first_column).map_err(|e| HostError::core("soak geometry", e))?;
    let fpga = fpga.then(|| {
        let taps = 1 + rng.below(8) as usize;
        dncal_fpga_model::Config {
            taps,
            // Enough bandwidth for every tap's read and write: no pixel may be dropped.
            mem_words_per_cycle: 2 * taps as u32,
            mem_latency: 1 + rng.below(64) as u32,
            h_blank: rng.below(65) as u32,
            v_blank: rng.below(1025) as u32,
            ..Default::default()
        }
    });
    Ok(Segment { geometry, first_row, frames, codes, fpga })
}

fn draw_codes(rng: &mut SplitMix64) -> Codes {
    match rng.below(4) {
        0 => Codes::Uniform,
        1 => Codes::OutOfRange,
        2 => Codes::NearTop,
        _ => Codes::Camera { peak: 0.2 + 1.1 * (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64 },
    }
}

/// The pool as each side needs it.
struct Pool {
    luts: Vec<Box<Mvd1024eLuts>>,
    images: Vec<Vec<u8>>,
    references: Vec<ReferenceTables>,
}

impl Pool {
    fn new(entries: &[PoolEntry]) -> Result<Self, HostError> {
        let mut pool = Pool { luts: vec![], images: vec![], references: vec![] };
        for e in entries {
            let slices: Vec<&[Weight]> = e.weights.iter().map(|w| w.as_slice()).collect();
            let slices: &[&[Weight]; N] = slices.as_slice().try_into().map_err(|_| HostError::invalid(Subject::SoakLutPool, format!("{} ADCs, need {N}", e.weights.len())))?;
            let luts = Box::new(Mvd1024eLuts::from_weights(slices).map_err(|err| HostError::core("soak LUT pool", err))?);
            let mut image = vec![0u8; image_len::<N, CODES>()];
            encode_image(&*luts, &mut image).map_err(|err| HostError::core("soak LUT image", err))?;
            if e.reference.len() != N {
                return Err(HostError::invalid(Subject::SoakLutPool, format!("{} reference weight vectors, need {N}", e.reference.len())));
            }
            pool.references.push(ReferenceLut::from_weights(&e.reference).tables()?);
            pool.luts.push(luts);
            pool.images.push(image);
        }
        Ok(pool)
    }
}

/// The core's LUT banks as the documentation describes them, tracked alongside.
#[derive(Debug, Clone, Copy)]
struct BankModel {
    active: usize,
    /// The pool index in a validated staging bank.
    staged: Option<usize>,
    pending: bool,
    swaps: u64,
}

impl BankModel {
    fn swap(&mut self) {
        if let Some(id) = self.staged.take() {
            self.active = id;
            self.swaps += 1;
        }
        self.pending = false;
    }
}

/// Runs the soak with [`lut_pool`]; `progress` gets the core pixels done.
pub fn run(params: &SoakParams, progress: impl FnMut(u64)) -> Result<SoakReport, HostError> {
    run_with_pool(params, &lut_pool(params.seed)?, progress)
}

/// Runs the soak with the LUT sets `entries` (at least one).
pub fn run_with_pool(params: &SoakParams, entries: &[PoolEntry], mut progress: impl FnMut(u64)) -> Result<SoakReport, HostError> {
    let start = Instant::now();
    if !(1..=SENSOR).contains(&params.sensor) {
        return Err(HostError::invalid(Subject::SoakParameters, format!("sensor side {} is not 1 to {SENSOR}", params.sensor)));
    }
    let pool = Pool::new(entries)?;
    if pool.luts.is_empty() {
        return Err(HostError::invalid(Subject::SoakLutPool, "no LUT sets"));
    }
    let camera = Camera::new(CameraConfig::default()).map_err(|source| HostError::BuiltInConfig { origin: Subject::DefaultCamera.into(), source })?;
    let mut rng = SplitMix64::new(params.seed);
    let mut report = SoakReport { seed: params.seed, ..Default::default() };
    let mut model = BankModel { active: 0, staged: None, pending: false, swaps: 0 };
    let mut banks = Box::new(LutBanks::new((*pool.luts[0]).clone()));
    while report.pixels_core < params.pixels {
        let segment = draw_segment(report.segments, &mut rng, params.fpga, params.sensor)?;
        let seed = rng.next_u64();
        run_segment(&segment, seed, &pool, &camera, &mut banks, &mut model, &mut rng, &mut report)?;
        report.segments += 1;
        progress(report.pixels_core);
    }
    report.wall_s = start.elapsed().as_secs_f64();
    Ok(report)
}

/// One LUT action on the core at a random moment; `frame_open` says whether a frame is.
fn lut_action(c: &mut Corrector<'_, N, CODES>, pool: &Pool, model: &mut BankModel, rng: &mut SplitMix64, report: &mut SoakReport) {
    let id = rng.below(pool.luts.len() as u64) as usize;
    let frame_open = c.frame_open();
    match rng.below(8) {
        0..=2 => {
            c.banks_mut().stage(&pool.luts[id]);
            model.staged = Some(id);
            model.pending = false;
        }
        3..=5 => {
            c.banks_mut().begin_upload();
            model.staged = None;
            model.pending = false;
            let image = &pool.images[id];
            let mut at = 0;
            while at < image.len() {
                let n = (1 + rng.below(9000) as usize).min(image.len() - at);
                if let Err(e) = c.banks_mut().upload(&image[at..at + n]) {
                    report.fail(format!("segment {}: a valid image's chunk at byte {at} refused: {e:?}", report.segments));
                }
                at += n;
            }
            match c.banks_mut().finish_upload() {
                Ok(()) => model.staged = Some(id),
                Err(e) => report.fail(format!("segment {}: a valid image refused: {e:?}", report.segments)),
            }
            report.chunked_uploads += 1;
        }
        6 => {
            // A corrupted image: one bit flipped, or the image cut short.
            let mut image = pool.images[id].clone();
            if rng.below(2) == 0 {
                let at = rng.below(image.len() as u64) as usize;
                image[at] ^= 1 << rng.below(8);
            } else {
                image.truncate(rng.below(image.len() as u64) as usize);
            }
            c.banks_mut().begin_upload();
            model.staged = None;
            model.pending = false;
            let mut at = 0;
            while at < image.len() {
                let n = (1 + rng.below(9000) as usize).min(image.len() - at);
                let _refused_early = c.banks_mut().upload(&image[at..at + n]).is_err();
                at += n;
            }
            let finished = c.banks_mut().finish_upload();
            let activated = c.request_activation();
            if finished.is_ok() || activated != Err(CoreError::StagingNotValid) {
                report.fail(format!("segment {}: a corrupted image was not refused (finish {finished:?}, activation {activated:?})", report.segments));
            } else {
                report.corrupt_images_refused += 1;
            }
            return;
        }
        _ => {}
    }
    // Ask for activation; it must succeed exactly when a validated set is staged.
    let asked = c.request_activation();
    match (asked, model.staged) {
        (Ok(()), Some(_)) => {
            model.pending = true;
            if frame_open {
                report.mid_frame_activations += 1;
            } else {
                model.swap();
            }
        }
        (Err(CoreError::StagingNotValid), None) => {}
        (got, staged) => report.fail(format!("segment {}: activation gave {got:?} with {staged:?} staged", report.segments)),
    }
}

/// What the references hold of a segment: exact sums (u64, never clipped) and f64 sums
/// of the code centres per pixel and state, the frames streamed per state, and the
/// recount of out-of-range codes and clipped additions.
struct References {
    pixels: usize,
    quantized: Vec<u64>,
    centers: Vec<f64>,
    frames: Vec<u64>,
    out_of_range: u64,
    clipped: u64,
}

impl References {
    fn new(g: Geometry) -> Self {
        References { pixels: g.pixels(), quantized: vec![0; g.sum_len()], centers: vec![0.0; g.sum_len()], frames: vec![0; g.states() as usize], out_of_range: 0, clipped: 0 }
    }

    /// State `s`'s sums.
    fn range(&self, s: usize) -> std::ops::Range<usize> {
        s * self.pixels..(s + 1) * self.pixels
    }
}

/// Streams `seg` (its frames drawn from `seed`) through the core on `banks` and, if the
/// segment asks, the FPGA model, with LUT actions at random moments, and checks every
/// counter and sum against the references.
#[allow(clippy::too_many_arguments)]
fn run_segment(
    seg: &Segment,
    seed: u64,
    pool: &Pool,
    camera: &Camera,
    banks: &mut LutBanks<N, CODES>,
    model: &mut BankModel,
    rng: &mut SplitMix64,
    report: &mut SoakReport,
) -> Result<(), HostError> {
    let g = seg.geometry;
    let (w, h, states) = (g.width() as usize, g.height() as usize, g.states() as usize);
    let mut sums = vec![0u32; g.sum_len()];
    let mut refs = References::new(g);
    let swaps_before = model.swaps;
    let mut corrector = Corrector::new(banks, g, &mut sums).map_err(|e| HostError::core("soak corrector", e))?;
    let mut fpga = match &seg.fpga {
        None => None,
        Some(config) => {
            let device = dncal_fpga_model::Fpga::new(config.clone(), g).map_err(|source| HostError::FpgaIn { subject: Subject::SoakFpga, source })?;
            let mut dp = Datapath::new(device);
            dp.identify().map_err(|e| HostError::core("soak FPGA identify", e))?;
            dp.configure(g).map_err(|e| HostError::core("soak FPGA configure", e))?;
            Some((dp, None::<usize>))
        }
    };
    let mut codes = vec![0u16; w * h];
    for frame in 0..seg.frames {
        let state = (frame as usize % states) as u8;
        // Between frames: perhaps a LUT change (at once: no frame is open).
        if rng.below(4) == 0 {
            lut_action(&mut corrector, pool, model, rng, report);
        }
        let lut = model.active;
        let frame_seed = crate::model::camera::sample::frame_seed(seed, frame as u64);
        draw_frame(seg, camera, frame_seed, state, &pool.references[lut], &mut codes, &mut refs);
        // The core: the whole frame in one call, or line by line with perhaps a LUT
        // change asked in the middle (it must wait for the frame's end).
        corrector.begin_frame(state).map_err(|e| HostError::core("soak begin frame", e))?;
        if rng.below(2) == 0 {
            corrector.accumulate_lines(0, &codes).map_err(|e| HostError::core("soak frame", e))?;
        } else {
            // Up to two actions in the frame: a second one after a requested activation
            // (a new upload or stage cancels it; a corrupt upload then leaves the old LUT).
            let mut at = || if rng.below(3) == 0 { rng.below(h as u64) as usize } else { usize::MAX };
            let (first_at, second_at) = (at(), at());
            for (y, line) in codes.chunks_exact(w).enumerate() {
                if y == first_at {
                    lut_action(&mut corrector, pool, model, rng, report);
                }
                if y == second_at {
                    lut_action(&mut corrector, pool, model, rng, report);
                }
                corrector.accumulate_line(y as u16, line).map_err(|e| HostError::core("soak line", e))?;
            }
        }
        corrector.end_frame().map_err(|e| HostError::core("soak end frame", e))?;
        if model.pending {
            model.swap();
        }
        report.frames += 1;
        report.pixels_core += (w * h) as u64;
        if let Some((dp, loaded)) = fpga.as_mut() {
            fpga_frame(dp, loaded, pool, lut, state, &codes, w, rng, report)?;
        }
    }
    check_counters(&corrector, seg, &refs, model.swaps - swaps_before, report);
    report.out_of_range_codes += refs.out_of_range;
    report.saturated_additions += corrector.status().saturated_additions as u64;
    report.lut_swaps += model.swaps - swaps_before;
    drop(corrector);
    let shape = format!("{w}x{h}+{}+{} x {states} states x {} frames, {:?}", g.first_column(), seg.first_row, seg.frames, seg.codes);
    check_core_sums(&sums, &refs, &shape, report);
    if let Some((mut dp, _)) = fpga {
        check_fpga_sums(dp.device_mut(), &refs, &shape, report);
    }
    Ok(())
}

/// Draws frame `frame_seed` of `seg` into `codes` and adds it to the references of
/// `state` with the active LUT's reference tables, line by line in parallel.
fn draw_frame(seg: &Segment, camera: &Camera, frame_seed: u64, state: u8, tables: &ReferenceTables, codes: &mut [u16], refs: &mut References) {
    let g = seg.geometry;
    let (w, states, x0) = (g.width() as usize, g.states() as usize, g.first_column() as usize);
    let cfg = &camera.config;
    let full_scale_photons = (TOP as f64 - cfg.offset_dn) * cfg.gain_e_per_dn / cfg.qe;
    let light: Vec<f64> = match seg.codes {
        Codes::Camera { peak } => (0..w).map(|x| full_scale_photons * peak * (0.05 + 0.9 * x as f64 / w.max(2) as f64) * (1.0 - 0.1 * state as f64 / states as f64)).collect(),
        _ => vec![],
    };
    let range = refs.range(state as usize);
    // (Laid out only where the segment draws from the camera.)
    let sampler = std::sync::OnceLock::new();
    let (frame_oor, frame_clipped) = codes
        .par_chunks_mut(w)
        .zip(refs.quantized[range.clone()].par_chunks_mut(w))
        .zip(refs.centers[range].par_chunks_mut(w))
        .enumerate()
        .map(|(y, ((line, q), f))| {
            draw_line(seg.codes, camera, &sampler, seg.first_row as usize + y, x0, frame_seed, &light, line);
            let counts = tables.add_line::<N>(x0, line, q, f);
            (counts.out_of_range, counts.clipped)
        })
        .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    refs.out_of_range += frame_oor;
    refs.clipped += frame_clipped;
    refs.frames[state as usize] += 1;
}

/// The FPGA's frame: the frame's LUT uploaded over SPI if it has another (`loaded`),
/// sometimes a corrupted image first (refused, nothing changes), then the frame.
#[allow(clippy::too_many_arguments)]
fn fpga_frame(dp: &mut Datapath<dncal_fpga_model::Fpga>, loaded: &mut Option<usize>, pool: &Pool, lut: usize, state: u8, codes: &[u16], w: usize, rng: &mut SplitMix64, report: &mut SoakReport) -> Result<(), HostError> {
    if rng.below(64) == 0 {
        let mut bad = pool.images[lut].clone();
        let at = rng.below(bad.len() as u64) as usize;
        bad[at] ^= 1 << rng.below(8);
        match dp.upload_lut_image(&bad) {
            Err(CoreError::StagingNotValid) => report.fpga_corrupt_refused += 1,
            other => report.fail(format!("segment {}: the FPGA took a corrupted image: {other:?}", report.segments)),
        }
    }
    if *loaded != Some(lut) {
        dp.upload_lut_image(&pool.images[lut]).map_err(|e| HostError::core("soak FPGA upload", e))?;
        *loaded = Some(lut);
        report.fpga_uploads += 1;
    }
    let lines: Vec<&[u16]> = codes.chunks_exact(w).collect();
    dp.device_mut().stream_frame(state, &lines).map_err(|source| HostError::FpgaIn { subject: Subject::SoakFpga, source })?;
    report.pixels_fpga += codes.len() as u64;
    Ok(())
}

/// The core's counters against the recount: out-of-range codes, clipped additions,
/// frames, `swaps` LUT swaps, no rejected line or incomplete frame, frames per state.
fn check_counters(corrector: &Corrector<'_, N, CODES>, seg: &Segment, refs: &References, swaps: u64, report: &mut SoakReport) {
    let status = corrector.status();
    let recount = |n: u64| n.min(u32::MAX as u64) as u32;
    let expected = [
        ("out-of-range codes", status.out_of_range_codes, recount(refs.out_of_range)),
        ("clipped additions", status.saturated_additions, recount(refs.clipped)),
        ("frames", status.frames, recount(seg.frames as u64)),
        ("LUT swaps", status.lut_swaps, recount(swaps)),
        ("rejected lines", status.rejected_lines, 0),
        ("incomplete frames", status.incomplete_frames, 0),
    ];
    for (what, got, want) in expected {
        if got != want {
            report.counter_mismatches += 1;
            report.fail(format!("segment {}: {what}: the core counted {got}, the recount is {want}", report.segments));
        }
    }
    for (s, &streamed) in refs.frames.iter().enumerate() {
        let got = corrector.sums().frames(s as u8).get() as u64;
        if got != streamed {
            report.counter_mismatches += 1;
            report.fail(format!("segment {}: state {s} holds {got} frames, {streamed} were streamed", report.segments));
        }
    }
}

/// Every core sum against the exact reference (clipped at u32::MAX) and, where it did
/// not clip, against the f64 reference within 2^-12 DN per frame.
fn check_core_sums(sums: &[u32], refs: &References, shape: &str, report: &mut SoakReport) {
    for (s, &streamed) in refs.frames.iter().enumerate() {
        let range = refs.range(s);
        let bound = streamed as f64 * LutSet::<N, CODES>::HALF_UNIT_DN + 1e-9;
        for ((&got, &q), &f) in sums[range.clone()].iter().zip(&refs.quantized[range.clone()]).zip(&refs.centers[range]) {
            let want = q.min(u32::MAX as u64);
            if got as u64 != want {
                report.mismatches_core += 1;
                report.fail(format!("segment {} ({shape}): core sum {got}, reference {want}", report.segments));
            }
            if q > u32::MAX as u64 {
                report.saturated_sums += 1;
            } else {
                let err = (LutSet::<N, CODES>::units_to_dn(got.into()) - f).abs();
                report.max_abs_err_dn = report.max_abs_err_dn.max(err);
                if err > bound {
                    report.out_of_bound += 1;
                    report.fail(format!("segment {} ({shape}): core sum {got} is {err:.3e} DN from the f64 reference, bound {bound:.3e}", report.segments));
                }
            }
        }
        report.sums_checked += refs.pixels as u64;
    }
}

/// The FPGA model's sums and frame counts, drained, against the exact reference; no
/// pixel dropped.
fn check_fpga_sums(device: &mut dncal_fpga_model::Fpga, refs: &References, shape: &str, report: &mut SoakReport) {
    device.drain();
    let stats = device.stats();
    if stats.fifo_overflows != 0 {
        report.fail(format!("segment {} ({shape}): the FPGA dropped {} pixels", report.segments, stats.fifo_overflows));
    }
    for (s, &streamed) in refs.frames.iter().enumerate() {
        let got = device.sums(s as u8).unwrap_or(&[]);
        if got.len() != refs.pixels || device.frames(s as u8) as u64 != streamed {
            report.mismatches_fpga += refs.pixels as u64;
            report.fail(format!("segment {} ({shape}): the FPGA holds {} sums and {} frames in state {s}", report.segments, got.len(), device.frames(s as u8)));
            continue;
        }
        for (&got, &q) in got.iter().zip(&refs.quantized[refs.range(s)]) {
            let want = q.min(u32::MAX as u64);
            if got as u64 != want {
                report.mismatches_fpga += 1;
                report.fail(format!("segment {} ({shape}): FPGA sum {got}, reference {want}", report.segments));
            }
        }
    }
}

/// Fills `line` (sensor row `row`, from column `x0`) with codes of the segment's kind.
#[allow(clippy::too_many_arguments)]
fn draw_line<'a>(kind: Codes, camera: &'a Camera, sampler: &std::sync::OnceLock<Sampler<'a>>, row: usize, x0: usize, frame_seed: u64, light: &[f64], line: &mut [u16]) {
    let mut rng = SplitMix64::new(frame_seed ^ (row as u64 + 1).wrapping_mul(0xA076_1D64_78BD_642F));
    match kind {
        Codes::Uniform => line.iter_mut().for_each(|c| *c = rng.below(CODES as u64) as u16),
        Codes::OutOfRange => line.iter_mut().for_each(|c| {
            let r = rng.next_u64();
            *c = if r & 7 == 0 { TOP + 1 + ((r >> 3) % (u16::MAX - TOP) as u64) as u16 } else { ((r >> 3) % CODES as u64) as u16 };
        }),
        Codes::NearTop => line.iter_mut().for_each(|c| *c = TOP - 7 + rng.below(16) as u16),
        Codes::Camera { .. } => sampler.get_or_init(|| camera.sampler()).sample_span_into(row, x0..x0 + line.len(), frame_seed, |c| light[c - x0], line),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_short_soak_checks_every_sum_and_sees_every_event() {
        let p = SoakParams { pixels: 3_000_000, seed: 18, fpga: true, sensor: 64 };
        let r = run(&p, |_| {}).unwrap();
        assert!(r.passed(), "{r:#?}");
        assert!(r.pixels_core >= p.pixels);
        assert_eq!(r.pixels_fpga, r.pixels_core);
        assert!(r.segments >= 10, "{} segments: not every class ran", r.segments);
        // The run must have exercised what it claims to check.
        for (what, n) in [
            ("LUT swaps", r.lut_swaps),
            ("mid-frame activations", r.mid_frame_activations),
            ("chunked uploads", r.chunked_uploads),
            ("refused corrupt images", r.corrupt_images_refused),
            ("sums checked", r.sums_checked),
            ("FPGA uploads", r.fpga_uploads),
            ("FPGA refusals of corrupt images", r.fpga_corrupt_refused),
            ("clipped additions", r.saturated_additions),
            ("saturated sums", r.saturated_sums),
            ("out-of-range codes", r.out_of_range_codes),
        ] {
            assert!(n > 0, "no {what} in {r:#?}");
        }
    }

    #[test]
    fn a_planted_difference_is_reported() {
        // The reference of one LUT set reads one code of one ADC 0.01 DN wider: every
        // center above it moves by 0.005 DN or more, ten LUT units.
        let mut pool = lut_pool(7).unwrap();
        pool[0].reference[1][2000] += 0.01;
        let r = run_with_pool(&SoakParams { pixels: 500_000, seed: 7, fpga: true, sensor: 64 }, &pool, |_| {}).unwrap();
        assert!(!r.passed());
        assert!(r.mismatches_core > 0 && r.mismatches_fpga > 0, "{r:#?}");
        assert!(r.failures.len() <= KEEP_FAILURES);
    }
}
