//! The frame-grabber datapath's register map and SPI framing. The
//! [`driver`](crate::driver) speaks it; the FPGA model answers it. Both take every
//! number from here.
//!
//! ## SPI transactions (one chip-select assertion each, bytes in order)
//! | command           | host sends                                  | device returns               |
//! |-------------------|---------------------------------------------|------------------------------|
//! | `WRITE_REG` 0x01  | `0x01, addr, value (u32 LE)`                | nothing                      |
//! | `READ_REG`  0x02  | `0x02, addr`, then 4 clocked bytes           | `value (u32 LE)` in those 4  |
//! | `LUT_DATA`  0x03  | `0x03, len (u16 LE), len bytes of image`    | nothing                      |
//!
//! `LUT_DATA` appends to the staging upload opened by `CONTROL.LUT_BEGIN`;
//! `CONTROL.LUT_COMMIT` validates it and, if valid, requests activation at the next frame
//! boundary. At most [`MAX_LUT_CHUNK`] image bytes travel per `LUT_DATA`.
//!
//! ## Registers (32-bit)
//! | addr | name          | access | meaning                                                           |
//! |------|---------------|--------|-------------------------------------------------------------------|
//! | 0x00 | `ID`          | RO     | [`DEVICE_ID`], ASCII `DNCL` little-endian                         |
//! | 0x04 | `CONTROL`     | WO     | bit 0 `ENABLE`, bit 1 `LUT_BEGIN`, bit 2 `LUT_COMMIT`, bit 3 `CLEAR_SUMS` |
//! | 0x08 | `STATUS`      | RO     | bit 0 staging valid, bit 1 activation pending, bit 2 frame open, bit 3 upload failed, bits 8-9 active bank |
//! | 0x0C | `WIDTH`       | RW     | pixels per line                                                   |
//! | 0x10 | `HEIGHT`      | RW     | lines per frame                                                   |
//! | 0x14 | `STATES`      | RW     | modulation states (1..=8)                                         |
//! | 0x18 | `FIRST_COLUMN`| RW     | sensor column of a line's first pixel                             |
//! | 0x1C | `OUT_OF_RANGE`| RO     | codes read above the top code                                     |
//! | 0x20 | `SATURATED`   | RO     | additions clipped at 2^32 - 1                                     |
//! | 0x24 | `REJECTED`    | RO     | lines rejected                                                    |
//! | 0x28 | `FRAMES`      | RO     | frames completed                                                  |
//! | 0x2C | `LUT_SWAPS`   | RO     | LUT bank swaps                                                    |
//! | 0x30 | `INCOMPLETE`  | RO     | frames ended before all their lines arrived                       |
//! | 0x34 | `FIFO_OVERFLOW`| RO    | pixels dropped by a full input FIFO (the FPGA datapath; 0 on the MCU) |

/// Write a register.
pub const CMD_WRITE_REG: u8 = 0x01;
/// Read a register.
pub const CMD_READ_REG: u8 = 0x02;
/// Stream LUT image bytes into the staging upload.
pub const CMD_LUT_DATA: u8 = 0x03;
/// Largest image chunk per `LUT_DATA` transaction, bytes.
pub const MAX_LUT_CHUNK: usize = 256;

/// The value of the `ID` register.
pub const DEVICE_ID: u32 = u32::from_le_bytes(*b"DNCL");

/// Register addresses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum Reg {
    /// Identification.
    Id = 0x00,
    /// Control actions.
    Control = 0x04,
    /// Status bits.
    Status = 0x08,
    /// Pixels per line.
    Width = 0x0C,
    /// Lines per frame.
    Height = 0x10,
    /// Modulation states.
    States = 0x14,
    /// First sensor column.
    FirstColumn = 0x18,
    /// Out-of-range codes counter.
    OutOfRange = 0x1C,
    /// Saturated additions counter.
    Saturated = 0x20,
    /// Rejected lines counter.
    Rejected = 0x24,
    /// Completed frames counter.
    Frames = 0x28,
    /// LUT swaps counter.
    LutSwaps = 0x2C,
    /// Incomplete frames counter.
    Incomplete = 0x30,
    /// Pixels dropped by a full input FIFO.
    FifoOverflow = 0x34,
}

impl Reg {
    /// Every register, for devices that decode addresses.
    pub const ALL: [Reg; 14] = [
        Reg::Id,
        Reg::Control,
        Reg::Status,
        Reg::Width,
        Reg::Height,
        Reg::States,
        Reg::FirstColumn,
        Reg::OutOfRange,
        Reg::Saturated,
        Reg::Rejected,
        Reg::Frames,
        Reg::LutSwaps,
        Reg::Incomplete,
        Reg::FifoOverflow,
    ];

    /// The register at `addr`, if any.
    pub fn from_addr(addr: u8) -> Option<Reg> {
        Self::ALL.into_iter().find(|r| *r as u8 == addr)
    }
}

/// `CONTROL` bits.
pub mod control {
    /// Corrections on.
    pub const ENABLE: u32 = 1 << 0;
    /// Open a new staging upload.
    pub const LUT_BEGIN: u32 = 1 << 1;
    /// Validate the upload; request activation at the next frame boundary if valid.
    pub const LUT_COMMIT: u32 = 1 << 2;
    /// Zero the sums and frame counts.
    pub const CLEAR_SUMS: u32 = 1 << 3;
}

/// `STATUS` bits.
pub mod status {
    /// The staging bank holds a validated set.
    pub const STAGING_VALID: u32 = 1 << 0;
    /// An activation waits for the next frame boundary.
    pub const ACTIVATION_PENDING: u32 = 1 << 1;
    /// A frame is open.
    pub const FRAME_OPEN: u32 = 1 << 2;
    /// The last upload failed validation.
    pub const UPLOAD_FAILED: u32 = 1 << 3;
    /// Shift of the active bank index.
    pub const ACTIVE_BANK_SHIFT: u32 = 8;
}
