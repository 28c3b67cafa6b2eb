//! Files in and out: FITS (histogram sets, linearity sets, frames), every LUT format in
//! one home ([`lut`]), the figures (PNG), the reports a command prints, the one door
//! inputs come in by and the all-or-nothing outputs. Imports `dncal-core` and [`crate::infra`] only.

pub mod bayer;
pub mod fits;
pub mod input;
pub mod lut;
pub mod outputs;
pub mod plots;
pub mod report;
pub mod same_file;
