//! FITS interchange: code histograms, linearity sets and LUTs as astronomers exchange them.
//!
//! Three files leave and enter dncal as FITS, so that astropy, ds9 or IDL can open them and
//! so that measurements taken elsewhere can be corrected here (layouts in `docs/formats.md`):
//!
//! - **Histogram set** ([`AdcHistograms`]): per ADC, how many samples of a smooth
//!   illumination ramp fell into each code (counts), from which the code widths in DN are
//!   estimated (de Wijn 2018, section 4). Image `NADC` rows x `2^BITDEPTH` codes.
//! - **Linearity set** ([`LinearitySet`]): mean frame (DN) and per-pixel standard
//!   deviation (DN) at each illumination level, the reference photodiode voltage (V) of
//!   each level (level 0 is dark), and optionally the known-bad pixels.
//! - **LUT file** ([`LutTables`]): per ADC, the corrected value of every code in units of
//!   2^-11 DN ([`dncal_core::FRAC_BITS`] fractional bits), unsigned 32-bit.
//!
//! All three record `ADCMAP = 'COLMOD'`: column `c` is read by ADC `c mod NADC`, as on the
//! PhotonFocus MV-D1024E.
//!
//! ## Robustness
//! Files are written through [`crate::outputs`]: the `stage_*` writers add a file to a
//! command's [`Outputs`], published with its other files or not at all; the `write_*`
//! ones write one file atomically. Either way a failed or rejected write never leaves a
//! half-written file at the destination. Readers check every shape, key and value
//! before returning and answer a truncated, foreign or malformed file with a
//! [`HostError::Format`] naming it. They deliberately avoid the `fitsio` calls that panic on
//! legal FITS they do not expect (unsigned 64-bit images, variable-length or complex table
//! columns): image and table headers are read key by key instead. Paths reach cfitsio only
//! in a form it takes literally (`CfitsioName`): `h.fits[1]` is a file of that name, not
//! HDU 1 of `h.fits`.
//!
//! ```
//! use dncal_host::fits::{read_histograms, write_histograms, AdcHistograms};
//! let dir = tempfile::tempdir().unwrap();
//! let path = dir.path().join("histograms.fits");
//! let hist = AdcHistograms { bit_depth: 2, counts: vec![vec![5, 6, 7, 8]; 4] };
//! write_histograms(&path, &hist)?;
//! assert_eq!(read_histograms(&path)?, hist);
//! # Ok::<(), dncal_host::HostError>(())
//! ```

use std::path::Path;

use dncal_core::FRAC_BITS;
use fitsio::errors::Error as FitsioError;
use fitsio::hdu::{FitsHdu, HduInfo};
use fitsio::headers::WritesKey;
use fitsio::images::{ImageDescription, ImageType, ReadImage, WriteImage};
use fitsio::tables::{ColumnDataType, ColumnDescription};
use fitsio::FitsFile;

use crate::outputs::{write_one, Outputs};
use crate::HostError;

/// The only ADC map dncal knows: column `c` is read by ADC `c mod NADC`.
pub const ADCMAP_COLMOD: &str = "COLMOD";

/// Deepest ADC the formats accept: codes are `u16` throughout dncal.
pub const MAX_BIT_DEPTH: u32 = 16;

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

/// The value type a linearity set's cubes are held in: `f64` (the default, every
/// command that writes from them) or `f32` (`diagnose`, which holds the cubes through the
/// whole run: half the memory, each value to 2^-24 of itself).
pub trait Sample: Copy + Into<f64> + Send + Sync + std::fmt::Display + 'static {
    /// A bound on the variance the type's rounding adds to a value `v`: `(v 2^-24)^2 / 3`
    /// for `f32` (an error uniform within half a last place taken at its widest relative
    /// size; up to 4 times the true variance, negligible beside a mean's noise either
    /// way), 0 for `f64`.
    fn rounding_var(v: f64) -> f64;
}

impl Sample for f64 {
    fn rounding_var(_: f64) -> f64 {
        0.0
    }
}

impl Sample for f32 {
    fn rounding_var(v: f64) -> f64 {
        (v * 2.0f64.powi(-24)).powi(2) / 3.0
    }
}

/// A linearity measurement: frames averaged at illumination levels of known reference
/// voltage.
#[derive(Debug, Clone, PartialEq)]
pub struct LinearitySet<T: Sample = f64> {
    /// Bits per code of the camera.
    pub bit_depth: u32,
    /// ADCs of the camera; column `c` is read by ADC `c mod n_adc`.
    pub n_adc: usize,
    /// Frames averaged at each level.
    pub n_frames: u32,
    /// Columns per frame.
    pub width: usize,
    /// Rows per frame.
    pub height: usize,
    /// Illumination levels; level 0 is dark.
    pub levels: usize,
    /// Mean frames in DN, level-major, then row, then column:
    /// `mean[(level * height + row) * width + column]`.
    pub mean: Vec<T>,
    /// Per-pixel standard deviation of the frames in DN, laid out as `mean`.
    pub std: Vec<T>,
    /// Reference photodiode voltage of each level in V.
    pub voltage: Vec<f64>,
    /// Known bad pixels, `mask[row * width + column]`, 1 = bad, 0 = good.
    pub mask: Option<Vec<u8>>,
}

/// Per-ADC lookup tables as exchanged; the core validates them again when it loads them.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LutTables {
    /// Fractional bits of every entry; must be [`dncal_core::FRAC_BITS`] (11).
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

/// Writes a histogram set atomically: see [`stage_histograms`].
pub fn write_histograms(path: &Path, hist: &AdcHistograms) -> Result<(), HostError> {
    write_one(|out| stage_histograms(out, path, hist))
}

/// Stages a histogram set in `out`: primary image of `NADC` rows x `2^BITDEPTH` codes,
/// 64-bit signed (BITPIX 64).
pub fn stage_histograms(out: &mut Outputs, path: &Path, hist: &AdcHistograms) -> Result<(), HostError> {
    let codes = check_tables(hist.bit_depth, &hist.counts, "codes").map_err(|m| format_error(path, m))?;
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

/// Writes a linearity set atomically: see [`stage_linearity`].
pub fn write_linearity(path: &Path, set: &LinearitySet) -> Result<(), HostError> {
    write_one(|out| stage_linearity(out, path, set))
}

/// Stages a linearity set in `out`: primary float64 cube of mean frames, extensions `STD`
/// (same cube), `MASK` (uint8, when present) and `REFERENCE` (table, column `VOLTAGE`).
pub fn stage_linearity(out: &mut Outputs, path: &Path, set: &LinearitySet) -> Result<(), HostError> {
    check_linearity(set).map_err(|m| format_error(path, m))?;
    out.write(path, |tmp| {
        let cube = [set.levels, set.height, set.width];
        let mut fits = FitsWriter::create(tmp, path, ImageType::Double, &cube)?;
        fits.adc_keys(set.bit_depth, set.n_adc)?;
        fits.key("NFRAMES", (i64::from(set.n_frames), "frames averaged per illumination level"))?;
        fits.key("BUNIT", ("DN", "mean of the frames at each level"))?;
        fits.image(&set.mean)?;
        fits.add_image("STD", ImageType::Double, &cube)?;
        fits.key("BUNIT", ("DN", "standard deviation of the frames"))?;
        fits.image(&set.std)?;
        if let Some(mask) = &set.mask {
            fits.add_image("MASK", ImageType::UnsignedByte, &[set.height, set.width])?;
            fits.image(mask)?;
        }
        // Last, so that a file cut at an HDU boundary lacks a required HDU rather than
        // reading as a valid set without its (optional) mask.
        fits.add_table("REFERENCE", "VOLTAGE", "V", &set.voltage)?;
        fits.finish()
    })
}

/// The pixel-wise correction as written: see [`stage_pixel_correction`].
#[derive(Debug, Clone, Copy)]
pub struct PixelCorrection<'a> {
    /// Coefficient cube, plane-major (`a_k` planes of `height x width`).
    pub coeffs: &'a [f64],
    /// Mask reasons per pixel.
    pub mask: &'a [u8],
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Polynomial order.
    pub order: usize,
    /// Camera bits per code.
    pub bit_depth: u32,
    /// Camera ADCs.
    pub n_adc: usize,
}

/// Stages the pixel-wise nonlinearity correction (`dncal linearity`): a float64 cube of
/// the polynomial coefficients (`NAXIS1` columns, `NAXIS2` rows, `NAXIS3 = ORDER + 1`,
/// plane k holds a_k of `m = sum a_k x^k`, x the normalized reference) and the uint8
/// extension `MASK` (non-zero = masked; bit 1 input mask, 2 low signal, 4 anomalous trend,
/// 8 unfitted).
pub fn stage_pixel_correction(out: &mut Outputs, path: &Path, c: &PixelCorrection) -> Result<(), HostError> {
    let PixelCorrection { coeffs, mask, width, height, order, bit_depth, n_adc } = *c;
    if coeffs.len() != (order + 1) * width * height || mask.len() != width * height {
        return Err(format_error(path, "coefficient cube or mask does not match the frame size"));
    }
    out.write(path, |tmp| {
        let mut fits = FitsWriter::create(tmp, path, ImageType::Double, &[order + 1, height, width])?;
        fits.adc_keys(bit_depth, n_adc)?;
        fits.key("ORDER", (order as i64, "m = sum_k a_k x^k, k = 0..ORDER; x = V / max V"))?;
        fits.key("BUNIT", ("DN", "coefficients give DN"))?;
        fits.image(coeffs)?;
        fits.add_image("MASK", ImageType::UnsignedByte, &[height, width])?;
        fits.image(mask)?;
        fits.finish()
    })
}

/// Stages a float64 cube of `levels` images (`NAXIS3 = levels`) with `BUNIT` `unit` (a
/// unit astropy parses: `DN`, `count`, or empty for a dimensionless quantity, which the
/// comment then names).
pub fn stage_cube(out: &mut Outputs, path: &Path, data: &[f64], levels: usize, width: usize, height: usize, (unit, comment): (&str, &str)) -> Result<(), HostError> {
    if data.len() != levels * width * height {
        return Err(format_error(path, "cube does not match its shape"));
    }
    out.write(path, |tmp| {
        let mut fits = FitsWriter::create(tmp, path, ImageType::Double, &[levels, height, width])?;
        fits.key("BUNIT", (unit.to_string(), comment.to_string()))?;
        fits.image(data)?;
        fits.finish()
    })
}

/// Writes LUTs atomically: see [`stage_lut`].
pub fn write_lut(path: &Path, lut: &LutTables) -> Result<(), HostError> {
    write_one(|out| stage_lut(out, path, lut))
}

/// Stages LUTs in `out`: primary image of `NADC` rows x `2^BITDEPTH` codes, unsigned
/// 32-bit (BITPIX 32 with BZERO 2^31, which astropy reads as uint32), with `FRACBITS`.
pub fn stage_lut(out: &mut Outputs, path: &Path, lut: &LutTables) -> Result<(), HostError> {
    let bit_depth = check_lut(lut).map_err(|m| format_error(path, m))?;
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

/// The parameters of the command being run, every one with the value it took (defaults
/// included), as `main` reads them from the command line: written as a `HISTORY` record
/// into every FITS file the process writes, beside the command line itself.
static PARAMETERS: std::sync::OnceLock<String> = std::sync::OnceLock::new();

/// Records `text` as the run's parameters for [`PARAMETERS`] (once; later calls are
/// ignored).
pub fn record_parameters(text: String) {
    let _ = PARAMETERS.set(text);
}

/// A FITS file being written at a temporary path; errors name the final `path`.
struct FitsWriter<'a> {
    file: FitsFile,
    /// Kept while cfitsio has the file open.
    _name: CfitsioName,
    path: &'a Path,
    /// The HDU that keys and data go to.
    hdu: FitsHdu,
}

impl<'a> FitsWriter<'a> {
    /// Creates `tmp` (replacing it) with a primary image of `dims` (slowest axis first).
    fn create(tmp: &Path, path: &'a Path, data_type: ImageType, dims: &[usize]) -> Result<Self, HostError> {
        let name = CfitsioName::for_writing(tmp, path)?;
        let description = ImageDescription { data_type, dimensions: dims };
        let mut file = FitsFile::create(&name.name)
            .with_custom_primary(&description)
            .overwrite()
            .open()
            .map_err(|e| fits_error(path, "creating the file", &e))?;
        let hdu = file.primary_hdu().map_err(|e| fits_error(path, "creating the primary HDU", &e))?;
        // fitsio names a custom primary HDU "_PRIMARY"; a primary HDU has no name in FITS
        // practice (astropy calls it PRIMARY), so the key goes.
        let mut status = 0;
        // SAFETY: `file` is open and its current HDU is the primary (moved to just above);
        // the key name is a NUL-terminated literal.
        unsafe { fitsio::sys::ffdkey(file.as_raw(), c"EXTNAME".as_ptr(), &mut status) };
        fitsio::errors::check_status(status).map_err(|e| fits_error(path, "removing fitsio's EXTNAME", &e))?;
        let mut writer = FitsWriter { file, _name: name, path, hdu };
        writer.provenance()?;
        Ok(writer)
    }

    /// Where the file comes from, in the primary HDU: `DATE` (UTC, when written),
    /// `CREATOR` (dncal and its version), `ORIGIN`, and as `HISTORY` cards (cfitsio
    /// continues a long line on further cards) the command line that made it and every
    /// parameter it ran with, defaults included ([`record_parameters`]).
    fn provenance(&mut self) -> Result<(), HostError> {
        let path = self.path;
        let mut status = 0;
        // SAFETY: `self.file` is open with the primary HDU current; ffpdat writes one key.
        unsafe { fitsio::sys::ffpdat(self.file.as_raw(), &mut status) };
        fitsio::errors::check_status(status).map_err(|e| fits_error(path, "writing key DATE", &e))?;
        self.key("CREATOR", (format!("dncal {}", env!("CARGO_PKG_VERSION")), "software that wrote this file"))?;
        self.key("ORIGIN", ("dncal", "camera detector correction and characterization"))?;
        // (`args_os`: `args` panics on an argument that is not Unicode, such as a path.)
        let args: Vec<String> = std::env::args_os().map(|a| a.to_string_lossy().into_owned()).collect();
        self.history(&format!("command: {}", args.join(" ")))?;
        match PARAMETERS.get() {
            Some(p) => self.history(&format!("parameters: {p}")),
            None => Ok(()),
        }
    }

    /// One `HISTORY` record of `text`: printable ASCII only (a FITS header holds nothing
    /// else, the rest becomes `?`), at most 4 KB of it.
    fn history(&mut self, text: &str) -> Result<(), HostError> {
        let text: String = text.chars().map(|c| if (' '..='~').contains(&c) { c } else { '?' }).take(4096).collect();
        let Ok(text) = std::ffi::CString::new(text) else { return Ok(()) };
        let mut status = 0;
        // SAFETY: `self.file` is open with the primary HDU current; `text` is NUL-terminated.
        unsafe { fitsio::sys::ffphis(self.file.as_raw(), text.as_ptr(), &mut status) };
        fitsio::errors::check_status(status).map_err(|e| fits_error(self.path, "writing HISTORY", &e))
    }

    /// Writes `value` (a value or a (value, comment) pair) as key `name` of the current HDU.
    fn key<T: WritesKey>(&mut self, name: &str, value: T) -> Result<(), HostError> {
        let path = self.path;
        self.hdu
            .write_key(&mut self.file, name, value)
            .map_err(|e| fits_error(path, &format!("writing key {name}"), &e))
    }

    /// The keys every format carries: `BITDEPTH`, `NADC`, `ADCMAP`.
    fn adc_keys(&mut self, bit_depth: u32, n_adc: usize) -> Result<(), HostError> {
        self.key("BITDEPTH", (i64::from(bit_depth), "bits per ADC code"))?;
        let n_adc = i64::try_from(n_adc).map_err(|_| format_error(self.path, "NADC exceeds the key's range"))?;
        self.key("NADC", (n_adc, "ADCs; column c is read by ADC c mod NADC"))?;
        self.key("ADCMAP", (ADCMAP_COLMOD, "ADC of column c is c mod NADC"))
    }

    /// Writes the whole data array of the current image HDU.
    fn image<T: WriteImage>(&mut self, data: &[T]) -> Result<(), HostError> {
        let path = self.path;
        self.hdu.write_image(&mut self.file, data).map_err(|e| fits_error(path, "writing image data", &e))
    }

    /// Appends image extension `extname` of `dims` and makes it current.
    fn add_image(&mut self, extname: &str, data_type: ImageType, dims: &[usize]) -> Result<(), HostError> {
        let description = ImageDescription { data_type, dimensions: dims };
        self.hdu = self
            .file
            .create_image(extname, &description)
            .map_err(|e| fits_error(self.path, &format!("creating extension {extname}"), &e))?;
        Ok(())
    }

    /// Appends binary table `extname` with the single float64 column `column` in `unit`.
    fn add_table(&mut self, extname: &str, column: &str, unit: &str, values: &[f64]) -> Result<(), HostError> {
        let path = self.path;
        let context = format!("writing table {extname}");
        let described = ColumnDescription::new(column).with_type(ColumnDataType::Double).create();
        let description = described.map_err(|e| fits_error(path, &context, &e))?;
        self.hdu = self.file.create_table(extname, &[description]).map_err(|e| fits_error(path, &context, &e))?;
        self.hdu.write_col(&mut self.file, column, values).map_err(|e| fits_error(path, &context, &e))?;
        self.key("TUNIT1", unit)
    }

    /// Flushes everything to disk, so that a full disk is an error here and not a silently
    /// short file when `Drop` closes it (fitsio ignores errors on close).
    /// Every HDU also gets the standard `DATASUM` and `CHECKSUM` keys (the FITS checksum
    /// convention, which astropy verifies), computed last, over the final header and data.
    fn finish(mut self) -> Result<(), HostError> {
        let (mut status, mut count) = (0, 0);
        // SAFETY: `self.file` is open; ffthdu counts its HDUs, ffmahd moves among them,
        // ffpcks writes the two keys of the current HDU, ffflus only writes its buffers.
        unsafe {
            let raw = self.file.as_raw();
            fitsio::sys::ffthdu(raw, &mut count, &mut status);
            for hdu in 1..=count {
                fitsio::sys::ffmahd(raw, hdu, std::ptr::null_mut(), &mut status);
                fitsio::sys::ffpcks(raw, &mut status);
            }
            fitsio::sys::ffflus(raw, &mut status);
        }
        fitsio::errors::check_status(status).map_err(|e| fits_error(self.path, "writing checksums and flushing to disk", &e))
    }
}

// ---------------------------------------------------------------------------------------
// Reading

/// The largest total count of one ADC's histogram the analyses accept: 2^53, where f64 (in
/// which every analysis of the counts runs) stops holding integers exactly. A camera at
/// 40 Ms/s per ADC takes over seven years to fill it; a count of 2^64 - 1 in a file
/// (issue 18: a panic in the binomial split of `diagnose`) is refused.
pub const MAX_HISTOGRAM_TOTAL: u64 = 1 << 53;

/// [`read_histograms`] for an analysis (`lut build`, `adc`, `diagnose`, `stream --hist`):
/// also refuses an ADC whose counts add up to more than [`MAX_HISTOGRAM_TOTAL`]. The
/// format itself holds any `u64` count, and [`read_histograms`] reads them all.
pub fn read_histograms_for_analysis(path: &Path) -> Result<AdcHistograms, HostError> {
    let h = read_histograms(path)?;
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
    let mut r = FitsReader::open(path)?;
    r.expect_kind(FileKind::Histograms)?;
    let (bit_depth, n_adc, codes) = r.adc_keys()?;
    let image = r.image(0, PRIMARY, 2)?;
    r.check_adc_image_shape(&image, codes, n_adc, bit_depth)?;
    let flat: Vec<u64> = r
        .integer_pixels(&image, "histogram counts")?
        .convert()
        .map_err(|(i, v)| r.error(format!("count {v} at ADC {}, code {} is negative", i / codes, i % codes)))?;
    let counts = flat.chunks(codes).map(<[u64]>::to_vec).collect();
    Ok(AdcHistograms { bit_depth, counts })
}

/// Recorded raw frames: `frames` images of `height` x `width` codes, row-major, frame
/// after frame.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FrameCube {
    /// Pixels per line.
    pub width: usize,
    /// Lines per frame.
    pub height: usize,
    /// Frames.
    pub frames: usize,
    /// The codes.
    pub codes: Vec<u16>,
}

impl FrameCube {
    /// Frame `f`'s codes.
    pub fn frame(&self, f: usize) -> &[u16] {
        let n = self.width * self.height;
        &self.codes[f * n..(f + 1) * n]
    }
}

/// Reads recorded frames (what a DAQ saves): the primary HDU as a 3-D integer image
/// (NAXIS1 columns, NAXIS2 rows, NAXIS3 frames) or a 2-D one (a single frame) of raw codes
/// 0 to 65535 (BITPIX 16 with BZERO 32768 as astropy writes `uint16`, or any wider
/// integer type). Rejects float or scaled images, other dimensions, empty frames and codes
/// outside 16 bits, naming the first.
pub fn read_frames(path: &Path) -> Result<FrameCube, HostError> {
    let mut r = FitsReader::open(path)?;
    let naxis = r.required_int(0, PRIMARY, "NAXIS")?;
    if naxis != 2 && naxis != 3 {
        return Err(r.error(format!("the {PRIMARY} has NAXIS = {naxis}; recorded frames are a 2-D frame or a 3-D cube (columns, rows, frames)")));
    }
    let image = r.image(0, PRIMARY, naxis as usize)?;
    let (width, height) = (image.naxes[0], image.naxes[1]);
    let frames = image.naxes.get(2).copied().unwrap_or(1);
    if width == 0 || height == 0 || frames == 0 {
        return Err(r.error(format!("the {PRIMARY} has no pixels ({})", shape_text(&image.naxes))));
    }
    let codes: Vec<u16> = r.integer_pixels(&image, "raw codes")?.convert().map_err(|(i, v)| {
        let n = width * height;
        r.error(format!("code {v} at frame {}, row {}, column {} does not fit 16 bits", i / n, i % n / width, i % width))
    })?;
    Ok(FrameCube { width, height, frames, codes })
}

/// Reads a linearity set. Rejects missing keys or extensions, shapes that disagree between
/// the primary cube, `STD`, `MASK` and the rows of `REFERENCE`, NaN or infinite values,
/// negative standard deviations and mask values other than 0 and 1.
pub fn read_linearity(path: &Path) -> Result<LinearitySet, HostError> {
    read_linearity_as(path)
}

/// [`read_linearity`] into cubes of `T` (converted by cfitsio as they are read: an
/// `f32` set never holds the `f64` one).
pub fn read_linearity_as<T: Sample>(path: &Path) -> Result<LinearitySet<T>, HostError>
where
    Vec<T>: ReadImage,
{
    let mut r = FitsReader::open(path)?;
    r.expect_kind(FileKind::Linearity)?;
    let (bit_depth, n_adc, _) = r.adc_keys()?;
    let n_frames = r.required_int(0, PRIMARY, "NFRAMES")?;
    let n_frames = u32::try_from(n_frames)
        .ok()
        .filter(|&n| n >= 1)
        .ok_or_else(|| r.error(format!("NFRAMES = {n_frames}, must be 1 to {}", u32::MAX)))?;
    let image = r.image(0, PRIMARY, 3)?;
    let (width, height, levels) = (image.naxes[0], image.naxes[1], image.naxes[2]);
    if width == 0 || height == 0 || levels == 0 {
        return Err(r.error(format!("the primary cube is {width} x {height} x {levels}: empty")));
    }
    let mean: Vec<T> = r.pixels(&image)?;

    let std_hdu = r.require_extension("STD", "per-pixel standard deviations")?;
    let std_image = r.image(std_hdu, "extension STD", 3)?;
    if std_image.naxes != image.naxes {
        return Err(r.error(format!(
            "extension STD is {} but the primary cube is {} (columns x rows x levels)",
            shape_text(&std_image.naxes),
            shape_text(&image.naxes)
        )));
    }
    let std: Vec<T> = r.pixels(&std_image)?;

    let ref_hdu = r.require_extension("REFERENCE", "reference voltages")?;
    let voltage = r.column_f64(ref_hdu, "extension REFERENCE", "VOLTAGE")?;
    if voltage.len() != levels {
        return Err(r.error(format!("extension REFERENCE has {} rows, the cube has {levels} levels", voltage.len())));
    }

    let mask = match r.extension("MASK")? {
        None => None,
        Some(hdu) => {
            let mask_image = r.image(hdu, "extension MASK", 2)?;
            if mask_image.naxes != [width, height] {
                return Err(r.error(format!(
                    "extension MASK is {} but frames are {width} x {height} (columns x rows)",
                    shape_text(&mask_image.naxes)
                )));
            }
            let mask: Vec<u8> = r.integer_pixels(&mask_image, "mask values")?.convert().map_err(|(i, v)| {
                r.error(format!("mask value {v} at row {}, column {} is not 0 or 1", i / width, i % width))
            })?;
            Some(mask)
        }
    };
    let set = LinearitySet { bit_depth, n_adc, n_frames, width, height, levels, mean, std, voltage, mask };
    check_linearity(&set).map_err(|m| r.error(m))?;
    Ok(set)
}

/// Reads LUTs. Accepts any integer image whose values fit in 32 unsigned bits; rejects a
/// shape other than `NADC` x `2^BITDEPTH`, missing or invalid keys, and `FRACBITS` other
/// than [`dncal_core::FRAC_BITS`].
pub fn read_lut(path: &Path) -> Result<LutTables, HostError> {
    let mut r = FitsReader::open(path)?;
    r.expect_kind(FileKind::Lut)?;
    let (bit_depth, n_adc, codes) = r.adc_keys()?;
    let frac_bits = r.required_int(0, PRIMARY, "FRACBITS")?;
    if frac_bits != i64::from(FRAC_BITS) {
        return Err(r.error(format!("FRACBITS = {frac_bits}, dncal LUT entries have {FRAC_BITS} fractional bits")));
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
    Ok(LutTables { frac_bits: FRAC_BITS, tables, weights, kcor_bits })
}

/// How messages name the primary HDU.
const PRIMARY: &str = "primary HDU";

/// cfitsio's status for a missing key.
const KEY_NO_EXIST: i32 = 202;
/// cfitsio's status for reading past the end of the file.
const END_OF_FILE: i32 = 107;
/// cfitsio's status for a failed read, such as a last block cut short.
const READ_ERROR: i32 = 108;

/// What an image HDU's header says about its data.
struct ImageHeader {
    /// HDU number, 0 = primary.
    hdu: usize,
    /// How messages name the HDU.
    label: String,
    bitpix: i64,
    /// NAXIS1 (fastest, columns) first.
    naxes: Vec<usize>,
    bzero: f64,
    bscale: f64,
    elements: usize,
}

/// Integer pixel values as cfitsio delivers them after BZERO.
enum IntegerPixels {
    Signed(Vec<i64>),
    /// BITPIX 64 with BZERO 2^63: the only integer data that does not fit `i64`.
    Unsigned(Vec<u64>),
}

impl IntegerPixels {
    /// Every value as `T`, or the flat index and value of the first that does not fit.
    fn convert<T: TryFrom<i128>>(self) -> Result<Vec<T>, (usize, i128)> {
        fn all<T: TryFrom<i128>>(values: impl Iterator<Item = i128>) -> Result<Vec<T>, (usize, i128)> {
            values.enumerate().map(|(i, v)| T::try_from(v).map_err(|_| (i, v))).collect()
        }
        match self {
            IntegerPixels::Signed(v) => all(v.into_iter().map(i128::from)),
            IntegerPixels::Unsigned(v) => all(v.into_iter().map(i128::from)),
        }
    }
}

/// The three FITS files dncal writes and reads (`docs/formats.md`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum FileKind {
    Histograms,
    Linearity,
    Lut,
}

impl FileKind {
    fn name(self) -> &'static str {
        match self {
            FileKind::Histograms => "a histogram set",
            FileKind::Linearity => "a linearity set",
            FileKind::Lut => "a LUT FITS",
        }
    }

    /// What it is and what reads it.
    fn describe(self) -> &'static str {
        match self {
            FileKind::Histograms => "a histogram set (per-ADC code counts, FITS keys BITDEPTH and NADC; `lut build`, `adc --hist` and `diagnose` read it)",
            FileKind::Linearity => "a linearity set (mean and std frames per level, FITS key NFRAMES; `linearity` and `diagnose` read it)",
            FileKind::Lut => "a LUT FITS (per-ADC tables, FITS key FRACBITS; `lut inspect`, `lut export`, `kcor-model --lut` and `fpga-size --lut` read it)",
        }
    }
}

/// Why a key could not be read.
enum KeyError {
    Fits(FitsioError),
    /// A string key whose value is not a quoted string: the card, trimmed.
    NotString(String),
}

/// A key value the readers read: numbers and logicals through fitsio, strings from the
/// card itself ([`string_from_card`]).
trait KeyValue: Sized {
    /// Key `name` of HDU `hdu` (0-based), `None` when absent.
    fn read(file: &mut FitsFile, hdu: usize, name: &str) -> Result<Option<Self>, KeyError>;
}

macro_rules! key_through_fitsio {
    ($($t:ty),*) => {$(
        impl KeyValue for $t {
            fn read(file: &mut FitsFile, hdu: usize, name: &str) -> Result<Option<Self>, KeyError> {
                // A hand-made handle: `FitsFile::hdu` would describe the HDU first, which
                // panics inside fitsio on some legal HDUs (see the module documentation).
                let handle = FitsHdu { info: HduInfo::AnyInfo, number: hdu };
                match handle.read_key::<$t>(file, name) {
                    Ok(v) => Ok(Some(v)),
                    Err(FitsioError::Fits(e)) if e.status == KEY_NO_EXIST => Ok(None),
                    Err(e) => Err(KeyError::Fits(e)),
                }
            }
        }
    )*};
}
key_through_fitsio!(f64, bool);

impl KeyValue for String {
    /// The card is read whole (`ffgcrd`, into cfitsio's 81-byte card size) and its quoted
    /// value parsed here. fitsio reads a string key into a 71-byte buffer, and cfitsio
    /// copies an unquoted value of up to 71 characters (a card with no space after `=`)
    /// into it with its terminating NUL: a heap overflow by one byte, found by the
    /// `fits_lut` fuzz target under AddressSanitizer (`EXTNAME =YYYY...` over the whole card).
    fn read(file: &mut FitsFile, hdu: usize, name: &str) -> Result<Option<Self>, KeyError> {
        let fits_error = |status| KeyError::Fits(fitsio::errors::check_status(status).err().unwrap_or(FitsioError::Message("unknown cfitsio error".into())));
        let Ok(key) = std::ffi::CString::new(name) else { return Ok(None) };
        let mut card = [0 as std::ffi::c_char; 81];
        let mut status = 0;
        // SAFETY: `file` is open and `hdu` one of its HDUs (or cfitsio sets a status);
        // `key` is NUL-terminated; `card` holds FLEN_CARD (81) bytes, the most ffgcrd writes.
        unsafe {
            let raw = file.as_raw();
            fitsio::sys::ffmahd(raw, hdu as i32 + 1, std::ptr::null_mut(), &mut status);
            fitsio::sys::ffgcrd(raw, key.as_ptr(), card.as_mut_ptr(), &mut status);
        }
        match status {
            0 => {}
            KEY_NO_EXIST => return Ok(None),
            _ => return Err(fits_error(status)),
        }
        let bytes: Vec<u8> = card.iter().take_while(|&&c| c != 0).map(|&c| c as u8).collect();
        string_from_card(&bytes).map(Some).ok_or_else(|| KeyError::NotString(printable(&bytes)))
    }
}

/// The value of a string card (`KEY     = 'value'  / comment`): the characters between
/// the quotes with `''` read as one quote, trailing spaces dropped (they are not
/// significant in FITS), `None` if the value is not a quoted string.
fn string_from_card(card: &[u8]) -> Option<String> {
    let value = card.get(8..)?.strip_prefix(b"=")?;
    let start = value.iter().position(|&b| b != b' ')?;
    let mut bytes = value[start..].strip_prefix(b"'")?.iter().peekable();
    // Bytes up to the closing quote only: the comment after it may hold anything.
    let mut out = Vec::new();
    loop {
        match *bytes.next()? {
            b'\'' if bytes.peek() == Some(&&b'\'') => {
                bytes.next();
                out.push(b'\'');
            }
            b'\'' => return Some(String::from_utf8_lossy(&out).trim_end().to_string()),
            b => out.push(b),
        }
    }
}

/// A card as a message shows it: bytes outside printable ASCII (a newline would break the
/// one-line error, NULs fill a block cut short) as `?`, trailing spaces dropped.
fn printable(card: &[u8]) -> String {
    card.iter().map(|&b| if (0x20..0x7f).contains(&b) { b as char } else { '?' }).collect::<String>().trim_end().to_string()
}

/// A FITS file open for reading, with every access turned into a [`HostError`] naming it.
struct FitsReader<'a> {
    file: FitsFile,
    /// Kept while cfitsio has the file open.
    _name: CfitsioName,
    path: &'a Path,
    /// Most data bytes the file can hold: no header may make us allocate more. The file
    /// size, or for a gzip-, compress- or zip-compressed file (cfitsio opens those too)
    /// the size times 1100, above deflate's largest ratio of 1032.
    len: u64,
}

impl<'a> FitsReader<'a> {
    fn open(path: &'a Path) -> Result<Self, HostError> {
        // A device or FIFO never reaches cfitsio, which would read or wait for ever.
        let mut plain_file = crate::input::open_regular(path)?;
        let size = plain_file.metadata().map_err(|e| HostError::io(path, e))?.len();
        let mut start = [0u8; 9];
        // Compressed by the magic numbers cfitsio recognizes (gzip, compress, pack, LZH,
        // zip); anything else is read as it is. (Deciding "plain" by an exact `SIMPLE  =`
        // let a file with `SIMPLE   =`, which cfitsio reads, skip the table check: found by
        // `fits_linearity`.)
        let read = std::io::Read::read_exact(&mut plain_file, &mut start).is_ok();
        let compressed = read && matches!(start[..2], [0x1f, 0x8b | 0x9d | 0x1e | 0xa0] | [b'P', b'K']);
        let plain = !compressed;
        let len = if plain { size } else { size.saturating_mul(1100) };
        if let Some(declared) = declared_uncompressed_size(&mut plain_file, size).map_err(|e| HostError::io(path, e))? {
            if declared > len {
                return Err(format_error(path, format!(
                    "a compressed file of {size} bytes whose header declares {declared} bytes uncompressed, more than it can hold; cfitsio would allocate them at once"
                )));
            }
            crate::budget::check(path, "decompressing it (the size its header declares)", declared)?;
            if start[..2] == [0x1f, 0x8b] {
                check_gzip_inflates_within(&mut plain_file, path, len.min(crate::budget::limit()))?;
            }
        }
        if plain {
            if let Some((at, card)) = malformed_table(&mut plain_file, size).map_err(|e| HostError::io(path, e))? {
                return Err(format_error(path, format!(
                    "the table header at byte {at} has \"{card}\"; a table header opens with BITPIX, NAXIS, NAXIS1, NAXIS2, PCOUNT, GCOUNT and TFIELDS (0 to 999), integers in range (cfitsio would take it for valid)"
                )));
            }
        }
        let name = CfitsioName::for_reading(path)?;
        let file = FitsFile::open(&name.name).map_err(|e| fits_error(path, "not a readable FITS file", &e))?;
        let mut reader = FitsReader { file, _name: name, path, len };
        reader.check_declared_sizes(plain)?;
        reader.verify_checksums()?;
        Ok(reader)
    }

    /// Refuses an HDU whose `CHECKSUM` or `DATASUM` (where present: files of other tools
    /// often have none) does not match its bytes: the file changed after it was written.
    fn verify_checksums(&mut self) -> Result<(), HostError> {
        let (mut status, mut count) = (0, 0);
        // SAFETY: `self.file` is open; ffthdu counts its HDUs.
        unsafe { fitsio::sys::ffthdu(self.file.as_raw(), &mut count, &mut status) };
        for hdu in 1..=count {
            // cfitsio's ffvcks reads both keys into 71-byte buffers that an unquoted value
            // filling the card overruns (see `String::read`): each must be absent or a
            // quoted string, read safely first.
            let label = if hdu == 1 { PRIMARY.to_string() } else { format!("HDU {}", hdu - 1) };
            for key in ["CHECKSUM", "DATASUM"] {
                let _: Option<String> = self.key(hdu as usize - 1, &label, key)?;
            }
            let (mut data_ok, mut hdu_ok) = (0, 0);
            // SAFETY: as above; ffvcks reads the current HDU and writes the two flags
            // (1 verified, 0 no key, -1 wrong).
            unsafe {
                let raw = self.file.as_raw();
                fitsio::sys::ffmahd(raw, hdu, std::ptr::null_mut(), &mut status);
                fitsio::sys::ffvcks(raw, &mut data_ok, &mut hdu_ok, &mut status);
            }
            fitsio::errors::check_status(status).map_err(|e| fits_error(self.path, &format!("verifying the checksums of HDU {}", hdu - 1), &e))?;
            if data_ok < 0 || hdu_ok < 0 {
                let which = if data_ok < 0 { "its data do not match DATASUM" } else { "its header and data do not match CHECKSUM" };
                return Err(self.error(format!(
                    "the {label} fails its checksum: {which} (the file was changed or damaged after it was written; a tool that edited it kept the old keys: have it write new ones, astropy's writeto(..., checksum=True), or delete CHECKSUM and DATASUM)"
                )));
            }
        }
        Ok(())
    }

    /// Refuses a file whose HDUs declare more bytes than it has: each HDU's header, data
    /// and heap (`PCOUNT`), in 2880-byte blocks, as cfitsio lays them out. cfitsio itself
    /// checks only what is read, so a binary table declaring a 2 GB heap would pass.
    fn check_declared_sizes(&mut self, plain: bool) -> Result<(), HostError> {
        let count = self.file.num_hdus().map_err(|e| fits_error(self.path, "counting HDUs", &e))?;
        for hdu in 0..count {
            let (mut status, mut end) = (0, 0);
            // SAFETY: `self.file` is open and `hdu` below its HDU count; cfitsio skips the
            // null outputs (HDU type, header and data start) and writes only `end`.
            unsafe {
                let raw = self.file.as_raw();
                fitsio::sys::ffmahd(raw, hdu as i32 + 1, std::ptr::null_mut(), &mut status);
                fitsio::sys::ffghadll(raw, std::ptr::null_mut(), std::ptr::null_mut(), &mut end, &mut status);
            }
            fitsio::errors::check_status(status)
                .map_err(|e| fits_error(self.path, &format!("reading the header of HDU {hdu}"), &e))?;
            if end as u64 > self.len {
                let label = match (hdu, self.key::<String>(hdu, "HDU", "EXTNAME")?) {
                    (0, _) => PRIMARY.to_string(),
                    (_, Some(name)) => format!("HDU {hdu} ({})", name.trim()),
                    (_, None) => format!("HDU {hdu}"),
                };
                let has = if plain { format!("the file has {} bytes", self.len) } else { "more than the compressed file can hold".into() };
                return Err(self.error(format!(
                    "the {label} declares its header, data and heap (PCOUNT) to end at byte {end}; {has} (truncated?)"
                )));
            }
        }
        Ok(())
    }

    fn error(&self, message: impl Into<String>) -> HostError {
        format_error(self.path, message)
    }

    /// Key `name` of HDU `hdu`, `None` when absent.
    fn key<T: KeyValue>(&mut self, hdu: usize, label: &str, name: &str) -> Result<Option<T>, HostError> {
        match T::read(&mut self.file, hdu, name) {
            Ok(v) => Ok(v),
            Err(KeyError::Fits(e)) => Err(fits_error(self.path, &format!("key {name} of the {label}"), &e)),
            Err(KeyError::NotString(card)) => Err(self.error(format!("key {name} of the {label} is not a quoted string: \"{card}\""))),
        }
    }

    fn required<T: KeyValue>(&mut self, hdu: usize, label: &str, name: &str) -> Result<T, HostError> {
        self.key(hdu, label, name)?.ok_or_else(|| self.error(format!("missing key {name} in the {label}")))
    }

    /// An integer-valued key (read as a float so that `4.5` is an error, not 4).
    fn int_key(&mut self, hdu: usize, label: &str, name: &str) -> Result<Option<i64>, HostError> {
        match self.key::<f64>(hdu, label, name)? {
            None => Ok(None),
            Some(v) if v.fract() == 0.0 && v.abs() <= 9.007_199_254_740_992e15 => Ok(Some(v as i64)),
            Some(v) => Err(self.error(format!("key {name} of the {label} is {v}, not an integer"))),
        }
    }

    fn required_int(&mut self, hdu: usize, label: &str, name: &str) -> Result<i64, HostError> {
        self.int_key(hdu, label, name)?.ok_or_else(|| self.error(format!("missing key {name} in the {label}")))
    }

    /// The kind of dncal file the primary HDU announces by the keys its writer puts there
    /// (`FRACBITS`: a LUT; `NFRAMES`: a linearity set; `BITDEPTH` on a 2-D image without
    /// either: a histogram set), `None` for anything else.
    fn kind(&mut self) -> Result<Option<FileKind>, HostError> {
        if self.key::<f64>(0, PRIMARY, "FRACBITS")?.is_some() {
            return Ok(Some(FileKind::Lut));
        }
        if self.key::<f64>(0, PRIMARY, "NFRAMES")?.is_some() {
            return Ok(Some(FileKind::Linearity));
        }
        let two_d = self.key::<f64>(0, PRIMARY, "NAXIS")? == Some(2.0);
        Ok((two_d && self.key::<f64>(0, PRIMARY, "BITDEPTH")?.is_some()).then_some(FileKind::Histograms))
    }

    /// Refuses a dncal file of another kind than `want`, naming what it is and which
    /// command reads it (rather than the first key it lacks).
    fn expect_kind(&mut self, want: FileKind) -> Result<(), HostError> {
        match self.kind()? {
            Some(found) if found != want => Err(self.error(format!("this is {}, not {}", found.describe(), want.name()))),
            _ => Ok(()),
        }
    }

    /// `BITDEPTH`, `NADC` and `ADCMAP` of the primary HDU: (bits, ADCs, codes).
    fn adc_keys(&mut self) -> Result<(u32, usize, usize), HostError> {
        let bits = self.required_int(0, PRIMARY, "BITDEPTH")?;
        let bit_depth = u32::try_from(bits).unwrap_or(0);
        let codes =
            codes_for(bit_depth).map_err(|_| self.error(format!("BITDEPTH = {bits}, must be 1 to {MAX_BIT_DEPTH}")))?;
        let n = self.required_int(0, PRIMARY, "NADC")?;
        let n_adc = usize::try_from(n)
            .ok()
            .filter(|&n| n >= 1)
            .ok_or_else(|| self.error(format!("NADC = {n}, must be at least 1")))?;
        let map: String = self.required(0, PRIMARY, "ADCMAP")?;
        if map.trim() != ADCMAP_COLMOD {
            return Err(self.error(format!(
                "ADCMAP = '{map}'; only '{ADCMAP_COLMOD}' (column c read by ADC c mod NADC) is defined"
            )));
        }
        Ok((bit_depth, n_adc, codes))
    }

    /// The first extension named `name` (case-insensitive), if any.
    fn extension(&mut self, name: &str) -> Result<Option<usize>, HostError> {
        let count = self.file.num_hdus().map_err(|e| fits_error(self.path, "counting HDUs", &e))?;
        for hdu in 1..count {
            let label = format!("HDU {hdu}");
            if let Some(extname) = self.key::<String>(hdu, &label, "EXTNAME")? {
                if extname.trim().eq_ignore_ascii_case(name) {
                    return Ok(Some(hdu));
                }
            }
        }
        Ok(None)
    }

    fn require_extension(&mut self, name: &str, holding: &str) -> Result<usize, HostError> {
        match self.extension(name)? {
            Some(hdu) => Ok(hdu),
            None => {
                let count = self.file.num_hdus().unwrap_or(0);
                Err(self.error(format!("missing extension {name} ({holding}); the file has {count} HDUs")))
            }
        }
    }

    /// The header of image HDU `hdu`, which must have `naxis` axes.
    fn image(&mut self, hdu: usize, label: &str, naxis: usize) -> Result<ImageHeader, HostError> {
        if hdu > 0 {
            let xtension: String = self.required(hdu, label, "XTENSION")?;
            if xtension.trim() != "IMAGE" {
                let hint = match self.key::<bool>(hdu, label, "ZIMAGE") {
                    Ok(Some(true)) => " (a tile-compressed image: write it uncompressed)",
                    _ => "",
                };
                return Err(self.error(format!("the {label} is a {} extension, not an image{hint}", xtension.trim())));
            }
        }
        let bitpix = self.required_int(hdu, label, "BITPIX")?;
        if ![8, 16, 32, 64, -32, -64].contains(&bitpix) {
            return Err(self.error(format!("the {label} has BITPIX = {bitpix}, not a FITS data type")));
        }
        let found = self.required_int(hdu, label, "NAXIS")?;
        if found != naxis as i64 {
            return Err(self.error(format!("the {label} has NAXIS = {found}, expected {naxis} axes")));
        }
        let mut naxes = Vec::with_capacity(naxis);
        for axis in 1..=naxis {
            let key = format!("NAXIS{axis}");
            let n = self.required_int(hdu, label, &key)?;
            naxes.push(usize::try_from(n).map_err(|_| self.error(format!("{key} = {n} in the {label}")))?);
        }
        let bzero = self.key::<f64>(hdu, label, "BZERO")?.unwrap_or(0.0);
        let bscale = self.key::<f64>(hdu, label, "BSCALE")?.unwrap_or(1.0);
        let elements = naxes.iter().try_fold(1usize, |acc, &n| acc.checked_mul(n));
        let bytes = elements.and_then(|n| n.checked_mul(bitpix.unsigned_abs() as usize / 8));
        match (elements, bytes) {
            (Some(elements), Some(bytes)) if bytes as u64 <= self.len => {
                Ok(ImageHeader { hdu, label: label.into(), bitpix, naxes, bzero, bscale, elements })
            }
            _ => Err(self.error(format!(
                "the {label} declares {} pixels of BITPIX {bitpix}, more than the file can hold (truncated?)",
                shape_text(&naxes)
            ))),
        }
    }

    /// Checks a per-ADC table image: NAXIS1 = codes, NAXIS2 = ADCs.
    fn check_adc_image_shape(
        &self,
        image: &ImageHeader,
        codes: usize,
        n_adc: usize,
        bits: u32,
    ) -> Result<(), HostError> {
        if image.naxes[0] != codes {
            return Err(self.error(format!(
                "the {} has NAXIS1 = {} codes, BITDEPTH = {bits} needs 2^{bits} = {codes}",
                image.label, image.naxes[0]
            )));
        }
        if image.naxes[1] != n_adc {
            return Err(self.error(format!("the {} has NAXIS2 = {} rows, NADC = {n_adc}", image.label, image.naxes[1])));
        }
        Ok(())
    }

    /// All pixels of an image as `T` (cfitsio converts), if they fit the memory budget.
    fn pixels<T>(&mut self, image: &ImageHeader) -> Result<Vec<T>, HostError>
    where
        Vec<T>: ReadImage,
    {
        let what = format!("the {} ({} pixels as {}-byte values)", image.label, shape_text(&image.naxes), std::mem::size_of::<T>());
        crate::budget::check(self.path, &what, crate::budget::bytes_of(image.elements as u64, std::mem::size_of::<T>() as u64))?;
        let shape = image.naxes.iter().rev().copied().collect();
        let handle = FitsHdu { info: HduInfo::ImageInfo { shape, image_type: ImageType::Double }, number: image.hdu };
        handle
            .read_section(&mut self.file, 0, image.elements)
            .map_err(|e| fits_error(self.path, &format!("reading the data of the {}", image.label), &e))
    }

    /// All pixels of an integer image, physical values (BZERO applied).
    fn integer_pixels(&mut self, image: &ImageHeader, what: &str) -> Result<IntegerPixels, HostError> {
        if image.bitpix < 0 {
            return Err(self.error(format!(
                "the {} is a floating-point image (BITPIX = {}); {what} must be integers",
                image.label, image.bitpix
            )));
        }
        if image.bscale != 1.0 || image.bzero.fract() != 0.0 {
            return Err(self.error(format!(
                "the {} is scaled (BSCALE = {}, BZERO = {}); {what} must be unscaled integers",
                image.label, image.bscale, image.bzero
            )));
        }
        if image.bitpix == 64 && image.bzero == 9_223_372_036_854_775_808.0 {
            Ok(IntegerPixels::Unsigned(self.pixels(image)?))
        } else {
            Ok(IntegerPixels::Signed(self.pixels(image)?))
        }
    }

    /// Scalar numeric column `column` (case-insensitive) of binary table `hdu`.
    fn column_f64(&mut self, hdu: usize, label: &str, column: &str) -> Result<Vec<f64>, HostError> {
        let xtension: String = self.required(hdu, label, "XTENSION")?;
        if xtension.trim() != "BINTABLE" {
            return Err(self.error(format!("the {label} is a {} extension, not a binary table", xtension.trim())));
        }
        let row_bytes = self.required_int(hdu, label, "NAXIS1")?;
        let rows = self.required_int(hdu, label, "NAXIS2")?;
        if row_bytes.checked_mul(rows).is_none_or(|b| b < 0 || b as u64 > self.len) {
            return Err(
                self.error(format!("the {label} declares {rows} rows of {row_bytes} bytes, more than the file holds"))
            );
        }
        let fields = self.required_int(hdu, label, "TFIELDS")?;
        let mut found = None;
        for n in 1..=fields {
            let tform: String = self.required(hdu, label, &format!("TFORM{n}"))?;
            let (repeat, letter) = split_tform(&tform);
            // fitsio describes every column when reading any, and panics on the types it
            // cannot describe: variable-length (P, Q) and complex (C, M) columns.
            if !matches!(letter, Some('L' | 'X' | 'B' | 'I' | 'J' | 'K' | 'E' | 'D' | 'A')) {
                return Err(self.error(format!(
                    "column {n} of the {label} has TFORM{n} = '{tform}'; variable-length and complex columns are not supported"
                )));
            }
            let name: Option<String> = self.key(hdu, label, &format!("TTYPE{n}"))?;
            if let Some(name) = name.filter(|t| t.trim().eq_ignore_ascii_case(column)) {
                found = Some((name, tform.clone(), repeat, letter));
            }
        }
        let (name, tform, repeat, letter) =
            found.ok_or_else(|| self.error(format!("the {label} has no column {column}")))?;
        if repeat != Some(1) || !matches!(letter, Some('B' | 'I' | 'J' | 'K' | 'E' | 'D')) {
            return Err(self.error(format!(
                "column {column} of the {label} has TFORM '{tform}'; it must hold one number per row (e.g. 'D')"
            )));
        }
        let handle = FitsHdu { info: HduInfo::AnyInfo, number: hdu };
        handle
            .read_col::<f64>(&mut self.file, &name)
            .map_err(|e| fits_error(self.path, &format!("reading column {column} of the {label}"), &e))
    }
}

/// The repeat count (`None` if unreadable) and type letter of a binary-table TFORM such as
/// `1D`, `D` or `10A`.
fn split_tform(tform: &str) -> (Option<usize>, Option<char>) {
    let tform = tform.trim();
    let digits = tform.len() - tform.trim_start_matches(|c: char| c.is_ascii_digit()).len();
    let repeat = if digits == 0 { Some(1) } else { tform[..digits].parse().ok() };
    (repeat, tform[digits..].chars().next().map(|c| c.to_ascii_uppercase()))
}

// ---------------------------------------------------------------------------------------
// Validation shared by writers and readers

/// Codes of an ADC of `bit_depth` bits, if the formats accept that depth.
fn codes_for(bit_depth: u32) -> Result<usize, String> {
    if (1..=MAX_BIT_DEPTH).contains(&bit_depth) {
        Ok(1usize << bit_depth)
    } else {
        Err(format!("bit depth {bit_depth}, must be 1 to {MAX_BIT_DEPTH}"))
    }
}

/// Per-ADC rows of `2^bit_depth` entries each, at least one row; returns the codes per row.
fn check_tables<T>(bit_depth: u32, rows: &[Vec<T>], what: &str) -> Result<usize, String> {
    let codes = codes_for(bit_depth)?;
    if rows.is_empty() {
        return Err("no ADCs: at least one row is needed".into());
    }
    for (adc, row) in rows.iter().enumerate() {
        if row.len() != codes {
            return Err(format!(
                "ADC {adc} has {} {what}, bit depth {bit_depth} needs 2^{bit_depth} = {codes}",
                row.len()
            ));
        }
    }
    Ok(codes)
}

/// A LUT set's bit depth, from its table length, after checking it is writable.
fn check_lut(lut: &LutTables) -> Result<u32, String> {
    if lut.frac_bits != FRAC_BITS {
        return Err(format!("{} fractional bits; dncal LUT entries have {FRAC_BITS}", lut.frac_bits));
    }
    let codes = lut.tables.first().map_or(0, Vec::len);
    if !codes.is_power_of_two() {
        return Err(format!("tables of {codes} entries; a table has 2^bits entries"));
    }
    let bit_depth = codes.trailing_zeros();
    check_tables(bit_depth, &lut.tables, "entries")?;
    if let Some(w) = &lut.weights {
        if w.len() != lut.tables.len() {
            return Err(format!("weights for {} ADCs, tables for {}", w.len(), lut.tables.len()));
        }
        check_tables(bit_depth, w, "weights")?;
    }
    Ok(bit_depth)
}

/// Everything a [`LinearitySet`] must satisfy, whether about to be written or just read.
fn check_linearity<T: Sample>(s: &LinearitySet<T>) -> Result<(), String> {
    codes_for(s.bit_depth)?;
    if s.n_adc == 0 {
        return Err("no ADCs: NADC must be at least 1".into());
    }
    if s.n_frames == 0 {
        return Err("NFRAMES must be at least 1".into());
    }
    let frame = s.width.checked_mul(s.height).filter(|&n| n > 0);
    let (Some(frame), Some(cube)) = (frame, frame.and_then(|f| f.checked_mul(s.levels)).filter(|&n| n > 0)) else {
        return Err(format!(
            "shape {} x {} x {} (columns x rows x levels) is empty or too large",
            s.width, s.height, s.levels
        ));
    };
    let at = |i: usize| format!("level {}, row {}, column {}", i / frame, i % frame / s.width, i % s.width);
    for (name, values) in [("mean", &s.mean), ("std", &s.std)] {
        if values.len() != cube {
            return Err(format!(
                "{name} holds {} values, {} x {} x {} (columns x rows x levels) needs {cube}",
                values.len(),
                s.width,
                s.height,
                s.levels
            ));
        }
        if let Some(i) = values.iter().position(|&v| !v.into().is_finite()) {
            return Err(format!("{name} is {} at {}", values[i], at(i)));
        }
    }
    // Negative at single precision: a negative subnormal below f32's smallest (a zero
    // written with a rounding error) reads as -0.0 in the f32 reader, which must not
    // accept what this one refuses (found by the `fits_linearity` fuzz target: -8e-322).
    if let Some(i) = s.std.iter().position(|&v| (v.into() as f32) < 0.0) {
        return Err(format!("std is negative ({}) at {}", s.std[i], at(i)));
    }
    if s.voltage.len() != s.levels {
        return Err(format!("{} reference voltages for {} levels", s.voltage.len(), s.levels));
    }
    if let Some(level) = s.voltage.iter().position(|v| !v.is_finite()) {
        return Err(format!("reference voltage is {} at level {level}", s.voltage[level]));
    }
    if let Some(mask) = &s.mask {
        if mask.len() != frame {
            return Err(format!("mask holds {} values, {} x {} frames need {frame}", mask.len(), s.width, s.height));
        }
        if let Some(i) = mask.iter().position(|&m| m > 1) {
            return Err(format!("mask value {} at row {}, column {} is not 0 or 1", mask[i], i / s.width, i % s.width));
        }
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------
// Errors

fn format_error(path: &Path, message: impl Into<String>) -> HostError {
    HostError::Format { path: path.into(), message: message.into() }
}

/// A fitsio error while doing `context`, as a message for people.
fn fits_error(path: &Path, context: &str, e: &FitsioError) -> HostError {
    let cause = match e {
        FitsioError::Fits(f) if f.status == END_OF_FILE || f.status == READ_ERROR => {
            format!("the file ends early or cannot be read, truncated? (cfitsio {}: {})", f.status, f.message)
        }
        FitsioError::Fits(f) => format!("cfitsio {}: {}", f.status, f.message),
        other => other.to_string(),
    };
    format_error(path, format!("{context}: {cause}"))
}

/// A name under which cfitsio opens a file as that file and nothing else.
///
/// cfitsio parses file names: `h.fits[1]` or `h.fits+1` is HDU 1 of `h.fits`, `a(b)`
/// copies `a` to `b`, `-` is standard input, `!x` clobbers `x`, `mem://` is memory; and
/// fitsio panics on a name that is not UTF-8. Absolute UTF-8 paths free of that syntax
/// are used as they are. Any other path is reached through a symbolic link with a plain
/// name in a fresh temporary directory (Unix only; elsewhere such paths are an error).
struct CfitsioName {
    name: String,
    /// Holds the link; removing it removes only the link.
    _alias: Option<tempfile::TempDir>,
}

impl CfitsioName {
    /// For the existing file `path`.
    fn for_reading(path: &Path) -> Result<Self, HostError> {
        let absolute = std::path::absolute(path).map_err(|e| HostError::io(path, e))?;
        match plain_for_cfitsio(&absolute) {
            Some(name) => Ok(CfitsioName { name, _alias: None }),
            None => Self::alias(&absolute, "file.fits", path),
        }
    }

    /// For `tmp`, a temporary [`Outputs::write`] made (its own name is plain), reporting
    /// errors as about `shown`. A directory with cfitsio syntax in its path is linked, so
    /// the file is still created in that directory and can be renamed into place.
    fn for_writing(tmp: &Path, shown: &Path) -> Result<Self, HostError> {
        let absolute = std::path::absolute(tmp).map_err(|e| HostError::io(shown, e))?;
        if let Some(name) = plain_for_cfitsio(&absolute) {
            return Ok(CfitsioName { name, _alias: None });
        }
        let (Some(dir), Some(file)) = (absolute.parent(), absolute.file_name()) else {
            return Err(format_error(shown, "no directory to write in"));
        };
        let mut alias = Self::alias(dir, "dir", shown)?;
        alias.name = format!("{}/{}", alias.name, file.to_string_lossy());
        Ok(alias)
    }

    /// A link named `link` to `target`, in a new temporary directory.
    fn alias(target: &Path, link: &str, shown: &Path) -> Result<Self, HostError> {
        #[cfg(unix)]
        {
            let dir = tempfile::Builder::new().prefix("dncal-fits").tempdir().map_err(|e| HostError::io(shown, e))?;
            let alias = dir.path().join(link);
            std::os::unix::fs::symlink(target, &alias).map_err(|e| HostError::io(shown, e))?;
            match plain_for_cfitsio(&alias) {
                Some(name) => Ok(CfitsioName { name, _alias: Some(dir) }),
                None => Err(format_error(shown, "the temporary directory's path is not usable by cfitsio")),
            }
        }
        #[cfg(not(unix))]
        {
            let _ = (target, link);
            Err(format_error(shown, "cfitsio would read this path's brackets, parentheses or other syntax; rename it"))
        }
    }
}

/// `path` as a string cfitsio takes literally: absolute, UTF-8, no extended syntax.
fn plain_for_cfitsio(path: &Path) -> Option<String> {
    let name = path.to_str()?;
    let ends_with_hdu_number =
        name.rsplit_once('+').is_some_and(|(_, n)| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()));
    let plain =
        path.is_absolute() && !name.contains(['[', ']', '(', ')']) && !name.contains("://") && !ends_with_hdu_number;
    plain.then(|| name.to_owned())
}

/// The size cfitsio allocates at once to uncompress `file` (of `size` bytes) into memory,
/// as it reads it from the header (`mem_compress_open` in cfitsio's `drvrmem.c`): gzip's
/// `ISIZE`, the last 4 bytes, plus 2^32 until above the file's size if the file has more
/// than 10 000 bytes; zip's uncompressed size at byte 22 (a file too short to hold it
/// leaves cfitsio with stale bytes: counted as 2^32, refused). `None` for a file that is
/// not gzip or zip: cfitsio estimates other methods at 3 x the file's size (issue 18: an
/// 11-byte file starting `PK` made every FITS reader allocate 4 GB).
fn declared_uncompressed_size(file: &mut std::fs::File, size: u64) -> std::io::Result<Option<u64>> {
    use std::io::{Read, Seek, SeekFrom};
    let le = |b: [u8; 4]| u64::from(u32::from_le_bytes(b));
    let mut magic = [0u8; 2];
    file.seek(SeekFrom::Start(0))?;
    if size < 2 {
        return Ok(None);
    }
    file.read_exact(&mut magic)?;
    let mut field = [0u8; 4];
    match &magic {
        b"\x1f\x8b" if size >= 4 => {
            file.seek(SeekFrom::End(-4))?;
            file.read_exact(&mut field)?;
            let mut declared = le(field);
            if size > 10_000 {
                while declared < size {
                    declared += 1 << 32;
                }
            }
            Ok(Some(declared))
        }
        b"PK" if size >= 26 => {
            file.seek(SeekFrom::Start(22))?;
            file.read_exact(&mut field)?;
            Ok(Some(le(field)))
        }
        b"\x1f\x8b" | b"PK" => Ok(Some(1 << 32)),
        _ => Ok(None),
    }
}

/// Refuses a gzip file that inflates to more than `limit` bytes. cfitsio decompresses a
/// gzip file whole into memory, growing its buffer past the size the trailer declares
/// (which is the size modulo 2^32: a 5 GiB file declares 1 GiB), so the only bound is the
/// inflated size itself: counted here by inflating into nothing, stopping one byte past
/// the limit (issue 18: a 5 MB file reached 3 GB in cfitsio before it gave up).
fn check_gzip_inflates_within(file: &mut std::fs::File, path: &Path, limit: u64) -> Result<(), HostError> {
    use std::io::{Read, Seek, SeekFrom};
    file.seek(SeekFrom::Start(0)).map_err(|e| HostError::io(path, e))?;
    let mut inflated = flate2::read::MultiGzDecoder::new(std::io::BufReader::new(&mut *file)).take(limit.saturating_add(1));
    // A corrupt stream is cfitsio's to report (with its own message); only the size is
    // ours, counted up to where the stream breaks.
    let (mut n, mut buf) = (0u64, vec![0u8; 1 << 16]);
    while let Ok(k) = inflated.read(&mut buf) {
        if k == 0 {
            break;
        }
        n += k as u64;
    }
    if n > limit {
        return Err(format_error(path, format!(
            "inflates to more than {} (gzip), more than {}",
            crate::budget::human(limit),
            if limit == crate::budget::limit() { "the memory budget (--max-memory)" } else { "1100 times its size, above deflate's largest ratio" }
        )));
    }
    Ok(())
}

/// The first table header of the plain FITS file `file` whose mandatory keywords cfitsio
/// mis-checks: its byte offset and the card. `ffgttb` compares the status where it means
/// to set it (`return(*status == BAD_TFIELDS)`), so a table with `TFIELDS` above 999 or a
/// negative `NAXIS1` or `NAXIS2` passes as valid, with `TFIELDS` as written or never read;
/// cfitsio then allocates a column descriptor for every field as soon as it walks past the
/// HDU, which counting HDUs does (issue 18, found by `fits_linearity`: an allocation of
/// 2^54 bytes; a third input reached the same allocation with a garbled `GCOUNT` card). So
/// a table header must open with the cards the standard fixes in place, `BITPIX`, `NAXIS`,
/// `NAXIS1`, `NAXIS2`, `PCOUNT`, `GCOUNT`, `TFIELDS`, each a plain integer in range
/// (`TFIELDS` at most 999).
/// The walk reads the headers only, skipping each data unit by the size its header
/// declares; past a header it cannot follow (cfitsio reads some values this parse does
/// not) it checks every following 2880-byte block that starts like a table header.
fn malformed_table(file: &mut std::fs::File, size: u64) -> std::io::Result<Option<(u64, String)>> {
    use std::io::{Read, Seek, SeekFrom};
    const BLOCK: u64 = 2880;
    // The value before the comment, as cfitsio reads it: bytes outside ASCII in the comment
    // do not hide the value (found by `fits_linearity`: an image's `NAXIS2` with a byte
    // 0xDF in its comment sent the walk to the wrong block, past the table after it).
    let integer = |card: &[u8]| -> Option<i64> {
        let value = card[10..].split(|&b| b == b'/').next()?;
        std::str::from_utf8(value).ok()?.trim().parse::<i64>().ok()
    };
    let (mut start, mut lost) = (0u64, false);
    let mut block = [0u8; BLOCK as usize];
    // A last block cut short is read too (the rest as zeros): cfitsio parses what a
    // truncated file holds of a header (found by `fits_linearity`: a table header cut
    // after its `PCOUNT` card made cfitsio allocate 2^54 bytes).
    while start < size {
        file.seek(SeekFrom::Start(start))?;
        block.fill(0);
        let n = (size - start).min(BLOCK) as usize;
        file.read_exact(&mut block[..n])?;
        let card = |n: usize| &block[80 * (n - 1)..80 * n];
        if &card(1)[..10] == b"XTENSION= " {
            // The quoted string, as cfitsio reads it, whatever follows it before the comment.
            let xtension = String::from_utf8_lossy(&card(1)[10..]);
            let xtension = xtension.trim_start().strip_prefix('\'').and_then(|v| v.split('\'').next()).unwrap_or("").trim();
            if ["TABLE", "BINTABLE", "A3DTABLE", "3DTABLE"].contains(&xtension) {
                let mandatory = [
                    (2, "BITPIX", i64::MIN, i64::MAX),
                    (3, "NAXIS", 0, 999),
                    (4, "NAXIS1", 0, i64::MAX),
                    (5, "NAXIS2", 0, i64::MAX),
                    (6, "PCOUNT", 0, i64::MAX),
                    (7, "GCOUNT", 0, i64::MAX),
                    (8, "TFIELDS", 0, 999),
                ];
                for (n, key, min, max) in mandatory {
                    let c = card(n);
                    if &c[..10] != format!("{key:<8}= ").as_bytes() || !integer(c).is_some_and(|v| (min..=max).contains(&v)) {
                        return Ok(Some((start, printable(c))));
                    }
                }
            }
        }
        // An extension must start where the one before ended; a walk that lands elsewhere
        // has misread a size, and from there checks every block instead.
        if start > 0 && &block[..9] != b"XTENSION=" {
            lost = true;
        }
        if lost {
            start += BLOCK;
            continue;
        }
        let (mut bitpix, mut naxis, mut pcount, mut gcount) = (None, None, 0i64, 1i64);
        let mut axes: Vec<i64> = Vec::new();
        let mut at = start + BLOCK;
        let ended = 'header: loop {
            for card in block.chunks_exact(80) {
                let key = std::str::from_utf8(&card[..8]).unwrap_or("").trim_end();
                if key == "END" {
                    break 'header true;
                }
                if &card[8..10] != b"= " {
                    continue;
                }
                let Some(value) = integer(card) else { continue };
                match key {
                    "BITPIX" => bitpix = Some(value),
                    "NAXIS" => naxis = Some(value),
                    "PCOUNT" => pcount = value,
                    "GCOUNT" => gcount = value,
                    k if k.starts_with("NAXIS") => {
                        if let Some(n) = k[5..].parse::<usize>().ok().filter(|n| (1..=999).contains(n)) {
                            axes.resize(axes.len().max(n), 0);
                            axes[n - 1] = value;
                        }
                    }
                    _ => {}
                }
            }
            if at + BLOCK > size {
                break false;
            }
            file.read_exact(&mut block)?;
            at += BLOCK;
        };
        if !ended {
            // No END: cfitsio refuses the header itself.
            return Ok(None);
        }
        let axes = naxis.and_then(|n| axes.get(..usize::try_from(n).ok()?));
        let bytes = match (bitpix, naxis, axes) {
            (Some(_), Some(0), _) => Some(0),
            (Some(bitpix), Some(_), Some(axes)) => {
                // Random groups (primary NAXIS1 = 0) leave out the first axis, as cfitsio does.
                let counted = if start == 0 && axes.first() == Some(&0) && axes.len() > 1 { &axes[1..] } else { axes };
                counted
                    .iter()
                    .try_fold(1i64, |p, &n| p.checked_mul(n))
                    .and_then(|p| p.checked_add(pcount))
                    .and_then(|p| p.checked_mul(gcount))
                    .and_then(|p| p.checked_mul(bitpix.abs() / 8))
                    .and_then(|b| u64::try_from(b).ok())
            }
            _ => None,
        };
        match bytes {
            Some(bytes) => start = at.saturating_add(bytes.div_ceil(BLOCK).saturating_mul(BLOCK)),
            None => {
                lost = true;
                start += BLOCK;
            }
        }
    }
    Ok(None)
}

/// `[4, 16]` as "4 x 16".
fn shape_text(naxes: &[usize]) -> String {
    naxes.iter().map(usize::to_string).collect::<Vec<_>>().join(" x ")
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use super::*;

    /// A key for hand-made test files.
    enum Key {
        Int(i64),
        Str(&'static str),
        Float(f64),
    }
    use Key::{Float, Int, Str};

    fn keys(out: &mut FitsWriter, keys: &[(&str, Key)]) {
        for (name, value) in keys {
            match value {
                Int(v) => out.key(name, *v),
                Str(v) => out.key(name, *v),
                Float(v) => out.key(name, *v),
            }
            .unwrap();
        }
    }

    /// A one-HDU file with any primary image and keys, bypassing every check.
    fn image_file<T: WriteImage>(path: &Path, data_type: ImageType, dims: &[usize], data: &[T], with: &[(&str, Key)]) {
        let mut out = FitsWriter::create(path, path, data_type, dims).unwrap();
        keys(&mut out, with);
        out.image(data).unwrap();
        out.finish().unwrap();
    }

    /// BITDEPTH 2 (4 codes), 2 ADCs.
    fn adc_keys_2x4() -> Vec<(&'static str, Key)> {
        vec![("BITDEPTH", Int(2)), ("NADC", Int(2)), ("ADCMAP", Str("COLMOD"))]
    }

    fn without(mut k: Vec<(&'static str, Key)>, name: &str) -> Vec<(&'static str, Key)> {
        k.retain(|(n, _)| *n != name);
        k
    }

    fn with(mut k: Vec<(&'static str, Key)>, name: &'static str, value: Key) -> Vec<(&'static str, Key)> {
        k.retain(|(n, _)| *n != name);
        k.push((name, value));
        k
    }

    /// The message of a `Format` error, after checking it names `path`.
    fn format_message<T: std::fmt::Debug>(result: Result<T, HostError>, path: &Path) -> String {
        match result {
            Err(HostError::Format { path: p, message }) => {
                assert_eq!(p, path, "error names the wrong file: {message}");
                message
            }
            other => panic!("expected a format error for {}, got {other:?}", path.display()),
        }
    }

    fn assert_rejects<T: std::fmt::Debug>(result: Result<T, HostError>, path: &Path, expected: &str) {
        let message = format_message(result, path);
        assert!(message.contains(expected), "message {message:?} does not contain {expected:?}");
    }

    fn files_in(dir: &Path) -> Vec<PathBuf> {
        let mut v: Vec<PathBuf> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).collect();
        v.sort();
        v
    }

    fn histograms() -> AdcHistograms {
        // Distinct in every ADC and code, with both ends of the signed 64-bit range's
        // non-negative half, so a transposed or truncated read cannot pass.
        let mut counts: Vec<Vec<u64>> = (0..3u64).map(|a| (0..16u64).map(|k| 1000 * a + k * k).collect()).collect();
        counts[2][15] = i64::MAX as u64;
        AdcHistograms { bit_depth: 4, counts }
    }

    fn linearity(mask: bool) -> LinearitySet {
        let (width, height, levels) = (5, 3, 4);
        let mean = (0..levels * height * width).map(|i| 100.0 + 0.25 * i as f64).collect();
        let std = (0..levels * height * width).map(|i| 0.5 + 0.125 * (i % 7) as f64).collect();
        LinearitySet {
            bit_depth: 12,
            n_adc: 4,
            n_frames: 64,
            width,
            height,
            levels,
            mean,
            std,
            voltage: vec![0.0, 0.5, 1.0, 1.5],
            mask: mask.then(|| (0..width * height).map(|i| u8::from(i % 4 == 1)).collect()),
        }
    }

    fn lut() -> LutTables {
        let mut tables: Vec<Vec<u32>> =
            (0..4u32).map(|a| (0..8u32).map(|k| (2 * k + 1) * 1024 + a).collect()).collect();
        tables[3][7] = u32::MAX;
        tables[0][0] = 0;
        LutTables { frac_bits: FRAC_BITS, tables, weights: None, kcor_bits: None }
    }

    #[test]
    fn histograms_round_trip_as_bitpix_64_without_primary_extname() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("h.fits");
        write_histograms(&path, &histograms()).unwrap();
        assert_eq!(read_histograms(&path).unwrap(), histograms());
        let mut r = FitsReader::open(&path).unwrap();
        assert_eq!(r.required_int(0, PRIMARY, "BITPIX").unwrap(), 64);
        assert_eq!(r.key::<String>(0, PRIMARY, "EXTNAME").unwrap(), None);
    }

    #[test]
    fn histograms_read_from_every_integer_bitpix() {
        let dir = tempfile::tempdir().unwrap();
        // (type, largest value it holds): the unsigned types exercise BZERO.
        let types = [
            (ImageType::UnsignedByte, 255),
            (ImageType::Byte, 127),
            (ImageType::Short, 32_767),
            (ImageType::UnsignedShort, 65_535),
            (ImageType::Long, i64::from(i32::MAX)),
            (ImageType::UnsignedLong, i64::from(u32::MAX)),
            (ImageType::LongLong, i64::MAX),
        ];
        for (i, (data_type, top)) in types.into_iter().enumerate() {
            let path = dir.path().join(format!("h{i}.fits"));
            let data = [0, 1, 2, 3, 4, 5, 6, top];
            image_file(&path, data_type, &[2, 4], &data, &adc_keys_2x4());
            let h = read_histograms(&path).unwrap();
            let expected = vec![vec![0, 1, 2, 3], vec![4, 5, 6, top as u64]];
            assert_eq!((h.bit_depth, h.counts), (2, expected), "{data_type:?}");
        }
    }

    #[test]
    fn histograms_reject_bad_images() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("h.fits");
        image_file(&p, ImageType::Double, &[2, 4], &[1.0f64; 8], &adc_keys_2x4());
        assert_rejects(read_histograms(&p), &p, "floating-point image (BITPIX = -64)");
        image_file(&p, ImageType::Float, &[2, 4], &[1.0f32; 8], &adc_keys_2x4());
        assert_rejects(read_histograms(&p), &p, "floating-point image (BITPIX = -32)");
        image_file(&p, ImageType::Long, &[2, 4], &[1, 2, 3, 4, 5, 6, -7, 8], &adc_keys_2x4());
        assert_rejects(read_histograms(&p), &p, "count -7 at ADC 1, code 2 is negative");
        image_file(&p, ImageType::Long, &[2, 3], &[1; 6], &adc_keys_2x4());
        assert_rejects(read_histograms(&p), &p, "NAXIS1 = 3 codes, BITDEPTH = 2 needs 2^2 = 4");
        image_file(&p, ImageType::Long, &[3, 4], &[1; 12], &adc_keys_2x4());
        assert_rejects(read_histograms(&p), &p, "NAXIS2 = 3 rows, NADC = 2");
        image_file(&p, ImageType::Long, &[1, 2, 4], &[1; 8], &adc_keys_2x4());
        assert_rejects(read_histograms(&p), &p, "NAXIS = 3, expected 2");
        image_file(&p, ImageType::Long, &[8], &[1; 8], &adc_keys_2x4());
        assert_rejects(read_histograms(&p), &p, "NAXIS = 1, expected 2");
    }

    #[test]
    fn histograms_reject_missing_and_bad_keys() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("h.fits");
        for name in ["BITDEPTH", "NADC", "ADCMAP"] {
            image_file(&p, ImageType::Long, &[2, 4], &[1; 8], &without(adc_keys_2x4(), name));
            assert_rejects(read_histograms(&p), &p, &format!("missing key {name} in the primary HDU"));
        }
        let cases = [
            ("ADCMAP", Str("ROWMOD"), "ADCMAP = 'ROWMOD'"),
            ("ADCMAP", Int(4), "key ADCMAP of the primary HDU is not a quoted string: \"ADCMAP  =                    4\""),
            ("BITDEPTH", Int(0), "BITDEPTH = 0, must be 1 to 16"),
            ("BITDEPTH", Int(17), "BITDEPTH = 17, must be 1 to 16"),
            ("BITDEPTH", Int(-3), "BITDEPTH = -3"),
            ("BITDEPTH", Float(2.5), "BITDEPTH of the primary HDU is 2.5, not an integer"),
            ("BITDEPTH", Str("two"), "key BITDEPTH of the primary HDU"),
            ("NADC", Int(0), "NADC = 0, must be at least 1"),
        ];
        for (name, value, expected) in cases {
            image_file(&p, ImageType::Long, &[2, 4], &[1; 8], &with(adc_keys_2x4(), name, value));
            assert_rejects(read_histograms(&p), &p, expected);
        }
    }

    #[test]
    fn each_kind_of_file_is_named_to_a_reader_of_another() {
        let dir = tempfile::tempdir().unwrap();
        let (h, l, s) = (dir.path().join("h.fits"), dir.path().join("l.fits"), dir.path().join("s.fits"));
        write_histograms(&h, &histograms()).unwrap();
        write_lut(&l, &lut()).unwrap();
        write_linearity(&s, &linearity(true)).unwrap();
        // Every wrong pairing of the three kinds, each message naming what the file is.
        let (hist, lin, lutk) = ("a histogram set (", "a linearity set (", "a LUT FITS (");
        for (message, starts, not) in [
            (format_message(read_histograms(&l), &l), lutk, "a histogram set"),
            (format_message(read_histograms(&s), &s), lin, "a histogram set"),
            (format_message(read_lut(&h), &h), hist, "a LUT FITS"),
            (format_message(read_lut(&s), &s), lin, "a LUT FITS"),
            (format_message(read_linearity(&h), &h), hist, "a linearity set"),
            (format_message(read_linearity(&l), &l), lutk, "a linearity set"),
        ] {
            assert!(message.starts_with(&format!("this is {starts}")) && message.ends_with(&format!("), not {not}")), "{message}");
        }
        // And each reads its own.
        assert!(read_histograms(&h).is_ok() && read_lut(&l).is_ok() && read_linearity(&s).is_ok());
    }

    #[test]
    fn histogram_writer_rejects_bad_sets_and_writes_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("h.fits");
        let ragged = AdcHistograms { bit_depth: 2, counts: vec![vec![1; 4], vec![1; 3]] };
        assert_rejects(write_histograms(&p, &ragged), &p, "ADC 1 has 3 codes, bit depth 2 needs 2^2 = 4");
        let empty = AdcHistograms { bit_depth: 2, counts: vec![] };
        assert_rejects(write_histograms(&p, &empty), &p, "no ADCs");
        for bits in [0, 17, 64, u32::MAX] {
            let h = AdcHistograms { bit_depth: bits, counts: vec![vec![1; 4]] };
            assert_rejects(write_histograms(&p, &h), &p, &format!("bit depth {bits}, must be 1 to 16"));
        }
        let huge = AdcHistograms { bit_depth: 1, counts: vec![vec![0, u64::MAX]] };
        assert_rejects(write_histograms(&p, &huge), &p, "count 18446744073709551615 (ADC 0, code 1)");
        assert_eq!(files_in(dir.path()), Vec::<PathBuf>::new());
    }

    #[test]
    fn linearity_round_trips_with_and_without_mask() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("lin.fits");
        for mask in [true, false] {
            write_linearity(&p, &linearity(mask)).unwrap();
            assert_eq!(read_linearity(&p).unwrap(), linearity(mask));
        }
    }

    #[test]
    fn linearity_writer_rejects_bad_sets_and_writes_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("lin.fits");
        type Edit = fn(&mut LinearitySet);
        let cases: [(Edit, &str); 13] = [
            (|s| s.mean[17] = f64::NAN, "mean is NaN at level 1, row 0, column 2"),
            (|s| s.mean[0] = f64::INFINITY, "mean is inf at level 0, row 0, column 0"),
            (|s| s.std[59] = f64::NAN, "std is NaN at level 3, row 2, column 4"),
            (|s| s.std[6] = -0.5, "std is negative (-0.5) at level 0, row 1, column 1"),
            (|s| s.voltage[2] = f64::NEG_INFINITY, "reference voltage is -inf at level 2"),
            (|s| s.voltage.push(2.0), "5 reference voltages for 4 levels"),
            (|s| s.mean.truncate(59), "mean holds 59 values, 5 x 3 x 4 (columns x rows x levels) needs 60"),
            (|s| s.std.push(1.0), "std holds 61 values"),
            (|s| s.mask = Some(vec![0; 14]), "mask holds 14 values, 5 x 3 frames need 15"),
            (|s| s.mask.as_mut().unwrap()[7] = 2, "mask value 2 at row 1, column 2 is not 0 or 1"),
            (|s| s.n_frames = 0, "NFRAMES must be at least 1"),
            (|s| s.n_adc = 0, "NADC must be at least 1"),
            (|s| s.width = 0, "is empty or too large"),
        ];
        for (edit, expected) in cases {
            let mut set = linearity(true);
            edit(&mut set);
            assert_rejects(write_linearity(&p, &set), &p, expected);
        }
        assert_eq!(files_in(dir.path()), Vec::<PathBuf>::new());
    }

    /// The HDUs of a linearity file, to be broken one at a time.
    struct Parts {
        keys: Vec<(&'static str, Key)>,
        cube: Vec<usize>,
        mean: Vec<f64>,
        std: Option<(Vec<usize>, Vec<f64>)>,
        mask: Option<(Vec<usize>, Vec<i64>)>,
        /// (column name, values)
        reference: Option<(&'static str, Vec<f64>)>,
    }

    fn parts() -> Parts {
        let s = linearity(true);
        Parts {
            keys: with(with(adc_keys_2x4(), "BITDEPTH", Int(12)), "NFRAMES", Int(64)),
            cube: vec![4, 3, 5],
            mean: s.mean,
            std: Some((vec![4, 3, 5], s.std)),
            mask: Some((vec![3, 5], vec![0; 15])),
            reference: Some(("VOLTAGE", s.voltage)),
        }
    }

    fn write_parts(path: &Path, p: &Parts) {
        let mut out = FitsWriter::create(path, path, ImageType::Double, &p.cube).unwrap();
        keys(&mut out, &p.keys);
        out.image(&p.mean).unwrap();
        if let Some((dims, std)) = &p.std {
            out.add_image("STD", ImageType::Double, dims).unwrap();
            out.image(std).unwrap();
        }
        if let Some((dims, mask)) = &p.mask {
            out.add_image("MASK", ImageType::UnsignedByte, dims).unwrap();
            out.image(mask).unwrap();
        }
        if let Some((column, voltage)) = &p.reference {
            out.add_table("REFERENCE", column, "V", voltage).unwrap();
        }
        out.finish().unwrap();
    }

    #[test]
    fn linearity_reader_rejects_bad_files() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("lin.fits");
        write_parts(&path, &parts());
        read_linearity(&path).unwrap();
        type Edit = fn(&mut Parts);
        let cases: [(Edit, &str); 17] = [
            (|p| p.std = None, "missing extension STD"),
            (|p| p.reference = None, "missing extension REFERENCE"),
            (|p| p.reference = Some(("VOLTS", vec![0.0; 4])), "the extension REFERENCE has no column VOLTAGE"),
            (
                |p| p.reference = Some(("VOLTAGE", vec![0.0; 3])),
                "extension REFERENCE has 3 rows, the cube has 4 levels",
            ),
            (|p| p.reference = Some(("VOLTAGE", vec![0.0, 1.0, f64::NAN, 2.0])), "reference voltage is NaN at level 2"),
            (
                |p| p.std = Some((vec![4, 5, 3], vec![1.0; 60])),
                "extension STD is 3 x 5 x 4 but the primary cube is 5 x 3 x 4",
            ),
            (|p| p.std = Some((vec![3, 3, 5], vec![1.0; 45])), "extension STD is 5 x 3 x 3"),
            (|p| p.std = Some((vec![60], vec![1.0; 60])), "extension STD has NAXIS = 1, expected 3"),
            (|p| p.mask = Some((vec![5, 3], vec![0; 15])), "extension MASK is 3 x 5 but frames are 5 x 3"),
            (|p| p.mask.as_mut().unwrap().1[7] = 3, "mask value 3 at row 1, column 2 is not 0 or 1"),
            (|p| p.mean[17] = f64::NAN, "mean is NaN at level 1, row 0, column 2"),
            (|p| p.std.as_mut().unwrap().1[6] = -1.0, "std is negative (-1) at level 0, row 1, column 1"),
            (|p| p.std.as_mut().unwrap().1[0] = f64::INFINITY, "std is inf at level 0, row 0, column 0"),
            (|p| p.keys.retain(|(n, _)| *n != "NFRAMES"), "missing key NFRAMES in the primary HDU"),
            (|p| p.keys = with(std::mem::take(&mut p.keys), "NFRAMES", Int(0)), "NFRAMES = 0"),
            (|p| p.keys.retain(|(n, _)| *n != "ADCMAP"), "missing key ADCMAP"),
            (|p| p.cube = vec![60], "the primary HDU has NAXIS = 1, expected 3"),
        ];
        for (edit, expected) in cases {
            let mut p = parts();
            edit(&mut p);
            write_parts(&path, &p);
            assert_rejects(read_linearity(&path), &path, expected);
        }
    }

    #[test]
    fn lut_round_trips_as_uint32_with_bzero() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("lut.fits");
        write_lut(&p, &lut()).unwrap();
        assert_eq!(read_lut(&p).unwrap(), lut());
        let mut r = FitsReader::open(&p).unwrap();
        assert_eq!(r.required_int(0, PRIMARY, "BITPIX").unwrap(), 32);
        assert_eq!(r.key::<f64>(0, PRIMARY, "BZERO").unwrap(), Some(2_147_483_648.0));
        assert_eq!(r.required_int(0, PRIMARY, "FRACBITS").unwrap(), 11);
        assert_eq!(r.required_int(0, PRIMARY, "BITDEPTH").unwrap(), 3);
        // With the weights extension and the K-Cor scaling.
        let mut with = lut();
        with.weights = Some((0..4u32).map(|a| (0..8u32).map(|k| (1 << 24) + 1000 * k + a).collect()).collect());
        with.kcor_bits = Some(23);
        write_lut(&p, &with).unwrap();
        assert_eq!(read_lut(&p).unwrap(), with);
        // Weights of the wrong shape are refused before anything is written.
        let q = dir.path().join("bad.fits");
        with.weights.as_mut().unwrap()[2].pop();
        assert!(write_lut(&q, &with).is_err() && !q.exists());
    }

    #[test]
    fn lut_reader_and_writer_reject_bad_tables() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("lut.fits");
        let k = || with(adc_keys_2x4(), "FRACBITS", Int(11));
        image_file(&p, ImageType::LongLong, &[2, 4], &[0, 1, 2, 3, 4, 5, 6, 1i64 << 32], &k());
        assert_rejects(read_lut(&p), &p, "entry 4294967296 at ADC 1, code 3 is outside 0 to 2^32 - 1");
        image_file(&p, ImageType::Long, &[2, 4], &[0, -1, 2, 3, 4, 5, 6, 7], &k());
        assert_rejects(read_lut(&p), &p, "entry -1 at ADC 0, code 1");
        image_file(&p, ImageType::Double, &[2, 4], &[0.5f64; 8], &k());
        assert_rejects(read_lut(&p), &p, "floating-point image");
        image_file(&p, ImageType::Long, &[2, 4], &[0; 8], &with(k(), "FRACBITS", Int(12)));
        assert_rejects(read_lut(&p), &p, "FRACBITS = 12, dncal LUT entries have 11 fractional bits");
        image_file(&p, ImageType::Long, &[2, 8], &[0; 16], &k());
        assert_rejects(read_lut(&p), &p, "NAXIS1 = 8 codes, BITDEPTH = 2 needs 2^2 = 4");

        let w = dir.path().join("w.fits");
        let bad_frac = LutTables { frac_bits: 12, ..lut() };
        assert_rejects(write_lut(&w, &bad_frac), &w, "12 fractional bits; dncal LUT entries have 11");
        let odd = LutTables { frac_bits: 11, tables: vec![vec![0; 6]], weights: None, kcor_bits: None };
        assert_rejects(write_lut(&w, &odd), &w, "tables of 6 entries");
        let one_code = LutTables { frac_bits: 11, tables: vec![vec![0; 1]], weights: None, kcor_bits: None };
        assert_rejects(write_lut(&w, &one_code), &w, "bit depth 0");
        let ragged = LutTables { frac_bits: 11, tables: vec![vec![0; 4], vec![0; 2]], weights: None, kcor_bits: None };
        assert_rejects(write_lut(&w, &ragged), &w, "ADC 1 has 2 entries");
        let none = LutTables { frac_bits: 11, tables: vec![], weights: None, kcor_bits: None };
        assert_rejects(write_lut(&w, &none), &w, "tables of 0 entries");
        assert!(!w.exists());
    }

    /// Every cut of a good file is an error naming it, even one in the last block's
    /// padding (the HDU declares whole blocks); never a panic or other data.
    fn check_truncations<T: std::fmt::Debug>(path: &Path, read: fn(&Path) -> Result<T, HostError>) {
        read(path).unwrap();
        let bytes = std::fs::read(path).unwrap();
        assert_eq!(bytes.len() % 2880, 0);
        let cut_path = path.with_extension("cut.fits");
        let cuts =
            (0..bytes.len()).step_by(173).chain((0..bytes.len()).step_by(2880)).chain([1, 79, 80, bytes.len() - 1]);
        for cut in cuts {
            std::fs::write(&cut_path, &bytes[..cut]).unwrap();
            match read(&cut_path) {
                Ok(v) => panic!("cut at {cut} of {} read as {v:?}", bytes.len()),
                Err(e) => {
                    format_message(Err::<(), _>(e), &cut_path);
                }
            }
        }
    }

    #[test]
    fn truncated_files_are_errors_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let (h, lin, l) = (dir.path().join("h.fits"), dir.path().join("lin.fits"), dir.path().join("lut.fits"));
        write_histograms(&h, &histograms()).unwrap();
        write_linearity(&lin, &linearity(true)).unwrap();
        write_lut(&l, &lut()).unwrap();
        check_truncations(&h, read_histograms);
        check_truncations(&lin, read_linearity);
        check_truncations(&l, read_lut);
        // The message says what happened.
        let bytes = std::fs::read(&h).unwrap();
        std::fs::write(&h, &bytes[..2880]).unwrap();
        assert_rejects(read_histograms(&h), &h, "truncated?");
    }

    #[test]
    fn foreign_and_missing_files_are_errors_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("notes.fits");
        let contents: [&[u8]; 4] = [b"", b"this is not a FITS file\n", &[0u8; 5760], b"\x89PNG\r\n\x1a\n0000"];
        for bytes in contents {
            std::fs::write(&p, bytes).unwrap();
            assert_rejects(read_histograms(&p), &p, "not a readable FITS file");
            assert_rejects(read_linearity(&p), &p, "not a readable FITS file");
            assert_rejects(read_lut(&p), &p, "not a readable FITS file");
        }
        let missing = dir.path().join("missing.fits");
        assert!(matches!(read_histograms(&missing), Err(HostError::Io { path, .. }) if path == missing));
        assert!(matches!(read_lut(dir.path()), Err(HostError::NotRegular { kind: "directory", .. })));
    }

    #[cfg(unix)]
    #[test]
    fn names_cfitsio_would_parse_are_files_like_any_other() {
        use std::os::unix::ffi::OsStrExt;
        let dir = tempfile::tempdir().unwrap();
        let other = AdcHistograms { bit_depth: 1, counts: vec![vec![7, 8]] };
        let names: [&[u8]; 9] = [
            b"h.fits[1]",
            b"h.fits+1",
            b"h(2).fits",
            b"h.fits(x.fits)",
            b"!h.fits",
            b"-",
            b"stdin",
            b"mem://x",
            b"h\xff.fits",
        ];
        for sub in ["plain", "run[1]", "run(2)", "-"] {
            let d = dir.path().join(sub);
            std::fs::create_dir_all(d.join("mem:")).unwrap();
            // The file cfitsio would read instead for h.fits[1], h.fits+1, ...
            write_histograms(&d.join("h.fits"), &histograms()).unwrap();
            for name in names {
                let file = d.join(std::ffi::OsStr::from_bytes(name));
                write_histograms(&file, &other).unwrap();
                assert_eq!(read_histograms(&file).unwrap(), other, "{}", file.display());
            }
            assert_eq!(read_histograms(&d.join("h.fits")).unwrap(), histograms());
            // Nothing else was made: no temporaries, no files cfitsio made up.
            assert_eq!(std::fs::read_dir(&d).unwrap().count(), names.len() + 1, "{}", d.display());
        }
    }

    #[test]
    fn split_tform_reads_repeat_and_type() {
        assert_eq!(split_tform("D"), (Some(1), Some('D')));
        assert_eq!(split_tform("1D "), (Some(1), Some('D')));
        assert_eq!(split_tform("10A"), (Some(10), Some('A')));
        assert_eq!(split_tform("1PD(5)"), (Some(1), Some('P')));
        assert_eq!(split_tform(""), (Some(1), None));
        assert_eq!(split_tform("99999999999999999999999E"), (None, Some('E')));
    }

    /// String values as the FITS standard (4.2.1) writes them, each card padded to 80.
    #[test]
    fn string_cards_read_as_the_standard_defines_them() {
        let card = |text: &str| format!("{text:<80}").into_bytes();
        assert_eq!(string_from_card(&card("XTENSION= 'IMAGE   '           / IMAGE extension")).as_deref(), Some("IMAGE"));
        assert_eq!(string_from_card(&card("EXTNAME = 'O''HARA'")).as_deref(), Some("O'HARA"));
        assert_eq!(string_from_card(&card("EXTNAME = '  lead'")).as_deref(), Some("  lead"));
        assert_eq!(string_from_card(&card("EXTNAME = ''")).as_deref(), Some(""));
        assert_eq!(string_from_card(&card("EXTNAME =    'late start' / still a value")).as_deref(), Some("late start"));
        assert_eq!(string_from_card(&card("EXTNAME = 'a/b' / the slash is inside the quotes")).as_deref(), Some("a/b"));
        // Bytes outside ASCII in the comment do not touch the value.
        let mut odd = card("EXTNAME = 'STD     '           / comment");
        odd[60] = 0xDF;
        assert_eq!(string_from_card(&odd).as_deref(), Some("STD"));
        assert_eq!(printable(b"A\nB\x00C   "), "A?B?C");
        for bad in ["EXTNAME = unquoted", "EXTNAME =YYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYY", "EXTNAME = 'never closed", "EXTNAME   'no equals'", "SHORT"] {
            assert_eq!(string_from_card(&card(bad)), None, "{bad}");
        }
    }
}
