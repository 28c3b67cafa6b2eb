//! Any bytes through the reader; see `dncal_host::checks::fuzzing::fits_histograms`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    dncal_host::checks::fuzzing::fits_histograms(data);
});
