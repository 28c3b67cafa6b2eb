//! The camera model and its simulation: the sensor, its ADCs and their architectures,
//! calibration sets drawn from it, synthetic lines, measured-looking sets with effects
//! hidden in them, and the float reference of the correction (an f64 model of the LUT,
//! written from the definition, against which the core's integers are checked). Imports
//! `dncal-core`, [`crate::formats`] and [`crate::infra`].

pub mod camera;
pub mod hidden;
pub mod reference;
pub mod sets;
pub mod synth;
