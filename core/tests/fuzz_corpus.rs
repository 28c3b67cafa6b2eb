//! The `lut_image_chunks` fuzz corpus, replayed without libFuzzer or nightly (issue 18):
//! every file of `fuzz/corpus/lut_image_chunks/` and `fuzz/regressions/lut_image_chunks/`
//! goes through `dncal_core::fuzzing::lut_image_chunks`, which panics if an upload panics
//! or activates anything but a valid image.
//!
//! `write_seed_corpus` (ignored) writes the seeds with the core's own encoder:
//! `cargo test -p dncal-core --test fuzz_corpus -- --ignored`.

use std::path::{Path, PathBuf};

use dncal_core::fuzzing::{lut_image_chunks, lut_image_input, LUT_IMAGE_PREFIX};
use dncal_core::{encode_image, image_len, LutSet, Mvd1024eLuts};

fn target_dirs() -> [PathBuf; 2] {
    let fuzz = Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz");
    [fuzz.join("corpus/lut_image_chunks"), fuzz.join("regressions/lut_image_chunks")]
}

#[test]
fn lut_image_corpus_activates_only_valid_images() {
    let mut inputs: Vec<PathBuf> = target_dirs()
        .iter()
        .filter_map(|d| std::fs::read_dir(d).ok())
        .flatten()
        .map(|e| e.unwrap().path())
        .collect();
    inputs.sort();
    assert!(inputs.len() >= 4, "the seeds are missing");
    for input in inputs {
        let bytes = std::fs::read(&input).unwrap();
        // The camera's banks are 128 KiB; the default test thread's stack is too small for
        // two sets of them in a debug build.
        let run = std::thread::Builder::new().stack_size(16 << 20).spawn(move || lut_image_chunks(&bytes)).unwrap();
        assert!(run.join().is_ok(), "{}", input.display());
    }
}

#[test]
#[ignore = "writes fuzz/corpus; run by hand to regenerate the seeds"]
fn write_seed_corpus() {
    let dir = &target_dirs()[0];
    std::fs::create_dir_all(dir).unwrap();
    let small = LutSet::<2, 16>::from_bits(&[core::array::from_fn(|k| 2048 * k as u32 + 1024), core::array::from_fn(|k| 2000 * k as u32)]).unwrap();
    let mut image = vec![0u8; image_len::<2, 16>()];
    encode_image(&small, &mut image).unwrap();
    let mut input = vec![0u8; LUT_IMAGE_PREFIX + image_len::<4, 4096>()];
    for (name, log2, seed) in [("small-bytes", 0, 1), ("small-chunks-8", 3, 77), ("small-chunks-128", 7, 4242)] {
        let n = lut_image_input(false, log2, seed, &image, &mut input).unwrap();
        std::fs::write(dir.join(format!("seed-{name}")), &input[..n]).unwrap();
    }
    // A one-bit error in the last entry: refused by the CRC.
    image[16 + 4 * 31] ^= 1;
    let n = lut_image_input(false, 2, 9, &image, &mut input).unwrap();
    std::fs::write(dir.join("seed-small-bad-crc"), &input[..n]).unwrap();
    let camera = Mvd1024eLuts::ideal();
    let mut image = vec![0u8; image_len::<4, 4096>()];
    encode_image(&camera, &mut image).unwrap();
    let n = lut_image_input(true, 7, 1234, &image, &mut input).unwrap();
    std::fs::write(dir.join("seed-camera-ideal"), &input[..n]).unwrap();
}
