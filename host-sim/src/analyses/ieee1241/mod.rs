//! The histogram (code-density) test of IEEE Std 1241 on one ADC: DNL per code with its
//! uncertainty, INL (end-point and best-fit), missing codes, the worst codes by number,
//! the DNL resolution the counts allow, and the structure of the DNL at every scale
//! ([`structure`]).
//!
//! ## Input densities
//! A code `k` that is `w_k` LSB wide collects `h_k ~ Poisson(E_k w_k)` samples, `E_k` the
//! counts a code of the mean width collects where it sits. How `E_k` is known depends on
//! the input:
//! - [`Density::Smooth`] (the paper's, the default): an illumination ramp whose density is
//!   smooth over tens of codes; `E_k` is the paper's spline times its running median
//!   ([`crate::analyses::flatten`]). Structure slower than the median window (21 codes) cannot be
//!   told from the illumination and is removed with it, so INL is measured on shorter
//!   scales only.
//! - [`Density::Ramp`]: the standard's linear ramp, `E_k` the same for every code.
//! - [`Density::Sine`]: the standard's sine-wave histogram test. The transition levels are
//!   `T_k = C - A cos(pi CH_k / S)` (`CH_k` the samples below code `k`, `S` all samples);
//!   offset `C` and amplitude `A` drop out of the normalization, and `E_k` is the
//!   arcsine density `S / (pi sqrt(1 - t^2))` times the mean width.
//!
//! In every case the analysed codes exclude the first and the last code holding counts
//! (they collect the overdrive of the ramp or sine), as the standard does.
//!
//! ## Definitions (IEEE Std 1241, LSB = the mean width of the analysed codes)
//! ```text
//! DNL_k        = w_k / mean(w) - 1
//! T_j          = sum_{first <= k < j} w_k / mean(w)        transition into code j
//! INL end-point = T_j - (j - first)                          (the line through both ends)
//! INL best-fit  = T_j - (a + b j), least squares over all transitions
//! ```
//!
//! ## Uncertainty and naming
//! A width's variance is `w / E` (Poisson), so the DNL of one code is known to
//! `1 / sqrt(E)` LSB: ±0.31 LSB at 3 sigma with 96 counts per code, and four times the
//! counts halve it. A code is **named** (wide, narrow, missing) when its count is outside
//! what a code of the mean width gives with probability `alpha / n` on either side (exact
//! Poisson tails; `alpha` = 0.001 family-wise over the `n` codes), with `E_k` taken at the
//! end of its own uncertainty least favourable to the naming (the smooth density's median
//! carries `pi / (2 window E)` relative variance), and when it departs from the mean width
//! by at least [`GROSS_LSB`]. A code with no counts is **missing** when even a code half
//! as wide would have collected some (`exp(-E/2) < alpha / n`); otherwise it is listed as
//! empty with the probability an ideal code had of being empty.

pub mod architecture;
pub mod structure;

use serde::Serialize;
use statrs::distribution::{DiscreteCDF, Poisson};

use std::path::Path;

use crate::formats::fits::AdcHistograms;
use crate::analyses::flatten::{flatten_narrowing, FlattenError, FlattenParams};
use crate::formats::outputs::Outputs;
use crate::formats::plots::{dnl_inl_plot, MarkedCodes, Series};
use crate::infra::stats::{max_abs, rms};
use crate::HostError;

/// Family-wise probability that an ideal ADC has any code named, over all analysed codes.
pub const ALPHA: f64 = 1e-3;
/// The least departure from the mean width, LSB, for a code to be named: half a code.
/// Below it, a significant departure is DNL, reported in the per-code arrays, but not a
/// defect a datasheet lists (at 10^6 counts a code every code is significant at 1%).
pub const GROSS_LSB: f64 = 0.5;
/// Fewest mean counts per code analysed (the flattening's default, defined there).
pub use crate::analyses::flatten::MIN_COUNTS_PER_CODE;
/// Fewest analysed codes.
pub const MIN_CODES: usize = 16;
/// Codes listed as the worst.
pub const WORST: usize = 10;
/// Confidence of the upper bound on a missing code's width.
const MISSING_BOUND: f64 = 0.999;

/// How the input spread its samples over the ADC's range (module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Density {
    /// An illumination ramp smooth over tens of codes: the paper's flattening.
    #[default]
    Smooth,
    /// The standard's linear ramp: the same counts per code everywhere.
    Ramp,
    /// The standard's sine-wave histogram test: the arcsine density.
    Sine,
}

impl Density {
    /// The name used on the command line and in JSON.
    pub fn name(self) -> &'static str {
        match self {
            Density::Smooth => "smooth",
            Density::Ramp => "ramp",
            Density::Sine => "sine",
        }
    }
}

/// Why one ADC's histogram could not be analysed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TestError {
    /// Not one count per code of a 1- to 16-bit ADC.
    #[error("histogram of {len} codes: expected 2^B codes with 5 <= B <= 16 (at least {MIN_CODES} codes between the two end codes)")]
    Length {
        /// Codes in the histogram.
        len: usize,
    },
    /// Too few codes between the two end codes that hold counts.
    #[error("{codes} codes between the first and the last code with counts (both excluded as the ramp's ends); at least {MIN_CODES} needed")]
    TooFewCodes {
        /// Codes analysable.
        codes: usize,
    },
    /// Too few counts per code to measure any width.
    #[error("{mean:.3} counts per code on average: below {MIN_COUNTS_PER_CODE} a code's width is not measured to better than its own size (1/sqrt(counts) LSB at 1 sigma)")]
    TooFewCounts {
        /// Mean counts per analysed code.
        mean: f64,
    },
    /// The paper's flattening failed (smooth density).
    #[error("{0}")]
    Flatten(#[from] FlattenError),
}

/// How a named code departs from the mean width.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum CodeKind {
    /// Wider than the mean by [`GROSS_LSB`] or more, significantly.
    Wide,
    /// Narrower by [`GROSS_LSB`] or more, significantly, but with counts.
    Narrow,
    /// No counts, where a code half the mean width would have had some.
    Missing,
}

/// One code's measured width.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CodeWidth {
    /// The code.
    pub code: usize,
    /// Samples it holds.
    pub counts: u64,
    /// Counts a code of the mean width collects there.
    pub expected: f64,
    /// Its DNL, LSB (`width - 1`).
    pub dnl_lsb: f64,
    /// One-sigma uncertainty of the DNL, LSB.
    pub sigma_lsb: f64,
    /// The probability of a count at least this far from `expected` on its side, for a
    /// code of the mean width (one-sided exact Poisson tail); computed for the codes
    /// listed (named, missing, empty, worst).
    pub p_ideal: f64,
    /// Named, and how (None: within what the counts resolve, or under [`GROSS_LSB`]).
    pub kind: Option<CodeKind>,
}

/// What the counts allow to be seen.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Resolution {
    /// Mean counts of a code of the mean width over the analysed codes.
    pub counts_per_code: f64,
    /// DNL uncertainty of one code at 1 sigma, LSB (`1 / sqrt(counts_per_code)`).
    pub dnl_sigma_lsb: f64,
    /// A code is named as wide from this width on, LSB (at the mean counts).
    pub named_wide_from_lsb: f64,
    /// A code is named as narrow below this width, LSB (at the mean counts).
    pub named_narrow_below_lsb: f64,
    /// A code with no counts is missing (not unlucky) from this many counts per code.
    pub missing_needs_counts: f64,
    /// Largest one-sigma uncertainty of the INL along the range, LSB (at mid range: the
    /// counts' noise summed code by code, tied at both ends).
    pub inl_sigma_lsb: f64,
    /// INL is measured only on scales shorter than this many codes (the smooth density's
    /// running median); None for the ramp and sine densities.
    pub inl_scale_codes: Option<usize>,
    /// RMS of the end-point INL over the RMS the counts' noise alone gives it (ramp and
    /// sine): about 1 or more for independent counts; far below 1 (under
    /// [`SUB_POISSON`]) when the counts are not independent, as from a stepped ramp
    /// sampled at fixed times, whose count errors are each code edge's and cancel between
    /// neighbours: then every uncertainty stated is an upper bound.
    pub inl_over_noise: Option<f64>,
}

/// [`Resolution::inl_over_noise`] below which the counts are said not to be independent.
pub const SUB_POISSON: f64 = 0.3;

impl Resolution {
    /// "±0.31 LSB per code at 3 sigma (96.3 counts a code; 4x the counts halve it) ..."
    pub fn sentence(&self) -> String {
        let inl = match self.inl_scale_codes {
            Some(w) => format!("INL over spans shorter than {w} codes only (slower structure is removed with the illumination)"),
            None => format!("INL to ±{:.2} LSB at 1 sigma mid-range", self.inl_sigma_lsb),
        };
        let dependent = match self.inl_over_noise {
            Some(r) if r < SUB_POISSON => format!(
                "; the INL scatters {r:.2} times what independent counts would give it: the counts are not independent (a stepped ramp sampled at fixed times?), so these uncertainties are upper bounds"
            ),
            _ => String::new(),
        };
        let narrow = if self.named_narrow_below_lsb > 0.0 { format!("or below {:.2} LSB", self.named_narrow_below_lsb) } else { "(no code with counts can be named narrow at these counts)".into() };
        format!(
            "DNL resolution ±{:.3} LSB per code at 3 sigma ({:.1} counts a code; 4x the counts halve it); codes named from {:.2} LSB wide {narrow}; a code with no counts is missing from {:.1} counts a code; {inl}{dependent}",
            3.0 * self.dnl_sigma_lsb,
            self.counts_per_code,
            self.named_wide_from_lsb,
            self.missing_needs_counts
        )
    }
}

/// The histogram test of one ADC.
#[derive(Debug, Clone, Serialize)]
pub struct AdcLinearity {
    /// How `E_k` was estimated.
    pub density: Density,
    /// Bits of the ADC.
    pub bits: u32,
    /// First analysed code.
    pub first_code: usize,
    /// Last analysed code (inclusive).
    pub last_code: usize,
    /// DNL of every analysed code, LSB (`dnl_lsb[i]` is code `first_code + i`).
    pub dnl_lsb: Vec<f64>,
    /// Its one-sigma uncertainty, LSB.
    pub dnl_sigma_lsb: Vec<f64>,
    /// End-point INL at every transition `first_code ..= last_code + 1`, LSB.
    pub inl_endpoint_lsb: Vec<f64>,
    /// Best-fit INL at the same transitions, LSB.
    pub inl_bestfit_lsb: Vec<f64>,
    /// Largest |DNL|, LSB.
    pub max_abs_dnl_lsb: f64,
    /// Largest |end-point INL|, LSB.
    pub max_abs_inl_endpoint_lsb: f64,
    /// Largest |best-fit INL|, LSB.
    pub max_abs_inl_bestfit_lsb: f64,
    /// Codes with no counts that are missing (module documentation).
    pub missing: Vec<CodeWidth>,
    /// Codes with no counts that an ideal code could have had by chance.
    pub empty_inconclusive: Vec<CodeWidth>,
    /// Every named code (wide, narrow, missing), by code.
    pub named: Vec<CodeWidth>,
    /// The [`WORST`] codes of largest |DNL|, worst first.
    pub worst: Vec<CodeWidth>,
    /// What the counts resolve.
    pub resolution: Resolution,
    /// Periods, bit-boundary patterns and architectures.
    pub structure: structure::Structure,
    /// Counts of a code of the mean width at each analysed code.
    #[serde(skip)]
    pub expected: Vec<f64>,
    /// The counts of the analysed codes.
    #[serde(skip)]
    pub counts: Vec<u64>,
}

impl AdcLinearity {
    /// The analysed codes.
    pub fn codes(&self) -> std::ops::Range<usize> {
        self.first_code..self.last_code + 1
    }

    /// One paragraph for the text summaries (indented by `indent`).
    pub fn text(&self, indent: &str) -> String {
        let mut t = format!(
            "{indent}IEEE 1241 histogram test ({} density), codes {}..={}: max |DNL| {:.3} LSB, max |INL| {:.3} LSB end-point, {:.3} LSB best-fit{}\n",
            self.density.name(),
            self.first_code,
            self.last_code,
            self.max_abs_dnl_lsb,
            self.max_abs_inl_endpoint_lsb,
            self.max_abs_inl_bestfit_lsb,
            match self.resolution.inl_scale_codes {
                Some(w) => format!(" (over spans below {w} codes)"),
                None => format!(" (the counts' noise alone: ±{:.2} LSB at 1 sigma mid-range)", self.resolution.inl_sigma_lsb),
            }
        );
        t += &format!("{indent}  {}\n", self.resolution.sentence());
        t += &format!("{indent}  missing codes: {}\n", list_codes(&self.missing, 12, |c| format!("{} (width < {:.3} LSB at {:.1}%)", c.code, missing_bound(c.expected), 100.0 * MISSING_BOUND)));
        if !self.empty_inconclusive.is_empty() {
            t += &format!("{indent}  empty but not resolved as missing: {}\n", list_codes(&self.empty_inconclusive, 12, |c| format!("{} (p = {:.2e} for an ideal code)", c.code, c.p_ideal)));
        }
        t += &format!("{indent}  wide codes: {}\n", self.named_list(CodeKind::Wide, 12));
        t += &format!("{indent}  narrow codes: {}\n", self.named_list(CodeKind::Narrow, 12));
        t += &format!("{indent}  worst codes: {}\n", self.worst.iter().map(width_text).collect::<Vec<_>>().join(", "));
        for line in self.structure.lines() {
            t += &format!("{indent}  {line}\n");
        }
        t
    }
}

impl AdcLinearity {
    /// The DNL/INL figure ([`dnl_inl_plot`]) staged in `out` at `path`.
    pub fn figure(&self, out: &mut Outputs, path: &Path, title: &str) -> Result<(), HostError> {
        let code = |i: usize| (self.first_code + i) as f64;
        let dnl = Series { label: format!("DNL, max |DNL| {:.3} LSB", self.max_abs_dnl_lsb), points: self.dnl_lsb.iter().enumerate().map(|(i, d)| (code(i), *d)).collect() };
        let band = |sign: f64| Series { label: "±3 sigma of the counts".into(), points: self.expected.iter().enumerate().map(|(i, e)| (code(i), sign * 3.0 / e.sqrt())).collect() };
        let inl = |v: &[f64], what: &str, max: f64| Series { label: format!("INL {what}, max {max:.3} LSB"), points: v.iter().enumerate().map(|(j, x)| (code(j), *x)).collect() };
        let mark = |c: &CodeWidth| (c.code as f64, c.dnl_lsb, c.code.to_string());
        let marks = MarkedCodes {
            named: self.named.iter().filter(|c| c.kind != Some(CodeKind::Missing)).map(mark).collect(),
            missing: self.missing.iter().map(mark).collect(),
        };
        let sigma = self.inl_sigma_lsb();
        let inl_band = |sign: f64| Series { label: "±2 sigma of the counts (end-point)".into(), points: sigma.iter().enumerate().map(|(j, s)| (code(j), sign * 2.0 * s)).collect() };
        let inls = [inl(&self.inl_endpoint_lsb, "end-point", self.max_abs_inl_endpoint_lsb), inl(&self.inl_bestfit_lsb, "best-fit", self.max_abs_inl_bestfit_lsb)];
        dnl_inl_plot(out, path, title, &dnl, &[band(1.0), band(-1.0)], &inls, &[inl_band(1.0), inl_band(-1.0)], &marks)
    }

    /// One-sigma noise of the end-point INL at each transition, LSB ([`bridge_sigma`]).
    pub fn inl_sigma_lsb(&self) -> Vec<f64> {
        bridge_sigma(&self.expected)
    }
}

/// One-sigma noise of the end-point INL at each of the `expected.len() + 1` transitions,
/// LSB: the widths' variances `1/E_k` summed, tied at both ends (a Brownian bridge).
fn bridge_sigma(expected: &[f64]) -> Vec<f64> {
    let cum: Vec<f64> = std::iter::once(0.0)
        .chain(expected.iter().scan(0.0, |s, e| {
            *s += 1.0 / e;
            Some(*s)
        }))
        .collect();
    let total = cum.last().copied().unwrap_or(0.0).max(1e-300);
    cum.iter().map(|a| (a * (total - a) / total).max(0.0).sqrt()).collect()
}

/// Every ADC of a histogram set through [`analyse`]; `source` names the set in errors.
pub fn analyse_set(h: &AdcHistograms, density: Density, flatten: &FlattenParams, source: &Path) -> Result<Vec<AdcLinearity>, HostError> {
    let flatten = &flatten.per_adc();
    h.counts
        .iter()
        .enumerate()
        .map(|(adc, counts)| analyse(counts, density, flatten).map_err(|e| HostError::Ieee1241 { path: source.into(), adc, density, source: e }))
        .collect()
}

impl AdcLinearity {
    /// The named codes of `kind`, each with its width, up to `most` and then how many
    /// more: "511 (9.06 ± 0.31 LSB), 1535 (...)"; "none".
    pub fn named_list(&self, kind: CodeKind, most: usize) -> String {
        let v: Vec<CodeWidth> = self.named.iter().filter(|c| c.kind == Some(kind)).cloned().collect();
        list_codes(&v, most, width_text)
    }
}

/// "2047 (0.02 ± 0.10 LSB)": a code and its width.
fn width_text(c: &CodeWidth) -> String {
    format!("{} ({:.2} ± {:.2} LSB)", c.code, 1.0 + c.dnl_lsb, c.sigma_lsb)
}

/// Up to `most` codes, then how many more; "none" when empty.
fn list_codes(v: &[CodeWidth], most: usize, f: impl Fn(&CodeWidth) -> String) -> String {
    if v.is_empty() {
        return "none".into();
    }
    let mut s = v.iter().take(most).map(f).collect::<Vec<_>>().join(", ");
    if v.len() > most {
        s += &format!(" and {} more", v.len() - most);
    }
    s
}

/// Upper bound on the width of a code with no counts, LSB, at [`MISSING_BOUND`].
pub fn missing_bound(expected: f64) -> f64 {
    -(1.0 - MISSING_BOUND).ln() / expected.max(1e-300)
}

/// What the density estimate gives per analysed code.
struct Estimate {
    first: usize,
    last: usize,
    /// Relative width of each analysed code (any scale).
    widths: Vec<f64>,
    /// Counts of a unit (same scale) width at each analysed code.
    expected: Vec<f64>,
    /// Relative variance of each `expected`.
    expected_var: Vec<f64>,
    inl_scale: Option<usize>,
    /// Codes this far inside either end of the analysed range are not named: the smooth
    /// density's spline and median cannot follow the edges of an illumination there
    /// (0 for the ramp and sine densities).
    edge_margin: usize,
}

/// The first and last codes with counts.
fn ends(counts: &[u64]) -> Option<(usize, usize)> {
    Some((counts.iter().position(|&c| c > 0)?, counts.iter().rposition(|&c| c > 0)?))
}

fn estimate(counts: &[u64], density: Density, flatten: &FlattenParams) -> Result<Estimate, TestError> {
    let n = counts.len();
    let (lo, hi) = ends(counts).ok_or(TestError::TooFewCodes { codes: 0 })?;
    let (mut first, mut last) = (lo + 1, hi.saturating_sub(1));
    let enough = |first: usize, last: usize| if last + 1 >= first + MIN_CODES { Ok(()) } else { Err(TestError::TooFewCodes { codes: (last + 1).saturating_sub(first) }) };
    enough(first, last)?;
    let total = |a: usize, b: usize| counts[a..=b].iter().map(|&c| c as f64).sum::<f64>();
    match density {
        Density::Ramp => {
            let e = total(first, last) / (last + 1 - first) as f64;
            let widths = counts[first..=last].iter().map(|&c| c as f64 / e.max(1e-300)).collect();
            let m = last + 1 - first;
            Ok(Estimate { first, last, widths, expected: vec![e; m], expected_var: vec![1.0 / total(first, last).max(1.0); m], inl_scale: None, edge_margin: 0 })
        }
        Density::Sine => {
            let s: f64 = counts.iter().map(|&c| c as f64).sum();
            let mut below = counts[..first].iter().map(|&c| c as f64).sum::<f64>();
            let mut t = Vec::with_capacity(last + 2 - first);
            for &c in &counts[first..=last] {
                t.push(-(std::f64::consts::PI * below / s).cos());
                below += c as f64;
            }
            t.push(-(std::f64::consts::PI * below / s).cos());
            let m = last + 1 - first;
            let delta = (t[m] - t[0]) / m as f64;
            let widths: Vec<f64> = t.windows(2).map(|p| (p[1] - p[0]) / delta).collect();
            let expected: Vec<f64> = t
                .windows(2)
                .map(|p| {
                    let centre = 0.5 * (p[0] + p[1]);
                    s * delta / (std::f64::consts::PI * (1.0 - centre * centre).max(1e-300).sqrt())
                })
                .collect();
            Ok(Estimate { first, last, widths, expected, expected_var: vec![1.0 / total(first, last).max(1.0); m], inl_scale: None, edge_margin: 0 })
        }
        Density::Smooth => {
            let (f, p) = flatten_narrowing(counts, &FlattenParams { min_mean_count: 0.0, ..flatten.clone() })?;
            first = first.max(f.fit_codes.start);
            last = last.min(f.fit_codes.end.saturating_sub(1)).min(n - 1);
            enough(first, last)?;
            let expected: Vec<f64> = (first..=last).map(|k| f.spline[k] * f.median[k]).collect();
            let widths: Vec<f64> = (first..=last).zip(&expected).map(|(k, e)| counts[k] as f64 / e).collect();
            let median_var = crate::analyses::flatten::median_variance(p.median_window);
            let expected_var = expected.iter().map(|e| median_var / e.max(1e-300)).collect();
            // A median window plus a knot interval of the spline, as `diagnose` scores
            // (an ideal ADC under a ramp blurred at its ends had codes 10 counts of 48
            // named narrow at the top edge before).
            let fit = &f.fit_codes;
            let edge_margin = p.median_window + (fit.end - fit.start) / p.spline_points.saturating_sub(3).max(1);
            Ok(Estimate { first, last, widths, expected, expected_var, inl_scale: Some(p.median_window), edge_margin })
        }
    }
}

/// Poisson tail `P(X >= h)` for mean `lambda`.
fn upper_tail(h: u64, lambda: f64) -> f64 {
    if h == 0 {
        return 1.0;
    }
    Poisson::new(lambda.max(1e-300)).map_or(0.0, |d| d.sf(h - 1))
}

/// Poisson tail `P(X <= h)` for mean `lambda`.
fn lower_tail(h: u64, lambda: f64) -> f64 {
    Poisson::new(lambda.max(1e-300)).map_or(1.0, |d| d.cdf(h))
}

/// The widths from which codes are named at mean counts `e` and tail `threshold`, LSB:
/// (least wide count / e, greatest narrow count / e), by walking the exact tails.
fn naming_widths(e: f64, threshold: f64) -> (f64, f64) {
    let mut h = e.ceil() as u64;
    while upper_tail(h, e) >= threshold {
        h += (e.sqrt() / 8.0).max(1.0) as u64;
    }
    let wide = (h as f64 / e).max(1.0 + GROSS_LSB);
    let mut l = e.floor() as u64;
    let narrow = loop {
        if lower_tail(l, e) < threshold {
            break (l as f64 / e).min(1.0 - GROSS_LSB);
        }
        if l == 0 {
            break 0.0;
        }
        l = l.saturating_sub((e.sqrt() / 8.0).max(1.0) as u64);
    };
    (wide, narrow)
}

/// The histogram test of one ADC's code histogram (module documentation).
///
/// ```
/// use dncal_host::analyses::ieee1241::{analyse, Density};
/// use dncal_host::analyses::flatten::FlattenParams;
/// // A 10-bit ramp with 100 counts a code and code 511 missing.
/// let mut counts = vec![100u64; 1024];
/// counts[511] = 0;
/// let t = analyse(&counts, Density::Ramp, &FlattenParams::default()).unwrap();
/// assert_eq!(t.missing.iter().map(|c| c.code).collect::<Vec<_>>(), vec![511]);
/// assert!((t.resolution.dnl_sigma_lsb - 0.1).abs() < 1e-3);
/// ```
pub fn analyse(counts: &[u64], density: Density, flatten: &FlattenParams) -> Result<AdcLinearity, TestError> {
    analyse_at(counts, density, flatten, ALPHA)
}

/// [`analyse`] with the family-wise probability `alpha` of naming a code of an ideal ADC
/// (`diagnose` names candidates on one half of the counts at 0.5 and confirms them on the
/// other).
pub fn analyse_at(counts: &[u64], density: Density, flatten: &FlattenParams, alpha: f64) -> Result<AdcLinearity, TestError> {
    let n = counts.len();
    if n < 32 || !n.is_power_of_two() || n > 1 << 16 {
        return Err(TestError::Length { len: n });
    }
    let bits = n.trailing_zeros();
    let est = estimate(counts, density, flatten)?;
    let (first, last) = (est.first, est.last);
    let m = last + 1 - first;
    let mean_w = est.widths.iter().sum::<f64>() / m as f64;
    // Expected counts of a code of the mean width: the LSB of the test.
    let expected: Vec<f64> = est.expected.iter().map(|e| e * mean_w).collect();
    let mean_e = expected.iter().sum::<f64>() / m as f64;
    if mean_e.is_nan() || mean_e < MIN_COUNTS_PER_CODE {
        return Err(TestError::TooFewCounts { mean: mean_e });
    }
    let dnl: Vec<f64> = est.widths.iter().map(|w| w / mean_w - 1.0).collect();
    let threshold = alpha / m as f64;
    let mut all = Vec::with_capacity(m);
    for i in 0..m {
        let (h, e) = (counts[first + i], expected[i]);
        let rel = est.expected_var[i].sqrt();
        let w = 1.0 + dnl[i];
        let sigma = ((w.max(1.0 / e) / e) + (w * rel).powi(2)).sqrt();
        let inside = i >= est.edge_margin && i + est.edge_margin < m;
        // Only a code half an LSB off (or empty) can be named; the exact tails of the
        // others are not needed (and cost seconds at 10^12 counts a code).
        let kind = if inside && (h == 0 || dnl[i].abs() >= GROSS_LSB) {
            // E at the end of its uncertainty least favourable to naming the code: a count
            // is less extreme against a higher E when wide, a lower E when narrow.
            let (e_lo, e_hi) = (e * (1.0 - 2.0 * rel).max(0.0), e * (1.0 + 2.0 * rel));
            if h == 0 && (-e_lo / 2.0).exp() < threshold {
                // Missing when a code half as wide would have had counts.
                Some(CodeKind::Missing)
            } else if h as f64 > e && upper_tail(h, e_hi) < threshold {
                Some(CodeKind::Wide)
            } else if (h as f64) < e && lower_tail(h, e_lo) < threshold {
                Some(CodeKind::Narrow)
            } else {
                None
            }
        } else {
            None
        };
        all.push(CodeWidth { code: first + i, counts: h, expected: e, dnl_lsb: dnl[i], sigma_lsb: sigma, p_ideal: f64::NAN, kind });
    }
    // INL at the transitions first..=last+1, in LSB of the mean width.
    let mut t = Vec::with_capacity(m + 1);
    let mut acc = 0.0;
    t.push(0.0);
    for d in &dnl {
        acc += 1.0 + d;
        t.push(acc);
    }
    let endpoint: Vec<f64> = t.iter().enumerate().map(|(j, tj)| tj - j as f64 * acc / m as f64).collect();
    let x: Vec<f64> = (0..=m).map(|j| j as f64).collect();
    let (c0, c1, _) = crate::infra::stats::fit_line(&x, &t);
    let bestfit: Vec<f64> = t.iter().enumerate().map(|(j, tj)| tj - c0 - c1 * j as f64).collect();
    let (named_wide_from_lsb, named_narrow_below_lsb) = naming_widths(mean_e, threshold);
    let inl_sigma = bridge_sigma(&expected);
    let inl_noise = max_abs(&inl_sigma);
    let resolution = Resolution {
        counts_per_code: mean_e,
        dnl_sigma_lsb: 1.0 / mean_e.sqrt(),
        named_wide_from_lsb,
        named_narrow_below_lsb,
        missing_needs_counts: 2.0 * (1.0 / threshold).ln(),
        inl_sigma_lsb: inl_noise,
        inl_scale_codes: est.inl_scale,
        inl_over_noise: (est.inl_scale.is_none() && rms(&inl_sigma) > 0.0).then(|| rms(&endpoint) / rms(&inl_sigma)),
    };
    // The probability of each listed code's count for a code of the mean width.
    let with_p = |c: &CodeWidth| CodeWidth { p_ideal: if c.counts as f64 > c.expected { upper_tail(c.counts, c.expected) } else { lower_tail(c.counts, c.expected) }, ..c.clone() };
    let missing: Vec<CodeWidth> = all.iter().filter(|c| c.kind == Some(CodeKind::Missing)).map(with_p).collect();
    let empty_inconclusive: Vec<CodeWidth> = all.iter().filter(|c| c.counts == 0 && c.kind.is_none()).map(with_p).collect();
    let named: Vec<CodeWidth> = all.iter().filter(|c| c.kind.is_some()).map(with_p).collect();
    let mut order: Vec<usize> = (0..m).collect();
    order.sort_by(|&a, &b| dnl[b].abs().total_cmp(&dnl[a].abs()).then(a.cmp(&b)));
    let worst = order.iter().take(WORST).map(|&i| with_p(&all[i])).collect();
    // The structure's weights come from the noise of a code of the mean width, not from
    // each code's own count: weights that fall with the count bias every weighted mean
    // low (an ideal ADC's even codes read 0.012 LSB narrow at 5 sigma).
    let model_sigma: Vec<f64> = expected.iter().zip(&est.expected_var).map(|(e, v)| (1.0 / e + v).sqrt()).collect();
    let structure = structure::Structure::of(bits, first, &dnl, &model_sigma, &named);
    Ok(AdcLinearity {
        density,
        bits,
        first_code: first,
        last_code: last,
        max_abs_dnl_lsb: max_abs(&dnl),
        max_abs_inl_endpoint_lsb: max_abs(&endpoint),
        max_abs_inl_bestfit_lsb: max_abs(&bestfit),
        dnl_lsb: dnl,
        dnl_sigma_lsb: all.iter().map(|c| c.sigma_lsb).collect(),
        inl_endpoint_lsb: endpoint,
        inl_bestfit_lsb: bestfit,
        missing,
        empty_inconclusive,
        named,
        worst,
        resolution,
        structure,
        expected,
        counts: counts[first..=last].to_vec(),
    })
}

#[cfg(test)]
mod tests;
