//! Histogram flattening: the width of every code of one ADC from its code histogram
//! (de Wijn 2018, section 4, "ADC Characterization").
//!
//! ## Physics
//! Illumination ramps from dark to saturation spread analog samples over the ADC's input
//! range with a smooth density `I(x)` (samples per ideal DN). Code `k` is `w_k` ideal DN
//! wide, so it collects `h_k ~ I(x_k) w_k` samples. Dividing the histogram by a smooth
//! estimate of `I` leaves `w_k` up to a constant; normalization fixes the constant. What
//! survives is every structure shorter than the median window (the DN error of a
//! pipelined ADC is periodic over a few codes, with jumps at major transitions); slower
//! structure cannot be told from the illumination and is removed with it.
//!
//! ## Steps, as in the paper (numbers are [`FlattenParams`] fields)
//! 1. Fit a smooth curve to the histogram over the *fitted codes*, `fixed_low_codes` up to
//!    the last code - 1: a least-squares cubic B-spline with `spline_points` = 50
//!    coefficients (see [`FlattenParams::spline_points`] for what that means exactly).
//! 2. Divide the histogram by the spline.
//! 3. Divide by the running median over `median_window` = 21 codes; the median follows
//!    what the spline missed (illumination detail, the spline's own ripple around large
//!    jumps) but, being a median, not isolated wide or narrow codes.
//! 4. Set the first `fixed_low_codes` = 150 codes ("very low readout values occur
//!    infrequently") and the last code (saturation) to 1.
//! 5. Scale the fitted codes so the weights sum to exactly `2^B`: then the cumulative
//!    offset at the top code is zero and the LUT does not drift from the ideal ADC over
//!    the full range because of normalization alone. The drift before and after is
//!    returned; a remaining drift above [`FlattenParams::max_top_offset_dn`] is an error.
//!    **Not in the paper**, which does not say how the cumulative sum is scaled: on the
//!    default camera's ramps the drift before this step is +32, -8, -31 and +4 DN at the
//!    top code (a gain error of up to 0.8%, different per ADC, which a per-pixel flat
//!    would take out; the K-Cor tables instead pin their last entry to full scale,
//!    `docs/kcor-luts.md`).
//!
//! ## The shared illumination (`Recipe::Shared`, the default for LUTs; not the paper's)
//! One histogram cannot tell an ADC's error slower than the smoothing from the
//! illumination, and the paper's steps take much of the real ADCs' error for
//! illumination: on the twelve K-Cor ADCs its LUT code values are off by 0.035-0.14 DN
//! rms, worse than no LUT on one. Measured shares (`docs/kcor-luts.md`, "The recipe's
//! error"): the running median is the largest (the median of skewed widths, a rare narrow
//! code among slightly wide ones, drifts along the codes and its drift is divided into
//! every code), then the 50-point spline's freedom (it follows structure of 128-256-code
//! period). [`flatten_set`] with [`Illumination::Shared`] fits one density, a 20-point
//! spline and no median, to the four ADCs' mean histogram: their DN errors are
//! independent and average down there, the illumination is common. On the K-Cor ADCs:
//! 0.028-0.062 DN rms (below code 300 the spline follows the ADCs' per-code median:
//! [`FlattenParams::median_of_adcs_below`]). Its weakness: isolated large jumps at the same codes in every ADC
//! (the default synthetic ADC's major transitions) leak into the spline over a knot
//! interval, where the paper's median ignores them (0.084-0.088 DN against the paper's
//! 0.039-0.088 on the default camera).
//!
//! The weights feed [`dncal_core::LutSet::from_weights`] through [`to_core_weights`];
//! [`cumulative_offsets`] is the LUT's deviation from an ideal ADC in the core's
//! code-center convention (see `core/src/lut.rs`).

use std::ops::Range;

use dncal_core::Weight;
use nalgebra::{DMatrix, DVector};

/// Largest ADC the flattening accepts: codes are `u16` throughout dncal.
const MAX_BITS: u32 = 16;

/// Least number of codes per knot interval of the spline: a cubic piece has 4 free
/// coefficients, so each piece is then determined by its own codes. The normal matrix's
/// condition number is then about 1e3 whatever the length (715 for 189 codes, 1374 for
/// 3945 codes, 50 points; set by the outermost basis functions, which reach one interval
/// into the range), so the normal equations lose about 3 of f64's 16 digits.
const MIN_CODES_PER_INTERVAL: usize = 4;

/// Fewest mean counts per code analysed (the IEEE 1241 test's and the analyses' default
/// `min_mean_count`): below one count a code's width is not measured to better than its
/// own size (`1 / sqrt(E)` LSB at 1 sigma).
pub const MIN_COUNTS_PER_CODE: f64 = 1.0;

/// Every number of the flattening, with the paper's values as defaults.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct FlattenParams {
    /// Number of coefficients (control points) of the least-squares uniform cubic
    /// B-spline, i.e. its degrees of freedom: the paper's "number of points in the spline
    /// fit", 50. The fitted codes `[a, b]` are cut into `spline_points - 3` equal knot
    /// intervals (`spline_points - 2` uniformly spaced breakpoints including both ends);
    /// the control points sit at the uniform spacing `h = (b - a) / (spline_points - 3)`
    /// codes, from `a - h` to `b + h`. For a 12-bit ADC with the defaults, `h` is 83.9
    /// codes. At least 4, and the fitted codes must hold at least 4 codes per interval.
    pub spline_points: usize,
    /// Width of the centered running median, codes (odd): 21 in the paper; 1 is no
    /// median step (the density is the spline alone).
    pub median_window: usize,
    /// The first this many codes are not fitted and their weights are set to 1: 150 in
    /// the paper. Raise it if the dark level of the data sits above it, so that no nearly
    /// empty codes enter the fit (the spline would sag toward zero there and the division
    /// by it would blow up; that is reported as [`FlattenError::SplineNotPositive`]).
    pub fixed_low_codes: usize,
    /// Treat the last code as the saturation bin: leave it out of the fit and set its
    /// weight to 1 (the paper does). When false the last code is fitted like the others,
    /// for data that never reach saturation.
    pub set_last_to_one: bool,
    /// Least mean number of counts per fitted code: 1 by default
    /// ([`MIN_COUNTS_PER_CODE`]), below which a code's width is not
    /// measured to better than its own size. Every count above it is analysed, and the
    /// resolution it gives is stated (`1/sqrt(counts)` of a code at 1 sigma: 10% at 100
    /// counts, more than the few-percent DN error of a pipelined ADC, but a 9-LSB-wide or
    /// a missing code stands out at 50; the paper's sums of 130 to 139 ramps hold ~10^6).
    pub min_mean_count: f64,
    /// Narrow the fit to the codes whose count reaches this fraction of the median count
    /// of the candidate codes (from the first to the last such code); codes left out get
    /// weight 1 like the fixed low codes. 0 (the default) keeps the paper's fixed range;
    /// `diagnose` uses 0.1 so that data whose dark level or saturation leave empty codes
    /// inside the range can be fitted.
    pub trim_below_fraction: f64,
    /// Largest cumulative offset at the top code accepted after normalization, DN. The
    /// normalization zeroes it up to f64 rounding (about 1e-12 DN); 1e-6 DN is far below
    /// a LUT unit of 2^-11 DN.
    pub max_top_offset_dn: f64,
    /// Whose histogram the smooth density is fitted to: each ADC's own (the paper) or the
    /// ADCs' mean, each scaled to the same total ([`flatten_set`]).
    pub illumination: Illumination,
    /// With a shared illumination of three or more ADCs: below this code the density's
    /// spline is fitted to the per-code **median** of the ADCs' scaled histograms instead
    /// of their mean, and scaled to meet the mean's spline at this code. 300 in the
    /// shared recipe; 0 (or anything at or below the first fitted code) for none; at or
    /// beyond the last fitted code, the median's spline everywhere.
    ///
    /// Why: the ramps' first few levels leave a real ripple in the light there (about 1%
    /// over codes 145-200 on the paper's ramps), and at the same codes every real K-Cor
    /// camera has isolated wide codes (+0.3-0.6 DN, one ADC at a time) that lift the
    /// 4-ADC mean by about 1% over 25 codes. The mean's spline follows both, so the
    /// weights there come out low and the LUT's centres fall by 0.14-0.23 DN between
    /// codes 150 and 200: the largest local error of the LUT, which sets the paper's
    /// Fig. 5 figure. The median of four ignores one ADC's wide code. Measured on the
    /// twelve K-Cor ADCs (docs/kcor-luts.md, issue 57): Fig. 5 at |Q| <= 0.01 I_max
    /// 0.26-0.44 of the limit where the mean alone gives 0.10-0.16, the code-centre rms
    /// unchanged (28-62 mDN); the median everywhere raises that rms to 59-173 mDN (the
    /// median of four skewed widths drifts).
    pub median_of_adcs_below: usize,
}

/// Where the flattening takes the illumination from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Illumination {
    /// Each ADC's own histogram: the paper's recipe.
    #[default]
    PerAdc,
    /// One density for all ADCs of the set, from their mean histogram.
    Shared,
}

/// How a LUT is built from a ramp histogram set (`--recipe`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Recipe {
    /// The paper's: each ADC alone, a 50-point spline, a 21-code running median.
    Paper,
    /// dncal's default for LUTs: one illumination for all ADCs (their mean
    /// histogram, their per-code median below code 300), a 20-point spline, no running
    /// median. On the twelve real K-Cor ADCs it puts the LUT's code values within
    /// 0.028-0.062 DN rms of the true centres where the paper's gives 0.035-0.140
    /// (`docs/kcor-luts.md`, "The recipe's error"), and reduces the paper's Fig. 5 error
    /// at |Q| <= 0.01 I_max 3.0-16.8x (the paper's recipe 2.8-10.7x; the limit the
    /// counts allow 8.5-42x, "What Fig. 5 at small Q sees").
    Shared,
}

impl Recipe {
    /// The flattening of this recipe, with the paper's other settings.
    pub fn params(self) -> FlattenParams {
        match self {
            Recipe::Paper => FlattenParams::default(),
            Recipe::Shared => FlattenParams { spline_points: 20, median_window: 1, illumination: Illumination::Shared, median_of_adcs_below: 300, ..FlattenParams::default() },
        }
    }
}

impl Default for FlattenParams {
    fn default() -> Self {
        FlattenParams {
            spline_points: 50,
            median_window: 21,
            fixed_low_codes: 150,
            set_last_to_one: true,
            min_mean_count: MIN_COUNTS_PER_CODE,
            trim_below_fraction: 0.0,
            max_top_offset_dn: 1e-6,
            illumination: Illumination::PerAdc,
            median_of_adcs_below: 0,
        }
    }
}

impl FlattenParams {
    /// The codes a LUT built with these parameters calibrates, of an ADC with `codes`
    /// codes: from the fixed low codes to the one below the top (the top code is open).
    pub fn calibrated_codes(&self, codes: usize) -> std::ops::Range<usize> {
        self.fixed_low_codes.min(codes - 2)..codes - 1
    }

    /// How the density is taken, in words for a report.
    pub fn describe(&self) -> String {
        let median = if self.median_window == 1 { "no running median".to_string() } else { format!("a {}-code running median", self.median_window) };
        match self.illumination {
            Illumination::PerAdc => format!("each ADC alone with a {}-point spline and {median} (de Wijn 2018, section 4)", self.spline_points),
            Illumination::Shared => {
                // As flatten_set applies it (with three ADCs or more, and unless the fit
                // starts above it; the trim may move the start).
                let below = if self.median_of_adcs_below > self.fixed_low_codes { format!(" (with 3 ADCs or more, their per-code median below code {})", self.median_of_adcs_below) } else { String::new() };
                format!(
                    "with one illumination for all ADCs, a {}-point spline through their mean histogram{below} and {median} (dncal's recipe, not the paper's: docs/kcor-luts.md; --recipe paper for the paper's)",
                    self.spline_points
                )
            }
        }
    }

    /// The per-ADC flattening the histogram analyses use (IEEE 1241 test, `diagnose`):
    /// these parameters when they are per ADC, else the paper's smoothing with these
    /// codes and counts (a shared density says nothing about one ADC's scales).
    pub fn per_adc(&self) -> FlattenParams {
        match self.illumination {
            Illumination::PerAdc => self.clone(),
            Illumination::Shared => FlattenParams {
                fixed_low_codes: self.fixed_low_codes,
                set_last_to_one: self.set_last_to_one,
                min_mean_count: self.min_mean_count,
                trim_below_fraction: self.trim_below_fraction,
                max_top_offset_dn: self.max_top_offset_dn,
                ..FlattenParams::default()
            },
        }
    }
}

/// `[start, end)` narrowed to the first and last code whose count reaches `fraction` of the
/// median count in it (unchanged for `fraction <= 0` or when no code does).
fn trimmed_range(counts: &[u64], start: usize, end: usize, fraction: f64) -> (usize, usize) {
    if fraction.is_nan() || fraction <= 0.0 || start >= end {
        return (start, end);
    }
    let mut sorted: Vec<u64> = counts[start..end].to_vec();
    sorted.sort_unstable();
    let threshold = fraction * sorted[sorted.len() / 2] as f64;
    let ok = |k: &usize| counts[*k] as f64 >= threshold && counts[*k] > 0;
    match ((start..end).find(ok), (start..end).rev().find(ok)) {
        (Some(a), Some(b)) => (a, b + 1),
        _ => (start, end),
    }
}

/// The result of [`flatten_histogram`]; every vector has one value per code.
#[derive(Debug, Clone, PartialEq)]
pub struct Flattened {
    /// Normalized code widths, DN (1 for an ideal code); the fixed codes are exactly 1 and
    /// the weights sum to `2^B`.
    pub weights: Vec<f64>,
    /// The spline fitted to the histogram, counts; NaN outside `fit_codes`.
    pub spline: Vec<f64>,
    /// The running median of histogram / spline (dimensionless, near 1); NaN outside
    /// `fit_codes`. `spline * median` is the smooth density: the counts a code of the
    /// mean width collects there.
    pub median: Vec<f64>,
    /// Histogram / spline / running median, before fixing and normalizing (dimensionless,
    /// near 1); NaN outside `fit_codes`.
    pub normalized: Vec<f64>,
    /// Cumulative offset at the top code with the fixed codes set to 1 but before
    /// scaling, DN: the drift normalization removes.
    pub top_offset_before_dn: f64,
    /// Cumulative offset at the top code of `weights`, DN (zero up to rounding).
    pub top_offset_dn: f64,
    /// The fitted codes: `fixed_low_codes` up to the last code - 1 (or the last code when
    /// `set_last_to_one` is false).
    pub fit_codes: Range<usize>,
}

/// Why a histogram could not be flattened or its weights not quantized.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FlattenError {
    /// The histogram is not one count per code of a 1- to 16-bit ADC.
    #[error("histogram of {len} codes: expected 2^B codes with 1 <= B <= 16")]
    Length {
        /// Codes in the histogram.
        len: usize,
    },
    /// The median window is even or zero.
    #[error("median window of {window} codes: it must be odd")]
    MedianWindow {
        /// The window, codes.
        window: usize,
    },
    /// Fewer than 4 spline coefficients.
    #[error("{points} spline points: a cubic spline needs at least 4")]
    SplinePoints {
        /// The requested number.
        points: usize,
    },
    /// A numeric parameter is negative or not finite.
    #[error("flattening parameter {name} = {value}: must be finite and >= 0")]
    Parameter {
        /// Field of [`FlattenParams`].
        name: &'static str,
        /// Its value.
        value: f64,
    },
    /// The fitted codes are too few for the spline or the median window.
    #[error("fitted codes {start}..{end} ({} codes): {needed} needed for {what}", end.saturating_sub(*start))]
    FitRange {
        /// First fitted code.
        start: usize,
        /// One past the last fitted code.
        end: usize,
        /// Codes needed.
        needed: usize,
        /// What needs them.
        what: &'static str,
    },
    /// No counts at all in the fitted codes.
    #[error("the histogram holds no counts in the fitted codes {start}..{end}")]
    NoCounts {
        /// First fitted code.
        start: usize,
        /// One past the last fitted code.
        end: usize,
    },
    /// Too few counts per fitted code for a meaningful width.
    #[error("{mean:.3} counts per fitted code on average; at least {minimum} needed (a code's width is measured to 1/sqrt(counts) of itself)")]
    TooFewCounts {
        /// Mean counts per fitted code.
        mean: f64,
        /// [`FlattenParams::min_mean_count`].
        minimum: f64,
    },
    /// The spline's normal equations could not be solved.
    #[error("the spline's normal equations are singular")]
    SplineSingular,
    /// The spline is zero or negative at a fitted code (nearly empty codes in the fit).
    #[error("the spline is {value} counts at code {code}; the histogram cannot be divided by it")]
    SplineNotPositive {
        /// The code.
        code: usize,
        /// The spline there, counts.
        value: f64,
    },
    /// Half or more of a median window has no counts.
    #[error("the running median is zero at code {code}: half the window or more is empty")]
    MedianNotPositive {
        /// The code.
        code: usize,
    },
    /// Normalization failed to zero the top cumulative offset.
    #[error("cumulative offset at the top code is {offset_dn} DN after normalization; tolerance {tolerance_dn} DN")]
    TopOffset {
        /// The offset, DN.
        offset_dn: f64,
        /// [`FlattenParams::max_top_offset_dn`].
        tolerance_dn: f64,
    },
    /// A weight cannot be a core [`Weight`].
    #[error("weight of code {code} is {value}: a core weight must be finite, >= 0 and round below 256")]
    Weight {
        /// The code.
        code: usize,
        /// The weight.
        value: f64,
    },
}

/// Flattens the summed code histogram `counts` (one count per code, `2^B` codes) of one
/// ADC into normalized code widths by the paper's steps (module documentation).
///
/// ```
/// use dncal_host::analyses::flatten::{flatten_histogram, FlattenParams};
/// // A perfect 12-bit ADC under a slowly varying illumination: every width is 1.
/// let counts: Vec<u64> = (0..4096).map(|k| 1_000_000 + 100 * k as u64).collect();
/// let f = flatten_histogram(&counts, &FlattenParams::default()).unwrap();
/// assert!(f.weights.iter().all(|w| (w - 1.0).abs() < 1e-9));
/// assert!(f.top_offset_dn.abs() < 1e-9);
/// ```
pub fn flatten_histogram(counts: &[u64], p: &FlattenParams) -> Result<Flattened, FlattenError> {
    let fit = fit_range(counts, p)?;
    let y: Vec<f64> = counts[fit.clone()].iter().map(|&c| c as f64).collect();
    let (spline, median) = smooth_density(&y, p, fit.start)?;
    weights_from(counts, fit, spline, median, p)
}

/// Flattens the histograms of all ADCs of one set. With [`Illumination::PerAdc`] each by
/// [`flatten_histogram`]. With [`Illumination::Shared`] the smooth density (spline and
/// running median) is fitted once, to the ADCs' mean histogram over the codes
/// every ADC fits, and each ADC's histogram is divided by it (scaled to its own counts):
/// the ADCs read interleaved columns of one region, so they see one illumination, while
/// their DN errors are independent (correlation 0.004 between the real K-Cor ADCs,
/// `docs/kcor-luts.md`) and average down in the mean, so the smooth fit takes less of
/// each ADC's own slow error for illumination. A single ADC is flattened alone. Errors
/// name the ADC, or `None` for the shared density.
pub fn flatten_set(hists: &[Vec<u64>], p: &FlattenParams) -> Result<Vec<Flattened>, (Option<usize>, FlattenError)> {
    if p.illumination == Illumination::PerAdc || hists.len() < 2 {
        // A single ADC has none to share with: the paper's flattening of it alone.
        let p = &p.per_adc();
        return hists.iter().enumerate().map(|(a, h)| flatten_histogram(h, p).map_err(|e| (Some(a), e))).collect();
    }
    let ranges: Vec<Range<usize>> = hists.iter().enumerate().map(|(a, h)| fit_range(h, p).map_err(|e| (Some(a), e))).collect::<Result<_, _>>()?;
    let n = hists[0].len();
    if let Some(a) = hists.iter().position(|h| h.len() != n) {
        return Err((Some(a), FlattenError::Length { len: hists[a].len() }));
    }
    let start = ranges.iter().map(|r| r.start).max().unwrap_or(0);
    let end = ranges.iter().map(|r| r.end).min().unwrap_or(0);
    let fit = start..end.max(start);
    check_fit_len(&fit, p).map_err(|e| (None, e))?;
    // The mean of the ADCs' histograms, each scaled to the same total over the fitted
    // codes (an arithmetic mean: at a few counts a code a geometric one is biased and
    // undefined at zero; to first order in the DN error the two are the same).
    let totals: Vec<f64> = hists.iter().map(|h| h[fit.clone()].iter().map(|&c| c as f64).sum::<f64>()).collect();
    // Each ADC's own counts checked again over the codes they share.
    for (a, &t) in totals.iter().enumerate() {
        if t == 0.0 {
            return Err((Some(a), FlattenError::NoCounts { start: fit.start, end: fit.end }));
        }
        if t / (fit.len() as f64) < p.min_mean_count {
            return Err((Some(a), FlattenError::TooFewCounts { mean: t / fit.len() as f64, minimum: p.min_mean_count }));
        }
    }
    let mean_total = totals.iter().sum::<f64>() / totals.len() as f64;
    let scales: Vec<f64> = totals.iter().map(|&t| if t > 0.0 { mean_total / t } else { 0.0 }).collect();
    let mean: Vec<f64> = fit.clone().map(|k| hists.iter().zip(&scales).map(|(h, s)| h[k] as f64 * s).sum::<f64>() / hists.len() as f64).collect();
    let mut spline = positive_spline(&mean, p, fit.start).map_err(|e| (None, e))?;
    let join = p.median_of_adcs_below.saturating_sub(fit.start).min(fit.len() - 1);
    if join > 0 && hists.len() >= 3 {
        let per_code_median: Vec<f64> = fit.clone().map(|k| crate::infra::stats::median(hists.iter().zip(&scales).map(|(h, s)| h[k] as f64 * s))).collect();
        let low = fit_uniform_cubic_spline(&per_code_median, p.spline_points).map_err(|e| (None, e))?;
        // Only the codes up to the join are used: only they must be positive.
        if let Some((i, &value)) = low[..=join].iter().enumerate().find(|(_, s)| s.is_nan() || **s <= 0.0) {
            return Err((None, FlattenError::SplineNotPositive { code: fit.start + i, value }));
        }
        let meet = spline[join] / low[join];
        for (s, l) in spline[..join].iter_mut().zip(&low) {
            *s = l * meet;
        }
    }
    let median = running_median_over(&mean, &spline, p, fit.start).map_err(|e| (None, e))?;
    let density: f64 = spline.iter().zip(&median).map(|(s, m)| s * m).sum();
    hists
        .iter()
        .enumerate()
        .map(|(a, h)| {
            let own: f64 = h[fit.clone()].iter().map(|&c| c as f64).sum();
            let scaled: Vec<f64> = spline.iter().map(|s| s * own / density).collect();
            weights_from(h, fit.clone(), scaled, median.clone(), p).map_err(|e| (Some(a), e))
        })
        .collect()
}

/// Every input check of [`flatten_histogram`] on one histogram: its fitted codes.
fn fit_range(counts: &[u64], p: &FlattenParams) -> Result<Range<usize>, FlattenError> {
    let n = counts.len();
    if n < 2 || !n.is_power_of_two() || n > 1 << MAX_BITS {
        return Err(FlattenError::Length { len: n });
    }
    if p.median_window.is_multiple_of(2) {
        return Err(FlattenError::MedianWindow { window: p.median_window });
    }
    if p.spline_points < 4 {
        return Err(FlattenError::SplinePoints { points: p.spline_points });
    }
    for (name, value) in [("min_mean_count", p.min_mean_count), ("max_top_offset_dn", p.max_top_offset_dn)] {
        if !(value.is_finite() && value >= 0.0) {
            return Err(FlattenError::Parameter { name, value });
        }
    }
    let end = if p.set_last_to_one { n - 1 } else { n };
    let (start, end) = trimmed_range(counts, p.fixed_low_codes.min(end), end, p.trim_below_fraction);
    let fit = start..end;
    check_fit_len(&fit, p)?;
    let total: u128 = counts[fit.clone()].iter().map(|&c| c as u128).sum();
    if total == 0 {
        return Err(FlattenError::NoCounts { start: fit.start, end });
    }
    let mean = total as f64 / fit.len() as f64;
    if mean < p.min_mean_count {
        return Err(FlattenError::TooFewCounts { mean, minimum: p.min_mean_count });
    }
    Ok(fit)
}

/// Whether the fitted codes hold the spline's and the median window's codes.
fn check_fit_len(fit: &Range<usize>, p: &FlattenParams) -> Result<(), FlattenError> {
    let range_error = |needed, what| FlattenError::FitRange { start: fit.start, end: fit.end, needed, what };
    let spline_needed = MIN_CODES_PER_INTERVAL * (p.spline_points - 3) + 1;
    if fit.len() < spline_needed {
        return Err(range_error(spline_needed, "the spline (4 codes per knot interval)"));
    }
    if fit.len() < p.median_window {
        return Err(range_error(p.median_window, "the median window"));
    }
    Ok(())
}

/// Steps 1 and 3's smooth density of `y` (one value per fitted code, the first at code
/// `first`): the spline and the running median of `y` over it.
fn smooth_density(y: &[f64], p: &FlattenParams, first: usize) -> Result<(Vec<f64>, Vec<f64>), FlattenError> {
    let spline = positive_spline(y, p, first)?;
    let median = running_median_over(y, &spline, p, first)?;
    Ok((spline, median))
}

/// Step 1: the spline of `y` (first value at code `first`), refused where it is not
/// positive.
fn positive_spline(y: &[f64], p: &FlattenParams, first: usize) -> Result<Vec<f64>, FlattenError> {
    let spline = fit_uniform_cubic_spline(y, p.spline_points)?;
    if let Some((i, &value)) = spline.iter().enumerate().find(|(_, s)| s.is_nan() || **s <= 0.0) {
        return Err(FlattenError::SplineNotPositive { code: first + i, value });
    }
    Ok(spline)
}

/// Step 3: the running median of `y / spline`, all ones for a window of one code.
fn running_median_over(y: &[f64], spline: &[f64], p: &FlattenParams, first: usize) -> Result<Vec<f64>, FlattenError> {
    // A median of one code would be the quotient itself and flatten everything to 1:
    // window 1 means no median step.
    if p.median_window == 1 {
        return Ok(vec![1.0; y.len()]);
    }
    let quotient: Vec<f64> = y.iter().zip(spline).map(|(h, s)| h / s).collect();
    let median = running_median(&quotient, p.median_window);
    if let Some(i) = median.iter().position(|m| m.is_nan() || *m <= 0.0) {
        return Err(FlattenError::MedianNotPositive { code: first + i });
    }
    Ok(median)
}


/// Steps 2 to 5 for one ADC: its counts over the fitted codes divided by the density
/// `spline * median`, the fixed codes set to 1, the scale that zeroes the top offset.
fn weights_from(counts: &[u64], fit: Range<usize>, spline: Vec<f64>, median: Vec<f64>, p: &FlattenParams) -> Result<Flattened, FlattenError> {
    let n = counts.len();
    let normalized_fit: Vec<f64> = counts[fit.clone()].iter().zip(spline.iter().zip(&median)).map(|(&h, (s, m))| h as f64 / s / m).collect();

    let mut weights = vec![1.0; n];
    weights[fit.clone()].copy_from_slice(&normalized_fit);
    let top_offset_before_dn = top_offset(&weights);

    // Scale the fitted codes so the top code's center lands at 2^B - 1/2 DN, i.e. its
    // cumulative offset is zero. With the last code fixed at 1 this is exactly "the
    // weights sum to 2^B"; when the last code is fitted it also keeps the core's top entry
    // below 2^23 whatever the last width.
    let top = n - 1;
    let center_share = |k: usize| if k == top { 0.5 } else { 1.0 };
    let (mut fixed_part, mut fitted_part) = (0.0, 0.0);
    for (k, w) in weights.iter().enumerate() {
        if fit.contains(&k) {
            fitted_part += center_share(k) * w;
        } else {
            fixed_part += center_share(k) * w;
        }
    }
    // fitted_part > 0: some fitted count is positive and every spline and median value is.
    let scale = (n as f64 - 0.5 - fixed_part) / fitted_part;
    for w in &mut weights[fit.clone()] {
        *w *= scale;
    }
    let top_offset_dn = top_offset(&weights);
    if top_offset_dn.is_nan() || top_offset_dn.abs() > p.max_top_offset_dn {
        return Err(FlattenError::TopOffset { offset_dn: top_offset_dn, tolerance_dn: p.max_top_offset_dn });
    }

    let full = |v: &[f64]| {
        let mut out = vec![f64::NAN; n];
        out[fit.clone()].copy_from_slice(v);
        out
    };
    Ok(Flattened { weights, spline: full(&spline), median: full(&median), normalized: full(&normalized_fit), top_offset_before_dn, top_offset_dn, fit_codes: fit })
}

/// [`flatten_histogram`] for an analysis rather than a LUT: where the spline (or the
/// running median) is not positive, the fit is narrowed to the codes holding a larger
/// share of the median count (`trim_below_fraction` 0.2, 0.4, 0.8) and tried again.
/// A ramp whose ends fall off over a few codes (an illumination blurred by noise) at a
/// few tens of counts a code has codes of 3 counts far into its tail, where the 10% trim
/// ends; the spline then undershoots to zero at the edge. Gaps and missing codes inside
/// the range stay: where the running median is zero **inside** the range (a run of
/// missing codes half a window long, as below a SAR's MSB when the bits under it weigh
/// more; codes with counts on both sides), the window is doubled first, up to 87 codes
/// ([`MAX_MEDIAN_WIDENING`]), and the fit range is left as it was. Returns the
/// flattening and the parameters it took.
pub fn flatten_narrowing(counts: &[u64], p: &FlattenParams) -> Result<(Flattened, FlattenParams), FlattenError> {
    let mut p = p.clone();
    let widest = MAX_MEDIAN_WIDENING * p.median_window;
    loop {
        match flatten_histogram(counts, &p) {
            Err(FlattenError::MedianNotPositive { code }) if 2 * p.median_window < widest && inside(counts, code, p.median_window) => {
                p.median_window = 2 * p.median_window + 1;
            }
            Err(FlattenError::SplineNotPositive { .. } | FlattenError::MedianNotPositive { .. }) if p.trim_below_fraction < 0.8 => {
                p.trim_below_fraction = (2.0 * p.trim_below_fraction).max(0.2);
            }
            Err(FlattenError::MedianNotPositive { .. }) if 2 * p.median_window < widest => {
                p.median_window = 2 * p.median_window + 1;
            }
            r => return r.map(|f| (f, p)),
        }
    }
}

/// Whether `code` lies inside the counts rather than in a tail: within two windows on
/// each side (but not the half window next to it) some code holds at least half the
/// median count of the codes with counts.
fn inside(counts: &[u64], code: usize, window: usize) -> bool {
    let mut nonzero: Vec<u64> = counts.iter().copied().filter(|&c| c > 0).collect();
    if nonzero.is_empty() {
        return false;
    }
    let mid = nonzero.len() / 2;
    let half_median = *nonzero.select_nth_unstable(mid).1 as f64 / 2.0;
    let full = |r: std::ops::Range<usize>| counts.get(r).is_some_and(|s| s.iter().any(|&c| c as f64 >= half_median));
    let (near, far) = (window / 2, 2 * window);
    full(code.saturating_sub(far)..code.saturating_sub(near)) && full((code + near + 1).min(counts.len())..(code + far + 1).min(counts.len()))
}

/// How many times its own a median window [`flatten_narrowing`] may widen to: below 8,
/// so the default 21 codes become 43 and at most 87 (runs of up to 43 missing codes).
pub const MAX_MEDIAN_WIDENING: usize = 8;

/// The variance of the running median of `window` samples, as a share of one sample's
/// variance: `(pi / 2) / window` (the median's large-window limit). The smooth density
/// `spline * median` carries it relative to the counts' own noise. A window of one code
/// is no median step ([`FlattenParams::median_window`]): 0.
pub fn median_variance(window: usize) -> f64 {
    if window <= 1 {
        0.0
    } else {
        std::f64::consts::FRAC_PI_2 / window as f64
    }
}

/// Quantizes weights to the core's [`Weight`] (`U8F24`) by the core's rule
/// ([`dncal_core::weight_nearest`]): each to the nearest multiple of 2^-24 DN, ties to
/// even, so the error is at most 2^-25 DN per code and 2^-13 DN summed over 4096 codes,
/// a quarter of a LUT unit. A weight that is NaN, infinite, negative, or rounds to 256 or
/// more (at or above `256 - 2^-25`) is an error, never clamped.
pub fn to_core_weights(w: &[f64]) -> Result<Vec<Weight>, FlattenError> {
    w.iter().enumerate().map(|(code, &value)| dncal_core::weight_nearest(value).ok_or(FlattenError::Weight { code, value })).collect()
}

/// The LUT's deviation from an ideal ADC at every code, DN: the center of code `k` on the
/// analog scale, `sum_{j<k} w_j + w_k / 2`, minus the ideal center `k + 1/2`. This is the
/// core's convention (`entry_k / 2^11 - (k + 1/2)`, `core/src/lut.rs`). The paper's
/// "cumulative offset" measures the top of each code instead, `sum_{j<=k} w_j - (k + 1)`,
/// which is larger by `(w_k - 1) / 2`: equal at the top code (weight 1), a few hundredths
/// of a DN apart elsewhere for a few-percent DN error. The running sum is compensated
/// (Neumaier), so the result is good to about 1e-13 DN for 2^16 codes.
pub fn cumulative_offsets(w: &[f64]) -> Vec<f64> {
    let mut below = CompensatedSum::default();
    w.iter()
        .enumerate()
        .map(|(k, &wk)| {
            let mut center = below.clone();
            center.add(wk / 2.0);
            center.add(-(k as f64 + 0.5));
            below.add(wk);
            center.value()
        })
        .collect()
}

/// The cumulative offset of the top code, DN.
fn top_offset(w: &[f64]) -> f64 {
    cumulative_offsets(w).last().copied().unwrap_or(0.0)
}

/// Neumaier's compensated sum: f64 addition that keeps the rounding error of each step.
#[derive(Debug, Clone, Default)]
struct CompensatedSum {
    sum: f64,
    carry: f64,
}

impl CompensatedSum {
    fn add(&mut self, x: f64) {
        let t = self.sum + x;
        self.carry += if self.sum.abs() >= x.abs() { (self.sum - t) + x } else { (x - t) + self.sum };
        self.sum = t;
    }
    fn value(&self) -> f64 {
        self.sum + self.carry
    }
}

/// The uniform cubic B-spline basis on knot interval `j` at local coordinate `t` in [0, 1]:
/// the four nonzero basis values, for coefficients `j..j + 4`. `u` is the position in
/// knot intervals from the first sample; the last sample belongs to the last interval.
fn cubic_basis(u: f64, intervals: usize) -> (usize, [f64; 4]) {
    let j = (u.max(0.0).floor() as usize).min(intervals - 1);
    let t = u - j as f64;
    let s = 1.0 - t;
    let (t2, t3) = (t * t, t * t * t);
    (j, [s * s * s / 6.0, (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0, (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0, t3 / 6.0])
}

/// Least-squares fit of a uniform cubic B-spline with `points` coefficients to samples
/// `y[i]` at `x = i`, evaluated at every sample. Unweighted: with ~1e6 counts per code
/// Poisson weights would change the fit by a fraction of a percent of the spline's own
/// ripple, which the running median removes anyway. Solved by Cholesky on the banded
/// normal equations (`points x points`), not on the `len x points` design matrix.
///
/// Needs `points >= 4` and `y.len() >= 4 (points - 3) + 1` (checked by the caller; see
/// [`MIN_CODES_PER_INTERVAL`] for the conditioning).
fn fit_uniform_cubic_spline(y: &[f64], points: usize) -> Result<Vec<f64>, FlattenError> {
    let intervals = points - 3;
    let per_interval = intervals as f64 / (y.len() - 1) as f64;
    let mut normal = DMatrix::<f64>::zeros(points, points);
    let mut rhs = DVector::<f64>::zeros(points);
    for (i, &yi) in y.iter().enumerate() {
        let (j, b) = cubic_basis(i as f64 * per_interval, intervals);
        for r in 0..4 {
            rhs[j + r] += b[r] * yi;
            for c in 0..4 {
                normal[(j + r, j + c)] += b[r] * b[c];
            }
        }
    }
    let coef = normal.cholesky().ok_or(FlattenError::SplineSingular)?.solve(&rhs);
    Ok((0..y.len())
        .map(|i| {
            let (j, b) = cubic_basis(i as f64 * per_interval, intervals);
            (0..4).map(|r| b[r] * coef[j + r]).sum()
        })
        .collect())
}

/// Centered running median of odd width `window` over `values` (at least `window` long).
/// Near the ends the window is shifted inward, not truncated or reflected: code `k` takes
/// the median of the `window` values starting at `clamp(k - window/2, 0, len - window)`.
/// Every median is then of the same number of samples, so its noise does not grow toward
/// the ends, and no value is counted twice. Slides a sorted window (O(len window)).
/// Needs `1 <= window <= values.len()`, `window` odd (checked by the caller).
pub(crate) fn running_median(values: &[f64], window: usize) -> Vec<f64> {
    let half = window / 2;
    let starts = values.len() + 1 - window;
    let mut sorted = values[..window].to_vec();
    sorted.sort_by(f64::total_cmp);
    let mut by_start = Vec::with_capacity(starts);
    by_start.push(sorted[half]);
    for s in 1..starts {
        let leaving = values[s - 1];
        // The leaving value is in the window, so the search finds it (Ok); its bits are
        // unchanged, and total_cmp is an exact order.
        let (Ok(at) | Err(at)) = sorted.binary_search_by(|v| v.total_cmp(&leaving));
        sorted.remove(at.min(window - 1));
        let entering = values[s + window - 1];
        let at = sorted.partition_point(|v| v.total_cmp(&entering).is_lt());
        sorted.insert(at, entering);
        by_start.push(sorted[half]);
    }
    (0..values.len()).map(|k| by_start[k.saturating_sub(half).min(starts - 1)]).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use dncal_core::LutSet;
    use rand::rngs::StdRng;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Poisson};

    const CODES: usize = 4096;

    /// Planted code widths of a 12-bit ADC: a period-8 DN error of up to 4 % (every odd
    /// code exactly 1, so any 21-code window has median 1), a mean excess of 0.125 % that
    /// normalization must remove, and large jumps at major transitions (cumulative offsets
    /// up to about 1 DN, as in the paper's figure), including a missing code.
    fn planted_widths() -> Vec<f64> {
        const PATTERN: [f64; 8] = [0.04, 0.0, -0.02, 0.0, -0.04, 0.0, 0.03, 0.0];
        let mut w: Vec<f64> = (0..CODES).map(|k| 1.0 + PATTERN[k % 8]).collect();
        for (code, width) in [(1023, 1.9), (1024, 1.3), (2047, 0.0), (2048, 1.5), (3071, 0.45)] {
            w[code] = width;
        }
        w
    }

    /// Samples per ideal DN of ramps from a dark level near code 100 to saturation:
    /// a turn-on above dark times broad Gaussians, ~1e6 counts per code.
    fn illumination(x: f64) -> f64 {
        let turn_on = 1.0 / (1.0 + (-(x - 100.0) / 6.0).exp());
        let g = |mu: f64, s: f64| (-((x - mu) / s).powi(2)).exp();
        1.0e6 * turn_on * (0.6 + 0.5 * g(1300.0, 700.0) + 0.3 * g(3200.0, 800.0))
    }

    /// Expected counts per code (density at the code's analog center times its width) and
    /// a seeded Poisson histogram of them; the saturation code collects 3e8 samples.
    fn synthesize(w: &[f64], seed: u64) -> (Vec<f64>, Vec<u64>) {
        let mut rng = StdRng::seed_from_u64(seed);
        let mut below = 0.0;
        let lambda: Vec<f64> = w
            .iter()
            .map(|&wk| {
                let l = illumination(below + wk / 2.0) * wk;
                below += wk;
                l
            })
            .collect();
        let mut counts: Vec<u64> =
            lambda.iter().map(|&l| if l > 0.0 { Poisson::new(l).unwrap().sample(&mut rng) as u64 } else { 0 }).collect();
        counts[CODES - 1] = 300_000_000;
        (lambda, counts)
    }

    /// The planted widths normalized the paper's way: fixed codes 1, sum 2^B.
    fn planted_normalized(w: &[f64], fit: &Range<usize>) -> Vec<f64> {
        let fixed = (CODES - fit.len()) as f64;
        let scale = (CODES as f64 - fixed) / w[fit.clone()].iter().sum::<f64>();
        (0..CODES).map(|k| if fit.contains(&k) { w[k] * scale } else { 1.0 }).collect()
    }

    #[test]
    fn recovers_planted_widths_within_poisson_noise() {
        let w = planted_widths();
        let (lambda, counts) = synthesize(&w, 1288);
        let f = flatten_histogram(&counts, &FlattenParams::default()).unwrap();
        assert_eq!(f.fit_codes, 150..4095);
        let truth = planted_normalized(&w, &f.fit_codes);
        // Relative Poisson noise of code k is 1/sqrt(lambda_k) (1.0e-3 to 1.3e-3 here). The
        // running median adds its own: it is set by the m = 10 codes of width 1 in the
        // window, so its relative sd is sqrt(pi / 2m) / sqrt(lambda) (the spline, averaging
        // ~84 codes, adds far less). Standardized by the Poisson sigma, the errors should
        // then have rms near sqrt(1 + pi/20) = 1.08 and, over 3945 codes, a largest |z|
        // near 4.2; 6 sqrt(1 + pi/20) = 6.5 is the limit (exceeded with probability ~1e-6).
        let z: Vec<f64> = f
            .fit_codes
            .clone()
            .filter(|&k| lambda[k] > 0.0)
            .map(|k| (f.weights[k] - truth[k]) / (truth[k] / lambda[k].sqrt()))
            .collect();
        let rms = (z.iter().map(|z| z * z).sum::<f64>() / z.len() as f64).sqrt();
        let worst = z.iter().fold(0.0f64, |m, z| m.max(z.abs()));
        eprintln!("standardized width errors: rms {rms:.3}, largest {worst:.2}");
        let sd = (1.0 + std::f64::consts::PI / 20.0).sqrt();
        assert!((0.9..1.2).contains(&rms), "rms {rms}");
        assert!(worst < 6.0 * sd, "largest {worst}");
        assert_eq!(f.weights[2047], 0.0, "a missing code stays missing");
        assert!(f.weights[..150].iter().all(|&x| x == 1.0));
        assert_eq!(f.weights[CODES - 1], 1.0);
        assert!((f.weights.iter().sum::<f64>() - CODES as f64).abs() < 1e-9);
    }

    #[test]
    fn recovers_planted_cumulative_offsets_and_zeroes_the_top() {
        let w = planted_widths();
        let (lambda, counts) = synthesize(&w, 2018);
        let f = flatten_histogram(&counts, &FlattenParams::default()).unwrap();
        let truth = cumulative_offsets(&planted_normalized(&w, &f.fit_codes));
        let got = cumulative_offsets(&f.weights);
        // Bound: code k's width has Poisson error sigma_k = w_k / sqrt(lambda_k) DN. The
        // running median's error (relative sd sqrt(pi / 2m) / sqrt(lambda), m = 10 codes of
        // width 1 per window, see the width test) is shared by the W = 21 codes of a window,
        // so over a long stretch it adds W pi / 2m = 3.3 times the Poisson variance. With
        // both, the offset error is a (time-changed) Brownian bridge over the fitted codes,
        // pinned at both ends by normalization, of total variance
        // V = (1 + 3.3) sum sigma_k^2; its largest excursion exceeds 2 sqrt(V) with
        // probability 7e-4 (Kolmogorov). 0.28 DN here; 40 seeds gave at most 0.18 DN.
        let poisson: f64 = f.fit_codes.clone().filter(|&k| lambda[k] > 0.0).map(|k| w[k] * w[k] / lambda[k]).sum();
        let median_factor = 21.0 * std::f64::consts::PI / 20.0;
        let tolerance_dn = 2.0 * ((1.0 + median_factor) * poisson).sqrt();
        let worst = f.fit_codes.clone().map(|k| (got[k] - truth[k]).abs()).fold(0.0, f64::max);
        let planted = truth.iter().fold(0.0f64, |m, o| m.max(o.abs()));
        eprintln!("offsets: largest error {worst:.4} DN, tolerance {tolerance_dn:.4} DN, planted up to {planted:.3} DN");
        assert!(worst < tolerance_dn, "{worst} DN");
        assert!(planted > 3.0 * tolerance_dn, "the planted offsets must be visible above the tolerance");
        assert!(got[..150].iter().all(|&o| o == 0.0));
        // The median scales to the pattern's median, not its mean: a real drift to remove.
        eprintln!("top offset: before {:.3} DN, after {:.2e} DN", f.top_offset_before_dn, f.top_offset_dn);
        assert!(f.top_offset_before_dn.abs() > 1.0);
        assert!(f.top_offset_dn.abs() < 1e-9);
        assert!(got[CODES - 1].abs() < 1e-9);
    }

    #[test]
    fn core_lut_entries_are_the_cumulative_offsets() {
        let (_, counts) = synthesize(&planted_widths(), 7);
        let f = flatten_histogram(&counts, &FlattenParams::default()).unwrap();
        let q = to_core_weights(&f.weights).unwrap();
        let lut = LutSet::<1, CODES>::from_weights(&[&q]).unwrap();
        let offsets = cumulative_offsets(&f.weights);
        // Entry rounding is 2^-12 DN; quantizing the weights adds at most 2^-25 per code.
        let tolerance_dn = 2f64.powi(-12) + CODES as f64 * 2f64.powi(-25);
        for (k, (e, o)) in lut.tables()[0].iter().zip(&offsets).enumerate() {
            let lut_offset = LutSet::<1, CODES>::entry_dn(*e) - (k as f64 + 0.5);
            assert!((lut_offset - o).abs() <= tolerance_dn, "code {k}: {lut_offset} vs {o}");
        }
        assert_eq!(lut.tables()[0][CODES - 1].to_bits(), (2 * CODES as u32 - 1) << 10, "top entry 4095.5 DN");
    }

    #[test]
    fn cumulative_offsets_match_hand_values() {
        assert_eq!(cumulative_offsets(&[2.0, 0.0, 1.0, 1.0]), vec![0.5, 0.5, 0.0, 0.0]);
        assert!(cumulative_offsets(&[1.0; 4096]).iter().all(|&o| o == 0.0));
        assert_eq!(cumulative_offsets(&[1.5, 0.5]), vec![0.25, 0.25]);
        assert!(cumulative_offsets(&[]).is_empty());
    }

    #[test]
    fn spline_reproduces_an_exact_cubic() {
        // Cubics lie in the span of cubic B-splines on any knots, so least squares must
        // return the polynomial itself, to rounding.
        let p = |x: f64| 2.0e5 + 3.0e2 * x - 0.4 * x * x + 1.0e-4 * x * x * x;
        for (len, points) in [(1001, 50), (3945, 50), (17, 4), (200, 20)] {
            let y: Vec<f64> = (0..len).map(|i| p(i as f64)).collect();
            let s = fit_uniform_cubic_spline(&y, points).unwrap();
            let scale = y.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let worst = y.iter().zip(&s).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
            assert!(worst < 1e-10 * scale, "len {len}, {points} points: {worst}");
        }
    }

    #[test]
    fn spline_is_smooth_not_interpolating() {
        // A single spike: a 50-point spline over 4000 codes spreads it over ~2 intervals,
        // so the fit at the spike is a small fraction of it.
        let mut y = vec![1000.0; 4000];
        y[2000] = 101_000.0;
        let s = fit_uniform_cubic_spline(&y, 50).unwrap();
        assert!(s[2000] - 1000.0 < 0.05 * 100_000.0, "{}", s[2000]);
    }

    fn naive_running_median(v: &[f64], window: usize) -> Vec<f64> {
        let half = window / 2;
        (0..v.len())
            .map(|k| {
                let start = k.saturating_sub(half).min(v.len() - window);
                let mut w = v[start..start + window].to_vec();
                w.sort_by(|a, b| a.partial_cmp(b).unwrap());
                w[half]
            })
            .collect()
    }

    #[test]
    fn running_median_matches_a_sorting_reference() {
        let mut rng = StdRng::seed_from_u64(21);
        let poisson = Poisson::new(3.0).unwrap();
        let ties: Vec<f64> = (0..500).map(|_| poisson.sample(&mut rng)).collect();
        let smooth: Vec<f64> = (0..300).map(|i| (i as f64 * 0.1).sin() + 0.001 * i as f64).collect();
        for v in [&ties, &smooth] {
            for window in [1, 3, 21, 99, v.len() - (v.len() + 1) % 2] {
                assert_eq!(running_median(v, window), naive_running_median(v, window), "window {window}");
            }
        }
        assert_eq!(running_median(&[5.0, 1.0, 3.0], 3), vec![3.0; 3]);
    }

    #[test]
    fn to_core_weights_rounds_to_nearest_even() {
        let ulp = 2f64.powi(-24);
        let cases = [
            (1.0, 1 << 24),
            (1.0 + ulp / 2.0, 1 << 24),            // tie, even below
            (1.0 + 1.5 * ulp, (1 << 24) + 2),      // tie, even above
            (1.0 + 0.4 * ulp, 1 << 24),
            (1.0 + 0.6 * ulp, (1 << 24) + 1),
            (0.0, 0),
            (256.0 - ulp, u32::MAX),
        ];
        for (w, bits) in cases {
            assert_eq!(to_core_weights(&[w]).unwrap()[0].to_bits(), bits, "{w}");
        }
        for (i, bad) in [-1e-12, -0.0 - ulp, f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 256.0, 256.0 - ulp / 2.0].into_iter().enumerate() {
            let w = [1.0, bad];
            assert!(matches!(to_core_weights(&w), Err(FlattenError::Weight { code: 1, .. })), "case {i}");
        }
    }

    /// The core's rule against the hand rule it replaced (`round_ties_even(w 2^24)` in
    /// f64, refused above `u32::MAX` or below 0): equal on every value near the grid's
    /// ties, on random widths and at both ends.
    #[test]
    fn the_core_weight_rule_is_nearest_even_on_the_2_to_the_24_grid() {
        let naive = |v: f64| -> Option<u32> {
            if !(v.is_finite() && v >= 0.0) {
                return None;
            }
            let b = (v * (1u64 << 24) as f64).round_ties_even();
            (b <= u32::MAX as f64).then_some(b as u32)
        };
        let ulp = 2f64.powi(-24);
        let mut s = 0x9e37_79b9_7f4a_7c15u64;
        let mut values = vec![0.0, -0.0, ulp / 2.0, 1.5 * ulp, 255.0 + 0.5 * ulp, 256.0 - ulp, 256.0 - ulp / 2.0, 256.0 - 0.75 * ulp];
        for _ in 0..100_000 {
            s = s.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            // A grid point below 256 DN, on it, a quarter off or at the tie between two.
            let k = (s >> 32) as f64;
            let frac = [0.0, 0.25, 0.5, 0.75][(s & 3) as usize];
            values.push((k + frac) * ulp);
        }
        for v in values {
            assert_eq!(dncal_core::weight_nearest(v).map(|w| w.to_bits()), naive(v), "{v:e}");
        }
    }

    #[test]
    fn bad_inputs_are_errors() {
        let p = FlattenParams::default();
        let good: Vec<u64> = vec![1_000_000; CODES];
        assert!(matches!(flatten_histogram(&good[..3000], &p), Err(FlattenError::Length { len: 3000 })));
        assert!(matches!(flatten_histogram(&good[..1], &p), Err(FlattenError::Length { .. })));
        assert!(matches!(flatten_histogram(&[], &p), Err(FlattenError::Length { .. })));
        assert!(matches!(flatten_histogram(&vec![0; CODES], &p), Err(FlattenError::NoCounts { .. })));
        let sparse: Vec<u64> = (0..CODES).map(|k| u64::from(k % 3 == 0)).collect();
        assert!(matches!(flatten_histogram(&sparse, &p), Err(FlattenError::TooFewCounts { .. })));
        assert!(matches!(flatten_histogram(&vec![50; CODES], &FlattenParams { min_mean_count: 100.0, ..p.clone() }), Err(FlattenError::TooFewCounts { .. })));
        assert!(flatten_histogram(&vec![50; CODES], &p).is_ok());
        assert!(matches!(flatten_histogram(&good[..256], &p), Err(FlattenError::FitRange { .. })));
        for window in [0, 20] {
            let q = FlattenParams { median_window: window, ..p.clone() };
            assert!(matches!(flatten_histogram(&good, &q), Err(FlattenError::MedianWindow { .. })));
        }
        let q = FlattenParams { median_window: 5001, fixed_low_codes: 0, ..p.clone() };
        assert!(matches!(flatten_histogram(&good, &q), Err(FlattenError::FitRange { needed: 5001, .. })));
        let q = FlattenParams { spline_points: 3, ..p.clone() };
        assert!(matches!(flatten_histogram(&good, &q), Err(FlattenError::SplinePoints { points: 3 })));
        let q = FlattenParams { spline_points: 2000, ..p.clone() };
        assert!(matches!(flatten_histogram(&good, &q), Err(FlattenError::FitRange { .. })));
        let q = FlattenParams { fixed_low_codes: 5000, ..p.clone() };
        assert!(matches!(flatten_histogram(&good, &q), Err(FlattenError::FitRange { .. })));
        let q = FlattenParams { min_mean_count: f64::NAN, ..p.clone() };
        assert!(matches!(flatten_histogram(&good, &q), Err(FlattenError::Parameter { .. })));
        // Saturation reached at code 2000: the upper half is empty, so the spline or the
        // median reaches zero there.
        let mut half_empty = good.clone();
        half_empty[2000..CODES - 1].fill(0);
        assert!(matches!(
            flatten_histogram(&half_empty, &p),
            Err(FlattenError::SplineNotPositive { .. } | FlattenError::MedianNotPositive { .. })
        ));
    }

    /// A run of 15 missing codes inside the range (below a SAR's MSB when the bits under
    /// it weigh more): the 21-code median is zero there; the narrowing widens it to 43,
    /// and the codes around the run keep their widths to 3% (the spline dips into the
    /// hole and the median follows it only over its window). A run of 100 is still
    /// refused.
    #[test]
    fn a_run_of_missing_codes_widens_the_median() {
        let p = FlattenParams::default();
        let mut counts: Vec<u64> = vec![10_000; CODES];
        counts[2033..2048].fill(0);
        assert!(matches!(flatten_histogram(&counts, &p), Err(FlattenError::MedianNotPositive { .. })));
        let (f, q) = flatten_narrowing(&counts, &p).unwrap();
        assert_eq!(q.median_window, 43);
        // The fit range is not narrowed for it (a run inside the counts, not a tail).
        assert_eq!(q.trim_below_fraction, p.trim_below_fraction);
        assert!(f.weights[2033..2048].iter().all(|w| *w == 0.0));
        assert!((f.weights[2032] - 1.0).abs() < 0.03 && (f.weights[2048] - 1.0).abs() < 0.03, "{} {}", f.weights[2032], f.weights[2048]);
        counts[2000..2100].fill(0);
        assert!(flatten_narrowing(&counts, &p).is_err());
    }

    #[test]
    fn without_the_saturation_bin_the_last_code_is_fitted() {
        let counts: Vec<u64> = (0..1024).map(|k| 1_000_000 + 500 * k as u64).collect();
        let p = FlattenParams { set_last_to_one: false, fixed_low_codes: 0, ..FlattenParams::default() };
        let f = flatten_histogram(&counts, &p).unwrap();
        assert_eq!(f.fit_codes, 0..1024);
        assert!(f.weights.iter().all(|w| (w - 1.0).abs() < 1e-9));
        assert!(f.top_offset_dn.abs() < 1e-9);
    }

    /// A median window of one code is no median step: the density is the spline alone,
    /// so a planted period-8 DN error under a cubic illumination comes back (a median of
    /// one code would be the quotient itself and flatten every width to 1).
    #[test]
    fn window_one_is_no_median() {
        const PATTERN: [f64; 8] = [0.04, 0.0, -0.02, 0.0, -0.04, 0.0, 0.03, 0.0];
        let w: Vec<f64> = (0..CODES).map(|k| 1.0 + PATTERN[k % 8]).collect();
        let cubic = |k: f64| 1e9 * (1.0 + 0.3 * k / 4096.0 - 0.2 * (k / 4096.0).powi(3));
        let counts: Vec<u64> = w.iter().enumerate().map(|(k, wk)| (cubic(k as f64) * wk).round() as u64).collect();
        let p = FlattenParams { median_window: 1, ..FlattenParams::default() };
        let f = flatten_histogram(&counts, &p).unwrap();
        let truth = planted_normalized(&w, &f.fit_codes);
        let err: Vec<f64> = f.fit_codes.clone().map(|k| f.weights[k] - truth[k]).collect();
        let (rms, worst) = (crate::infra::stats::rms(&err), crate::infra::stats::max_abs(&err));
        // What is left is the period-8 pattern's leak into the 50-point spline, largest
        // at the ends where the outer basis functions see part of a period (measured: rms
        // 3e-4 or so, at most 4.3e-3); flattening every width to 1 would leave rms 0.025.
        assert!(rms < 1e-3 && worst < 0.01, "width error rms {rms}, largest {worst}");
        assert!(f.median[f.fit_codes.clone()].iter().all(|&m| m == 1.0));
    }

    /// Four ADCs whose offsets ramp within each 256-code block by a gain error of their
    /// own and snap back at the block's end (the real K-Cor ADCs' shape: a narrow code and
    /// a slow rise, `docs/kcor-luts.md`), under one illumination with Poisson counts. The
    /// shared illumination keeps more of each ADC's slow error than each ADC's own
    /// spline and median do (the paper's recipe takes part of it for illumination):
    /// measured centre errors raw 0.19-0.21 DN, paper 0.26-0.52 DN (worse than raw: its
    /// median follows the ramps), shared 0.074-0.103 DN. With ideal ADCs the shared
    /// recipe's widths are the counts' Poisson noise alone.
    #[test]
    fn a_shared_illumination_keeps_what_each_adcs_own_smoothing_takes() {
        let mut rng = StdRng::seed_from_u64(38);
        let gain = rand_distr::Normal::new(0.0, 1.5e-3).unwrap();
        let planted: Vec<Vec<f64>> = (0..4)
            .map(|_| {
                let g: Vec<f64> = (0..CODES / 256).map(|_| gain.sample(&mut rng)).collect();
                (0..CODES).map(|k| if k % 256 == 255 { 1.0 - 255.0 * g[k / 256] } else { 1.0 + g[k / 256] }).collect()
            })
            .collect();
        let hists: Vec<Vec<u64>> = planted.iter().enumerate().map(|(a, w)| synthesize(w, 100 + a as u64).1).collect();
        let error = |w: &[f64], truth: &[f64], fit: &Range<usize>| {
            let centers = |v: &[f64]| -> Vec<f64> { fit.clone().map(|k| cumulative_offsets(v)[k] + k as f64).collect() };
            // The error after the best offset and gain against the truth.
            let (t, c) = (centers(truth), centers(w));
            let rows: Vec<Vec<f64>> = t.iter().map(|&x| vec![1.0, x]).collect();
            let line = crate::infra::stats::lstsq(&rows, &c).unwrap();
            crate::infra::stats::rms(&t.iter().zip(&c).map(|(x, y)| y - line[0] - line[1] * x).collect::<Vec<_>>())
        };
        let shared = flatten_set(&hists, &Recipe::Shared.params()).unwrap();
        let paper = flatten_set(&hists, &Recipe::Paper.params()).unwrap();
        for a in 0..4 {
            let truth = planted_normalized(&planted[a], &shared[a].fit_codes);
            let raw = error(&vec![1.0; CODES], &truth, &shared[a].fit_codes);
            let (s, p) = (error(&shared[a].weights, &truth, &shared[a].fit_codes), error(&paper[a].weights, &truth, &paper[a].fit_codes));
            eprintln!("ADC {a}: centre error raw {raw:.4} DN, paper {p:.4}, shared {s:.4}");
            assert!(s < 0.6 * p && s < 0.6 * raw, "ADC {a}: shared {s}, paper {p}, raw {raw}");
        }
        // Ideal ADCs: the widths' errors standardized by the Poisson sigma have rms near 1
        // (the spline of the mean of four histograms adds about 1/4 of a code's variance
        // spread over 200 codes, far less).
        let ideal: Vec<Vec<u64>> = (0..4).map(|a| synthesize(&vec![1.0; CODES], 7 + a).1).collect();
        let lambda = synthesize(&vec![1.0; CODES], 0).0;
        for (a, f) in flatten_set(&ideal, &Recipe::Shared.params()).unwrap().iter().enumerate() {
            let z: Vec<f64> = f.fit_codes.clone().map(|k| (f.weights[k] - 1.0) * lambda[k].sqrt()).collect();
            let rms = crate::infra::stats::rms(&z);
            assert!((0.9..1.15).contains(&rms), "ADC {a}: standardized rms {rms}");
        }
    }

    /// The largest change of the LUT's centre error over 36 codes (what Fig. 5 at
    /// |Q| <= 0.01 I_max sees, docs/kcor-luts.md) within `codes`, DN.
    fn worst_span_error(w: &[f64], truth: &[f64], codes: Range<usize>) -> f64 {
        let (c, t) = (cumulative_offsets(w), cumulative_offsets(truth));
        let e: Vec<f64> = c.iter().zip(&t).map(|(a, b)| a - b).collect();
        codes.map(|k| (e[k + 36] - e[k]).abs()).fold(0.0, f64::max)
    }

    /// Four ADCs with independent 2% code widths under a light that dips by 1% over
    /// codes 145-175 (the ramps' first levels), and a few wide codes (+0.5 DN) of one ADC
    /// at a time at codes 170-200, as on every real K-Cor camera. The wide codes lift the
    /// four ADCs' mean histogram there and its spline with it; their per-code median
    /// ignores them. The shared recipe (median below code 300) keeps the LUT's worst
    /// 36-code error over codes 150-400 under 0.4 of the mean-only fit's (measured
    /// 0.127-0.145 DN against 0.624-0.637 DN over the four ADCs; what is left is the
    /// dip, which neither spline follows; the counts' own noise is 0.006 DN over 36
    /// codes), and leaves the codes above 300 as they were up to one scale.
    #[test]
    fn one_adcs_wide_codes_at_the_low_end_do_not_bend_the_shared_light() {
        let mut rng = StdRng::seed_from_u64(57);
        let spread = rand_distr::Normal::new(0.0, 0.02).unwrap();
        let widths: Vec<Vec<f64>> = (0..4)
            .map(|a| {
                let mut w: Vec<f64> = (0..CODES).map(|_| 1.0 + spread.sample(&mut rng)).collect();
                for k in [170 + 7 * a, 182 + 7 * a, 194 + 5 * a] {
                    w[k] += 0.5;
                }
                w
            })
            .collect();
        let light = |x: f64| 1.0e6 * (1.0 + 0.2 * x / 4096.0) * (1.0 - 0.012 * (-((x - 160.0) / 12.0).powi(2)).exp());
        let hists: Vec<Vec<u64>> = widths
            .iter()
            .map(|w| {
                let mut below = 0.0;
                let mut counts: Vec<u64> = w
                    .iter()
                    .map(|&wk| {
                        let l = light(below + wk / 2.0) * wk;
                        below += wk;
                        Poisson::new(l).unwrap().sample(&mut rng) as u64
                    })
                    .collect();
                counts[CODES - 1] = 300_000_000;
                counts
            })
            .collect();
        let median_low = Recipe::Shared.params();
        assert_eq!(median_low.median_of_adcs_below, 300);
        let mean_only = FlattenParams { median_of_adcs_below: 0, ..median_low.clone() };
        let (with, without) = (flatten_set(&hists, &median_low).unwrap(), flatten_set(&hists, &mean_only).unwrap());
        let (mut worst_with, mut worst_without) = (0.0f64, 0.0f64);
        for a in 0..4 {
            let truth = planted_normalized(&widths[a], &with[a].fit_codes);
            let (w, wo) = (worst_span_error(&with[a].weights, &truth, 150..400), worst_span_error(&without[a].weights, &truth, 150..400));
            eprintln!("ADC {a}: worst 36-code error over codes 150-400: median below 300 {w:.4} DN, mean only {wo:.4} DN");
            worst_with = worst_with.max(w);
            worst_without = worst_without.max(wo);
            // Above the join the density is the mean's spline, scaled by one constant:
            // the widths differ by that constant alone.
            let ratio: Vec<f64> = (300..4000).map(|k| with[a].weights[k] / without[a].weights[k]).collect();
            let spread = ratio.iter().fold(f64::NEG_INFINITY, |m, &r| m.max(r)) - ratio.iter().fold(f64::INFINITY, |m, &r| m.min(r));
            assert!(spread < 1e-12, "ADC {a}: the widths above the join differ by more than a scale ({spread})");
        }
        assert!(worst_with < 0.4 * worst_without, "median below 300: {worst_with} DN, mean only {worst_without} DN");
        // From the join up the density is the mean's spline itself (scaled to the ADC's
        // counts alike in both), below it the median's: they differ by the join code.
        for a in 0..4 {
            let (sw, so) = (&with[a].spline, &without[a].spline);
            let r: Vec<f64> = (298..303).map(|k| sw[k] / so[k]).collect();
            assert!(r[2..].iter().all(|x| (x / r[2] - 1.0).abs() < 1e-12), "ADC {a}: not the mean's spline from code 300: {r:?}");
            assert!((r[1] / r[2] - 1.0).abs() > 1e-9, "ADC {a}: code 299 is the mean's spline too: {r:?}");
        }
    }
}
