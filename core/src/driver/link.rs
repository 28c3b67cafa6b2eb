//! The driver's link layer: frames out, checked responses back.
//!
//! The datapath counts the frames it accepts and returns the count, modulo 2^16, with
//! every response ([`crate::regs`]). The driver counts the frames it sends; a response
//! whose count differs says that a frame since the last check was lost, refused or
//! delivered twice. Every exchange ends with such a check, so a count known at its start
//! covers all of its frames. A response that fails its CRC-8 leaves the count unknown (the
//! request may or may not have been counted); the next response sets it again.

use embedded_hal::spi::{Operation, SpiDevice};

use super::{bump, Datapath};
use crate::error::{LinkFault, LinkStep};
use crate::regs::{parse_read_response, read_request, write_frame, Reg, IDLE_BYTE, READ_RESPONSE_LEN};
use crate::CoreError;

/// An exchange's outcome: the outer error is the SPI peripheral's (not repeated), the
/// inner one a failed check (the step is repeated).
pub(super) type Checked<T> = Result<Result<T, LinkFault>, CoreError>;

impl<SPI: SpiDevice> Datapath<SPI> {
    /// Sends one frame (one chip-select assertion).
    pub(super) fn send(&mut self, ops: &mut [Operation<'_, u8>]) -> Result<(), CoreError> {
        self.expected_count = self.expected_count.map(|c| c.wrapping_add(1));
        self.spi.transaction(ops).map_err(|_| {
            self.expected_count = None;
            CoreError::Bus
        })
    }

    /// Reads `reg` once. Passes if the response's CRC-8 holds and the datapath's count is
    /// the one expected; with no count known, the response's becomes it.
    pub(super) fn read_checked(&mut self, reg: Reg) -> Checked<u32> {
        let mut response = [IDLE_BYTE; READ_RESPONSE_LEN];
        self.send(&mut [Operation::Write(&read_request(reg)), Operation::Read(&mut response)])?;
        let Some((value, count)) = parse_read_response(reg, &response) else {
            self.expected_count = None;
            bump(&mut self.stats.response_crc);
            return Ok(Err(LinkFault::ResponseCrc));
        };
        match self.expected_count.replace(count) {
            Some(expected) if expected != count => {
                bump(&mut self.stats.frame_count);
                Ok(Err(LinkFault::FrameCount { expected, got: count }))
            }
            _ => Ok(Ok(value)),
        }
    }

    /// Writes `value` to `reg`, then reads `check`: passes, with `check`'s value, if the
    /// datapath counted exactly the write and the read. With no count known it first reads
    /// `STATUS` to learn it (else a lost write could not be told from a counted one).
    pub(super) fn write_checked(&mut self, reg: Reg, value: u32, check: Reg) -> Checked<u32> {
        if self.expected_count.is_none() {
            if let Err(fault) = self.read_checked(Reg::Status)? {
                return Ok(Err(fault));
            }
        }
        self.send(&mut [Operation::Write(&write_frame(reg, value))])?;
        self.read_checked(check)
    }

    /// Runs `exchange` until its checks pass, at most `attempts` times.
    pub(super) fn retried<T>(&mut self, step: LinkStep, attempts: u8, mut exchange: impl FnMut(&mut Self) -> Checked<T>) -> Result<T, CoreError> {
        let mut attempt = 1;
        loop {
            match exchange(self)? {
                Ok(value) => return Ok(value),
                Err(last) if attempt >= attempts => {
                    bump(&mut self.stats.give_ups);
                    return Err(CoreError::Link { step, attempts: attempt, last });
                }
                Err(_) => {
                    attempt += 1;
                    bump(&mut self.stats.retries);
                }
            }
        }
    }
}
