//! Simulated calibration data sets, as the paper's lab setup records them (section 3).
//!
//! - **ADC histograms** (section 4): per-ADC code histograms of a region near the sensor
//!   center, summed over illumination ramps of 130, 131, ..., 139 levels from dark to
//!   saturation. The signal is not uniform across the region (vignetting, lamp
//!   gradient, PRNU, DSNU): a pixel's mean photoelectrons at a level of mean `mu` are
//!   `mu f`, `f` gamma distributed with mean 1 and rms `field_spread`, so the level's
//!   photoelectrons follow the Poisson-gamma mixture, a negative binomial of mean `mu`
//!   and variance `mu + (field_spread mu)^2`. The mixtures of all levels are summed per
//!   electron count `n` into `M(n)` (it does not depend on the ADC), then each ADC's
//!   expected counts are `E_k = N sum_n M(n) [Phi((T_{k+1} - v_n)/s) - Phi((T_k - v_n)/s)]`,
//!   the exact model of [`super::exact`], with `N` = pixels x frames; the recorded counts
//!   are Poisson draws around them.
//!
//!   Why the spread, and why a smooth one: without it the low levels of every ramp land
//!   on the same codes (level i of each ramp is near i x 31 DN, read noise 4 DN) and leave
//!   a comb of period ~31 DN up to ~500 DN that neither the 50-point spline nor the
//!   21-code median removes; in the first demo it biased the LUT's cumulative offset by
//!   up to 18 DN. A uniform (box) spread of +-25% still left lumps from the box edges
//!   near code 150 and 2.5 DN errors there; a smooth distribution's lumps fall off as
//!   `exp(-2 pi^2 (spread / spacing)^2)`.
//! - **Linearity sets** (section 5): 41 levels from dark to saturation, 256 frames per
//!   level; per pixel the mean and standard deviation of the sampled frames, and the
//!   reference photodiode's voltage, linear in the light.

use rand::{rngs::StdRng, Rng, SeedableRng};
use rand_distr::{Distribution, Normal, Poisson};
use rayon::prelude::*;

use super::exact::{phi, poisson_range};
use super::{Camera, AdcTransfer};

/// How the ramps are recorded.
#[derive(Debug, Clone)]
pub struct RampParams {
    /// Levels of each ramp (the paper: 130 to 139).
    pub ramp_levels: Vec<usize>,
    /// Pixels of each ADC in the region.
    pub pixels_per_adc: u64,
    /// Frames recorded per level.
    pub frames_per_level: u64,
    /// The last level, as a multiple of the light that just saturates the ADC.
    pub overshoot: f64,
    /// Relative rms spread of the pixels' mean signal across the region (light and
    /// dark; a gamma distribution of mean 1: 0.25 means 25% rms).
    pub field_spread: f64,
    /// Seed of the Poisson draws.
    pub seed: u64,
}

impl Default for RampParams {
    fn default() -> Self {
        RampParams { ramp_levels: (130..140).collect(), pixels_per_adc: 256 * 256 / 4, frames_per_level: 100, overshoot: 1.03, field_spread: 0.25, seed: 4 }
    }
}

impl Camera {
    /// Photons per pixel per frame at which a typical pixel saturates: its noiseless
    /// signal (global nonlinearity) reaches the ADC's top code, or the full well if that
    /// comes first. Found by bisection on the monotonic response.
    pub fn saturation_photons(&self) -> f64 {
        let c = &self.config;
        let top_dn = (c.codes() - 1) as f64;
        let dn = |n: f64| self.response_e(n, &c.nonlinearity) / c.gain_e_per_dn + c.offset_dn;
        let (mut lo, mut hi) = (0.0, c.full_well_e);
        if dn(hi) > top_dn {
            for _ in 0..100 {
                let mid = 0.5 * (lo + hi);
                if dn(mid) > top_dn { hi = mid } else { lo = mid }
            }
        }
        ((hi - c.dark_e) / c.qe).max(0.0)
    }

    /// Mean photoelectrons (light plus dark) of a typical pixel at `photons`.
    pub fn mean_signal_e(&self, photons: f64) -> f64 {
        self.config.qe * photons + self.config.dark_e
    }

    /// The ramps' illumination levels, photons per pixel per frame.
    pub fn ramp_levels(&self, p: &RampParams) -> Vec<f64> {
        let sat = self.saturation_photons() * p.overshoot;
        p.ramp_levels.iter().flat_map(|&l| (0..l).map(move |i| sat * i as f64 / (l - 1).max(1) as f64)).collect()
    }

    /// `M(n)`: the photoelectron distributions of all ramp levels summed (each level
    /// contributes probability 1), indexed by electron count. Counts above the full well
    /// are kept (the response clips them). `progress` gets the number of levels done.
    pub fn ramp_electrons(&self, p: &RampParams, progress: impl Fn(u64) + Sync) -> Vec<f64> {
        let levels = self.ramp_levels(p);
        let done = std::sync::atomic::AtomicU64::new(0);
        let g = p.field_spread;
        // In fixed chunks (at most 32, each holding its own masses) merged in order, so
        // that the masses (and every count drawn from them) are the same on every run.
        crate::infra::parallel::fold_in_order(
            &levels,
            levels.len().div_ceil(32),
            Vec::new,
            |mut m: Vec<f64>, &photons| {
                add_poisson_gamma(&mut m, self.mean_signal_e(photons), g);
                progress(done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1);
                m
            },
            |mut a, b| {
                if a.len() < b.len() {
                    a.resize(b.len(), 0.0);
                }
                a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                a
            },
        )
    }

    /// Expected fraction of samples in each code of `adc` when the photoelectrons follow
    /// `m` (any non-negative masses by electron count): the exact model, Gaussian read
    /// noise of `read_noise_e` around `v_n`, integrated over each code's interval.
    pub fn codes_from_electrons(&self, adc: &AdcTransfer, m: &[f64]) -> Vec<f64> {
        let cfg = &self.config;
        let s = cfg.read_noise_e / cfg.gain_e_per_dn;
        let v: Vec<f64> = (0..m.len()).map(|n| self.response_e(n as f64, &cfg.nonlinearity) / cfg.gain_e_per_dn + cfg.offset_dn).collect();
        // Prefix sums of m: the mass far below a transition level counts whole.
        let mut below = Vec::with_capacity(m.len() + 1);
        let mut acc = 0.0;
        below.push(0.0);
        for &x in m {
            acc += x;
            below.push(acc);
        }
        let total = acc;
        let reach = 9.0 * s;
        // C(T) = sum_n m(n) Phi((T - v_n)/s): mass below the analog level T.
        let cdf = |t: f64| -> f64 {
            if s == 0.0 {
                return below[v.partition_point(|&x| x < t)];
            }
            let i0 = v.partition_point(|&x| x < t - reach);
            let i1 = v.partition_point(|&x| x <= t + reach);
            below[i0] + (i0..i1).map(|n| m[n] * phi((t - v[n]) / s)).sum::<f64>()
        };
        let codes = adc.codes();
        let c: Vec<f64> = (0..=codes).map(|k| if k == 0 { 0.0 } else if k == codes { total } else { cdf(adc.level(k)) }).collect();
        c.windows(2).map(|w| (w[1] - w[0]).max(0.0)).collect()
    }

    /// The summed per-ADC histograms of the ramps, `[adc][code]`: Poisson draws around
    /// [`Self::codes_from_electrons`] of [`Self::ramp_electrons`] times pixels x frames.
    /// `progress` gets the number of levels done.
    pub fn ramp_histograms(&self, p: &RampParams, progress: impl Fn(u64) + Sync) -> Vec<Vec<u64>> {
        let m = self.ramp_electrons(p, progress);
        let scale = (p.pixels_per_adc * p.frames_per_level) as f64;
        self.adcs
            .par_iter()
            .enumerate()
            .map(|(adc, conv)| {
                let mut rng = StdRng::seed_from_u64(p.seed.wrapping_add(adc as u64 * 7919));
                self.codes_from_electrons(conv, &m)
                    .into_iter()
                    .map(|e| {
                        let lambda = scale * e;
                        if lambda > 0.0 { Poisson::new(lambda).map(|d| d.sample(&mut rng) as u64).unwrap_or(0) } else { 0 }
                    })
                    .collect()
            })
            .collect()
    }
}

/// Adds to `m` the distribution of `n ~ Pois(mu)` with `mu = mean f`, `f` gamma
/// distributed with mean 1 and relative spread `g` (shape `k = 1/g^2`): the negative
/// binomial `P(n) = Gamma(n + k) / (n! Gamma(k)) (1 - q)^k q^n`, `q = mean g^2 / (1 + mean g^2)`,
/// of mean `mean` and variance `mean + g^2 mean^2`. It is evaluated by the ratio
/// `P(n + 1) / P(n) = q (n + k) / (n + 1)` outward from the mode until terms fall below
/// 1e-20 of it, and normalized over that range. `g = 0` is plain Poisson.
fn add_poisson_gamma(m: &mut Vec<f64>, mean: f64, g: f64) {
    let (lo, p) = if g <= 0.0 || mean <= 0.0 {
        poisson_range(mean.max(0.0))
    } else {
        let k = 1.0 / (g * g);
        let q = mean * g * g / (1.0 + mean * g * g);
        let mode = if k > 1.0 { ((k - 1.0) * q / (1.0 - q)).floor() as usize } else { 0 };
        let ratio = |n: usize| q * (n as f64 + k) / (n as f64 + 1.0);
        let mut up = vec![1.0];
        let mut n = mode;
        while *up.last().unwrap_or(&0.0) > 1e-20 {
            let next = up[up.len() - 1] * ratio(n);
            up.push(next);
            n += 1;
        }
        let mut down = Vec::new();
        let (mut n, mut x) = (mode, 1.0);
        while n > 0 && x > 1e-20 {
            x /= ratio(n - 1);
            down.push(x);
            n -= 1;
        }
        let lo = mode - down.len();
        let mut p: Vec<f64> = down.into_iter().rev().chain(up).collect();
        let total: f64 = p.iter().sum();
        p.iter_mut().for_each(|x| *x /= total);
        (lo, p)
    };
    if m.len() < lo + p.len() {
        m.resize(lo + p.len(), 0.0);
    }
    m[lo..lo + p.len()].iter_mut().zip(&p).for_each(|(x, y)| *x += y);
}

/// The relative change of the light's spatial pattern at linearity level `level` over a
/// region of `w x h` pixels, row-major: `rms phi(x, y)`, `phi` a sum of 24
/// long-wavelength Fourier modes over the region (wave numbers `kx` in -3..=3 and `ky` in
/// 0..=3 cycles per side, the half plane without (0, 0)), amplitudes N(0, 1) / |k| and
/// uniform phases, then its mean taken out and scaled to unit rms over the region, so the
/// reference diode, which sees the total light, does not see it
/// ([`super::config::BenchConfig::illumination_change_rms`]). Drawn from (`seed`, level)
/// alone: independent between levels, the same for any frame.
pub fn illumination_change(rms: f64, w: usize, h: usize, seed: u64, level: usize) -> Vec<f64> {
    let mut rng = StdRng::seed_from_u64(seed ^ (level as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15));
    let unit = Normal::new(0.0, 1.0).expect("unit normal");
    let modes: Vec<(f64, f64, f64, f64)> = (0..=3i32)
        .flat_map(|ky| (-3..=3i32).map(move |kx| (kx, ky)))
        .filter(|&(kx, ky)| ky > 0 || kx > 0)
        .map(|(kx, ky)| {
            let k = f64::from(kx * kx + ky * ky).sqrt();
            (f64::from(kx), f64::from(ky), unit.sample(&mut rng) / k, rng.random::<f64>() * std::f64::consts::TAU)
        })
        .collect();
    let mut field: Vec<f64> = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| {
            let (u, v) = ((x as f64 + 0.5) / w as f64, (y as f64 + 0.5) / h as f64);
            modes.iter().map(|&(kx, ky, a, phase)| a * (std::f64::consts::TAU * (kx * u + ky * v) + phase).cos()).sum()
        })
        .collect();
    let n = field.len().max(1) as f64;
    let mean = field.iter().sum::<f64>() / n;
    let sd = (field.iter().map(|f| (f - mean).powi(2)).sum::<f64>() / n).sqrt();
    let scale = if sd > 0.0 { rms / sd } else { 0.0 };
    field.iter_mut().for_each(|f| *f = (*f - mean) * scale);
    field
}

/// How a linearity set is recorded.
#[derive(Debug, Clone)]
pub struct LinearityParams {
    /// Illumination levels, the first dark (the paper: 41).
    pub levels: usize,
    /// Frames per level (the paper: 256).
    pub frames: u32,
    /// Region read out: first column, first row, width, height.
    pub roi: (usize, usize, usize, usize),
    /// The brightest level, as a multiple of the saturation light.
    pub overshoot: f64,
    /// Reference photodiode volts per photon reaching a pixel (it is linear by
    /// assumption: the paper's SM1PD1A photodiode and amplifier).
    pub volts_per_photon: f64,
    /// Seed of the frames.
    pub seed: u64,
}

impl LinearityParams {
    /// The paper's set: 41 levels to 1.02 x saturation, 256 frames, here on a region of
    /// up to 128 x 128 pixels at the sensor center (its first column the nearest below
    /// of ADC 0, so that the set's columns keep `ADCMAP = 'COLMOD'`); 1e-5 V per photon;
    /// seed 41.
    pub fn paper(camera: &Camera) -> Self {
        let (w, h) = (camera.config.width.min(128), camera.config.height.min(128));
        let n = camera.config.n_adc.max(1);
        let x0 = (camera.config.width - w) / 2 / n * n;
        LinearityParams { levels: 41, frames: 256, roi: (x0, (camera.config.height - h) / 2, w, h), overshoot: 1.02, volts_per_photon: 1e-5, seed: 41 }
    }
}

/// A recorded linearity set: per-pixel mean and standard deviation of the frames at each
/// level (level-major, then row, then column), the reference voltages, and the pixels
/// the camera model knows to be bad.
#[derive(Debug, Clone)]
pub struct LinearityData {
    /// Width of the ROI.
    pub width: usize,
    /// Height of the ROI.
    pub height: usize,
    /// Mean code per level and pixel, DN.
    pub mean: Vec<f64>,
    /// Standard deviation (n - 1) per level and pixel, DN.
    pub std: Vec<f64>,
    /// Reference voltage per level, V.
    pub voltage: Vec<f64>,
    /// 1 where the pixel is hot or dead.
    pub mask: Vec<u8>,
}

/// The light's errors at linearity level `level` of the bench (`[bench] level_error_rms`,
/// `frame_jitter_rms`): the level's relative error and each of its `frames` frames'
/// relative jitter, normal, drawn from (`bench.seed`, `level`) apart from the pattern
/// change's draws; all zero on a bench without them (the draws are then not made, so a
/// set without them is the set it was before they existed).
pub fn light_errors(bench: &super::config::BenchConfig, level: usize, frames: usize) -> (f64, Vec<f64>) {
    if bench.level_error_rms == 0.0 && bench.frame_jitter_rms == 0.0 {
        return (0.0, vec![0.0; frames]);
    }
    let mut rng = StdRng::seed_from_u64(bench.seed ^ 0x4C49_4748_5400_0000 ^ (level as u64 + 1).wrapping_mul(0xD1B5_4A32_D192_ED03));
    let mut normal = || -> f64 { rand_distr::StandardNormal.sample(&mut rng) };
    let level_error = bench.level_error_rms * normal();
    let jitter = (0..frames).map(|_| bench.frame_jitter_rms * normal()).collect();
    (level_error, jitter)
}

impl Camera {
    /// Records a linearity set by sampling `p.frames` frames at each level. `progress`
    /// gets the number of levels done.
    pub fn linearity_set(&self, p: &LinearityParams, progress: impl Fn(u64) + Sync) -> LinearityData {
        let (x0, y0, w, h) = p.roi;
        let sat = self.saturation_photons() * p.overshoot;
        let done = std::sync::atomic::AtomicU64::new(0);
        let sampler = self.sampler();
        let per_level: Vec<(Vec<f64>, Vec<f64>)> = (0..p.levels)
            .into_par_iter()
            .map(|level| {
                let bench = &self.config.bench;
                let (level_error, jitter) = light_errors(bench, level, p.frames as usize);
                let nominal = sat * level as f64 / (p.levels - 1).max(1) as f64 * (1.0 + level_error);
                let change = (bench.illumination_change_rms > 0.0).then(|| illumination_change(bench.illumination_change_rms, w, h, bench.seed, level));
                // Welford per pixel over the frames.
                let mut mean = vec![0.0; w * h];
                let mut m2 = vec![0.0; w * h];
                for f in 0..p.frames {
                    let photons = nominal * (1.0 + jitter[f as usize]);
                    let seed = p.seed ^ ((level as u64) << 40) ^ ((f as u64) << 8);
                    for y in 0..h {
                        let line = match &change {
                            Some(c) => sampler.sample_span(y0 + y, x0..x0 + w, seed, |x| photons * (1.0 + c[y * w + x - x0])),
                            None => sampler.sample_span(y0 + y, x0..x0 + w, seed, |_| photons),
                        };
                        for (x, &c) in line.iter().enumerate() {
                            let i = y * w + x;
                            let d = c as f64 - mean[i];
                            mean[i] += d / (f + 1) as f64;
                            m2[i] += d * (c as f64 - mean[i]);
                        }
                    }
                }
                let std = m2.iter().map(|v| (v / (p.frames.max(2) - 1) as f64).sqrt()).collect();
                progress(done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1);
                (mean, std)
            })
            .collect();
        let voltage = (0..p.levels).map(|l| p.volts_per_photon * sat * l as f64 / (p.levels - 1).max(1) as f64).collect();
        let mask = (0..h)
            .flat_map(|y| (0..w).map(move |x| (y, x)))
            .map(|(y, x)| (self.pixels.state[(y0 + y) * self.config.width + x0 + x] != super::PixelState::Good) as u8)
            .collect();
        let (mut mean, mut std) = (Vec::with_capacity(p.levels * w * h), Vec::with_capacity(p.levels * w * h));
        for (m, s) in per_level {
            mean.extend(m);
            std.extend(s);
        }
        LinearityData { width: w, height: h, mean, std, voltage, mask }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::camera::CameraConfig;
    use statrs::function::gamma::ln_gamma;

    fn moments(m: &[f64]) -> (f64, f64, f64) {
        let total: f64 = m.iter().sum();
        let mean = m.iter().enumerate().map(|(n, p)| n as f64 * p).sum::<f64>() / total;
        let var = m.iter().enumerate().map(|(n, p)| (n as f64 - mean).powi(2) * p).sum::<f64>() / total;
        (total, mean, var)
    }

    /// The bench's pattern change at a level: zero mean and the asked rms over the
    /// region (exactly, by construction), smooth (neighbouring pixels alike: its shortest
    /// wavelength is a third of the region), the same for the same seed and level, and
    /// unrelated between levels (the correlation of 20 level pairs scatters about 0).
    #[test]
    fn the_illumination_change_has_zero_mean_the_asked_rms_and_differs_per_level() {
        let (w, h) = (40, 24);
        let a = illumination_change(3e-4, w, h, 735, 5);
        let n = a.len() as f64;
        assert!((a.iter().sum::<f64>() / n).abs() < 1e-18);
        assert!(((a.iter().map(|x| x * x).sum::<f64>() / n).sqrt() - 3e-4).abs() < 1e-15);
        assert_eq!(a, illumination_change(3e-4, w, h, 735, 5));
        let corr = |u: &[f64], v: &[f64]| u.iter().zip(v).map(|(x, y)| x * y).sum::<f64>() / (u.iter().map(|x| x * x).sum::<f64>() * v.iter().map(|y| y * y).sum::<f64>()).sqrt();
        let neighbours: Vec<f64> = (0..h).flat_map(|y| (0..w - 1).map(move |x| y * w + x)).map(|i| a[i + 1] - a[i]).collect();
        // (Measured 0.25 of the rms here; white noise would differ by sqrt(2) of it.)
        assert!(crate::infra::stats::rms(&neighbours) < 0.35 * 3e-4, "neighbouring pixels differ by {}", crate::infra::stats::rms(&neighbours));
        let pairs: Vec<f64> = (1..=20).map(|l| corr(&illumination_change(1.0, w, h, 735, l), &illumination_change(1.0, w, h, 735, l + 20))).collect();
        let mean = pairs.iter().sum::<f64>() / 20.0;
        assert!(mean.abs() < 0.2 && pairs.iter().all(|c| c.abs() < 0.9), "correlations between levels {pairs:?}");
        assert!(illumination_change(0.0, w, h, 735, 5).iter().all(|&x| x == 0.0));
    }

    #[test]
    fn poisson_gamma_mixture_has_the_closed_form_moments() {
        for (mean, g) in [(0.0, 0.25), (3.0, 0.0), (400.0, 0.25), (20_000.0, 0.1), (150_000.0, 0.35)] {
            let mut m = Vec::new();
            add_poisson_gamma(&mut m, mean, g);
            let (total, mu, var) = moments(&m);
            assert!((total - 1.0).abs() < 1e-12, "{mean} {g}: total {total}");
            assert!((mu - mean).abs() < 1e-9 * mean.max(1.0), "{mean} {g}: mean {mu}");
            let want = mean + g * g * mean * mean;
            assert!((var - want).abs() < 1e-8 * want.max(1.0), "{mean} {g}: variance {var} vs {want}");
        }
    }

    #[test]
    fn poisson_gamma_mixture_matches_the_integral_over_the_spread() {
        // Independent oracle: int Pois(n; mean f) Gamma(f; k, 1/k) df by the midpoint rule
        // on a fine grid, in logs from ln_gamma.
        let (mean, g) = (60.0, 0.3);
        let k = 1.0 / (g * g);
        let mut m = Vec::new();
        add_poisson_gamma(&mut m, mean, g);
        let df = 1e-4;
        for n in [0usize, 10, 45, 60, 90, 150] {
            let mut integral = 0.0;
            let mut f = df / 2.0;
            while f < 6.0 {
                let ln_pois = n as f64 * (mean * f).ln() - mean * f - ln_gamma(n as f64 + 1.0);
                let ln_gam = k * k.ln() + (k - 1.0) * f.ln() - k * f - ln_gamma(k);
                integral += (ln_pois + ln_gam).exp() * df;
                f += df;
            }
            assert!((m[n] - integral).abs() < 1e-7 * integral.max(1e-12) + 1e-15, "n {n}: {} vs {integral}", m[n]);
        }
    }

    #[test]
    fn codes_from_poisson_electrons_equal_the_exact_code_pmf() {
        // Two evaluations of the same model: every-n convolution here, the strided sum
        // of `exact::code_pmf` there.
        let cam = Camera::new(CameraConfig { width: 8, height: 2, ..Default::default() }).unwrap();
        for mu in [400.0, 9_000.0, 120_000.0] {
            let mut m = Vec::new();
            add_poisson_gamma(&mut m, mu, 0.0);
            for adc in &cam.adcs {
                let e = cam.codes_from_electrons(adc, &m);
                let pmf = cam.code_pmf(adc, mu, &cam.config.nonlinearity);
                let worst = e.iter().enumerate().map(|(k, x)| (x - pmf.prob(k)).abs()).fold(0.0, f64::max);
                assert!(worst < 1e-10, "mu {mu}: worst {worst}");
                assert!((e.iter().sum::<f64>() - 1.0).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn ramp_histograms_count_every_sample_and_cover_the_codes() {
        let cam = Camera::new(CameraConfig { width: 8, height: 2, ..Default::default() }).unwrap();
        let p = RampParams { ramp_levels: vec![60], pixels_per_adc: 1000, frames_per_level: 10, ..Default::default() };
        let h = cam.ramp_histograms(&p, |_| {});
        assert_eq!(h.len(), 4);
        for counts in &h {
            let total: u64 = counts.iter().sum();
            let expected = 60.0 * 1000.0 * 10.0;
            // Poisson draws per bin: the total is Poisson around 600000, sd ~775.
            assert!((total as f64 - expected).abs() < 5.0 * expected.sqrt(), "total {total}");
            // Overshooting saturation puts mass in the top code; codes far below the
            // offset plus dark never occur.
            assert!(counts[4095] > 0);
            assert_eq!(counts[0], 0);
        }
    }

    /// A 16 x 8 camera whose pixels are all alike (no PRNU, DSNU, own nonlinearity or bad
    /// pixels): every pixel of an ADC has the same exact code PMF.
    fn uniform_camera() -> Camera {
        let cfg = CameraConfig { width: 16, height: 8, prnu_rms: 0.0, dsnu_rms_e: 0.0, pixel_nonlinearity_rms: vec![], bad_pixel_fraction: 0.0, ..Default::default() };
        Camera::new(cfg).unwrap()
    }

    #[test]
    fn linearity_means_follow_the_exact_model() {
        let cam = uniform_camera();
        let p = LinearityParams { levels: 5, frames: 64, roi: (4, 2, 8, 4), overshoot: 1.0, volts_per_photon: 1e-5, seed: 9 };
        let d = cam.linearity_set(&p, |_| {});
        assert_eq!(d.mean.len(), 5 * 32);
        let sat = cam.saturation_photons();
        for level in 1..4 {
            let photons = sat * level as f64 / 4.0;
            assert!((d.voltage[level] - 1e-5 * photons).abs() < 1e-9);
            for i in 0..32 {
                let x = 4 + i % 8;
                let pmf = cam.code_pmf(cam.adc_of(x), cam.mean_signal_e(photons), &cam.config.nonlinearity);
                let m = d.mean[level * 32 + i];
                let se = (pmf.variance() / 64.0).sqrt();
                assert!((m - pmf.mean()).abs() < 5.0 * se, "level {level} pixel {i}: {m} vs {}", pmf.mean());
                let s = d.std[level * 32 + i];
                // The sample sd of 64 frames has a relative standard error of 1/sqrt(126) = 9%: 45% is 5 of them.
                assert!((s - pmf.variance().sqrt()).abs() < 0.45 * pmf.variance().sqrt(), "std {s}");
            }
        }
    }

    /// The frames' variance over a level, pooled over pixels, is the exact model's: the
    /// sample variance (denominator frames - 1) is unbiased, and 128 pixels x 255 degrees
    /// of freedom put its pooled relative standard error at sqrt(2 / 32640) = 0.78%;
    /// checked to 5 of them (a per-pixel tolerance of 45% let a halved variance pass).
    #[test]
    fn linearity_variances_pooled_over_pixels_are_the_exact_models() {
        let cam = uniform_camera();
        let p = LinearityParams { levels: 3, frames: 256, roi: (0, 0, 16, 8), overshoot: 1.0, volts_per_photon: 1e-5, seed: 4 };
        let d = cam.linearity_set(&p, |_| {});
        let photons = cam.saturation_photons() / 2.0;
        let (mut measured, mut exact) = (0.0, 0.0);
        for i in 0..128 {
            let pmf = cam.code_pmf(cam.adc_of(i % 16), cam.mean_signal_e(photons), &cam.config.nonlinearity);
            measured += d.std[128 + i].powi(2);
            exact += pmf.variance();
        }
        let rel = measured / exact - 1.0;
        assert!(rel.abs() < 5.0 * (2.0f64 / (128.0 * 255.0)).sqrt(), "pooled variance off by {:.2}%", 100.0 * rel);
    }
}
