//! Characterization and diagnosis: the paper's flattening and its LUTs, the IEEE 1241
//! histogram test and ADC architectures, the K-Cor tables' ADCs, EMVA 1288, pixel-wise
//! linearity, quantization bias, the K-Coronagraph polarimetric model, the paper's claims
//! and `diagnose`. Imports the core, [`crate::formats`], [`crate::model`] and
//! [`crate::infra`].

pub mod adc;
pub mod diagnose;
pub mod emva;
pub mod flatten;
pub mod fpga_size;
pub mod ieee1241;
pub mod kcor;
pub mod linearity;
pub mod lut;
pub mod paper_claims;
pub mod quantization;
pub mod real_adcs;
pub mod width_statistics;
