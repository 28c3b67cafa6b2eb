//! The K-Coronagraph's deployed DN-error tables (NCAR kcor-pipeline, `observing/LUTs`):
//! reading, writing, and their relation to dncal's LUTs.
//!
//! ## Their format
//! One file per ADC (column c read by ADC c mod 4), 4096 little-endian `u32` entries, one
//! per 12-bit code; the DAQ adds `table[code]` into a 32-bit sum per pixel, 512 frames per
//! modulation state. Entry 0 is 0 and the last entry is the top of the range, `2^B - 1`
//! with `B` = 22 (the 20131106 tables) or 23 (20131203: "LUTs change from 2^22 to 2^23",
//! kcor-pipeline `src/epochs.cfg`). Entry k is the paper's inclusive cumulative sum up to
//! code k, scaled so that the last entry is `2^B - 1` and rounded; entries 0-149 are
//! identical across a camera's four ADCs (the paper sets the first 150 histogram values to
//! one), so entry k includes code k's own width. The K-Cor tables also carry a global
//! cubic response correction (the mean step grows about 1.6 times across the range), so
//! their steps are not code widths alone.
//!
//! ## Ours, and the conversion
//! A dncal LUT maps code k to the *center* of its analog interval in units of 2^-11 DN,
//! built by the core from per-code weights ([`dncal_core::LutSet::from_weights`]); a K-Cor
//! table maps it to the interval's *top* (inclusive sum), full scale `2^B - 1` for 4095 DN
//! (one K-Cor unit is `4095 / (2^B - 1)` DN, 0.012% more than 2^-11 at B = 23). Import
//! reads the table as cumulative widths in DN, `W_k = e_k 4095 / (2^B - 1)`, rounds each
//! `W_k` (not each width) to the weights' 2^-24 DN grid and takes the widths as their
//! differences, so that no rounding accumulates; the core then builds our entries, each
//! the K-Cor value minus half its code's step, rounded to 2^-11 DN (what the conversion
//! loses: the top-of-code reading, and below 2^-12 DN per entry). The widths are kept in
//! the LUT FITS (extension `WEIGHTS`), and export recomputes
//! `e_k = RNE((2^B - 1) W_k / W_top)` from them: for an imported table the cumulative
//! weights are within 2^-25 DN of `e_k 4095 / (2^B - 1)`, which moves `e_k` by less than
//! 1e-4 of a unit, so the export is the deployed file byte for byte (tested on every
//! shared file). A LUT dncal built from histograms exports by the same rule; it keeps code
//! 0's width (a K-Cor table starts at 0), an offset of about one code that dark
//! subtraction removes.

use std::path::{Path, PathBuf};

use dncal_core::Weight;

use crate::HostError;

/// Codes per K-Cor table (12-bit ADCs).
pub const KCOR_CODES: usize = 4096;
/// The full-scale values the deployed tables use: `2^22 - 1` and `2^23 - 1`.
pub const KCOR_SCALINGS: [u32; 2] = [22, 23];
/// The largest file read as a K-Cor table: 1 MiB, so that a table of the wrong length is
/// still read and named by [`KcorTable::parse`], and a stream without end is not read.
const TABLE_FILE_LIMIT: crate::input::SizeLimit = crate::input::SizeLimit { what: "K-Cor table", bytes: 1 << 20 };
/// The weights' fractional bits (a [`Weight`] is U8F24).
const WEIGHT_FRAC_BITS: u32 = 24;
/// The analog range a table spans, bottom of code 0 to top of code 4095, DN.
const FULL_SCALE_DN: u128 = KCOR_CODES as u128 - 1;

/// One ADC's K-Cor table.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct KcorTable {
    /// The scaling: the last entry is `2^bits - 1`.
    pub bits: u32,
    /// The 4096 entries.
    pub entries: Vec<u32>,
}

/// Round half to even of `num / den`, exact.
fn rne(num: u128, den: u128) -> u128 {
    let (q, r) = (num / den, num % den);
    if 2 * r > den || (2 * r == den && q % 2 == 1) {
        q + 1
    } else {
        q
    }
}

impl KcorTable {
    /// Parses a deployed file's bytes; `path` names it in errors.
    pub fn parse(bytes: &[u8], path: &Path) -> Result<KcorTable, HostError> {
        let err = |message: String| HostError::Format { path: path.into(), message };
        if bytes.len() != 4 * KCOR_CODES {
            return Err(err(format!("{} bytes; a K-Cor table is {} little-endian u32 entries ({} bytes)", bytes.len(), KCOR_CODES, 4 * KCOR_CODES)));
        }
        let entries: Vec<u32> = bytes.chunks_exact(4).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
        let top = entries[KCOR_CODES - 1];
        let Some(bits) = KCOR_SCALINGS.into_iter().find(|&b| top == (1u32 << b) - 1) else {
            return Err(err(format!("the last entry is {top}; the deployed tables end at 2^22 - 1 = {} or 2^23 - 1 = {}", (1u32 << 22) - 1, (1u32 << 23) - 1)));
        };
        if let Some(k) = (1..KCOR_CODES).find(|&k| entries[k] < entries[k - 1]) {
            return Err(err(format!("entry {k} ({}) is below entry {} ({}): a table must not decrease", entries[k], k - 1, entries[k - 1])));
        }
        Ok(KcorTable { bits, entries })
    }

    /// Reads one deployed file.
    pub fn read(path: &Path) -> Result<KcorTable, HostError> {
        let bytes = crate::input::read_regular(path, TABLE_FILE_LIMIT)?;
        KcorTable::parse(&bytes, path)
    }

    /// The file's bytes.
    pub fn to_bytes(&self) -> Vec<u8> {
        self.entries.iter().flat_map(|e| e.to_le_bytes()).collect()
    }

    /// The code widths in DN (module documentation): cumulative widths rounded to the
    /// weights' grid, widths their differences. A step of 256 DN or more (a [`Weight`]
    /// holds less) is an error naming the code; `path` names the file.
    pub fn weights(&self, path: &Path) -> Result<Vec<Weight>, HostError> {
        let den = (1u128 << self.bits) - 1;
        let mut below = 0u128;
        self.entries
            .iter()
            .enumerate()
            .map(|(k, &e)| {
                // Non-decreasing entries (checked on parsing) give non-decreasing sums.
                let cumulative = rne((e as u128 * FULL_SCALE_DN) << WEIGHT_FRAC_BITS, den);
                let w = cumulative - below;
                below = cumulative;
                u32::try_from(w).map(Weight::from_bits).map_err(|_| HostError::Format {
                    path: path.into(),
                    message: format!("code {k} is {:.1} DN wide; a dncal LUT holds code widths below 256 DN", w as f64 / (1u64 << WEIGHT_FRAC_BITS) as f64),
                })
            })
            .collect()
    }

    /// The table of code widths `weights` (DN, any normalization) at scaling `bits`:
    /// `e_k = RNE((2^bits - 1) W_k / W_top)`, `W_k` the inclusive sum. `None` if the
    /// weights sum to zero or there are not 4096 of them.
    pub fn from_weights(weights: &[Weight], bits: u32) -> Option<KcorTable> {
        if weights.len() != KCOR_CODES {
            return None;
        }
        let top: u128 = weights.iter().map(|w| w.to_bits() as u128).sum();
        if top == 0 {
            return None;
        }
        let full = (1u128 << bits) - 1;
        let mut cumulative = 0u128;
        let entries = weights
            .iter()
            .map(|w| {
                cumulative += w.to_bits() as u128;
                rne(full * cumulative, top) as u32
            })
            .collect();
        Some(KcorTable { bits, entries })
    }
}

/// The four files of a camera: `spec` is either a path with `{adc}` in it (replaced by
/// 0-3), or a prefix: the files in its folder whose names start with it and contain
/// `adcN`, exactly one per ADC (a prefix that matches two dates is an error listing them).
pub fn expand(spec: &str) -> Result<[PathBuf; 4], HostError> {
    if spec.contains("{adc}") {
        return Ok(std::array::from_fn(|a| PathBuf::from(spec.replace("{adc}", &a.to_string()))));
    }
    let prefix = Path::new(spec);
    let (dir, stem) = match (prefix.parent(), prefix.file_name()) {
        (Some(d), Some(s)) if !spec.ends_with('/') => (if d.as_os_str().is_empty() { Path::new(".") } else { d }, s.to_string_lossy().into_owned()),
        _ => (prefix, String::new()),
    };
    let names: Vec<String> = std::fs::read_dir(dir)
        .map_err(|e| HostError::io(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.file_name().to_string_lossy().into_owned()))
        .filter(|n| n.starts_with(&stem))
        .collect();
    let mut out: [PathBuf; 4] = Default::default();
    for (adc, slot) in out.iter_mut().enumerate() {
        let tag = format!("adc{adc}");
        let mut found: Vec<&String> = names.iter().filter(|n| n.contains(&tag)).collect();
        found.sort();
        match found[..] {
            [one] => *slot = dir.join(one),
            [] => return Err(HostError::Format { path: prefix.into(), message: format!("no file for ADC {adc} (a name starting with '{stem}' and containing '{tag}') in {}", dir.display()) }),
            _ => {
                let list: Vec<&str> = found.iter().map(|s| s.as_str()).collect();
                return Err(HostError::Format {
                    path: prefix.into(),
                    message: format!("{} files for ADC {adc}: {}; give a longer prefix or a path with {{adc}} in it", found.len(), list.join(", ")),
                });
            }
        }
    }
    Ok(out)
}

/// Where export writes ADC `adc`'s table: `prefix` with `{adc}` replaced, or
/// `PREFIX_adcN.bin`.
pub fn export_path(prefix: &str, adc: usize) -> PathBuf {
    if prefix.contains("{adc}") {
        PathBuf::from(prefix.replace("{adc}", &adc.to_string()))
    } else {
        PathBuf::from(format!("{prefix}_adc{adc}.bin"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A table of a planted width pattern at both scalings: weights -> table -> weights ->
    /// table is the identity on the table, and the weights come back within 2^-24 DN of
    /// the planted widths rescaled to 4095 DN (a naive float sum).
    #[test]
    fn tables_and_widths_round_trip() {
        let widths: Vec<f64> = (0..KCOR_CODES).map(|k| if k == 0 { 0.0 } else { 1.0 + 0.03 * ((k * 7919) % 13) as f64 / 13.0 - 0.015 + 2e-4 * k as f64 }).collect();
        let weights: Vec<Weight> = widths.iter().map(|&w| Weight::from_num(w)).collect();
        for bits in KCOR_SCALINGS {
            let t = KcorTable::from_weights(&weights, bits).unwrap();
            assert_eq!(t.entries[0], 0);
            assert_eq!(*t.entries.last().unwrap(), (1 << bits) - 1);
            let back = KcorTable::parse(&t.to_bytes(), Path::new("t.bin")).unwrap();
            assert_eq!(back, t);
            let w2 = back.weights(Path::new("t.bin")).unwrap();
            assert_eq!(KcorTable::from_weights(&w2, bits).unwrap(), t, "bits {bits}");
            // The naive float: cumulative widths scaled to 4095 DN at the top.
            let total: f64 = weights.iter().map(|w| w.to_num::<f64>()).sum();
            let mut cum = 0.0;
            let mut got = 0.0;
            for (w, w2) in weights.iter().zip(&w2) {
                cum += w.to_num::<f64>() * 4095.0 / total;
                got += w2.to_num::<f64>();
                // The table's own rounding: half a unit of 4095 / (2^bits - 1) DN.
                assert!((cum - got).abs() < 0.5 * 4095.0 / ((1u64 << bits) - 1) as f64 + 1e-7, "bits {bits}: {cum} vs {got}");
            }
        }
    }

    #[test]
    fn bad_tables_are_errors_naming_the_problem() {
        let p = Path::new("x.bin");
        let msg = |b: &[u8]| match KcorTable::parse(b, p) {
            Err(HostError::Format { message, .. }) => message,
            other => panic!("{other:?}"),
        };
        assert!(msg(&[0u8; 100]).contains("100 bytes"));
        let mut t: Vec<u32> = (0..KCOR_CODES as u32).map(|k| k * 2048).collect();
        let bytes = |t: &[u32]| t.iter().flat_map(|e| e.to_le_bytes()).collect::<Vec<u8>>();
        assert!(msg(&bytes(&t)).contains("the last entry is"));
        t[4095] = (1 << 23) - 1;
        t[10] = 5;
        assert!(msg(&bytes(&t)).contains("entry 10 (5) is below entry 9"));
        // Valid, but one code 300 DN wide: the weights refuse it rather than wrap.
        let mut wide: Vec<u32> = (0..KCOR_CODES as u32).map(|k| k * 1800).collect();
        for e in &mut wide[100..] {
            *e += 300 * 2048;
        }
        wide[4095] = (1 << 23) - 1;
        let t = KcorTable::parse(&bytes(&wide), p).unwrap();
        match t.weights(p) {
            Err(HostError::Format { message, .. }) => assert!(message.contains("code 100 is") && message.contains("below 256 DN"), "{message}"),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn prefixes_expand_to_one_file_per_adc() {
        let dir = tempfile::tempdir().unwrap();
        for date in ["20131106", "20131203"] {
            for adc in 0..4 {
                std::fs::write(dir.path().join(format!("cam_77_adc{adc}_{date}.bin")), b"").unwrap();
            }
        }
        let spec = |s: &str| dir.path().join(s).to_string_lossy().into_owned();
        let two = expand(&spec("cam_77")).unwrap_err().to_string();
        assert!(two.contains("2 files for ADC 0") && two.contains("cam_77_adc0_20131106.bin"), "{two}");
        let placeholder = expand(&spec("cam_77_adc{adc}_20131203.bin")).unwrap();
        assert_eq!(placeholder[3], dir.path().join("cam_77_adc3_20131203.bin"));
        assert!(expand(&spec("cam_78")).unwrap_err().to_string().contains("no file for ADC 0"));
        assert_eq!(export_path("out/cam", 2), PathBuf::from("out/cam_adc2.bin"));
    }
}
