//! Sampled frames, line by line: the model of [`super`] with random draws. Each line
//! has its own generator seeded from (frame seed, row), so lines can be drawn in any
//! order or in parallel and a frame is reproducible from its seed.
//!
//! Every pixel has its own Poisson mean (PRNU, DSNU), so a sampler that builds its
//! constants once per mean (rand_distr's `Poisson`: ten of them, divisions and powers)
//! pays that per pixel. [`poisson`] is PTRS instead (Hoermann 1993, the transformed
//! rejection numpy uses for means of 10 and up): a square root and two divisions per
//! mean, two uniforms per draw, accepted at once 35% of the time at a mean of 10 and
//! 80% at large means (the rest through a logarithmic test); below 10 it
//! multiplies uniforms (Knuth). Both are exact in distribution (tested against the
//! Poisson PMF by chi-square). The generator is Xoshiro256++ (`rand_xoshiro`, a fixed
//! algorithm: the Poisson draws depend on the generator alone; the read noise's Gaussian
//! comes from rand_distr's ziggurat, pinned by Cargo.lock), seeded per line through
//! SplitMix64.

use rand::{Rng, RngCore, SeedableRng};
use rand_distr::StandardNormal;
use rand_xoshiro::Xoshiro256PlusPlus;

use super::{Camera, PixelState};

/// The seed of frame `frame` of a run seeded `seed`: what `stream` and the Python
/// `simulate_frames` draw frame `frame` with.
pub fn frame_seed(seed: u64, frame: u64) -> u64 {
    seed.wrapping_mul(0x2545_F491_4F6C_DD1D).wrapping_add(frame)
}

/// The generator of one line of one frame: independent streams per (frame seed, row).
pub fn line_rng(frame_seed: u64, row: usize) -> Xoshiro256PlusPlus {
    Xoshiro256PlusPlus::seed_from_u64(frame_seed ^ (row as u64 + 1).wrapping_mul(0xA076_1D64_78BD_642F))
}

/// A uniform double in [0, 1) with 53 random bits.
#[inline]
fn uniform(rng: &mut impl RngCore) -> f64 {
    (rng.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// floor(x) for |x| < 2^63 without a libm call (baseline x86-64 has no rounding
/// instruction).
#[inline]
fn floor(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t > x { t - 1.0 } else { t }
}

/// One draw of Poisson(`lambda`), `lambda` >= 0 and finite (0 otherwise).
#[inline]
pub fn poisson(rng: &mut impl RngCore, lambda: f64) -> f64 {
    if lambda >= 10.0 && lambda.is_finite() {
        ptrs(rng, lambda)
    } else if lambda > 0.0 && lambda < 10.0 {
        // Knuth: the count of uniforms whose running product stays above exp(-lambda).
        let limit = (-lambda).exp();
        let mut k = 0.0;
        let mut p = uniform(rng);
        while p > limit {
            k += 1.0;
            p *= uniform(rng);
        }
        k
    } else {
        0.0
    }
}

/// ln k! for an integer-valued `k` >= 0: exact sums below 16, Stirling's series beyond
/// (five terms; the first left out, 691 / (360360 x^11), is under 1e-16 at x = 17).
fn ln_factorial(k: f64) -> f64 {
    if k < 16.0 {
        return (2..=k as u32).map(|j| (j as f64).ln()).sum();
    }
    let x = k + 1.0;
    let (r, r2) = (1.0 / x, 1.0 / (x * x));
    const HALF_LN_TAU: f64 = 0.918_938_533_204_672_8;
    (x - 0.5) * x.ln() - x + HALF_LN_TAU + r * (1.0 / 12.0 - r2 * (1.0 / 360.0 - r2 * (1.0 / 1260.0 - r2 * (1.0 / 1680.0 - r2 / 1188.0))))
}

/// PTRS (W. Hoermann, "The transformed rejection method for generating Poisson random
/// variables", Insurance: Mathematics and Economics 12, 1993), for `lambda` >= 10: the
/// rejection steps after a first pair `(u, v)` missed the immediate acceptance.
#[cold]
#[inline(never)]
fn ptrs_slow(rng: &mut impl RngCore, lambda: f64, a: f64, b: f64, vr: f64, mut u: f64, mut v: f64) -> f64 {
    let (log_lambda, inv_alpha) = (lambda.ln(), 1.1239 + 1.1328 / (b - 3.4));
    loop {
        let us = 0.5 - u.abs();
        let k = floor((2.0 * a / us + b) * u + lambda + 0.43);
        if !(k < 0.0 || (us < 0.013 && v > us)) {
            if us >= 0.07 && v <= vr {
                return k;
            }
            // log(v) + log(inv_alpha) - log(a / us^2 + b) <= log(lambda^k e^-lambda / k!)
            if (v * inv_alpha / (a / (us * us) + b)).ln() <= k * log_lambda - lambda - ln_factorial(k) {
                return k;
            }
        }
        u = uniform(rng) - 0.5;
        v = uniform(rng);
    }
}

#[inline]
fn ptrs(rng: &mut impl RngCore, lambda: f64) -> f64 {
    let b = 0.931 + 2.53 * lambda.sqrt();
    let a = -0.059 + 0.02483 * b;
    let vr = 0.9277 - 3.6224 / (b - 2.0);
    let u = uniform(rng) - 0.5;
    let v = uniform(rng);
    let us = 0.5 - u.abs();
    if us >= 0.07 && v <= vr {
        // The immediate acceptance (35% of draws at a mean of 10, 80% at large means).
        return floor((2.0 * a / us + b) * u + lambda + 0.43);
    }
    ptrs_slow(rng, lambda, a, b, vr, u, v)
}

impl Camera {
    /// Draws line `row` of a frame with seed `frame_seed`; `photons(column)` is the mean
    /// number of photons reaching each pixel in the frame.
    pub fn sample_line(&self, row: usize, frame_seed: u64, photons: impl Fn(usize) -> f64) -> Vec<u16> {
        self.sample_span(row, 0..self.config.width, frame_seed, photons)
    }

    /// Draws the pixels `columns` of line `row` (a ROI readout), as [`Self::sample_line`].
    pub fn sample_span(&self, row: usize, columns: std::ops::Range<usize>, frame_seed: u64, photons: impl Fn(usize) -> f64) -> Vec<u16> {
        let mut out = vec![0; columns.len()];
        self.sample_span_into(row, columns, frame_seed, photons, &mut out);
        out
    }

    /// As [`Self::sample_span`], into `out` (one code per column of `columns`; extra
    /// columns or codes are left alone): a frame's lines drawn straight into its buffer.
    pub fn sample_span_into(&self, row: usize, columns: std::ops::Range<usize>, frame_seed: u64, photons: impl Fn(usize) -> f64, out: &mut [u16]) {
        let cfg = &self.config;
        let mut rng = line_rng(frame_seed, row);
        let top = (cfg.codes() - 1) as u16;
        let base = row * cfg.width;
        let (inv_gain, offset, read, qe) = (1.0 / cfg.gain_e_per_dn, cfg.offset_dn, cfg.read_noise_e, cfg.qe);
        // The ADC index walks with the column (column mod n_adc without a division per pixel).
        let n_adc = self.adcs.len();
        let mut adc = dncal_core::adc_of_column(columns.start, n_adc);
        for (c, slot) in columns.zip(out.iter_mut()) {
            let i = base + c;
            let code = match self.pixels.state[i] {
                PixelState::Hot => top,
                state => {
                    let gain = if state == PixelState::Dead { 0.0 } else { self.pixels.gain[i] };
                    let mu = (qe * photons(c) * gain + self.pixels.dark_e[i]).max(0.0);
                    let n = poisson(&mut rng, mu);
                    let z: f64 = rng.sample(StandardNormal);
                    let y = self.response_e(n, self.pixels.coefficients(row, c)) + read * z;
                    self.adcs[adc].code(y * inv_gain + offset)
                }
            };
            *slot = code;
            adc += 1;
            if adc == n_adc {
                adc = 0;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{line_rng, poisson};
    use crate::model::camera::{Camera, CameraConfig};
    use statrs::distribution::{Discrete, Poisson as Pmf};

    /// Chi-square of `draws` samples of [`poisson`] against statrs' Poisson PMF over the
    /// values with at least 20 expected (the rest pooled), as (chi2, degrees of freedom).
    fn chi_square(lambda: f64, draws: usize, seed: u64) -> (f64, usize, f64, f64) {
        let mut rng = line_rng(seed, 0);
        let mut counts = std::collections::BTreeMap::<u64, u64>::new();
        let (mut sum, mut sum2) = (0.0, 0.0);
        for _ in 0..draws {
            let k = poisson(&mut rng, lambda);
            assert!(k >= 0.0 && k.fract() == 0.0, "{k}");
            *counts.entry(k as u64).or_default() += 1;
            sum += k;
            sum2 += k * k;
        }
        let pmf = Pmf::new(lambda).unwrap();
        let (mut chi2, mut dof, mut rest_obs, mut rest_exp) = (0.0, 0usize, 0.0, draws as f64);
        let hi = (lambda + 12.0 * lambda.sqrt() + 20.0) as u64;
        for k in 0..=hi {
            let e = pmf.pmf(k) * draws as f64;
            if e >= 20.0 {
                let o = *counts.get(&k).unwrap_or(&0) as f64;
                chi2 += (o - e).powi(2) / e;
                dof += 1;
                rest_exp -= e;
                rest_obs += o;
            }
        }
        let rest_obs = draws as f64 - rest_obs;
        if rest_exp >= 20.0 {
            chi2 += (rest_obs - rest_exp).powi(2) / rest_exp;
            dof += 1;
        }
        let mean = sum / draws as f64;
        (chi2, dof - 1, mean, sum2 / draws as f64 - mean * mean)
    }

    #[test]
    fn poisson_draws_follow_the_pmf_on_both_branches() {
        // Knuth below 10, PTRS from 10 (the boundary both sides), up to a full well.
        for (i, &lambda) in [0.3, 4.0, 9.99, 10.0, 37.5, 1000.0, 182_000.0].iter().enumerate() {
            let n = 400_000;
            let (chi2, dof, mean, var) = chi_square(lambda, n, 17 + i as u64);
            // chi^2 with dof degrees of freedom: mean dof, sd sqrt(2 dof); 5 sd.
            assert!(chi2 < dof as f64 + 5.0 * (2.0 * dof as f64).sqrt(), "lambda {lambda}: chi2 {chi2} on {dof}");
            // Mean and variance both lambda; 5 standard errors (var of s^2 ~ lambda (1 + 2 lambda) / n).
            assert!((mean - lambda).abs() < 5.0 * (lambda / n as f64).sqrt(), "lambda {lambda}: mean {mean}");
            assert!((var - lambda).abs() < 5.0 * (lambda * (1.0 + 2.0 * lambda) / n as f64).sqrt(), "lambda {lambda}: var {var}");
        }
        for degenerate in [0.0, -3.0, f64::NAN, f64::INFINITY] {
            assert_eq!(poisson(&mut line_rng(1, 1), degenerate), 0.0, "{degenerate}");
        }
    }

    #[test]
    fn ln_factorial_matches_statrs_ln_gamma() {
        for k in (0..200).chain([1_000, 20_000, 182_000, 10_000_000]) {
            let k = k as f64;
            let want = statrs::function::gamma::ln_gamma(k + 1.0);
            assert!((super::ln_factorial(k) - want).abs() <= 1e-14 * want.abs().max(1.0), "{k}: {} vs {want}", super::ln_factorial(k));
        }
    }

    #[test]
    fn neighbouring_lines_draw_independent_streams() {
        // Lines of one frame, and the same line of consecutive frames, are uncorrelated:
        // the correlation of 1e5 uniforms' worth of draws stays within 5 / sqrt(n).
        let n = 100_000;
        let draws = |seed: u64, row: usize| {
            let mut r = line_rng(seed, row);
            (0..n).map(|_| poisson(&mut r, 50.0) - 50.0).collect::<Vec<f64>>()
        };
        let corr = |a: &[f64], b: &[f64]| {
            let ab: f64 = a.iter().zip(b).map(|(x, y)| x * y).sum();
            ab / (a.iter().map(|x| x * x).sum::<f64>() * b.iter().map(|y| y * y).sum::<f64>()).sqrt()
        };
        let base = draws(735, 3);
        for other in [draws(735, 4), draws(736, 3), draws(735 ^ 1, 2)] {
            assert!(corr(&base, &other).abs() < 5.0 / (n as f64).sqrt());
        }
    }

    #[test]
    fn sampled_codes_follow_the_exact_distribution() {
        // One ADC, uniform pixels: the sampled code histogram must match the exact PMF
        // (chi-square over bins with >= 20 expected) and its mean and variance within
        // 5 standard errors.
        let cfg = CameraConfig {
            width: 256,
            height: 64,
            n_adc: 1,
            prnu_rms: 0.0,
            dsnu_rms_e: 0.0,
            pixel_nonlinearity_rms: vec![],
            bad_pixel_fraction: 0.0,
            ..Default::default()
        };
        let cam = Camera::new(cfg).unwrap();
        let photons = 20_000.0;
        let mu = cam.config.qe * photons + cam.config.dark_e;
        let pmf = cam.code_pmf(&cam.adcs[0], mu, &cam.config.nonlinearity.clone());
        let mut counts = vec![0u64; 4096];
        let mut n = 0u64;
        for frame in 0..4u64 {
            for row in 0..64 {
                for c in cam.sample_line(row, 1000 + frame, |_| photons) {
                    counts[c as usize] += 1;
                    n += 1;
                }
            }
        }
        let mean = counts.iter().enumerate().map(|(k, &c)| k as f64 * c as f64).sum::<f64>() / n as f64;
        let var = counts.iter().enumerate().map(|(k, &c)| (k as f64 - mean).powi(2) * c as f64).sum::<f64>() / (n - 1) as f64;
        let se_mean = (pmf.variance() / n as f64).sqrt();
        assert!((mean - pmf.mean()).abs() < 5.0 * se_mean, "mean {mean} vs exact {}", pmf.mean());
        let se_var = pmf.variance() * (2.0 / n as f64).sqrt();
        assert!((var - pmf.variance()).abs() < 5.0 * se_var, "variance {var} vs exact {}", pmf.variance());
        let (mut chi2, mut dof) = (0.0, 0);
        for (k, &c) in counts.iter().enumerate() {
            let expected = pmf.prob(k) * n as f64;
            if expected >= 20.0 {
                chi2 += (c as f64 - expected).powi(2) / expected;
                dof += 1;
            }
        }
        // chi^2 with dof degrees of freedom: mean dof, sd sqrt(2 dof); 5 sd is a loose bound.
        assert!(dof > 10);
        assert!(chi2 < dof as f64 + 5.0 * (2.0 * dof as f64).sqrt(), "chi2 {chi2} with {dof} bins");
    }
}
