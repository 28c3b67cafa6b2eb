//! Defect pixels of an EMVA 1288 set, from its spatial series (the many-frame bright and
//! dark levels), held out by frames: the pixels are classified (`emva::spatial`:
//! hot, dead, high PRNU) on the first half of each series' frames and again on the
//! second; a pixel is a defect when both halves flag it with the same kind. A pixel that
//! is an outlier by noise in one half is not one in the other, so the count holds only
//! what reproduces.
//!
//! Significance: how unlikely the confirmed count is from chance coincidence of the two
//! halves' flags (Poisson with mean `n_A n_B / N`), as a one-sided normal deviate: three
//! defects where chance gives 0.01 are 5.1 sigma (a `(n - mean) / sqrt(mean + 1)` score
//! could never reach 5 below 5 defects). Held-out RMS: of the
//! second half's pixel scores (each pixel's larger departure, dark or response, in robust
//! standard deviations), over all pixels and over those the first half did not flag.

use super::*;
use crate::analyses::emva::cells::CellPattern;
use crate::analyses::emva::spatial::{defect_map, spatial_levels, SpatialSeries, DEAD, HIGH_PRNU, HOT};
use crate::analyses::emva::{EmvaSet, Release};
use crate::HostError;

/// Frames a spatial series needs for the halves: three each.
const MIN_FRAMES: usize = 6;

/// What the defect test of a set gave.
#[derive(Debug, Clone)]
pub enum DefectOutcome {
    /// Tested: the finding if defects reproduce (else `None`), and the pixels both halves
    /// flagged alike (row-major; the photon transfer is then taken without them, as the
    /// standard leaves defect pixels out of what it reports).
    Tested {
        /// The `cfa-pattern` finding, where both halves find the same response pattern
        /// ([`pattern_finding`]: the pixels were held against their own cells), then the
        /// `bad-pixels` finding, when significant.
        findings: Vec<Finding>,
        /// The confirmed defect pixels, row-major; empty when none.
        defects: Vec<bool>,
    },
    /// Not tested, and why.
    NotTested(String),
}

/// The `bad-pixels` finding of `set`'s spatial series, if it has defects that reproduce;
/// not tested without a spatial series of at least [`MIN_FRAMES`] frames.
pub fn diagnose_defects(set: &EmvaSet) -> Result<DefectOutcome, HostError> {
    let Some((bright, dark)) = spatial_levels(set)? else {
        return Ok(DefectOutcome::NotTested("bad-pixels: no spatial series (a bright and a dark level of more than two frames)".into()));
    };
    let frames = bright.images.len().min(dark.images.len());
    if frames < MIN_FRAMES {
        return Ok(DefectOutcome::NotTested(format!("bad-pixels: the spatial series has {frames} frames; holding the defects out by halves needs {MIN_FRAMES} (dncal emva still counts them on all frames)")));
    }
    let half = frames / 2;
    let map = |range: std::ops::Range<usize>| -> Result<_, HostError> {
        let (b, d) = rayon::join(|| SpatialSeries::load_frames(set, bright, range.clone()), || SpatialSeries::load_frames(set, dark, range.clone()));
        let (b, d) = (b?, d?);
        let (cb, cd) = (b.components(Release::R3), d.components(Release::R3));
        Ok(defect_map(&b, &d, cb.stack_var_dn2, cd.stack_var_dn2))
    };
    let (a, b) = (map(0..half)?, map(half..2 * half)?);
    let pattern = pattern_finding(a.cells.as_ref(), b.cells.as_ref(), half);
    let n = a.kind.len() as f64;
    let confirmed: Vec<u8> = a.kind.iter().zip(&b.kind).map(|(x, y)| x & y).collect();
    let count = confirmed.iter().filter(|&&k| k != 0).count();
    if count == 0 {
        return Ok(DefectOutcome::Tested { findings: pattern.into_iter().collect(), defects: Vec::new() });
    }
    let by = |bit: u8| confirmed.iter().filter(|&&k| k & bit != 0).count();
    let (na, nb) = (a.kind.iter().filter(|&&k| k != 0).count() as f64, b.kind.iter().filter(|&&k| k != 0).count() as f64);
    let chance = na * nb / n;
    let significance = chance_sigma(count, chance);
    let mean_sq = |keep: &dyn Fn(usize) -> bool| {
        let (s, c) = b.score.iter().enumerate().filter(|(i, _)| keep(*i)).fold((0.0, 0usize), |(s, c), (_, v)| (s + v * v, c + 1));
        s / c.max(1) as f64
    };
    let before = mean_sq(&|_| true);
    let after = mean_sq(&|i| a.kind[i] == 0);
    if significance <= SIGNIFICANCE {
        return Ok(DefectOutcome::Tested { findings: pattern.into_iter().collect(), defects: Vec::new() });
    }
    let defects = confirmed.iter().map(|&k| k != 0).collect();
    let finding = Some(Finding {
        effect: Effect::BadPixels,
        adc: None,
        count: Some(count),
        sigma_dn: None,
        significance,
        rms_before: before.sqrt(),
        rms_after: after.sqrt(),
        gain: (before / after.max(1e-300)).sqrt(),
        all_data_rms_after: None,
        detail: format!(
            "{count} defect pixels flagged alike on both halves of the spatial series ({half} + {half} frames): {} hot, {} dead, {} high PRNU (dncal's criteria, docs/emva.md{}); flagged on one half only: {}",
            by(HOT),
            by(DEAD),
            by(HIGH_PRNU),
            a.cells.as_ref().map_or(String::new(), |c| format!("; each pixel against its own cell of {}", c.describe())),
            (na + nb) as usize - 2 * count
        ),
        residuals: None,
    });
    Ok(DefectOutcome::Tested { findings: pattern.into_iter().chain(finding).collect(), defects })
}

/// The `cfa-pattern` finding of an EMVA set, from the two halves of its spatial series'
/// frames: named where both halves' averaged responses have a pattern ([`CellPattern`]:
/// each a cell 2% and 5 standard errors off the cells' mean) of the same period whose
/// rows and columns interact ([`interaction`]). The halves share the pixels, so they
/// replicate the pattern against the temporal noise only, not against another sensor's
/// pixels. Significance: the smaller of the two halves' largest interaction in its
/// standard errors (what the naming tests); the test's RMS: the second half's cells off
/// the flat response (before) and off the first half's cells (after), in their standard
/// errors. The channels' own datasheets (gain, quantum efficiency, PRNU within each) are
/// the datasheet's (`emva::channels`).
pub fn pattern_finding(a: Option<&CellPattern>, b: Option<&CellPattern>, half: usize) -> Option<Finding> {
    let (a, b) = (a?, b?);
    if a.period != b.period || !interacts(a) || !interacts(b) {
        return None;
    }
    let rms = crate::infra::stats::rms;
    let before = rms(&b.response.iter().zip(&b.se).map(|(r, se)| (r - 1.0) / se.max(1e-300)).collect::<Vec<_>>());
    let after = rms(&b.response.iter().zip(&a.response).zip(a.se.iter().zip(&b.se)).map(|((rb, ra), (sa, sb))| (rb - ra) / sa.hypot(*sb).max(1e-300)).collect::<Vec<_>>());
    let p = a.period;
    let cells: Vec<String> = b.response.iter().enumerate().map(|(c, r)| format!("({}, {}) {r:.3}", c / p, c % p)).collect();
    Some(Finding {
        effect: Effect::CfaPattern,
        adc: None,
        count: None,
        sigma_dn: None,
        significance: interaction(a).min(interaction(b)),
        rms_before: before,
        rms_after: after,
        gain: before / after.max(1e-300),
        all_data_rms_after: None,
        detail: format!(
            "a {p} x {p} pattern of response in rows and columns together (a colour filter array), found alike on both halves of the spatial series ({half} + {half} frames): cells (row, column mod {p}) {} of their mean (second half). Each pixel's defect test is against its own cell's population, and each channel gets a datasheet of its own pixels (EMVA 1288 takes a colour camera's channels apart)",
            cells.join(", ")
        ),
        residuals: None,
    })
}

/// Whether a pattern is of rows and columns together, as a colour filter's is: some
/// cell's interaction (its response's logarithm less its row's and its column's means,
/// plus the grand mean) departs by more than 2% and [`INTERACTION_SES`] of its standard
/// errors. A pattern of columns alone is interleaved column ADCs' gains (of rows alone,
/// a two-sided readout's), not a colour filter: the channels' datasheets still give each
/// its own. What this cannot tell: a 2 x 2 readout of four taps whose gains interact
/// (`ln(g00 g11 / (g01 g10)) / 4` beyond 2%) is the same data as a colour filter, and a
/// Bayer filter whose `R B` is its greens' square has no interaction (docs/diagnose.md).
fn interacts(c: &CellPattern) -> bool {
    interaction_cells(c).into_iter().any(|(i, se)| i.abs() > 0.02_f64.max(INTERACTION_SES * se))
}

/// Standard errors an interaction must exceed ([`interacts`]).
const INTERACTION_SES: f64 = 5.0;

/// The largest interaction of `c`'s cells in its standard errors ([`interacts`]).
fn interaction(c: &CellPattern) -> f64 {
    interaction_cells(c).into_iter().map(|(i, se)| i.abs() / se.max(1e-300)).fold(0.0, f64::max)
}

/// Per cell of `c`: its interaction (as [`interacts`] defines it) and the standard error of
/// its log-response (its response's over the response).
fn interaction_cells(c: &CellPattern) -> Vec<(f64, f64)> {
    let p = c.period;
    let log: Vec<f64> = c.response.iter().map(|r| r.max(1e-300).ln()).collect();
    let mean = |f: &dyn Fn(usize) -> bool| {
        let v: Vec<f64> = (0..p * p).filter(|&k| f(k)).map(|k| log[k]).collect();
        v.iter().sum::<f64>() / v.len().max(1) as f64
    };
    let grand = mean(&|_| true);
    (0..p * p)
        .map(|k| {
            let (i, j) = (k / p, k % p);
            (log[k] - mean(&|m| m / p == i) - mean(&|m| m % p == j) + grand, c.se[k] / c.response[k].max(1e-300))
        })
        .collect()
}

/// `P(X >= count)` for `X` Poisson of mean `chance`, as a one-sided normal deviate
/// (capped at 40 sigma, where the tail underflows).
fn chance_sigma(count: usize, chance: f64) -> f64 {
    use statrs::distribution::{ContinuousCDF, DiscreteCDF, Normal, Poisson};
    if count == 0 {
        return 0.0;
    }
    let tail = Poisson::new(chance.max(1e-12)).map_or(0.0, |p| p.sf(count as u64 - 1));
    if tail <= 0.0 {
        return 40.0;
    }
    Normal::new(0.0, 1.0).map_or(40.0, |z| z.inverse_cdf(1.0 - tail).min(40.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A Bayer filter's cells interact (rows and columns together); four column ADCs'
    /// gains, read at period 4, and rows apart do not.
    #[test]
    fn a_colour_filter_interacts_and_column_gains_do_not() {
        let pattern = |period: usize, response: Vec<f64>| CellPattern { period, se: vec![0.001; response.len()], response };
        assert!(interacts(&pattern(2, vec![1.23, 0.99, 0.55, 1.23])));
        let adcs: Vec<f64> = (0..16).map(|k| [1.0, 1.03, 0.98, 0.99][k % 4]).collect();
        assert!(!interacts(&pattern(4, adcs)));
        assert!(!interacts(&pattern(2, vec![1.1, 1.1, 0.9, 0.9])));
        // (Beyond 5 standard errors only.)
        assert!(!interacts(&CellPattern { period: 2, response: vec![1.03, 0.97, 0.97, 1.03], se: vec![0.01; 4] }));
        assert!(interacts(&pattern(2, vec![1.03, 0.97, 0.97, 1.03])));
        // (The interaction of a 2 x 2 pattern is ln(g00 g11 / (g01 g10)) / 4 at every cell,
        // in standard errors of 0.001 / g: the most of them at the largest g.)
        let want = (1.23f64 * 1.23 / (0.99 * 0.55)).ln() / 4.0 / (0.001 / 1.23);
        assert!((interaction(&pattern(2, vec![1.23, 0.99, 0.55, 1.23])) / want - 1.0).abs() < 1e-9);
    }

    /// Against hand values: P(X >= 3 | 0.01) = 1.65e-7 (5.10 sigma); P(X >= 1 | 1) =
    /// 1 - e^-1 = 0.632 (-0.34 sigma).
    #[test]
    fn chance_sigma_matches_the_poisson_tail() {
        assert!((chance_sigma(3, 0.01) - 5.10).abs() < 0.01, "{}", chance_sigma(3, 0.01));
        assert!((chance_sigma(1, 1.0) + 0.337).abs() < 0.01, "{}", chance_sigma(1, 1.0));
        assert_eq!(chance_sigma(0, 1.0), 0.0);
    }
}
