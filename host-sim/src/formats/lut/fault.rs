//! What can be wrong with a LUT file or a LUT set, in any format; `HostError::Lut` wraps
//! a fault once with the file it concerns. Each prints as the message the commands have
//! always printed.

use std::path::PathBuf;

use super::kcor::{FILE_BYTES, KCOR_CODES};

/// A LUT file's or LUT set's fault.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LutFault {
    /// A K-Cor table file of the wrong size.
    #[error("{bytes} bytes; a K-Cor table is {} little-endian u32 entries ({} bytes)", KCOR_CODES, FILE_BYTES)]
    KcorSize {
        /// The file's size.
        bytes: usize,
    },
    /// A K-Cor table whose last entry is neither deployed scaling's top.
    #[error("the last entry is {top}; the deployed tables end at 2^22 - 1 = {} or 2^23 - 1 = {}", (1u32 << 22) - 1, (1u32 << 23) - 1)]
    KcorTop {
        /// The last entry.
        top: u32,
    },
    /// A K-Cor table that decreases.
    #[error("entry {code} ({entry}) is below entry {} ({previous}): a table must not decrease", .code - 1)]
    KcorDecreasing {
        /// The first code whose entry is below the one before.
        code: usize,
        /// Its entry.
        entry: u32,
        /// The entry before.
        previous: u32,
    },
    /// A K-Cor table with a code too wide for the core's weights.
    #[error("code {code} is {width_dn:.1} DN wide; a dncal LUT holds code widths below 256 DN")]
    KcorWideCode {
        /// The code.
        code: usize,
        /// Its width, DN.
        width_dn: f64,
    },
    /// No file of a camera's set for one ADC.
    #[error("no file for ADC {adc} (a name starting with '{stem}' and containing '{tag}') in {}", .dir.display())]
    NoFileForAdc {
        /// The ADC.
        adc: usize,
        /// The names' common start.
        stem: String,
        /// The ADC's tag (`adcN`).
        tag: String,
        /// The folder looked in.
        dir: PathBuf,
    },
    /// Several files of a camera's set for one ADC.
    #[error("{} files for ADC {adc}: {}; give a longer prefix or a path with {{adc}} in it", .files.len(), .files.join(", "))]
    SeveralFilesForAdc {
        /// The ADC.
        adc: usize,
        /// The files' names.
        files: Vec<String>,
    },
    /// One of four K-Cor tables given in a place its name contradicts.
    #[error("its name says ADC {named}, but it is given as table {} of four (ADC {position}): give the tables in ADC order 0 to 3, or one prefix", .position + 1)]
    AdcOutOfOrder {
        /// The ADC the name says.
        named: usize,
        /// The place it was given in (0-based: the ADC it would be read as).
        position: usize,
    },
    /// A K-Cor table whose name does not say its ADC.
    #[error("a K-Cor table (4096 little-endian u32) whose name does not say its ADC (one of adc0 .. adc3): give the camera's four tables, a prefix or a path with {{adc}} in it")]
    NameWithoutAdc,
    /// One camera's tables at different scalings.
    #[error("ends at 2^{bits} - 1 where ADC 0's table ends at 2^{first_bits} - 1: one camera's tables share a scaling")]
    ScalingDiffers {
        /// This table's scaling, bits.
        bits: u32,
        /// ADC 0's.
        first_bits: u32,
    },
    /// A LUT set that is not four ADCs of 4096 codes, for the K-Cor tables.
    #[error("{n_adc} ADCs of {codes} codes; K-Cor tables are four ADCs of 4096 codes")]
    NotKcorShape {
        /// ADCs.
        n_adc: usize,
        /// Codes per ADC.
        codes: usize,
    },
    /// A LUT file without the code widths the K-Cor tables are made from.
    #[error("no WEIGHTS extension: the code widths a K-Cor table needs are not in this LUT (LUT files written by `lut build` or `lut import` carry them)")]
    NoWeights,
    /// A scaling the K-Cor tables do not have.
    #[error("--bits {bits}: K-Cor tables end at 2^22 - 1 or 2^23 - 1")]
    KcorBits {
        /// The scaling asked for.
        bits: u32,
    },
    /// Code widths that do not rebuild the file's tables.
    #[error("ADC {adc}: the WEIGHTS extension does not rebuild the tables (the file was edited?); refusing to export")]
    WeightsDisagree {
        /// The first ADC that differs.
        adc: usize,
    },
    /// A table that does not rise: the same entry at every code (all zero, say).
    #[error("ADC {adc}'s table holds {entry} at every code: a LUT maps each code to its cumulative width and must rise (a constant table would read every code as one value)")]
    FlatTable {
        /// The ADC.
        adc: usize,
        /// Its one entry.
        entry: u32,
    },
    /// Code widths that sum to zero.
    #[error("ADC {adc}: the weights sum to zero")]
    ZeroWeights {
        /// The ADC.
        adc: usize,
    },
    /// A device image shorter than its header.
    #[error("device image shorter than its 16-byte header")]
    ImageShort,
    /// A device image's bits per code outside 1 to 16.
    #[error("device image declares {bits} bits")]
    ImageBits {
        /// What the header says.
        bits: u32,
    },
    /// A core entry the independent float reference does not reproduce.
    #[error("ADC {adc} code {code}: core entry {core} differs from the float reference {reference}")]
    CoreDiffersFromReference {
        /// The ADC.
        adc: usize,
        /// The code.
        code: usize,
        /// The core's entry, LUT units.
        core: u32,
        /// The reference's, LUT units.
        reference: u64,
    },
    /// A LUT without a table for the ADC asked for.
    #[error("no table for ADC {adc}")]
    NoTableForAdc {
        /// The ADC.
        adc: usize,
    },
    /// A table of another length than the camera's ADC has codes.
    #[error("{codes} codes, the camera's ADC has {camera_codes}")]
    CodesDiffer {
        /// The table's length.
        codes: usize,
        /// The camera ADC's codes.
        camera_codes: usize,
    },
    /// A table the FPGA model is not built for.
    #[error("a table of {entries} entries; the FPGA model is built for 4096")]
    FpgaTableLength {
        /// The table's length.
        entries: usize,
    },
    /// A table count the FPGA model is not built for.
    #[error("{tables} tables; the FPGA model is built for 4 ADCs")]
    FpgaTableCount {
        /// The LUT's tables.
        tables: usize,
    },
    /// An `-o` that names a directory where a file prefix is expected.
    #[error("names a directory; -o takes a file prefix OUT and writes {writes} (e.g. -o {example})")]
    OutputIsDirectory {
        /// What the prefix becomes.
        writes: String,
        /// A prefix that would do.
        example: String,
    },
}
