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

use super::{Lut, LutFault};
use crate::{HostError, Origin};

/// Codes per K-Cor table (12-bit ADCs).
pub const KCOR_CODES: usize = 4096;
/// The full-scale values the deployed tables use: `2^22 - 1` and `2^23 - 1`.
pub const KCOR_SCALINGS: [u32; 2] = [22, 23];
/// The largest file read as a K-Cor table: 1 MiB, so that a table of the wrong length is
/// still read and named by [`KcorTable::parse`], and a stream without end is not read.
const TABLE_FILE_LIMIT: crate::formats::input::SizeLimit = crate::formats::input::SizeLimit { what: "K-Cor table", bytes: 1 << 20 };
/// Bytes of one table file.
pub const FILE_BYTES: usize = 4 * KCOR_CODES;
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
        let err = |fault: LutFault| HostError::lut(path, fault);
        if bytes.len() != FILE_BYTES {
            return Err(err(LutFault::KcorSize { bytes: bytes.len() }));
        }
        let entries: Vec<u32> = bytes.chunks_exact(4).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
        let top = entries[KCOR_CODES - 1];
        let Some(bits) = KCOR_SCALINGS.into_iter().find(|&b| top == (1u32 << b) - 1) else {
            return Err(err(LutFault::KcorTop { top }));
        };
        if let Some(k) = (1..KCOR_CODES).find(|&k| entries[k] < entries[k - 1]) {
            return Err(err(LutFault::KcorDecreasing { code: k, entry: entries[k], previous: entries[k - 1] }));
        }
        Ok(KcorTable { bits, entries })
    }

    /// Reads one deployed file.
    pub fn read(path: &Path) -> Result<KcorTable, HostError> {
        let bytes = crate::formats::input::read_regular(path, TABLE_FILE_LIMIT)?;
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
                let cumulative = rne((e as u128 * FULL_SCALE_DN) << dncal_core::WEIGHT_FRAC_BITS, den);
                let w = cumulative - below;
                below = cumulative;
                u32::try_from(w)
                    .map(Weight::from_bits)
                    .map_err(|_| HostError::lut(path, LutFault::KcorWideCode { code: k, width_dn: w as f64 / (1u64 << dncal_core::WEIGHT_FRAC_BITS) as f64 }))
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
            [] => return Err(HostError::lut(prefix, LutFault::NoFileForAdc { adc, stem: stem.clone(), tag, dir: dir.to_path_buf() })),
            _ => return Err(HostError::lut(prefix, LutFault::SeveralFilesForAdc { adc, files: found.iter().map(|s| s.to_string()).collect() })),
        }
    }
    Ok(out)
}

/// The four files `specs` names (`--kcor`): one spec (a prefix or a path with `{adc}`,
/// [`expand`]), or four paths.
pub fn files(specs: &[String]) -> Result<[PathBuf; 4], HostError> {
    match specs {
        [one] => expand(one),
        [a, b, c, d] => {
            let files = [a, b, c, d].map(PathBuf::from);
            // By position, unless a name says another ADC (issue 43: `adc3 adc2 adc1
            // adc0` was taken in that order without a word).
            for (position, f) in files.iter().enumerate() {
                match f.file_name().and_then(|n| adc_in_name(&n.to_string_lossy())) {
                    Some(named) if named != position => return Err(HostError::lut(f, LutFault::AdcOutOfOrder { named, position })),
                    _ => {}
                }
            }
            Ok(files)
        }
        _ => Err(HostError::Argument { flag: "--kcor".into(), message: format!("{} files given; give the four tables of ADC 0-3, or one prefix", specs.len()) }),
    }
}

/// The ADC a table's file name says: the number after `adc` (`..._adc3_...`), where the
/// name has exactly one such number.
pub fn adc_in_name(name: &str) -> Option<usize> {
    let lower = name.to_ascii_lowercase();
    let mut found = lower.match_indices("adc").filter_map(|(i, _)| {
        let digits: String = lower[i + 3..].chars().take_while(char::is_ascii_digit).collect();
        digits.parse::<usize>().ok()
    });
    let first = found.next()?;
    found.all(|n| n == first).then_some(first)
}

/// The four files of the camera whose table `path` is: its name with `adcN` read as
/// `adc{adc}` ([`expand`]). A name that does not say its ADC is an error.
pub fn siblings(path: &Path) -> Result<[PathBuf; 4], HostError> {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let tags: Vec<String> = (0..4).map(|a| format!("adc{a}")).filter(|t| name.contains(t.as_str())).collect();
    match &tags[..] {
        [tag] => expand(&path.with_file_name(name.replacen(tag.as_str(), "adc{adc}", 1)).to_string_lossy()),
        _ => Err(HostError::lut(path, LutFault::NameWithoutAdc)),
    }
}

/// Reads a camera's four tables (ADC 0 to 3), which must share a scaling, as deployed
/// and as a [`Lut`] (the core's entries from their code widths).
pub fn read_set(files: &[PathBuf; 4]) -> Result<(Vec<KcorTable>, Lut), HostError> {
    let tables: Vec<KcorTable> = files.iter().map(|p| KcorTable::read(p)).collect::<Result<_, _>>()?;
    let bits = tables[0].bits;
    if let Some((i, t)) = tables.iter().enumerate().find(|(_, t)| t.bits != bits) {
        return Err(HostError::lut(&files[i], LutFault::ScalingDiffers { bits: t.bits, first_bits: bits }));
    }
    let weights: Vec<Vec<Weight>> = tables.iter().zip(files).map(|(t, p)| t.weights(p)).collect::<Result<_, _>>()?;
    let (ours, _) = super::tables_from_weights(&weights, &files[0].as_path().into())?;
    Ok((tables, Lut { tables: ours, weights: Some(weights), kcor_bits: Some(bits) }))
}

/// The four K-Cor tables of `lut`, from its code widths, at scaling `bits` (default the
/// LUT's own K-Cor scaling, else 23). The widths must rebuild the LUT's entries in the
/// core (else the file was edited and the two disagree); `source` names the LUT's file.
pub fn tables_of(lut: &Lut, bits: Option<u32>, source: &Origin) -> Result<Vec<KcorTable>, HostError> {
    let err = |fault: LutFault| HostError::lut(source.clone(), fault);
    let codes = lut.tables.first().map_or(0, Vec::len);
    if lut.tables.len() != 4 || codes != KCOR_CODES {
        return Err(err(LutFault::NotKcorShape { n_adc: lut.tables.len(), codes }));
    }
    let Some(weights) = &lut.weights else {
        return Err(err(LutFault::NoWeights));
    };
    let bits = bits.or(lut.kcor_bits).unwrap_or(23);
    if !KCOR_SCALINGS.contains(&bits) {
        return Err(err(LutFault::KcorBits { bits }));
    }
    let (rebuilt, _) = super::tables_from_weights(weights, source)?;
    if let Some(adc) = (0..4).find(|&a| rebuilt[a] != lut.tables[a]) {
        return Err(err(LutFault::WeightsDisagree { adc }));
    }
    weights.iter().enumerate().map(|(adc, w)| KcorTable::from_weights(w, bits).ok_or_else(|| err(LutFault::ZeroWeights { adc }))).collect()
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

// What a deployed table says about its ADC: the slow trend (the global response
// correction the tables carry) and, divided out, the DN error (`dncal adc --from-luts`,
// [`crate::analyses::real_adcs`], and camera models with `adc.widths_from`). The trend is
// a cubic `P(x)` in `x = k / 4095` fitted over the calibrated codes; the DN error is
// `r_k = (t_k - t_{k-1}) / (P(x_k) - P(x_{k-1})) - 1` and the cumulative offset
// `o_k = t_k - P(x_k)` (DN).

/// The first code the recipe calibrated (entries below are the recipe's constant).
pub const FIRST_CALIBRATED: usize = 150;
/// The last calibrated code (the recipe sets the last histogram value).
pub const LAST_CALIBRATED: usize = KCOR_CODES - 2;

/// `x = k / 4095` of code k.
pub fn x(k: usize) -> f64 {
    k as f64 / (KCOR_CODES - 1) as f64
}

/// A table's cubic trend and what it leaves (module documentation).
pub struct Detrended {
    /// The cubic's coefficients, DN.
    pub c: [f64; 4],
    /// `r_k`, k in 151..=4094.
    pub dn_error: Vec<f64>,
    /// `o_k`, k in 150..=4094.
    pub offsets: Vec<f64>,
}

impl KcorTable {
    /// The table's cubic trend and what it leaves: the ADC's DN error and cumulative
    /// offsets (module documentation).
    pub fn detrended(&self) -> Detrended {
        let table = self;
        let unit = (KCOR_CODES - 1) as f64 / ((1u64 << table.bits) - 1) as f64;
        let t: Vec<f64> = table.entries.iter().map(|&e| e as f64 * unit).collect();
        let cal = FIRST_CALIBRATED..=LAST_CALIBRATED;
        let c = crate::infra::stats::cubic_fit(&t, cal.clone()).unwrap_or([0.0; 4]);
        let dn_error = (FIRST_CALIBRATED + 1..=LAST_CALIBRATED).map(|k| (t[k] - t[k - 1]) / (cubic(&c, k) - cubic(&c, k - 1)) - 1.0).collect();
        let offsets = cal.map(|k| t[k] - cubic(&c, k)).collect();
        Detrended { c, dn_error, offsets }
    }
}

/// The cubic `c` at code k, DN.
pub fn cubic(c: &[f64; 4], k: usize) -> f64 {
    crate::infra::stats::cubic_at(c, k, KCOR_CODES)
}

/// The code widths of a real ADC for the camera model: 1 outside the calibrated codes,
/// `1 + r_k` inside (the table's DN error without its trend), normalized to mean 1.
pub fn model_widths(table: &KcorTable) -> Vec<f64> {
    let mut w = vec![1.0; KCOR_CODES];
    for (i, r) in table.detrended().dn_error.iter().enumerate() {
        w[FIRST_CALIBRATED + 1 + i] = 1.0 + r;
    }
    let m = w.iter().sum::<f64>() / w.len() as f64;
    w.iter().map(|v| v / m).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A table of a planted width pattern at both scalings: weights -> table -> weights ->
    /// table is the identity on the table, and the weights come back within 2^-24 DN of
    /// the planted widths rescaled to 4095 DN (a naive float sum).
    /// Issue 43: four tables given out of order are refused by the name of the first
    /// that its place contradicts; names without an ADC are taken by place.
    #[test]
    fn four_tables_are_taken_in_the_order_their_names_say() {
        assert_eq!(adc_in_name("Photonfocus_MV-D1024E_13889_adc3_20131203.bin"), Some(3));
        assert_eq!(adc_in_name("k_ADC12.bin"), Some(12));
        assert_eq!(adc_in_name("adc1_of_adc2.bin"), None);
        assert_eq!(adc_in_name("table.bin"), None);
        let given = |names: [&str; 4]| files(&names.map(String::from));
        let e = given(["k_adc3.bin", "k_adc2.bin", "k_adc1.bin", "k_adc0.bin"]).unwrap_err().to_string();
        assert_eq!(e, "k_adc3.bin: its name says ADC 3, but it is given as table 1 of four (ADC 0): give the tables in ADC order 0 to 3, or one prefix");
        assert_eq!(given(["k_adc0.bin", "k_adc1.bin", "k_adc2.bin", "k_adc3.bin"]).unwrap()[3], PathBuf::from("k_adc3.bin"));
        assert_eq!(given(["a.bin", "b.bin", "c.bin", "d.bin"]).unwrap()[1], PathBuf::from("b.bin"));
    }

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
    fn rne_rounds_the_exact_quotient_half_to_even() {
        // Worked by hand: below, at and above each half, even and odd quotients.
        for (num, den, want) in [(0, 3, 0), (1, 3, 0), (2, 3, 1), (4, 2, 2), (5, 2, 2), (7, 2, 4), (9, 4, 2), (10, 4, 2), (14, 4, 4), (11, 4, 3), (29, 10, 3), (25, 10, 2), (35, 10, 4)] {
            assert_eq!(rne(num, den), want, "{num} / {den}");
        }
        // Against f64's round_ties_even: its division is correctly rounded, and no
        // quotient here lies within an ulp of a half without being one.
        for num in 0..2000u128 {
            for den in [1u128, 2, 3, 8, 10, 4095, 8388607] {
                assert_eq!(rne(num, den) as f64, (num as f64 / den as f64).round_ties_even(), "{num} / {den}");
            }
        }
        // Beyond u64, where the K-Cor weights live (entries times 4095, shifted by 24 bits).
        let big = (8388607u128 * 4095) << 24;
        assert_eq!(rne(big + 1, 2), big >> 1);
        assert_eq!(rne(big + 3, 2), (big >> 1) + 2);
    }

    #[test]
    fn bad_tables_are_errors_naming_the_problem() {
        let p = Path::new("x.bin");
        let msg = |b: &[u8]| match KcorTable::parse(b, p) {
            Err(HostError::Lut { fault, .. }) => fault.to_string(),
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
            Err(HostError::Lut { fault: LutFault::KcorWideCode { code: 100, width_dn }, .. }) => assert!(width_dn > 256.0, "{width_dn}"),
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
