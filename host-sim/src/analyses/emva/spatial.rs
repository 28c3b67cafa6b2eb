//! The spatial series of an EMVA 1288 set: dark signal and photo-response nonuniformity
//! (DSNU, PRNU) with their row, column and pixel parts, spectrograms, logarithmic
//! histograms and defect pixels.
//!
//! A spatial series is one level of `L > 2` frames, a bright one and a dark one at the
//! same exposure. Per pixel `(m, n)` of the `M x N` frame, in exact integers (EMVA 1288
//! Release 4.0 section 8.2; the reference implementation's `Data1288._get_spatial_data`):
//!
//! ```text
//! <y>[m][n]      = (1/L) sum_l y_l[m][n]                        the averaged image
//! mu_y           = mean of <y>
//! sigma^2_stack  = mean over pixels of the pixel's own temporal variance (1/(L-1))
//! s^2_y.measured = variance of <y> over pixels (1/(MN-1); Release 4.0: 1/MN)
//! s^2_y          = s^2_y.measured - sigma^2_stack / L           temporal noise taken out
//! s^2_y.cav      = (1/N) sum_n (mu_y[n] - mu_y)^2 - sigma^2_stack / (L M)   column means
//! s^2_y.rav      = (1/M) sum_m (mu_y[m] - mu_y)^2 - sigma^2_stack / (L N)   row means
//! s^2_y.col      = (MN - M)/(MN - M - N) s^2_y.cav - N/(MN - M - N) (s^2_y - s^2_y.rav)
//! s^2_y.row      = (MN - N)/(MN - M - N) s^2_y.rav - M/(MN - M - N) (s^2_y - s^2_y.cav)
//! s^2_y.pixel    = MN/(MN - M - N) (s^2_y - s^2_y.cav - s^2_y.rav)
//! ```
//!
//! `DSNU = s_y.dark / K` (e-), `PRNU = sqrt(s^2_y - s^2_y.dark) / (mu_y - mu_y.dark)`, and
//! the same for each part. A part whose variance comes out negative (smaller than what
//! the finite `L` leaves) has no value: the datasheet says so instead of printing NaN.

use rayon::prelude::*;
use rustfft::{num_complex::Complex, FftPlanner};
use serde::Serialize;

use super::descriptor::{at_line, DescriptorFault};
use super::highpass::{high_pass, NoiseGains, SCALE};
use super::cells::CellPattern;
use super::Release;
use super::{load_image, EmvaLevel, EmvaSet, LevelKind, Series};
use crate::infra::stats::robust;
use crate::HostError;

/// The integer statistics of one spatial series: per-pixel sums of the codes and of
/// their squares, exact in `i64` (an `L` of up to 2^31 frames of 16-bit codes fits).
#[derive(Debug, Clone)]
pub struct SpatialSeries {
    /// Frames averaged.
    pub frames: usize,
    /// Rows `M`.
    pub rows: usize,
    /// Columns `N`.
    pub cols: usize,
    /// Photons per pixel (0 for the dark series).
    pub photons: f64,
    /// Exposure time as written.
    pub exposure: f64,
    /// Descriptor line of the level.
    pub line: usize,
    /// `sum_l y_l`, row-major, DN.
    pub sum: Vec<i64>,
    /// `sum_l y_l^2`, row-major, DN^2.
    pub sum_sq: Vec<i64>,
}

/// The variance components of one series, DN^2, and its mean, DN.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Components {
    /// `mu_y`, DN.
    pub mean_dn: f64,
    /// `sigma^2_y.stack`: the mean temporal variance of a single frame, DN^2.
    pub stack_var_dn2: f64,
    /// `s^2_y` (temporal noise taken out), DN^2.
    pub total_dn2: f64,
    /// `s^2_y.row`, DN^2.
    pub row_dn2: f64,
    /// `s^2_y.col`, DN^2.
    pub col_dn2: f64,
    /// `s^2_y.pixel`, DN^2.
    pub pixel_dn2: f64,
}

/// Bytes per pixel a series holds while it is loaded ([`SpatialSeries::load_frames`]): its
/// two sums (`i64`, 16) and a batch of one frame per thread, each as codes (2) with the
/// decoder's buffer of the frame being decoded (2); 4 per thread, counted once per series.
pub fn load_bytes_per_pixel(threads: u64) -> u64 {
    16 + 4 * threads
}

impl SpatialSeries {
    /// Sums the frames of `level` (loaded in parallel).
    pub fn load(set: &EmvaSet, level: &EmvaLevel) -> Result<SpatialSeries, HostError> {
        SpatialSeries::load_frames(set, level, 0..level.images.len())
    }

    /// Sums the frames `frames` of `level` (loaded in parallel): a part of the series, for
    /// results held out by frames. The frames are decoded a batch of one per thread at a
    /// time and added, by blocks of pixels in parallel, into one pair of sums: what it
    /// holds is the sums and one batch ([`load_bytes_per_pixel`]), whatever the frames and
    /// however rayon splits them (a fold per task held a pair of sums each: on the real
    /// CCD's 640 x 480 frames the datasheet's peak was 42 MB on 1 thread, 54 MB on 2, 120
    /// MB on 4 and 218 MB on 8).
    pub fn load_frames(set: &EmvaSet, level: &EmvaLevel, frames: std::ops::Range<usize>) -> Result<SpatialSeries, HostError> {
        const BLOCK: usize = 1 << 14;
        let n = set.width * set.height;
        let images = level.images.get(frames).unwrap_or(&[]);
        let (mut sum, mut sum_sq) = (vec![0i64; n], vec![0i64; n]);
        for batch in images.chunks(rayon::current_num_threads().max(1)) {
            let codes: Vec<Vec<u16>> = batch.par_iter().map(|image| load_image(set, image)).collect::<Result<_, _>>()?;
            sum.par_chunks_mut(BLOCK).zip(sum_sq.par_chunks_mut(BLOCK)).enumerate().for_each(|(b, (s, q))| {
                let first = b * BLOCK;
                for frame in &codes {
                    for ((s, q), &c) in s.iter_mut().zip(q.iter_mut()).zip(frame.get(first..).unwrap_or(&[])) {
                        let c = c as i64;
                        *s += c;
                        *q += c * c;
                    }
                }
            });
        }
        Ok(SpatialSeries {
            frames: images.len(),
            rows: set.height,
            cols: set.width,
            photons: level.photons(),
            exposure: level.exposure,
            line: level.line,
            sum,
            sum_sq,
        })
    }

    /// The sub-series of one cell of a pattern of `period` pixels in rows and columns:
    /// the pixels at rows `row, row + period, ...` and columns `column, column + period,
    /// ...` as an image of their own (a colour filter's channel, as EMVA 1288 takes a
    /// colour camera's channels apart). `None` where the cell holds no pixel.
    pub fn cell(&self, row: usize, column: usize, period: usize) -> Option<SpatialSeries> {
        let p = period.max(1);
        let (rows, cols) = (self.rows.saturating_sub(row).div_ceil(p), self.cols.saturating_sub(column).div_ceil(p));
        if rows == 0 || cols == 0 {
            return None;
        }
        let pick = |v: &[i64]| -> Vec<i64> { (0..rows).flat_map(|r| (0..cols).map(move |c| (row + r * p) * self.cols + column + c * p)).map(|i| v[i]).collect() };
        Some(SpatialSeries { rows, cols, sum: pick(&self.sum), sum_sq: pick(&self.sum_sq), ..*self })
    }

    /// The variance components (module documentation). Release 4.0 takes the spatial
    /// variance over `MN` instead of `MN - 1` (eq. 35), and all of them from the averaged
    /// image high-pass filtered ([`super::highpass`], section 8.1), with the temporal
    /// noise taken out as it passes the filter; the mean stays the unfiltered image's.
    /// An image too small for the filter (under 20 x 20) gives NaN variances.
    pub fn components(&self, release: Release) -> Components {
        let l = self.frames as f64;
        let pixels = self.sum.len() as f64;
        let mean = self.sum.iter().map(|&s| s as f64).sum::<f64>() / l / pixels;
        // Per-pixel temporal variance (1/(L-1)), from exact integer moments.
        let stack: f64 = self
            .sum
            .iter()
            .zip(&self.sum_sq)
            .map(|(&s, &q)| (self.frames as i128 * q as i128 - s as i128 * s as i128) as f64)
            .sum::<f64>()
            / (l * (l - 1.0))
            / pixels;
        let parts = match release {
            Release::R3 => {
                let image: Vec<f64> = self.sum.iter().map(|&s| s as f64 / l).collect();
                variance_parts(&image, self.rows, self.cols, pixels - 1.0, stack / l, NoiseGains::unfiltered(self.rows, self.cols))
            }
            Release::R4 => {
                let (filtered, rows, cols) = high_pass(&self.sum, self.rows, self.cols);
                let image: Vec<f64> = filtered.iter().map(|&s| s as f64 / l / SCALE as f64).collect();
                if image.is_empty() {
                    [f64::NAN; 4]
                } else {
                    variance_parts(&image, rows, cols, (rows * cols) as f64, stack / l, NoiseGains::filtered(rows, cols))
                }
            }
        };
        let [total_dn2, row_dn2, col_dn2, pixel_dn2] = parts;
        Components { mean_dn: mean, stack_var_dn2: stack, total_dn2, row_dn2, col_dn2, pixel_dn2 }
    }
}

/// The total, row, column and pixel variances (eqs. 37-41) of a `rows x cols` averaged
/// image, its spatial variance over `dof`, with the temporal noise `temporal` (`sigma^2
/// / L`, DN^2) taken out as it passes to a pixel, a column mean and a row mean (`gains`).
fn variance_parts(image: &[f64], rows: usize, cols: usize, dof: f64, temporal: f64, gains: NoiseGains) -> [f64; 4] {
    let (m, n) = (rows as f64, cols as f64);
    let mean = image.iter().sum::<f64>() / image.len() as f64;
    let measured = image.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / dof;
    let total = measured - temporal * gains.pixel;
    let col_means: Vec<f64> = (0..cols).map(|c| (0..rows).map(|r| image[r * cols + c]).sum::<f64>() / m).collect();
    let row_means: Vec<f64> = image.chunks_exact(cols).map(|row| row.iter().sum::<f64>() / n).collect();
    let cav = col_means.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n - temporal * gains.col_mean;
    let rav = row_means.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / m - temporal * gains.row_mean;
    // The split needs M, N >= 2 and MN > M + N; a 2 x 2 or one-line image has none.
    let d = if rows_cols_ok(rows, cols) { m * n - m - n } else { f64::NAN };
    [total, (m * n - n) / d * rav - m / d * (total - cav), (m * n - m) / d * cav - n / d * (total - rav), m * n / d * (total - cav - rav)]
}

/// DSNU and PRNU with their row, column and pixel parts (module documentation);
/// a value that is missing has its reason in the datasheet's `why` under its key.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Nonuniformity {
    /// DSNU, DN.
    pub dsnu_dn: Option<f64>,
    /// DSNU, e-.
    pub dsnu_e: Option<f64>,
    /// Row part of the DSNU, e-.
    pub dsnu_row_e: Option<f64>,
    /// Column part, e-.
    pub dsnu_col_e: Option<f64>,
    /// Pixel part, e-.
    pub dsnu_pixel_e: Option<f64>,
    /// PRNU, %.
    pub prnu_pct: Option<f64>,
    /// Row part of the PRNU, %.
    pub prnu_row_pct: Option<f64>,
    /// Column part, %.
    pub prnu_col_pct: Option<f64>,
    /// Pixel part, %.
    pub prnu_pixel_pct: Option<f64>,
}

/// Every key of [`Nonuniformity`].
pub const NONUNIFORMITY_KEYS: [&str; 9] = ["dsnu_dn", "dsnu_e", "dsnu_row_e", "dsnu_col_e", "dsnu_pixel_e", "prnu_pct", "prnu_row_pct", "prnu_col_pct", "prnu_pixel_pct"];

impl Nonuniformity {
    /// The DSNU and PRNU of a bright and a dark series' components at gain `k` (DN/e-),
    /// the reason for each missing one recorded in `why`.
    pub fn of(why: &mut std::collections::BTreeMap<String, String>, b: &Components, d: &Components, k: f64) -> Nonuniformity {
        let signal = b.mean_dn - d.mean_dn;
        let mut n = Nonuniformity {
            dsnu_dn: root(why, "dsnu_dn", d.total_dn2, 1.0, "the dark spatial"),
            dsnu_e: root(why, "dsnu_e", d.total_dn2, k, "the dark spatial"),
            dsnu_row_e: root(why, "dsnu_row_e", d.row_dn2, k, "the dark row"),
            dsnu_col_e: root(why, "dsnu_col_e", d.col_dn2, k, "the dark column"),
            dsnu_pixel_e: root(why, "dsnu_pixel_e", d.pixel_dn2, k, "the dark pixel"),
            ..Nonuniformity::default()
        };
        if signal > 0.0 {
            let pct = signal / 100.0;
            n.prnu_pct = root(why, "prnu_pct", b.total_dn2 - d.total_dn2, pct, "the bright minus dark spatial");
            n.prnu_row_pct = root(why, "prnu_row_pct", b.row_dn2 - d.row_dn2, pct, "the bright minus dark row");
            n.prnu_col_pct = root(why, "prnu_col_pct", b.col_dn2 - d.col_dn2, pct, "the bright minus dark column");
            n.prnu_pixel_pct = root(why, "prnu_pixel_pct", b.pixel_dn2 - d.pixel_dn2, pct, "the bright minus dark pixel");
        } else {
            for key in ["prnu_pct", "prnu_row_pct", "prnu_col_pct", "prnu_pixel_pct"] {
                why.insert(key.into(), format!("the bright spatial series is {signal:.3} DN above dark: no photo response to compare"));
            }
        }
        n
    }
}

/// `sqrt(variance) / scale` when the variance is positive; else `None` with the reason
/// under `key`.
fn root(why: &mut std::collections::BTreeMap<String, String>, key: &str, variance: f64, scale: f64, what: &str) -> Option<f64> {
    if variance.is_finite() && variance >= 0.0 && scale.is_finite() && scale > 0.0 {
        Some(variance.sqrt() / scale)
    } else if variance.is_nan() {
        why.insert(key.into(), "the row, column and pixel split needs at least 2 rows and 2 columns with MN > M + N".into());
        None
    } else {
        why.insert(key.into(), format!("{what} variance {variance:.4e} DN^2 is negative: below what the spatial series resolves"));
        None
    }
}

/// Whether a `rows x cols` image can be split into row, column and pixel parts: at least
/// two of each and `MN > M + N`.
pub fn rows_cols_ok(rows: usize, cols: usize) -> bool {
    rows >= 2 && cols >= 2 && rows * cols > rows + cols
}

/// The bright and dark spatial series of `set`, or why there are none: the standard
/// takes exactly one of each, at one exposure.
pub fn spatial_pair(set: &EmvaSet) -> Result<Option<(SpatialSeries, SpatialSeries)>, HostError> {
    let Some((b, d)) = spatial_levels(set)? else { return Ok(None) };
    let (b, d) = rayon::join(|| SpatialSeries::load(set, b), || SpatialSeries::load(set, d));
    Ok(Some((b?, d?)))
}

/// The bright and dark spatial levels of `set` (see [`spatial_pair`]).
pub fn spatial_levels(set: &EmvaSet) -> Result<Option<(&EmvaLevel, &EmvaLevel)>, HostError> {
    let spatial: Vec<&EmvaLevel> = set.levels.iter().filter(|l| l.series() == Some(Series::Spatial)).collect();
    if spatial.is_empty() {
        return Ok(None);
    }
    let bright: Vec<&&EmvaLevel> = spatial.iter().filter(|l| matches!(l.kind, LevelKind::Bright { .. })).collect();
    let dark: Vec<&&EmvaLevel> = spatial.iter().filter(|l| l.kind == LevelKind::Dark).collect();
    let (&[b], &[d]) = (&bright[..], &dark[..]) else {
        return Err(at_line(&set.path, spatial[0].line, DescriptorFault::SpatialLevels { bright: bright.len(), dark: dark.len() }));
    };
    if b.exposure != d.exposure {
        return Err(at_line(&set.path, d.line, DescriptorFault::SpatialExposures { dark: d.exposure, bright: b.exposure }));
    }
    Ok(Some((b, d)))
}

/// A spectrogram as EMVA 1288 defines it (Release 3.1 section 8.6): each row's discrete
/// Fourier transform (the image mean removed, `1/sqrt(N)` normalization), its power
/// averaged over the rows; `N/2 + 1` frequencies `0, 1/N, ..., 1/2` cycles per pixel.
/// `vertical` transforms the columns instead. Returns the amplitude (square root of the
/// mean power) in the image's units.
pub fn spectrogram(image: &[f64], rows: usize, cols: usize, vertical: bool) -> Vec<f64> {
    let (lines, len) = if vertical { (cols, rows) } else { (rows, cols) };
    let at = |line: usize, i: usize| if vertical { image[i * cols + line] } else { image[line * cols + i] };
    let mean = image.iter().sum::<f64>() / image.len() as f64;
    let fft = FftPlanner::<f64>::new().plan_fft_forward(len);
    let add = |mut a: Vec<f64>, b: Vec<f64>| {
        a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
        a
    };
    let line_numbers: Vec<usize> = (0..lines).collect();
    let power = crate::infra::parallel::fold_in_order(&line_numbers, lines.div_ceil(64), || vec![0.0; len], |acc, &line| {
        let mut buf: Vec<Complex<f64>> = (0..len).map(|i| Complex::new(at(line, i) - mean, 0.0)).collect();
        fft.process(&mut buf);
        add(acc, buf.iter().map(|c| c.norm_sqr() / len as f64).collect())
    }, add);
    power[..len / 2 + 1].iter().map(|p| (p / lines as f64).sqrt()).collect()
}

/// A histogram of integer values as EMVA 1288 bins it (the reference's `Histogram1288`):
/// bins of integer width `W`, as many as fit up to `max_bins` over `[min, max]`; each bin
/// labelled by its lower edge.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Histogram {
    /// Lower edge of each bin, in the caller's units (the integers divided by `scale`).
    pub bins: Vec<f64>,
    /// Pixels in each bin.
    pub counts: Vec<u64>,
}

/// Bins integer `values` (module documentation): `W = 1` when the range fits
/// `max_bins`, else `floor((max - min) / max_bins) + 1`; edges divided by `scale`.
pub fn histogram(values: &[i64], max_bins: usize, scale: f64) -> Histogram {
    let (Some(&min), Some(&max)) = (values.iter().min(), values.iter().max()) else {
        return Histogram { bins: Vec::new(), counts: Vec::new() };
    };
    let range = (max - min) as u64;
    let (width, bins) = if range < max_bins as u64 { (1, range + 1) } else {
        let w = range / max_bins as u64 + 1;
        (w, range / w + 1)
    };
    let mut counts = vec![0u64; bins as usize];
    for &v in values {
        // numpy's histogram puts the maximum into the last bin.
        let i = (((v - min) as u64) / width).min(bins - 1);
        counts[i as usize] += 1;
    }
    Histogram { bins: (0..bins).map(|i| (min + (i * width) as i64) as f64 / scale).collect(), counts }
}

/// The EMVA 1288 high-pass filter of a `rows x cols` integer image: each pixel minus the
/// mean of the `5 x 5` box around it, kept in integers as `25 y - box sum` (so the result
/// is 25 times the filtered value); only pixels whose box lies inside the image, giving a
/// `(rows - 4) x (cols - 4)` image. Removes illumination gradients so that the PRNU
/// histogram shows pixels, not the light source.
pub fn high_pass_5x5(image: &[i64], rows: usize, cols: usize) -> (Vec<i64>, usize, usize) {
    if rows < 5 || cols < 5 {
        return (Vec::new(), 0, 0);
    }
    let (out_rows, out_cols) = (rows - 4, cols - 4);
    let out = (0..out_rows)
        .into_par_iter()
        .flat_map_iter(|r| {
            (0..out_cols).map(move |c| {
                let mut box_sum = 0i64;
                for dr in 0..5 {
                    box_sum += image[(r + dr) * cols + c..(r + dr) * cols + c + 5].iter().sum::<i64>();
                }
                25 * image[(r + 2) * cols + c + 2] - box_sum
            })
        })
        .collect();
    (out, out_rows, out_cols)
}

/// The accumulated (complementary cumulative) form of a histogram of absolute
/// deviations, in percent of the pixels: entry `i` is the share of pixels at or beyond
/// bin `i`'s lower edge.
pub fn accumulated_percent(h: &Histogram) -> Vec<f64> {
    let total: u64 = h.counts.iter().sum();
    let mut acc = 0u64;
    let mut out: Vec<f64> = h
        .counts
        .iter()
        .rev()
        .map(|&c| {
            acc += c;
            100.0 * acc as f64 / total as f64
        })
        .collect();
    out.reverse();
    out
}

/// Outlier threshold of the defect-pixel counts, in robust standard deviations: a
/// Gaussian population gives 2e-9 false defects per pixel (under 0.001 on a 640 x 480
/// sensor).
pub const DEFECT_SIGMAS: f64 = 6.0;
/// A pixel responding with less than this share of its neighbourhood's mean is dead.
pub const DEAD_RESPONSE: f64 = 0.5;

/// Defect pixels of the averaged images. EMVA 1288 (Release 4.0 section 4.4) defines no
/// counts ("it will not be possible to find a common denominator to exactly define when
/// a pixel is defective") and leaves the stop band of its histograms to the user; these
/// are dncal's criteria, on the standard's images:
///
/// - **hot**: the averaged dark image above its median by more than [`DEFECT_SIGMAS`]
///   robust standard deviations (1.4826 x the median absolute deviation, at least the
///   temporal noise of the average);
/// - **dead**: the averaged bright-minus-dark image below [`DEAD_RESPONSE`] of the
///   median of its `5 x 5` neighbourhood (clipped at the edges, at least `3 x 3`);
/// - **high PRNU**: not dead, and the averaged bright-minus-dark image off the median of
///   its `5 x 5` neighbourhood by more than [`DEFECT_SIGMAS`] robust standard deviations
///   of that difference (a median high-pass: the standard's box high-pass would let one
///   dead pixel push its neighbours over the threshold).
///
/// Where the response has a pattern periodic in rows and columns ([`CellPattern`]: a
/// colour filter's channels), a pixel's neighbourhood is its own cell's pixels a period
/// apart (the `5 x 5` of that channel's image) and its departure is divided by its
/// cell's response, so each channel is its own population (EMVA 1288 treats a colour
/// camera's channels apart).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DefectPixels {
    /// Hot pixels.
    pub hot: usize,
    /// Dead pixels.
    pub dead: usize,
    /// High-PRNU pixels.
    pub high_prnu: usize,
    /// Pixels of any kind (a pixel counts once).
    pub total: usize,
    /// The hot threshold above the dark median, DN.
    pub hot_threshold_dn: f64,
    /// The high-PRNU threshold on the response's departure from its neighbourhood, DN
    /// (where there is a response pattern, DN of the mean cell's response).
    pub prnu_threshold_dn: f64,
    /// Positions `(row, column)` of the first 1000 defects, row-major.
    pub positions: Vec<(usize, usize)>,
    /// A response pattern periodic in rows and columns (a colour filter's channels,
    /// interleaved column ADCs' gains), where the image has one: each pixel was held
    /// against its own cell's neighbours and its departure scaled by its cell's response.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cells: Option<CellPattern>,
}

impl DefectPixels {
    /// What the counts were taken against beyond the criteria: the response pattern,
    /// where there is one ("" without).
    pub fn against(&self) -> String {
        self.cells.as_ref().map_or(String::new(), |c| format!("; each pixel against its own cell of {}", c.describe()))
    }
}


/// A pixel's defect kinds, bits of [`DefectMap::kind`].
pub const HOT: u8 = 1;
/// Dead.
pub const DEAD: u8 = 2;
/// High PRNU.
pub const HIGH_PRNU: u8 = 4;

/// Counts the defect pixels of a bright and a dark spatial series (see [`DefectPixels`]).
pub fn defect_pixels(bright: &SpatialSeries, dark: &SpatialSeries, bright_stack_dn2: f64, dark_stack_dn2: f64) -> DefectPixels {
    let DefectMap { kind, hot_threshold_dn, prnu_threshold_dn, cells, .. } = defect_map(bright, dark, bright_stack_dn2, dark_stack_dn2);
    let cols = dark.cols;
    let count = |bit: u8| kind.iter().filter(|&&k| k & bit != 0).count();
    DefectPixels {
        hot: count(HOT),
        dead: count(DEAD),
        high_prnu: count(HIGH_PRNU),
        total: kind.iter().filter(|&&k| k != 0).count(),
        hot_threshold_dn,
        prnu_threshold_dn,
        positions: kind.iter().enumerate().filter(|(_, &k)| k != 0).take(1000).map(|(i, _)| (i / cols, i % cols)).collect(),
        cells,
    }
}

/// Every pixel's defect classification (see [`DefectPixels`]).
#[derive(Debug, Clone)]
pub struct DefectMap {
    /// Kinds, row-major ([`HOT`], [`DEAD`], [`HIGH_PRNU`] bits).
    pub kind: Vec<u8>,
    /// The larger of the pixel's dark departure and response departure, in their robust
    /// standard deviations (the border's response departure is 0).
    pub score: Vec<f64>,
    /// The hot threshold, DN.
    pub hot_threshold_dn: f64,
    /// The high-PRNU threshold, DN.
    pub prnu_threshold_dn: f64,
    /// The response pattern each pixel was held against its own cell of, where the
    /// image has one ([`CellPattern`]).
    pub cells: Option<CellPattern>,
}

/// Every pixel's defect kinds and score (see [`DefectPixels`] for the criteria).
pub fn defect_map(bright: &SpatialSeries, dark: &SpatialSeries, bright_stack_dn2: f64, dark_stack_dn2: f64) -> DefectMap {
    let (rows, cols) = (dark.rows, dark.cols);
    let (lb, ld) = (bright.frames as f64, dark.frames as f64);
    let dark_mean: Vec<f64> = dark.sum.iter().map(|&v| v as f64 / ld).collect();
    let (dark_centre, dark_sigma) = robust(&dark_mean);
    let hot_threshold = DEFECT_SIGMAS * dark_sigma.max((dark_stack_dn2 / ld).sqrt());
    let mut kind = vec![0u8; rows * cols];
    let mut score: Vec<f64> = dark_mean.iter().map(|v| (v - dark_centre).abs() * DEFECT_SIGMAS / hot_threshold.max(1e-300)).collect();
    for (k, &v) in kind.iter_mut().zip(&dark_mean) {
        if v - dark_centre > hot_threshold {
            *k |= HOT;
        }
    }
    // Bright minus dark in units of 1/(lb ld) DN, exact in integers; each interior pixel
    // against the median of its 5 x 5 neighbourhood (a median, not the standard's box
    // mean, so that one dead or hot neighbour does not make its neighbours defects; on a
    // plane the median of the symmetric window is the centre value, so gradients cancel).
    let response: Vec<i64> = bright.sum.iter().zip(&dark.sum).map(|(&b, &d)| b * dark.frames as i64 - d * bright.frames as i64).collect();
    let unit = lb * ld;
    // A response pattern periodic in rows and columns (a colour filter's channels): each
    // pixel against its own cell's neighbours (the pixels a period apart), its departure
    // over its cell's response ([`CellPattern`]); without one, period 1.
    let cells = CellPattern::find(&response.iter().map(|&v| v as f64).collect::<Vec<_>>(), cols);
    let p = cells.as_ref().map_or(1, |c| c.period);
    let relative = |i: usize| cells.as_ref().map_or(1.0, |c| c.at(i / cols, i % cols));
    // The pixels of `x`'s cell within 2 periods of it, in `0..n`.
    let span = |x: usize, n: usize| (x - p * (x / p).min(2)..=x + p * ((n - 1 - x) / p).min(2)).step_by(p);
    // Each pixel against the median of the 5 x 5 window around it (of its cell's pixels),
    // clipped at the image's edges (at least 3 x 3 pixels: a corner's), so that border
    // pixels are classified too.
    let local: Vec<Option<(f64, f64)>> = (0..rows * cols)
        .into_par_iter()
        .map(|i| {
            let (r, c) = (i / cols, i % cols);
            let response = &response;
            let mut window: Vec<i64> = span(r, rows).flat_map(|rr| span(c, cols).map(move |cc| response[rr * cols + cc])).collect();
            if window.len() < 9 {
                return None;
            }
            let mid = window.len() / 2;
            let (_, &mut med, _) = window.select_nth_unstable(mid);
            Some((response[i] as f64 / unit, med as f64 / unit))
        })
        .collect();
    // Departures over the cell's response: in the units of the mean cell's.
    let deviation: Vec<f64> = local.iter().enumerate().filter_map(|(i, l)| l.map(|(v, m)| (v - m) / relative(i))).collect();
    let (dev_centre, dev_sigma) = robust(&deviation);
    let temporal = (bright_stack_dn2 / lb + dark_stack_dn2 / ld).sqrt();
    let prnu_threshold = DEFECT_SIGMAS * dev_sigma.max(temporal);
    for (at, l) in local.iter().enumerate() {
        let Some(&(value, neighbourhood)) = l.as_ref() else { continue };
        let departure = (value - neighbourhood) / relative(at) - dev_centre;
        score[at] = score[at].max(departure.abs() * DEFECT_SIGMAS / prnu_threshold.max(1e-300));
        if neighbourhood > 0.0 && value < DEAD_RESPONSE * neighbourhood {
            kind[at] |= DEAD;
        } else if departure.abs() > prnu_threshold {
            kind[at] |= HIGH_PRNU;
        }
    }
    DefectMap { kind, score, hot_threshold_dn: hot_threshold, prnu_threshold_dn: prnu_threshold, cells }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A series built from explicit frames.
    fn series(frames: &[Vec<i64>], rows: usize, cols: usize) -> SpatialSeries {
        let n = rows * cols;
        let mut sum = vec![0i64; n];
        let mut sum_sq = vec![0i64; n];
        for f in frames {
            for i in 0..n {
                sum[i] += f[i];
                sum_sq[i] += f[i] * f[i];
            }
        }
        SpatialSeries { frames: frames.len(), rows, cols, photons: 0.0, exposure: 0.0, line: 0, sum, sum_sq }
    }

    /// Frames of planted independent row, column and pixel offsets (rms 2, 3 and 1.5 DN)
    /// beside temporal noise of 2 DN rms over 4 frames: each component must come out as
    /// its planted variance, the temporal noise taken out, within about three of its
    /// standard errors (500 rows and columns: 6% for the row and column parts).
    #[test]
    fn components_recover_planted_row_column_pixel_variances() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let (rows, cols, frames) = (500, 500, 4);
        let mut rng = rand::rngs::StdRng::seed_from_u64(1288);
        let draw = |sd: f64, n: usize, rng: &mut rand::rngs::StdRng| -> Vec<f64> {
            let d = Normal::new(0.0, sd).unwrap();
            (0..n).map(|_| d.sample(rng)).collect()
        };
        let (a, b, e) = (draw(2.0, rows, &mut rng), draw(3.0, cols, &mut rng), draw(1.5, rows * cols, &mut rng));
        // Codes scaled by 16 so that rounding (1/12 of 1/256 DN^2) is negligible.
        let temporal = Normal::new(0.0, 2.0).unwrap();
        let list: Vec<Vec<i64>> = (0..frames)
            .map(|_| (0..rows * cols).map(|i| (16.0 * (1000.0 + a[i / cols] + b[i % cols] + e[i] + temporal.sample(&mut rng))).round() as i64).collect())
            .collect();
        let c = series(&list, rows, cols).components(Release::R3);
        let scale = 256.0; // variances in (DN/16)^2
        for (what, got, planted, tolerance) in [
            ("stack", c.stack_var_dn2 / scale, 4.0, 0.02),
            ("row", c.row_dn2 / scale, 4.0, 0.2),
            ("col", c.col_dn2 / scale, 9.0, 0.2),
            ("pixel", c.pixel_dn2 / scale, 2.25, 0.03),
            ("total", c.total_dn2 / scale, 4.0 + 9.0 + 2.25, 0.15),
        ] {
            assert!((got / planted - 1.0).abs() < tolerance, "{what}: {got} for {planted}");
        }
    }

    /// Release 4.0's filter keeps a white pixel pattern (1% PRNU at 1000 DN, 100 DN^2) and
    /// drops a 3% illumination fall-off towards the corners that Release 3.1 counts: the
    /// filtered total and pixel variances are the planted one times the filter's white
    /// gain 0.9885 (within 3%: 182 x 182 filtered pixels), the temporal noise (5 DN rms
    /// over 4 frames) taken out as it passes the filter; 3.1's total is well above it.
    #[test]
    fn release_4_filters_out_the_illumination() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let (rows, cols, frames) = (200, 200, 4);
        let mut rng = rand::rngs::StdRng::seed_from_u64(40);
        let pattern = Normal::new(0.0, 10.0).unwrap();
        let e: Vec<f64> = (0..rows * cols).map(|_| pattern.sample(&mut rng)).collect();
        let light = |i: usize| {
            let (y, x) = ((i / cols) as f64 / (rows - 1) as f64 - 0.5, (i % cols) as f64 / (cols - 1) as f64 - 0.5);
            1000.0 * (1.0 - 0.06 * (x * x + y * y))
        };
        let temporal = Normal::new(0.0, 5.0).unwrap();
        let list: Vec<Vec<i64>> =
            (0..frames).map(|_| (0..rows * cols).map(|i| (16.0 * (light(i) + e[i] + temporal.sample(&mut rng))).round() as i64).collect()).collect();
        let scale = 256.0;
        let planted = 100.0 * super::super::highpass::NoiseGains::filtered(rows - 18, cols - 18).pixel;
        let s = series(&list, rows, cols);
        let (r3, r4) = (s.components(Release::R3), s.components(Release::R4));
        assert!((r4.total_dn2 / scale / planted - 1.0).abs() < 0.03, "4.0 total {} for {planted}", r4.total_dn2 / scale);
        assert!((r4.pixel_dn2 / scale / planted - 1.0).abs() < 0.03, "4.0 pixel {} for {planted}", r4.pixel_dn2 / scale);
        assert!(r3.total_dn2 / scale > 1.3 * 100.0, "3.1 total {} should include the fall-off", r3.total_dn2 / scale);
        assert_eq!(r3.mean_dn, r4.mean_dn);
        // Too small for the filter: no variances, and the datasheet says why.
        let small = series(&[vec![5; 19 * 40], vec![6; 19 * 40]], 19, 40).components(Release::R4);
        assert!(small.total_dn2.is_nan() && small.pixel_dn2.is_nan());
    }

    /// A 2 x 2 image (MN = M + N) or a single row or column has no row/column/pixel split:
    /// NaN (reported as null with its reason), where the formulas would divide by zero or
    /// by a negative number; the total stays.
    #[test]
    fn degenerate_sizes_have_no_split() {
        assert!(!rows_cols_ok(2, 2) && !rows_cols_ok(1, 24) && !rows_cols_ok(24, 1) && rows_cols_ok(3, 3));
        for (rows, cols) in [(2, 2), (1, 6), (6, 1)] {
            let frames: Vec<Vec<i64>> = (0..3).map(|f| (0..rows * cols).map(|i| 10 + i as i64 + f).collect()).collect();
            let c = series(&frames, rows, cols).components(Release::R3);
            assert!(c.row_dn2.is_nan() && c.col_dn2.is_nan() && c.pixel_dn2.is_nan(), "{rows} x {cols}: {c:?}");
            assert!(c.total_dn2.is_finite());
        }
    }

    #[test]
    fn temporal_noise_is_taken_out_of_the_spatial_variance() {
        // Two pixels, three frames: per-pixel variances (1/(L-1)) 1 and 4; the mean image
        // [11, 22]: measured spatial variance (1/(MN-1)) 60.5 before the correction.
        let frames = vec![vec![10, 20], vec![11, 22], vec![12, 24]];
        let s = series(&frames, 1, 2);
        let c = s.components(Release::R3);
        assert!((c.stack_var_dn2 - 2.5).abs() < 1e-12, "{c:?}");
        assert!((c.total_dn2 - (60.5 - 2.5 / 3.0)).abs() < 1e-12, "{c:?}");
    }

    #[test]
    fn histogram_bins_like_the_reference() {
        let h = histogram(&[0, 1, 1, 3], 256, 1.0);
        assert_eq!((h.bins, h.counts), (vec![0.0, 1.0, 2.0, 3.0], vec![1, 2, 0, 1]));
        // Range 1000 over at most 256 bins: width floor(1000/256)+1 = 4, 251 bins.
        let values: Vec<i64> = (0..=1000).collect();
        let h = histogram(&values, 256, 2.0);
        assert_eq!(h.counts.len(), 251);
        assert_eq!(h.bins[1], 2.0);
        assert_eq!(h.counts.iter().sum::<u64>(), 1001);
        assert_eq!(h.counts[250], 1, "the maximum goes into the last bin");
        assert_eq!(accumulated_percent(&Histogram { bins: vec![0.0, 1.0], counts: vec![3, 1] }), vec![100.0, 25.0]);
    }

    #[test]
    fn high_pass_removes_gradients_and_keeps_a_spike() {
        let (rows, cols) = (7, 9);
        let mut img: Vec<i64> = (0..rows * cols).map(|i| 5 * (i / cols) as i64 + 3 * (i % cols) as i64).collect();
        let (flat, r, c) = high_pass_5x5(&img, rows, cols);
        assert_eq!((r, c), (3, 5));
        assert!(flat.iter().all(|&v| v == 0), "a linear gradient is removed: {flat:?}");
        img[3 * cols + 4] += 100;
        let (spiked, _, _) = high_pass_5x5(&img, rows, cols);
        assert_eq!(spiked[cols - 4 + 2], 2400, "25 x 100 minus its own share in the box");
    }

    /// Planted defects on a smooth illumination gradient with Gaussian nonuniformity, some
    /// on the border: each kind counted exactly, nothing else (6 sigma over 4,096 pixels:
    /// no false ones).
    #[test]
    fn defect_pixels_count_planted_hot_dead_and_high_prnu_pixels() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let (rows, cols, frames) = (64, 64, 8);
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let (dsnu, prnu, noise) = (Normal::new(0.0, 1.0).unwrap(), Normal::new(0.0, 0.01).unwrap(), Normal::new(0.0, 1.0).unwrap());
        let offset: Vec<f64> = (0..rows * cols).map(|_| 100.0 + dsnu.sample(&mut rng)).collect();
        let mut gain: Vec<f64> = (0..rows * cols).map(|_| 1.0 + prnu.sample(&mut rng)).collect();
        let hot = [5 * cols + 9, 40 * cols + 1, 63 * cols + 63];
        // One dead pixel on the top edge and one high-PRNU pixel on the right edge: the
        // window is clipped there, not the pixel left out.
        let dead = [10 * cols + 10, 30 * cols + 50, 7];
        let high = [20 * cols + 20, 50 * cols + 33, 33 * cols + 44, 12 * cols + 40, 40 * cols + 63];
        let mut offset_hot = offset.clone();
        hot.iter().for_each(|&i| offset_hot[i] += 80.0);
        dead.iter().for_each(|&i| gain[i] = 0.0);
        high.iter().for_each(|&i| gain[i] *= 1.3);
        let frame = |light: bool, rng: &mut rand::rngs::StdRng| -> Vec<i64> {
            (0..rows * cols)
                .map(|i| {
                    let illumination = 1000.0 + 5.0 * (i / cols) as f64 + 3.0 * (i % cols) as f64;
                    let signal = if light { gain[i] * illumination } else { 0.0 };
                    (offset_hot[i] + signal + noise.sample(rng)).round() as i64
                })
                .collect()
        };
        let bright: Vec<Vec<i64>> = (0..frames).map(|_| frame(true, &mut rng)).collect();
        let dark: Vec<Vec<i64>> = (0..frames).map(|_| frame(false, &mut rng)).collect();
        let (b, d) = (series(&bright, rows, cols), series(&dark, rows, cols));
        let (cb, cd) = (b.components(Release::R3), d.components(Release::R3));
        let found = defect_pixels(&b, &d, cb.stack_var_dn2, cd.stack_var_dn2);
        assert_eq!((found.hot, found.dead, found.high_prnu, found.total), (3, 3, 5, 11), "{found:?}");
        let mut planted: Vec<(usize, usize)> = hot.iter().chain(&dead).chain(&high).map(|&i| (i / cols, i % cols)).collect();
        planted.sort_unstable();
        assert_eq!(found.positions, planted);
    }

    /// A pure cosine along the rows: its spectrogram is one line, at the cosine's frequency.
    #[test]
    fn spectrogram_of_a_cosine_is_one_line() {
        let (rows, cols, k) = (4, 32, 5);
        let img: Vec<f64> = (0..rows * cols).map(|i| 7.0 + 2.0 * (2.0 * std::f64::consts::PI * k as f64 * (i % cols) as f64 / cols as f64).cos()).collect();
        let s = spectrogram(&img, rows, cols, false);
        assert_eq!(s.len(), cols / 2 + 1);
        // |X_k|^2 / N = (N A / 2)^2 / N = N A^2 / 4: amplitude sqrt(N) A / 2.
        let expected = (cols as f64).sqrt() * 2.0 / 2.0;
        for (i, &v) in s.iter().enumerate() {
            if i == k {
                assert!((v - expected).abs() < 1e-9, "{v}");
            } else {
                assert!(v < 1e-9, "bin {i}: {v}");
            }
        }
        // Down the columns each column is constant: only frequency 0 carries power, the
        // column's offset from the image mean d_c = 2 cos(..): |X_0|^2 / M = M d_c^2,
        // averaged over columns (mean d_c^2 = 2).
        let vertical = spectrogram(&img, rows, cols, true);
        assert!((vertical[0] - (rows as f64 * 2.0).sqrt()).abs() < 1e-9, "{}", vertical[0]);
        assert!(vertical[1..].iter().all(|&v| v < 1e-9), "no structure down the columns");
    }
}
