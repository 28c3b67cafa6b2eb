//! Checks of the core against independent references: bit-exact streaming against the
//! float reference ([`crate::model::reference`]) and the FPGA model, the soak, the
//! firmware in QEMU and the fuzz targets. Imports every room but the CLI.

pub mod bench;
pub mod firmware;
#[doc(hidden)]
pub mod fuzzing;
pub mod soak;
pub mod stream_run;
pub mod streaming;
