//! The float reference: an *independent* f64 implementation of the LUT, written from
//! the definition and not from the core's integer code, so that agreement means
//! something.
//!
//! The LUT of an ADC with per-code weights `w_j` (normalized code widths, DN) returns the
//! center of code `k` measured from the bottom of code 0:
//! `c_k = sum_{j<k} w_j + w_k / 2` DN. The core stores `RNE(2^11 c_k)` (round half to
//! even). With weights on the core's 2^-24 grid every `c_k` is exact in f64 (at most
//! 2^12 DN with 25 fractional bits needs 37 bits), so `f64::round_ties_even(2048 c_k)`
//! must reproduce every core entry bit for bit, and a sum of `F` frames of entries must
//! lie within `F 2^-12` DN of the f64 sum of the centers.

/// Centers of every code of every ADC, DN.
#[derive(Debug, Clone, PartialEq)]
pub struct ReferenceLut {
    /// `centers[adc][code]`.
    pub centers: Vec<Vec<f64>>,
}

impl ReferenceLut {
    /// The f64 cumulative sums of `weights[adc][code]`.
    pub fn from_weights(weights: &[Vec<f64>]) -> Self {
        let centers = weights
            .iter()
            .map(|w| {
                let mut below = 0.0;
                w.iter()
                    .map(|&wk| {
                        let c = below + wk / 2.0;
                        below += wk;
                        c
                    })
                    .collect()
            })
            .collect();
        ReferenceLut { centers }
    }

    /// The entries the core's rounding rule gives: `RNE(2^11 c_k)`, as integers.
    pub fn quantized(&self) -> Vec<Vec<u64>> {
        self.centers.iter().map(|t| t.iter().map(|&c| (c * dncal_core::UNITS_PER_DN).round_ties_even() as u64).collect()).collect()
    }

    /// Deviation of each code's center from an ideal ADC's `k + 1/2`, DN: the cumulative
    /// offset the paper plots in Fig. 3.
    pub fn cumulative_offsets(&self) -> Vec<Vec<f64>> {
        self.centers.iter().map(|t| t.iter().enumerate().map(|(k, &c)| c - (k as f64 + 0.5)).collect()).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use dncal_core::{LutSet, Weight};

    #[test]
    fn reproduces_every_core_entry() {
        // Weights with ties built in: w = 1 + j 2^-13 hits half-unit centers often.
        let w: Vec<Weight> = (0..4096).map(|j| Weight::from_bits((1 << 24) + ((j % 7) << 11) - 3 * (1 << 11))).collect();
        let core = LutSet::<1, 4096>::from_weights(&[&w]).unwrap();
        let reference = ReferenceLut::from_weights(&[w.iter().map(|x| x.to_num::<f64>()).collect()]);
        let q = reference.quantized();
        for (k, (entry, &want)) in core.tables()[0].iter().zip(&q[0]).enumerate() {
            assert_eq!(entry.to_bits() as u64, want, "code {k}");
        }
        assert_eq!(q[0].len(), 4096);
        assert_eq!(reference.cumulative_offsets()[0][0], w[0].to_num::<f64>() / 2.0 - 0.5);
    }
}
