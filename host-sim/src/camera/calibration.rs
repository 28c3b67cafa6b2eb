//! Simulated calibration data sets, as the paper's lab setup records them (section 3).
//!
//! - **ADC histograms** (section 4): per-ADC code histograms of a region near the sensor
//!   center, summed over illumination ramps of 130, 131, ..., 139 levels from dark to
//!   saturation. Each level's expected histogram is the exact code distribution
//!   ([`super::exact`]) of the region's mean signal times the pixels per ADC and frames;
//!   the recorded counts are Poisson draws around it. The spread of PRNU and DSNU inside
//!   the region is not modeled here (it only broadens each level's bump, which the
//!   flattening divides out).
//! - **Linearity sets** (section 5): 41 levels from dark to saturation, 256 frames per
//!   level; per pixel the mean and standard deviation of the sampled frames, and the
//!   reference photodiode's voltage, linear in the light.

use rand::{rngs::StdRng, SeedableRng};
use rand_distr::{Distribution, Poisson};
use rayon::prelude::*;

use super::Camera;

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
    /// Seed of the Poisson draws.
    pub seed: u64,
}

impl Default for RampParams {
    fn default() -> Self {
        RampParams { ramp_levels: (130..140).collect(), pixels_per_adc: 64 * 64 / 4, frames_per_level: 8, overshoot: 1.03, seed: 4 }
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

    /// The summed per-ADC histograms of the ramps, `[adc][code]`. `progress` gets the
    /// number of levels done.
    pub fn ramp_histograms(&self, p: &RampParams, progress: impl Fn(u64) + Sync) -> Vec<Vec<u64>> {
        let sat = self.saturation_photons() * p.overshoot;
        let levels: Vec<f64> = p.ramp_levels.iter().flat_map(|&l| (0..l).map(move |i| sat * i as f64 / (l - 1).max(1) as f64)).collect();
        let done = std::sync::atomic::AtomicU64::new(0);
        let a = self.config.nonlinearity.clone();
        let expected: Vec<Vec<f64>> = levels
            .par_iter()
            .map(|&photons| {
                let mu = self.mean_signal_e(photons);
                let mut e = vec![0.0; self.config.codes() * self.adcs.len()];
                for (i, adc) in self.adcs.iter().enumerate() {
                    let pmf = self.code_pmf(adc, mu, &a);
                    for (j, &pk) in pmf.p.iter().enumerate() {
                        e[i * self.config.codes() + pmf.first + j] += pk;
                    }
                }
                progress(done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1);
                e
            })
            .collect();
        let scale = (p.pixels_per_adc * p.frames_per_level) as f64;
        let codes = self.config.codes();
        (0..self.adcs.len())
            .into_par_iter()
            .map(|adc| {
                let mut rng = StdRng::seed_from_u64(p.seed.wrapping_add(adc as u64 * 7919));
                (0..codes)
                    .map(|k| {
                        let lambda = scale * expected.iter().map(|e| e[adc * codes + k]).sum::<f64>();
                        if lambda > 0.0 { Poisson::new(lambda).map(|d| d.sample(&mut rng) as u64).unwrap_or(0) } else { 0 }
                    })
                    .collect()
            })
            .collect()
    }
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

impl Camera {
    /// Records a linearity set by sampling `p.frames` frames at each level. `progress`
    /// gets the number of levels done.
    pub fn linearity_set(&self, p: &LinearityParams, progress: impl Fn(u64) + Sync) -> LinearityData {
        let (x0, y0, w, h) = p.roi;
        let sat = self.saturation_photons() * p.overshoot;
        let done = std::sync::atomic::AtomicU64::new(0);
        let per_level: Vec<(Vec<f64>, Vec<f64>)> = (0..p.levels)
            .into_par_iter()
            .map(|level| {
                let photons = sat * level as f64 / (p.levels - 1).max(1) as f64;
                // Welford per pixel over the frames.
                let mut mean = vec![0.0; w * h];
                let mut m2 = vec![0.0; w * h];
                for f in 0..p.frames {
                    let seed = p.seed ^ ((level as u64) << 40) ^ ((f as u64) << 8);
                    for y in 0..h {
                        let line = self.sample_span(y0 + y, x0..x0 + w, seed, |_| photons);
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
    use crate::camera::CameraConfig;

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

    #[test]
    fn linearity_means_follow_the_exact_model() {
        let cfg = CameraConfig { width: 16, height: 8, prnu_rms: 0.0, dsnu_rms_e: 0.0, pixel_nonlinearity_rms: vec![], bad_pixel_fraction: 0.0, ..Default::default() };
        let cam = Camera::new(cfg).unwrap();
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
}
