//! A set diagnosed by blocks of rows from its file against the same set held whole.

use super::*;
use crate::formats::fits::{open_linearity_rows, read_linearity_as, write_linearity};
use crate::model::hidden::{linearity_set, pick, Plant};
use rand::SeedableRng;

/// A 256 x 256 set with two planted effects and some masked pixels, written to a file.
fn written(seed: u64) -> (tempfile::TempDir, std::path::PathBuf) {
    let mut gen = rand::rngs::StdRng::seed_from_u64(seed);
    let hidden = pick(&mut gen, 4, 2);
    let mut set = linearity_set(&Plant { width: 256, height: 256, ..Plant::default() }, &hidden, seed + 40);
    set.mask = Some((0..256 * 256).map(|p| u8::from(p % 997 == 3)).collect());
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("set.fits");
    write_linearity(&path, &set).unwrap();
    (dir, path)
}

/// The whole-array path (the set held as f32) and the block path give the same report,
/// byte for byte, at block sizes that divide the rows and that do not, and at the
/// default block; the findings are the planted ones' (not an empty report twice).
#[test]
fn blocks_of_rows_give_the_diagnosis_of_the_held_set_number_for_number() {
    let (_dir, path) = written(5);
    let held = diagnose_linearity(&read_linearity_as::<f32>(&path).unwrap(), 0.01).unwrap();
    assert!(!held.findings.is_empty(), "nothing found: a comparison of two empty reports");
    let want = serde_json::to_string(&held).unwrap();
    let rows = open_linearity_rows(&path).unwrap().expect("an uncompressed float set is read by rows").check::<f32>().unwrap();
    for (block, used) in [(Some(1), 1), (Some(7), 7), (Some(64), 64), (Some(1000), 256), (None, 99)] {
        let mut got = diagnose_linearity_rows(&rows, block, false, 0.01).unwrap();
        // (Blocks of 8 MiB by default: 256 columns x 41 levels x 2 cubes x 4 bytes a row.)
        assert_eq!(got.block_rows.take(), Some(used), "blocks of {block:?} rows");
        assert_eq!(serde_json::to_string(&got).unwrap(), want, "blocks of {block:?} rows");
    }
}

/// The per-pixel records spilled to temporary files give the same report, byte for
/// byte, with the set held and with the set read by rows (blocks smaller than a block of
/// records and larger).
#[test]
fn spilled_records_give_the_diagnosis_of_held_ones_number_for_number() {
    let (_dir, path) = written(5);
    let set = read_linearity_as::<f32>(&path).unwrap();
    let held = diagnose_linearity(&set, 0.01).unwrap();
    assert!(!held.findings.is_empty(), "nothing found: a comparison of two empty reports");
    let want = serde_json::to_string(&held).unwrap();
    let mut spilled = diagnose_linearity_spilled(&set, 0.01).unwrap();
    assert!(std::mem::take(&mut spilled.records_spilled));
    assert_eq!(serde_json::to_string(&spilled).unwrap(), want);
    let rows = open_linearity_rows(&path).unwrap().unwrap().check::<f32>().unwrap();
    for block in [Some(3), None] {
        let mut got = diagnose_linearity_rows(&rows, block, true, 0.01).unwrap();
        assert!(got.block_rows.take().is_some() && std::mem::take(&mut got.records_spilled));
        assert_eq!(serde_json::to_string(&got).unwrap(), want, "blocks of {block:?} rows");
    }
}

/// A file cut after it was opened (and checked) fails the diagnosis with the read's
/// error, not with a report of NaN pixels.
#[test]
fn a_file_cut_while_it_is_diagnosed_is_an_error() {
    let (_dir, path) = written(6);
    let rows = open_linearity_rows(&path).unwrap().unwrap().check::<f32>().unwrap();
    let len = std::fs::metadata(&path).unwrap().len();
    std::fs::OpenOptions::new().write(true).open(&path).unwrap().set_len(len / 2).unwrap();
    match diagnose_linearity_rows(&rows, Some(16), false, 0.01) {
        Err(DiagnoseError::Read { message }) => assert!(message.starts_with("reading rows ") && message.contains("of the set"), "{message}"),
        other => panic!("{other:?}"),
    }
}

/// A cube large enough that its checksum is verified as it is read (16 MiB and more)
/// and damaged in its data: refused by rows as by the whole read, word for word.
#[test]
fn a_damaged_large_cube_fails_its_checksum_by_rows_too() {
    let (_dir, path) = written(7);
    let mut bytes = std::fs::read(&path).unwrap();
    let at = bytes.len() / 3;
    bytes[at] ^= 0x10;
    std::fs::write(&path, &bytes).unwrap();
    let whole = read_linearity_as::<f32>(&path).unwrap_err().to_string();
    assert!(whole.contains("fails its checksum"), "{whole}");
    let by_rows = open_linearity_rows(&path).unwrap().expect("read by rows").check::<f32>().unwrap_err().to_string();
    assert_eq!(by_rows, whole);
}
