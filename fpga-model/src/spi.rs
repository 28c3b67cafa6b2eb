//! The register map and LUT upload of [`dncal_core::regs`], answered over SPI.
//!
//! Malformed transactions (an unknown command, a short header, a chunk longer than
//! [`MAX_LUT_CHUNK`], a read without its read buffer) are refused with
//! [`ErrorKind::Other`] and change nothing; the model never panics on bus input.

use dncal_core::driver::DatapathStatus;
use dncal_core::regs::{control, Reg, CMD_LUT_DATA, CMD_READ_REG, CMD_WRITE_REG, DEVICE_ID, MAX_LUT_CHUNK};
use dncal_core::{Geometry, StagingState};
use embedded_hal::spi::{ErrorKind, ErrorType, Operation, SpiDevice};

use crate::Fpga;

impl Fpga {
    /// The value a register read returns.
    pub fn read_register(&self, reg: Reg) -> u32 {
        let g = self.geometry;
        let s = &self.stats;
        match reg {
            Reg::Id => DEVICE_ID,
            Reg::Control => 0,
            Reg::Status => {
                let st = self.banks.staging_state();
                DatapathStatus {
                    staging_valid: st == StagingState::Valid,
                    activation_pending: self.banks.activation_pending(),
                    frame_open: self.frame_open.is_some(),
                    upload_failed: matches!(st, StagingState::Failed(_)),
                    active_bank: self.banks.active_index() as u8,
                }
                .to_bits()
            }
            Reg::Width => u32::from(g.width()),
            Reg::Height => u32::from(g.height()),
            Reg::States => u32::from(g.states()),
            Reg::FirstColumn => u32::from(g.first_column()),
            Reg::OutOfRange => s.out_of_range,
            Reg::Saturated => s.saturated,
            Reg::Rejected => s.rejected_lines,
            Reg::Frames => s.frames,
            Reg::LutSwaps => s.lut_swaps,
            Reg::Incomplete => s.incomplete_frames,
            Reg::FifoOverflow => s.fifo_overflows,
        }
    }

    /// A register write. `CONTROL.ENABLE` is accepted and has no effect (the model
    /// always corrects; the core's driver never clears it). Geometry registers take effect together (a new geometry clears
    /// the sums); an invalid value (zero width, too many states, more than 16 bits) is
    /// refused and leaves the register as it was.
    pub fn write_register(&mut self, reg: Reg, value: u32) -> Result<(), ErrorKind> {
        let g = self.geometry;
        let narrow = |v: u32| u16::try_from(v).map_err(|_| ErrorKind::Other);
        let new = match reg {
            Reg::Control => {
                if value & control::LUT_BEGIN != 0 {
                    self.begin_upload();
                }
                if value & control::LUT_COMMIT != 0 && self.banks.finish_upload().is_ok() && self.banks.request_activation().is_ok() {
                    self.activation_requested();
                }
                if value & control::CLEAR_SUMS != 0 {
                    self.clear_sums();
                }
                return Ok(());
            }
            Reg::Width => Geometry::new(narrow(value)?, g.height(), g.states(), g.first_column()),
            Reg::Height => Geometry::new(g.width(), narrow(value)?, g.states(), g.first_column()),
            Reg::States => Geometry::new(g.width(), g.height(), u8::try_from(value).map_err(|_| ErrorKind::Other)?, g.first_column()),
            Reg::FirstColumn => Geometry::new(g.width(), g.height(), g.states(), narrow(value)?),
            _ => return Err(ErrorKind::Other),
        };
        let new = new.map_err(|_| ErrorKind::Other)?;
        if new != g {
            self.set_geometry(new).map_err(|_| ErrorKind::Other)?;
        }
        Ok(())
    }
}

impl ErrorType for Fpga {
    type Error = ErrorKind;
}

impl SpiDevice for Fpga {
    fn transaction(&mut self, ops: &mut [Operation<'_, u8>]) -> Result<(), ErrorKind> {
        let Some(Operation::Write(head)) = ops.first() else { return Err(ErrorKind::Other) };
        let head: Vec<u8> = head.to_vec();
        match (head.first().copied(), head.len()) {
            (Some(CMD_WRITE_REG), 6) => {
                let reg = Reg::from_addr(head[1]).ok_or(ErrorKind::Other)?;
                self.write_register(reg, u32::from_le_bytes([head[2], head[3], head[4], head[5]]))
            }
            (Some(CMD_READ_REG), 2) => {
                let reg = Reg::from_addr(head[1]).ok_or(ErrorKind::Other)?;
                let value = self.read_register(reg);
                match ops.get_mut(1) {
                    Some(Operation::Read(buf)) if buf.len() == 4 => {
                        buf.copy_from_slice(&value.to_le_bytes());
                        Ok(())
                    }
                    _ => Err(ErrorKind::Other),
                }
            }
            (Some(CMD_LUT_DATA), 3) => {
                let len = u16::from_le_bytes([head[1], head[2]]) as usize;
                match ops.get(1) {
                    Some(Operation::Write(chunk)) if chunk.len() == len && len <= MAX_LUT_CHUNK => {
                        // A chunk the staging parser refuses marks the upload failed; the
                        // commit then refuses it too (the core's rule).
                        let _ = self.banks.upload(chunk);
                        Ok(())
                    }
                    _ => Err(ErrorKind::Other),
                }
            }
            _ => Err(ErrorKind::Other),
        }
    }
}
