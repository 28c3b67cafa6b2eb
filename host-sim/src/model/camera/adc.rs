//! A pipelined ADC with stage mismatch: where DN error comes from (de Wijn 2018,
//! section 4).
//!
//! A pipelined ADC resolves a few bits per stage, most significant first; each stage
//! subtracts its DAC level from the residue and passes it on amplified. A DAC level that
//! is off by `e` LSB (capacitor mismatch) shifts every code boundary that uses that
//! digit by `e`. With stage `s` resolving digit `d_s(k)` of code `k`, the transition level
//! from code `k - 1` to code `k` is, in ideal DN,
//!
//! ```text
//! T_k = k - 1/2 + E(k),    E(k) = sum_s e_{s, d_s(k)},   e_{s,0} = 0,
//! ```
//!
//! so an ideal ADC (all `e = 0`) reads analog value `v` as the nearest integer. Code `k`
//! is `w_k = T_{k+1} - T_k = 1 + E(k+1) - E(k)` DN wide: periodic DN error with the
//! period of each stage's digit, large jumps at the major (high-stage) transitions,
//! exactly the pattern of the paper's Fig. 3. The level errors `e_{s,d}` are drawn once
//! from N(0, `stage_error_lsb[s]`) with the ADC's seed. Code 0 takes everything below
//! `T_1`, the top code everything from `T_{2^B-1}` up (saturation).

use rand::{rngs::StdRng, SeedableRng};
use rand_distr::{Distribution, Normal};

use super::config::{AdcConfig, ConfigError};

/// One ADC's transfer: its transition levels.
#[derive(Debug, Clone, PartialEq)]
pub struct AdcTransfer {
    /// `levels[k]` = T_k for k = 1..codes-1; `levels[0]` is unused (-inf).
    levels: Vec<f64>,
}

impl AdcTransfer {
    /// The ADC number `index` of a camera, drawn from `config.model` with seed
    /// `config.seed + index`.
    pub fn from_model(config: &AdcConfig, bits: u32, index: usize) -> Result<Self, ConfigError> {
        match config.model {
            super::config::AdcModel::Stages => Self::from_config(config, bits, index),
            super::config::AdcModel::Nested => Self::from_widths(&config.nested.widths(bits, adc_seed(config.seed, index))),
        }
    }

    /// The ADC number `index` of a camera: stage errors drawn from `config` with seed
    /// `config.seed + index`. Fails if a code would have zero or negative width.
    pub fn from_config(config: &AdcConfig, bits: u32, index: usize) -> Result<Self, ConfigError> {
        let mut rng = StdRng::seed_from_u64(adc_seed(config.seed, index));
        let mut stage_errors = Vec::new();
        for (&b, &sigma) in config.stage_bits.iter().zip(&config.stage_error_lsb) {
            let normal = Normal::new(0.0, sigma).map_err(|_| ConfigError::StageErrors)?;
            let mut e: Vec<f64> = (0..1usize << b).map(|_| normal.sample(&mut rng)).collect();
            e[0] = 0.0;
            stage_errors.push(e);
        }
        let codes = 1usize << bits;
        let levels = super::architecture::pipelined_levels(bits, &config.stage_bits, &stage_errors, &[]);
        let adc = AdcTransfer { levels };
        if let Some(k) = (1..codes - 1).find(|&k| adc.levels[k + 1] <= adc.levels[k]) {
            return Err(ConfigError::NoWidth { adc: index, code: k, stage_error_lsb: config.stage_error_lsb.clone() });
        }
        Ok(adc)
    }

    /// An ideal ADC of `bits` bits: `T_k = k - 1/2`.
    pub fn ideal(bits: u32) -> Self {
        AdcTransfer { levels: super::architecture::Architecture::Ideal {}.levels(bits) }
    }

    /// An ADC whose code k is `widths[k]` DN wide (codes 0 and top: open ends, their
    /// widths unused): `T_k = 1/2 + sum_{0<j<k} w_j`, so unit widths are the ideal ADC.
    pub fn from_widths(widths: &[f64]) -> Result<Self, ConfigError> {
        let levels: Vec<f64> = (1..widths.len()).scan(0.5, |t, k| {
            let level = *t;
            *t += widths[k];
            Some(level)
        }).collect();
        Self::from_levels(&levels)
    }

    /// An ADC with the given transition levels `T_1..T_{codes-1}` (strictly increasing).
    pub fn from_levels(levels_from_1: &[f64]) -> Result<Self, ConfigError> {
        if levels_from_1.windows(2).any(|p| p[1] <= p[0]) {
            return Err(ConfigError::Levels);
        }
        Self::from_monotone_levels(levels_from_1)
    }

    /// An ADC with the given transition levels `T_1..T_{codes-1}`, non-decreasing and
    /// finite: equal neighbours `T_k = T_{k+1}` make code k a missing code (no input
    /// reaches it), as a fitted architecture may ([`super::architecture`]).
    pub fn from_monotone_levels(levels_from_1: &[f64]) -> Result<Self, ConfigError> {
        if !(levels_from_1.len() + 1).is_power_of_two() || levels_from_1.iter().any(|t| !t.is_finite()) || levels_from_1.windows(2).any(|p| p[1] < p[0]) {
            return Err(ConfigError::Levels);
        }
        let mut levels = vec![f64::NEG_INFINITY];
        levels.extend_from_slice(levels_from_1);
        Ok(AdcTransfer { levels })
    }

    /// The ADC of a fitted `architecture` ([`super::architecture`]) of `bits` bits.
    pub fn from_architecture(architecture: &super::architecture::Architecture, bits: u32) -> Result<Self, ConfigError> {
        Self::from_monotone_levels(&architecture.levels(bits)[1..])
    }

    /// Number of codes.
    pub fn codes(&self) -> usize {
        self.levels.len()
    }

    /// Transition level T_k (k >= 1) into code k, DN; -inf for k = 0, +inf for k = codes.
    pub fn level(&self, k: usize) -> f64 {
        self.levels.get(k).copied().unwrap_or(f64::INFINITY)
    }

    /// The code of analog value `v` DN: the largest k with T_k <= v.
    #[inline]
    pub fn code(&self, v: f64) -> u16 {
        let top = self.levels.len() - 1;
        if v.is_nan() {
            return 0;
        }
        // Start at the ideal code and walk: |E(k)| is a few LSB at most. The start is
        // floor(v + 1/2) clamped to the codes; truncation gives the same after the clamp
        // (it differs from floor only below 0) without a libm call per pixel.
        let mut k = ((v + 0.5) as i64).clamp(0, top as i64) as usize;
        // One step either way as arithmetic, not a branch: the comparisons go either way
        // pixel by pixel (a code's DN error moves its edges by a few percent of a code),
        // where a branch on them was mispredicted. `levels[0]` is -inf: never above `v`.
        // Then the walk ([`Self::walk`]) finishes what one step could not (an edge a code or more away),
        // a branch that almost never goes. Same codes (a simulated set byte for byte);
        // `dncal stream --frames 64` at 0.945 of its wall time (farm-bench, 6 pairs).
        // Both neighbours' edges are loaded at once (the step up read the edge the step
        // down had chosen, a second load after the first): with monotone edges at most
        // one of the two steps applies, so the code is the same.
        let (below, above) = (self.levels[k] > v, k < top && self.levels[(k + 1).min(top)] <= v);
        k = k - usize::from(below) + usize::from(above);
        self.walk(k, v)
    }

    /// The code of analog value `v` DN walked to from code `k`: down while `T_k > v`, up
    /// while `T_{k+1} <= v` (a code from a guess a few codes off).
    #[inline]
    pub fn walk(&self, mut k: usize, v: f64) -> u16 {
        let top = self.levels.len() - 1;
        k = k.min(top);
        while k > 0 && self.levels[k] > v {
            k -= 1;
        }
        while k < top && self.levels[k + 1] <= v {
            k += 1;
        }
        k as u16
    }

    /// The transition levels `T_0..T_{codes-1}` (`T_0` = -inf), DN: what a sampler
    /// searches.
    pub fn edges(&self) -> &[f64] {
        &self.levels
    }

    /// Code widths w_k = T_{k+1} - T_k for the inner codes 1..codes-2, DN. Code 0 and the
    /// top code are open-ended and reported as 1.
    pub fn widths(&self) -> Vec<f64> {
        let n = self.levels.len();
        (0..n).map(|k| if k == 0 || k == n - 1 { 1.0 } else { self.levels[k + 1] - self.levels[k] }).collect()
    }

    /// The true code widths as LUT weights: the open end codes set to 1 and the inner
    /// codes scaled so that all weights sum to the number of codes, the normalization the
    /// flattening of a measured histogram applies. A perfect calibration.
    pub fn normalized_widths(&self) -> Vec<f64> {
        let mut w = self.widths();
        normalize_inner(&mut w);
        w
    }

    /// The center of each code, (T_k + T_{k+1})/2, with the open end codes centered one
    /// width (1 DN) beyond their finite boundary's half: k for an ideal ADC.
    pub fn centers(&self) -> Vec<f64> {
        let n = self.levels.len();
        (0..n)
            .map(|k| match k {
                0 => self.levels[1] - 0.5,
                k if k == n - 1 => self.levels[n - 1] + 0.5,
                k => 0.5 * (self.levels[k] + self.levels[k + 1]),
            })
            .collect()
    }
}

/// The seed of ADC `index` of a camera whose ADCs have seed `seed`.
fn adc_seed(seed: u64, index: usize) -> u64 {
    seed.wrapping_add(index as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
}

/// Re-exported from its home, where the model and the analyses both reach it.
pub use crate::infra::dims::normalize_inner;

#[cfg(test)]
mod widths_tests {
    use super::*;

    #[test]
    fn unit_widths_are_the_ideal_adc_and_widths_round_trip() {
        assert_eq!(AdcTransfer::from_widths(&[1.0; 16]).unwrap(), AdcTransfer::ideal(4));
        let w: Vec<f64> = (0..16).map(|k| 1.0 + 0.05 * ((k * 7 % 5) as f64 - 2.0)).collect();
        let adc = AdcTransfer::from_widths(&w).unwrap();
        let back = adc.widths();
        for k in 1..15 {
            assert!((back[k] - w[k]).abs() < 1e-12, "code {k}");
        }
        assert!(AdcTransfer::from_widths(&[1.0, 1.0, -1.0, 1.0]).is_err());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ideal_adc_rounds_to_nearest() {
        let adc = AdcTransfer::ideal(4);
        assert_eq!(adc.code(-3.0), 0);
        assert_eq!(adc.code(0.49), 0);
        assert_eq!(adc.code(0.5), 1);
        assert_eq!(adc.code(7.2), 7);
        assert_eq!(adc.code(99.0), 15);
        assert_eq!(adc.centers()[5], 5.0);
    }

    #[test]
    fn stage_errors_shift_levels_by_digit() {
        let cfg = AdcConfig { stage_bits: vec![2, 2], stage_error_lsb: vec![0.1, 0.05], seed: 7, ..AdcConfig::stages() };
        let adc = AdcTransfer::from_config(&cfg, 4, 0).unwrap();
        // E(k) = e_hi[k / 4] + e_lo[k % 4] with e_hi[0] = e_lo[0] = 0, so every level
        // error is the sum of the errors of its high-digit-only and low-digit-only codes.
        let e = |k: usize| adc.level(k) - (k as f64 - 0.5);
        for k in 5..16 {
            if k % 4 != 0 {
                assert!((e(k) - e(4 * (k / 4)) - e(k % 4)).abs() < 1e-12, "code {k}");
            }
        }
        assert!(e(1) != 0.0 && e(4) != 0.0);
        // Widths sum to the span of the levels.
        let w = adc.widths();
        let inner: f64 = w[1..15].iter().sum();
        assert!((inner - (adc.level(15) - adc.level(1))).abs() < 1e-12);
    }

    #[test]
    fn code_inverts_levels() {
        let adc = AdcTransfer::from_config(&AdcConfig::default(), 12, 3).unwrap();
        for k in 1..4095 {
            assert_eq!(adc.code(adc.level(k)), k as u16);
            assert_eq!(adc.code(adc.level(k) - 1e-9), (k - 1) as u16);
        }
    }

    proptest::proptest! {
        /// The code of any value is the largest k with T_k <= v, as a plain scan finds it:
        /// edges up to three codes from their ideal place (past the one step the search
        /// takes as arithmetic), missing codes (equal neighbours), values far outside.
        #[test]
        fn the_code_is_the_largest_level_below_the_value(
            shifts in proptest::collection::vec(-3.0f64..3.0, 15),
            missing in proptest::collection::vec(proptest::bool::weighted(0.1), 15),
            values in proptest::collection::vec(-8.0f64..24.0, 1..200),
        ) {
            // Non-decreasing levels from shifted ideal ones (a running maximum), with
            // some equal to their neighbour below.
            let mut levels: Vec<f64> = Vec::new();
            for k in 0..15 {
                let ideal = k as f64 + 0.5 + shifts[k];
                let t = match levels.last() {
                    Some(&prev) if missing[k] => prev,
                    Some(&prev) => ideal.max(prev),
                    None => ideal,
                };
                levels.push(t);
            }
            let adc = AdcTransfer::from_monotone_levels(&levels).unwrap();
            for &v in &values {
                let naive = (1..16).filter(|&k| levels[k - 1] <= v).max().unwrap_or(0) as u16;
                proptest::prop_assert_eq!(adc.code(v), naive, "v = {}", v);
            }
        }
    }

    #[test]
    fn too_large_errors_are_rejected() {
        let cfg = AdcConfig { stage_bits: vec![2, 2], stage_error_lsb: vec![3.0, 3.0], seed: 1, ..AdcConfig::stages() };
        assert!(AdcTransfer::from_config(&cfg, 4, 0).is_err());
    }
}
