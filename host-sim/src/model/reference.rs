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

use crate::{HostError, Subject};

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

    /// The entries the core's rounding rule gives: `RNE(2^F c_k)` with `F` the fractional
    /// bits of the tables' depth (11 up to 12 bits), as integers.
    pub fn quantized(&self) -> Vec<Vec<u64>> {
        self.centers
            .iter()
            .map(|t| {
                let unit = crate::infra::dims::units_per_dn(t.len());
                t.iter().map(|&c| (c * unit).round_ties_even() as u64).collect()
            })
            .collect()
    }

    /// The tables the checks sum: [`Self::quantized`] beside the centres.
    pub fn tables(self) -> Result<ReferenceTables, HostError> {
        ReferenceTables::new(&self.quantized(), &self.centers)
    }

    /// Deviation of each code's center from an ideal ADC's `k + 1/2`, DN: the cumulative
    /// offset the paper plots in Fig. 3.
    pub fn cumulative_offsets(&self) -> Vec<Vec<f64>> {
        self.centers.iter().map(|t| t.iter().enumerate().map(|(k, &c)| c - (k as f64 + 0.5)).collect()).collect()
    }
}

/// The reference as the bit-exactness checks (`stream`, the soak) sum it, per ADC and
/// code: the quantized entries `RNE(2^11 c_k)` (LUT units) and the centres `c_k` (DN),
/// every ADC's table one after the other so that a line's loop reads any pixel's entry
/// with one index (a vector unit's gather).
#[derive(Debug, Clone, PartialEq)]
pub struct ReferenceTables {
    /// ADC `a`'s entry for code `k` at `a * codes + k`, LUT units.
    quantized: Vec<u64>,
    /// The centres, in the same places, DN.
    centers: Vec<f64>,
    /// Codes a table.
    codes: usize,
}

/// What one line added to the reference sums.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LineCounts {
    /// Codes above the top code (each summed as the top code, the core's rule).
    pub out_of_range: u64,
    /// Sums that passed `u32::MAX` with this line's entry, where the core's 32-bit sum
    /// saturates (counted once more for every entry added past it).
    pub clipped: u64,
}

impl ReferenceTables {
    /// The tables of `quantized[adc][code]` and `centers[adc][code]`: at least one ADC,
    /// every table of the same non-zero length, as many centre tables as quantized ones.
    pub fn new(quantized: &[Vec<u64>], centers: &[Vec<f64>]) -> Result<Self, HostError> {
        let codes = quantized.first().map_or(0, Vec::len);
        if codes == 0 || centers.len() != quantized.len() || quantized.iter().any(|t| t.len() != codes) || centers.iter().any(|t| t.len() != codes) {
            let lengths = |t: &[usize]| t.iter().map(|n| n.to_string()).collect::<Vec<_>>().join(", ");
            return Err(HostError::invalid(
                Subject::ReferenceWeights,
                format!(
                    "the reference needs one table of codes per ADC, all of one non-zero length: quantized tables of {} codes, centre tables of {}",
                    lengths(&quantized.iter().map(Vec::len).collect::<Vec<_>>()),
                    lengths(&centers.iter().map(Vec::len).collect::<Vec<_>>())
                ),
            ));
        }
        Ok(ReferenceTables { quantized: quantized.concat(), centers: centers.concat(), codes })
    }

    /// The number of ADCs.
    pub fn adcs(&self) -> usize {
        self.quantized.len() / self.codes.max(1)
    }

    /// Adds one line of raw codes to one state's sums: the exact sums `q` (LUT units, u64,
    /// not clipped at 32 bits as the core's are; saturating at u64::MAX, which 2^41
    /// frames of the largest entries would reach) and the float sums `f` (DN). The
    /// line's first pixel is sensor column `first_column`; column `c` is read by ADC
    /// `c mod N` (the paper's four pipelined ADCs for N = 4), `N` at most the tables'
    /// ADCs (a larger `N` is the caller's error: it panics, as an index past the tables
    /// did). The one reference-sum loop of the host's checks.
    ///
    /// (A loop a vector unit runs: indices in wrapping arithmetic that cannot wrap, an
    /// index at most the tables' last after its `min`.)
    pub fn add_line<const N: usize>(&self, first_column: usize, line: &[u16], q: &mut [u64], f: &mut [f64]) -> LineCounts {
        assert!(N <= self.adcs(), "add_line::<{N}> on reference tables of {} ADCs", self.adcs());
        let mut counts = LineCounts::default();
        let Some(last) = self.quantized.len().min(self.centers.len()).checked_sub(1) else { return counts };
        let (top, codes) = (self.codes.saturating_sub(1), self.codes);
        let len = line.len().min(q.len()).min(f.len());
        let (line, q, f) = (&line[..len], &mut q[..len], &mut f[..len]);
        let (quantized, centers) = (&self.quantized[..=last], &self.centers[..=last]);
        let adc0 = first_column % N.max(1);
        let (mut out_of_range, mut clipped) = (0u64, 0u64);
        for x in 0..len {
            let code = usize::from(line[x]);
            let k = code.min(top);
            out_of_range = out_of_range.wrapping_add(u64::from(code > top));
            let at = (adc0.wrapping_add(x) % N.max(1)).wrapping_mul(codes).wrapping_add(k).min(last);
            let e = quantized[at];
            clipped = clipped.wrapping_add(u64::from(q[x].min(u64::from(u32::MAX)).wrapping_add(e) > u64::from(u32::MAX)));
            q[x] = q[x].saturating_add(e);
            f[x] += centers[at];
        }
        counts.out_of_range = out_of_range;
        counts.clipped = clipped;
        counts
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

    #[test]
    fn a_line_adds_the_entry_of_its_adc_and_clamped_code_to_each_sum() {
        // Two ADCs of four codes, written out: column c is read by ADC c mod 2.
        let tables = ReferenceTables::new(&[vec![1, 10, 100, 1000], vec![2, 20, 200, u64::from(u32::MAX)]], &[vec![0.5, 1.5, 2.5, 3.5], vec![0.25, 1.25, 2.25, 3.25]]).unwrap();
        // Tables of two lengths, or centres for another count of ADCs, are refused.
        assert!(ReferenceTables::new(&[vec![1, 10], vec![2]], &[vec![0.5, 1.5], vec![0.25]]).is_err());
        assert!(ReferenceTables::new(&[vec![1, 10]], &[vec![0.5, 1.5], vec![0.25, 1.25]]).is_err());
        assert!(ReferenceTables::new(&[], &[]).is_err());
        // The line starts at sensor column 3 (ADC 1); code 9 is above the top (3) and
        // sums as code 3.
        let line = [0u16, 1, 9, 3];
        let mut q = vec![0u64, 0, 5, 1];
        let mut f = vec![0.0; 4];
        let counts = tables.add_line::<2>(3, &line, &mut q, &mut f);
        // Columns 3, 4, 5, 6 -> ADCs 1, 0, 1, 0.
        assert_eq!(q, vec![2, 10, 5 + u64::from(u32::MAX), 1001]);
        assert_eq!(f, vec![0.25, 1.5, 3.25, 3.5]);
        // One code above the top; one sum (column 5) passed u32::MAX.
        assert_eq!(counts, LineCounts { out_of_range: 1, clipped: 1 });
        // A sum already past u32::MAX counts as clipped again with any further entry.
        let again = tables.add_line::<2>(3, &[0, 0, 0, 0], &mut q, &mut f);
        assert_eq!(again, LineCounts { out_of_range: 0, clipped: 1 });
    }
}
