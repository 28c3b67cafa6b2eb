//! Defect pixels of an EMVA 1288 set, from its spatial series (the many-frame bright and
//! dark levels), held out by frames: the pixels are classified (`emva::spatial`:
//! hot, dead, high PRNU) on the first half of each series' frames and again on the
//! second; a pixel is a defect when both halves flag it with the same kind. A pixel that
//! is an outlier by noise in one half is not one in the other, so the count holds only
//! what reproduces.
//!
//! Significance: the confirmed count over what chance coincidence of the two halves'
//! flags would give, `(n - n_A n_B / N) / sqrt(n_A n_B / N + 1)`. Held-out RMS: of the
//! second half's pixel scores (each pixel's larger departure, dark or response, in robust
//! standard deviations), over all pixels and over those the first half did not flag.

use super::*;
use crate::emva::spatial::{defect_map, spatial_levels, SpatialSeries, DEAD, HIGH_PRNU, HOT};
use crate::emva::{EmvaSet, Release};
use crate::HostError;

/// Frames a spatial series needs for the halves: three each.
const MIN_FRAMES: usize = 6;

/// The `bad-pixels` finding of `set`'s spatial series, if it has one with defects that
/// reproduce; `None` without a spatial series of at least [`MIN_FRAMES`] frames.
pub fn diagnose_defects(set: &EmvaSet) -> Result<Option<Finding>, HostError> {
    let Some((bright, dark)) = spatial_levels(set)? else { return Ok(None) };
    let frames = bright.images.len().min(dark.images.len());
    if frames < MIN_FRAMES {
        return Ok(None);
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
        return Ok(None);
    }
    let by = |bit: u8| confirmed.iter().filter(|&&k| k & bit != 0).count();
    let (na, nb) = (a.kind.iter().filter(|&&k| k != 0).count() as f64, b.kind.iter().filter(|&&k| k != 0).count() as f64);
    let chance = na * nb / n;
    let significance = (count as f64 - chance) / (chance + 1.0).sqrt();
    let mean_sq = |keep: &dyn Fn(usize) -> bool| {
        let (s, c) = b.score.iter().enumerate().filter(|(i, _)| keep(*i)).fold((0.0, 0usize), |(s, c), (_, v)| (s + v * v, c + 1));
        s / c.max(1) as f64
    };
    let before = mean_sq(&|_| true);
    let after = mean_sq(&|i| a.kind[i] == 0);
    if significance <= SIGNIFICANCE {
        return Ok(None);
    }
    Ok(Some(Finding {
        effect: "bad-pixels".into(),
        adc: None,
        count: Some(count),
        sigma_dn: None,
        significance,
        rms_before: before.sqrt(),
        rms_after: after.sqrt(),
        gain: (before / after.max(1e-300)).sqrt(),
        detail: format!(
            "{count} defect pixels flagged alike on both halves of the spatial series ({half} + {half} frames): {} hot, {} dead, {} high PRNU (dncal's criteria, docs/emva.md); flagged on one half only: {}",
            by(HOT),
            by(DEAD),
            by(HIGH_PRNU),
            (na + nb) as usize - 2 * count
        ),
        residuals: None,
    }))
}
