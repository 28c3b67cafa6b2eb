//! ADC architectures fitted to one ADC's histogram test, as camera models
//! ([`crate::model::camera::Architecture`]): what `dncal diagnose` scores on held-out counts and
//! writes into `model.toml` when one explains the code widths.
//!
//! Both kinds put the transition into code k at `T_k = k - 1/2 + x(k) . b`, linear in
//! their parameters `b` for every code that is not missing; a missing code's transition
//! is its successor's. So each analysed code `k` that is not missing, with `n` the next
//! code that is not, gives one equation for the parameters:
//!
//! ```text
//! w_k - (n - k) = (x(n) - x(k)) . b,     weight 1 / sigma_k^2
//! ```
//!
//! (`w_k = 1 + DNL_k` its width: for `n = k + 1` the DNL itself; across a run of missing
//! codes, the code below takes their span). The DNL's noise is independent from code to
//! code, the INL's is not: hence weighted least squares on widths, not on the INL.
//!
//! - **Binary-weighted SAR**: `x_b(k)` is bit b of k, `b` the weight errors
//!   ([`crate::model::camera::Architecture::Sar`]; a non-missing code's lower level is
//!   `sum_b bit_b(k) W_b - 1/2` for any positive weights). The flattening makes the mean
//!   width 1, which spreads a heavy bit's excess over all bits in proportion to `2^b` (a
//!   common gain); the weights are given back **relative to the median bit**, all
//!   scaled by `1 / (1 + g)`, `g = median_j(e_j / 2^j)`, so that a SAR with one wrong
//!   capacitor has one weight error (its full scale `sum_b W_b` then differs from
//!   `2^B - 1` by it). A scale leaves every code's share of the range as fitted.
//! - **Pipelined** layouts (the stage models of [`crate::analyses::real_adcs`], for any bit
//!   depth): `x(k)` is [`stage_row`], a DAC-level error per stage and
//!   digit and, for some layouts, a gain per first-stage sub-range (its constant and
//!   cubic left out: a cubic trades with the sub-ranges' offsets and slopes, and the
//!   flattening took the slow trend out).
//!
//! With a smooth input density the flattening's running median follows any change of
//! the mean width that lasts longer than its window, so a sub-range gain shows only at
//! the sub-range's ends: the gain layouts are fitted but seldom win there; on a ramp or
//! sine input they are seen whole.

use crate::model::camera::Architecture;

use super::AdcLinearity;

/// One candidate architecture.
#[derive(Debug, Clone, PartialEq)]
pub struct Candidate {
    /// The model.
    pub architecture: Architecture,
    /// Parameters fitted for it (the SAR: bits with a weight error).
    pub parameters: usize,
}

/// The pipelined layouts tried for a `bits`-bit ADC: stages of 1, 2, 3 and 4 bits (the
/// last takes the remainder), a 4-bit first stage before one stage of the rest, and with
/// a gain per first-stage sub-range: 4-bit stages, 4 + rest and 5 + rest. For 12 bits,
/// the stage models of [`crate::analyses::real_adcs::STAGE_MODELS`].
pub fn layouts(bits: u32) -> Vec<(Vec<u32>, bool)> {
    let uniform = |s: u32| -> Vec<u32> {
        let mut v = vec![s; (bits / s) as usize];
        if !bits.is_multiple_of(s) {
            v.push(bits % s);
        }
        v
    };
    let mut out: Vec<(Vec<u32>, bool)> = (1..=4).filter(|&s| s < bits).map(|s| (uniform(s), false)).collect();
    if bits > 8 {
        out.push((vec![4, bits - 4], false));
        out.push((uniform(4), true));
        out.push((vec![4, bits - 4], true));
    }
    if bits > 10 {
        out.push((vec![5, bits - 5], true));
    }
    out
}

/// The design row of the stage model for the transition into `code`: a constant, a cubic
/// in x, one indicator per stage and non-zero digit and, with `segment_gains`, per digit
/// of the first stage the lower stages' value (as a fraction of the sub-range) where the
/// code is in that digit's sub-range. Its columns beyond the first four are
/// [`stage_features`].
pub fn stage_row(stages: &[u32], segment_gains: bool, code: usize, x: f64) -> Vec<f64> {
    let mut row = vec![0.0; 4 + stage_columns(stages, segment_gains)];
    row[..4].copy_from_slice(&[1.0, x, x * x, x * x * x]);
    for (i, v) in stage_features(stages, segment_gains, code) {
        row[i] = v;
    }
    row
}

/// Columns of [`stage_row`] after its constant and cubic: per stage its non-zero digits,
/// with `segment_gains` the first stage's non-zero digits again.
fn stage_columns(stages: &[u32], segment_gains: bool) -> usize {
    let digits: usize = stages.iter().map(|&b| (1usize << b) - 1).sum();
    digits + if let (true, Some(&top)) = (segment_gains, stages.first()) { (1usize << top) - 1 } else { 0 }
}

/// The non-zero entries of [`stage_row`] after its constant and cubic, as (column,
/// value) in rising column order: one indicator per stage whose digit is not 0 and, with
/// `segment_gains`, the lower stages' value in the code's first-stage sub-range. A
/// 16-bit layout with a 12-bit last stage has 4,110 columns and at most five of them
/// non-zero: its fit is held and solved sparse ([`weighted_lstsq`]).
pub fn stage_features(stages: &[u32], segment_gains: bool, code: usize) -> Vec<(usize, f64)> {
    let mut out = Vec::with_capacity(stages.len() + 1);
    let bits: u32 = stages.iter().sum();
    let (mut shift, mut at) = (bits, 4);
    for &b in stages {
        shift -= b;
        let digit = (code >> shift) & ((1 << b) - 1);
        if digit != 0 {
            out.push((at + digit - 1, 1.0));
        }
        at += (1usize << b) - 1;
    }
    if let (true, Some(&top)) = (segment_gains, stages.first()) {
        let low = bits - top;
        let (digit, below) = ((code >> low) & ((1 << top) - 1), (code & ((1 << low) - 1)) as f64 / (1u64 << low) as f64);
        // Digit 0's slope is left out: the slopes of all digits sum to the lower stages'
        // value, which their offsets already span; the others are relative to it.
        if digit != 0 && below != 0.0 {
            out.push((at + digit - 1, below));
        }
    }
    out
}

/// A design row held by its non-zero entries, (column, value) in rising column order.
type SparseRow = Vec<(usize, f64)>;

/// `hi - lo` of two sparse rows, exact zeros left out.
fn sparse_difference(hi: &[(usize, f64)], lo: &[(usize, f64)]) -> SparseRow {
    let mut out = Vec::with_capacity(hi.len() + lo.len());
    let (mut i, mut j) = (0, 0);
    while i < hi.len() || j < lo.len() {
        let (c, v) = match (hi.get(i), lo.get(j)) {
            (Some(&(a, x)), Some(&(b, y))) if a == b => {
                (i, j) = (i + 1, j + 1);
                (a, x - y)
            }
            (Some(&(a, x)), Some(&(b, _))) if a < b => {
                i += 1;
                (a, x)
            }
            (Some(&(a, x)), None) => {
                i += 1;
                (a, x)
            }
            (_, Some(&(b, y))) => {
                j += 1;
                (b, -y)
            }
            (None, None) => unreachable!("the loop runs while either has entries"),
        };
        if v != 0.0 {
            out.push((c, v));
        }
    }
    out
}

/// Largest parameter count solved by the dense pseudo-inverse; every layout of a 12-bit
/// ADC (at most 4 + 31 + 127 + 31 = 193, or 4 + 15 + 255 + 15 = 289 columns) is. Its cost
/// grows as `p^3` and its memory as `p^2`: a 16-bit `4 + 12` layout (4,114 columns) took
/// minutes and gigabytes in one SVD, where its normal equations have about seven
/// non-zeros a column.
const DENSE_MAX_PARAMETERS: usize = 300;

/// Weighted least squares by the normal equations, for design rows that are mostly
/// zeros (a few indicators each): `sum_i w_i (y_i - x_i b)^2` minimal. Up to
/// [`DENSE_MAX_PARAMETERS`] columns, the pseudo-inverse of `X^T W X` by its SVD (columns
/// that are not all independent, a column of zeros or digits the codes never use, get
/// 0); beyond, a sparse Cholesky factor of `X^T W X` with the columns no row uses left at
/// 0 ([`sparse_normal_solve`]), whose cost grows with the codes. None if the system
/// cannot be solved.
fn weighted_lstsq(rows: &[(SparseRow, f64, f64)], p: usize) -> Option<Vec<f64>> {
    if p > DENSE_MAX_PARAMETERS {
        return sparse_normal_solve(rows, p);
    }
    let mut xtx = nalgebra::DMatrix::<f64>::zeros(p, p);
    let mut xty = nalgebra::DVector::<f64>::zeros(p);
    for (nz, y, w) in rows {
        for &(i, a) in nz {
            xty[i] += w * a * y;
            for &(j, b) in nz {
                xtx[(i, j)] += w * a * b;
            }
        }
    }
    let scale = (0..p).map(|i| xtx[(i, i)]).fold(0.0, f64::max);
    xtx.svd(true, true).solve(&xty, 1e-12 * scale.max(1e-300)).ok().map(|b| b.iter().copied().collect())
}

/// The normal equations of [`weighted_lstsq`] held sparse and solved by a sparse Cholesky
/// factor (`nalgebra-sparse`; its fill follows the layouts' column order: each stage's
/// digits form a chain of neighbours, the sub-range gains come last and are dense among
/// themselves only). Columns no row touches are left out and get 0, as the
/// pseudo-inverse gives them. A system with dependent columns has no unique fit, and a
/// factor of it carries an arbitrary part of the null direction (a test planted one and
/// got 3e-4 relative errors): when the factor fails, or a pivot falls below
/// [`SINGULAR_PIVOT`] of its column's diagonal, None (the candidate is not offered).
fn sparse_normal_solve(rows: &[(SparseRow, f64, f64)], p: usize) -> Option<Vec<f64>> {
    use nalgebra_sparse::{factorization::CscCholesky, CooMatrix, CscMatrix};
    let mut used = vec![false; p];
    rows.iter().flat_map(|(nz, _, _)| nz).for_each(|&(i, _)| used[i] = true);
    // Column i of the full system is column index[i] of the reduced one.
    let mut index = vec![usize::MAX; p];
    let mut m = 0;
    for (i, _) in used.iter().enumerate().filter(|(_, u)| **u) {
        index[i] = m;
        m += 1;
    }
    if m == 0 {
        return Some(vec![0.0; p]);
    }
    let mut xty = nalgebra::DVector::<f64>::zeros(m);
    let mut coo = CooMatrix::<f64>::new(m, m);
    let mut diagonal = vec![0.0f64; m];
    for (nz, y, w) in rows {
        for &(i, a) in nz {
            xty[index[i]] += w * a * y;
            diagonal[index[i]] += w * a * a;
            for &(j, b) in nz {
                coo.push(index[i], index[j], w * a * b);
            }
        }
    }
    if !diagonal.iter().all(|d| d.is_finite() && *d > 0.0) {
        return None;
    }
    let factor = CscCholesky::factor(&CscMatrix::from(&coo)).ok()?;
    let singular = (0..m).any(|i| factor.l().get_entry(i, i).is_none_or(|e| e.into_value().powi(2) < SINGULAR_PIVOT * diagonal[i]));
    if singular {
        return None;
    }
    let solution = factor.solve(&xty);
    let mut out = vec![0.0; p];
    for (i, &k) in index.iter().enumerate().filter(|(_, k)| **k != usize::MAX) {
        out[i] = solution[(k, 0)];
    }
    out.iter().all(|v| v.is_finite()).then_some(out)
}

/// A Cholesky pivot (`L_ii^2`) below this fraction of its column's diagonal marks a column
/// that depends on the others. A chain of digits anchored at digit 0 keeps pivots above
/// half its diagonal; an exact dependence leaves rounding, about 1e-16.
const SINGULAR_PIVOT: f64 = 1e-10;

/// The equations of the module documentation for the features `x` (sparse, rising
/// columns): (x(n) - x(k), w_k - (n - k), 1 / sigma_k^2) per analysed code k that is not
/// missing.
fn width_equations(t: &AdcLinearity, x: impl Fn(usize) -> SparseRow) -> Vec<(SparseRow, f64, f64)> {
    let first = t.first_code;
    let present = |i: usize| t.dnl_lsb[i] > -1.0 + 1e-9;
    let mut rows = Vec::new();
    let mut next = (0..t.dnl_lsb.len()).filter(|&i| present(i)).peekable();
    while let (Some(i), Some(&j)) = (next.next(), next.peek()) {
        let (d, s) = (t.dnl_lsb[i], t.dnl_sigma_lsb[i]);
        if !(d.is_finite() && s.is_finite() && s > 0.0) {
            continue;
        }
        rows.push((sparse_difference(&x(first + j), &x(first + i)), 1.0 + d - (j - i) as f64, 1.0 / (s * s)));
    }
    rows
}

/// A binary-weighted SAR fitted to the widths of `t` (module documentation).
fn fit_sar(t: &AdcLinearity) -> Option<Candidate> {
    let bits = t.bits as usize;
    let rows = width_equations(t, |k| (0..bits).filter(|&b| k >> b & 1 == 1).map(|b| (b, 1.0)).collect());
    if rows.len() < 2 * bits {
        return None;
    }
    let e = weighted_lstsq(&rows, bits)?;
    // A common gain, taken out as a scale of all the weights (not a shift of each: that
    // would change the widths' proportions, 0.04 LSB at codes 9 LSB wide).
    let gain = crate::infra::stats::median(e.iter().enumerate().map(|(b, e)| e / (1u64 << b) as f64));
    let weight_error_lsb: Vec<f64> = e.iter().enumerate().map(|(b, e)| ((1u64 << b) as f64 + e) / (1.0 + gain) - (1u64 << b) as f64).collect();
    let architecture = Architecture::Sar { weight_error_lsb };
    architecture.check(t.bits).ok()?;
    Some(Candidate { architecture, parameters: bits })
}

/// A pipelined layout fitted to the widths of `t`.
fn fit_pipelined(t: &AdcLinearity, stages: &[u32], gains: bool) -> Option<Candidate> {
    let codes = 1usize << t.bits;
    // The constant and cubic of the stage row are left at zero: within each sub-range a
    // cubic over the range is nearly an offset and a slope, so fitted beside the
    // sub-ranges' offsets and gains it trades with them (a first-stage offset came back
    // 0.5 LSB off); the flattening has taken the slow trend out already.
    let rows = width_equations(t, |k| stage_features(stages, gains, k % codes));
    let p = 4 + stage_columns(stages, gains);
    if rows.len() < 2 * p {
        return None;
    }
    let b = weighted_lstsq(&rows, p)?;
    let architecture = pipelined_from(stages, gains, &b, t.bits);
    architecture.check(t.bits).ok()?;
    Some(Candidate { architecture, parameters: p - 4 })
}

/// The pipelined architecture of the coefficients `b` of a fit on the columns of
/// [`stage_row`] (a constant and a cubic, left out; per stage its
/// non-zero digits' offsets, LSB; with `gains`, per first-stage digit but 0 the drift
/// across its sub-range relative to digit 0's, LSB, which is `c_d` in `j (1/(1+g) - 1) =
/// c_d j / 2^low`).
pub(crate) fn pipelined_from(stages: &[u32], gains: bool, b: &[f64], bits: u32) -> Architecture {
    let mut at = 4;
    let offset_lsb: Vec<Vec<f64>> = stages
        .iter()
        .map(|&s| {
            let n = (1usize << s) - 1;
            let v = std::iter::once(0.0).chain(b[at..at + n].iter().copied()).collect();
            at += n;
            v
        })
        .collect();
    let low = bits - stages[0];
    let subrange_gain_error: Vec<f64> = if gains {
        std::iter::once(0.0).chain(b[at..at + (1usize << stages[0]) - 1].iter().map(|c| 1.0 / (1.0 + c / (1u64 << low) as f64).max(1e-9) - 1.0)).collect()
    } else {
        Vec::new()
    };
    Architecture::Pipelined { stage_bits: stages.to_vec(), offset_lsb, subrange_gain_error }
}

/// Every candidate for the ADC of `t`: the SAR and each pipelined layout the codes can
/// carry (at least two codes per parameter), fewest parameters first. The layout of
/// 1-bit stages is the SAR itself (a stage's digit-1 offset is its bit's weight error)
/// and is left out. The models nest (binary weights are also a 4-bit stage's 16 levels),
/// so a caller choosing among them held out takes the fewest parameters that fit as
/// well as the best ([`choose`]).
pub fn candidates(t: &AdcLinearity) -> Vec<Candidate> {
    let pipelined = layouts(t.bits).into_iter().filter(|(stages, _)| stages.iter().any(|&b| b > 1));
    let mut out: Vec<Candidate> = fit_sar(t).into_iter().chain(pipelined.filter_map(|(stages, gains)| fit_pipelined(t, &stages, gains))).collect();
    out.sort_by_key(|c| c.parameters);
    out
}

/// The index of the candidate to keep among `(parameters, z^2 per code)`, every
/// candidate scored on the same codes: the fewest parameters whose `sum z^2` exceeds the
/// best's by at most one standard deviation of that excess, taken from the code-by-code
/// differences (`sqrt(n) sd(d_k)`; two candidates scored on the same counts differ far
/// less than either's noise, which one `sqrt(2/N)` of mean z^2 would have allowed). On
/// a tie the first (the SAR before a pipeline of as many).
pub fn choose(candidates: &[(usize, &[f64])]) -> Option<usize> {
    let sums: Vec<f64> = candidates.iter().map(|(_, z2)| z2.iter().sum()).collect();
    let best = (0..sums.len()).min_by(|&i, &j| sums[i].total_cmp(&sums[j]))?;
    let fits = |i: usize| {
        let d: Vec<f64> = candidates[i].1.iter().zip(candidates[best].1).map(|(a, b)| a - b).collect();
        let n = d.len().max(2) as f64;
        let mean = d.iter().sum::<f64>() / n;
        let sd_sum = (d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0) * n).sqrt();
        sums[i] - sums[best] <= sd_sum
    };
    let fewest = (0..candidates.len()).filter(|&i| fits(i)).map(|i| candidates[i].0).min()?;
    (0..candidates.len()).find(|&i| fits(i) && candidates[i].0 == fewest)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::camera::AdcTransfer;
    use crate::analyses::flatten::FlattenParams;
    use crate::analyses::ieee1241::{analyse, Density};
    use rand::SeedableRng;
    use rand_distr::{Distribution, Poisson};

    /// Ramp counts of `adc`, `per_code` a code on average.
    fn ramp_counts(adc: &AdcTransfer, per_code: f64, seed: u64) -> Vec<u64> {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        adc.widths().iter().map(|w| Poisson::new(per_code * w).map_or(0, |d| d.sample(&mut rng) as u64)).collect()
    }

    fn ramp() -> FlattenParams {
        FlattenParams::default()
    }

    /// A planted pipelined ADC (4+4+4, offsets 0.7/0.1/0.05 LSB rms, up to 1.2 LSB in the
    /// first stage so that a fit of zeros there fails the tolerance, sub-range gains of
    /// up to 2%) measured on a ramp at 20 000 counts a code: the 4+4+4 layout with gains
    /// returns the planted offsets and gains; its model's widths match the planted ones.
    /// The precisions: a gain from its sub-range's 255 widths, `sigma_g = 16 sigma / 256`
    /// (`sigma` = 0.007 LSB a width); a first-stage offset from one width at the
    /// sub-range's end, where the gain below drifts, `16 sigma` = 0.11 LSB; the lower
    /// stages' from 16 or 256 widths each. Tolerances about 4.5 of them.
    #[test]
    fn a_planted_pipeline_comes_back() {
        let mut s = 99u64;
        let mut next = || {
            s = s.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let offset_lsb: Vec<Vec<f64>> = [2.4, 0.35, 0.17].iter().map(|a| (0..16).map(|d| if d == 0 { 0.0 } else { a * next() }).collect()).collect();
        let subrange_gain_error: Vec<f64> = (0..16).map(|d| if d == 0 { 0.0 } else { 0.04 * next() }).collect();
        let planted = Architecture::Pipelined { stage_bits: vec![4, 4, 4], offset_lsb: offset_lsb.clone(), subrange_gain_error: subrange_gain_error.clone() };
        let adc = AdcTransfer::from_architecture(&planted, 12).unwrap();
        let t = analyse(&ramp_counts(&adc, 20_000.0, 1), Density::Ramp, &ramp()).unwrap();
        let c = candidates(&t);
        let fit = c.iter().find(|c| c.architecture.name() == "pipelined 4+4+4 with sub-range gains").expect("fitted");
        let Architecture::Pipelined { offset_lsb: got, subrange_gain_error: g, .. } = &fit.architecture else { panic!() };
        // Two directions the widths do not fix: a common gain (the test makes the mean
        // width 1) and the slope of sub-range 0, the gains' reference (its 255 widths fix
        // it to 16 sigma = 0.11 LSB across the sub-range); both are linear in each stage's
        // digit. So each stage's offsets are compared after the line through digit 0
        // that fits their difference best.
        let w = adc.widths();
        let m = w[1..4095].iter().sum::<f64>() / 4094.0;
        for (s, (got, want)) in got.iter().zip(&offset_lsb).enumerate() {
            let diff: Vec<f64> = (0..16).map(|d| got[d] - want[d]).collect();
            let slope = (1..16).map(|d| diff[d] * d as f64).sum::<f64>() / (1..16).map(|d| (d * d) as f64).sum::<f64>();
            let tolerance = if s == 0 { 0.5 } else { 0.03 };
            for d in 1..16 {
                assert!((diff[d] - slope * d as f64).abs() < tolerance, "stage {s} digit {d}: {} vs {} (slope {slope})", got[d], want[d]);
            }
        }
        for d in 1..16 {
            assert!((g[d] - subrange_gain_error[d]).abs() < 0.002, "gain {d}: {} vs {}", g[d], subrange_gain_error[d]);
        }
        let model = AdcTransfer::from_architecture(&fit.architecture, 12).unwrap().widths();
        let rms = ((1..4095).map(|k| (model[k] - w[k] / m).powi(2)).sum::<f64>() / 4094.0).sqrt();
        assert!(rms < 0.01, "width rms {rms}");
    }

    /// A SAR with bit 9 eight LSB heavy and bit 10 1.5 LSB lighter than that (the codes
    /// below its carries missing, and with them a run of codes below the MSB whose
    /// weights overlap it) at 100 counts a code: the SAR candidate reproduces the widths,
    /// the missing codes included, with two weight errors.
    #[test]
    fn a_planted_sar_with_missing_codes_comes_back() {
        let mut e = vec![0.0; 12];
        e[9] = 8.0;
        e[10] = -1.5 + 8.0;
        let planted = Architecture::Sar { weight_error_lsb: e };
        let adc = AdcTransfer::from_architecture(&planted, 12).unwrap();
        let want = adc.widths();
        let missing: Vec<usize> = (1..4095).filter(|&k| want[k] == 0.0).collect();
        assert!(!missing.is_empty());
        let t = analyse(&ramp_counts(&adc, 100.0, 2), Density::Ramp, &ramp()).unwrap();
        let sar = candidates(&t).into_iter().find(|c| matches!(c.architecture, Architecture::Sar { .. })).expect("a SAR candidate");
        let model = AdcTransfer::from_architecture(&sar.architecture, 12).unwrap().widths();
        for &k in &missing {
            assert!(model[k] < 1e-9, "code {k} should be missing: {}", model[k]);
        }
        for k in [511usize, 1535, 2559, 3583, 1022] {
            assert!((model[k] - want[k]).abs() < 0.3, "code {k}: {} vs {}", model[k], want[k]);
        }
        let Architecture::Sar { weight_error_lsb: e } = &sar.architecture else { panic!() };
        assert!((e[9] - 8.0).abs() < 0.3 && (e[10] - 6.5).abs() < 0.5, "{e:?}");
        for b in (0..9).chain([11]) {
            assert!(e[b].abs() < 0.3, "bit {b}: {e:?}");
        }
    }

    /// A 16-bit SAR (bit 13 three LSB heavy, bit 7 half an LSB light) and a 16-bit 4+4+4+4
    /// pipeline at 2,000 counts a code on a ramp: the SAR's weight errors come back, and the
    /// pipeline's widths come back from its own layout (75 parameters, dense) and from the
    /// 4 + 12 layout that nests it (4,114 parameters, the sparse solve), every candidate of
    /// a 16-bit ADC fitted.
    #[test]
    fn planted_16_bit_adcs_come_back() {
        let mut e = vec![0.0; 16];
        (e[13], e[7]) = (3.0, -0.5);
        let adc = AdcTransfer::from_architecture(&Architecture::Sar { weight_error_lsb: e }, 16).unwrap();
        let t = analyse(&ramp_counts(&adc, 2000.0, 3), Density::Ramp, &ramp()).unwrap();
        let sar = fit_sar(&t).expect("a SAR candidate");
        let Architecture::Sar { weight_error_lsb: got } = &sar.architecture else { panic!() };
        // Each weight from 2^15 codes' widths at 0.022 LSB: far below 0.05 LSB.
        for (b, (g, w)) in got.iter().zip([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 3.0, 0.0, 0.0]).enumerate() {
            assert!((g - w).abs() < 0.05, "bit {b}: {g} vs {w} ({got:?})");
        }

        let mut s = 7u64;
        let mut next = || {
            s = s.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let offset_lsb: Vec<Vec<f64>> = [1.6, 0.5, 0.2, 0.1].iter().map(|a| (0..16).map(|d| if d == 0 { 0.0 } else { a * next() }).collect()).collect();
        let planted = Architecture::Pipelined { stage_bits: vec![4, 4, 4, 4], offset_lsb, subrange_gain_error: Vec::new() };
        let adc = AdcTransfer::from_architecture(&planted, 16).unwrap();
        let t = analyse(&ramp_counts(&adc, 2000.0, 4), Density::Ramp, &ramp()).unwrap();
        let all = candidates(&t);
        let names: Vec<String> = all.iter().map(|c| c.architecture.name()).collect();
        for (stages, gains) in layouts(16).into_iter().filter(|(s, _)| s.iter().any(|&b| b > 1)) {
            let name = Architecture::Pipelined { stage_bits: stages.clone(), offset_lsb: stages.iter().map(|&b| vec![0.0; 1 << b]).collect(), subrange_gain_error: if gains { vec![0.0; 1 << stages[0]] } else { Vec::new() } }.name();
            assert!(names.contains(&name), "{name} not fitted: {names:?}");
        }
        let w = adc.widths();
        let m = w[1..65535].iter().sum::<f64>() / 65534.0;
        for name in ["pipelined 4+4+4+4", "pipelined 4+12"] {
            let fit = all.iter().find(|c| c.architecture.name() == name).unwrap_or_else(|| panic!("{name} in {names:?}"));
            let model = AdcTransfer::from_architecture(&fit.architecture, 16).unwrap().widths();
            let rms = ((1..65535).map(|k| (model[k] - w[k] / m).powi(2)).sum::<f64>() / 65534.0).sqrt();
            // 4+4+4+4: 75 parameters from 65,534 widths of 0.022 LSB; 4+12: each of its
            // 4,095 last-stage offsets from 16 widths, 0.022 / 4 = 0.006 LSB a width.
            let limit = if fit.parameters < 100 { 0.004 } else { 0.012 };
            assert!(rms < limit, "{name}: width rms {rms} against the planted widths");
        }
    }

    /// The sparse normal-equation solve against an independent least squares (nalgebra's
    /// SVD of the weighted design itself, not of its normal equations) on a problem with
    /// the shape of a long last stage: 396 columns chained by differences of neighbours
    /// and anchored, repeated in five sub-ranges of which four carry a gain column (as
    /// digit 0's slope is left out of the layouts), and one column no row uses (0 in
    /// both). With a gain in the fifth sub-range too, a ramp of the chain trades exactly
    /// with the gains: no unique fit, None.
    #[test]
    fn the_sparse_solve_agrees_with_a_dense_least_squares() {
        let (p, subranges) = (402usize, 5usize);
        let problem = |gains_from: usize| {
            let mut s = 11u64;
            let mut next = || {
                s = s.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
                (s >> 11) as f64 / (1u64 << 53) as f64
            };
            let mut rows: Vec<(SparseRow, f64, f64)> = Vec::new();
            for rep in 0..subranges {
                rows.push((vec![(1, 1.0)], next(), 1.0 + next()));
                for c in 1..p - subranges - 1 {
                    let mut row = vec![(c, -1.0), (c + 1, 1.0)];
                    if rep >= gains_from {
                        row.push((p - subranges + rep, 1.0 / 400.0));
                    }
                    rows.push((row, next() - 0.5, 0.5 + next()));
                }
            }
            rows
        };
        let rows = problem(1);
        assert!(p > DENSE_MAX_PARAMETERS, "the test must take the sparse path");
        let got = weighted_lstsq(&rows, p).expect("solved");
        let mut x = nalgebra::DMatrix::<f64>::zeros(rows.len(), p);
        let mut y = nalgebra::DVector::<f64>::zeros(rows.len());
        for (r, (nz, v, w)) in rows.iter().enumerate() {
            nz.iter().for_each(|&(c, a)| x[(r, c)] = a * w.sqrt());
            y[r] = v * w.sqrt();
        }
        let want = x.svd(true, true).solve(&y, 1e-12).unwrap();
        assert_eq!((got[0], got[p - subranges]), (0.0, 0.0), "columns no row uses");
        for c in 1..p {
            assert!((got[c] - want[c]).abs() < 1e-8 * (1.0 + want[c].abs()), "column {c}: {} vs {}", got[c], want[c]);
        }
        assert_eq!(weighted_lstsq(&problem(0), p), None, "a gain in every sub-range trades with a ramp of the chain");
    }

    /// The sparse difference of two sparse rows is the dense one, zeros left out.
    #[test]
    fn sparse_difference_is_the_dense_difference() {
        let dense = |r: &[(usize, f64)]| {
            let mut d = vec![0.0; 8];
            r.iter().for_each(|&(c, v)| d[c] = v);
            d
        };
        let cases: [(SparseRow, SparseRow); 4] = [
            (vec![(0, 1.0), (3, 2.0)], vec![(3, 2.0), (5, 1.0)]),
            (vec![], vec![(2, 1.0)]),
            (vec![(1, 0.5), (7, 1.0)], vec![]),
            (vec![(2, 1.0), (4, 1.0), (6, 0.25)], vec![(1, 1.0), (4, 0.5), (6, 0.25), (7, 1.0)]),
        ];
        for (hi, lo) in &cases {
            let got = sparse_difference(hi, lo);
            assert!(got.windows(2).all(|w| w[0].0 < w[1].0) && got.iter().all(|&(_, v)| v != 0.0), "{got:?}");
            let want: Vec<f64> = dense(hi).iter().zip(dense(lo)).map(|(a, b)| a - b).collect();
            assert_eq!(dense(&got), want, "{hi:?} - {lo:?}");
        }
    }

    #[test]
    fn the_fewest_parameters_that_fit_as_well_are_chosen() {
        // Per-code z^2 of three candidates on four codes. The 12-parameter one is worse by
        // 0.2 in total with code-by-code differences of 0.05 +- 0.1: within one sd (0.23).
        let best: &[f64] = &[1.0, 1.0, 1.0, 1.0];
        let close: &[f64] = &[1.15, 0.95, 1.15, 0.95];
        assert_eq!(choose(&[(12, close), (45, best)]), Some(0));
        // The same excess with no scatter: the differences say it is real.
        let worse: &[f64] = &[1.05, 1.05, 1.05, 1.05];
        assert_eq!(choose(&[(12, worse), (45, best)]), Some(1));
        // Ties go to the first of as many parameters; nothing to choose from, None.
        assert_eq!(choose(&[(12, best), (12, best)]), Some(0));
        assert_eq!(choose(&[]), None);
    }

}
