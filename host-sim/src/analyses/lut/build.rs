//! From a histogram set to LUTs: the ADCs' histograms flattened
//! ([`crate::analyses::flatten::flatten_set`], by the paper's recipe or with one shared
//! illumination), the weights quantized to the core's grid, the core's
//! LUT set built by its rounding rule ([`crate::formats::lut`]), and every entry checked
//! against the independent float reference ([`crate::model::reference`]) of the same
//! weights. `lut build`, `adc` and `stream --hist` call it.

use crate::Origin;

use dncal_core::Weight;
use serde::Serialize;

use crate::analyses::flatten::{flatten_set, to_core_weights, FlattenParams, Flattened};
use crate::formats::fits::AdcHistograms;
use crate::formats::lut::Lut;
use crate::HostError;

/// The LUT of one ADC, summarized.
#[derive(Debug, Clone, Serialize)]
pub struct AdcLutSummary {
    /// ADC index.
    pub adc: usize,
    /// Cumulative offset at the top code before normalization, DN.
    pub top_offset_before_dn: f64,
    /// Cumulative offset at the top code after normalization, DN (~0).
    pub top_offset_dn: f64,
    /// Largest |cumulative offset| over the codes, DN.
    pub max_abs_offset_dn: f64,
    /// Smallest and largest weight of the inner codes.
    pub weight_range: (f64, f64),
    /// Top entry, LUT units: 2^-11 DN up to 12-bit codes, `dncal_core::frac_bits` (must be below 2^23).
    pub top_entry: u32,
}

/// The LUTs built from a histogram set: weights, flattening details, core tables, image.
pub struct BuiltLuts {
    /// Flattening results per ADC.
    pub flattened: Vec<Flattened>,
    /// The weights the core received, per ADC.
    pub weights: Vec<Vec<Weight>>,
    /// The core's entries, per ADC.
    pub tables: Vec<Vec<u32>>,
    /// The device image.
    pub image: Vec<u8>,
}

impl BuiltLuts {
    /// The LUT set (entries and the weights they were built from).
    pub fn lut(&self) -> Lut {
        Lut { tables: self.tables.clone(), weights: Some(self.weights.clone()), kcor_bits: None }
    }

    /// Each ADC's summary.
    pub fn summaries(&self) -> Vec<AdcLutSummary> {
        self.flattened.iter().zip(&self.tables).enumerate().map(|(a, (f, t))| summarize(a, f, t)).collect()
    }
}

/// Flattens `hist` and builds the LUT set in the core; `source` names the input in errors.
pub fn build_luts(hist: &AdcHistograms, params: &FlattenParams, source: impl Into<Origin>) -> Result<BuiltLuts, HostError> {
    let source = source.into();
    let flattened = flatten_set(&hist.counts, params).map_err(|(adc, e)| match adc {
        Some(adc) => HostError::AdcFlatten { origin: source.clone(), adc, source: e },
        None => HostError::SharedFlatten { origin: source.clone(), source: e },
    })?;
    let weights = flattened
        .iter()
        .enumerate()
        .map(|(adc, f)| to_core_weights(&f.weights).map_err(|e| HostError::AdcFlatten { origin: source.clone(), adc, source: e }))
        .collect::<Result<Vec<_>, _>>()?;
    let (tables, image) = crate::formats::lut::tables_from_weights(&weights, &source)?;
    // The independent float reference must reproduce every entry.
    let reference = crate::model::reference::ReferenceLut::from_weights(&weights.iter().map(|w| w.iter().map(|x| x.to_num::<f64>()).collect()).collect::<Vec<_>>());
    for (adc, (q, t)) in reference.quantized().iter().zip(&tables).enumerate() {
        if let Some(k) = (0..t.len()).find(|&k| q[k] != t[k] as u64) {
            return Err(HostError::lut(source.clone(), crate::formats::lut::LutFault::CoreDiffersFromReference { adc, code: k, core: t[k], reference: q[k] }));
        }
    }
    Ok(BuiltLuts { flattened, weights, tables, image })
}

/// Bytes per count that building a set's LUTs holds beside the counts read: each ADC's
/// flattening (its spline and running median, the weights), the IEEE 1241 test of every
/// ADC (`lut build`, `adc`) and the core's tables, weights and device image (measured:
/// 115 bytes a count from 1 to 8 ADCs of 4096 codes; counted with room, 232).
pub const LUT_BYTES_PER_COUNT: u64 = 232;

/// What a command that builds LUTs from a histogram set (`lut build`, `adc --hist`,
/// `stream --hist`) asks of the set's header before reading its counts: ADCs and codes
/// the core is built for (1024 ADCs were read, 191 MB, before this refusal), then the
/// counts read and the LUTs built within the memory budget, `path` named in either
/// refusal.
pub fn plan_luts(path: &std::path::Path, shape: &crate::formats::fits::HistogramShape) -> Result<(), HostError> {
    fn supported<const N: usize, const CODES: usize>() -> Result<(), HostError> {
        Ok(())
    }
    crate::dispatch_lut_dims!(shape.n_adc, shape.codes, path, supported())?;
    let counts = shape.counts();
    crate::infra::budget::Need::new()
        .with("the counts as read", crate::infra::budget::bytes_of(counts, crate::formats::fits::READ_BYTES_PER_COUNT))
        .with("the flattening, the IEEE 1241 test and the tables", crate::infra::budget::bytes_of(counts, LUT_BYTES_PER_COUNT))
        .with("the file decompressed", shape.resident)
        .check(path, &format!("building the LUTs of {} ADCs of {} codes", shape.n_adc, shape.codes))
}

/// One ADC's summary from its flattening and its core table.
pub fn summarize(adc: usize, f: &Flattened, table: &[u32]) -> AdcLutSummary {
    let n = f.weights.len();
    let offsets = crate::analyses::flatten::cumulative_offsets(&f.weights);
    let inner = &f.weights[1..n - 1];
    AdcLutSummary {
        adc,
        top_offset_before_dn: f.top_offset_before_dn,
        top_offset_dn: f.top_offset_dn,
        max_abs_offset_dn: offsets.iter().fold(0.0, |m: f64, o| m.max(o.abs())),
        weight_range: (inner.iter().cloned().fold(f64::INFINITY, f64::min), inner.iter().cloned().fold(f64::NEG_INFINITY, f64::max)),
        top_entry: table.last().copied().unwrap_or(0),
    }
}
