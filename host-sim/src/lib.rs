//! # dncal-host: dncal on the host
//!
//! Everything that needs `std`: the camera model, the float reference and the streaming
//! check, the FITS and EMVA 1288 formats, the paper's flattening and characterizations,
//! figures, the firmware-versus-host run, and the `dncal` command's subcommands. All
//! correction arithmetic comes from `dncal-core`.

pub mod budget;
pub mod camera;
pub mod commands;
pub mod diagnose;
pub mod dims;
pub mod emva;
pub mod error;
pub mod firmware;
pub mod fits;
#[doc(hidden)]
pub mod fuzzing;
pub mod hidden;
pub mod ieee1241;
pub mod input;
pub mod flatten;
pub mod kcor;
pub mod kcor_tables;
pub mod linearity;
pub mod outputs;
pub mod paper_claims;
pub mod plots;
pub mod quantization;
pub mod parallel;
pub mod real_adcs;
pub mod reference;
pub mod roi;
pub mod select;
pub mod soak;
pub mod stats;
pub mod streaming;
pub mod synth;

pub use error::HostError;
