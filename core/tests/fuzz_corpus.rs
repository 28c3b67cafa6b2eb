//! The `lut_image_chunks` fuzz corpus, replayed without libFuzzer or nightly (issue 18):
//! every file of `fuzz/corpus/lut_image_chunks/` and `fuzz/regressions/lut_image_chunks/`
//! goes through `dncal_core::fuzzing::lut_image_chunks`, which panics if an upload panics
//! or activates anything but a valid image.
//!
//! The seeds are the core's own encoder's (checked by a test here;
//! `DNCAL_WRITE_SEEDS=1 cargo test -p dncal-core --test fuzz_corpus` rewrites them).

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

/// The seeds are written by the core's encoder into a temporary folder; each must be
/// a committed seed, byte for byte (the generator is seeded), and replay cleanly. With
/// `DNCAL_WRITE_SEEDS=1` they are written into `fuzz/corpus/` instead.
#[test]
fn the_seed_writer_makes_the_committed_seeds() {
    let temp = std::env::temp_dir().join(format!("dncal-core-seeds-{}", std::process::id()));
    let regenerate = std::env::var_os("DNCAL_WRITE_SEEDS").is_some_and(|v| v == "1");
    let dir = if regenerate { target_dirs()[0].clone() } else { temp.clone() };
    write_seeds(&dir);
    let mut seeds = 0;
    for seed in std::fs::read_dir(&dir).unwrap() {
        let seed = seed.unwrap().path();
        let bytes = std::fs::read(&seed).unwrap();
        let committed = target_dirs()[0].join(seed.file_name().unwrap());
        assert_eq!(std::fs::read(&committed).ok().as_deref(), Some(&bytes[..]), "{} differs from the committed seed (DNCAL_WRITE_SEEDS=1 rewrites it)", committed.display());
        let run = std::thread::Builder::new().stack_size(16 << 20).spawn(move || lut_image_chunks(&bytes)).unwrap();
        assert!(run.join().is_ok(), "{}", seed.display());
        seeds += 1;
    }
    if !regenerate {
        std::fs::remove_dir_all(&temp).unwrap();
    }
    assert_eq!(seeds, 5);
}

fn write_seeds(dir: &Path) {
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
