//! Quantization bias of an averaged readout (de Wijn 2018, section 2).
//!
//! An ideal ADC returns code k for analog values in `[k - 1/2, k + 1/2)` (the first and
//! last codes take everything below and above). Averaging many readouts of a signal of
//! true mean `lambda` DN with noise of CDF `F` converges to `sum_k k p_k`, not to `lambda`:
//!
//! ```text
//! delta = lambda - sum_{k=1}^{N-1} k p_k                                    (eq. 1)
//! p_0 = F(1/2),  p_k = F(k + 1/2) - F(k - 1/2),  p_{N-1} = 1 - F(N - 3/2)     (eq. 2)
//! ```
//!
//! For Gaussian noise of rms `sigma` DN and `lambda` away from both ends this reduces to
//! (eq. 4, with `lambda' = lambda mod 1` and a symmetric range of `2M` terms):
//!
//! ```text
//! delta = lambda' + 1/2 sum_{j=-M}^{M-1} erf((j + 1/2 - lambda') / (sqrt(2) sigma))
//! ```
//!
//! Four evaluations, for four purposes: [`bias_exact`] is eq. 1-2 for any CDF and any
//! `lambda`, ends included; [`bias_erf`] is eq. 4; [`bias_fourier`] is the Fourier series
//! `delta = -sum_m (-1)^m sin(2 pi m lambda') exp(-2 pi^2 m^2 sigma^2) / (pi m)`, whose
//! first term gives the worst case `exp(-2 pi^2 sigma^2) / pi` the device's noise check
//! uses, and which stays accurate where eq. 4 reaches its rounding floor (~1e-11 DN at
//! sigma = 4 DN); [`bias_monte_carlo`] samples, rounds and averages, as a camera does.
//! Maps and searches use [`bias_gaussian`]: the series from sigma = 0.3 DN, eq. 4 below.

pub mod run;

use rand::Rng;
use rand_distr::{Distribution, Normal};
use serde::Serialize;
use statrs::function::erf::erf;

use crate::model::camera::exact::phi;

/// `delta` of eq. 1-2: the true mean minus the mean code of an ideal `codes`-code ADC
/// whose input has CDF `cdf`, DN.
pub fn bias_exact(lambda: f64, codes: usize, cdf: impl Fn(f64) -> f64) -> f64 {
    let top = codes.saturating_sub(1);
    // sum_k k p_k = sum_{k=1}^{N-1} (1 - F(k - 1/2)) = sum_{k=1}^{N-1} P(code >= k): the
    // telescoped form of eq. 2, with no cancellation between neighbouring CDF values.
    let mean: f64 = (1..=top).map(|k| 1.0 - cdf(k as f64 - 0.5)).sum();
    lambda - mean
}

/// [`bias_exact`] for Gaussian noise of rms `sigma` DN (`sigma = 0`: no noise).
pub fn bias_exact_gaussian(lambda: f64, sigma: f64, codes: usize) -> f64 {
    if sigma <= 0.0 {
        return bias_exact(lambda, codes, |x| if x >= lambda { 1.0 } else { 0.0 });
    }
    bias_exact(lambda, codes, |x| phi((x - lambda) / sigma))
}

/// `delta` of eq. 4 at `lambda' = lambda_frac` (in [0, 1)), Gaussian noise of rms `sigma`
/// DN. The range `M = ceil(10 sigma) + 2` leaves out terms below `erfc(7) = 4e-23`.
pub fn bias_erf(lambda_frac: f64, sigma: f64) -> f64 {
    if sigma <= 0.0 {
        // The noiseless limit: the readout is round(lambda), a half-way value going to the
        // lower code as eq. 2 assigns it (F(k + 1/2) includes the boundary).
        return if lambda_frac > 0.5 { lambda_frac - 1.0 } else { lambda_frac };
    }
    let m = (10.0 * sigma).ceil() as i64 + 2;
    let s = std::f64::consts::SQRT_2 * sigma;
    let sum: f64 = (-m..m).map(|j| erf((j as f64 + 0.5 - lambda_frac) / s)).sum();
    lambda_frac + 0.5 * sum
}

/// `delta` from its Fourier series (Poisson summation of eq. 1 for Gaussian noise):
/// `-sum_{m>=1} (-1)^m sin(2 pi m lambda') exp(-2 pi^2 m^2 sigma^2) / (pi m)`. Summed until
/// the factor `exp(-2 pi^2 m^2 sigma^2)` is below 1e-18 of the first: few terms for
/// `sigma >= 0.3` (where it is accurate to the last bit while the erf sum of eq. 4 stops
/// at its rounding level, ~1e-11 DN), many for small `sigma`.
pub fn bias_fourier(lambda_frac: f64, sigma: f64) -> f64 {
    use std::f64::consts::PI;
    let first = (-2.0 * PI * PI * sigma * sigma).exp();
    let mut sum = 0.0;
    for m in 1..100_000u32 {
        let mf = m as f64;
        let damp = (-2.0 * PI * PI * mf * mf * sigma * sigma).exp();
        // Past 1e-18 of the first term, or past f64's range (sigma above ~6 DN, where
        // every term underflows to 0 and the series is 0).
        if damp == 0.0 || (m > 1 && damp < 1e-18 * first) {
            break;
        }
        let sign = if m % 2 == 0 { 1.0 } else { -1.0 };
        sum += sign * (2.0 * PI * mf * lambda_frac).sin() * damp / (PI * mf);
    }
    -sum
}

/// `delta` for Gaussian noise by the most accurate of the two closed forms: the Fourier
/// series from `sigma = 0.3` DN up, eq. 4 below.
pub fn bias_gaussian(lambda_frac: f64, sigma: f64) -> f64 {
    if sigma >= 0.3 { bias_fourier(lambda_frac, sigma) } else { bias_erf(lambda_frac, sigma) }
}

/// A Monte Carlo estimate of `delta`: `samples` Gaussian readouts of mean `lambda` and rms
/// `sigma`, rounded to codes of a `codes`-code ADC and averaged. Returns the estimate and
/// its standard error, DN.
pub fn bias_monte_carlo(lambda: f64, sigma: f64, codes: usize, samples: u64, rng: &mut impl Rng) -> (f64, f64) {
    let top = codes.saturating_sub(1) as f64;
    let normal = Normal::new(lambda, sigma.max(0.0)).unwrap_or_else(|_| Normal::new(lambda, 0.0).expect("zero sigma is valid"));
    let (mut sum, mut sum2) = (0.0, 0.0);
    for _ in 0..samples {
        // Round half down, as eq. 2 assigns a boundary value (matters only without noise).
        let code = (normal.sample(rng) - 0.5).ceil().clamp(0.0, top);
        let d = code - lambda;
        sum += d;
        sum2 += d * d;
    }
    let n = samples.max(1) as f64;
    let mean = sum / n;
    let var = (sum2 / n - mean * mean).max(0.0);
    (-mean, (var / (n - 1.0).max(1.0)).sqrt())
}

/// The worst case over `lambda'` at one noise level.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct WorstBias {
    /// Noise rms, DN.
    pub sigma: f64,
    /// max over lambda' in [0, 1) of |delta|, DN.
    pub max_abs_bias_dn: f64,
    /// The lambda' where it occurs.
    pub at_lambda_frac: f64,
}

/// `max |delta|` over `lambda'` in [0, 1): a 2000-point scan, then golden-section
/// refinement around the best point (|delta| is smooth in `lambda'` for `sigma > 0`).
pub fn worst_bias(sigma: f64) -> WorstBias {
    let f = |x: f64| bias_gaussian(x, sigma).abs();
    let n = 2000;
    let (mut best_x, mut best) = (0.0, f(0.0));
    for i in 1..n {
        let x = i as f64 / n as f64;
        let v = f(x);
        if v > best {
            best = v;
            best_x = x;
        }
    }
    if sigma > 0.0 {
        let g = (5f64.sqrt() - 1.0) / 2.0;
        let (mut a, mut b) = ((best_x - 1.0 / n as f64).max(0.0), (best_x + 1.0 / n as f64).min(1.0 - 1e-15));
        for _ in 0..60 {
            let c = b - g * (b - a);
            let d = a + g * (b - a);
            if f(c) > f(d) { b = d } else { a = c }
        }
        let x = 0.5 * (a + b);
        if f(x) > best {
            best = f(x);
            best_x = x;
        }
    }
    WorstBias { sigma, max_abs_bias_dn: best, at_lambda_frac: best_x }
}

/// The mean square of `delta` over `lambda'` uniform in [0, 1), DN^2: from the Fourier
/// series, `sum_{m>=1} exp(-4 pi^2 m^2 sigma^2) / (2 pi^2 m^2)`; 1/12 without noise (a
/// mean of identical codes is off by up to half a code), 2.6e-6 at 0.5 DN. Where the
/// noise is too low to average below a code, this is the error of a mean that its
/// frames' spread does not show: the variance floor of a mean across levels.
pub fn mean_square_bias(sigma: f64) -> f64 {
    use std::f64::consts::PI;
    let mut sum = 0.0;
    for m in 1..100_000u32 {
        let mf = f64::from(m);
        let term = (-4.0 * PI * PI * mf * mf * sigma * sigma).exp() / (2.0 * PI * PI * mf * mf);
        sum += term;
        if term < 1e-18 * sum.max(1e-300) {
            break;
        }
    }
    sum
}

/// The analog noise rms (DN) behind quantized frames whose variance, averaged over
/// readouts spread evenly within a code (pixels at one level), is `v` DN^2: the inverse of
/// `V(sigma) = sigma^2 + 1/12 - mean_square_bias(sigma)` (the readout error is the noise
/// plus a uniform rounding, whose total variance splits into the frames' spread and the
/// square of the means' bias), by bisection. 0 for `v <= 0`.
pub fn sigma_from_quantized_variance(v: f64) -> f64 {
    if v.is_nan() || v <= 0.0 {
        return 0.0;
    }
    let f = |s: f64| s * s + 1.0 / 12.0 - mean_square_bias(s);
    let (mut lo, mut hi) = (0.0, v.sqrt() + 1.0);
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if f(mid) < v { lo = mid } else { hi = mid }
    }
    0.5 * (lo + hi)
}

/// The smallest noise rms (DN) whose worst-case bias is at most `bias` DN: a scan upward
/// in steps of 0.001 DN from 0 to the first noise level that meets it, then bisection
/// between it and the step below. `None` for `bias <= 0` (no finite noise reaches zero)
/// or above 0.5 DN (met without noise, `Some(0)`).
pub fn sigma_for_bias(bias: f64) -> Option<f64> {
    if bias.is_nan() || bias <= 0.0 {
        return None;
    }
    if worst_bias(0.0).max_abs_bias_dn <= bias {
        return Some(0.0);
    }
    let step = 1e-3;
    let mut lo = 0.0;
    for i in 1..=10_000 {
        let s = i as f64 * step;
        if worst_bias(s).max_abs_bias_dn <= bias {
            let mut hi = s;
            for _ in 0..40 {
                let mid = 0.5 * (lo + hi);
                if worst_bias(mid).max_abs_bias_dn <= bias { hi = mid } else { lo = mid }
            }
            return Some(hi);
        }
        lo = s;
    }
    None
}

/// |delta| on a grid: `rows[i][j]` at `sigma = sigma_max i / (n_sigma - 1)` and
/// `lambda' = j / (n_lambda - 1)`.
pub fn bias_map(n_lambda: usize, n_sigma: usize, sigma_max: f64) -> Vec<Vec<f64>> {
    use rayon::prelude::*;
    (0..n_sigma)
        .into_par_iter()
        .map(|i| {
            let sigma = sigma_max * i as f64 / (n_sigma - 1).max(1) as f64;
            (0..n_lambda).map(|j| bias_gaussian(j as f64 / (n_lambda - 1).max(1) as f64, sigma).abs()).collect()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn three_forms_and_the_fourier_series_agree() {
        for sigma in [0.1, 0.2, 0.3, 0.4, 0.7, 1.5] {
            for lf in [0.0, 0.05, 0.25, 0.4, 0.5, 0.6, 0.83, 0.99] {
                let e = bias_erf(lf, sigma);
                let x = bias_exact_gaussian(2048.0 + lf, sigma, 4096);
                let f = bias_fourier(lf, sigma);
                assert!((e - x).abs() < 1e-12, "sigma {sigma} lf {lf}: erf {e} exact {x}");
                // statrs' erf is good to ~1e-12 a term, and eq. 4 adds ~100 of them.
                assert!((e - f).abs() < 1e-10, "sigma {sigma} lf {lf}: erf {e} fourier {f}");
                // bias_gaussian is the series from 0.3 DN up and eq. 4 below: it must agree
                // with the exact sum everywhere.
                assert!((bias_gaussian(lf, sigma) - x).abs() < 1e-10, "sigma {sigma} lf {lf}");
            }
        }
    }

    #[test]
    fn noiseless_readout_is_rounding() {
        for lf in [0.0f64, 0.1, 0.3, 0.49, 0.51, 0.9] {
            let want = lf - (lf + 0.5).floor();
            assert!((bias_exact_gaussian(100.0 + lf, 0.0, 4096) - want).abs() < 1e-12);
            assert!((bias_erf(lf, 0.0) - want).abs() < 1e-12);
        }
        // Exactly half-way: eq. 2 gives the lower code, and so do the other forms.
        let mut rng = rand::rngs::StdRng::seed_from_u64(1);
        assert_eq!(bias_exact_gaussian(100.5, 0.0, 4096), 0.5);
        assert_eq!(bias_erf(0.5, 0.0), 0.5);
        assert_eq!(bias_monte_carlo(100.5, 0.0, 4096, 10, &mut rng).0, 0.5);
    }

    #[test]
    fn the_exact_sum_sees_the_ends() {
        // At lambda = 0 half of the noise is clipped up to code 0: the mean code is
        // sigma / sqrt(2 pi) above 0 (the half-normal mean), to rounding.
        let sigma = 3.0;
        let d = bias_exact_gaussian(0.0, sigma, 4096);
        let half_normal = sigma / (2.0 * std::f64::consts::PI).sqrt();
        assert!((d + half_normal).abs() < 0.01, "{d} vs {}", -half_normal);
        // A uniform CDF over [lambda - 1/2, lambda + 1/2) is unbiased (dither).
        for lambda in [10.0, 10.3, 10.77] {
            let d = bias_exact(lambda, 64, |x| (x - lambda + 0.5).clamp(0.0, 1.0));
            assert!(d.abs() < 1e-12, "{lambda}: {d}");
        }
    }

    #[test]
    fn monte_carlo_agrees_within_its_error() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(2018);
        for (sigma, lf) in [(0.15, 0.25), (0.25, 0.8), (0.3, 0.1)] {
            let (mc, se) = bias_monte_carlo(512.0 + lf, sigma, 4096, 400_000, &mut rng);
            let e = bias_erf(lf, sigma);
            assert!((mc - e).abs() < 5.0 * se, "sigma {sigma} lf {lf}: mc {mc} +- {se}, erf {e}");
        }
    }

    #[test]
    fn worst_case_matches_the_leading_term_where_it_dominates() {
        // max |delta| is within R = sum_{m>=2} exp(-2 pi^2 m^2 s^2) / (pi m) of the first
        // term's amplitude exp(-2 pi^2 s^2) / pi, reached near lambda' = 1/4 or 3/4.
        use std::f64::consts::PI;
        for sigma in [0.3, 0.4, 0.6] {
            let w = worst_bias(sigma);
            let term = |m: f64| (-2.0 * PI * PI * m * m * sigma * sigma).exp() / (PI * m);
            let rest: f64 = (2..50).map(|m| term(m as f64)).sum();
            assert!((w.max_abs_bias_dn - term(1.0)).abs() <= rest + 1e-15, "{w:?} vs {}", term(1.0));
            assert!(rest < 5e-3 * term(1.0), "the bound must be tight to mean anything");
            assert!((w.at_lambda_frac - 0.25).abs() < 0.01 || (w.at_lambda_frac - 0.75).abs() < 0.01, "{w:?}");
        }
        // Noiseless: 1/2 just below lambda' = 1/2.
        assert!((worst_bias(0.0).max_abs_bias_dn - 0.5).abs() < 1e-3);
        // The MV-D1024E, 182 e- / 44 e-/DN: the leading term is ~1e-147 DN.
        let w = worst_bias(182.0 / 44.0);
        let lead = (-2.0 * std::f64::consts::PI.powi(2) * (182.0f64 / 44.0).powi(2)).exp() / std::f64::consts::PI;
        assert!((w.max_abs_bias_dn / lead - 1.0).abs() < 1e-6, "{w:?} vs {lead}");
    }

    #[test]
    fn sigma_for_bias_inverts_the_worst_case() {
        for b in [0.2, 0.05, 0.01, 1e-3, 1e-4] {
            let s = sigma_for_bias(b).unwrap();
            assert!(worst_bias(s).max_abs_bias_dn <= b * (1.0 + 1e-9), "{b}: {s}");
            assert!(worst_bias(s - 1e-4).max_abs_bias_dn > b, "{b}: {s} is not the smallest");
        }
        assert_eq!(sigma_for_bias(0.6), Some(0.0));
        assert_eq!(sigma_for_bias(0.0), None);
    }

    /// The closed form against a direct average of `bias_gaussian` over `lambda'`.
    #[test]
    fn mean_square_bias_is_the_average_of_the_squared_bias() {
        for sigma in [0.0, 0.05, 0.1, 0.2, 0.3, 0.5] {
            let n = 20_000;
            let direct = (0..n).map(|i| bias_gaussian((i as f64 + 0.5) / n as f64, sigma).powi(2)).sum::<f64>() / n as f64;
            let closed = mean_square_bias(sigma);
            assert!((closed - direct).abs() <= 1e-3 * direct + 1e-12, "sigma {sigma}: {closed} vs {direct}");
        }
        assert!((mean_square_bias(0.0) - 1.0 / 12.0).abs() < 1e-4);
    }


    /// Pixels spread evenly within a code, frames of analog noise `sigma` rounded: the
    /// mean of their frame variances gives `sigma` back (Monte Carlo, 4000 x 64 frames).
    #[test]
    fn the_analog_noise_comes_back_from_quantized_frames() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(5);
        for sigma in [0.05, 0.1, 0.17, 0.3, 0.6] {
            let normal = Normal::new(0.0, sigma).unwrap();
            let (pixels, frames) = (4000, 64);
            let mut mean_var = 0.0;
            for p in 0..pixels {
                let lambda = 100.0 + (p as f64 + 0.5) / pixels as f64;
                let q: Vec<f64> = (0..frames).map(|_| (lambda + normal.sample(&mut rng)).round()).collect();
                let m = q.iter().sum::<f64>() / frames as f64;
                mean_var += q.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (frames - 1) as f64 / pixels as f64;
            }
            let back = sigma_from_quantized_variance(mean_var);
            assert!((back / sigma - 1.0).abs() < 0.03, "sigma {sigma}: {back} from variance {mean_var}");
        }
    }

}
