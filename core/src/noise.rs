//! The on-device noise check: is there enough random noise to average below one DN?
//!
//! Averaging a quantized signal converges to the truth only if the noise dithers the
//! quantizer. For Gaussian noise of `sigma` DN the bias of the average as a function of
//! the fractional signal is a Fourier series whose leading term bounds it:
//! `|delta| ~ exp(-2 pi^2 sigma^2) / pi` DN (de Wijn 2018, section 2 and Fig. 1; the host
//! evaluates the exact sum). The K-Coronagraph needs 0.2 DN.
//!
//! ## Estimator
//! From two frames of the same dark or flat region, the difference `d = a - b` of each
//! pixel removes the fixed pattern, and `var(d) = 2 sigma_q^2` where `sigma_q` is the
//! temporal noise of the *quantized* readout (the EMVA 1288 way). Quantization adds
//! `1/12` DN^2 for `sigma >~ 0.5` DN (Sheppard's correction); the analog noise used for the
//! bias is `sigma^2 = max(sigma_q^2 - 1/12, 0)`, which can only under-estimate sigma and
//! so over-estimate the bias: the warning errs on the safe side. Pairs in which either
//! code is clipped (0, the top code, or above it) are skipped: clipping is not noise,
//! and one saturated pixel would otherwise dominate the variance. Sums are exact
//! integers; only the final square root and exponential are floating point (micromath on
//! the device, checked against the host's f64 in the tests; the square root is refined by
//! three Newton steps because micromath's is good to only a few percent).

use micromath::F32Ext;

use crate::error::Quantity;
use crate::CoreError;

/// The K-Coronagraph's accuracy requirement on an average, DN: a dynamic range of 10^4
/// on 12 bits with a factor 2 margin (de Wijn 2018, section 2).
pub const KCOR_ACCURACY_DN: f32 = 0.2;

/// Fewest pixel pairs for an estimate.
pub const MIN_SAMPLES: u32 = 64;

/// Accumulates pixel differences between two frames, exactly.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct NoiseEstimator {
    top_code: u16,
    skipped: u32,
    samples: u32,
    sum: i64,
    sum_sq: u64,
}

/// The outcome of a noise check.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct NoiseReport {
    /// Temporal noise of the quantized readout, DN.
    pub sigma_quantized_dn: f32,
    /// Analog noise after removing the 1/12 DN^2 of quantization, DN.
    pub sigma_dn: f32,
    /// Leading-term worst-case bias of an average, `exp(-2 pi^2 sigma^2)/pi`, DN.
    pub worst_bias_dn: f32,
    /// The accuracy the check was made against, DN.
    pub accuracy_dn: f32,
    /// Pixel pairs used.
    pub samples: u32,
    /// Pixel pairs skipped because a code was clipped.
    pub skipped: u32,
}

impl NoiseReport {
    /// Whether averaging can reach the configured accuracy.
    pub fn ok(&self) -> bool {
        self.worst_bias_dn <= self.accuracy_dn
    }
}

impl NoiseEstimator {
    /// An empty estimator for an ADC whose top (saturation) code is `top_code`.
    pub const fn new(top_code: u16) -> Self {
        NoiseEstimator { top_code, skipped: 0, samples: 0, sum: 0, sum_sq: 0 }
    }

    /// Adds the same line from two frames. Codes are raw; the pair must match in length.
    pub fn add_pair(&mut self, a: &[u16], b: &[u16]) -> Result<(), CoreError> {
        if a.len() != b.len() {
            return Err(CoreError::Length { what: Quantity::NoisePair, expected: a.len() as u32, got: b.len() as u32 });
        }
        let clipped = |c: u16| c == 0 || c >= self.top_code;
        for (&x, &y) in a.iter().zip(b) {
            if clipped(x) || clipped(y) {
                self.skipped = self.skipped.saturating_add(1);
                continue;
            }
            let d = x as i64 - y as i64;
            self.sum = self.sum.saturating_add(d);
            self.sum_sq = self.sum_sq.saturating_add((d * d) as u64);
            self.samples = self.samples.saturating_add(1);
        }
        Ok(())
    }

    /// The estimate and the bias check against `accuracy_dn`; logs a defmt warning when
    /// the bias exceeds it.
    pub fn check(&self, accuracy_dn: f32) -> Result<NoiseReport, CoreError> {
        if self.samples < MIN_SAMPLES {
            return Err(CoreError::NoiseSamples { samples: self.samples });
        }
        // var(d) = (n sum_sq - sum^2) / n^2, exact in i128 until the division.
        let n = self.samples as i128;
        let num = n * self.sum_sq as i128 - (self.sum as i128) * (self.sum as i128);
        let var_d = num as f32 / (n * n) as f32;
        let var_q = var_d / 2.0;
        let sigma_quantized_dn = sqrt_refined(var_q);
        let var = (var_q - 1.0 / 12.0).max(0.0);
        let sigma_dn = sqrt_refined(var);
        let worst_bias_dn = leading_bias_dn(sigma_dn);
        let report = NoiseReport { sigma_quantized_dn, sigma_dn, worst_bias_dn, accuracy_dn, samples: self.samples, skipped: self.skipped };
        #[cfg(feature = "defmt")]
        if !report.ok() {
            defmt::warn!(
                "noise {=f32} DN too low: averages may be biased by up to {=f32} DN (accuracy {=f32} DN)",
                sigma_dn,
                worst_bias_dn,
                accuracy_dn
            );
        }
        Ok(report)
    }
}

/// `exp(-2 pi^2 sigma^2) / pi`, the leading Fourier term of the worst-case bias. It is
/// accurate to 1e-3 DN for `sigma >= 0.25` DN; towards `sigma = 0` the true worst case
/// rises to 0.5 DN while this stays at `1/pi = 0.32` DN, still far above any accuracy
/// worth asking for, so the check warns all the same.
pub fn leading_bias_dn(sigma_dn: f32) -> f32 {
    let pi = core::f32::consts::PI;
    F32Ext::exp(-2.0 * pi * pi * sigma_dn * sigma_dn) / pi
}

/// micromath's square root refined by three Newton steps (relative error e -> e^2/2) (`x <- (x + v/x) / 2`).
pub fn sqrt_refined(v: f32) -> f32 {
    if v <= 0.0 {
        return 0.0;
    }
    // Called through the trait: with std linked (host tests) `v.sqrt()` would be std's.
    let mut x = F32Ext::sqrt(v);
    for _ in 0..3 {
        x = 0.5 * (x + v / x);
    }
    x
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;

    #[test]
    fn refined_sqrt_and_exp_match_f64() {
        for i in 1..2000 {
            let v = i as f32 * 0.37;
            let exact = (v as f64).sqrt();
            assert!(((sqrt_refined(v) as f64 - exact) / exact).abs() < 1e-6, "sqrt {v}");
        }
        for i in 0..200 {
            let s = i as f32 * 0.005;
            let exact = (-2.0 * core::f64::consts::PI.powi(2) * (s as f64).powi(2)).exp() / core::f64::consts::PI;
            let got = leading_bias_dn(s) as f64;
            // The bias is a warning threshold: 1% relative (or 1e-7 DN absolute) is plenty.
            assert!((got - exact).abs() < 0.01 * exact + 1e-7, "sigma {s}: {got} vs {exact}");
        }
    }

    #[test]
    fn estimates_a_planted_difference_variance() {
        // Pairs whose differences are +-2 exactly: var(d) = 4, sigma_q^2 = 2.
        let a: std::vec::Vec<u16> = (0..128).map(|i| 100 + if i % 2 == 0 { 2 } else { 0 }).collect();
        let b: std::vec::Vec<u16> = (0..128).map(|i| 100 + if i % 2 == 0 { 0 } else { 2 }).collect();
        let mut e = NoiseEstimator::new(4095);
        e.add_pair(&a, &b).unwrap();
        // Clipped pairs (0, top, above top) are skipped, not counted as noise.
        e.add_pair(&[0, 4095, 5000, 100], &[100, 100, 100, 4095]).unwrap();
        let r = e.check(0.2).unwrap();
        assert!((r.sigma_quantized_dn - 2f32.sqrt()).abs() < 1e-5);
        assert!((r.sigma_dn as f64 - (2.0f64 - 1.0 / 12.0).sqrt()).abs() < 1e-5);
        assert!(r.ok());
        assert_eq!((r.samples, r.skipped), (128, 4));
        let mut flat = NoiseEstimator::new(4095);
        flat.add_pair(&[7; 100], &[7; 100]).unwrap();
        let r = flat.check(0.2).unwrap();
        assert_eq!((r.sigma_dn, r.worst_bias_dn), (0.0, 1.0 / core::f32::consts::PI));
        assert!(!r.ok());
        assert_eq!(NoiseEstimator::new(4095).check(0.2), Err(CoreError::NoiseSamples { samples: 0 }));
    }

    /// Frames offset from each other (a mean difference) leave the variance of the
    /// differences as it was: `var(d) = E[d^2] - E[d]^2` (the planted test above has a
    /// zero mean). Differences 3 and 5 alternate: mean 4, var(d) = 1, sigma_q^2 = 1/2.
    /// And exactly MIN_SAMPLES samples are enough.
    #[test]
    fn a_mean_difference_is_not_noise() {
        let n = MIN_SAMPLES as usize;
        let a: std::vec::Vec<u16> = (0..n).map(|i| 200 + if i % 2 == 0 { 3 } else { 5 }).collect();
        let b = std::vec![200u16; n];
        let mut e = NoiseEstimator::new(4095);
        e.add_pair(&a, &b).unwrap();
        let r = e.check(0.2).unwrap();
        assert_eq!(r.samples, MIN_SAMPLES);
        assert!((r.sigma_quantized_dn - 0.5f32.sqrt()).abs() < 1e-6, "{}", r.sigma_quantized_dn);
        assert!((r.sigma_dn as f64 - (0.5f64 - 1.0 / 12.0).sqrt()).abs() < 1e-6, "{}", r.sigma_dn);
        let mut short = NoiseEstimator::new(4095);
        short.add_pair(&a[..n - 1], &b[..n - 1]).unwrap();
        assert_eq!(short.check(0.2), Err(CoreError::NoiseSamples { samples: MIN_SAMPLES - 1 }));
    }
}
