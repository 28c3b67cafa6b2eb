//! `lut inspect`: what a LUT file holds, in any format ([`super::read`]): each ADC's
//! entries, steps (each the mean width of two neighbouring codes) and cumulative offsets.

use std::path::{Path, PathBuf};

use serde::Serialize;

use super::LutFormat;
use crate::formats::report::Report;
use crate::HostError;

/// One ADC's table as `lut inspect` shows it.
#[derive(Debug, Serialize)]
pub struct InspectAdc {
    /// ADC index.
    pub adc: usize,
    /// Entries, units of 2^-11 DN.
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
    /// Whether the readable text lists every code (`--table`; JSON always has them).
    #[serde(skip)]
    pub list_codes: bool,
}

impl Report for InspectSummary {
    fn text(&self) -> String {
        let mut t = format!("{} ({}, {} bits, {} ADCs)\n", self.path.display(), self.kind, self.bit_depth, self.adcs.len());
        t += "(entry steps: entry k+1 - entry k, the mean width of codes k and k+1; `lut build` reports the single-code widths, a wider range)\n";
        for a in &self.adcs {
            t += &format!("ADC {}: entry steps {:.4}..{:.4} DN, max |cumulative offset| {:.3} DN, top entry {}\n", a.adc, a.step_range.0, a.step_range.1, a.max_abs_offset_dn, a.entries.last().copied().unwrap_or(0));
            if self.list_codes {
                t += "  code      entry          DN     step   offset\n";
                for k in 0..a.entries.len() {
                    let step = if k == 0 { f64::NAN } else { a.step_dn[k - 1] };
                    t += &format!("  {k:4} {:10} {:11.5} {:8.5} {:+8.5}\n", a.entries[k], dncal_core::units_to_dn(a.entries[k].into()), step, a.cumulative_offset_dn[k]);
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
    let adcs = lut
        .tables
        .into_iter()
        .enumerate()
        .map(|(adc, entries)| {
            let dn: Vec<f64> = entries.iter().map(|&e| dncal_core::units_to_dn(e.into())).collect();
            let step_dn: Vec<f64> = dn.windows(2).map(|p| p[1] - p[0]).collect();
            let cumulative_offset_dn: Vec<f64> = dn.iter().enumerate().map(|(k, v)| v - (k as f64 + 0.5)).collect();
            InspectAdc {
                adc,
                max_abs_offset_dn: cumulative_offset_dn.iter().fold(0.0, |m: f64, o| m.max(o.abs())),
                step_range: (step_dn.iter().cloned().fold(f64::INFINITY, f64::min), step_dn.iter().cloned().fold(f64::NEG_INFINITY, f64::max)),
                entries,
                step_dn,
                cumulative_offset_dn,
            }
        })
        .collect();
    Ok(InspectSummary { path: path.into(), kind, bit_depth, adcs, list_codes: false })
}
