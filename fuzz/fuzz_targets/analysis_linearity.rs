//! Any bytes through the reader and, where accepted, the analyses and their figures (issue
//! 43); see `dncal_host::checks::fuzzing::analysis_linearity`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    dncal_host::checks::fuzzing::analysis_linearity(data);
});
