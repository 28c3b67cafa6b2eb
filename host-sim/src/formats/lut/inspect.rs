//! `lut inspect`: what a LUT file holds, in any format ([`super::read`]): each ADC's
//! entries, steps (each the mean width of two neighbouring codes) and cumulative offsets.
//!
//! A table may carry more than its ADC's code widths: the K-Coronagraph's deployed tables
//! fold a global response correction into every ADC's table (docs/kcor-luts.md), a
//! smooth curve that bends the entries by some 200-260 DN from a straight line, so their
//! raw cumulative offsets say nothing about the ADC. Each table's cubic trend is fitted
//! (codes [`first_fitted`]..=top - 1, as `adc --from-luts` fits the K-Cor tables); where
//! every ADC's trend bends far more than what it leaves and the trends agree with each
//! other, the tables share a response curve ([`CommonTrend`]), and the offsets are shown
//! with it taken out beside the raw ones.

use std::path::{Path, PathBuf};

use serde::Serialize;

use super::LutFormat;
use crate::formats::report::Report;
use crate::infra::stats::{cubic_at, cubic_bow, cubic_fit};
use crate::HostError;

/// One ADC's table as `lut inspect` shows it.
#[derive(Debug, Serialize)]
pub struct InspectAdc {
    /// ADC index.
    pub adc: usize,
    /// Entries, LUT units: 2^-11 DN up to 12-bit codes, `dncal_core::frac_bits`.
    pub entries: Vec<u32>,
    /// Step between consecutive entries in DN: the mean width of two adjacent codes,
    /// the normalized histogram as the table sees it.
    pub step_dn: Vec<f64>,
    /// Cumulative offset: entry in DN minus (k + 1/2).
    pub cumulative_offset_dn: Vec<f64>,
    /// Largest |cumulative offset|, DN.
    pub max_abs_offset_dn: f64,
    /// Smallest and largest step, DN.
    pub step_range: (f64, f64),
    /// The table's cubic trend in `x = k / (codes - 1)`, `p0 + p1 x + p2 x^2 + p3 x^3`, DN,
    /// fitted over codes [`first_fitted`]..=top - 1.
    pub trend_dn: [f64; 4],
    /// The trend's largest departure from the straight line through its ends, DN.
    pub trend_bow_dn: f64,
    /// Largest |entry - trend| over the fitted codes: the cumulative offset with the
    /// table's own smooth curve taken out, DN.
    pub detrended_max_abs_offset_dn: f64,
}

/// A smooth response curve all tables of a LUT share (module documentation).
#[derive(Debug, Serialize)]
pub struct CommonTrend {
    /// The ADCs' mean trend's largest departure from its chord, DN.
    pub bow_dn: f64,
    /// Largest difference between one ADC's trend and the mean trend, DN.
    pub spread_dn: f64,
}

/// A trend is a response curve, not DN error, where it bends by at least this (DN, at
/// any bit depth)...
const TREND_MIN_BOW_DN: f64 = 5.0;
/// ... and by at least this many times what it leaves on its ADC ...
const TREND_OVER_RESIDUAL: f64 = 10.0;
/// ... and the ADCs' trends differ by at most this fraction of the bow.
const TREND_MAX_SPREAD: f64 = 0.1;

/// The first code of the trend fit: the K-Cor recipe's flat start
/// ([`super::kcor::FIRST_CALIBRATED`] of its 4096 codes), in proportion at other bit depths.
pub fn first_fitted(codes: usize) -> usize {
    super::kcor::FIRST_CALIBRATED * codes / super::kcor::KCOR_CODES
}

/// What `lut inspect` found.
#[derive(Debug, Serialize)]
pub struct InspectSummary {
    /// The file.
    pub path: PathBuf,
    /// Its format.
    pub kind: LutFormat,
    /// Bits per code.
    pub bit_depth: u32,
    /// Per ADC.
    pub adcs: Vec<InspectAdc>,
    /// The response curve the tables share, where they do.
    pub common_trend: Option<CommonTrend>,
    /// Whether the readable text lists every code (`--table`; JSON always has them).
    #[serde(skip)]
    pub list_codes: bool,
}

impl Report for InspectSummary {
    fn text(&self) -> String {
        let mut t = format!("{} ({}, {} bits, {} ADCs)\n", self.path.display(), self.kind, self.bit_depth, self.adcs.len());
        t += "(entry steps: entry k+1 - entry k, the mean width of codes k and k+1; `lut build` reports the single-code widths, a wider range)\n";
        if let Some(c) = &self.common_trend {
            t += &format!(
                "common trend: the {} tables share a smooth response curve (a cubic in the code bending {:.1} DN from its chord, the same within {:.2} DN on every ADC): a global response correction folded into the tables, not DN error (docs/kcor-luts.md); offsets are given raw and with each table's cubic trend taken out\n",
                self.adcs.len(),
                c.bow_dn,
                c.spread_dn
            );
        }
        for a in &self.adcs {
            let offset = match self.common_trend {
                Some(_) => format!("{:.3} DN raw, {:.3} DN with the trend taken out", a.max_abs_offset_dn, a.detrended_max_abs_offset_dn),
                None => format!("{:.3} DN", a.max_abs_offset_dn),
            };
            t += &format!("ADC {}: entry steps {:.4}..{:.4} DN, max |cumulative offset| {offset}, top entry {}\n", a.adc, a.step_range.0, a.step_range.1, a.entries.last().copied().unwrap_or(0));
            if self.list_codes {
                t += "  code      entry          DN     step   offset\n";
                for k in 0..a.entries.len() {
                    let step = if k == 0 { f64::NAN } else { a.step_dn[k - 1] };
                    t += &format!("  {k:4} {:10} {:11.5} {:8.5} {:+8.5}\n", a.entries[k], crate::infra::dims::units_to_dn(a.entries[k].into(), a.entries.len()), step, a.cumulative_offset_dn[k]);
                }
            }
        }
        t
    }
}

/// `lut inspect FILE`: a LUT in any format, its tables as the core loads them. The text
/// lists every code when the caller sets `list_codes`.
pub fn inspect(path: &Path) -> Result<InspectSummary, HostError> {
    let (kind, lut) = super::read(path)?;
    super::validate(&lut, path)?;
    let bit_depth = lut.bit_depth();
    let (adcs, common_trend) = tables(lut.tables);
    Ok(InspectSummary { path: path.into(), kind, bit_depth, adcs, common_trend, list_codes: false })
}

/// Each table as `lut inspect` shows it, and the response curve they share, if any.
fn tables(tables: Vec<Vec<u32>>) -> (Vec<InspectAdc>, Option<CommonTrend>) {
    let adcs = tables
        .into_iter()
        .enumerate()
        .map(|(adc, entries)| {
            let dn: Vec<f64> = entries.iter().map(|&e| crate::infra::dims::units_to_dn(e.into(), entries.len())).collect();
            let step_dn: Vec<f64> = dn.windows(2).map(|p| p[1] - p[0]).collect();
            let cumulative_offset_dn: Vec<f64> = dn.iter().enumerate().map(|(k, v)| v - (k as f64 + 0.5)).collect();
            let Trend { c: trend_dn, bow_dn: trend_bow_dn, max_residual_dn: detrended_max_abs_offset_dn } = Trend::of(&dn);
            InspectAdc {
                trend_dn,
                trend_bow_dn,
                detrended_max_abs_offset_dn,
                adc,
                max_abs_offset_dn: cumulative_offset_dn.iter().fold(0.0, |m: f64, o| m.max(o.abs())),
                step_range: (step_dn.iter().cloned().fold(f64::INFINITY, f64::min), step_dn.iter().cloned().fold(f64::NEG_INFINITY, f64::max)),
                entries,
                step_dn,
                cumulative_offset_dn,
            }
        })
        .collect::<Vec<_>>();
    let codes = adcs.first().map_or(0, |a| a.entries.len());
    let common = common_trend(&adcs, codes);
    (adcs, common)
}

/// One table's cubic trend (module documentation).
struct Trend {
    c: [f64; 4],
    bow_dn: f64,
    max_residual_dn: f64,
}

impl Trend {
    fn of(dn: &[f64]) -> Trend {
        let n = dn.len();
        let fitted = first_fitted(n)..=n.saturating_sub(2);
        let Some(c) = cubic_fit(dn, fitted.clone()) else {
            return Trend { c: [f64::NAN; 4], bow_dn: f64::NAN, max_residual_dn: f64::NAN };
        };
        let bow_dn = cubic_bow(&c, n);
        let max_residual_dn = fitted.map(|k| (dn[k] - cubic_at(&c, k, n)).abs()).fold(0.0, f64::max);
        Trend { c, bow_dn, max_residual_dn }
    }
}

/// The response curve the tables share, where every table's trend bends by at least
/// [`TREND_MIN_BOW_DN`] and [`TREND_OVER_RESIDUAL`] times what it leaves, and no trend
/// differs from their mean by more than [`TREND_MAX_SPREAD`] of its bow.
fn common_trend(adcs: &[InspectAdc], codes: usize) -> Option<CommonTrend> {
    let smooth = |a: &InspectAdc| a.trend_bow_dn >= TREND_MIN_BOW_DN && a.trend_bow_dn >= TREND_OVER_RESIDUAL * a.detrended_max_abs_offset_dn;
    // (One table has nothing to share a curve with.)
    if adcs.len() < 2 || !adcs.iter().all(smooth) {
        return None;
    }
    let mean: [f64; 4] = std::array::from_fn(|p| adcs.iter().map(|a| a.trend_dn[p]).sum::<f64>() / adcs.len() as f64);
    let bow_dn = cubic_bow(&mean, codes);
    let spread_dn = adcs.iter().flat_map(|a| (0..codes).map(move |k| (cubic_at(&a.trend_dn, k, codes) - cubic_at(&mean, k, codes)).abs())).fold(0.0, f64::max);
    (spread_dn <= TREND_MAX_SPREAD * bow_dn).then_some(CommonTrend { bow_dn, spread_dn })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Entries (2^-11 DN) of a 12-bit table: code centres `k + 1/2`, plus `bend(x)` and a
    /// fine pattern `ripple_dn * sin(2 pi k / 64 + phase)` of one ADC.
    fn planted(bend: impl Fn(f64) -> f64, ripple_dn: f64, phase: f64) -> Vec<u32> {
        (0..4096)
            .map(|k| {
                let x = k as f64 / 4095.0;
                let dn = k as f64 + 0.5 + bend(x) + ripple_dn * (std::f64::consts::TAU * k as f64 / 64.0 + phase).sin();
                (dn * 2048.0).round() as u32
            })
            .collect()
    }

    /// A 250 DN bow shared by four tables (the K-Cor tables' size) is named a common
    /// trend with its bow; taken out, each table's offset is its planted 0.3-0.6 DN
    /// ripple (within 5%: the cubic fitted to the whole table also bends a little with
    /// the sine, which adds 2-3% here, as numpy's polyfit gives too), while the raw offset
    /// is the bow's size.
    #[test]
    fn a_shared_response_curve_is_named_and_taken_out() {
        // Zero at both ends, about 250 DN near mid-range, a little lopsided: a true cubic.
        let bend = |x: f64| 1000.0 * x * (1.0 - x) * (0.9 + 0.2 * x);
        let ripples = [0.3, 0.4, 0.5, 0.6];
        let (adcs, common) = tables(ripples.iter().enumerate().map(|(a, &r)| planted(bend, r, a as f64)).collect());
        let bow = (0..4096).map(|k| bend(k as f64 / 4095.0)).fold(0.0, f64::max);
        let common = common.expect("a common trend");
        assert!((common.bow_dn - bow).abs() < 0.05, "{} vs planted {bow}", common.bow_dn);
        assert!(common.spread_dn < 0.05, "{}", common.spread_dn);
        for (a, r) in adcs.iter().zip(ripples) {
            assert!((a.detrended_max_abs_offset_dn - r).abs() < 0.05 * r, "ADC {}: {} vs planted {r}", a.adc, a.detrended_max_abs_offset_dn);
            assert!(a.max_abs_offset_dn > 0.9 * bow, "{}", a.max_abs_offset_dn);
        }
    }

    /// Tables of DN error alone (no bend), tables whose bends differ from ADC to ADC, and
    /// a bend no larger than the DN error are not a common trend.
    #[test]
    fn ripples_alone_or_bends_that_differ_are_not_a_common_trend() {
        let flat: Vec<Vec<u32>> = (0..4).map(|a| planted(|_| 0.0, 0.4, a as f64)).collect();
        assert!(tables(flat).1.is_none());
        let different: Vec<Vec<u32>> = (0..4).map(|a| planted(move |x| (100.0 + 60.0 * a as f64) * 4.0 * x * (1.0 - x), 0.4, 0.0)).collect();
        assert!(tables(different).1.is_none());
        let small: Vec<Vec<u32>> = (0..4).map(|a| planted(|x| 3.0 * 4.0 * x * (1.0 - x), 0.4, a as f64)).collect();
        assert!(tables(small).1.is_none());
    }
}
