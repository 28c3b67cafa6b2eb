//! Any bytes, in any chunks, into the LUT banks; see `dncal_core::fuzzing`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| dncal_core::fuzzing::lut_image_chunks(data));
