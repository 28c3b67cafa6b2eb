//! # dncal-host: dncal on the host
//!
//! Everything that needs `std`: synthetic camera data, the firmware-versus-host run, and
//! (in later issues) the camera model, the float reference, characterization and the
//! `dncal` command's subcommands. All correction arithmetic comes from `dncal-core`.

pub mod camera;
pub mod commands;
pub mod dims;
pub mod emva;
pub mod error;
pub mod firmware;
pub mod fits;
pub mod flatten;
pub mod plots;
pub mod reference;
pub mod streaming;
pub mod synth;

pub use error::HostError;
