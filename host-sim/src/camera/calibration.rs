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
}
