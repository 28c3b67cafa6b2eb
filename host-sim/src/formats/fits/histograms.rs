//! Histogram sets: per ADC, samples per code (`docs/formats.md`, section 1).

use super::*;

/// Code histograms of every ADC of a camera, in samples per code.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AdcHistograms {
    /// Bits per code; each ADC has `2^bit_depth` codes.
    pub bit_depth: u32,
    /// `counts[adc][code]`: samples read as `code` by ADC `adc`.
    pub counts: Vec<Vec<u64>>,
}

impl AdcHistograms {
    /// Number of ADCs (histogram rows).
    pub fn n_adc(&self) -> usize {
        self.counts.len()
    }
}

/// Writes a histogram set atomically: see [`stage_histograms`].
pub fn write_histograms(path: &Path, hist: &AdcHistograms) -> Result<(), HostError> {
    write_one(|out| stage_histograms(out, path, hist))
}

/// Stages a histogram set in `out`: primary image of `NADC` rows x `2^BITDEPTH` codes,
/// 64-bit signed (BITPIX 64).
pub fn stage_histograms(out: &mut Outputs, path: &Path, hist: &AdcHistograms) -> Result<(), HostError> {
    let codes = check_tables(hist.bit_depth, &hist.counts, "codes").map_err(fault(path))?;
    let mut flat = Vec::with_capacity(hist.n_adc() * codes);
    for (adc, row) in hist.counts.iter().enumerate() {
        for (code, &n) in row.iter().enumerate() {
            let n = i64::try_from(n).map_err(|_| {
                format_error(path, format!("count {n} (ADC {adc}, code {code}) exceeds BITPIX 64's signed range"))
            })?;
            flat.push(n);
        }
    }
    out.write(path, |tmp| {
        let mut fits = FitsWriter::create(tmp, path, ImageType::LongLong, &[hist.n_adc(), codes])?;
        fits.adc_keys(hist.bit_depth, hist.n_adc())?;
        fits.key("BUNIT", ("count", "samples per code"))?;
        fits.image(&flat)?;
        fits.finish()
    })
}

/// The largest total count of one ADC's histogram the analyses accept: 2^53, where f64 (in
/// which every analysis of the counts runs) stops holding integers exactly. A camera at
/// 40 Ms/s per ADC takes over seven years to fill it; a count of 2^64 - 1 in a file
/// (issue 18: a panic in the binomial split of `diagnose`) is refused.
pub const MAX_HISTOGRAM_TOTAL: u64 = 1 << 53;

/// [`read_histograms`] for an analysis (`lut build`, `adc`, `diagnose`, `stream --hist`):
/// also refuses an ADC whose counts add up to more than [`MAX_HISTOGRAM_TOTAL`]. The
/// format itself holds any `u64` count, and [`read_histograms`] reads them all.
pub fn read_histograms_for_analysis(path: &Path) -> Result<AdcHistograms, HostError> {
    read_histograms_for_analysis_planned(path, |_| Ok(()))
}

/// [`read_histograms_for_analysis`], calling `plan` with the set's shape once its header
/// is read and before any count is: a command refuses there, from the header alone, a
/// set it cannot analyze (the core's ADCs and codes) or whose counts and analysis
/// together would not fit its memory budget.
pub fn read_histograms_for_analysis_planned(path: &Path, plan: impl FnOnce(&HistogramShape) -> Result<(), HostError>) -> Result<AdcHistograms, HostError> {
    let h = read_histograms_planned(path, plan)?;
    for (adc, counts) in h.counts.iter().enumerate() {
        if counts.iter().try_fold(0u64, |t, &c| t.checked_add(c).filter(|&t| t <= MAX_HISTOGRAM_TOTAL)).is_none() {
            return Err(HostError::Format {
                path: path.into(),
                message: format!("the counts of ADC {adc} add up to more than 2^53 ({MAX_HISTOGRAM_TOTAL}), the largest total the analyses' floating point holds exactly"),
            });
        }
    }
    Ok(h)
}

/// Reads a histogram set. Accepts any integer image (BITPIX 8, 16, 32 or 64, with BZERO for
/// unsigned data); rejects float images, negative counts, a shape other than `NADC` x
/// `2^BITDEPTH`, missing or invalid keys, and LUT files (which carry `FRACBITS`).
pub fn read_histograms(path: &Path) -> Result<AdcHistograms, HostError> {
    read_histograms_planned(path, |_| Ok(()))
}

/// What a histogram set's header says it will take to hold, before any count is read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HistogramShape {
    /// Bits per code (`BITDEPTH`).
    pub bit_depth: u32,
    /// ADCs (`NADC`).
    pub n_adc: usize,
    /// Codes per ADC (`2^BITDEPTH`).
    pub codes: usize,
    /// Bytes cfitsio holds of the file itself while it is read: a compressed file's
    /// inflated size (0 for a plain file).
    pub resident: u64,
}

impl HistogramShape {
    /// Counts of the set (ADCs x codes).
    pub fn counts(&self) -> u64 {
        (self.n_adc as u64).saturating_mul(self.codes as u64)
    }
}

/// Bytes the reader holds per count at once: the image as cfitsio reads it (`i64`), the
/// counts converted (`u64`) and split into one row per ADC.
pub const READ_BYTES_PER_COUNT: u64 = 24;

/// [`read_histograms`], calling `plan` with the set's shape once its header is read and
/// before any count is (see [`read_histograms_for_analysis_planned`]).
pub fn read_histograms_planned(path: &Path, plan: impl FnOnce(&HistogramShape) -> Result<(), HostError>) -> Result<AdcHistograms, HostError> {
    let mut r = FitsReader::open(path)?;
    r.expect_kind(FileKind::Histograms)?;
    let (bit_depth, n_adc, codes) = r.adc_keys()?;
    let image = r.image(0, PRIMARY, 2)?;
    r.check_adc_image_shape(&image, codes, n_adc, bit_depth)?;
    plan(&HistogramShape { bit_depth, n_adc, codes, resident: r.resident() })?;
    let flat: Vec<u64> = r
        .integer_pixels(&image, "histogram counts")?
        .convert()
        .map_err(|(i, v)| r.error(format!("count {v} at ADC {}, code {} is negative", i / codes, i % codes)))?;
    let counts = flat.chunks(codes).map(<[u64]>::to_vec).collect();
    Ok(AdcHistograms { bit_depth, counts })
}
