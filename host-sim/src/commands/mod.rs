//! The `dncal` subcommands as library functions: each takes its arguments and returns a
//! serializable summary; `main.rs` only parses, prints and sets the exit code.

pub mod adc;
pub mod bench;
pub mod demo;
pub mod diagnose;
pub mod fpga;
pub mod kcor;
pub mod linearity;
pub mod lut;
pub mod progress;
pub mod quantization;
pub mod simulate;
pub mod stream;
