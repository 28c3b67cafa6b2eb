//! LUT files: per ADC the corrected value of every code, unsigned 32-bit, in units of
//! 2^-FRACBITS DN (`docs/formats.md`, section 3).

use super::*;

/// Per-ADC lookup tables as exchanged; the core validates them again when it loads them.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LutTables {
    /// Fractional bits of every entry; must be the core's for the tables' depth
    /// ([`dncal_core::frac_bits`]: 11 up to 12 bits, `23 - bits` above).
    pub frac_bits: u32,
    /// `tables[adc][code]`: corrected value of `code` in units of 2^-frac_bits DN.
    pub tables: Vec<Vec<u32>>,
    /// The per-code weights the core built the tables from (raw bits of
    /// [`dncal_core::Weight`], 2^-24 DN), extension `WEIGHTS`: what `lut export` needs
    /// (the centers alone do not determine the code widths). `None` in files without it.
    pub weights: Option<Vec<Vec<u32>>>,
    /// For tables imported from K-Coronagraph files, their scaling `B` (last entry
    /// `2^B - 1`), key `KCORBITS`: `lut export --format kcor` writes it by default.
    pub kcor_bits: Option<u32>,
}

impl LutTables {
    /// Number of ADCs (table rows).
    pub fn n_adc(&self) -> usize {
        self.tables.len()
    }
}

// ---------------------------------------------------------------------------------------
// Writing

/// Writes LUTs atomically: see [`stage_lut`].
pub fn write_lut(path: &Path, lut: &LutTables) -> Result<(), HostError> {
    write_one(|out| stage_lut(out, path, lut))
}

/// Stages LUTs in `out`: primary image of `NADC` rows x `2^BITDEPTH` codes, unsigned
/// 32-bit (BITPIX 32 with BZERO 2^31, which astropy reads as uint32), with `FRACBITS`.
pub fn stage_lut(out: &mut Outputs, path: &Path, lut: &LutTables) -> Result<(), HostError> {
    let bit_depth = check_lut(lut).map_err(fault(path))?;
    let flat: Vec<u32> = lut.tables.concat();
    out.write(path, |tmp| {
        let codes = 1usize << bit_depth;
        let mut fits = FitsWriter::create(tmp, path, ImageType::UnsignedLong, &[lut.n_adc(), codes])?;
        fits.adc_keys(bit_depth, lut.n_adc())?;
        fits.key("FRACBITS", (i64::from(lut.frac_bits), "entries in units of 2^-FRACBITS DN"))?;
        if let Some(b) = lut.kcor_bits {
            fits.key("KCORBITS", (i64::from(b), "imported from K-Cor tables ending at 2^KCORBITS - 1"))?;
        }
        fits.image(&flat)?;
        if let Some(w) = &lut.weights {
            fits.add_image("WEIGHTS", ImageType::UnsignedLong, &[lut.n_adc(), codes])?;
            fits.key("FRACBITS", (24, "code widths in units of 2^-FRACBITS DN"))?;
            fits.image(&w.concat())?;
        }
        fits.finish()
    })
}

/// Reads LUTs. Accepts any integer image whose values fit in 32 unsigned bits; rejects a
/// shape other than `NADC` x `2^BITDEPTH`, missing or invalid keys, and `FRACBITS` other
/// than the core's for `BITDEPTH` ([`crate::infra::dims::lut_frac_bits`]).
pub fn read_lut(path: &Path) -> Result<LutTables, HostError> {
    let mut r = FitsReader::open(path)?;
    r.expect_kind(FileKind::Lut)?;
    let (bit_depth, n_adc, codes) = r.adc_keys()?;
    let frac_bits = r.required_int(0, PRIMARY, "FRACBITS")?;
    let expected = crate::infra::dims::lut_frac_bits(bit_depth);
    if frac_bits != i64::from(expected) {
        return Err(r.error(format!("FRACBITS = {frac_bits}, dncal LUT entries of {bit_depth}-bit codes have {expected} fractional bits")));
    }
    let image = r.image(0, PRIMARY, 2)?;
    r.check_adc_image_shape(&image, codes, n_adc, bit_depth)?;
    let flat: Vec<u32> = r.integer_pixels(&image, "LUT entries")?.convert().map_err(|(i, v)| {
        r.error(format!("entry {v} at ADC {}, code {} is outside 0 to 2^32 - 1", i / codes, i % codes))
    })?;
    let tables = flat.chunks(codes).map(<[u32]>::to_vec).collect();
    let kcor_bits = match r.int_key(0, PRIMARY, "KCORBITS")? {
        None => None,
        Some(b) if b == 22 || b == 23 => Some(b as u32),
        Some(b) => return Err(r.error(format!("KCORBITS = {b}; K-Cor tables end at 2^22 - 1 or 2^23 - 1"))),
    };
    let weights = match r.extension("WEIGHTS")? {
        None => None,
        Some(hdu) => {
            let frac = r.required_int(hdu, "extension WEIGHTS", "FRACBITS")?;
            if frac != 24 {
                return Err(r.error(format!("extension WEIGHTS has FRACBITS = {frac}; dncal weights have 24")));
            }
            let w_image = r.image(hdu, "extension WEIGHTS", 2)?;
            if w_image.naxes != image.naxes {
                return Err(r.error(format!("extension WEIGHTS is {} but the tables are {}", shape_text(&w_image.naxes), shape_text(&image.naxes))));
            }
            let flat: Vec<u32> = r.integer_pixels(&w_image, "weights")?.convert().map_err(|(i, v)| {
                r.error(format!("weight {v} at ADC {}, code {} is outside 0 to 2^32 - 1", i / codes, i % codes))
            })?;
            Some(flat.chunks(codes).map(<[u32]>::to_vec).collect())
        }
    };
    Ok(LutTables { frac_bits: expected, tables, weights, kcor_bits })
}

/// A LUT set's bit depth, from its table length, after checking it is writable.
pub(super) fn check_lut(lut: &LutTables) -> Result<u32, Fault> {
    let codes = lut.tables.first().map_or(0, Vec::len);
    if !codes.is_power_of_two() {
        return Err(Fault::TableLength(codes));
    }
    let bit_depth = codes.trailing_zeros();
    let expected = crate::infra::dims::lut_frac_bits(bit_depth);
    if lut.frac_bits != expected {
        return Err(Fault::FracBits { got: lut.frac_bits, bits: bit_depth, expected });
    }
    check_tables(bit_depth, &lut.tables, "entries")?;
    if let Some(w) = &lut.weights {
        if w.len() != lut.tables.len() {
            return Err(Fault::WeightRows { weights: w.len(), tables: lut.tables.len() });
        }
        check_tables(bit_depth, w, "weights")?;
    }
    Ok(bit_depth)
}
