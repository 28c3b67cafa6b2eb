//! `dncal bench`: speed as ratios against references run in the same process, run by run
//! (issue 17). A shared 2-core machine is noisy; what one run of two loops shares (the
//! load, the clock, the caches' neighbours) cancels in their ratio, so the ratio is what
//! to read, and its spread over runs says how far to trust it.
//!
//! The references are written here, plainly, as the baseline a reader would write:
//! - **plain LUT loop**: `sums[i] += lut[i mod 4][min(code, top)]` over groups of four
//!   pixels, no bookkeeping (the core must also count out-of-range codes and check lines);
//! - **byte bound**: `sums[i] += code` (the same memory traffic without the table);
//! - **gather loop**: the plain LUT loop as one vector gather a step where the CPU has
//!   one (AVX-512 or AVX2, [`gather`]), the bare instruction the core's host path must
//!   keep up with;
//! - **numpy**: `sums[s] += lut[column mod 4, codes]` in python3 with numpy, timed in its
//!   own process around the same work (skipped, with a note, where numpy is missing).
//!
//! With `--whole` ([`whole`]) the bench also runs the commands whose targets are whole
//! processes on inputs of gigabytes (`linearity`, `diagnose`, the demo) against the
//! issue's limits.

pub mod child;
pub mod gather;
pub mod python;
pub mod ratchet;
pub mod whole;

use std::hint::black_box;
use std::process::Command;
use std::time::Instant;

use dncal_core::{Corrector, Geometry, LutBanks, Mvd1024eLuts};
use rand::{rngs::StdRng, Rng, SeedableRng};
use serde::Serialize;

use crate::formats::report::Report;
use crate::infra::parallel::{band_rows, Bands};
use crate::infra::stats::median;
use crate::HostError;

/// What the bench runs.
#[derive(Debug, Clone)]
pub struct BenchParams {
    /// Runs; each times every variant once (the ratios' spread is over runs).
    pub runs: usize,
    /// Frames per timing (of 1024 x 1024 pixels, in 4 states).
    pub frames: usize,
    /// Time numpy too.
    pub numpy: bool,
    /// An interpreter with the `dncal` package: adds the Python package's rows.
    pub python: Option<std::path::PathBuf>,
}

impl Default for BenchParams {
    fn default() -> Self {
        BenchParams { runs: 7, frames: 32, numpy: true, python: None }
    }
}

/// Which way a row's measure improves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Better {
    /// A rate: the ratio is the rate over the baseline's.
    Higher,
    /// A cost (seconds, bytes) against a limit: the ratio is the limit over the cost, so
    /// that here too a ratio of 1 or more is within the baseline.
    Lower,
}

/// One ratio: a measured thing against its baseline, run by run.
#[derive(Debug, Clone, Serialize)]
pub struct Ratio {
    /// What is measured.
    pub name: String,
    /// Its rate, or its cost (see `better`): the median over runs, in `unit`.
    pub rate: f64,
    /// The baseline.
    pub baseline: String,
    /// The baseline's rate or limit (median over runs).
    pub baseline_rate: f64,
    /// Unit of the rates.
    pub unit: &'static str,
    /// Whether `rate` is a rate (higher is better) or a cost (lower is better).
    pub better: Better,
    /// Rate over baseline rate (a cost: the baseline over the cost), per run: median,
    /// min, max.
    pub ratio_median: f64,
    /// Smallest per-run ratio.
    pub ratio_min: f64,
    /// Largest per-run ratio.
    pub ratio_max: f64,
    /// The target (issue 17), if any: the median ratio must reach it.
    pub target: Option<f64>,
    /// Whether the median reaches the target.
    pub holds: Option<bool>,
}

/// The bench's output.
#[derive(Debug, Clone, Serialize)]
pub struct BenchReport {
    /// CPU model and logical cores.
    pub machine: String,
    /// Runs.
    pub runs: usize,
    /// The ratios.
    pub ratios: Vec<Ratio>,
    /// What was skipped and why.
    pub notes: Vec<String>,
    /// Each row against its recorded floor, with `--check` ([`ratchet`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub check: Option<ratchet::Checked>,
}

impl Report for BenchReport {
    fn text(&self) -> String {
        let mut t = format!("{}; {} runs; ratios are per run (median, min-max); a cost's ratio is its limit over it\n", self.machine, self.runs);
        let name_width = self.ratios.iter().map(|x| x.name.len()).max().unwrap_or(0);
        let baseline_width = self.ratios.iter().map(|x| x.baseline.len()).max().unwrap_or(0);
        for x in &self.ratios {
            let target = x.target.map_or(String::new(), |g| format!("  target >= {g}: {}", if x.holds == Some(true) { "holds" } else { "NOT MET" }));
            let floor = match ratchet::floor_of(x) {
                Some((ratchet::Floor::Ratio(f), _)) => format!("  floor {f}"),
                Some((ratchet::Floor::Reported, _)) => "  (reported, not checked)".to_string(),
                None => "  NO FLOOR".to_string(),
            };
            // Rates below 10 (pixels an instruction) keep three decimals.
            let rate = |r: f64| if r < 10.0 { format!("{r:>8.3}") } else { format!("{r:>8.1}") };
            t += &format!(
                "{:<name_width$} {} {:<8} vs {:<baseline_width$} {}: {}x ({}-{}){target}{floor}\n",
                x.name,
                rate(x.rate),
                x.unit,
                x.baseline,
                rate(x.baseline_rate),
                ratio_text(x.ratio_median),
                ratio_text(x.ratio_min),
                ratio_text(x.ratio_max)
            );
        }
        for n in &self.notes {
            t += &format!("note: {n}\n");
        }
        if let Some(c) = &self.check {
            for u in &c.unchecked {
                t += &format!("check: {u}\n");
            }
            t += &match c.holds() {
                true => format!("check: every row at or above {} of its floor\n", ratchet::SLACK),
                false => c.failures.iter().map(|f| format!("check FAILS: {f}\n")).collect(),
            };
        }
        t
    }
}

/// A ratio as the text prints it: two decimals, or three significant digits below 0.1
/// (`diagnose` against its fits read 0.01x at 0.013 and at 0.007 alike).
fn ratio_text(r: f64) -> String {
    if r.abs() < 0.1 && r != 0.0 {
        format!("{:.*}", (2 - r.abs().log10().floor() as i32) as usize, r)
    } else {
        format!("{r:.2}")
    }
}

const WIDTH: usize = 1024;
const HEIGHT: usize = 1024;
const STATES: usize = 4;
const TOP: usize = 4095;

/// The plain LUT loop (see the module documentation).
fn plain_lut_frame(tables: &[[u32; 4096]; 4], codes: &[u16], sums: &mut [u32]) {
    for (cs, ss) in codes.chunks_exact(4).zip(sums.chunks_exact_mut(4)) {
        for j in 0..4 {
            ss[j] = ss[j].wrapping_add(tables[j][(cs[j] as usize).min(TOP)]);
        }
    }
}

/// The plain LUT loop on a frame cut into `sums.len()` bands of rows, each band on its
/// own thread and clearing its own sums first, as the core's bands do
/// ([`crate::infra::parallel`]): what the parallel path's speed-up can reach on this machine.
fn plain_lut_bands(tables: &[[u32; 4096]; 4], codes: &[u16], frames: usize, sums: &mut [Vec<u32>]) {
    use rayon::prelude::*;
    let count = sums.len();
    sums.par_iter_mut().enumerate().for_each(|(b, band)| {
        let rows = band_rows(HEIGHT, count, b);
        let (first, n) = (rows.start * WIDTH, rows.len() * WIDTH);
        band.fill(0);
        for f in 0..frames {
            plain_lut_frame(tables, black_box(&codes[first..first + n]), &mut band[f % STATES * n..][..n]);
        }
    });
}

/// The byte bound (see the module documentation).
fn bytes_frame(codes: &[u16], sums: &mut [u32]) {
    for (s, &c) in sums.iter_mut().zip(codes) {
        *s = s.wrapping_add(c as u32);
    }
}

/// A simulated `side x side` x 41-level linearity set (16 frames a level) at the sensor's
/// centre, in a temporary directory kept alive by the returned handle.
fn simulated_linearity(camera: &crate::model::camera::Camera, side: usize) -> Result<(tempfile::TempDir, std::path::PathBuf), HostError> {
    let dir = tempfile::tempdir().map_err(|e| HostError::io(std::env::temp_dir(), e))?;
    let path = dir.path().join("linearity.fits");
    let corner = (WIDTH - side) / 2;
    let lp = crate::model::camera::calibration::LinearityParams { frames: 16, roi: (corner, corner, side, side), ..crate::model::camera::calibration::LinearityParams::paper(camera) };
    crate::model::sets::simulate_linearity(camera, &lp, path.clone())?;
    Ok((dir, path))
}

/// The bench's floor for `diagnose`: every pixel's weighted least-squares quartic through
/// its levels (noise of the mean from the frames' deviation), by SVD; the sum of the
/// coefficients, so nothing is optimized away.
fn quartic_per_pixel(set: &crate::formats::fits::LinearitySet) -> f64 {
    use rayon::prelude::*;
    let np = set.width * set.height;
    let vmax = set.voltage.iter().copied().fold(f64::MIN, f64::max);
    let n = f64::from(set.n_frames);
    (0..np)
        .into_par_iter()
        .map(|p| {
            let a = nalgebra::DMatrix::from_fn(set.levels, 5, |l, k| (set.voltage[l] / vmax).powi(k as i32) / (set.std[l * np + p] / n.sqrt()).max(1e-3));
            let b = nalgebra::DVector::from_fn(set.levels, |l, _| set.mean[l * np + p] / (set.std[l * np + p] / n.sqrt()).max(1e-3));
            a.svd(true, true).solve(&b, 1e-12).map_or(0.0, |c| c.sum())
        })
        .sum()
}

/// The firmware's exact-mode correction, instructions a pixel counted by QEMU
/// ([`crate::checks::firmware::instructions::correction_cost`]), against issue 17's limit of 7, as
/// pixels an instruction (so that more is better, as in every other row). A count, not a
/// timing: one run. Skipped with a note where the cross toolchain is missing (the bench
/// does not install it: `scripts/firmware.sh install`) or the count fails.
fn firmware_ratio() -> Result<(Ratio, String), Skipped> {
    let script = crate::checks::firmware::repo_root().join("scripts/firmware.sh");
    let have = std::process::Command::new(&script).arg("have").status().map(|s| s.success()).unwrap_or(false);
    if !have {
        return Err(Skipped::NoToolchain);
    }
    let cost = crate::checks::firmware::build_firmware().and_then(|elf| crate::checks::firmware::instructions::correction_cost(&elf)).map_err(Skipped::Firmware)?;
    let limit = 7.0;
    let r = ratio("firmware correction, QEMU count", &[1.0 / cost.per_pixel], "issue 17: 7 instructions a pixel", &[1.0 / limit], "px/instr", Some(1.0));
    Ok((r, format!("firmware: the exact-mode correction executes {:.3} instructions a pixel plus {:.1} a line (Cortex-M4 under QEMU)", cost.per_pixel, cost.per_line)))
}

/// Mpx/s of `frames` frames of 1024 x 1024 pixels taking `seconds`.
fn mpx_per_s(frames: usize, seconds: f64) -> f64 {
    (frames * WIDTH * HEIGHT) as f64 / seconds.max(1e-12) / 1e6
}

fn ratio(name: &str, rates: &[f64], baseline: &str, base: &[f64], unit: &'static str, target: Option<f64>) -> Ratio {
    compared(name, rates, baseline, base, unit, Better::Higher, target)
}

/// A cost per run (seconds, bytes) against a fixed limit: the ratio is the limit over
/// the cost.
fn cost(name: &str, costs: &[f64], baseline: &str, limit: f64, unit: &'static str, target: Option<f64>) -> Ratio {
    compared(name, costs, baseline, &vec![limit; costs.len()], unit, Better::Lower, target)
}

/// A row: per run, `rates` against `base` (rate over baseline, or for a cost the
/// baseline over the cost); the target read on the median of the per-run ratios.
fn compared(name: &str, rates: &[f64], baseline: &str, base: &[f64], unit: &'static str, better: Better, target: Option<f64>) -> Ratio {
    let per_run: Vec<f64> = rates.iter().zip(base).map(|(a, b)| if better == Better::Higher { a / b } else { b / a }).collect();
    let ratio_median = median(per_run.clone());
    Ratio {
        name: name.into(),
        rate: median(rates.to_vec()),
        baseline: baseline.into(),
        baseline_rate: median(base.to_vec()),
        unit,
        better,
        ratio_median,
        ratio_min: per_run.iter().copied().fold(f64::INFINITY, f64::min),
        ratio_max: per_run.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        target,
        holds: target.map(|t| ratio_median >= t),
    }
}

/// The CPU model and logical core count, from /proc/cpuinfo where there is one.
pub fn machine() -> String {
    let info = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    let model = info.lines().find(|l| l.starts_with("model name")).and_then(|l| l.split(':').nth(1)).map(str::trim).unwrap_or("unknown CPU");
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    format!("{model}, {cores} logical cores")
}

/// The numpy reference: prints its Mpx/s for `frames` frames of the same work.
const NUMPY: &str = r#"
import sys, time
import numpy as np
frames = int(sys.argv[1])
rng = np.random.default_rng(1)
codes = rng.integers(0, 4096, size=(1024, 1024), dtype=np.uint16)
lut = (np.arange(4 * 4096, dtype=np.uint32).reshape(4, 4096) * 2048) % (1 << 23)
sums = np.zeros((4, 1024, 1024), dtype=np.uint32)
adc = (np.arange(1024) % 4)[None, :]
sums[0] += lut[adc, codes]
t = time.perf_counter()
for f in range(frames):
    sums[f % 4] += lut[adc, codes]
print((frames * 1024 * 1024) / (time.perf_counter() - t) / 1e6)
"#;

/// The steps of `dncal linearity` in numpy and astropy (`scripts/linearity_numpy.py`),
/// the baseline of the linearity row; its results are checked against ours there.
const LINEARITY_NUMPY: &str = include_str!("../../../../scripts/linearity_numpy.py");

/// Seconds the numpy version of `linearity` takes on `set` (its own clock, from after its
/// imports: reading the file and every step), and its largest pixel-wise RMS.
fn numpy_linearity(set: &std::path::Path) -> Result<(f64, f64), Skipped> {
    let out = python(LINEARITY_NUMPY, set.as_os_str())?;
    let v: serde_json::Value = serde_json::from_slice(&out).map_err(Skipped::LinearityJson)?;
    match (v["seconds"].as_f64(), v["pixelwise"].as_f64()) {
        (Some(s), Some(p)) => Ok((s, p)),
        _ => Err(Skipped::LinearityFields(v)),
    }
}

fn numpy_rate(frames: usize) -> Result<f64, Skipped> {
    let out = python(NUMPY, frames.to_string().as_ref())?;
    String::from_utf8_lossy(&out).trim().parse::<f64>().map_err(Skipped::Rate)
}

/// Why a reference of the bench did not run: its row is then a note saying this.
#[derive(Debug, thiserror::Error)]
enum Skipped {
    /// The cross toolchain is not installed.
    #[error("firmware skipped: no cross toolchain (scripts/firmware.sh install)")]
    NoToolchain,
    /// Building or counting the firmware failed.
    #[error("firmware skipped: {0}")]
    Firmware(HostError),
    /// `python3` could not be started.
    #[error("python3: {0}")]
    Spawn(std::io::Error),
    /// The script failed: the last line of its error output.
    #[error("{0}")]
    Python(String),
    /// The numpy linearity script's output is not JSON.
    #[error("numpy linearity output: {0}")]
    LinearityJson(serde_json::Error),
    /// ... or lacks its two numbers.
    #[error("numpy linearity output without seconds or pixelwise: {0}")]
    LinearityFields(serde_json::Value),
    /// The numpy rate is not a number.
    #[error("numpy output: {0}")]
    Rate(std::num::ParseFloatError),
}

/// Standard output of `python3 -c script arg`, or the last line of its error output.
fn python(script: &str, arg: &std::ffi::OsStr) -> Result<Vec<u8>, Skipped> {
    let out = Command::new("python3").arg("-c").arg(script).arg(arg).output().map_err(Skipped::Spawn)?;
    if !out.status.success() {
        return Err(Skipped::Python(child::last_line(&out.stderr).unwrap_or_else(|| "python3 failed".into())));
    }
    Ok(out.stdout)
}

/// Whether our largest pixel-wise RMS and numpy's are the same number (to 1e-9 of ours;
/// neither may be NaN or infinite).
fn same_rms(ours: f64, numpys: f64) -> bool {
    ours.is_finite() && numpys.is_finite() && (ours - numpys).abs() <= 1e-9 * ours.abs()
}

impl BenchParams {
    /// Refuses runs and frames the bench cannot time (before anything runs).
    pub fn check(&self) -> Result<(), HostError> {
        let (runs, frames) = (self.runs, self.frames);
        if runs == 0 || frames == 0 {
            return Err(HostError::Argument { flag: "--runs / --frames".into(), message: "need at least 1 run and 1 frame".into() });
        }
        // The core's exact mode holds 512 frames per state; the bench compares its sums
        // with the plain loop's wrapping ones, so it stays inside (warm-up run included).
        if frames.saturating_mul(runs + 1) > 512 * STATES {
            return Err(HostError::Argument { flag: "--frames".into(), message: format!("{frames} frames x {} runs (one to warm up) exceed 512 frames per state in 4 states", runs + 1) });
        }
        Ok(())
    }
}

/// Runs the bench: the core against its baselines, then the end-to-end rows (stream,
/// linearity and diagnose on small sets, the firmware).
pub fn bench(p: &BenchParams, progress: impl Fn(&str)) -> Result<BenchReport, HostError> {
    p.check()?;
    let runs = p.runs;
    let mut notes = Vec::new();
    let core = core_runs(p, &progress, &mut notes)?;
    let mut ratios = vec![
        ratio("core, line by line", &core.by_line, "plain LUT loop", &core.plain, "Mpx/s", None),
        ratio("core, frame as a block", &core.by_block, "plain LUT loop", &core.plain, "Mpx/s", Some(0.95)),
        ratio("core, frame as a block", &core.by_block, "byte bound (no LUT)", &core.bytes, "Mpx/s", Some(0.4)),
    ];
    // Said after the rows: an empty `notes` until then means numpy ran.
    #[cfg(target_arch = "x86_64")]
    let kernel = dncal_core::simd::Kernel::detected().name();
    #[cfg(not(target_arch = "x86_64"))]
    let kernel = "portable";
    let mut kernel_notes = vec![format!("the core's line loop on this CPU: {kernel}")];
    match gather::available().filter(|_| !core.gather.is_empty()) {
        Some(width) => ratios.push(ratio("core, frame as a block", &core.by_block, &format!("gather loop ({width})"), &core.gather, "Mpx/s", Some(1.0))),
        None => kernel_notes.push("no vector gather on this CPU: the gather loop's row was not measured".into()),
    }
    match &core.banded {
        Some(b) => {
            let t = b.threads;
            ratios.push(ratio(&format!("core, {t} bands, {t} threads"), &b.core_n, "core, 1 band, 1 thread", &b.core_1, "Mpx/s", Some(1.8)));
            ratios.push(ratio(&format!("plain loop, {t} bands, {t} threads"), &b.plain_n, "plain loop, 1 band, 1 thread", &b.plain_1, "Mpx/s", None));
        }
        None => notes.push("one core: the parallel path was not measured".into()),
    }
    let camera = crate::model::camera::Camera::new(crate::model::camera::CameraConfig::default()).map_err(|source| HostError::BuiltInConfig { origin: crate::Subject::DefaultCamera.into(), source })?;
    ratios.extend(stream_ratios(&camera, runs)?);
    ratios.push(poisson_ratio(runs));
    if p.numpy && notes.is_empty() {
        ratios.extend(linearity_ratio(&camera, runs, &mut notes)?);
    }
    ratios.push(diagnose_ratio(&camera, runs)?);
    if let Some(py) = &p.python {
        let (_dir, set) = simulated_linearity(&camera, 256)?;
        match python::python_ratios(py, &set, runs) {
            Ok(rows) => ratios.extend(rows),
            Err(e) => notes.push(e.to_string()),
        }
    }
    match firmware_ratio() {
        Ok((r, note)) => {
            ratios.push(r);
            notes.push(note);
        }
        Err(note) => notes.push(note.to_string()),
    }
    if core.numpy.len() == runs {
        ratios.push(ratio("core, frame as a block", &core.by_block, "numpy lut[adc, codes]", &core.numpy, "Mpx/s", Some(8.0)));
    } else if p.numpy && notes.is_empty() {
        notes.push("numpy: not every run measured".into());
    }
    notes.extend(kernel_notes);
    Ok(BenchReport { machine: machine(), runs, ratios, notes, check: None })
}

/// How many times [`bench`] calls its `progress`: each run of the core, and each of the
/// bands where there is more than one thread.
pub fn progress_steps(runs: usize) -> u64 {
    let passes = if rayon::current_num_threads() > 1 { 2 } else { 1 };
    (runs * passes) as u64
}

/// Times `work` (`frames` frames) and, unless `run` is the warm-up (0), adds its rate in
/// Mpx/s to `into`.
fn timed(run: usize, frames: usize, into: &mut Vec<f64>, work: &mut dyn FnMut() -> Result<(), HostError>) -> Result<(), HostError> {
    let t = Instant::now();
    work()?;
    if run > 0 {
        into.push(mpx_per_s(frames, t.elapsed().as_secs_f64()));
    }
    Ok(())
}

/// The core's rates per run, Mpx/s, and its baselines' in the same runs.
struct CoreRates {
    by_line: Vec<f64>,
    by_block: Vec<f64>,
    plain: Vec<f64>,
    bytes: Vec<f64>,
    /// The gather loop's, where the CPU has a gather.
    gather: Vec<f64>,
    numpy: Vec<f64>,
    /// With more than one thread: the bands' rates.
    banded: Option<Banded>,
}

/// The frame in bands of rows, as many as threads and one, the core's and the plain
/// loop's, Mpx/s per run.
struct Banded {
    threads: usize,
    core_n: Vec<f64>,
    core_1: Vec<f64>,
    plain_n: Vec<f64>,
    plain_1: Vec<f64>,
}

/// Times the core (line by line, a frame as a block, in bands on every thread and on one)
/// and the plain LUT loop, the byte bound and numpy on the same frames of uniform codes,
/// each once per run (run 0 warms up); the core's sums must equal the plain loop's.
fn core_runs(p: &BenchParams, progress: &impl Fn(&str), notes: &mut Vec<String>) -> Result<CoreRates, HostError> {
    let (runs, frames) = (p.runs, p.frames);
    let codes = uniform_codes(WIDTH * HEIGHT);
    let bits: Box<[[u32; 4096]; 4]> = Box::new(core::array::from_fn(|a| core::array::from_fn(|k| ((a * 4096 + k) as u32 * 2048) % (1 << 23))));
    let luts = Mvd1024eLuts::from_bits(&bits).map_err(|e| HostError::core(crate::Subject::BenchLut.to_string(), e))?;
    let mut banks_line = Box::new(LutBanks::new(luts.clone()));
    let mut banks_block = Box::new(LutBanks::new(luts.clone()));
    let geometry = Geometry::new(WIDTH as u16, HEIGHT as u16, STATES as u8, 0).map_err(|e| HostError::core(crate::Subject::BenchGeometry.to_string(), e))?;
    let core_err = |e: dncal_core::CoreError| HostError::core(format!("{}: the core refused the bench's frame", crate::Subject::Bench), e);
    let n = WIDTH * HEIGHT;
    let (mut line_sums, mut block_sums, mut plain_sums, mut byte_sums) = (vec![0u32; STATES * n], vec![0u32; STATES * n], vec![0u32; STATES * n], vec![0u32; STATES * n]);
    let gather_codes = gather::available().and_then(|_| gather::InRange::new(&codes));
    let mut gather_sums = vec![0u32; if gather_codes.is_some() { STATES * n } else { 0 }];
    let mut r = CoreRates { by_line: Vec::new(), by_block: Vec::new(), plain: Vec::new(), bytes: Vec::new(), gather: Vec::new(), numpy: Vec::new(), banded: None };
    // The parallel path against itself on one band: both clear their sums once per run.
    // The bands run on rayon's pool: as many as it has threads.
    let threads = rayon::current_num_threads();
    let mut one_band = Bands::new(&luts, geometry, 1).map_err(core_err)?;
    let mut many_bands = Bands::new(&luts, geometry, threads).map_err(core_err)?;
    let frame_list: Vec<(u8, &[u16])> = (0..frames).map(|f| ((f % STATES) as u8, codes.as_slice())).collect();
    let (mut banded_1, mut banded_n, mut plain_1, mut plain_n) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let band_sums = |count: usize| (0..count).map(|b| vec![0u32; STATES * band_rows(HEIGHT, count, b).len() * WIDTH]).collect::<Vec<_>>();
    let (mut plain_sums_1, mut plain_sums_n) = (band_sums(1), band_sums(threads));
    let mut c_line = Corrector::new(&mut banks_line, geometry, &mut line_sums).map_err(core_err)?;
    let mut c_block = Corrector::new(&mut banks_block, geometry, &mut block_sums).map_err(core_err)?;
    // Run 0 warms up (first touches of the sum buffers fault their pages in) and is not
    // counted.
    for run in 0..=runs {
        if run > 0 {
            progress(&format!("run {run}/{runs}"));
        }
        let timed = |into: &mut Vec<f64>, work: &mut dyn FnMut() -> Result<(), HostError>| timed(run, frames, into, work);
        timed(&mut r.by_line, &mut || {
            for f in 0..frames {
                c_line.begin_frame((f % STATES) as u8).map_err(core_err)?;
                for (row, line) in codes.chunks_exact(WIDTH).enumerate() {
                    black_box(c_line.accumulate_line(row as u16, black_box(line)).map_err(core_err)?);
                }
                c_line.end_frame().map_err(core_err)?;
            }
            Ok(())
        })?;
        timed(&mut r.by_block, &mut || {
            for f in 0..frames {
                c_block.begin_frame((f % STATES) as u8).map_err(core_err)?;
                black_box(c_block.accumulate_lines(0, black_box(&codes)).map_err(core_err)?);
                c_block.end_frame().map_err(core_err)?;
            }
            Ok(())
        })?;
        timed(&mut r.plain, &mut || {
            (0..frames).for_each(|f| plain_lut_frame(&bits, black_box(&codes), &mut plain_sums[f % STATES * n..][..n]));
            Ok(())
        })?;
        timed(&mut r.bytes, &mut || {
            (0..frames).for_each(|f| bytes_frame(black_box(&codes), &mut byte_sums[f % STATES * n..][..n]));
            Ok(())
        })?;
        if let Some(frame) = gather_codes {
            timed(&mut r.gather, &mut || {
                (0..frames).for_each(|f| {
                    black_box(gather::gather_lut_frame(&bits, black_box(frame), &mut gather_sums[f % STATES * n..][..n]));
                });
                Ok(())
            })?;
        }
        if run > 0 && p.numpy && notes.is_empty() {
            match numpy_rate(frames) {
                Ok(rate) => r.numpy.push(rate),
                Err(e) => notes.push(format!("numpy skipped: {e}")),
            }
        }
        black_box((&plain_sums, &byte_sums));
    }
    // The bands in runs of their own: between the one-thread timings above the second
    // core idles for some 80 ms, and a 20 ms timing on two threads right after that ran
    // at 1.2-1.6x where the same loop timed back to back with its one-thread twin ran
    // at 2.0x (a standalone test on this machine kind, 2026-11-26); a DAQ keeps its
    // threads busy frame after frame. (Not on one core: nothing to compare.)
    for run in (0..=runs).filter(|_| threads > 1) {
        if run > 0 {
            progress(&format!("bands, run {run}/{runs}"));
        }
        let timed = |into: &mut Vec<f64>, work: &mut dyn FnMut() -> Result<(), HostError>| timed(run, frames, into, work);
        timed(&mut banded_1, &mut || one_band.run(&frame_list).map(|_| ()).map_err(core_err))?;
        timed(&mut banded_n, &mut || many_bands.run(&frame_list).map(|_| ()).map_err(core_err))?;
        timed(&mut plain_1, &mut || {
            plain_lut_bands(&bits, &codes, frames, &mut plain_sums_1);
            Ok(())
        })?;
        timed(&mut plain_n, &mut || {
            plain_lut_bands(&bits, &codes, frames, &mut plain_sums_n);
            Ok(())
        })?;
    }
    // The core and the plain loop must agree bit for bit, or the comparison is void.
    if c_line.sums().as_slice() != plain_sums.as_slice() || c_block.sums().as_slice() != plain_sums.as_slice() || (gather_codes.is_some() && gather_sums != plain_sums) {
        return Err(HostError::invalid(crate::Subject::Bench, "the core's sums differ from the plain LUT loop's"));
    }
    if many_bands.sums() != one_band.sums() {
        return Err(HostError::invalid(crate::Subject::Bench, "the bands' sums differ from one band's"));
    }
    // The plain bands put together must be the core's bands' sums of the last run.
    let plain_whole: Vec<u32> = (0..STATES).flat_map(|st| plain_sums_n.iter().flat_map(move |b| b[st * b.len() / STATES..(st + 1) * b.len() / STATES].iter().copied())).collect();
    if plain_whole != many_bands.sums() || plain_sums_1[0] != one_band.sums() {
        return Err(HostError::invalid(crate::Subject::Bench, "the plain loop's bands differ from the core's"));
    }
    r.banded = (threads > 1).then_some(Banded { threads, core_n: banded_n, core_1: banded_1, plain_n, plain_1 });
    Ok(r)
}

/// End to end: `dncal stream` (camera model sampling, the core, the float reference
/// check) on 1024 x 1024 frames, and replay (`stream --frames-from`) of recorded frames
/// of uniform codes, against one K-Coronagraph camera's rate (1024 x 1024 x 150 Hz): a
/// fixed rate, not a run in this process, so a ratio's spread is the stream's own.
///
/// And the stream on one thread against the draws alone on one thread, run by run: what
/// the sampler adds to its draws (each pixel's code, the check's references, the core),
/// a ratio the machine's speed cancels in, so that a slower code stage fails the ratchet
/// where the rows against the fixed rate are only reported.
fn stream_ratios(camera: &crate::model::camera::Camera, runs: usize) -> Result<[Ratio; 3], HostError> {
    use crate::checks::streaming::{run_stream, StreamParams};
    let weights = crate::checks::stream_run::oracle_weights(camera)?;
    let cube = crate::formats::fits::FrameCube { width: WIDTH, height: HEIGHT, frames: 16, codes: uniform_codes(WIDTH * HEIGHT).repeat(16) };
    let replay = StreamParams { recorded: Some(std::sync::Arc::new(cube)), ..StreamParams::full_frame(camera, 16) };
    let rates = |what: &str, params: &StreamParams| -> Result<Vec<f64>, HostError> {
        (0..runs.min(3))
            .map(|_| {
                let r = run_stream(camera, &weights, params, |_| {})?;
                match r.mismatches {
                    0 => Ok(r.pixels as f64 / r.wall_s / 1e6),
                    m => Err(HostError::invalid(crate::Subject::Bench, format!("{what}: {m} mismatches against the float reference"))),
                }
            })
            .collect()
    };
    let sampled = rates("stream", &StreamParams::full_frame(camera, 8))?;
    let replayed = rates("replay", &replay)?;
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().map_err(|e| HostError::invalid(crate::Subject::Bench, format!("a one-thread pool: {e}")))?;
    let (mut alone, mut drawn) = (Vec::new(), Vec::new());
    let means = draw_means();
    for run in 0..runs.min(3) {
        alone.extend(one.install(|| rates("stream on one thread", &StreamParams::full_frame(camera, 4)))?);
        drawn.push(draws_alone(&means, run as u64));
    }
    let camera_rate = |n: usize| vec![1024.0 * 1024.0 * 150.0 / 1e6; n];
    Ok([
        ratio("stream, end to end, 1 thread", &alone, "its draws alone, 1 thread", &drawn, "Mpx/s", None),
        ratio("stream, end to end", &sampled, "one K-Cor camera (fixed)", &camera_rate(sampled.len()), "Mpx/s", Some(1.0)),
        ratio("stream --frames-from", &replayed, "one K-Cor camera (fixed)", &camera_rate(replayed.len()), "Mpx/s", Some(1.0)),
    ])
}

/// The camera sampler's draws, a mean per pixel as in a frame with PRNU: a line's eight
/// streams (`camera::draws::LineDraws`, a Poisson count and a read-noise Gaussian per
/// pixel, in chunks of 256 as the sampler takes them) against rand_distr's `Poisson`
/// built per mean on one Xoshiro256++ stream (its Poisson count alone), on the same
/// means (electrons across the range, 200 to 180 000). Its target, 4: four lanes' worth
/// of a scalar draw, the least a vectorized draw should give.
fn poisson_ratio(runs: usize) -> Ratio {
    use crate::model::camera::draws::Stream;
    let means = draw_means();
    let (mut ptrs_rates, mut crate_rates) = (Vec::new(), Vec::new());
    for run in 0..=runs {
        let ours = draws_alone(&means, run as u64);
        let mut g = Stream::from_seed(run as u64);
        let t = Instant::now();
        black_box(means.iter().map(|&m| rand_distr::Poisson::new(m).map_or(0.0, |d| rand_distr::Distribution::sample(&d, &mut g))).sum::<f64>());
        let b = t.elapsed().as_secs_f64();
        if run > 0 {
            ptrs_rates.push(ours);
            crate_rates.push(means.len() as f64 / b / 1e6);
        }
    }
    ratio("camera draws, 8 streams (PTRS, Box-Muller)", &ptrs_rates, "rand_distr Poisson::new + sample", &crate_rates, "Mpx/s", Some(4.0))
}

/// The means the draw rows draw: 2^18 electrons across the range, 200 to 180 000.
fn draw_means() -> Vec<f64> {
    (0..1 << 18).map(|i| 200.0 + (i as f64 * 0.618_034).fract() * 179_800.0).collect()
}

/// A line's eight streams drawing `means` ([`draw_means`]: a Poisson count and a
/// Gaussian a pixel, in chunks as the sampler takes them) on this thread, Mpx/s.
fn draws_alone(means: &[f64], seed: u64) -> f64 {
    use crate::model::camera::draws::{LineDraws, CHUNK};
    let (mut n, mut z) = ([0.0; CHUNK], [0.0; CHUNK]);
    let mut lanes = LineDraws::new(seed, 0);
    let t = Instant::now();
    let mut total = 0.0;
    for mu in means.chunks(CHUNK) {
        lanes.draw(mu, &mut n, &mut z);
        total += black_box(&n)[0] + black_box(&z)[0];
    }
    black_box(total);
    means.len() as f64 / t.elapsed().as_secs_f64() / 1e6
}

/// `linearity` on a 256 x 256 x 41-level set against the same steps in numpy, both from
/// reading the file to the RMS per level (the numpy script's own clock starts after its
/// imports), on the same file; the results must agree. None, with a note, where numpy
/// could not run.
fn linearity_ratio(camera: &crate::model::camera::Camera, runs: usize, notes: &mut Vec<String>) -> Result<Option<Ratio>, HostError> {
    let (_dir, set) = simulated_linearity(camera, 256)?;
    let (mut ours, mut theirs) = (Vec::new(), Vec::new());
    for _ in 0..runs.min(3) {
        let t = Instant::now();
        let r = crate::analyses::linearity::run::linearity(&set, 4, None, &[], None)?;
        let seconds = t.elapsed().as_secs_f64();
        match numpy_linearity(&set) {
            Ok((s, pw)) => {
                let want = r.report.rms_pixelwise_max;
                if !same_rms(want, pw) {
                    return Err(HostError::invalid(crate::Subject::Bench, format!("linearity: numpy's largest pixel-wise RMS {pw} differs from ours {want}")));
                }
                ours.push(1.0 / seconds);
                theirs.push(1.0 / s);
            }
            Err(e) => {
                notes.push(format!("numpy linearity skipped: {e}"));
                return Ok(None);
            }
        }
    }
    Ok(Some(ratio("linearity, 256 x 256 x 41", &ours, "numpy/astropy, same steps", &theirs, "sets/s", Some(10.0))))
}

/// `diagnose` on a 128 x 128 x 41-level linearity set (read from its file, as the command
/// does) against the plainest per-pixel work it contains: one weighted least-squares
/// quartic per pixel through all its levels by nalgebra's SVD, on the same means. The
/// ratio says how many such fits a diagnosis costs per pixel.
fn diagnose_ratio(camera: &crate::model::camera::Camera, runs: usize) -> Result<Ratio, HostError> {
    let (_dir, path) = simulated_linearity(camera, 128)?;
    // The baseline's means, read once (the diagnosis reads its file every run, as the
    // command does).
    let wide = crate::formats::fits::read_linearity(&path)?;
    let pixels = (wide.width * wide.height) as f64;
    let (mut ours, mut fits) = (Vec::new(), Vec::new());
    for _ in 0..runs.min(3) {
        let t = Instant::now();
        let set = crate::formats::fits::read_linearity_as::<f32>(&path)?;
        black_box(crate::analyses::diagnose::diagnose_linearity(&set, 0.01).map_err(|source| HostError::Diagnose { path: path.clone(), source })?);
        ours.push(pixels / t.elapsed().as_secs_f64() / 1e3);
        let t = Instant::now();
        black_box(quartic_per_pixel(&wide));
        fits.push(pixels / t.elapsed().as_secs_f64() / 1e3);
    }
    Ok(ratio("diagnose, 128 x 128 x 41 linearity set", &ours, "one quartic SVD fit per pixel", &fits, "kpx/s", None))
}

/// `n` codes drawn uniformly from 0..4096 (seed 17): every table entry equally likely,
/// the least cache-friendly case.
fn uniform_codes(n: usize) -> Vec<u16> {
    let mut rng = StdRng::seed_from_u64(17);
    (0..n).map(|_| rng.random_range(0..4096u16)).collect()
}
