//! The `dncal` subcommands as library functions: each takes its arguments and returns a
//! [`Report`] (serializable, and rendering its own readable text); `main.rs` only parses,
//! dispatches, prints and sets the exit code.

pub mod adc;
pub mod bench;
pub mod demo;
pub mod diagnose;
pub mod emva;
pub mod firmware;
pub mod fpga;
pub mod kcor;
pub mod linearity;
pub mod lut;
pub mod progress;
pub mod quantization;
pub mod simulate;
pub mod stream;

pub use crate::formats::report::{wrote, Report};
