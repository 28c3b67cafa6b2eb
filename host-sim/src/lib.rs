//! # dncal-host: dncal on the host
//!
//! Everything that needs `std`: the camera model, the float reference and the streaming
//! check, the FITS and EMVA 1288 formats, the paper's flattening and characterizations,
//! figures, the firmware-versus-host run, and the `dncal` command's subcommands. All
//! correction arithmetic comes from `dncal-core`.

pub mod analyses;
pub mod checks;
pub mod commands;
pub mod error;
pub mod formats;
pub mod infra;
pub mod model;

pub use error::{HostError, Origin, Subject};
