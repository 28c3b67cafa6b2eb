//! The host-MCU side of the frame-grabber datapath: writes LUT images and control
//! registers over SPI, generic over any `embedded_hal::spi::SpiDevice`. The same driver
//! runs on the firmware against the real bus and on the host against the FPGA model.
//! The wire format and register map are in [`crate::regs`].

use embedded_hal::spi::{Operation, SpiDevice};

use crate::regs::{control, status, Reg, CMD_LUT_DATA, CMD_READ_REG, CMD_WRITE_REG, DEVICE_ID, MAX_LUT_CHUNK};
use crate::{CoreError, Geometry, Status};

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
            | ((self.active_bank as u32) << status::ACTIVE_BANK_SHIFT)
    }
}

/// The datapath behind an SPI device.
pub struct Datapath<SPI> {
    spi: SPI,
}

impl<SPI: SpiDevice> Datapath<SPI> {
    /// A driver on `spi`; talks to nothing until called.
    pub fn new(spi: SPI) -> Self {
        Datapath { spi }
    }

    /// Gives the bus back.
    pub fn release(self) -> SPI {
        self.spi
    }

    /// The device behind the bus, for a host that also drives its data path (a simulated
    /// datapath receives frames this way; on hardware they come from the camera).
    pub fn device_mut(&mut self) -> &mut SPI {
        &mut self.spi
    }

    /// Reads the ID register and checks it is a dncal datapath.
    pub fn identify(&mut self) -> Result<(), CoreError> {
        match self.read_reg(Reg::Id)? {
            DEVICE_ID => Ok(()),
            id => Err(CoreError::DeviceId { id }),
        }
    }

    /// Writes one register.
    pub fn write_reg(&mut self, reg: Reg, value: u32) -> Result<(), CoreError> {
        let v = value.to_le_bytes();
        self.spi.write(&[CMD_WRITE_REG, reg as u8, v[0], v[1], v[2], v[3]]).map_err(|_| CoreError::Bus)
    }

    /// Reads one register.
    pub fn read_reg(&mut self, reg: Reg) -> Result<u32, CoreError> {
        let mut v = [0u8; 4];
        self.spi
            .transaction(&mut [Operation::Write(&[CMD_READ_REG, reg as u8]), Operation::Read(&mut v)])
            .map_err(|_| CoreError::Bus)?;
        Ok(u32::from_le_bytes(v))
    }

    /// Sets the geometry registers.
    pub fn configure(&mut self, geometry: Geometry) -> Result<(), CoreError> {
        self.write_reg(Reg::Width, geometry.width() as u32)?;
        self.write_reg(Reg::Height, geometry.height() as u32)?;
        self.write_reg(Reg::States, geometry.states() as u32)?;
        self.write_reg(Reg::FirstColumn, geometry.first_column() as u32)
    }

    /// Uploads a LUT device image into the staging bank and commits it: the datapath
    /// validates it and activates it at the next frame boundary. An image the datapath
    /// rejects gives [`CoreError::StagingNotValid`] and leaves the active LUTs in place.
    pub fn upload_lut_image(&mut self, image: &[u8]) -> Result<DatapathStatus, CoreError> {
        self.write_reg(Reg::Control, control::LUT_BEGIN)?;
        for chunk in image.chunks(MAX_LUT_CHUNK) {
            let len = (chunk.len() as u16).to_le_bytes();
            self.spi
                .transaction(&mut [Operation::Write(&[CMD_LUT_DATA, len[0], len[1]]), Operation::Write(chunk)])
                .map_err(|_| CoreError::Bus)?;
        }
        self.write_reg(Reg::Control, control::LUT_COMMIT)?;
        let status = self.status()?;
        if status.upload_failed {
            return Err(CoreError::StagingNotValid);
        }
        Ok(status)
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
