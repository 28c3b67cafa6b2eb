//! Checks of the core against independent references: bit-exact streaming against the
//! float reference ([`crate::model::reference`]) and the FPGA model (`dncal stream`:
//! [`stream_run`]), the soak, the firmware in QEMU (`dncal firmware-check`), the fuzz
//! targets, and `dncal bench` (ratios against references run in the same process).
//! Imports every room but the CLI.

pub mod bench;
pub mod firmware;
#[doc(hidden)]
pub mod fuzzing;
pub mod soak;
pub mod stream_run;
pub mod streaming;
