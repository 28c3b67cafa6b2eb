//! The statistics by which one ADC's code-width pattern is compared with another's: a
//! real ADC's (a K-Cor table's DN error, [`crate::analyses::real_adcs`]) with a model's
//! (the built-in camera's nested pipeline, [`crate::model::camera::nested`]).
//!
//! They are taken on the relative width errors `r_k = w_k / mean(w) - 1` of a run of codes
//! (the K-Cor tables' calibrated codes 151-4094), mean removed:
//!
//! - **rms per code**: `sd(r)`, % (the size of the DN error);
//! - **narrow-code spacing**: codes per code narrower than `mean - 3 sd` (how often the
//!   deep narrow codes of a snap-back come: every 40-130 codes on the real ADCs);
//! - **period**: the smallest power of two `m` whose means by `k mod m` explain half of
//!   `var(r)` (the real ADCs: 128, some 64 or 256);
//! - **sawtooth**: the cumulative offsets `o_k = sum_{j<=k} r_j` after a straight line,
//!   averaged by `k mod 128`, peak to peak, DN (the size of the periodic ramp and its
//!   snap-back);
//! - **offsets peak to peak**: `max o - min o` after the line, DN (what Fig. 3 of the
//!   paper plots);
//! - **share at 256**: the share of `var(r)` the means by `k mod 256` explain (how
//!   periodic the pattern is).
//!
//! The independence of a camera's ADCs is the correlation of their `r`
//! ([`crate::analyses::real_adcs::correlation`]).

use serde::{Deserialize, Serialize};

use crate::infra::stats::{mean, variance};

/// The sawtooth's fold, codes: the real ADCs' usual period.
pub const SAWTOOTH_FOLD: usize = 128;
/// The modulus of [`WidthStatistics::share_256`].
pub const SHARE_MODULUS: usize = 256;
/// Narrow codes are below the mean by this many standard deviations.
pub const NARROW_SDS: f64 = 3.0;

/// One ADC's width statistics (module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct WidthStatistics {
    /// RMS relative width error, %.
    pub rms_pct: f64,
    /// Codes per narrow code (the number of codes when there is none: at most one).
    pub narrow_spacing_codes: f64,
    /// The smallest power-of-two period (2-512) explaining half the variance, codes.
    pub period_codes: Option<usize>,
    /// Peak to peak of the offsets' mean by `k mod 128`, DN.
    pub sawtooth_dn: f64,
    /// Peak to peak of the offsets after a straight line, DN.
    pub offsets_p2p_dn: f64,
    /// Share of the variance explained by the means by `k mod 256`.
    pub share_256: f64,
}

/// The share of `var(r)` that the means of `r` by `k mod m` explain, `r[i]` the error of
/// code `first_code + i`; NaN when `r` has no variance.
pub fn residue_explained(r: &[f64], first_code: usize, m: usize) -> f64 {
    let mut sum = vec![0.0; m];
    let mut count = vec![0usize; m];
    for (i, &v) in r.iter().enumerate() {
        sum[(first_code + i) % m] += v;
        count[(first_code + i) % m] += 1;
    }
    let means: Vec<f64> = sum.iter().zip(&count).map(|(s, &c)| if c == 0 { 0.0 } else { s / c as f64 }).collect();
    let fitted: Vec<f64> = (0..r.len()).map(|i| means[(first_code + i) % m]).collect();
    variance(&fitted) / variance(r)
}

impl WidthStatistics {
    /// The statistics of the relative width errors `r` (`r[i]` of code `first_code + i`).
    /// `r` needs at least [`SHARE_MODULUS`] codes for the period and share to mean
    /// anything; the caller's range decides.
    pub fn of(r: &[f64], first_code: usize) -> WidthStatistics {
        let m = mean(r);
        let r: Vec<f64> = r.iter().map(|v| v - m).collect();
        let sd = variance(&r).sqrt();
        let narrow = r.iter().filter(|&&v| v < -NARROW_SDS * sd).count();
        let mut o: Vec<f64> = r.iter().scan(0.0, |acc, v| {
            *acc += v;
            Some(*acc)
        }).collect();
        let x: Vec<f64> = (0..o.len()).map(|i| i as f64).collect();
        let (a, b, _) = crate::infra::stats::fit_line(&x, &o);
        for (i, v) in o.iter_mut().enumerate() {
            *v -= a + b * i as f64;
        }
        let p2p = |v: &[f64]| v.iter().copied().fold(f64::NEG_INFINITY, f64::max) - v.iter().copied().fold(f64::INFINITY, f64::min);
        let mut fold_sum = vec![0.0; SAWTOOTH_FOLD];
        let mut fold_count = vec![0usize; SAWTOOTH_FOLD];
        for (i, v) in o.iter().enumerate() {
            fold_sum[(first_code + i) % SAWTOOTH_FOLD] += v;
            fold_count[(first_code + i) % SAWTOOTH_FOLD] += 1;
        }
        let profile: Vec<f64> = fold_sum.iter().zip(&fold_count).filter(|(_, &c)| c > 0).map(|(s, &c)| s / c as f64).collect();
        WidthStatistics {
            rms_pct: 100.0 * sd,
            narrow_spacing_codes: r.len() as f64 / narrow.max(1) as f64,
            period_codes: (1..=9).map(|j| 1usize << j).find(|&m| residue_explained(&r, first_code, m) >= 0.5),
            sawtooth_dn: p2p(&profile),
            offsets_p2p_dn: p2p(&o),
            share_256: residue_explained(&r, first_code, SHARE_MODULUS),
        }
    }

    /// The relative width errors of `widths` (a model's, codes and all) over `codes`:
    /// `w_k / mean - 1`, the form [`WidthStatistics::of`] takes.
    pub fn of_widths(widths: &[f64], codes: std::ops::RangeInclusive<usize>) -> WidthStatistics {
        let w = &widths[codes.clone()];
        let m = mean(w);
        let r: Vec<f64> = w.iter().map(|v| v / m - 1.0).collect();
        WidthStatistics::of(&r, *codes.start())
    }

    /// The median of each statistic over `all` (the period: the upper median of those
    /// found, a power of two as each is).
    pub fn median(all: &[WidthStatistics]) -> WidthStatistics {
        use crate::infra::stats::median;
        let periods: Vec<f64> = all.iter().filter_map(|s| s.period_codes).map(|p| p as f64).collect();
        let upper = crate::infra::stats::upper_median(periods.iter().copied());
        WidthStatistics {
            rms_pct: median(all.iter().map(|s| s.rms_pct)),
            narrow_spacing_codes: median(all.iter().map(|s| s.narrow_spacing_codes)),
            period_codes: (!periods.is_empty()).then_some(upper as usize),
            sawtooth_dn: median(all.iter().map(|s| s.sawtooth_dn)),
            offsets_p2p_dn: median(all.iter().map(|s| s.offsets_p2p_dn)),
            share_256: median(all.iter().map(|s| s.share_256)),
        }
    }

    /// The statistics as (name, value) pairs, for comparisons and reports.
    pub fn named(&self) -> [(&'static str, f64); 6] {
        [
            ("rms per code, %", self.rms_pct),
            ("narrow-code spacing, codes", self.narrow_spacing_codes),
            ("period, codes", self.period_codes.map_or(f64::NAN, |p| p as f64)),
            ("sawtooth (mod 128), DN", self.sawtooth_dn),
            ("offsets peak to peak, DN", self.offsets_p2p_dn),
            ("share of variance at mod 256", self.share_256),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A planted pattern with closed-form statistics: period 64, within each period one
    /// code `d` narrow and 63 codes `d / 63` wide (offsets that ramp up by `d` and snap
    /// back), over 16384 codes from code 64.
    #[test]
    fn a_planted_sawtooth_has_its_closed_form_statistics() {
        let (d, period) = (0.32, 64usize);
        let r: Vec<f64> = (0..16384).map(|i| if i % period == period - 1 { -d } else { d / (period - 1) as f64 }).collect();
        let s = WidthStatistics::of(&r, 64);
        // sd of one value -d and 63 values d/63 (mean 0): sqrt((d^2 + 63 (d/63)^2) / 64).
        let sd = ((d * d + 63.0 * (d / 63.0).powi(2)) / 64.0).sqrt();
        assert!((s.rms_pct - 100.0 * sd).abs() < 1e-9, "{s:?}");
        // One narrow code per period (-d < -3 sd = -0.38 d; the ramp codes are above).
        assert_eq!(s.narrow_spacing_codes, 64.0);
        // Means by k mod 32 put the narrow code with one ramp code: they explain 31/63 of
        // the variance, under half; by k mod 64, all of it.
        assert!((residue_explained(&r, 64, 32) - 31.0 / 63.0).abs() < 1e-12);
        assert_eq!(s.period_codes, Some(64));
        assert!((s.share_256 - 1.0).abs() < 1e-12);
        // The offsets run 0, d/63, ..., d and back to 0: peak to peak d, in the fold by 128
        // too. The line through 256 whole periods tilts them by a few 1e-3 d.
        assert!((s.sawtooth_dn - d).abs() < 0.005 * d, "{s:?}");
        assert!((s.offsets_p2p_dn - d).abs() < 0.01 * d, "{s:?}");
    }

    /// White width errors have no period, no sawtooth beyond a random walk's, and about
    /// the share of variance chance gives at mod 256 ((m - 1) / (n - 1)).
    #[test]
    fn white_errors_have_no_period() {
        use rand::{rngs::StdRng, SeedableRng};
        use rand_distr::{Distribution, Normal};
        let mut rng = StdRng::seed_from_u64(5);
        let normal = Normal::new(0.0, 0.03).unwrap();
        let r: Vec<f64> = (0..3944).map(|_| normal.sample(&mut rng)).collect();
        let s = WidthStatistics::of(&r, 151);
        assert_eq!(s.period_codes, None);
        assert!((s.rms_pct - 3.0).abs() < 0.15, "{s:?}");
        let chance = 255.0 / 3943.0;
        assert!((s.share_256 - chance).abs() < 0.3 * chance, "{s:?}");
        // Gaussian: 0.135% below -3 sd, one in 740 codes; a few in 3944.
        assert!(s.narrow_spacing_codes > 300.0, "{s:?}");
        // No narrow code at all: one in the whole run at most.
        let flat: Vec<f64> = (0..512).map(|i| if i % 2 == 0 { 0.01 } else { -0.01 }).collect();
        assert_eq!(WidthStatistics::of(&flat, 0).narrow_spacing_codes, 512.0);
        // Periods 128, 128, 256, 256: the median is one of them.
        let with = |p| WidthStatistics { period_codes: Some(p), ..s };
        assert_eq!(WidthStatistics::median(&[with(128), with(128), with(256), with(256)]).period_codes, Some(256));
    }
}
