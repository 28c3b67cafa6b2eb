//! The host-MCU side of the frame-grabber datapath: writes LUT images and control
//! registers over SPI, generic over any `embedded_hal::spi::SpiDevice`. The same driver
//! runs on the firmware against the real bus and on the host against the FPGA model.
//! The wire format and register map are in [`crate::regs`].
//!
//! ## Not trusting the wire
//! An SPI master hears no acknowledgement: a frame corrupted, cut short, split by a
//! chip-select glitch, lost or delivered twice still leaves the bus reporting success.
//! So every operation ends with a checked read (`driver/link.rs`): the response's CRC-8 must hold
//! and the datapath's frame count must have advanced by exactly the frames sent since the
//! last check. On top of that
//! - a register write is confirmed by reading the register back (`CONTROL`, which reads
//!   0, by the frame count alone);
//! - an upload is `LUT_BEGIN` (confirmed: `STATUS` says open and empty), the chunks,
//!   `LUT_END` (confirmed: every chunk counted and `STATUS` says staging valid, that is the
//!   datapath's CRC-32 check of the image passed) and `LUT_COMMIT` (confirmed: the active
//!   bank is the one just filled, or the activation waits for a frame boundary).
//!
//! A failed check is counted in [`LinkStats`] and the step is repeated, reads and writes
//! up to [`ATTEMPTS`] times and whole uploads up to [`UPLOAD_ATTEMPTS`] times; then the
//! driver gives up with [`CoreError::Link`]. Repeating is safe: register writes and
//! `CONTROL` actions are idempotent, and the datapath activates only a staging bank it has
//! validated whole, so the active LUTs are never anything but the old or the new image.

mod link;

use embedded_hal::spi::{Operation, SpiDevice};

use crate::error::{LinkFault, LinkStep};
use crate::image::CRC32;
use crate::regs::{control, lut_header, status, Reg, DEVICE_ID, MAX_LUT_CHUNK};
use crate::{CoreError, Geometry, Status};

/// Tries of one register read or write before the driver gives up.
pub const ATTEMPTS: u8 = 4;
/// Tries of a whole LUT upload before the driver gives up.
pub const UPLOAD_ATTEMPTS: u8 = 4;

/// The decoded `STATUS` register.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DatapathStatus {
    /// The staging bank holds a validated set.
    pub staging_valid: bool,
    /// An activation waits for the next frame boundary.
    pub activation_pending: bool,
    /// A frame is open.
    pub frame_open: bool,
    /// The last upload failed validation.
    pub upload_failed: bool,
    /// An upload is open: begun, neither ended nor failed.
    pub upload_open: bool,
    /// The active bank, 0 or 1.
    pub active_bank: u8,
}

impl DatapathStatus {
    /// Decodes the register value.
    pub fn from_bits(bits: u32) -> Self {
        DatapathStatus {
            staging_valid: bits & status::STAGING_VALID != 0,
            activation_pending: bits & status::ACTIVATION_PENDING != 0,
            frame_open: bits & status::FRAME_OPEN != 0,
            upload_failed: bits & status::UPLOAD_FAILED != 0,
            upload_open: bits & status::UPLOAD_OPEN != 0,
            active_bank: ((bits >> status::ACTIVE_BANK_SHIFT) & 0b11) as u8,
        }
    }
    /// Encodes the register value.
    pub fn to_bits(self) -> u32 {
        let bit = |on: bool, mask: u32| if on { mask } else { 0 };
        bit(self.staging_valid, status::STAGING_VALID)
            | bit(self.activation_pending, status::ACTIVATION_PENDING)
            | bit(self.frame_open, status::FRAME_OPEN)
            | bit(self.upload_failed, status::UPLOAD_FAILED)
            | bit(self.upload_open, status::UPLOAD_OPEN)
            | ((self.active_bank as u32) << status::ACTIVE_BANK_SHIFT)
    }
}

/// What the driver's checks found since it was made. A fault on the wire shows in one of
/// the first four counters ([`Self::detections`]); the rest say what the driver did about it.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LinkStats {
    /// Responses that failed their CRC-8 ([`LinkFault::ResponseCrc`]).
    pub response_crc: u32,
    /// Checks at which the datapath had counted other frames than were sent
    /// ([`LinkFault::FrameCount`]).
    pub frame_count: u32,
    /// Uploads the datapath received whole and rejected ([`LinkFault::ImageRejected`]).
    pub image_rejected: u32,
    /// Upload steps that left another `STATUS` than they must ([`LinkFault::Status`]).
    pub status: u32,
    /// Steps repeated after a failed check.
    pub retries: u32,
    /// Operations abandoned after their last attempt ([`CoreError::Link`], or
    /// [`CoreError::StagingNotValid`] after the last upload attempt).
    pub give_ups: u32,
}

impl LinkStats {
    /// Failed checks of every kind.
    pub fn detections(&self) -> u32 {
        self.response_crc.saturating_add(self.frame_count).saturating_add(self.image_rejected).saturating_add(self.status)
    }
}

/// Counts one more, saturating (a driver that runs for years must not panic on a counter).
fn bump(counter: &mut u32) {
    *counter = counter.saturating_add(1);
}

/// The datapath behind an SPI device.
pub struct Datapath<SPI> {
    spi: SPI,
    /// The datapath's frame count once every frame sent so far is counted; `None` until a
    /// response tells it (at first, and after a response that failed its CRC).
    expected_count: Option<u16>,
    stats: LinkStats,
}

impl<SPI: SpiDevice> Datapath<SPI> {
    /// A driver on `spi`; talks to nothing until called.
    pub fn new(spi: SPI) -> Self {
        Datapath { spi, expected_count: None, stats: LinkStats::default() }
    }

    /// Gives the bus back.
    pub fn release(self) -> SPI {
        self.spi
    }

    /// The device behind the bus, for a host that also drives its data path (a simulated
    /// datapath receives frames this way; on hardware they come from the camera). SPI
    /// frames sent through it are not the driver's: its next check counts them as a
    /// frame-count fault and resynchronizes.
    pub fn device_mut(&mut self) -> &mut SPI {
        &mut self.spi
    }

    /// What the driver's checks found so far.
    pub fn link_stats(&self) -> LinkStats {
        self.stats
    }

    /// Reads the ID register and checks it is a dncal datapath.
    pub fn identify(&mut self) -> Result<(), CoreError> {
        match self.read_reg(Reg::Id)? {
            DEVICE_ID => Ok(()),
            id => Err(CoreError::DeviceId { id }),
        }
    }

    /// Writes one register and confirms it: by its read-back, or for `CONTROL` by the
    /// frame count (the action arrived exactly once). A value the datapath refuses gives
    /// [`CoreError::WriteRefused`].
    pub fn write_reg(&mut self, reg: Reg, value: u32) -> Result<(), CoreError> {
        let check = if reg.reads_back() { reg } else { Reg::Status };
        let read = self.retried(LinkStep::Write(reg), ATTEMPTS, |dp| dp.write_checked(reg, value, check))?;
        if reg.reads_back() && read != value {
            return Err(CoreError::WriteRefused { reg, value, read });
        }
        Ok(())
    }

    /// Reads one register (its response's CRC-8 and frame count checked).
    pub fn read_reg(&mut self, reg: Reg) -> Result<u32, CoreError> {
        self.retried(LinkStep::Read(reg), ATTEMPTS, |dp| dp.read_checked(reg))
    }

    /// Sets the geometry registers.
    pub fn configure(&mut self, geometry: Geometry) -> Result<(), CoreError> {
        self.write_reg(Reg::Width, geometry.width() as u32)?;
        self.write_reg(Reg::Height, geometry.height() as u32)?;
        self.write_reg(Reg::States, geometry.states() as u32)?;
        self.write_reg(Reg::FirstColumn, geometry.first_column() as u32)
    }

    /// Uploads a LUT device image into the staging bank and commits it: the datapath
    /// validates it and activates it at the next frame boundary (at once if no frame is
    /// open). An image the datapath rejects on every attempt gives
    /// [`CoreError::StagingNotValid`] (at once if the image fails its own CRC-32:
    /// resending cannot help) and leaves the active LUTs in place.
    pub fn upload_lut_image(&mut self, image: &[u8]) -> Result<DatapathStatus, CoreError> {
        let mut attempt = 1;
        let mut rejected_every_time = true;
        loop {
            let fault = match self.upload_once(image)? {
                Ok(status) => return Ok(status),
                Err(fault) => fault,
            };
            rejected_every_time &= fault == LinkFault::ImageRejected;
            if fault == LinkFault::ImageRejected && !image_crc_holds(image) {
                return Err(CoreError::StagingNotValid);
            }
            if attempt >= UPLOAD_ATTEMPTS {
                bump(&mut self.stats.give_ups);
                return Err(if rejected_every_time {
                    CoreError::StagingNotValid
                } else {
                    CoreError::Link { step: LinkStep::LutUpload, attempts: attempt, last: fault }
                });
            }
            attempt += 1;
            bump(&mut self.stats.retries);
        }
    }

    /// One attempt of an upload: begin, chunks, end, commit, each step confirmed.
    fn upload_once(&mut self, image: &[u8]) -> link::Checked<DatapathStatus> {
        let begun = match self.write_checked(Reg::Control, control::LUT_BEGIN, Reg::Status)? {
            Ok(bits) => DatapathStatus::from_bits(bits),
            Err(fault) => return Ok(Err(fault)),
        };
        if !begun.upload_open || begun.staging_valid || begun.upload_failed || begun.activation_pending {
            return Ok(Err(self.status_fault(begun)));
        }
        let mut offset = 0u32;
        for chunk in image.chunks(MAX_LUT_CHUNK) {
            // A chunk is at most MAX_LUT_CHUNK bytes; an image past 4 GiB saturates the
            // offset, which the datapath refuses.
            self.send(&mut [Operation::Write(&lut_header(offset, chunk.len() as u16)), Operation::Write(chunk)])?;
            offset = offset.saturating_add(chunk.len() as u32);
        }
        let ended = match self.write_checked(Reg::Control, control::LUT_END, Reg::Status)? {
            Ok(bits) => DatapathStatus::from_bits(bits),
            Err(fault) => return Ok(Err(fault)),
        };
        if ended.upload_failed {
            bump(&mut self.stats.image_rejected);
            return Ok(Err(LinkFault::ImageRejected));
        }
        if !ended.staging_valid || ended.upload_open || ended.active_bank != begun.active_bank {
            return Ok(Err(self.status_fault(ended)));
        }
        self.commit(begun.active_bank ^ 1)
    }

    /// `LUT_COMMIT` of a validated staging bank that is to become bank `target`.
    fn commit(&mut self, target: u8) -> link::Checked<DatapathStatus> {
        let committed = |st: DatapathStatus| {
            let swapped = st.active_bank == target && !st.activation_pending && !st.staging_valid;
            let waiting = st.activation_pending && st.staging_valid && st.active_bank != target;
            swapped || waiting
        };
        let mut attempt = 1;
        loop {
            let fault = match self.write_checked(Reg::Control, control::LUT_COMMIT, Reg::Status)? {
                Ok(bits) if committed(DatapathStatus::from_bits(bits)) => return Ok(Ok(DatapathStatus::from_bits(bits))),
                Ok(bits) => self.status_fault(DatapathStatus::from_bits(bits)),
                Err(fault) => fault,
            };
            // The COMMIT may have landed though its confirmation did not: look before
            // repeating it (a repeated one finds the staging bank empty and does nothing,
            // but the look is cheaper than a repeat and tells a lost staging bank).
            let st = self.status()?;
            if committed(st) {
                return Ok(Ok(st));
            }
            if !st.staging_valid || attempt >= ATTEMPTS {
                return Ok(Err(fault));
            }
            attempt += 1;
            bump(&mut self.stats.retries);
        }
    }

    fn status_fault(&mut self, st: DatapathStatus) -> LinkFault {
        bump(&mut self.stats.status);
        LinkFault::Status { bits: st.to_bits() }
    }

    /// The decoded `STATUS` register.
    pub fn status(&mut self) -> Result<DatapathStatus, CoreError> {
        Ok(DatapathStatus::from_bits(self.read_reg(Reg::Status)?))
    }

    /// The datapath's counters.
    pub fn counters(&mut self) -> Result<Status, CoreError> {
        Ok(Status {
            out_of_range_codes: self.read_reg(Reg::OutOfRange)?,
            saturated_additions: self.read_reg(Reg::Saturated)?,
            rejected_lines: self.read_reg(Reg::Rejected)?,
            incomplete_frames: self.read_reg(Reg::Incomplete)?,
            frames: self.read_reg(Reg::Frames)?,
            lut_swaps: self.read_reg(Reg::LutSwaps)?,
        })
    }

    /// Pixels the datapath dropped because its input FIFO was full (an FPGA datapath
    /// behind a camera that cannot be stalled; never silent).
    pub fn fifo_overflows(&mut self) -> Result<u32, CoreError> {
        self.read_reg(Reg::FifoOverflow)
    }
}

/// Whether an image's CRC-32 trailer matches its bytes (the datapath's last check, which
/// the host can make too).
fn image_crc_holds(image: &[u8]) -> bool {
    match image.len().checked_sub(4) {
        Some(n) => CRC32.checksum(&image[..n]).to_le_bytes() == image[n..],
        None => false,
    }
}
