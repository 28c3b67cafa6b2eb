//! ADC architectures a measurement can be fitted with (`adc.architecture` in the camera
//! model, one entry per ADC): the transition levels of a **binary-weighted SAR** with
//! capacitor-weight errors, or of a **pipelined (sub-ranging) ADC** with a DAC-level
//! error per stage and digit and an inter-stage gain error per first-stage sub-range.
//! `dncal diagnose` writes them (`docs/diagnose.md`); `dncal simulate` reads them.
//!
//! Levels are in ideal DN of the ADC's input; an ideal ADC reads `v` as the nearest
//! integer, `T_k = k - 1/2`. Unlike the drawn stage errors of [`super::adc`], a fitted
//! architecture may leave a code **missing** (no input reaches it): the levels are then
//! non-decreasing, `T_k = T_{k+1}`, and the code never comes out.

use serde::{Deserialize, Serialize};

/// One ADC's architecture.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum Architecture {
    /// `T_k = k - 1/2`. A struct variant without fields, not a unit one: serde reads an
    /// internally tagged unit variant without looking at the rest of its table, so
    /// `deny_unknown_fields` did not hold for it and `kind = "ideal"` beside
    /// `weight_error_lsb = [1.0]` or a typo passed silently (issue 56); an empty struct
    /// refuses every key but `kind`.
    Ideal {},
    /// A binary-weighted successive-approximation ADC. Bit `b` (0 = LSB) weighs
    /// `W_b = 2^b + weight_error_lsb[b]` LSB; the conversion decides the bits from the
    /// top, setting bit `b` when `v >= P + W_b - 1/2` (`P`: the weights of the bits set
    /// above it). Code k then comes out for `v` in `[L_k, U_k)`: `L_k` the largest
    /// threshold of a set bit, `U_k` the smallest of an unset one, so code k is
    /// `max(0, U_k - L_k)` LSB wide: the code below a carry into bit `b` is
    /// `1 + e_b - sum_{j<b} e_j` wide, missing when that is not positive.
    Sar {
        /// Weight error of each bit, LSB first, LSB (one per bit).
        weight_error_lsb: Vec<f64>,
    },
    /// A pipelined or sub-ranging ADC, stages most significant first (as
    /// `adc.stage_bits`). The transition into code k is
    /// `k - 1/2 + sum_s offset_lsb[s][d_s(k)] + j (1 / (1 + g_d) - 1)`, with `d_s(k)`
    /// the stage-s digit, `d` the first stage's digit, `j` the value of the lower stages
    /// (LSB) and `g_d = subrange_gain_error[d]` the relative error of the gain with which
    /// sub-range `d`'s residue is passed on (a gain too high makes the sub-range's codes
    /// narrower and its top code wide; too low, its top codes missing). A transition a
    /// higher stage makes first wins: `T_k = min(T_k, T_{k+1})`. The lower stages'
    /// offsets are not divided by the gain (a second-order term).
    Pipelined {
        /// Bits per stage, most significant first; they sum to the bit depth.
        stage_bits: Vec<u32>,
        /// Per stage, the DAC-level error of each digit, LSB (`2^b` values; digit 0's is
        /// usually 0, the fit's reference).
        offset_lsb: Vec<Vec<f64>>,
        /// Per first-stage digit, the relative inter-stage gain error (empty: none).
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        subrange_gain_error: Vec<f64>,
    },
}

/// What is wrong with an architecture for a `bits`-bit ADC (a [`super::ConfigError`]
/// names the ADC).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ArchitectureError {
    /// A SAR's weight errors, one per bit.
    #[error("sar: weight_error_lsb needs one finite value per bit, each above -2^b (a bit's weight must be positive)")]
    SarWeights,
    /// A pipelined ADC's stages.
    #[error("pipelined: stage_bits must be positive and sum to the bit depth")]
    StageBits,
    /// A pipelined ADC's offsets.
    #[error("pipelined: offset_lsb needs one list of 2^b finite values per stage")]
    Offsets,
    /// A pipelined ADC's gains.
    #[error("pipelined: subrange_gain_error needs none or one finite value above -1 per first-stage digit")]
    Gains,
}

/// The transition level into each code of a pipelined layout before the higher stages'
/// precedence (`T_k` of [`Architecture::Pipelined`] without the `min`), `levels[0]`
/// unused: the one home of `E(k)` that the drawn stage errors of [`super::adc`] use too.
pub(crate) fn pipelined_levels(bits: u32, stage_bits: &[u32], offset_lsb: &[Vec<f64>], subrange_gain_error: &[f64]) -> Vec<f64> {
    let codes = 1usize << bits;
    let low = bits - stage_bits.first().copied().unwrap_or(0);
    let mut levels = vec![f64::NEG_INFINITY; codes];
    for (k, level) in levels.iter_mut().enumerate().skip(1) {
        let mut shift = bits;
        let mut error = 0.0;
        for (&b, e) in stage_bits.iter().zip(offset_lsb) {
            shift -= b;
            error += e[(k >> shift) & ((1 << b) - 1)];
        }
        if let Some(g) = subrange_gain_error.get(k >> low) {
            let j = (k & ((1usize << low) - 1)) as f64;
            error += j * (1.0 / (1.0 + g) - 1.0);
        }
        *level = k as f64 - 0.5 + error;
    }
    levels
}

impl Architecture {
    /// Checks the shape and values for a `bits`-bit ADC.
    pub fn check(&self, bits: u32) -> Result<(), ArchitectureError> {
        match self {
            Architecture::Ideal {} => Ok(()),
            Architecture::Sar { weight_error_lsb: e } => {
                let ok = e.len() == bits as usize && e.iter().enumerate().all(|(b, x)| x.is_finite() && (1u64 << b) as f64 + x > 0.0);
                if ok { Ok(()) } else { Err(ArchitectureError::SarWeights) }
            }
            Architecture::Pipelined { stage_bits, offset_lsb, subrange_gain_error } => {
                let sum: u64 = stage_bits.iter().map(|&b| u64::from(b)).sum();
                if sum != u64::from(bits) || stage_bits.contains(&0) {
                    return Err(ArchitectureError::StageBits);
                }
                if offset_lsb.len() != stage_bits.len() || offset_lsb.iter().zip(stage_bits).any(|(o, &b)| o.len() != 1 << b || o.iter().any(|x| !x.is_finite())) {
                    return Err(ArchitectureError::Offsets);
                }
                if !subrange_gain_error.is_empty() && (subrange_gain_error.len() != 1 << stage_bits[0] || subrange_gain_error.iter().any(|g| !(g.is_finite() && *g > -1.0))) {
                    return Err(ArchitectureError::Gains);
                }
                Ok(())
            }
        }
    }

    /// The transition levels `T_0..T_{2^bits - 1}` (`T_0 = -inf`), non-decreasing; equal
    /// neighbours mark a missing code. Call [`Architecture::check`] first.
    pub fn levels(&self, bits: u32) -> Vec<f64> {
        let codes = 1usize << bits;
        match self {
            Architecture::Ideal {} => (0..codes).map(|k| if k == 0 { f64::NEG_INFINITY } else { k as f64 - 0.5 }).collect(),
            Architecture::Sar { weight_error_lsb } => {
                let w: Vec<f64> = weight_error_lsb.iter().enumerate().map(|(b, e)| (1u64 << b) as f64 + e).collect();
                let mut levels = vec![f64::NEG_INFINITY; codes];
                let mut next = f64::INFINITY;
                for k in (1..codes).rev() {
                    let (mut set, mut lo, mut hi) = (0.0, f64::NEG_INFINITY, f64::INFINITY);
                    for b in (0..bits as usize).rev() {
                        let threshold = set + w[b] - 0.5;
                        if k >> b & 1 == 1 {
                            lo = lo.max(threshold);
                            set += w[b];
                        } else {
                            hi = hi.min(threshold);
                        }
                    }
                    // An empty region: the code never comes out; its level is the next one's.
                    levels[k] = if lo < hi { lo } else { next };
                    next = levels[k];
                }
                levels
            }
            Architecture::Pipelined { stage_bits, offset_lsb, subrange_gain_error } => {
                let mut levels = pipelined_levels(bits, stage_bits, offset_lsb, subrange_gain_error);
                for k in (1..codes - 1).rev() {
                    levels[k] = levels[k].min(levels[k + 1]);
                }
                levels
            }
        }
    }

    /// A short name: "ideal", "binary-weighted SAR", "pipelined 4+4+4 with sub-range gains".
    pub fn name(&self) -> String {
        match self {
            Architecture::Ideal {} => "ideal".into(),
            Architecture::Sar { .. } => "binary-weighted SAR".into(),
            Architecture::Pipelined { stage_bits, subrange_gain_error, .. } => {
                let layout: Vec<String> = stage_bits.iter().map(u32::to_string).collect();
                format!("pipelined {}{}", layout.join("+"), if subrange_gain_error.is_empty() { "" } else { " with sub-range gains" })
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The conversion itself, run on an input: the SAR's bit decisions from the top.
    fn sar_convert(w: &[f64], v: f64) -> usize {
        let (mut code, mut set) = (0usize, 0.0);
        for b in (0..w.len()).rev() {
            if v >= set + w[b] - 0.5 {
                code |= 1 << b;
                set += w[b];
            }
        }
        code
    }

    /// The levels of a SAR with large weight errors (bit 3 heavy, bit 5 light by more
    /// than the bits below it, bit 1 light) against the conversion run on a fine grid of
    /// inputs: every code comes out exactly where its levels say, and the codes the
    /// levels call missing never do.
    #[test]
    fn sar_levels_are_the_conversions_regions() {
        let bits = 7u32;
        let e = vec![0.0, -0.4, 0.0, 1.7, 0.0, -2.6, 0.3];
        let arch = Architecture::Sar { weight_error_lsb: e.clone() };
        arch.check(bits).unwrap();
        let levels = arch.levels(bits);
        let adc = super::super::AdcTransfer::from_monotone_levels(&levels[1..]).unwrap();
        let w: Vec<f64> = e.iter().enumerate().map(|(b, x)| (1u64 << b) as f64 + x).collect();
        let mut seen = vec![0usize; 1 << bits];
        let step = 1.0 / 1024.0;
        let mut v = -2.0;
        while v < 140.0 {
            let want = sar_convert(&w, v);
            assert_eq!(adc.code(v) as usize, want, "v = {v}");
            seen[want] += 1;
            v += step;
        }
        let widths = adc.widths();
        let mut missing = 0;
        for k in 1..(1 << bits) - 1 {
            // The grid's count of a code is its width in steps (to one step).
            assert!((seen[k] as f64 * step - widths[k]).abs() <= step + 1e-9, "code {k}: {} vs {}", seen[k] as f64 * step, widths[k]);
            missing += usize::from(widths[k] == 0.0);
        }
        // Bit 5 is 2.6 LSB light: the code below its carry is 1 - 2.6 - (-0.4 + 1.7) <= 0
        // wide, and so is the one below that.
        assert_eq!(widths[31], 0.0);
        assert!(missing >= 2, "{missing}");
        // Bit 3 is 1.7 heavy (less bit 1's -0.4): codes below its carries are 3.1 LSB wide.
        assert!((widths[7] - (1.0 + 1.7 + 0.4)).abs() < 1e-12, "{}", widths[7]);
    }

    #[test]
    fn an_ideal_sar_and_an_ideal_pipeline_are_the_ideal_adc() {
        let ideal = Architecture::Ideal {}.levels(8);
        assert_eq!(Architecture::Sar { weight_error_lsb: vec![0.0; 8] }.levels(8), ideal);
        let p = Architecture::Pipelined { stage_bits: vec![4, 4], offset_lsb: vec![vec![0.0; 16]; 2], subrange_gain_error: vec![0.0; 16] };
        p.check(8).unwrap();
        assert_eq!(p.levels(8), ideal);
    }

    /// A sub-range passed on with a gain 10% too high: its codes are 1/1.1 wide and its
    /// top code takes the rest; 10% too low: its top codes are missing.
    #[test]
    fn a_sub_range_gain_error_narrows_its_codes_or_drops_its_top() {
        let mut g = vec![0.0; 4];
        g[1] = 0.1;
        g[2] = -0.1;
        let p = Architecture::Pipelined { stage_bits: vec![2, 4], offset_lsb: vec![vec![0.0; 4], vec![0.0; 16]], subrange_gain_error: g };
        p.check(6).unwrap();
        let adc = super::super::AdcTransfer::from_monotone_levels(&p.levels(6)[1..]).unwrap();
        let w = adc.widths();
        for (k, w) in w.iter().enumerate().take(31).skip(16) {
            assert!((w - 1.0 / 1.1).abs() < 1e-12, "code {k}: {w}");
        }
        // Code 31 reaches from its transition to the next sub-range's (at 31.5 DN).
        assert!((w[31] - (31.5 - (16.0 - 0.5 + 15.0 / 1.1))).abs() < 1e-12);
        // Sub-range 2's codes are 1/0.9 wide; a transition beyond the next sub-range's
        // (31.5 + j/0.9 > 47.5 DN: j = 15) never comes out, and code 46 reaches to 47.5.
        let missing: Vec<usize> = (32..48).filter(|&k| w[k] == 0.0).collect();
        assert_eq!(missing, vec![47]);
        assert!((w[46] - (47.5 - (31.5 + 14.0 / 0.9))).abs() < 1e-12, "{}", w[46]);
    }

    #[test]
    fn shapes_and_values_are_checked() {
        assert_eq!(Architecture::Sar { weight_error_lsb: vec![0.0; 7] }.check(8), Err(ArchitectureError::SarWeights));
        assert_eq!(Architecture::Sar { weight_error_lsb: vec![-1.0, 0.0] }.check(2), Err(ArchitectureError::SarWeights));
        let p = |stage_bits: Vec<u32>, offset_lsb: Vec<Vec<f64>>, subrange_gain_error: Vec<f64>| Architecture::Pipelined { stage_bits, offset_lsb, subrange_gain_error }.check(4);
        assert_eq!(p(vec![2, 1], vec![vec![0.0; 4], vec![0.0; 2]], vec![]), Err(ArchitectureError::StageBits));
        assert_eq!(p(vec![2, 2], vec![vec![0.0; 4], vec![0.0; 3]], vec![]), Err(ArchitectureError::Offsets));
        assert_eq!(p(vec![2, 2], vec![vec![0.0; 4]; 2], vec![0.0, -1.0, 0.0, 0.0]), Err(ArchitectureError::Gains));
        assert_eq!(p(vec![2, 2], vec![vec![0.0; 4]; 2], vec![0.0; 4]), Ok(()));
    }

    /// The TOML a model file carries, read back.
    #[test]
    fn the_toml_form_round_trips() {
        #[derive(Serialize, Deserialize, PartialEq, Debug)]
        struct Holder {
            architecture: Vec<Architecture>,
        }
        let h = Holder {
            architecture: vec![
                Architecture::Sar { weight_error_lsb: vec![0.0, 0.5] },
                Architecture::Ideal {},
                Architecture::Pipelined { stage_bits: vec![1, 1], offset_lsb: vec![vec![0.0, 0.1], vec![0.0, -0.1]], subrange_gain_error: vec![] },
            ],
        };
        let text = toml::to_string(&h).unwrap();
        assert!(text.contains("kind = \"sar\"") && text.contains("kind = \"pipelined\""), "{text}");
        assert_eq!(toml::from_str::<Holder>(&text).unwrap(), h);
        let bad = "[[architecture]]\nkind = \"sar\"\nweight_error = [0.0]\n";
        assert!(toml::from_str::<Holder>(bad).is_err());
        // Issue 56: an ideal ADC's table took any other key and ignored it.
        for extra in ["weight_error_lsb = [1.0]", "foo = 1"] {
            let e = toml::from_str::<Holder>(&format!("[[architecture]]\nkind = \"ideal\"\n{extra}\n")).unwrap_err().to_string();
            let field = extra.split(' ').next().unwrap();
            assert!(e.contains(&format!("unknown field `{field}`")), "{extra}: {e}");
        }
        assert_eq!(toml::from_str::<Holder>("[[architecture]]\nkind = \"ideal\"\n").unwrap(), Holder { architecture: vec![Architecture::Ideal {}] });
    }
}
