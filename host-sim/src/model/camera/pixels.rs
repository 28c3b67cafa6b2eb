//! Per-pixel maps: gain (PRNU), dark (DSNU), nonlinearity coefficients and defects, drawn
//! once from the camera's seed, row by row so that any row can be regenerated alone.

use rand::{rngs::StdRng, Rng, SeedableRng};
use rand_distr::{Distribution, Normal};
use rayon::prelude::*;

use super::CameraConfig;

/// Whether a pixel works.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PixelState {
    /// Responds as modeled.
    Good,
    /// Always reads the top code.
    Hot,
    /// No photo-response (dark signal and noise only).
    Dead,
}

/// The maps, row-major.
#[derive(Debug, Clone)]
pub struct PixelMaps {
    width: usize,
    /// Relative gain g_i.
    pub gain: Vec<f64>,
    /// Mean dark signal d_i, e- per frame.
    pub dark_e: Vec<f64>,
    /// Nonlinearity coefficients a2, a3, ... of each pixel, `terms` per pixel.
    pub nonlinearity: Vec<f64>,
    /// Coefficients per pixel.
    pub terms: usize,
    /// Defects.
    pub state: Vec<PixelState>,
}

fn row_rng(seed: u64, row: usize) -> StdRng {
    StdRng::seed_from_u64(seed ^ (row as u64 + 1).wrapping_mul(0xD6E8_FEB8_6659_FD93))
}

impl PixelMaps {
    /// Draws the maps of `config`.
    pub fn generate(config: &CameraConfig) -> Self {
        let (w, h) = (config.width, config.height);
        let terms = config.nonlinearity.len();
        let rows: Vec<_> = (0..h)
            .into_par_iter()
            .map(|row| {
                let mut rng = row_rng(config.seed, row);
                let prnu = Normal::new(0.0, config.prnu_rms).expect("validated rms");
                let dsnu = Normal::new(0.0, config.dsnu_rms_e).expect("validated rms");
                let mut gain = Vec::with_capacity(w);
                let mut dark = Vec::with_capacity(w);
                let mut nl = Vec::with_capacity(w * terms);
                let mut state = Vec::with_capacity(w);
                for col in 0..w {
                    // (A colour filter's cell scales the pixel's own gain; the draws are
                    // the same with or without one.)
                    let cell = config.cfa.as_ref().map_or(1.0, |c| c.at(col, row));
                    gain.push(cell * (1.0 + prnu.sample(&mut rng)));
                    dark.push((config.dark_e + dsnu.sample(&mut rng)).max(0.0));
                    for (m, &a) in config.nonlinearity.iter().enumerate() {
                        let rms = config.pixel_nonlinearity_rms.get(m).copied().unwrap_or(0.0);
                        nl.push(a + rms * Normal::new(0.0, 1.0).expect("unit normal").sample(&mut rng));
                    }
                    let u: f64 = rng.random();
                    state.push(if u < config.bad_pixel_fraction / 2.0 {
                        PixelState::Hot
                    } else if u < config.bad_pixel_fraction {
                        PixelState::Dead
                    } else {
                        PixelState::Good
                    });
                }
                (gain, dark, nl, state)
            })
            .collect();
        let mut maps = PixelMaps { width: w, gain: vec![], dark_e: vec![], nonlinearity: vec![], terms, state: vec![] };
        for (g, d, nl, s) in rows {
            maps.gain.extend(g);
            maps.dark_e.extend(d);
            maps.nonlinearity.extend(nl);
            maps.state.extend(s);
        }
        maps
    }

    /// Nonlinearity coefficients of pixel (row, column).
    #[inline]
    pub fn coefficients(&self, row: usize, column: usize) -> &[f64] {
        let i = (row * self.width + column) * self.terms;
        &self.nonlinearity[i..i + self.terms]
    }
}
