//! Sampled frames, line by line: the model of [`super`] with random draws. Each line
//! has its own eight streams seeded from (frame seed, row) ([`super::draws`], whose
//! module comment is the seed contract), so lines can be drawn in any order or in
//! parallel, a frame is reproducible from its seed, and a vector unit draws eight
//! pixels of a line at once.
//!
//! Every pixel has its own Poisson mean (PRNU, DSNU), so a sampler that builds its
//! constants once per mean (rand_distr's `Poisson`: ten of them, divisions and powers)
//! pays that per pixel. The draw is PTRS instead (Hoermann 1993, the transformed
//! rejection numpy uses for means of 10 and up): a square root and a few divisions per
//! mean, two uniforms per trial, accepted at once 35% of the time at a mean of 10 and
//! 80% at large means (the rest through a logarithmic test); below 10 it multiplies
//! uniforms (Knuth). The read noise's Gaussian is Box-Muller, a pair every second
//! pixel of a stream. Both are exact in distribution (tested against the Poisson PMF by
//! chi-square and the normal's moments and CDF).

use super::draws::{LineDraws, CHUNK};
use super::{Camera, PixelState};

/// The seed of frame `frame` of a run seeded `seed`: what `stream` and the Python
/// `simulate_frames` draw frame `frame` with.
pub fn frame_seed(seed: u64, frame: u64) -> u64 {
    seed.wrapping_mul(0x2545_F491_4F6C_DD1D).wrapping_add(frame)
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
        // A chunk of means, then their draws eight streams at a time, then the codes: the
        // draws in a loop of their own, where a vector unit runs them.
        let cfg = &self.config;
        let mut draws = LineDraws::new(frame_seed, row);
        let top = (cfg.codes() - 1) as u16;
        let base = row * cfg.width;
        let (inv_gain, offset, read, qe) = (1.0 / cfg.gain_e_per_dn, cfg.offset_dn, cfg.read_noise_e, cfg.qe);
        // The ADC index walks with the column (column mod n_adc without a division per pixel).
        let n_adc = self.adcs.len();
        let mut adc = dncal_core::adc_of_column(columns.start, n_adc);
        let count = columns.len().min(out.len());
        let (mut mu, mut n, mut z) = ([0.0; CHUNK], [0.0; CHUNK], [0.0; CHUNK]);
        for (start, out) in (0..count).step_by(CHUNK).zip(out[..count].chunks_mut(CHUNK)) {
            let first = columns.start + start;
            let len = out.len();
            for (t, mu) in mu[..len].iter_mut().enumerate() {
                let (c, i) = (first + t, base + first + t);
                *mu = match self.pixels.state[i] {
                    PixelState::Hot => 0.0,
                    PixelState::Dead => self.pixels.dark_e[i].max(0.0),
                    PixelState::Good => (qe * photons(c) * self.pixels.gain[i] + self.pixels.dark_e[i]).max(0.0),
                };
            }
            draws.draw(&mu[..len], &mut n[..len], &mut z[..len]);
            for (t, slot) in out.iter_mut().enumerate() {
                let (c, i) = (first + t, base + first + t);
                *slot = if self.pixels.state[i] == PixelState::Hot {
                    top
                } else {
                    let y = self.response_e(n[t], self.pixels.coefficients(row, c)) + read * z[t];
                    self.adcs[adc].code(y * inv_gain + offset)
                };
                adc += 1;
                if adc == n_adc {
                    adc = 0;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::model::camera::{Camera, CameraConfig};

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
