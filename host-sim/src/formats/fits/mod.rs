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
//!   2^-FRACBITS DN (11 fractional bits up to 12-bit codes, `23 - BITDEPTH` above:
//!   [`dncal_core::frac_bits`]), unsigned 32-bit.
//!
//! All three record `ADCMAP = 'COLMOD'`: column `c` is read by ADC `c mod NADC`, as on the
//! PhotonFocus MV-D1024E.
//!
//! ## Robustness
//! Files are written through [`crate::formats::outputs`]: the `stage_*` writers add a file to a
//! command's [`Outputs`], published with its other files or not at all; the `write_*`
//! ones write one file atomically. Either way a failed or rejected write never leaves a
//! half-written file at the destination. Readers check every shape, key and value
//! before returning and answer a truncated, foreign or malformed file with a
//! [`HostError::Format`] naming it (a data set that breaks a rule of its contents: a
//! typed [`Fault`] in [`HostError::FitsContent`]). They deliberately avoid the `fitsio` calls that panic on
//! legal FITS they do not expect (unsigned 64-bit images, variable-length or complex table
//! columns): image and table headers are read key by key instead. Paths reach cfitsio only
//! in a form it takes literally (`CfitsioName`): `h.fits[1]` is a file of that name, not
//! HDU 1 of `h.fits`.
//!
//! ```
//! use dncal_host::formats::fits::{read_histograms, write_histograms, AdcHistograms};
//! let dir = tempfile::tempdir().unwrap();
//! let path = dir.path().join("histograms.fits");
//! let hist = AdcHistograms { bit_depth: 2, counts: vec![vec![5, 6, 7, 8]; 4] };
//! write_histograms(&path, &hist)?;
//! assert_eq!(read_histograms(&path)?, hist);
//! # Ok::<(), dncal_host::HostError>(())
//! ```

use std::path::Path;

use fitsio::errors::Error as FitsioError;
use fitsio::hdu::{FitsHdu, HduInfo};
use fitsio::headers::WritesKey;
use fitsio::images::{ImageDescription, ImageType, ReadImage, WriteImage};
use fitsio::tables::{ColumnDataType, ColumnDescription};
use fitsio::FitsFile;

use crate::formats::outputs::{write_one, Outputs};
use crate::HostError;

mod direct;
mod frames;
mod histograms;
mod linearity;
mod lut;
mod name;
mod reader;
pub(crate) use reader::compressed_magic;
mod scan;
mod writer;
#[cfg(test)]
mod tests;

pub use frames::*;
pub use histograms::*;
pub use linearity::*;
pub use lut::*;
pub use writer::record_parameters;
use name::*;
use reader::*;
use scan::*;
use writer::*;

/// The only ADC map dncal knows: column `c` is read by ADC `c mod NADC`.
pub const ADCMAP_COLMOD: &str = "COLMOD";

/// Deepest ADC the formats accept: codes are `u16` throughout dncal.
pub const MAX_BIT_DEPTH: u32 = 16;

/// How messages name the primary HDU.
const PRIMARY: &str = "primary HDU";

/// cfitsio's status for a missing key.
const KEY_NO_EXIST: i32 = 202;

/// cfitsio's status for reading past the end of the file.
const END_OF_FILE: i32 = 107;

/// cfitsio's status for a failed read, such as a last block cut short.
const READ_ERROR: i32 = 108;

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

/// What is wrong with a data set's contents, found before it is written or as it is read
/// (each prints as the message it always printed). [`HostError::FitsContent`] wraps it
/// with the file.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Fault {
    /// A bit depth the formats do not take.
    #[error("bit depth {0}, must be 1 to {MAX_BIT_DEPTH}")]
    BitDepth(u32),
    /// Tables without a row.
    #[error("no ADCs: at least one row is needed")]
    NoRows,
    /// A row of the wrong length.
    #[error("ADC {adc} has {len} {what}, bit depth {bit_depth} needs 2^{bit_depth} = {codes}")]
    RowLength { adc: usize, len: usize, what: &'static str, bit_depth: u32, codes: usize },
    /// `NADC = 0`.
    #[error("no ADCs: NADC must be at least 1")]
    NoAdcs,
    /// More ADCs than a frame has columns (issue 56: `NADC = 65` on 16 columns was read
    /// as 16 ADCs of one column each, and `diagnose` sized its per-ADC tables by NADC).
    #[error("NADC = {n_adc} but the frames have {width} columns; column c is read by ADC c mod NADC, so at most {width} ADCs")]
    AdcsBeyondColumns { n_adc: usize, width: usize },
    /// `NFRAMES = 0`.
    #[error("NFRAMES must be at least 1")]
    NoFrames,
    /// A cube shape that is empty or overflows.
    #[error("shape {width} x {height} x {levels} (columns x rows x levels) is empty or too large")]
    Shape { width: usize, height: usize, levels: usize },
    /// A cube (`mean` or `std`) of the wrong length.
    #[error("{name} holds {len} values, {width} x {height} x {levels} (columns x rows x levels) needs {cube}")]
    CubeLength { name: &'static str, len: usize, width: usize, height: usize, levels: usize, cube: usize },
    /// A value a cube must not hold: `what` is "mean is", "std is" or "std is negative",
    /// `value` the value as the file holds it.
    #[error("{what} {value} at level {level}, row {row}, column {column}")]
    Value { what: &'static str, value: String, level: usize, row: usize, column: usize },
    /// A mean that no `bit_depth`-bit codes can have.
    #[error("mean {value} at level {level}, row {row}, column {column} is no mean of {bit_depth}-bit codes (allowed {lo} to {hi}: one code range either side)")]
    MeanRange { value: String, level: usize, row: usize, column: usize, bit_depth: u32, lo: f64, hi: f64 },
    /// As many reference voltages as levels are needed.
    #[error("{len} reference voltages for {levels} levels")]
    Voltages { len: usize, levels: usize },
    /// A reference voltage that is not finite.
    #[error("reference voltage is {value} at level {level}")]
    Voltage { value: f64, level: usize },
    /// A mask of the wrong length.
    #[error("mask holds {len} values, {width} x {rows} frames need {frame}")]
    MaskLength { len: usize, width: usize, rows: usize, frame: usize },
    /// A mask value other than 0 and 1.
    #[error("mask value {value} at row {row}, column {column} is not 0 or 1")]
    MaskValue { value: u8, row: usize, column: usize },
    /// LUT entries of another fixed-point format.
    #[error("{got} fractional bits; dncal LUT entries of {bits}-bit codes have {expected}")]
    FracBits { got: u32, bits: u32, expected: u32 },
    /// LUT tables whose length is not a power of two.
    #[error("tables of {0} entries; a table has 2^bits entries")]
    TableLength(usize),
    /// LUT weights for another number of ADCs than the tables.
    #[error("weights for {weights} ADCs, tables for {tables}")]
    WeightRows { weights: usize, tables: usize },
}

/// Codes of an ADC of `bit_depth` bits, if the formats accept that depth.
fn codes_for(bit_depth: u32) -> Result<usize, Fault> {
    if (1..=MAX_BIT_DEPTH).contains(&bit_depth) {
        Ok(1usize << bit_depth)
    } else {
        Err(Fault::BitDepth(bit_depth))
    }
}

/// Per-ADC rows of `2^bit_depth` entries each, at least one row; returns the codes per row.
fn check_tables<T>(bit_depth: u32, rows: &[Vec<T>], what: &'static str) -> Result<usize, Fault> {
    let codes = codes_for(bit_depth)?;
    if rows.is_empty() {
        return Err(Fault::NoRows);
    }
    for (adc, row) in rows.iter().enumerate() {
        if row.len() != codes {
            return Err(Fault::RowLength { adc, len: row.len(), what, bit_depth, codes });
        }
    }
    Ok(codes)
}

/// A fault of the file `path`.
fn fault(path: &Path) -> impl Fn(Fault) -> HostError + '_ {
    move |source| HostError::FitsContent { path: path.into(), source }
}

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

/// `[4, 16]` as "4 x 16".
fn shape_text(naxes: &[usize]) -> String {
    naxes.iter().map(usize::to_string).collect::<Vec<_>>().join(" x ")
}
