//! # dncal-core: the real-time DN-error correction core
//!
//! A camera such as the PhotonFocus MV-D1024E of the K-Coronagraph digitizes with
//! four pipelined 12-bit ADCs; sensor column `c` goes through ADC `c mod 4`. Each ADC
//! has *DN error*: its code widths differ from one DN (de Wijn 2018, section 4; the
//! K-Coronagraph's deployed tables show 2.2-4.7% rms per code, `docs/kcor-luts.md`). The correction is a lookup table per ADC, the cumulative sum of the
//! normalized code histogram, held as 23-bit integers (12 integer + 11 fractional bits)
//! so that 2^9 = 512 corrected frames sum into one `u32` without overflow.
//!
//! This crate is the single source of arithmetic truth for that correction: the rounding
//! rule of a LUT entry ([`lut`]), the per-modulation-state sums ([`accumulate`]), the
//! histogram capture that feeds calibration ([`histogram`]), the LUT device image and
//! its validation ([`image`]), the double-buffered LUT banks ([`banks`]), the on-device
//! noise check ([`noise`]) and the SPI driver of the frame-grabber datapath ([`driver`]).
//! It is `#![no_std]`, allocates nothing and never panics on bad input: every
//! constructor validates and returns a [`CoreError`].
//!
//! ```
//! use dncal_core::{Corrector, Geometry, LutBanks, Mvd1024eLuts};
//! let geometry = Geometry::new(8, 2, 4, 0).unwrap();
//! let mut sums = [0u32; 8 * 2 * 4];
//! let mut banks = LutBanks::new(Mvd1024eLuts::ideal());
//! let mut corrector = Corrector::new(&mut banks, geometry, &mut sums).unwrap();
//! corrector.begin_frame(0).unwrap();
//! corrector.accumulate_line(0, &[0, 1, 2, 3, 4, 5, 6, 7]).unwrap();
//! corrector.accumulate_line(1, &[7, 6, 5, 4, 3, 2, 1, 0]).unwrap();
//! corrector.end_frame().unwrap();
//! // An ideal ADC maps code k to (k + 1/2) DN, in units of 2^-11 DN.
//! assert_eq!(corrector.sums().state(0).unwrap()[1], (1 * 2 + 1) << 10);
//! ```
#![no_std]
// Free of `unsafe` everywhere but the host's gather loop (feature `simd`, x86-64 only).
#![cfg_attr(not(all(feature = "simd", target_arch = "x86_64")), forbid(unsafe_code))]
#![cfg_attr(all(feature = "simd", target_arch = "x86_64"), deny(unsafe_code))]
#![warn(missing_docs)]

pub mod accumulate;
pub mod adc;
pub mod banks;
pub mod driver;
pub mod error;
#[doc(hidden)]
pub mod fuzzing;
pub mod histogram;
pub mod image;
pub mod lut;
pub mod noise;
pub mod regs;
#[cfg(all(feature = "simd", target_arch = "x86_64"))]
pub mod simd;
pub mod stream;

pub use accumulate::{Corrector, FrameCount, Geometry, LineReport, Status, SealedSums, SumImages, Suspended, EXACT_FRAMES, MAX_STATES};
pub use adc::{adc_of_column, AdcMap, Code};
pub use banks::{LutBanks, StagingState};
pub use error::{CoreError, LinkFault, LinkStep};
pub use histogram::{HistogramSet, Roi};
pub use image::{encode_image, image_len, ImageLoader};
pub use lut::{frac_bits, half_unit_dn, units_per_dn, units_to_dn, weight_nearest, LutEntry, LutSet, Weight, LUT_ENTRY_BITS, LUT_ENTRY_LIMIT, WEIGHT_FRAC_BITS};
pub use noise::{NoiseEstimator, NoiseReport};
pub use stream::StreamHeader;

/// The LUT set of the paper's camera: 4 ADCs, 12-bit codes.
pub type Mvd1024eLuts = LutSet<4, 4096>;
