//! Pixel-to-pixel gain variation and nonlinearity (de Wijn 2018, section 5, Figs. 7-8).
//!
//! Input: a linearity set (mean and standard-deviation frames at levels from dark to
//! saturation, and a linear reference detector's voltage per level; `docs/formats.md`).
//!
//! ## Definitions
//! - Normalized reference `x_l = V_l / max V`; the *gain level* `g` is the level whose
//!   `x` is nearest 1/2 (in the default 41-level set, level index 20, about 51% of
//!   saturation; the paper's example flat, Fig. 6, is near 57%), level 0 is dark. A level is *expected*
//!   to read the normalized intensity `e_l = (x_l - x_0) / (x_g - x_0)`.
//! - A pixel's level is *saturated* when its mean is within `4 max(std, 0.5)` DN of the
//!   top code, or when its temporal noise falls below half the previous level's in the
//!   upper half of the range (clipping below the top code); it and every level above are
//!   left out for that pixel.
//! - *Masked* pixels: the set's `MASK`, pixels whose signal at the gain level is below half
//!   the median of their cell of a 2 x 2 period (a colour filter's channel: issue 58),
//!   and pixels whose own 4th-order fit leaves an rms residual above 10 times the median
//!   of their cell (anomalous trends: dead, hot, stuck pixels). Masked pixels are left out
//!   of every statistic and replaced in corrected images by the mean of their good
//!   neighbours (8-connected).
//!
//! ## The three corrections, per pixel `p` and level `l`, with mean `m_l(p)` DN
//! - **raw**: `c = m_l(p) / <m_l>` (the pixel against the mean of the good pixels); its
//!   residual is `c - 1`: the fixed-pattern structure of the paper's Fig. 7, left.
//! - **standard**: a global cubic `f` fitted to `x_l` against the median pixel's mean,
//!   applied to every pixel, then dark and gain: `c = (f(m_l) - f(m_0)) / (f(m_g) - f(m_0))`.
//! - **pixel-wise**: per pixel the 4th-order polynomial `m = P_p(x) = sum_k a_k x^k` fitted
//!   by least squares to its unsaturated levels; the correction inverts it,
//!   `x^_l = P_p^-1(m_l)` (Newton from the linear guess), then dark and gain:
//!   `c = (x^_l - x^_0) / (x^_g - x^_0)`.
//!
//! For the standard and pixel-wise corrections the residual is `c - e_l`. The RMS of a
//! level is over the good, unsaturated pixels. The *random* noise is the frames' standard
//! deviation over `sqrt(NFRAMES)` propagated through the dark and gain correction:
//! `sigma_c = sqrt(s_l^2 + (c s_g)^2 + ((1 - c) s_0)^2) / (m_g - m_0)`, `s = std / sqrt(N)`.
//!
//! All pixels share the design matrix of a level prefix, so the least-squares fit is one
//! precomputed pseudo-inverse per distinct number of unsaturated levels: a matrix-vector
//! product per pixel.

use nalgebra::DMatrix;
use rayon::prelude::*;
use serde::Serialize;

use crate::formats::fits::{LinearitySet, Sample, SetView};
use crate::infra::stats::median;

pub mod held_out;
mod inverse;
pub mod paper_fig8;
pub mod run;
pub mod stages;
pub use inverse::invert;
use inverse::poly;
use stages::{counted_means, MaskRule, Plan};

/// Order of the pixel-wise polynomial (the paper: 4; higher did not help).
pub const PIXEL_ORDER: usize = 4;
/// The highest order `analyze` accepts (the powers of x in [0, 1] grow collinear).
pub const MAX_ORDER: usize = 8;
/// Order of the global nonlinearity of the standard correction (the paper: 3).
pub const GLOBAL_ORDER: usize = 3;

/// Why a pixel is masked (bit flags).
pub mod reason {
    /// In the set's MASK extension.
    pub const INPUT: u8 = 1;
    /// Signal at the gain level below half the median.
    pub const LOW: u8 = 2;
    /// Pixel-wise fit residual above 10x the median.
    pub const TREND: u8 = 4;
    /// Too few unsaturated levels to fit, or non-finite data.
    pub const UNFIT: u8 = 8;
}

/// The analysis of one set.
#[derive(Debug, Clone, Serialize)]
pub struct LinearityReport {
    /// Levels, dark included.
    pub levels: usize,
    /// Pixels in a frame.
    pub pixels: usize,
    /// The gain (flat) level.
    pub gain_level: usize,
    /// Expected normalized intensity of each level (1 at the gain level).
    pub intensity: Vec<f64>,
    /// Normalized reference `x = V / max V` of each level.
    pub reference: Vec<f64>,
    /// RMS residual per level, raw (NaN at level 0).
    pub rms_raw: Vec<f64>,
    /// RMS residual per level, standard correction (NaN at the dark and gain levels, where
    /// it is zero by construction).
    pub rms_standard: Vec<f64>,
    /// RMS residual per level, pixel-wise correction (NaN at dark and gain).
    pub rms_pixelwise: Vec<f64>,
    /// Propagated random noise per level (NaN at dark and gain): the frames' standard
    /// deviations over sqrt(N) of the level, the flat and the dark, through the linear dark
    /// and gain correction.
    pub rms_random: Vec<f64>,
    /// The paper's three dashed curves of Fig. 8. Raw: `s_l / <m_l>`.
    pub rms_random_raw: Vec<f64>,
    /// Standard: through the global cubic's slope, dark and gain.
    pub rms_random_standard: Vec<f64>,
    /// Pixel-wise: through the inverse polynomial's slope `1 / P_p'`, dark and gain.
    pub rms_random_pixelwise: Vec<f64>,
    /// The level's own noise alone, `s_l / (m_g - m_0)`, without the flat's and dark's:
    /// the part that averages away over levels (the flat's and dark's noise is one fixed
    /// error per pixel, repeated at every level, growing as `c` and `1 - c`).
    pub rms_random_level_only: Vec<f64>,
    /// Mean of the good, unsaturated pixels per level, DN (the raw correction's divisor).
    pub level_mean_dn: Vec<f64>,
    /// max over levels of `rms_raw`.
    pub rms_raw_max: f64,
    /// max over levels of `rms_standard`.
    pub rms_standard_max: f64,
    /// max over levels of `rms_pixelwise`.
    pub rms_pixelwise_max: f64,
    /// max over levels of `rms_random`.
    pub rms_random_max: f64,
    /// Masked pixels.
    pub masked_pixels: usize,
    /// Order of the pixel-wise polynomial.
    pub order: usize,
    /// Global cubic of the standard correction, `x = sum c_k (m / top)^k`.
    pub global_coefficients: Vec<f64>,
}

/// The per-pixel results, for the FITS outputs.
#[derive(Debug, Clone)]
pub struct PixelResults {
    /// Coefficients `a_k` of `m = sum a_k x^k`, k-major: `coeffs[(k * height + row) * width + col]`;
    /// NaN for unfitted pixels.
    pub coeffs: Vec<f64>,
    /// Mask reasons per pixel (0 = good).
    pub mask: Vec<u8>,
    /// Pixel-wise corrected normalized intensity per level, masked pixels filled from
    /// their good neighbours, laid out as the set's mean cube: where it was asked for
    /// ([`Cube::Keep`]).
    pub corrected: Option<Vec<f64>>,
}

/// Whether an analysis keeps the corrected cube (for the FITS outputs and the example
/// row) or only its statistics: without the cube, the pixel-levels no statistic counts
/// (masked pixels, saturated levels) are not inverted, and the cube's 8 bytes a pixel and
/// level are never allocated.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Cube {
    /// Keep it.
    Keep,
    /// Statistics only.
    Skip,
}

/// Least-squares pseudo-inverse `(A^T A)^-1 A^T` of the Vandermonde matrix of `x` up to
/// `order`, via SVD (robust for the near-collinear powers of x in [0, 1]).
fn pseudo_inverse(x: &[f64], order: usize) -> DMatrix<f64> {
    let a = DMatrix::from_fn(x.len(), order + 1, |r, c| x[r].powi(c as i32));
    a.pseudo_inverse(1e-13).unwrap_or_else(|_| DMatrix::zeros(order + 1, x.len()))
}

/// Replaces masked pixels of one `width x height` image by the mean of their good
/// 8-neighbours (left as they are when none is good).
pub fn fill_masked(image: &mut [f64], mask: &[u8], width: usize, height: usize) {
    stages::fill_cube(image, mask, width, height);
}

/// Per pixel, how many levels from dark up are unsaturated (they form a prefix): a level
/// is saturated at the top code (within `4 max(std, 0.5)` DN), or where the temporal
/// noise collapses to less than half the previous level's while the signal is in the
/// upper half of the range (a sensor or amplifier that clips below the top code, as the
/// real EMVA CCD does at 4080 DN with zero variance), or where the data are not finite.
pub fn unsaturated_levels<T: Sample>(set: &SetView<'_, T>) -> Vec<usize> {
    let (nl, np) = (set.levels, set.width * set.height);
    let top = ((1u64 << set.bit_depth) - 1) as f64;
    let m = |l: usize, p: usize| -> f64 { set.mean[l * np + p].into() };
    let sd = |l: usize, p: usize| -> f64 { set.std[l * np + p].into() };
    let saturated = |l: usize, p: usize| saturated_at(l, top, |l| m(l, p), |l| sd(l, p));
    // Level by level over blocks of pixels: the cube is level-major, so a pixel's levels
    // are a frame apart and walking them pixel by pixel misses the cache at every level.
    const BLOCK: usize = 4096;
    let mut valid = vec![nl; np];
    valid.par_chunks_mut(BLOCK).enumerate().for_each(|(b, block)| {
        let first = b * BLOCK;
        for l in 0..nl {
            for (i, v) in block.iter_mut().enumerate() {
                if *v == nl && saturated(l, first + i) {
                    *v = l;
                }
            }
        }
    });
    valid
}

/// Whether a pixel whose mean and frame deviation at level `k` are `m(k)` and `sd(k)`
/// is saturated at level `l` (see [`unsaturated_levels`]); `top` is the top code.
pub(crate) fn saturated_at(l: usize, top: f64, m: impl Fn(usize) -> f64, sd: impl Fn(usize) -> f64) -> bool {
    !(m(l).is_finite() && sd(l).is_finite()) || m(l) >= top - 4.0 * sd(l).max(0.5) || (l > 0 && m(l) > 0.5 * top && sd(l) < 0.5 * sd(l - 1))
}

/// The paper's Fig. 7 data: `n` consecutive pixels centered in the region's middle row,
/// per level from 1 on (`values[level - 1][i]`), the normalized value of each correction:
/// raw `m_l / <m_l>`, standard and pixel-wise `c / e_l`. NaN where the pixel is masked or
/// saturated at that level (the paper's lines break there too).
#[derive(Debug, Clone)]
pub struct ExampleRow {
    /// Row of the region.
    pub row: usize,
    /// First column of the region.
    pub first_column: usize,
    /// Raw, `[level - 1][pixel]`.
    pub raw: Vec<Vec<f64>>,
    /// Standard correction.
    pub standard: Vec<Vec<f64>>,
    /// Pixel-wise correction.
    pub pixelwise: Vec<Vec<f64>>,
}

/// See [`ExampleRow`]; `report`, `px` and its `corrected` cube are [`analyze`]'s of `set`.
pub fn example_row(set: &LinearitySet, report: &LinearityReport, px: &PixelResults, corrected: &[f64], n: usize) -> ExampleRow {
    let (nl, w, h) = (set.levels, set.width, set.height);
    let np = w * h;
    let n = n.min(w);
    let (row, first_column) = (h / 2, (w - n) / 2);
    let top = ((1u64 << set.bit_depth) - 1) as f64;
    let f = |v: f64| poly(&report.global_coefficients, v / top);
    let m = |l: usize, p: usize| set.mean[l * np + p];
    let valid = unsaturated_levels(&set.view());
    let g = report.gain_level;
    let pixels: Vec<usize> = (first_column..first_column + n).map(|c| row * w + c).collect();
    let per_level = |value: &dyn Fn(usize, usize) -> f64| -> Vec<Vec<f64>> {
        (1..nl).map(|l| pixels.iter().map(|&p| if px.mask[p] == 0 && l < valid[p] { value(l, p) } else { f64::NAN }).collect()).collect()
    };
    let e = &report.intensity;
    ExampleRow {
        row,
        first_column,
        raw: per_level(&|l, p| m(l, p) / report.level_mean_dn[l]),
        standard: per_level(&|l, p| (f(m(l, p)) - f(m(0, p))) / (f(m(g, p)) - f(m(0, p))) / e[l]),
        pixelwise: per_level(&|l, p| corrected[l * np + p] / e[l]),
    }
}

/// Analyzes `set` with the pixel-wise polynomial of `order` (clamped to 1..=[`MAX_ORDER`]):
/// masks, the three corrections, their RMS per level, the random noise.
pub fn analyze(set: &LinearitySet, order: usize) -> Result<(LinearityReport, PixelResults), LinearityError> {
    analyze_with_flat(set, order, None)
}

/// [`analyze`] with the flat (gain) level chosen: `Some(l)` with `1 <= l < levels` (the
/// caller checks, [`check_flat_level`]), `None` the level whose reference is nearest half
/// the maximum (the paper's text: "approximately half saturation"; its Figs. 6-7 use a
/// flat near 57%).
pub fn analyze_with_flat(set: &LinearitySet, order: usize, flat: Option<usize>) -> Result<(LinearityReport, PixelResults), LinearityError> {
    analyze_unsaturated(&set.view(), order, flat, unsaturated_levels(&set.view()), Cube::Keep)
}

/// Why a linearity set cannot be corrected as asked.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LinearityError {
    /// A flat level that is dark or beyond the set.
    #[error("{level}: the flat must be one of the illuminated levels 1 to {}", levels - 1)]
    FlatLevel { level: usize, levels: usize },
    /// A flat level where most pixels saturate (it would mask most of the sensor).
    #[error("{level}: {saturated} of {pixels} pixels are saturated at that level; {}", match highest_usable {
        Some(k) => format!("levels 1 to {k} keep at least half of them unsaturated"),
        None => "no level keeps half of them unsaturated".to_string(),
    })]
    SaturatedFlat { level: usize, saturated: usize, pixels: usize, highest_usable: Option<usize> },
    /// Every pixel masked before or during the fits.
    #[error("no pixel left to correct: all {pixels} are masked (the input MASK, too little signal at the flat, no fit of order {order}, or a residual 10x the median)")]
    AllMasked { pixels: usize, order: usize },
    /// Too few levels for the standard correction's global polynomial.
    #[error("{levels} levels where most good pixels are unsaturated; the standard correction's global polynomial of order {GLOBAL_ORDER} needs {}", GLOBAL_ORDER + 1)]
    TooFewLevels { levels: usize },
    /// Fewer levels than a pixel's fit of `order` needs.
    #[error("{levels} levels; an order-{order} fit needs at least {}", .order + 3)]
    LevelsForOrder { levels: usize, order: usize },
    /// A reference voltage that is negative, not finite, or zero everywhere.
    #[error("REFERENCE VOLTAGE must be finite, >= 0 and not all zero")]
    ReferenceVoltage,
    /// Fewer distinct reference voltages than the fit needs levels.
    #[error("the reference voltages take {distinct} distinct value(s) (to 1e-6 of the largest); an order-{order} fit needs at least {} levels of different signal", .order + 3)]
    DistinctVoltages { distinct: usize, order: usize },
    /// The levels' means do not rise.
    #[error("the means do not change with the level: the levels' mean signals span {span:.3e} DN (at least 1 DN is a linearity set)")]
    NoSignal { span: f64 },
    /// The frames' standard deviations are zero nearly everywhere.
    #[error("the standard deviations are zero at {zero} of {finite} pixels and levels: the noise of the means, and so the random floor, is unknown")]
    NoNoise { zero: usize, finite: usize },
    /// Outputs asked of an analysis that kept no corrected cube.
    #[error("the analysis kept no corrected cube for the outputs")]
    NoCorrectedCube,
}

/// Whether level `l` can be the flat of a set whose pixels keep `valid[p]` levels below
/// saturation ([`unsaturated_levels`]): one of the illuminated levels, and one where at
/// least half the pixels are unsaturated (a pixel can only be fit and flat-fielded if it
/// is unsaturated there: a flat where most saturate would mask most of the sensor). The
/// message names the highest usable level.
pub fn check_flat_level(valid: &[usize], levels: usize, l: usize) -> Result<(), LinearityError> {
    let mut reaching = vec![0usize; levels + 1];
    valid.iter().for_each(|&n| reaching[n.min(levels)] += 1);
    check_flat_counts(&reaching, l)
}

/// [`check_flat_level`] from the count of pixels whose unsaturated levels number `n`,
/// `reaching[n]` for `n` in `0..=levels` (added over blocks of pixels).
pub fn check_flat_counts(reaching: &[usize], l: usize) -> Result<(), LinearityError> {
    let levels = reaching.len().saturating_sub(1);
    if !(1..levels).contains(&l) {
        return Err(LinearityError::FlatLevel { level: l, levels });
    }
    let np: usize = reaching.iter().sum();
    let unsaturated_at = |level: usize| reaching[level + 1..].iter().sum::<usize>();
    if 2 * unsaturated_at(l) < np {
        let highest_usable = (1..levels).rev().find(|&k| 2 * unsaturated_at(k) >= np);
        return Err(LinearityError::SaturatedFlat { level: l, saturated: np - unsaturated_at(l), pixels: np, highest_usable });
    }
    Ok(())
}

/// [`analyze_with_flat`] given the set's [`unsaturated_levels`] (a caller that checked the
/// flat with them computes them once): the [`stages`] on the whole set as one block, the
/// medians by selection in memory.
pub fn analyze_unsaturated(set: &SetView, order: usize, flat: Option<usize>, valid: Vec<usize>, cube: Cube) -> Result<(LinearityReport, PixelResults), LinearityError> {
    let plan = Plan::new(set.voltage, set.bit_depth, set.n_frames, order, flat);
    let np = set.width * set.height;
    let fits = plan.fit(set, valid);
    let (signal, resid) = rayon::join(|| stages::cell_medians(&fits.signal, set.width), || stages::cell_medians(&fits.resid, set.width));
    let mask = fits.mask(set.mask, MaskRule { signal, width: set.width, resid });
    let good = mask.iter().filter(|&&m| m == 0).count();
    if good == 0 {
        return Err(LinearityError::AllMasked { pixels: np, order: plan.order });
    }
    // A level's median is a selection over up to every pixel: the levels on every thread.
    let valid = &fits.valid[..];
    let reached = |l: usize| counted_means(set, &mask, valid, l);
    let medians: Vec<(f64, usize)> = (0..plan.levels).into_par_iter().map(|l| (median(reached(l)), reached(l).count())).collect();
    let global = plan.global(&medians, good)?;
    let mean_l: Vec<f64> = Plan::level_sums(set, &mask, valid).iter().map(|(s, n)| s.value() / (*n).max(1) as f64).collect();
    let (acc, mut corrected) = plan.level_pass(set, (&fits.valid, &fits.coef), &mask, &global, &mean_l, cube);
    if let Some(c) = corrected.as_mut() {
        stages::fill_cube(c, &mask, set.width, set.height);
    }
    let report = plan.report(&acc, &mean_l, global, np - good, np);
    Ok((report, PixelResults { coeffs: fits.k_major(plan.k1()), mask, corrected }))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A set whose pixel p reads exactly `sum_k a_k(p) x^k` at x = l / (levels - 1).
    fn planted(w: usize, h: usize, levels: usize, a: impl Fn(usize) -> [f64; 5]) -> LinearitySet {
        let np = w * h;
        let mut mean = vec![0.0; levels * np];
        for l in 0..levels {
            let x = l as f64 / (levels - 1) as f64;
            for p in 0..np {
                mean[l * np + p] = poly(&a(p), x);
            }
        }
        LinearitySet { bit_depth: 12, n_adc: 4, n_frames: 256, width: w, height: h, levels, std: vec![2.0; levels * np], mean, voltage: (0..levels).map(|l| 0.01 * l as f64).collect(), mask: None, keys: Default::default() }
    }

    fn coefficients(p: usize) -> [f64; 5] {
        let t = p as f64;
        [100.0 + t, 3000.0 + 7.0 * t, -150.0 + t % 5.0, 40.0 - (t % 3.0) * 10.0, -12.0 + (t % 7.0)]
    }

    #[test]
    fn the_example_row_shows_each_correction_as_the_closed_form() {
        // Planted quartic pixels (a_0 = 100 + t, a_1 = 3000 + 7t, ...; t the pixel index):
        // the pixel-wise correction returns exactly e_l (value 1); raw is the pixel's mean
        // over the level's mean of all pixels; the standard correction's value is the
        // closed form with the fitted global cubic.
        let set = planted(12, 4, 41, coefficients);
        let (r, px) = analyze(&set, PIXEL_ORDER).unwrap();
        let ex = example_row(&set, &r, &px, px.corrected.as_ref().unwrap(), 6);
        assert_eq!((ex.row, ex.first_column), (2, 3));
        assert_eq!(ex.raw.len(), 40);
        let np = 48;
        let top = 4095.0;
        let f = |v: f64| poly(&r.global_coefficients, v / top);
        for l in 1..41 {
            let mean_l = (0..np).map(|p| set.mean[l * np + p]).sum::<f64>() / np as f64;
            for i in 0..6 {
                let p = 2 * 12 + 3 + i;
                let m = |l: usize| set.mean[l * np + p];
                assert!((ex.pixelwise[l - 1][i] - 1.0).abs() < 1e-6, "level {l} pixel {p}: {}", ex.pixelwise[l - 1][i]);
                assert!((ex.raw[l - 1][i] - m(l) / mean_l).abs() < 1e-12);
                let standard = (f(m(l)) - f(m(0))) / (f(m(20)) - f(m(0))) / (l as f64 / 20.0);
                assert!((ex.standard[l - 1][i] - standard).abs() < 1e-9, "level {l}");
            }
        }
        // The standard correction is exact at the flat.
        assert!(ex.standard[19].iter().all(|v| (v - 1.0).abs() < 1e-12));
    }

    #[test]
    fn the_pixel_fit_recovers_planted_coefficients() {
        let set = planted(6, 5, 41, coefficients);
        let (r, px) = analyze(&set, PIXEL_ORDER).unwrap();
        let np = 30;
        for p in 0..np {
            for (k, want) in coefficients(p).iter().enumerate() {
                let got = px.coeffs[k * np + p];
                assert!((got - want).abs() < 1e-6 * want.abs().max(1.0), "pixel {p} a{k}: {got} vs {want}");
            }
        }
        // Exact quartics: the pixel-wise correction is exact, the standard one is not.
        assert!(r.rms_pixelwise_max < 1e-9, "{}", r.rms_pixelwise_max);
        assert!(r.rms_standard_max > 1e-4, "{}", r.rms_standard_max);
        assert_eq!(r.masked_pixels, 0);
        assert_eq!(r.gain_level, 20);
    }

    #[test]
    fn saturated_levels_are_left_out_of_the_fit() {
        // Pixel 0 clips at the top code from level 30: its fit uses levels 0..29 only and
        // still recovers the quartic.
        let mut set = planted(4, 1, 41, coefficients);
        for l in 30..41 {
            set.mean[l * 4] = 4095.0;
        }
        let (_, px) = analyze(&set, PIXEL_ORDER).unwrap();
        for (k, want) in coefficients(0).iter().enumerate() {
            assert!((px.coeffs[k * 4] - want).abs() < 1e-6 * want.abs().max(1.0), "a{k}");
        }
    }

    #[test]
    fn clipping_below_the_top_code_is_saturation() {
        // Pixel 1 clips at 4080 DN with no noise from level 33 (as the real EMVA CCD does):
        // the fit must stop there and still recover its quartic.
        let mut set = planted(4, 1, 41, coefficients);
        for l in 33..41 {
            set.mean[l * 4 + 1] = 4080.0;
            set.std[l * 4 + 1] = 0.0;
        }
        let (_, px) = analyze(&set, PIXEL_ORDER).unwrap();
        for (k, want) in coefficients(1).iter().enumerate() {
            assert!((px.coeffs[k * 4 + 1] - want).abs() < 1e-6 * want.abs().max(1.0), "a{k}: {}", px.coeffs[k * 4 + 1]);
        }
    }

    #[test]
    fn the_statistics_without_the_cube_are_those_with_it_bit_for_bit() {
        // Pixels that vary, one dead, one with a kink, two clipping at the top from
        // levels 30 and 36, one flagged in the input: the statistics only count good,
        // unsaturated pixel-levels, so leaving the others uninverted changes no bit.
        let mut set = planted(6, 5, 41, |p| [100.0 + p as f64, 3000.0 - 7.0 * p as f64, -150.0, 40.0 + p as f64, -12.0]);
        let np = 30;
        for l in 0..41 {
            set.mean[l * np + 7] = 100.0;
            if l > 20 {
                set.mean[l * np + 12] += 300.0;
            }
            if l >= 30 {
                set.mean[l * np + 3] = 4095.0;
            }
            if l >= 36 {
                set.mean[l * np + 20] = 4095.0;
            }
            for p in 0..np {
                set.std[l * np + p] = 1.0 + 0.01 * ((l * 7 + p * 3) % 11) as f64;
            }
        }
        set.mask = Some((0..np).map(|p| (p == 25) as u8).collect());
        let valid = unsaturated_levels(&set.view());
        assert!(valid[3] == 30 && valid[20] == 36, "{valid:?}");
        let (kept, px_kept) = analyze_unsaturated(&set.view(), PIXEL_ORDER, None, valid.clone(), Cube::Keep).unwrap();
        let (skipped, px_skipped) = analyze_unsaturated(&set.view(), PIXEL_ORDER, None, valid, Cube::Skip).unwrap();
        assert!(kept.masked_pixels >= 3, "{}", kept.masked_pixels);
        let json = |r: &LinearityReport| serde_json::to_string(r).unwrap();
        assert_eq!(json(&kept), json(&skipped));
        assert_eq!(px_kept.mask, px_skipped.mask);
        assert!(px_kept.coeffs.iter().zip(&px_skipped.coeffs).all(|(a, b)| a.to_bits() == b.to_bits()));
        assert_eq!(px_kept.corrected.map(|c| c.len()), Some(41 * np));
        assert!(px_skipped.corrected.is_none());
    }

    #[test]
    fn a_colour_filters_channels_are_not_masked() {
        // Issue 58: a Bayer red at 0.45 of the green median was "low signal", a quarter
        // of the sensor masked; each channel now meets its own median. Dead pixels are
        // still masked.
        use crate::model::hidden::{linearity_set, Hidden, Plant};
        let plant = Plant { full_dn: 2800.0, ..Plant::default() };
        let set = linearity_set(&plant, &[Hidden::Cfa { response: [1.23, 0.99, 0.55, 1.23] }], 58);
        assert_eq!(analyze(&set, PIXEL_ORDER).unwrap().0.masked_pixels, 0);
        let mut dead = set.clone();
        let np = dead.width * dead.height;
        // One pixel of the red cell (row 1, column 0) at a third of its channel's signal.
        let p = dead.width;
        for l in 0..dead.levels {
            dead.mean[l * np + p] = dead.mean[p] + (set.mean[l * np + p] - set.mean[p]) / 3.0;
        }
        let (r, px) = analyze(&dead, PIXEL_ORDER).unwrap();
        assert_eq!((r.masked_pixels, px.mask[p] & reason::LOW != 0), (1, true));
    }

    #[test]
    fn dead_and_anomalous_pixels_are_masked_and_filled() {
        let mut set = planted(5, 5, 41, |_| [100.0, 3000.0, -150.0, 40.0, -12.0]);
        let np = 25;
        // Pixel 7 is dead (no signal), pixel 12 (the center) has a kink no quartic fits.
        for l in 0..41 {
            set.mean[l * np + 7] = 100.0;
            if l > 20 {
                set.mean[l * np + 12] += 300.0;
            }
        }
        let (r, px) = analyze(&set, PIXEL_ORDER).unwrap();
        assert_eq!(px.mask[7] & reason::LOW, reason::LOW);
        assert_eq!(px.mask[12] & reason::TREND, reason::TREND);
        assert_eq!(r.masked_pixels, 2);
        // The filled value is the mean of the good neighbours: here every good pixel reads
        // the same corrected intensity, so the filled one must equal it.
        for l in [5, 20, 35] {
            let row = &px.corrected.as_ref().unwrap()[l * np..(l + 1) * np];
            assert!((row[12] - row[0]).abs() < 1e-12 && (row[7] - row[0]).abs() < 1e-12, "level {l}: {row:?}");
        }
    }

    #[test]
    fn fill_masked_averages_the_good_neighbours() {
        let mut img = vec![1.0, 2.0, 3.0, 4.0, 99.0, 6.0, 7.0, 8.0, 9.0];
        let mut mask = vec![0u8; 9];
        mask[4] = 1;
        mask[0] = 1;
        fill_masked(&mut img, &mask, 3, 3);
        assert_eq!(img[4], (2.0 + 3.0 + 4.0 + 6.0 + 7.0 + 8.0 + 9.0) / 7.0);
        assert_eq!(img[0], (2.0 + 4.0) / 2.0);
    }

    #[test]
    fn random_noise_propagates_as_the_closed_form() {
        // Linear pixels (no fit error) with std 2 DN, 256 frames: at level l the noise is
        // sqrt(s^2 (1 + c^2 + (1 - c)^2)) / (m_g - m_0) with s = 2/16.
        let set = planted(3, 3, 41, |_| [100.0, 3000.0, 0.0, 0.0, 0.0]);
        let (r, _) = analyze(&set, PIXEL_ORDER).unwrap();
        let d = 3000.0 * 0.5;
        for l in [1usize, 10, 30, 40] {
            let c = (l as f64 / 40.0) / 0.5;
            let s: f64 = 2.0 / 16.0;
            let want = (s * s * (1.0 + c * c + (1.0 - c).powi(2))).sqrt() / d;
            assert!((r.rms_random[l] - want).abs() < 1e-12, "level {l}");
            // Linear pixels: the pixel-wise inverse has slope 1/3000 per DN and the
            // corrections' curves are the linear one; raw is s over the level's mean; the
            // level alone is s / (m_g - m_0).
            assert!((r.rms_random_pixelwise[l] - want).abs() < 1e-9 * want, "level {l}: {}", r.rms_random_pixelwise[l]);
            // The global cubic fit to the median pixel's levels is exactly linear here, so
            // the standard correction propagates the noise the same way.
            assert!((r.rms_random_standard[l] - want).abs() < 1e-9 * want, "level {l}: {}", r.rms_random_standard[l]);
            let mean = 100.0 + 3000.0 * l as f64 / 40.0;
            assert!((r.rms_random_raw[l] - s / mean).abs() < 1e-12, "level {l}");
            assert!((r.rms_random_level_only[l] - s / d).abs() < 1e-12, "level {l}");
        }
        assert!(r.rms_random[0].is_nan() && r.rms_random[20].is_nan());
        assert!(r.rms_random_standard[20].is_nan() && r.rms_random_raw[0].is_nan());
    }
}
