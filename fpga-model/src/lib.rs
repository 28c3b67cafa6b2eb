//! # dncal-fpga-model: the frame grabber's correction datapath, cycle by cycle
//!
//! In the instrument the frame grabber sums frames at the camera's full rate while the
//! microcontroller configures it over SPI. This crate models that datapath at the level
//! of clock cycles so that it can be sized and checked before anyone writes HDL:
//!
//! - a pixel clock delivering `taps` pixels per cycle (1 to 8) while line-valid is high,
//!   with horizontal and vertical blanking, as a Camera Link frame grabber sees it;
//! - an input FIFO of configurable depth; a pixel that finds it full is dropped and
//!   counted (`FIFO_OVERFLOW`), never silently;
//! - the per-ADC LUT lookup in block RAM with a one-cycle read latency;
//! - the read-modify-write of the sum image in external memory with a configurable
//!   latency and bandwidth (a pixel costs two words: the read of its sum and the write);
//! - the register map and the LUT upload of [`dncal_core::regs`], answered as an
//!   [`embedded_hal::spi::SpiDevice`] so that the core's own driver configures it;
//! - and, as test equipment, a bus that injects faults between the two ([`faults`]).
//!
//! The arithmetic is the core's, not a copy: every lookup is
//! [`dncal_core::accumulate::lookup`], every addition
//! [`dncal_core::accumulate::saturating_sum`], every LUT image is validated by the core's
//! [`dncal_core::LutBanks`]. Timing and data are modelled separately: a pixel's sum is
//! updated when its write-back completes, with the table it was looked up in (each pixel
//! carries the bank it entered with, so a LUT swap at a frame boundary never touches
//! pixels of the previous frame still in the pipeline).

pub mod config;
pub mod datapath;
pub mod error;
pub mod faults;
pub mod sizing;
pub mod spi;

pub use config::Config;
pub use datapath::{Fpga, FrameTiming, Stats};
pub use error::FpgaError;

