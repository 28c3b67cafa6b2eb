//! The built-in camera's ADCs (`[adc] model = "nested"`, the default since issue 57): a
//! nested 1-bit pipeline whose code widths have the statistics of the real K-Cor ADCs
//! (`docs/model.md`, "The nested pipeline"), not their values.
//!
//! The real ADCs' DN error ([`crate::analyses::real_adcs`]) repeats every 128 or 256 codes:
//! the cumulative offsets ramp up over a sub-range and snap back in one or a few narrow
//! codes, at positions near, not at, the binary boundaries, independently in each of a
//! camera's four ADCs. A pipeline of 1-bit stages whose residue gains are off does that:
//! stage `l` (1-4) splits each 256-code block into sub-ranges of `256 / 2^l` codes, and a
//! gain error makes the transitions within a sub-range drift by up to its **drop** `d_l`
//! DN and snap back at its end. The offset of transition `T_k = k - 1/2 + o(k)` is
//!
//! ```text
//! o(k) = sum_l saw_l(k) + step(k) + block offset + noise
//! ```
//!
//! `saw_l` rising linearly by `d_l` over each sub-range of stage `l` (bounded by the
//! boundaries of stages `<= l`), falling back to 0 over the last `s` codes (`s` = 1, or
//! 2-4 with [`NestedPipeline::split_probability`]); `step` a DAC step of the first stage
//! (high over the first half of a block after a Hann rise, 0 over the second half). Each
//! boundary `16 j` of a block (j = 1..15) is moved by a jitter fixed per ADC (the same for
//! `j` and `j + 8`: one circuit serves both halves) and a small wobble per block, and each
//! ADC's pattern starts at a phase of its own, uniform over a block: the real ADCs' narrow
//! codes sit where no binary boundary explains them and their patterns are independent
//! (mean correlation 0.004 between a camera's ADCs), where the same boundaries in every ADC
//! made the model's ADCs correlate by 0.4. The
//! drops are log-normal: per ADC, per stage, per block and per sub-range. Widths
//! `1 + o(k+1) - o(k)` are kept above [`NestedPipeline::min_width`] and normalized as LUT
//! weights are ([`crate::infra::dims::normalize_inner`]).
//!
//! The defaults were fitted (numpy, 60-120 ADCs a setting) to the median over the twelve
//! shared K-Cor ADCs of the statistics of [`crate::analyses::width_statistics`]; the
//! tables themselves (research-only licence) are not in the model. The test
//! `kcor_luts::the_built_in_adcs_have_the_real_adcs_statistics` holds the built-in
//! camera's four ADCs to those medians.

use rand::{rngs::StdRng, Rng, SeedableRng};
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

/// Codes of one block: the pattern's period.
pub const BLOCK: usize = 256;
/// Codes between neighbouring boundaries of the deepest stage.
const SPACING: usize = 16;
/// The stage whose boundary is at `16 j` of a block (0: the block's own edge).
const STAGE_OF_BOUNDARY: [usize; 16] = [0, 4, 3, 4, 2, 4, 3, 4, 1, 4, 3, 4, 2, 4, 3, 4];
/// The largest jitter and wobble [`NestedPipeline::check`] allows, codes: boundaries 16
/// codes apart then stay at least 5 apart, more than the widest snap-back (4 codes).
const MAX_JITTER: u32 = 4;
const MAX_WOBBLE: f64 = 1.5;
/// The widest snap-back, codes.
const MAX_SPLIT: u64 = 4;
/// The largest log-normal sigma and the largest size in DN [`NestedPipeline::check`]
/// allows: beyond them a draw can overflow (`exp(500 z)`) or round the levels together.
const MAX_SPREAD: f64 = 3.0;
const MAX_DN: f64 = 10.0;

/// A standard normal draw.
fn gauss(rng: &mut StdRng) -> f64 {
    StandardNormal.sample(rng)
}

/// The nested pipeline's parameters (module documentation). Drops and offsets in DN (LSB).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NestedPipeline {
    /// Median drop of the first stage, DN.
    pub drop_dn: f64,
    /// Log-normal sigma of an ADC's drop scale about `drop_dn`.
    pub drop_adc_spread: f64,
    /// Each stage's median drop relative to the first's (stages 1-4, sub-ranges of
    /// 128/64/32/16 codes).
    pub stage_drop_ratio: [f64; 4],
    /// Log-normal sigma of a stage's drop about its median, per ADC.
    pub stage_spread: f64,
    /// Log-normal sigma of a stage's drops from block to block.
    pub block_spread: f64,
    /// Log-normal sigma of each sub-range's drop.
    pub drop_spread: f64,
    /// Largest drop of one sub-range, DN.
    pub max_drop_dn: f64,
    /// Per stage 1-4, the largest jitter of its boundaries, codes (uniform integers in
    /// `[-J, J]`, fixed per ADC); at most 4.
    pub boundary_jitter_codes: [u32; 4],
    /// Sigma of a boundary's move from block to block, codes (clipped at 1.5); at most 0.5.
    pub boundary_wobble_codes: f64,
    /// Probability that a snap-back spreads over 2-4 codes instead of one.
    pub split_probability: f64,
    /// The first stage's DAC step: `dac_step_ratio x` the ADC's drop scale `x |N(0,1)|`, DN.
    pub dac_step_ratio: f64,
    /// Codes of the step's Hann rise at the block's start.
    pub dac_rise_codes: f64,
    /// Sigma of a block's offset (the top stage's DAC levels), DN.
    pub block_offset_dn: f64,
    /// Sigma of each transition's own offset, DN (median over ADCs).
    pub level_noise_dn: f64,
    /// Log-normal sigma of `level_noise_dn` between ADCs.
    pub level_noise_spread: f64,
    /// Smallest code width before normalization, DN.
    pub min_width: f64,
    /// Start each ADC's pattern at a random phase (uniform over a block); false: at the
    /// binary boundaries.
    pub random_phase: bool,
}

impl Default for NestedPipeline {
    fn default() -> Self {
        NestedPipeline {
            drop_dn: 0.15,
            drop_adc_spread: 0.22,
            stage_drop_ratio: [1.0, 0.569, 0.6, 0.163],
            stage_spread: 0.331,
            block_spread: 0.234,
            drop_spread: 0.15,
            max_drop_dn: 0.6,
            boundary_jitter_codes: [4, 3, 2, 0],
            boundary_wobble_codes: 0.284,
            split_probability: 0.255,
            dac_step_ratio: 0.276,
            dac_rise_codes: 10.0,
            block_offset_dn: 0.05,
            level_noise_dn: 0.0022,
            level_noise_spread: 0.3,
            min_width: 0.3,
            random_phase: true,
        }
    }
}

/// What is wrong with a nested pipeline's parameters (a [`super::ConfigError`] names the
/// table).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum NestedError {
    /// Too few bits for one block.
    #[error("needs bits >= 8 (its pattern repeats every 256 codes); give model = \"stages\" for fewer bits")]
    Bits,
    /// A parameter out of range.
    #[error("{field} must be finite, non-negative and at most 3 for a log-normal sigma, 10 for a size in DN or a ratio, 0.5 for the wobble, 256 for the rise")]
    OutOfRange {
        /// The field.
        field: &'static str,
    },
    /// Jitter or wobble that would let boundaries cross.
    #[error("boundary_jitter_codes at most 4 and boundary_wobble_codes at most 0.5 (boundaries 16 codes apart must not cross)")]
    Boundaries,
    /// A probability or width outside its range.
    #[error("split_probability must be in [0, 1] and min_width in (0, 1)")]
    Range,
}

impl NestedPipeline {
    /// Checks the parameters for a `bits`-bit ADC.
    pub fn check(&self, bits: u32) -> Result<(), NestedError> {
        if bits < BLOCK.trailing_zeros() {
            return Err(NestedError::Bits);
        }
        // (field, value, largest allowed)
        let fields = [
            ("drop_dn", self.drop_dn, MAX_DN),
            ("drop_adc_spread", self.drop_adc_spread, MAX_SPREAD),
            ("stage_spread", self.stage_spread, MAX_SPREAD),
            ("block_spread", self.block_spread, MAX_SPREAD),
            ("drop_spread", self.drop_spread, MAX_SPREAD),
            ("max_drop_dn", self.max_drop_dn, MAX_DN),
            ("boundary_wobble_codes", self.boundary_wobble_codes, 0.5),
            ("dac_step_ratio", self.dac_step_ratio, MAX_DN),
            ("dac_rise_codes", self.dac_rise_codes, BLOCK as f64),
            ("block_offset_dn", self.block_offset_dn, MAX_DN),
            ("level_noise_dn", self.level_noise_dn, MAX_DN),
            ("level_noise_spread", self.level_noise_spread, MAX_SPREAD),
        ];
        let ratios = self.stage_drop_ratio.iter().map(|&r| ("stage_drop_ratio", r, MAX_DN));
        if let Some((field, _, _)) = fields.into_iter().chain(ratios).find(|(_, v, max)| !(v.is_finite() && *v >= 0.0 && v <= max)) {
            return Err(NestedError::OutOfRange { field });
        }
        if self.boundary_jitter_codes.iter().any(|&j| j > MAX_JITTER) || self.boundary_wobble_codes > 0.5 {
            return Err(NestedError::Boundaries);
        }
        if !((0.0..=1.0).contains(&self.split_probability) && self.min_width > 0.0 && self.min_width < 1.0) {
            return Err(NestedError::Range);
        }
        Ok(())
    }

    /// The code widths of one ADC of `bits` bits (>= 8, [`NestedPipeline::check`]ed),
    /// drawn with `seed`: `2^bits` values, the open end codes 1, the inner codes of mean 1.
    pub fn widths(&self, bits: u32, seed: u64) -> Vec<f64> {
        let codes = 1usize << bits;
        let mut rng = StdRng::seed_from_u64(seed);
        let mut normal = || gauss(&mut rng);
        let scale = self.drop_dn * (self.drop_adc_spread * normal()).exp();
        let stage_drop: Vec<f64> = self.stage_drop_ratio.iter().map(|r| scale * r * (self.stage_spread * normal()).exp()).collect();
        let step = self.dac_step_ratio * scale * normal().abs();
        let noise = self.level_noise_dn * (self.level_noise_spread * normal()).exp();
        let mut jitter = [0.0f64; 16];
        for j in 1..16 {
            // j and j + 8 share their circuit below the first stage.
            if j > 8 {
                jitter[j] = jitter[j - 8];
                continue;
            }
            let max = i64::from(self.boundary_jitter_codes[STAGE_OF_BOUNDARY[j] - 1]);
            jitter[j] = rng.random_range(-max..=max) as f64;
        }
        let phase = if self.random_phase { rng.random_range(0..BLOCK) } else { 0 };
        // o[k], the offset of transition k - phase, over one block more than the codes.
        let mut o = vec![0.0f64; codes + BLOCK];
        for block in 0..o.len() / BLOCK {
            let base = (block * BLOCK) as f64;
            let mut edge = [0.0f64; 17];
            for (j, e) in edge.iter_mut().enumerate() {
                let wobble = if (1..16).contains(&j) { (self.boundary_wobble_codes * gauss(&mut rng)).clamp(-MAX_WOBBLE, MAX_WOBBLE) } else { 0.0 };
                *e = base + (j * SPACING) as f64 + if j < 16 { jitter[j] } else { 0.0 } + wobble;
            }
            for (stage, &median) in (1..=4).zip(&stage_drop) {
                let block_scale = (self.block_spread * gauss(&mut rng)).exp();
                let bounds: Vec<f64> = (0..=16).filter(|&j| j == 16 || STAGE_OF_BOUNDARY[j] <= stage).map(|j| edge[j]).collect();
                for pair in bounds.windows(2) {
                    let (a, z) = (pair[0], pair[1]);
                    let d = (median * block_scale * (self.drop_spread * gauss(&mut rng)).exp()).min(self.max_drop_dn);
                    let split = if rng.random::<f64>() < self.split_probability { rng.random_range(2..=MAX_SPLIT) } else { 1 } as f64;
                    for (k, ok) in o.iter_mut().enumerate().take(z.ceil() as usize).skip(a.ceil() as usize) {
                        let x = k as f64;
                        *ok += if x < z - split { d * (x - a) / (z - split - a).max(1.0) } else { d * (z - x) / split };
                    }
                }
            }
            let offset = self.block_offset_dn * gauss(&mut rng);
            let mid = base + (BLOCK / 2) as f64 + jitter[8];
            for (k, ok) in o.iter_mut().enumerate().skip(block * BLOCK).take(BLOCK) {
                let x = k as f64;
                let rise = ((x - base) / self.dac_rise_codes.max(f64::MIN_POSITIVE)).clamp(0.0, 1.0);
                *ok += offset + if x < mid { step * (0.5 - 0.5 * (std::f64::consts::PI * rise).cos()) } else { 0.0 };
            }
        }
        for ok in o.iter_mut() {
            *ok += noise * gauss(&mut rng);
        }
        let o = &o[phase..phase + codes + 1];
        let mut w: Vec<f64> = (0..codes).map(|k| if k == 0 || k == codes - 1 { 1.0 } else { (1.0 + o[k + 1] - o[k]).max(self.min_width) }).collect();
        crate::infra::dims::normalize_inner(&mut w);
        w
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// With every spread, jitter, split, step, offset and noise off, each stage's saw has
    /// the closed form: a stage-l sub-range of `L = 256 / 2^l` codes rises by `d_l` over
    /// its first `L - 1` codes (`d_l / (L - 1)` each) and its last code is `d_l` narrow.
    #[test]
    fn without_spread_the_widths_are_the_four_saws() {
        let drop = [0.2, 0.1, 0.08, 0.03];
        let p = NestedPipeline {
            drop_adc_spread: 0.0,
            stage_drop_ratio: [1.0, 0.5, 0.4, 0.15],
            stage_spread: 0.0,
            block_spread: 0.0,
            drop_spread: 0.0,
            boundary_jitter_codes: [0; 4],
            boundary_wobble_codes: 0.0,
            split_probability: 0.0,
            dac_step_ratio: 0.0,
            block_offset_dn: 0.0,
            level_noise_dn: 0.0,
            min_width: 0.01,
            random_phase: false,
            ..NestedPipeline::default()
        };
        let p = NestedPipeline { drop_dn: drop[0], ..p };
        let w = p.widths(10, 3);
        let raw: Vec<f64> = (0..1024)
            .map(|k| {
                if k == 0 || k == 1023 {
                    return 1.0;
                }
                1.0 + (1..=4usize)
                    .map(|l| {
                        let len = BLOCK >> l;
                        if (k + 1) % len == 0 { -drop[l - 1] } else { drop[l - 1] / (len - 1) as f64 }
                    })
                    .sum::<f64>()
            })
            .collect();
        let inner: f64 = raw[1..1023].iter().sum();
        for k in 1..1023 {
            let want = raw[k] * 1022.0 / inner;
            assert!((w[k] - want).abs() < 1e-12, "code {k}: {} against {want}", w[k]);
        }
        assert_eq!((w[0], w[1023]), (1.0, 1.0));
    }

    /// The same seed is the same ADC; another seed another one; the check refuses what
    /// would let boundaries cross or a block not fit.
    #[test]
    fn seeds_and_checks() {
        let p = NestedPipeline::default();
        assert_eq!(p.check(12), Ok(()));
        assert_eq!(p.widths(12, 9), p.widths(12, 9));
        assert_ne!(p.widths(12, 9), p.widths(12, 10));
        assert_eq!(p.check(7), Err(NestedError::Bits));
        assert_eq!(NestedPipeline { boundary_jitter_codes: [5, 0, 0, 0], ..p.clone() }.check(12), Err(NestedError::Boundaries));
        assert_eq!(NestedPipeline { drop_dn: f64::NAN, ..p.clone() }.check(12), Err(NestedError::OutOfRange { field: "drop_dn" }));
        assert_eq!(NestedPipeline { level_noise_spread: 500.0, ..p.clone() }.check(12), Err(NestedError::OutOfRange { field: "level_noise_spread" }));
        // At every bound the widths are finite and positive.
        let edge = NestedPipeline { drop_dn: 10.0, drop_adc_spread: 3.0, stage_spread: 3.0, block_spread: 3.0, drop_spread: 3.0, max_drop_dn: 10.0, dac_step_ratio: 10.0, block_offset_dn: 10.0, level_noise_dn: 10.0, level_noise_spread: 3.0, stage_drop_ratio: [10.0; 4], ..p.clone() };
        assert_eq!(edge.check(12), Ok(()));
        for seed in 0..20 {
            assert!(edge.widths(12, seed).iter().all(|x| x.is_finite() && *x > 0.0), "seed {seed}");
        }
        assert_eq!(NestedPipeline { min_width: 1.0, ..p }.check(12), Err(NestedError::Range));
        let w = NestedPipeline::default().widths(16, 1);
        assert_eq!(w.len(), 65536);
        assert!(w.iter().all(|x| x.is_finite() && *x > 0.0));
    }
}
