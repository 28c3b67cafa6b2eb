//! Sampled frames, line by line: the model of [`super`] with random draws. Each line
//! has its own generator seeded from (frame seed, row), so lines can be drawn in any
//! order or in parallel and a frame is reproducible from its seed.

use rand::{rngs::StdRng, SeedableRng};
use rand_distr::{Distribution, Normal, Poisson};

use super::{Camera, PixelState};

impl Camera {
    /// Draws line `row` of a frame with seed `frame_seed`; `photons(column)` is the mean
    /// number of photons reaching each pixel in the frame.
    pub fn sample_line(&self, row: usize, frame_seed: u64, photons: impl Fn(usize) -> f64) -> Vec<u16> {
        self.sample_span(row, 0..self.config.width, frame_seed, photons)
    }

    /// Draws the pixels `columns` of line `row` (a ROI readout), as [`Self::sample_line`].
    pub fn sample_span(&self, row: usize, columns: std::ops::Range<usize>, frame_seed: u64, photons: impl Fn(usize) -> f64) -> Vec<u16> {
        let cfg = &self.config;
        let mut rng = StdRng::seed_from_u64(frame_seed ^ (row as u64 + 1).wrapping_mul(0xA076_1D64_78BD_642F));
        let read = Normal::new(0.0, cfg.read_noise_e).expect("validated read noise");
        let top = (cfg.codes() - 1) as u16;
        let base = row * cfg.width;
        columns
            .map(|c| {
                let i = base + c;
                let state = self.pixels.state[i];
                if state == PixelState::Hot {
                    return top;
                }
                let gain = if state == PixelState::Dead { 0.0 } else { self.pixels.gain[i] };
                let mu = (cfg.qe * photons(c) * gain + self.pixels.dark_e[i]).max(0.0);
                let n = if mu > 0.0 { Poisson::new(mu).map(|p| p.sample(&mut rng)).unwrap_or(mu) } else { 0.0 };
                let y = self.response_e(n, self.pixels.coefficients(row, c)) + read.sample(&mut rng);
                self.adc_of(c).code(y / cfg.gain_e_per_dn + cfg.offset_dn)
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use crate::camera::{Camera, CameraConfig};

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
