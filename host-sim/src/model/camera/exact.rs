//! Exact code probabilities for a given mean signal: Poisson photoelectrons convolved
//! with Gaussian read noise, through the nonlinearity, then integrated over each code's
//! interval of the ADC (de Wijn 2018, section 4: "a PMF ... Poissonian ... convolved
//! with a Gaussian distribution for read noise ... multiplied with the cumulative ADC
//! histogram").
//!
//! ```text
//! P(code = k | mu) = sum_n Pois(n; mu) [ Phi((T_{k+1} - v_n)/s) - Phi((T_k - v_n)/s) ]
//! v_n = FW p(min(n, FW)/FW) / K + offset_dn,    s = read_noise_e / K
//! ```
//!
//! ## How the sum over n is evaluated
//! Near saturation, or when `h = floor(min(sqrt(mu), read_noise_e) / 4) <= 1`, every `n`
//! is summed. Otherwise every `h`-th `n` is summed (weights renormalized): the summand is an
//! analytic function of `n` whose narrowest feature is `min(sqrt(mu), read_noise_e) >= 4h`
//! wide, and by the Poisson summation formula the error of such a sampled sum is of
//! order `exp(-2 pi^2 (4h/h)^2) = exp(-316)`: the same Fourier argument as the
//! quantization bias of section 2. Measured against the every-`n` sum the code
//! probabilities agree to 2e-12 (absolute), the level at which different evaluation
//! points see the rounding of `erfc` and of the sums; the tests hold it to 5e-12 and
//! check closed forms.

use statrs::function::erf::erfc;

use super::{Camera, AdcTransfer};

/// The distribution of codes: `p[j]` is the probability of code `first + j`.
#[derive(Debug, Clone, PartialEq)]
pub struct CodePmf {
    /// The lowest code with non-negligible probability.
    pub first: usize,
    /// Probabilities from `first` on.
    pub p: Vec<f64>,
}

impl CodePmf {
    /// Mean code, DN.
    pub fn mean(&self) -> f64 {
        self.p.iter().enumerate().map(|(j, p)| (self.first + j) as f64 * p).sum()
    }
    /// Variance of the code, DN^2.
    pub fn variance(&self) -> f64 {
        let m = self.mean();
        self.p.iter().enumerate().map(|(j, p)| ((self.first + j) as f64 - m).powi(2) * p).sum()
    }
    /// Probability of code `k`.
    pub fn prob(&self, k: usize) -> f64 {
        k.checked_sub(self.first).and_then(|j| self.p.get(j)).copied().unwrap_or(0.0)
    }
    /// Mean of `f(code)`: e.g. a LUT applied to the code.
    pub fn expect(&self, f: impl Fn(usize) -> f64) -> f64 {
        self.p.iter().enumerate().map(|(j, p)| f(self.first + j) * p).sum()
    }
}

/// Standard normal CDF.
#[inline]
pub fn phi(x: f64) -> f64 {
    0.5 * erfc(-x / std::f64::consts::SQRT_2)
}

/// Poisson probabilities `Pois(n; mu)` for `n` in `lo..=hi` (the whole mass beyond is
/// below 1e-30 when the range spans 12 sqrt(mu) + 12 each side), by the ratio recurrence
/// outward from the mode and normalized over the range: `n ln mu - mu - ln n!` would
/// cancel 1e5-sized terms.
pub(crate) fn poisson_range(mu: f64) -> (usize, Vec<f64>) {
    let spread = 12.0 * mu.sqrt() + 12.0;
    let lo = (mu - spread).floor().max(0.0) as usize;
    let hi = (mu + spread).ceil() as usize;
    let mode = (mu.floor() as usize).clamp(lo, hi);
    let mut p = vec![0.0; hi - lo + 1];
    p[mode - lo] = 1.0;
    for n in mode..hi {
        p[n + 1 - lo] = p[n - lo] * mu / (n + 1) as f64;
    }
    for n in (lo..mode).rev() {
        p[n - lo] = p[n + 1 - lo] * (n + 1) as f64 / mu;
    }
    let total: f64 = p.iter().sum();
    p.iter_mut().for_each(|x| *x /= total);
    (lo, p)
}

/// Nodes and weights of the sum over photoelectrons for mean `mu`: every `h`-th count of
/// [`poisson_range`], renormalized over the nodes kept.
fn poisson_nodes(mu: f64, read_noise_e: f64, full_well_e: f64) -> Vec<(f64, f64)> {
    if mu <= 0.0 {
        return vec![(0.0, 1.0)];
    }
    let (lo, p) = poisson_range(mu);
    let hi = lo + p.len() - 1;
    let h = if read_noise_e <= 0.0 || hi as f64 >= full_well_e { 1 } else { (mu.sqrt().min(read_noise_e) / 4.0).floor().max(1.0) as usize };
    let nodes: Vec<(f64, f64)> = (0..p.len()).step_by(h).map(|i| ((lo + i) as f64, p[i])).collect();
    let total: f64 = nodes.iter().map(|(_, w)| w).sum();
    nodes.into_iter().map(|(n, w)| (n, w / total)).collect()
}

impl Camera {
    /// The code distribution of a pixel with mean photoelectron signal `mu_e` (light and
    /// dark), nonlinearity coefficients `a`, read by `adc`.
    pub fn code_pmf(&self, adc: &AdcTransfer, mu_e: f64, a: &[f64]) -> CodePmf {
        let cfg = &self.config;
        let k_gain = cfg.gain_e_per_dn;
        let s = cfg.read_noise_e / k_gain;
        let top = adc.codes() - 1;
        let nodes = poisson_nodes(mu_e, cfg.read_noise_e, cfg.full_well_e);
        let v: Vec<f64> = nodes.iter().map(|&(n, _)| self.response_e(n, a) / k_gain + cfg.offset_dn).collect();
        let reach = 9.0 * s;
        let first = adc.code(v.iter().cloned().fold(f64::INFINITY, f64::min) - reach) as usize;
        let last = adc.code(v.iter().cloned().fold(f64::NEG_INFINITY, f64::max) + reach) as usize;
        let mut p = vec![0.0; last - first + 1];
        for (&(_, w), &vn) in nodes.iter().zip(&v) {
            if s == 0.0 {
                p[adc.code(vn) as usize - first] += w;
                continue;
            }
            let ka = adc.code(vn - reach) as usize;
            let kb = adc.code(vn + reach) as usize;
            // CDF at the lower boundary of each code in ka+1..=kb; code ka takes all below.
            let mut below = 0.0;
            for k in ka..=kb {
                let upper = if k == kb || k == top { 1.0 } else { phi((adc.level(k + 1) - vn) / s) };
                p[k - first] += w * (upper - below);
                below = upper;
            }
        }
        CodePmf { first, p }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::camera::{CameraConfig, AdcTransfer};

    fn camera(cfg: CameraConfig) -> Camera {
        let mut cfg = cfg;
        cfg.width = 8;
        cfg.height = 2;
        Camera::new(cfg).unwrap()
    }

    #[test]
    fn pure_poisson_through_an_ideal_adc_is_the_poisson_pmf() {
        // K = 1 e-/DN, no read noise, no offset, linear: code = n.
        let cam = camera(CameraConfig { gain_e_per_dn: 1.0, read_noise_e: 0.0, offset_dn: 0.0, nonlinearity: vec![], pixel_nonlinearity_rms: vec![], ..Default::default() });
        let adc = AdcTransfer::ideal(12);
        let mu = 7.3f64;
        let pmf = cam.code_pmf(&adc, mu, &[]);
        for k in 0..30usize {
            let closed = (-mu).exp() * mu.powi(k as i32) / (1..=k).map(|i| i as f64).product::<f64>();
            assert!((pmf.prob(k) - closed).abs() < 1e-14, "k={k}");
        }
    }

    #[test]
    fn read_noise_only_is_a_binned_gaussian() {
        let cam = camera(CameraConfig { read_noise_e: 88.0, offset_dn: 100.3, nonlinearity: vec![], pixel_nonlinearity_rms: vec![], ..Default::default() });
        let adc = AdcTransfer::ideal(12);
        let pmf = cam.code_pmf(&adc, 0.0, &[]);
        let s = 2.0; // 88 e- / 44 e-/DN
        for k in 90..112usize {
            let closed = phi((k as f64 + 0.5 - 100.3) / s) - phi((k as f64 - 0.5 - 100.3) / s);
            assert!((pmf.prob(k) - closed).abs() < 1e-14, "k={k}");
        }
        assert!((pmf.p.iter().sum::<f64>() - 1.0).abs() < 1e-14);
    }

    #[test]
    fn sampled_node_sum_equals_the_every_n_sum() {
        let cam = camera(CameraConfig { nonlinearity: vec![], pixel_nonlinearity_rms: vec![], ..Default::default() });
        let adc = &cam.adcs[1];
        for mu in [500.0, 12_345.6, 90_000.0] {
            let fast = cam.code_pmf(adc, mu, &[]);
            // The every-n sum, written out, with Poisson weights from the product form
            // p_n = p_0 prod_{i<=n} mu/i in log space accumulated term by term (no
            // cancellation of large terms), normalized over the range.
            let s = cam.config.read_noise_e / 44.0;
            let spread = 12.0 * f64::sqrt(mu) + 12.0;
            let (lo, hi) = ((mu - spread).floor().max(0.0) as usize, (mu + spread).ceil() as usize);
            let mut ln_p = vec![0.0f64; hi + 1];
            for n in 1..=hi {
                ln_p[n] = ln_p[n - 1] + (mu / n as f64).ln();
            }
            let peak = ln_p[lo..=hi].iter().cloned().fold(f64::NEG_INFINITY, f64::max);
            let total: f64 = ln_p[lo..=hi].iter().map(|l| (l - peak).exp()).sum();
            let mut slow = vec![0.0; adc.codes()];
            for (n, &ln_pn) in ln_p.iter().enumerate().skip(lo) {
                let w = (ln_pn - peak).exp() / total;
                let v = n as f64 / 44.0 + cam.config.offset_dn;
                for (k, slot) in slow.iter_mut().enumerate() {
                    let lo = if k == 0 { 0.0 } else { phi((adc.level(k) - v) / s) };
                    let hi = if k == adc.codes() - 1 { 1.0 } else { phi((adc.level(k + 1) - v) / s) };
                    *slot += w * (hi - lo);
                }
            }
            let worst = (0..adc.codes()).map(|k| (fast.prob(k) - slow[k]).abs()).fold(0.0, f64::max);
            let kw = (0..adc.codes()).max_by(|&a, &b| (fast.prob(a) - slow[a]).abs().total_cmp(&(fast.prob(b) - slow[b]).abs())).unwrap();
            assert!(worst < 5e-12, "mu {mu}: worst difference {worst} at code {kw}: {} vs {}", fast.prob(kw), slow[kw]);
        }
    }

    #[test]
    fn mean_and_variance_match_the_closed_forms_for_large_signals() {
        // Ideal ADC, linear: mean = mu/K + offset, variance = (mu + sigma_r^2)/K^2 + 1/12
        // (Sheppard's correction), valid when the noise spans many codes.
        let cam = camera(CameraConfig { nonlinearity: vec![], pixel_nonlinearity_rms: vec![], ..Default::default() });
        let adc = AdcTransfer::ideal(12);
        for mu in [1_000.0, 50_000.0, 120_000.0] {
            let pmf = cam.code_pmf(&adc, mu, &[]);
            let mean = mu / 44.0 + cam.config.offset_dn;
            let var = (mu + 182.0f64.powi(2)) / 44.0f64.powi(2) + 1.0 / 12.0;
            assert!((pmf.mean() - mean).abs() < 1e-9, "mu {mu}: mean {} vs {mean}", pmf.mean());
            assert!((pmf.variance() - var).abs() < 1e-6 * var, "mu {mu}: var {} vs {var}", pmf.variance());
        }
    }
}
