//! The one error type of the core. Every variant says what was wrong and where, so a
//! firmware log line or a host error message can be read without the source.

use core::fmt;

use crate::regs::Reg;

/// Everything the core can reject. `Display` for people, `defmt::Format` for the device.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CoreError {
    /// The number of codes of a LUT set is not a power of two between 2 and 2^16.
    CodeCount {
        /// The number of codes asked for.
        codes: usize,
    },
    /// A code exceeds the top code `2^B - 1` where an exact code was required.
    CodeOutOfRange {
        /// The raw code.
        code: u16,
        /// The highest valid code.
        max: u16,
    },
    /// A LUT entry is not below 2^23 (12 integer + 11 fractional bits).
    EntryOutOfRange {
        /// ADC index.
        adc: u16,
        /// Code index.
        code: u16,
        /// Raw bits of the entry.
        bits: u32,
    },
    /// A LUT table decreases from `code - 1` to `code`.
    NonMonotonic {
        /// ADC index.
        adc: u16,
        /// First code whose entry is below its predecessor.
        code: u16,
    },
    /// A slice had the wrong number of elements (weights, line pixels, sum buffer).
    Length {
        /// What was measured.
        what: Quantity,
        /// Expected number of elements.
        expected: u32,
        /// Number given.
        got: u32,
    },
    /// Geometry out of bounds: zero size or too many modulation states.
    Geometry {
        /// Width in pixels.
        width: u16,
        /// Height in lines.
        height: u16,
        /// Modulation states.
        states: u8,
    },
    /// An ADC index is not below the number of ADCs.
    Adc {
        /// The ADC given.
        adc: u16,
        /// The number of ADCs.
        adcs: u16,
    },
    /// A modulation state index is not below the configured number of states.
    State {
        /// The state given.
        state: u8,
        /// The configured number of states.
        states: u8,
    },
    /// A line arrived out of order within a frame (lines must come 0, 1, ..., height-1).
    LineOrder {
        /// The next line the frame expects.
        expected: u16,
        /// The line given.
        got: u16,
    },
    /// `begin_frame` while a frame is open.
    FrameOpen,
    /// A line or `end_frame` while no frame is open.
    NoFrame,
    /// A ROI outside the geometry or empty.
    Roi,
    /// The device image does not start with the magic bytes `DNLT`.
    ImageMagic,
    /// The device image has a version this core does not read.
    ImageVersion {
        /// The version found.
        version: u16,
    },
    /// The image's bits, ADC count or fractional bits do not match this LUT set.
    ImageLayout {
        /// Bits per code in the image.
        bits: u8,
        /// ADC count in the image.
        adcs: u8,
        /// Fractional bits of the entries in the image.
        frac_bits: u8,
    },
    /// The image's reserved header bytes are not zero.
    ImageReserved,
    /// A line-stream header lacks the magic `DNLS`, version 1 or zero reserved byte.
    StreamHeader,
    /// The image ended before its declared length, or continued past it.
    ImageLength {
        /// Declared length in bytes.
        expected: u32,
        /// Length received in bytes.
        got: u32,
    },
    /// The image's CRC-32 does not match its contents.
    ImageCrc {
        /// CRC stored in the image.
        stored: u32,
        /// CRC computed over the received bytes.
        computed: u32,
    },
    /// A loader was fed after it failed or finished; begin a new upload.
    LoaderState,
    /// Activation asked for while the staging bank holds no validated LUT set.
    StagingNotValid,
    /// An output buffer is too small.
    BufferTooSmall {
        /// Bytes needed.
        needed: u32,
        /// Bytes available.
        got: u32,
    },
    /// The SPI peripheral itself reported an error (the driver does not retry: the host's
    /// own bus is broken, not a frame on it).
    Bus,
    /// The driver's checks of an exchange with the datapath failed on every attempt (see
    /// [`crate::driver`]); the active LUTs are the old ones or, for an upload whose
    /// activation could not be confirmed, possibly the new ones, never anything else.
    Link {
        /// What the driver was doing.
        step: LinkStep,
        /// Attempts made.
        attempts: u8,
        /// What the last attempt's check found.
        last: LinkFault,
    },
    /// A register write arrived (the frame count says so) but the register reads back
    /// another value: the datapath refused it (a geometry it cannot hold, a read-only
    /// register).
    WriteRefused {
        /// The register.
        reg: Reg,
        /// The value written.
        value: u32,
        /// The value read back.
        read: u32,
    },
    /// The datapath abandoned an upload because one of its frames was lost or malformed.
    UploadAborted,
    /// The datapath answered with an unexpected identification word.
    DeviceId {
        /// The word read from the ID register.
        id: u32,
    },
    /// Too few samples to estimate a noise level.
    NoiseSamples {
        /// Samples accumulated.
        samples: u32,
    },
}

/// What a [`CoreError::Length`] counted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Quantity {
    /// Per-code weights of one ADC.
    Weights,
    /// Pixels of one line.
    LinePixels,
    /// Elements of the sum buffer.
    SumBuffer,
    /// Pixels of a pair of lines for the noise estimate.
    NoisePair,
    /// Pixels of a block of whole lines (a multiple of the line width).
    BlockPixels,
}

/// What the driver was doing when it gave up ([`CoreError::Link`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LinkStep {
    /// Reading a register.
    Read(Reg),
    /// Writing a register.
    Write(Reg),
    /// Uploading and activating a LUT image.
    LutUpload,
}

/// What one of the driver's checks found wrong with an exchange.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LinkFault {
    /// A response failed its CRC-8: corrupted on the way back, cut short, or never driven
    /// because its request was lost or refused.
    ResponseCrc,
    /// The datapath had accepted another number of frames than the driver sent: one was
    /// lost, refused (corrupted, truncated, split) or delivered twice.
    FrameCount {
        /// The count the driver expected.
        expected: u16,
        /// The count the datapath reported.
        got: u16,
    },
    /// The datapath received every frame of an upload but its validation failed: image
    /// bytes were corrupted on the way (or the image itself is invalid).
    ImageRejected,
    /// `STATUS` after an upload step is not what that step leaves.
    Status {
        /// The `STATUS` bits read.
        bits: u32,
    },
}

impl fmt::Display for LinkStep {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LinkStep::Read(reg) => write!(f, "reading {reg:?}"),
            LinkStep::Write(reg) => write!(f, "writing {reg:?}"),
            LinkStep::LutUpload => f.write_str("uploading a LUT image"),
        }
    }
}

impl fmt::Display for LinkFault {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LinkFault::ResponseCrc => f.write_str("a response failed its CRC-8"),
            LinkFault::FrameCount { expected, got } => write!(f, "the datapath counted frame {got}, the driver sent up to {expected}"),
            LinkFault::ImageRejected => f.write_str("the datapath rejected the image it received"),
            LinkFault::Status { bits } => write!(f, "unexpected STATUS {bits:#06x}"),
        }
    }
}

impl fmt::Display for Quantity {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Quantity::Weights => "weights",
            Quantity::LinePixels => "line pixels",
            Quantity::SumBuffer => "sum buffer elements",
            Quantity::NoisePair => "noise line pair pixels",
            Quantity::BlockPixels => "block pixels (whole lines)",
        })
    }
}

impl fmt::Display for CoreError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        use CoreError::*;
        match *self {
            CodeCount { codes } => write!(f, "{codes} codes is not a power of two in 2..=65536"),
            CodeOutOfRange { code, max } => write!(f, "code {code} above the top code {max}"),
            EntryOutOfRange { adc, code, bits } => {
                write!(f, "LUT entry ADC {adc} code {code} = {bits} is not below 2^23")
            }
            NonMonotonic { adc, code } => write!(f, "LUT of ADC {adc} decreases at code {code}"),
            Length { what, expected, got } => write!(f, "expected {expected} {what}, got {got}"),
            Geometry { width, height, states } => write!(
                f,
                "geometry {width}x{height} with {states} states is invalid (sizes >= 1, states 1..=8)"
            ),
            Adc { adc, adcs } => write!(f, "ADC {adc} not below {adcs}"),
            State { state, states } => write!(f, "modulation state {state} not below {states}"),
            LineOrder { expected, got } => write!(f, "line {got} out of order, expected line {expected}"),
            FrameOpen => f.write_str("a frame is already open"),
            NoFrame => f.write_str("no frame is open"),
            Roi => f.write_str("region of interest empty or outside the geometry"),
            ImageMagic => f.write_str("LUT image does not start with magic 'DNLT'"),
            ImageVersion { version } => write!(f, "LUT image version {version} is not supported"),
            ImageLayout { bits, adcs, frac_bits } => write!(
                f,
                "LUT image layout ({bits} bits, {adcs} ADCs, {frac_bits} fractional bits) does not match"
            ),
            ImageReserved => f.write_str("LUT image reserved header bytes are not zero"),
            StreamHeader => f.write_str("line stream header invalid (magic 'DNLS', version 1, reserved 0)"),
            ImageLength { expected, got } => {
                write!(f, "LUT image length {got} bytes, header declares {expected}")
            }
            ImageCrc { stored, computed } => {
                write!(f, "LUT image CRC-32 mismatch: stored {stored:#010x}, computed {computed:#010x}")
            }
            LoaderState => f.write_str("LUT loader is not accepting data; begin a new upload"),
            StagingNotValid => f.write_str("staging bank holds no validated LUT set"),
            BufferTooSmall { needed, got } => write!(f, "buffer of {got} bytes, {needed} needed"),
            Bus => f.write_str("SPI bus error"),
            Link { step, attempts, last } => write!(f, "SPI link: gave up {step} after {attempts} attempts; last: {last}"),
            WriteRefused { reg, value, read } => write!(f, "datapath refused {value:#x} for {reg:?}, which reads {read:#x}"),
            UploadAborted => f.write_str("the datapath abandoned the upload: a frame of it was lost or malformed"),
            DeviceId { id } => write!(f, "unexpected datapath ID {id:#010x}"),
            NoiseSamples { samples } => write!(f, "{samples} samples are too few for a noise estimate"),
        }
    }
}

impl core::error::Error for CoreError {}
