//! Any bytes through the reader; see `dncal_host::checks::fuzzing::camera_toml`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    dncal_host::checks::fuzzing::camera_toml(data);
});
