//! The frame-grabber datapath's register map and SPI framing. The
//! [`driver`](crate::driver) speaks it; the FPGA model answers it. Both take every
//! number, and every frame they build or parse, from here.
//!
//! ## SPI frames (one chip-select assertion each, bytes in order), version 2
//! | command           | host sends                                          | device returns                       |
//! |-------------------|-----------------------------------------------------|--------------------------------------|
//! | `WRITE_REG` 0x01  | `0x01, addr, value (u32 LE), crc8`                  | nothing                              |
//! | `READ_REG`  0x02  | `0x02, addr, crc8`, then 7 clocked bytes            | `value (u32 LE), count (u16 LE), crc8` in those 7 |
//! | `LUT_DATA`  0x03  | `0x03, offset (u32 LE), len (u16 LE), len bytes`    | nothing                              |
//!
//! `crc8` is [`frame_crc`] (CRC-8/SMBUS: polynomial 0x07, initial value 0) over every byte
//! before it; a response's covers the request's `0x02, addr` and then `value, count`, so
//! an answer is bound to the question. `count` is the number of frames the device has
//! accepted (this read included), modulo 2^16: the host knows how many it sent, so a
//! frame lost, refused or delivered twice shows as a count other than the one expected.
//! (The host checks at least once per upload, whose 2 + ceil(image bytes / 256) frames
//! are far fewer than 2^16, so the count cannot wrap onto the expected one. A count of 8
//! bits could: losing the third of 257 chunks makes the device refuse the 254 after it
//! and the `LUT_END`, 256 frames missing, which it does not see.)
//! A `LUT_DATA` payload has no CRC of its own: the image's CRC-32 trailer covers it
//! ([`crate::image`]); `offset` must equal the number of image bytes the open upload has
//! received, so a chunk lost, repeated or out of order is refused. An upload is open on
//! the link from `LUT_BEGIN` until `LUT_END`, `LUT_COMMIT` or a refused frame; image bytes
//! that fail the image's checks do not close it (the rest is taken and discarded, so the
//! count stays right and `STATUS` says "upload failed" at `LUT_END`).
//!
//! The device *refuses* a frame that fails its CRC, has the wrong length, an unknown
//! command or register, or (`LUT_DATA`) no open upload, an offset other than the bytes
//! received, or more than [`MAX_LUT_CHUNK`] bytes. A refused frame changes nothing and is
//! not counted; it fails an open upload (a gap makes the rest useless), a refused read
//! leaves MISO idle (every response byte 0xFF, which never passes the CRC), and the
//! device then refuses every `WRITE_REG` and `LUT_DATA` until the host's next accepted
//! `READ_REG`. That hold is what makes a chip-select glitch safe: the second half of a
//! split frame arrives as a frame of its own, and could otherwise be taken for a write.
//! A well-formed write of a value the register cannot take (a geometry the device cannot
//! hold, a read-only register) is counted and leaves the register as it was; the host
//! sees it in the read-back.
//!
//! `CONTROL.LUT_BEGIN` opens an empty staging upload (and cancels a pending activation);
//! `LUT_DATA` appends to it; `CONTROL.LUT_END` validates it (STATUS: staging valid, or
//! upload failed); `CONTROL.LUT_COMMIT` validates it if still open and, if valid,
//! requests activation at the next frame boundary. Every `CONTROL` action is idempotent
//! when repeated at once (a second `LUT_COMMIT` finds the staging bank empty), so a write
//! that arrived twice does no harm and the host may repeat one it could not confirm.
//!
//! ## Registers (32-bit)
//! | addr | name          | access | meaning                                                           |
//! |------|---------------|--------|-------------------------------------------------------------------|
//! | 0x00 | `ID`          | RO     | [`DEVICE_ID`], ASCII `DNCL` little-endian                         |
//! | 0x04 | `CONTROL`     | WO     | bit 0 `ENABLE`, bit 1 `LUT_BEGIN`, bit 2 `LUT_COMMIT`, bit 3 `CLEAR_SUMS`, bit 4 `LUT_END` (reads 0) |
//! | 0x08 | `STATUS`      | RO     | bit 0 staging valid, bit 1 activation pending, bit 2 frame open, bit 3 upload failed, bit 4 upload open, bits 8-9 active bank |
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

use crc::{Crc, CRC_8_SMBUS};

/// Write a register.
pub const CMD_WRITE_REG: u8 = 0x01;
/// Read a register.
pub const CMD_READ_REG: u8 = 0x02;
/// Stream LUT image bytes into the staging upload.
pub const CMD_LUT_DATA: u8 = 0x03;
/// Largest image chunk per `LUT_DATA` transaction, bytes.
pub const MAX_LUT_CHUNK: usize = 256;
/// Bytes of a `WRITE_REG` frame.
pub const WRITE_FRAME_LEN: usize = 7;
/// Bytes of a `READ_REG` request.
pub const READ_REQUEST_LEN: usize = 3;
/// Bytes clocked back after a `READ_REG` request.
pub const READ_RESPONSE_LEN: usize = 7;
/// Bytes of a `LUT_DATA` header, before the image bytes.
pub const LUT_HEADER_LEN: usize = 7;
/// What an undriven MISO line reads as (pulled up).
pub const IDLE_BYTE: u8 = 0xFF;

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

    /// Whether a read returns what a write set: every register but the write-only
    /// `CONTROL` (a write to a read-only one is refused, which its read-back shows).
    pub fn reads_back(self) -> bool {
        self != Reg::Control
    }
}

static CRC8: Crc<u8> = Crc::<u8>::new(&CRC_8_SMBUS);

/// The CRC-8 of a frame's bytes. Over the frames of this protocol (at most 64 bits before
/// the CRC, of which at most 56 travel) it detects every error of up to three bits and every burst of up to eight
/// bits on the wire (both tested exhaustively below), and, its polynomial having x + 1 as
/// a factor, every error of an odd number of bits.
pub fn frame_crc(bytes: &[u8]) -> u8 {
    CRC8.checksum(bytes)
}

/// The `WRITE_REG` frame setting `reg` to `value`.
pub fn write_frame(reg: Reg, value: u32) -> [u8; WRITE_FRAME_LEN] {
    let v = value.to_le_bytes();
    let mut f = [CMD_WRITE_REG, reg as u8, v[0], v[1], v[2], v[3], 0];
    f[6] = frame_crc(&f[..6]);
    f
}

/// The `READ_REG` request for `reg`.
pub fn read_request(reg: Reg) -> [u8; READ_REQUEST_LEN] {
    let head = [CMD_READ_REG, reg as u8];
    [head[0], head[1], frame_crc(&head)]
}

fn response_crc(reg: Reg, payload: &[u8]) -> u8 {
    let mut digest = CRC8.digest();
    digest.update(&[CMD_READ_REG, reg as u8]);
    digest.update(payload);
    digest.finalize()
}

/// The device's answer to a read of `reg`: its value and the device's frame count.
pub fn read_response(reg: Reg, value: u32, count: u16) -> [u8; READ_RESPONSE_LEN] {
    let (v, c) = (value.to_le_bytes(), count.to_le_bytes());
    let mut r = [v[0], v[1], v[2], v[3], c[0], c[1], 0];
    r[6] = response_crc(reg, &r[..6]);
    r
}

/// The value and frame count of a response to a read of `reg`, if its CRC holds.
pub fn parse_read_response(reg: Reg, bytes: &[u8; READ_RESPONSE_LEN]) -> Option<(u32, u16)> {
    (response_crc(reg, &bytes[..6]) == bytes[6])
        .then_some((u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]), u16::from_le_bytes([bytes[4], bytes[5]])))
}

/// The `LUT_DATA` header of `len` image bytes starting at image byte `offset`.
pub fn lut_header(offset: u32, len: u16) -> [u8; LUT_HEADER_LEN] {
    let (o, l) = (offset.to_le_bytes(), len.to_le_bytes());
    [CMD_LUT_DATA, o[0], o[1], o[2], o[3], l[0], l[1]]
}

/// A frame as the device parses it from the bytes of one chip-select assertion.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Frame<'a> {
    /// Set `reg` to `value`.
    Write {
        /// The register.
        reg: Reg,
        /// The value.
        value: u32,
    },
    /// Read `reg` (the response follows in the same assertion).
    Read {
        /// The register.
        reg: Reg,
    },
    /// Image bytes for the open upload.
    LutData {
        /// Image bytes the upload must have received before these.
        offset: u32,
        /// The image bytes.
        data: &'a [u8],
    },
}

/// Parses the host's bytes of one frame; `None` if the device must refuse them (CRC,
/// length, command, register, or a chunk of more than [`MAX_LUT_CHUNK`] bytes; whether a
/// chunk fits the open upload is the device's to check).
pub fn parse_frame(bytes: &[u8]) -> Option<Frame<'_>> {
    let crc_ok = |n: usize| bytes.len() == n && frame_crc(&bytes[..n - 1]) == bytes[n - 1];
    match *bytes.first()? {
        CMD_WRITE_REG if crc_ok(WRITE_FRAME_LEN) => {
            Some(Frame::Write { reg: Reg::from_addr(bytes[1])?, value: u32::from_le_bytes([bytes[2], bytes[3], bytes[4], bytes[5]]) })
        }
        CMD_READ_REG if crc_ok(READ_REQUEST_LEN) => Some(Frame::Read { reg: Reg::from_addr(bytes[1])? }),
        CMD_LUT_DATA if bytes.len() > LUT_HEADER_LEN => {
            let len = u16::from_le_bytes([bytes[5], bytes[6]]) as usize;
            let data = &bytes[LUT_HEADER_LEN..];
            (data.len() == len && len <= MAX_LUT_CHUNK).then_some(Frame::LutData { offset: u32::from_le_bytes([bytes[1], bytes[2], bytes[3], bytes[4]]), data })
        }
        _ => None,
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
    /// Validate the upload without activating it.
    pub const LUT_END: u32 = 1 << 4;
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
    /// An upload is open (begun, neither ended nor failed).
    pub const UPLOAD_OPEN: u32 = 1 << 4;
    /// Shift of the active bank index.
    pub const ACTIVE_BANK_SHIFT: u32 = 8;
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A copy of `frame` with bits `bits` flipped, numbered in wire order (SPI sends the
    /// most significant bit first: bit b is bit 7 - b % 8 of byte b / 8), so that
    /// consecutive numbers are a burst on the wire.
    fn flipped<const N: usize>(frame: [u8; N], bits: &[usize]) -> [u8; N] {
        let mut f = frame;
        for &b in bits {
            f[b / 8] ^= 0x80 >> (b % 8);
        }
        f
    }

    /// Every error of one to three bits, and every burst of up to eight, is refused in a
    /// write frame and a read request, and fails a response's CRC.
    #[test]
    fn the_frame_crc_catches_every_error_of_up_to_three_bits_and_every_short_burst() {
        let write = write_frame(Reg::FirstColumn, 0x0001_0082);
        let request = read_request(Reg::Status);
        let response = read_response(Reg::Status, 0x0000_0119, 0x017E);
        assert_eq!(parse_frame(&write), Some(Frame::Write { reg: Reg::FirstColumn, value: 0x0001_0082 }));
        assert_eq!(parse_frame(&request), Some(Frame::Read { reg: Reg::Status }));
        assert_eq!(parse_read_response(Reg::Status, &response), Some((0x119, 0x017E)));
        let check = |bits: &[usize]| {
            if bits.iter().all(|&b| b < 8 * WRITE_FRAME_LEN) {
                assert_eq!(parse_frame(&flipped(write, bits)), None, "write frame, bits {bits:?}");
            }
            if bits.iter().all(|&b| b < 8 * READ_REQUEST_LEN) {
                assert_eq!(parse_frame(&flipped(request, bits)), None, "read request, bits {bits:?}");
            }
            if bits.iter().all(|&b| b < 8 * READ_RESPONSE_LEN) {
                assert_eq!(parse_read_response(Reg::Status, &flipped(response, bits)), None, "response, bits {bits:?}");
            }
        };
        let n = 8 * WRITE_FRAME_LEN;
        for a in 0..n {
            check(&[a]);
            for b in a + 1..n {
                check(&[a, b]);
                for c in b + 1..n {
                    check(&[a, b, c]);
                }
            }
        }
        // Bursts: any pattern inside a window of 8 bits on the wire, at any position.
        for start in 0..n {
            for mask in 1u32..256 {
                let bits: heapless::Vec<usize, 8> = (0..8).filter(|i| mask >> i & 1 == 1).map(|i| start + i).filter(|&b| b < n).collect();
                if !bits.is_empty() {
                    check(&bits);
                }
            }
        }
    }

    /// An undriven MISO (all ones) or one stuck low never reads as a valid response, for
    /// any register: a lost or refused read is always noticed.
    #[test]
    fn an_idle_or_stuck_line_is_never_a_valid_response() {
        for reg in Reg::ALL {
            assert_eq!(parse_read_response(reg, &[IDLE_BYTE; READ_RESPONSE_LEN]), None, "{reg:?}");
            assert_eq!(parse_read_response(reg, &[0; READ_RESPONSE_LEN]), None, "{reg:?}");
        }
    }

    /// A response names the register asked for: the same bytes for another register fail.
    #[test]
    fn a_response_is_bound_to_its_register() {
        let r = read_response(Reg::Width, 64, 3);
        assert_eq!(parse_read_response(Reg::Width, &r), Some((64, 3)));
        assert_eq!(parse_read_response(Reg::Height, &r), None);
    }

    #[test]
    fn lut_frames_are_checked_for_length_and_size() {
        let mut f = [0u8; LUT_HEADER_LEN + 4];
        f[..LUT_HEADER_LEN].copy_from_slice(&lut_header(512, 4));
        assert_eq!(parse_frame(&f), Some(Frame::LutData { offset: 512, data: &[0; 4] }));
        assert_eq!(parse_frame(&f[..LUT_HEADER_LEN + 3]), None, "a truncated chunk");
        assert_eq!(parse_frame(&f[..LUT_HEADER_LEN]), None, "a header alone");
        let mut big = [0u8; LUT_HEADER_LEN + MAX_LUT_CHUNK + 1];
        big[..LUT_HEADER_LEN].copy_from_slice(&lut_header(0, MAX_LUT_CHUNK as u16 + 1));
        assert_eq!(parse_frame(&big), None, "more than MAX_LUT_CHUNK bytes");
        assert_eq!(parse_frame(&[]), None);
        assert_eq!(parse_frame(&[0x7F, 0, 0]), None);
    }
}
