//! The EMVA 1288 datasheet of a linear camera, computed as the standard defines it and
//! as its reference implementation (`emva1288` 1.0.2, Release 3.1 definitions) applies
//! it; where Release 4.0 differs and the descriptor says `v 4...` (or `--release 4.0`),
//! the 4.0 definition is used (`docs/emva.md` lists every difference).
//!
//! Temporal quantities, from the photon-transfer points ([`super::photon_transfer`]),
//! sorted by photons; `Y = mu_y - mu_y.dark` the mean above dark, DN:
//!
//! - **Saturation**: the variance maximum, searched from the brightest level down and
//!   stopping at the first level where this and the next lower level are both below the
//!   running maximum (one-level dips pass), as the reference does. Where no brighter
//!   level has less than 80% of that maximum the variance never turned over: saturation
//!   was not reached, the fit ranges are taken from the brightest level, and the
//!   quantities that need saturation have no value. Release 4.0 (section 6.6): the brightest level
//!   with at most 0.2% of its pixels at the top code, once some level reaches 0.1%.
//! - **System gain K**, DN/e-: least squares through the origin of `sigma_y^2 -
//!   sigma_y.dark^2` on `Y` over the levels up to the last one with `Y <= 0.7 Y_sat`;
//!   Release 4.0 (eq. 50) with a free offset.
//! - **Responsivity R**, DN/photon: the same fit of `Y` on photons; **QE** `eta = R / K`.
//! - **Dark noise** `sigma_y.dark`, DN: the dark variance at the shortest exposure (with
//!   at most two exposure times) or the zero-exposure intercept of its line in exposure
//!   time (Release 4.0: always the shortest exposure); below 0.24 DN^2 it is set to 0.24
//!   DN^2, i.e. 0.49 DN (quantization dominates; the standard's floor, eqs. 53-54). In electrons `sigma_d = sqrt(sigma_y.dark^2 - 1/12) / K`: the quantization
//!   variance of 1/12 DN^2 is taken out.
//! - **Absolute sensitivity threshold**, photons: Release 3.1 `(sigma_y.dark / K + 1/2) /
//!   eta`; Release 4.0 the signal where SNR = 1 exactly, `(1/2 + sqrt(1/4 + sigma_y.dark^2
//!   / K^2)) / eta`.
//! - **Saturation capacity** `mu_e.sat = eta mu_p.sat`, **SNR_max** `sqrt(mu_e.sat)`,
//!   **dynamic range** `mu_p.sat / mu_p.min`.
//! - **Linearity error**: the line minimizing the squared relative deviations over
//!   `0.05 Y_sat <= Y <= 0.95 Y_sat`, and the smallest and largest deviation `100 (Y - fit)
//!   / fit` there, %; and Release 4.0's single figure (eq. 63), the mean |deviation|.
//! - **Dark current** (with more than two exposure times): slope of the dark mean (DN/s,
//!   then / K) and of the dark variance (DN^2/s, then / K^2) on exposure time, e-/s.

use std::collections::BTreeMap;

use serde::Serialize;

use super::fit::{fit_line, fit_origin, fit_relative};
use super::PtcPoint;

/// The standard's quantization noise variance, DN^2.
const QUANTIZATION_VAR_DN2: f64 = 1.0 / 12.0;
/// The dark variance below which quantization dominates and the standard substitutes
/// this value, DN^2 (Release 3.1 section 6.3; the reference implementation's floor).
const DARK_VAR_FLOOR_DN2: f64 = 0.24;
/// Release 4.0 saturation (section 6.6): the brightest level with at most this share of
/// pixels at the top code...
const OVERFLOW_MAX: f64 = 0.002;
/// ... once some level reaches this share (else saturation by overflow was not measured).
const OVERFLOW_MIN: f64 = 0.001;
/// A level brighter than the variance maximum with less than this share of it shows that
/// the variance turned over (saturation reached).
const TURNOVER: f64 = 0.8;
/// A series whose variance has not turned over but whose brightest level (dark included)
/// is at this share of the top code or above **ends at saturation**: the standard's
/// saturation, the variance maximum, is taken there (as the reference does) and noted.
/// Below it nothing near saturation was measured and the values that need it are `None`.
const AT_SERIES_END: f64 = 0.9;
/// Fewest photon-transfer levels accepted. The standard asks for at least 50 equally
/// spaced levels; with fewer the fits still work, so fewer than this many is refused and
/// fewer than 50 is noted.
pub const MIN_LEVELS: usize = 6;
/// The standard's number of levels.
pub const STANDARD_LEVELS: usize = 50;

/// Which release's definitions are applied.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Release {
    /// Release 3.0/3.1, as the reference implementation computes them.
    #[serde(rename = "3.1")]
    R3,
    /// Release 4.0 (linear cameras).
    #[serde(rename = "4.0")]
    R4,
}

impl Release {
    /// The release a descriptor's `v` record selects: 4.x is Release 4.0, anything else
    /// (3.0, 3.1, none) Release 3.1.
    pub fn from_version(version: Option<&str>) -> Release {
        match version {
            Some(v) if v.trim().starts_with('4') => Release::R4,
            _ => Release::R3,
        }
    }

    /// Parses `3.0`, `3.1` or `4.0` (a command-line choice).
    pub fn parse(s: &str) -> Result<Release, String> {
        match s {
            "3" | "3.0" | "3.1" => Ok(Release::R3),
            "4" | "4.0" => Ok(Release::R4),
            other => Err(format!("unknown EMVA 1288 release {other:?}: 3.1 or 4.0")),
        }
    }
}

/// One level of the SNR curve.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SnrPoint {
    /// Photons per pixel.
    pub photons: f64,
    /// Measured `Y / sigma_y`.
    pub measured: f64,
    /// The linear model's `eta mu_p / sqrt(sigma_d^2 + sigma_q^2 / K^2 + eta mu_p)`.
    pub model: f64,
}

/// The temporal part of the datasheet. Values that a set cannot give are `None`, with
/// the reason in `why` under the same key.
#[derive(Debug, Clone, Serialize)]
pub struct PtcSummary {
    /// Definitions applied.
    pub release: Release,
    /// Photon-transfer levels (temporal series, illuminated).
    pub levels: usize,
    /// Index (in photon order) of the saturation level.
    pub saturation_index: usize,
    /// Whether the variance turned over below the brightest level (or, Release 4.0,
    /// pixels overflowed).
    pub saturation_reached: bool,
    /// The variance did not turn over, but the series ends at 90% of the top code or
    /// above: saturation is taken at the variance maximum, the standard's definition
    /// (`why["saturation"]` says so), and the values that need it are given.
    pub saturation_at_series_end: bool,
    /// Mean above dark at saturation, DN.
    pub saturation_dn: f64,
    /// Photons per pixel at saturation (`mu_p.sat`, when reached).
    pub saturation_photons: Option<f64>,
    /// Levels in the gain and responsivity fits (up to 70% of saturation).
    pub gain_fit_levels: usize,
    /// Responsivity R, DN per photon.
    pub responsivity_dn_per_photon: f64,
    /// R^2 of a free line of `Y` on photons over the same levels (a quality figure).
    pub linearity_r2: f64,
    /// System gain K, DN per electron.
    pub gain_dn_per_e: f64,
    /// R^2 of a free line of the variance on `Y` over the same levels.
    pub gain_r2: f64,
    /// 1/K, electrons per DN.
    pub gain_e_per_dn: f64,
    /// Quantum efficiency `R / K` (a fraction).
    pub quantum_efficiency: f64,
    /// `sigma_y.dark`, DN, after the standard's floor.
    pub dark_noise_dn: f64,
    /// `sigma_y.dark` as measured, DN (before the floor).
    pub dark_noise_measured_dn: f64,
    /// `sigma_d`, electrons.
    pub dark_noise_e: Option<f64>,
    /// `mu_p.min`, photons.
    pub sensitivity_threshold_photons: Option<f64>,
    /// `mu_e.min = eta mu_p.min`, electrons.
    pub sensitivity_threshold_e: Option<f64>,
    /// `mu_e.sat`, electrons.
    pub saturation_capacity_e: Option<f64>,
    /// `sqrt(mu_e.sat)`.
    pub snr_max: Option<f64>,
    /// `20 log10 SNR_max`, dB.
    pub snr_max_db: Option<f64>,
    /// `mu_p.sat / mu_p.min`.
    pub dynamic_range: Option<f64>,
    /// `20 log10 DR`, dB.
    pub dynamic_range_db: Option<f64>,
    /// Smallest linearity deviation, %.
    pub linearity_error_min_pct: Option<f64>,
    /// Largest linearity deviation, %.
    pub linearity_error_max_pct: Option<f64>,
    /// Release 4.0's linearity error (eq. 63): the mean |deviation| over the fit range, %.
    pub linearity_error_pct: Option<f64>,
    /// Offset of the free-offset variance line over the gain fit's levels, DN^2 (the
    /// Release 4.0 fit; near 0 for a linear camera).
    pub gain_offset_dn2: f64,
    /// Dark current from the dark mean, e-/s.
    pub dark_current_mean_e_per_s: Option<f64>,
    /// Dark current from the dark variance, e-/s.
    pub dark_current_var_e_per_s: Option<f64>,
    /// Relative deviation from the linearity fit at every level, % (the fit range's
    /// levels are those of the min/max).
    pub linearity_deviation_pct: Vec<(f64, f64)>,
    /// The SNR curve.
    pub snr: Vec<SnrPoint>,
    /// The photon-transfer curve, in photon order: (mean above dark, DN; temporal
    /// variance minus dark variance, DN^2).
    pub photon_transfer: Vec<(f64, f64)>,
    /// Why a value is `None`, by its key; and notes on the set (`levels`).
    pub why: BTreeMap<String, String>,
}

/// `value` when finite, else `None` with `reason` recorded under `key`.
fn checked(why: &mut BTreeMap<String, String>, key: &str, value: f64, reason: impl FnOnce() -> String) -> Option<f64> {
    if value.is_finite() {
        Some(value)
    } else {
        why.insert(key.to_string(), reason());
        None
    }
}

/// The reference's saturation search (module documentation) over variances in photon
/// order.
fn saturation_index(var: &[f64]) -> usize {
    let (mut max, mut at) = (0.0, 0);
    for i in (0..var.len()).rev() {
        // The reference compares with index |i - 1|: at the dimmest level, the next one.
        let below = var[if i == 0 { 1.min(var.len() - 1) } else { i - 1 }];
        if var[i] >= max || below >= max {
            max = var[i];
            at = i;
        } else {
            break;
        }
    }
    at
}

/// Why a photon-transfer set cannot be characterized at all.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PtcError {
    /// Too few illuminated levels.
    #[error("{levels} illuminated two-frame levels: at least {MIN_LEVELS} are needed (the standard asks for {STANDARD_LEVELS})")]
    TooFewLevels { levels: usize },
    /// A level whose statistics are NaN or infinite (its descriptor line).
    #[error("level at line {line} has no finite mean or variance")]
    NotFinite { line: usize },
    /// Every level at the same photon count.
    #[error("every illuminated level states the same photon count: the responsivity and linearity cannot be measured")]
    OnePhotonCount,
    /// Identical frame pairs: no temporal noise.
    #[error("every pair of frames is identical: no temporal noise, so the variance does not rise with the signal and the photon transfer cannot be measured")]
    NoNoise,
    /// No signal above dark at the variance maximum.
    #[error("the mean above dark at the variance maximum is {mean_dn:.4} DN: the signal does not rise above dark")]
    NoSignal { mean_dn: f64 },
    /// Fewer than two levels for the gain fit.
    #[error("fewer than two levels up to 70% of saturation ({limit_dn:.1} DN above dark) for the gain fit")]
    TooFewGainLevels { limit_dn: f64 },
    /// A conversion gain that is not positive.
    #[error("the temporal variance does not rise with the signal (K = {gain:.4e} DN/e-): no photon transfer to characterize")]
    Gain { gain: f64 },
    /// A responsivity that is not positive.
    #[error("the signal does not rise with the photons (R = {responsivity:.4e} DN/photon): check the photon counts")]
    Responsivity { responsivity: f64 },
}

/// How the saturation level was found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Seen {
    /// The variance turned over (or, Release 4.0, pixels overflowed).
    Reached,
    /// The series ends at saturation without the turnover ([`AT_SERIES_END`]).
    AtSeriesEnd,
    /// Nothing near saturation was measured.
    NotReached,
}

/// The saturation level's index and how it was found: Release 4.0's (the last level with
/// at most OVERFLOW_MAX of its pixels at the top code, where some level has OVERFLOW_MIN
/// there), else the variance maximum where the variance turned over or where the series
/// ends at saturation ([`AT_SERIES_END`]: the standard's variance maximum, the
/// reference's search), else the brightest level (not reached). `why` notes a Release 4.0
/// fallback and a series that ends at saturation.
fn saturation(p: &[PtcPoint], release: Release, why: &mut BTreeMap<String, String>) -> (usize, Seen) {
    let variance: Vec<f64> = p.iter().map(|q| q.var_dn2).collect();
    let variance_sat = saturation_index(&variance);
    // The variance turned over when a brighter level lies well below the maximum (a
    // clipped pixel has almost none); noise alone moves the reference's search off the
    // brightest level of a set that never saturated.
    let turned_over = variance[variance_sat + 1..].iter().any(|&v| v < TURNOVER * variance[variance_sat]);
    let last = &p[p.len() - 1];
    let top = last.mean_dn + last.dark_mean_dn;
    let by_variance = if turned_over {
        (variance_sat, Seen::Reached)
    } else if top >= AT_SERIES_END * last.top_dn {
        why.insert(
            "saturation".into(),
            format!(
                "the variance has not turned over, but the brightest level is at {top:.1} of {:.0} DN ({:.1}% of the top code): saturation is taken at the variance maximum, the standard's definition; a brighter level would show whether the variance still rises",
                last.top_dn,
                100.0 * top / last.top_dn
            ),
        );
        (variance_sat, Seen::AtSeriesEnd)
    } else {
        (p.len() - 1, Seen::NotReached)
    };
    let overflow_sat = (0..p.len()).rev().find(|&i| p[i].top_fraction <= OVERFLOW_MAX);
    let overflowed = p.iter().any(|q| q.top_fraction >= OVERFLOW_MIN);
    match (release, overflow_sat) {
        (Release::R4, Some(i)) if overflowed => {
            why.remove("saturation");
            (i, Seen::Reached)
        }
        (Release::R4, _) => {
            let note = format!("no level has {:.1}% of its pixels at the top code (Release 4.0's saturation); the variance maximum is used", 100.0 * OVERFLOW_MIN);
            let note = match why.get("saturation") {
                Some(end) => format!("{note}; {end}"),
                None => note,
            };
            why.insert("saturation".into(), note);
            by_variance
        }
        (Release::R3, _) => by_variance,
    }
}

/// Linearity error over 5% to 95% of saturation (`y_sat` DN above dark): the smallest,
/// largest and mean absolute deviation from the relative fit, %, and every level's
/// deviation against its photons. `why` says what could not be measured.
#[allow(clippy::type_complexity)]
fn linearity_error(photons: &[f64], y: &[f64], y_sat: f64, why: &mut BTreeMap<String, String>) -> (Option<f64>, Option<f64>, Option<f64>, Vec<(f64, f64)>) {
    let lin_start = (0..y.len()).find(|&i| y[i] >= 0.05 * y_sat);
    let lin_end = (0..y.len()).rev().find(|&i| y[i] <= 0.95 * y_sat);
    match (lin_start, lin_end) {
        (Some(a), Some(b)) if b > a => {
            let (slope, offset) = fit_relative(&photons[a..=b], &y[a..=b]);
            let dev: Vec<f64> = photons.iter().zip(y).map(|(&x, &v)| 100.0 * (v - (slope * x + offset)) / (slope * x + offset)).collect();
            let inside = &dev[a..=b];
            let le_min = checked(why, "linearity_error_min_pct", inside.iter().copied().fold(f64::INFINITY, f64::min), || "the linearity fit failed".into());
            let le_max = checked(why, "linearity_error_max_pct", inside.iter().copied().fold(f64::NEG_INFINITY, f64::max), || "the linearity fit failed".into());
            let mean_abs = inside.iter().map(|d| d.abs()).sum::<f64>() / inside.len() as f64;
            let le_mean = checked(why, "linearity_error_pct", mean_abs, || "the linearity fit failed".into());
            (le_min, le_max, le_mean, photons.iter().copied().zip(dev).collect())
        }
        _ => {
            for key in ["linearity_error_min_pct", "linearity_error_max_pct", "linearity_error_pct"] {
                why.insert(key.into(), "fewer than two levels between 5% and 95% of saturation".into());
            }
            (None, None, None, Vec::new())
        }
    }
}

/// The dark levels, one per exposure time in increasing order: (exposure ns, mean DN,
/// variance DN^2).
fn dark_levels(p: &[PtcPoint]) -> Vec<(f64, f64, f64)> {
    let mut darks: Vec<(f64, f64, f64)> = Vec::new();
    for q in p {
        if !darks.iter().any(|d| d.0 == q.exposure) {
            darks.push((q.exposure, q.dark_mean_dn, q.dark_var_dn2));
        }
    }
    darks.sort_by(|a, b| a.0.total_cmp(&b.0));
    darks
}

/// The dark variance, DN^2: Release 4.0 measures it at the shortest exposure; 3.1 and the
/// reference take the zero-exposure intercept of a dark-current series (more than two
/// exposure times).
fn dark_variance(darks: &[(f64, f64, f64)], release: Release) -> f64 {
    if darks.len() > 2 && release == Release::R3 {
        let (t, v): (Vec<f64>, Vec<f64>) = darks.iter().map(|d| (d.0, d.2)).unzip();
        fit_line(&t, &v).0
    } else {
        darks[0].2
    }
}

/// Dark current, e-/s, from the mean and the variance of the dark levels `darks`
/// (exposure ns, mean DN, variance DN^2) against exposure time, with more than two
/// exposure times; `gain` DN/e-.
fn dark_current(darks: &[(f64, f64, f64)], gain: f64, why: &mut BTreeMap<String, String>) -> (Option<f64>, Option<f64>) {
    if darks.len() <= 2 {
        for key in ["dark_current_mean_e_per_s", "dark_current_var_e_per_s"] {
            why.insert(key.into(), format!("{} exposure time(s): a dark-current series needs more than two", darks.len()));
        }
        return (None, None);
    }
    let t: Vec<f64> = darks.iter().map(|d| d.0 * 1e-9).collect();
    let (_, mean_slope, _) = fit_line(&t, &darks.iter().map(|d| d.1).collect::<Vec<_>>());
    let (_, var_slope, _) = fit_line(&t, &darks.iter().map(|d| d.2).collect::<Vec<_>>());
    let dc_mean = checked(why, "dark_current_mean_e_per_s", mean_slope / gain, || "no finite slope".into());
    let dc_var = if var_slope >= 0.0 {
        checked(why, "dark_current_var_e_per_s", var_slope / (gain * gain), || "no finite slope".into())
    } else {
        why.insert("dark_current_var_e_per_s".into(), format!("the dark variance falls with exposure time ({var_slope:.3e} DN^2/s)"));
        None
    };
    (dc_mean, dc_var)
}

/// The temporal datasheet from photon-transfer `points` (any order). Errors, as one
/// line, when the set cannot be characterized at all: too few levels, a variance that
/// does not rise with the signal (K <= 0, or all frames equal), a signal that does not
/// rise with the photons (R <= 0).
///
/// About 130 lines: the datasheet's quantities in the standard's order, each from those
/// before it (gain, responsivity, QE, dark noise, threshold, saturation quantities);
/// saturation, linearity, the dark levels and dark current are functions of their own.
pub fn summarize_points(points: &[PtcPoint], release: Release) -> Result<PtcSummary, PtcError> {
    let mut p = points.to_vec();
    p.sort_by(|a, b| a.photons.total_cmp(&b.photons).then(a.exposure.total_cmp(&b.exposure)));
    if p.len() < MIN_LEVELS {
        return Err(PtcError::TooFewLevels { levels: p.len() });
    }
    if let Some(bad) = p.iter().find(|q| !(q.mean_dn.is_finite() && q.var_dn2.is_finite() && q.dark_var_dn2.is_finite())) {
        return Err(PtcError::NotFinite { line: bad.line });
    }
    if p.first().map(|q| q.photons) == p.last().map(|q| q.photons) {
        return Err(PtcError::OnePhotonCount);
    }
    let mut why = BTreeMap::new();
    if p.len() < STANDARD_LEVELS {
        why.insert("levels".into(), format!("{} levels; the standard asks for at least {STANDARD_LEVELS}", p.len()));
    }
    let y: Vec<f64> = p.iter().map(|q| q.mean_dn).collect();
    let var: Vec<f64> = p.iter().map(|q| q.var_dn2 - q.dark_var_dn2).collect();
    let photons: Vec<f64> = p.iter().map(|q| q.photons).collect();
    if p.iter().all(|q| q.var_dn2 == 0.0 && q.dark_var_dn2 == 0.0) {
        return Err(PtcError::NoNoise);
    }
    let (sat, seen) = saturation(&p, release, &mut why);
    let (saturation_reached, saturation_at_series_end) = (seen == Seen::Reached, seen == Seen::AtSeriesEnd);
    let saturation_known = seen != Seen::NotReached;
    let y_sat = y[sat];
    if y_sat.is_nan() || y_sat <= 0.0 {
        return Err(PtcError::NoSignal { mean_dn: y_sat });
    }
    // Fit ranges as index ranges from the first level, as the reference takes them.
    let last_at_most = |limit: f64| (0..y.len()).rev().find(|&i| y[i] <= limit);
    let Some(gain_end) = last_at_most(0.7 * y_sat).filter(|&i| i >= 1) else {
        return Err(PtcError::TooFewGainLevels { limit_dn: 0.7 * y_sat });
    };
    let range = 0..gain_end + 1;
    // Release 4.0 eq. 50 fits the variance with a free offset; 3.1 and the reference
    // through the origin.
    let (gain_offset, free_slope, gain_r2) = fit_line(&y[range.clone()], &var[range.clone()]);
    let gain = match release {
        Release::R3 => fit_origin(&y[range.clone()], &var[range.clone()]),
        Release::R4 => free_slope,
    };
    if !(gain.is_finite() && gain > 0.0) {
        return Err(PtcError::Gain { gain });
    }
    let responsivity = fit_origin(&photons[range.clone()], &y[range.clone()]);
    if !(responsivity.is_finite() && responsivity > 0.0) {
        return Err(PtcError::Responsivity { responsivity });
    }
    let (_, _, linearity_r2) = fit_line(&photons[range.clone()], &y[range.clone()]);
    let qe = responsivity / gain;

    let darks = dark_levels(&p);
    let dark_var = dark_variance(&darks, release);
    let dark_noise_measured = dark_var.max(0.0).sqrt();
    let dark_var_used = dark_var.max(DARK_VAR_FLOOR_DN2);
    let dark_noise_dn = dark_var_used.sqrt();
    let dark_noise_e = checked(&mut why, "dark_noise_e", (dark_var_used - QUANTIZATION_VAR_DN2).sqrt() / gain, || "negative".into());
    let sigma_y_e = dark_noise_dn / gain;
    let threshold = match release {
        Release::R3 => (sigma_y_e + 0.5) / qe,
        Release::R4 => (0.5 + (0.25 + sigma_y_e * sigma_y_e).sqrt()) / qe,
    };
    let sensitivity_threshold_photons = checked(&mut why, "sensitivity_threshold_photons", threshold, || "no finite threshold".into());
    let not_reached = || format!("saturation not reached: the variance still rises at the brightest level ({:.1} DN above dark)", y_sat);
    let saturation_photons = if saturation_known { Some(photons[sat]) } else { None };
    let mut need_sat = |key: &str, value: f64| -> Option<f64> {
        if saturation_known {
            checked(&mut why, key, value, || "not finite".into())
        } else {
            why.insert(key.to_string(), not_reached());
            None
        }
    };
    let saturation_capacity_e = need_sat("saturation_capacity_e", qe * photons[sat]);
    let snr_max = need_sat("snr_max", (qe * photons[sat]).sqrt());
    let snr_max_db = need_sat("snr_max_db", 20.0 * (qe * photons[sat]).sqrt().log10());
    let dynamic_range = need_sat("dynamic_range", photons[sat] / threshold);
    let dynamic_range_db = need_sat("dynamic_range_db", 20.0 * (photons[sat] / threshold).log10());
    if !saturation_known {
        why.insert("saturation_photons".into(), not_reached());
    }

    let (le_min, le_max, le_mean, deviation) = linearity_error(&photons, &y, y_sat, &mut why);
    let (dc_mean, dc_var) = dark_current(&darks, gain, &mut why);

    let sigma_d2 = dark_noise_e.map_or(f64::NAN, |s| s * s);
    let snr = p
        .iter()
        .map(|q| {
            let e = qe * q.photons;
            SnrPoint { photons: q.photons, measured: q.mean_dn / q.var_dn2.sqrt(), model: e / (sigma_d2 + QUANTIZATION_VAR_DN2 / (gain * gain) + e).sqrt() }
        })
        .collect();
    Ok(PtcSummary {
        release,
        levels: p.len(),
        saturation_index: sat,
        saturation_reached,
        saturation_at_series_end,
        saturation_dn: y_sat,
        saturation_photons,
        gain_fit_levels: range.len(),
        responsivity_dn_per_photon: responsivity,
        linearity_r2,
        gain_dn_per_e: gain,
        gain_r2,
        gain_e_per_dn: 1.0 / gain,
        quantum_efficiency: qe,
        dark_noise_dn,
        dark_noise_measured_dn: dark_noise_measured,
        dark_noise_e,
        sensitivity_threshold_photons,
        sensitivity_threshold_e: sensitivity_threshold_photons.map(|t| t * qe),
        saturation_capacity_e,
        snr_max,
        snr_max_db,
        dynamic_range,
        dynamic_range_db,
        linearity_error_min_pct: le_min,
        linearity_error_max_pct: le_max,
        linearity_error_pct: le_mean,
        gain_offset_dn2: gain_offset,
        dark_current_mean_e_per_s: dc_mean,
        dark_current_var_e_per_s: dc_var,
        linearity_deviation_pct: deviation,
        snr,
        photon_transfer: y.iter().copied().zip(var.iter().copied()).collect(),
        why,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Levels at different exposures that all state the same photon count: refused (the
    /// responsivity and linearity have no lever arm), with one line saying so.
    #[test]
    fn one_photon_count_for_every_level_is_refused() {
        let points: Vec<PtcPoint> = (1..=10)
            .map(|i| PtcPoint {
                line: i,
                dark_line: 100 + i,
                exposure: i as f64,
                photons: 5000.0,
                mean_dn: 100.0 * i as f64,
                var_dn2: 25.0 * i as f64 + 4.0,
                dark_mean_dn: 10.0,
                dark_var_dn2: 4.0,
                frame_diff_dn: 0.0,
                dark_frame_diff_dn: 0.0,
                top_fraction: 0.0,
                top_dn: 4095.0,
            })
            .collect();
        assert_eq!(summarize_points(&points, Release::R3).unwrap_err(), PtcError::OnePhotonCount);
    }

    #[test]
    fn saturation_search_tolerates_one_level_dips_and_stops_at_the_turnover() {
        assert_eq!(saturation_index(&[1.0, 2.0, 3.0, 5.0, 4.0, 1.0]), 3);
        // A dip of one level below the maximum on the way down is passed.
        assert_eq!(saturation_index(&[1.0, 2.0, 6.0, 5.5, 5.8, 3.0, 1.0]), 2);
        // Still rising at the top: the brightest level.
        assert_eq!(saturation_index(&[1.0, 2.0, 3.0]), 2);
    }
}
