//! The register map and LUT upload of [`dncal_core::regs`], answered over SPI.
//!
//! The core parses each frame ([`parse_frame`]); this module applies it and keeps the
//! device's side of the link: the frames accepted (returned with every response), the
//! hold after a refused frame and the bytes of the open upload. A refused frame (an
//! unknown command, a bad CRC, a wrong length, a chunk out of order, a read without its
//! seven response bytes; the rules are in [`dncal_core::regs`]) changes nothing but the hold
//! and an open upload, which fails, and leaves a read's response idle (0xFF). The model
//! answers it with [`ErrorKind::Other`] to tell a test; a real master hears nothing, and
//! [`crate::faults::FaultyBus`] passes nothing on. The model never panics on bus input.

use dncal_core::driver::DatapathStatus;
use dncal_core::regs::{control, parse_frame, read_response, Frame, Reg, DEVICE_ID, IDLE_BYTE, READ_RESPONSE_LEN};
use dncal_core::{Geometry, StagingState};
use embedded_hal::spi::{ErrorKind, ErrorType, Operation, SpiDevice};

use crate::Fpga;

/// The device's side of the link.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct LinkState {
    /// Frames accepted, modulo 2^16.
    accepted: u16,
    /// A frame was refused: writes and chunks are refused until the next accepted read.
    hold: bool,
    /// Image bytes taken by the upload open on the link, if one is.
    lut_received: Option<u32>,
}

/// Why a frame did not take effect.
enum Refusal {
    /// The frame itself: refused, not counted.
    Frame,
    /// The value it carried: counted, the register kept.
    Value,
}

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
                    upload_open: st == StagingState::Loading,
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
    /// always corrects; the core's driver never clears it); its actions run in the order
    /// `LUT_BEGIN`, `LUT_END`, `LUT_COMMIT`, `CLEAR_SUMS`. Geometry registers take effect
    /// together (a new geometry clears the sums); an invalid value (zero width, too many
    /// states, more than 16 bits) is refused and leaves the register as it was.
    pub fn write_register(&mut self, reg: Reg, value: u32) -> Result<(), ErrorKind> {
        let g = self.geometry;
        let narrow = |v: u32| u16::try_from(v).map_err(|_| ErrorKind::Other);
        let new = match reg {
            Reg::Control => {
                if value & control::LUT_BEGIN != 0 {
                    self.begin_upload();
                    self.link.lut_received = Some(0);
                }
                if value & (control::LUT_END | control::LUT_COMMIT) != 0 {
                    self.link.lut_received = None;
                    if self.banks.staging_state() == StagingState::Loading {
                        // A failure shows in STATUS; the commit below then finds nothing.
                        let _ = self.banks.finish_upload();
                    }
                }
                if value & control::LUT_COMMIT != 0 && self.banks.request_activation().is_ok() {
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

    /// Applies one parsed frame (`None`: unparsable) with the read clocked after it.
    fn apply_frame(&mut self, frame: Option<Frame<'_>>, response: Option<&mut [u8]>) -> Result<(), Refusal> {
        let link = &mut self.link;
        match frame {
            Some(Frame::Read { reg }) => {
                let Some(buf) = response.filter(|b| b.len() == READ_RESPONSE_LEN) else { return Err(Refusal::Frame) };
                link.accepted = link.accepted.wrapping_add(1);
                link.hold = false;
                let count = link.accepted;
                buf.copy_from_slice(&read_response(reg, self.read_register(reg), count));
                Ok(())
            }
            None => Err(Refusal::Frame),
            Some(_) if response.is_some() || link.hold => Err(Refusal::Frame),
            Some(Frame::Write { reg, value }) => {
                link.accepted = link.accepted.wrapping_add(1);
                self.write_register(reg, value).map_err(|_| Refusal::Value)
            }
            Some(Frame::LutData { offset, data }) => {
                if link.lut_received != Some(offset) {
                    return Err(Refusal::Frame);
                }
                link.accepted = link.accepted.wrapping_add(1);
                // At most MAX_LUT_CHUNK bytes (parse_frame checked), so no overflow.
                link.lut_received = Some(offset + data.len() as u32);
                // Bytes the image's checks refuse fail the staging bank (STATUS says so at
                // LUT_END); the rest of the image is taken and discarded.
                let _ = self.banks.upload(data);
                Ok(())
            }
        }
    }
}

impl ErrorType for Fpga {
    type Error = ErrorKind;
}

impl SpiDevice for Fpga {
    fn transaction(&mut self, ops: &mut [Operation<'_, u8>]) -> Result<(), ErrorKind> {
        // The host's bytes of this chip-select assertion, then the read clocked after them.
        let mut mosi = Vec::new();
        let mut response: Option<&mut [u8]> = None;
        let mut well_formed = !ops.is_empty();
        for op in ops.iter_mut() {
            match op {
                Operation::Write(bytes) if response.is_none() => mosi.extend_from_slice(bytes),
                Operation::Read(buf) if response.is_none() => response = Some(buf),
                Operation::DelayNs(_) => {}
                _ => well_formed = false,
            }
        }
        let frame = if well_formed { parse_frame(&mosi) } else { None };
        match self.apply_frame(frame, response.as_deref_mut()) {
            Ok(()) => Ok(()),
            Err(Refusal::Value) => Err(ErrorKind::Other),
            Err(Refusal::Frame) => {
                self.link.hold = true;
                if self.link.lut_received.take().is_some() {
                    self.banks.abort_upload();
                }
                if let Some(buf) = response {
                    buf.fill(IDLE_BYTE);
                }
                Err(ErrorKind::Other)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use dncal_core::regs::{lut_header, parse_read_response, read_request, write_frame, LUT_HEADER_LEN};

    use super::*;
    use crate::Config;

    fn model() -> Fpga {
        Fpga::new(Config::default(), Geometry::new(16, 2, 1, 0).unwrap()).unwrap()
    }

    /// The value and frame count a read returns, or `None` if the response is idle.
    fn read(fpga: &mut Fpga, reg: Reg) -> Option<(u32, u16)> {
        let mut r = [0u8; READ_RESPONSE_LEN];
        let _ = fpga.transaction(&mut [Operation::Write(&read_request(reg)), Operation::Read(&mut r)]);
        parse_read_response(reg, &r)
    }

    fn send(fpga: &mut Fpga, bytes: &[u8]) -> Result<(), ErrorKind> {
        fpga.transaction(&mut [Operation::Write(bytes)])
    }

    #[test]
    fn every_accepted_frame_is_counted_and_a_refused_one_is_not() {
        let mut fpga = model();
        assert_eq!(read(&mut fpga, Reg::Id), Some((DEVICE_ID, 1)));
        send(&mut fpga, &write_frame(Reg::Width, 8)).unwrap();
        let mut corrupted = write_frame(Reg::Width, 9);
        corrupted[3] ^= 0x40;
        assert!(send(&mut fpga, &corrupted).is_err());
        assert!(send(&mut fpga, &write_frame(Reg::Width, 0)).is_err(), "held: refused before its value is looked at");
        assert_eq!(read(&mut fpga, Reg::Width), Some((8, 3)), "the write and both reads");
        assert!(send(&mut fpga, &write_frame(Reg::Width, 0)).is_err(), "a zero width is refused, but counted");
        assert_eq!(read(&mut fpga, Reg::Width), Some((8, 5)));
        let mut corrupted = read_request(Reg::Width);
        corrupted[1] ^= 0x01;
        let mut r = [0u8; READ_RESPONSE_LEN];
        assert!(fpga.transaction(&mut [Operation::Write(&corrupted), Operation::Read(&mut r)]).is_err());
        assert_eq!(r, [IDLE_BYTE; READ_RESPONSE_LEN], "a refused read leaves MISO idle");
    }

    /// The second half of a frame split by a chip-select glitch is a frame of its own on
    /// the wire. Here a chunk's last 7 bytes are a valid write of `WIDTH`: the first half
    /// is refused (it is shorter than its header says) and the hold refuses the second.
    #[test]
    fn the_tail_of_a_split_chunk_is_not_taken_for_a_write() {
        let mut fpga = model();
        fpga.write_register(Reg::Control, control::LUT_BEGIN).unwrap();
        let tail = write_frame(Reg::Width, 3);
        let mut frame = lut_header(0, 20).to_vec();
        frame.extend_from_slice(&[0; 13]);
        frame.extend_from_slice(&tail);
        let (first, second) = frame.split_at(LUT_HEADER_LEN + 13);
        assert!(send(&mut fpga, first).is_err());
        assert!(send(&mut fpga, second).is_err());
        assert_eq!(fpga.geometry().width(), 16);
        assert!(matches!(fpga.banks().staging_state(), StagingState::Failed(_)), "the upload lost a frame");
        assert_eq!(read(&mut fpga, Reg::Width), Some((16, 1)));
        send(&mut fpga, &tail).unwrap();
        assert_eq!(fpga.geometry().width(), 3, "after a read, the same frame is a write");
    }

    #[test]
    fn chunks_must_come_in_order_once_each() {
        let mut fpga = model();
        let chunk = |offset| {
            let mut f = lut_header(offset, 4).to_vec();
            f.extend_from_slice(&[0; 4]);
            f
        };
        assert!(send(&mut fpga, &chunk(0)).is_err(), "no upload open");
        assert!(read(&mut fpga, Reg::Status).is_some());
        fpga.write_register(Reg::Control, control::LUT_BEGIN).unwrap();
        send(&mut fpga, &chunk(0)).unwrap();
        assert!(send(&mut fpga, &chunk(0)).is_err(), "a repeated chunk");
        assert!(matches!(fpga.banks().staging_state(), StagingState::Failed(_)));
        fpga.write_register(Reg::Control, control::LUT_BEGIN).unwrap();
        assert!(read(&mut fpga, Reg::Status).is_some());
        send(&mut fpga, &chunk(0)).unwrap();
        assert!(send(&mut fpga, &chunk(8)).is_err(), "a chunk after a gap");
        assert!(matches!(fpga.banks().staging_state(), StagingState::Failed(_)));
    }
}
