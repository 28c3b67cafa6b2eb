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
        /// The `bad-pixels` finding, when significant.
        finding: Option<Finding>,
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
    let n = a.kind.len() as f64;
    let confirmed: Vec<u8> = a.kind.iter().zip(&b.kind).map(|(x, y)| x & y).collect();
    let count = confirmed.iter().filter(|&&k| k != 0).count();
    if count == 0 {
        return Ok(DefectOutcome::Tested { finding: None, defects: Vec::new() });
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
        return Ok(DefectOutcome::Tested { finding: None, defects: Vec::new() });
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
    Ok(DefectOutcome::Tested { finding, defects })
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

    /// Against hand values: P(X >= 3 | 0.01) = 1.65e-7 (5.10 sigma); P(X >= 1 | 1) =
    /// 1 - e^-1 = 0.632 (-0.34 sigma).
    #[test]
    fn chance_sigma_matches_the_poisson_tail() {
        assert!((chance_sigma(3, 0.01) - 5.10).abs() < 0.01, "{}", chance_sigma(3, 0.01));
        assert!((chance_sigma(1, 1.0) + 0.337).abs() < 0.01, "{}", chance_sigma(1, 1.0));
        assert_eq!(chance_sigma(0, 1.0), 0.0);
    }
}
