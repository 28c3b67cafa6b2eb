//! Synthetic calibration and line data for runs that need no camera model: a LUT set
//! with a periodic DN error, and lines whose level depends on modulation state, column
//! and row, with Gaussian-like noise and planted clipped codes. Seeded and reproducible.

use dncal_core::{Geometry, Weight};

/// SplitMix64 (the FPGA model's fault injector's, one copy): small, seeded, reproducible
/// on every platform.
#[derive(Debug, Clone)]
pub struct Rng(dncal_fpga_model::faults::SplitMix64);

impl Rng {
    /// A generator from `seed`.
    pub fn new(seed: u64) -> Self {
        Rng(dncal_fpga_model::faults::SplitMix64::new(seed))
    }
    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0.next_u64()
    }
    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Approximately normal (Irwin-Hall of 12 uniforms): mean 0, standard deviation 1.
    pub fn normal(&mut self) -> f64 {
        (0..12).map(|_| self.uniform()).sum::<f64>() - 6.0
    }
}

/// Per-code weights with a periodic DN error of 3% and 1% random error, normalized like
/// a flattened histogram: the first `codes - 1` weights sum to just under `codes - 1`,
/// the last is 1, so the top LUT entry stays below 2^23.
pub fn dn_error_weights(rng: &mut Rng, codes: usize) -> Vec<Weight> {
    let phase = rng.uniform() * std::f64::consts::TAU;
    let raw: Vec<f64> = (0..codes - 1).map(|k| 1.0 + 0.03 * ((k as f64) * 0.7 + phase).sin() + 0.01 * rng.normal()).collect();
    let scale = (codes - 1) as f64 / raw.iter().sum::<f64>() * (1.0 - 1e-9);
    let mut w: Vec<Weight> = raw.iter().map(|x| Weight::from_num(x * scale)).collect();
    w.push(Weight::from_num(1));
    w
}

/// Frames of codes, row-major: frame `f` (state `f mod states`) sees
/// `300 + 800 state + 5 x + 3 y` DN plus noise of `sigma_dn`; in every frame one code is
/// planted above the top code, one at 65535 and one at the top code.
pub fn synthetic_frames(rng: &mut Rng, g: Geometry, frames: u32, sigma_dn: f64, codes: usize) -> Vec<Vec<u16>> {
    let (w, h) = (g.width() as usize, g.height() as usize);
    let top = (codes - 1) as f64;
    (0..frames as usize)
        .map(|f| {
            let state = f % g.states() as usize;
            let mut frame: Vec<u16> = (0..w * h)
                .map(|i| {
                    let level = 300.0 + 800.0 * state as f64 + 5.0 * (i % w) as f64 + 3.0 * (i / w) as f64;
                    (level + sigma_dn * rng.normal()).round().clamp(0.0, top) as u16
                })
                .collect();
            frame[(f * 7) % (w * h)] = codes as u16 + 100;
            frame[(f * 13 + 1) % (w * h)] = u16::MAX;
            frame[(f * 17 + 2) % (w * h)] = (codes - 1) as u16;
            frame
        })
        .collect()
}
