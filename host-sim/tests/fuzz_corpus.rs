//! The fuzz corpus, replayed without libFuzzer or nightly (issue 18): every file of
//! `fuzz/corpus/<target>/` and `fuzz/regressions/<target>/` goes through the function the
//! fuzz target calls (`dncal_host::checks::fuzzing`), which panics if a reader panics or an
//! invariant breaks. The regressions are the inputs that once crashed a target.
//!
//! The seeds are written by the project's own writers (checked by a test here;
//! `DNCAL_WRITE_SEEDS=1 cargo test -p dncal-host --test fuzz_corpus` rewrites them).

use std::path::{Path, PathBuf};

use dncal_host::model::camera::CameraConfig;
use dncal_host::formats::fits::{write_histograms, write_linearity, write_lut, AdcHistograms, LinearitySet, LutTables};
use dncal_host::checks::fuzzing::{self, EMVA_FILE_SEPARATOR};

fn fuzz_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz")
}

/// The `fits_linearity` regression input `name`.
fn linearity_regression(name: &str) -> PathBuf {
    fuzz_dir().join("regressions/fits_linearity").join(name)
}

/// The linearity reader's refusal of the `fits_linearity` regression input `name`.
fn linearity_refusal(name: &str) -> String {
    dncal_host::formats::fits::read_linearity(&linearity_regression(name)).unwrap_err().to_string()
}

/// The committed linearity seed without a mask, and the byte where its REFERENCE table's
/// header starts (the tests change one of its cards).
fn seed_and_table() -> (Vec<u8>, usize) {
    let seed = std::fs::read(fuzz_dir().join("corpus/fits_linearity/seed-no-mask.fits")).unwrap();
    let table = seed.windows(19).position(|w| w == b"XTENSION= 'BINTABLE").unwrap();
    (seed, table)
}

/// Runs `entry` on every input of `target`; returns how many there were.
fn replay(target: &str, entry: Entry) -> usize {
    replay_of(&[target], entry).0
}

/// Runs `entry` on every input of each of `targets`; returns how many there were and
/// how many `entry` accepted.
fn replay_of(targets: &[&str], entry: Entry) -> (usize, usize) {
    let mut inputs = Vec::new();
    for kind in ["corpus", "regressions"] {
        for target in targets {
            let Ok(dir) = std::fs::read_dir(fuzz_dir().join(kind).join(target)) else { continue };
            inputs.extend(dir.map(|e| e.unwrap().path()).filter(|p| p.is_file()));
        }
    }
    inputs.sort();
    for input in &inputs {
        let bytes = std::fs::read(input).unwrap();
        if let Err(panic) = std::panic::catch_unwind(|| entry(&bytes)) {
            let message = panic.downcast_ref::<String>().cloned().or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()));
            panic!("{}: {}", input.display(), message.unwrap_or_default());
        }
    }
    let accepted = inputs.iter().filter(|p| entry(&std::fs::read(p).unwrap())).count();
    (inputs.len(), accepted)
}

/// The analysis targets (issue 43) read what their readers' targets read: those seeds and
/// regressions, and their own regressions. The seeds are valid files, so each target
/// also runs its analyses on some of them.
#[test]
fn analysis_corpora_never_panic_nor_print_a_non_finite_result() {
    for (target, reader, entry) in [
        ("analysis_linearity", "fits_linearity", fuzzing::analysis_linearity as Entry),
        ("analysis_histograms", "fits_histograms", fuzzing::analysis_histograms),
        ("analysis_lut", "fits_lut", fuzzing::analysis_lut),
    ] {
        let (inputs, accepted) = replay_of(&[target, reader], entry);
        assert!(inputs >= 3 && accepted >= 2, "{target}: {accepted} of {inputs} inputs accepted");
    }
}

#[test]
fn a_report_showing_a_non_finite_number_is_found() {
    assert_eq!(fuzzing::non_finite_word("max RMS: raw 1.1e-2, standard NaN, pixel-wise 2e-3"), Some("NaN".into()));
    assert_eq!(fuzzing::non_finite_word("0.000e0 B_sun with the LUT: infx less"), Some("infx".into()));
    assert_eq!(fuzzing::non_finite_word("gain (-inf)"), Some("-inf".into()));
    assert_eq!(fuzzing::non_finite_word("inflates to 5.8x; information, infinite loops, 12%"), None);
}

#[test]
fn fits_histograms_corpus_never_panics() {
    assert!(replay("fits_histograms", fuzzing::fits_histograms) >= 4);
}

#[test]
fn fits_linearity_corpus_never_panics() {
    assert!(replay("fits_linearity", fuzzing::fits_linearity) >= 2);
}

#[test]
fn fits_lut_corpus_never_panics() {
    assert!(replay("fits_lut", fuzzing::fits_lut) >= 3);
}

#[test]
fn emva_descriptor_corpus_never_panics() {
    assert!(replay("emva_descriptor", fuzzing::emva_descriptor) >= 2);
}

#[test]
fn camera_toml_corpus_never_panics() {
    assert!(replay("camera_toml", fuzzing::camera_toml) >= 3);
}

/// A grayscale PNG of `codes`, row-major, of `depth` bits.
fn png(width: u32, height: u32, codes: &[u16], depth: png::BitDepth) -> Vec<u8> {
    let mut out = Vec::new();
    let mut encoder = png::Encoder::new(std::io::Cursor::new(&mut out), width, height);
    encoder.set_color(png::ColorType::Grayscale);
    encoder.set_depth(depth);
    let bytes: Vec<u8> = match depth {
        png::BitDepth::Sixteen => codes.iter().flat_map(|c| c.to_be_bytes()).collect(),
        _ => codes.iter().map(|&c| c as u8).collect(),
    };
    let mut writer = encoder.write_header().unwrap();
    writer.write_image_data(&bytes).unwrap();
    writer.finish().unwrap();
    out
}

/// The seeds are written by the project's writers into a temporary folder; each must be
/// accepted by its target's reader and be in the committed corpus under its name. With
/// `DNCAL_WRITE_SEEDS=1` they are written into `fuzz/corpus/` instead (to regenerate them
/// after a format change).
#[test]
fn the_seed_writers_make_accepted_seeds_that_are_committed() {
    let temp = tempfile::tempdir().unwrap();
    let regenerate = std::env::var_os("DNCAL_WRITE_SEEDS").is_some_and(|v| v == "1");
    let corpus = if regenerate { fuzz_dir().join("corpus") } else { temp.path().to_path_buf() };
    write_seeds(&corpus);
    // Seeds the readers refuse would leave the fuzzer at the door.
    let mut seeds = 0;
    for (target, entry) in TARGETS {
        for seed in std::fs::read_dir(corpus.join(target)).unwrap() {
            let seed = seed.unwrap().path();
            assert!(entry(&std::fs::read(&seed).unwrap()), "{} is refused", seed.display());
            let committed = fuzz_dir().join("corpus").join(target).join(seed.file_name().unwrap());
            assert!(committed.is_file(), "{} is not committed (DNCAL_WRITE_SEEDS=1 writes it)", committed.display());
            seeds += 1;
        }
    }
    assert!(seeds >= 15, "{seeds} seeds");
}

/// The seed corpus under `corpus/<target>/`, from the project's writers (and the
/// astropy-written FITS fixtures).
fn write_seeds(corpus: &Path) {
    let dir = |t: &str| {
        let d = corpus.join(t);
        std::fs::create_dir_all(&d).unwrap();
        d
    };
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures");

    let h = dir("fits_histograms");
    write_histograms(&h.join("seed-2adc-4bit.fits"), &AdcHistograms { bit_depth: 4, counts: vec![(0..16).collect(), vec![7; 16]] }).unwrap();
    write_histograms(&h.join("seed-4adc-1bit.fits"), &AdcHistograms { bit_depth: 1, counts: vec![vec![1 << 60, 3]; 4] }).unwrap();
    for f in ["histograms_int32.fits", "histograms_uint16.fits", "histograms_uint64.fits"] {
        std::fs::copy(fixtures.join(f), h.join(format!("astropy-{f}"))).unwrap();
    }

    let l = dir("fits_linearity");
    let (width, height, levels) = (4, 2, 3);
    let n = width * height * levels;
    let set = LinearitySet {
        bit_depth: 12,
        n_adc: 4,
        n_frames: 16,
        width,
        height,
        levels,
        mean: (0..n).map(|i| 100.0 + 10.5 * i as f64).collect(),
        std: (0..n).map(|i| 1.0 + 0.25 * i as f64).collect(),
        voltage: vec![0.0, 0.5, 1.0],
        mask: Some(vec![0, 1, 0, 0, 0, 0, 1, 0]),
        keys: Default::default(),
    };
    write_linearity(&l.join("seed-with-mask.fits"), &set).unwrap();
    write_linearity(&l.join("seed-no-mask.fits"), &LinearitySet { mask: None, ..set }).unwrap();
    std::fs::copy(fixtures.join("linearity.fits"), l.join("astropy-linearity.fits")).unwrap();

    let t = dir("fits_lut");
    let ideal = |codes: u32| (0..codes).map(|k| (k << 11) | 1 << 10).collect::<Vec<u32>>();
    // 8 bits: the smallest depth the core (and so `lut inspect`) is built for.
    let lut = LutTables { frac_bits: 11, tables: vec![ideal(256), ideal(256)], weights: None, kcor_bits: None };
    write_lut(&t.join("seed-2adc-8bit.fits"), &lut).unwrap();
    let with = LutTables { weights: Some(vec![vec![1 << 24; 256]; 2]), kcor_bits: Some(23), ..lut };
    write_lut(&t.join("seed-weights-kcorbits.fits"), &with).unwrap();
    std::fs::copy(fixtures.join("lut_uint32.fits"), t.join("astropy-lut_uint32.fits")).unwrap();
    // `lut inspect` also reads device images.
    let set = dncal_core::LutSet::<1, 256>::from_bits(&[core::array::from_fn(|k| 2000 * k as u32 + 1024)]).unwrap();
    let mut image = vec![0u8; dncal_core::image_len::<1, 256>()];
    dncal_core::encode_image(&set, &mut image).unwrap();
    std::fs::write(t.join("seed-device-image-1x256.bin"), &image).unwrap();

    let e = dir("emva_descriptor");
    let codes: Vec<u16> = (0..12).map(|i| i * 300).collect();
    let mut input = b"v 3.0\nn 12 4 3\nb 40000.0 120.0\ni f1.png\ni f2.png\nd 40000.0\ni f3.png\ni f3.png\n".to_vec();
    for image in [png(4, 3, &codes, png::BitDepth::Sixteen), png(4, 3, &codes[..].iter().rev().copied().collect::<Vec<_>>(), png::BitDepth::Sixteen), png(4, 3, &[0; 12], png::BitDepth::Sixteen)] {
        input.extend_from_slice(EMVA_FILE_SEPARATOR);
        input.extend_from_slice(&image);
    }
    std::fs::write(e.join("seed-12bit-temporal.txt"), &input).unwrap();
    let mut input = b"# spatial series, 8-bit\r\nn 8 3 2\r\nb 10 5\r\ni f1.png\r\ni f2.png\r\ni f1.png\r\n".to_vec();
    for image in [png(3, 2, &[0, 1, 2, 3, 4, 255], png::BitDepth::Eight), png(3, 2, &[9; 6], png::BitDepth::Eight)] {
        input.extend_from_slice(EMVA_FILE_SEPARATOR);
        input.extend_from_slice(&image);
    }
    std::fs::write(e.join("seed-8bit-spatial.txt"), &input).unwrap();

    let c = dir("camera_toml");
    std::fs::write(c.join("seed-default.toml"), toml::to_string(&CameraConfig::default()).unwrap()).unwrap();
    std::fs::write(c.join("seed-small.toml"), "name = \"small\"\nwidth = 16\nheight = 8\nbits = 4\nn_adc = 2\n\n[adc]\nmodel = \"stages\"\nstage_bits = [2, 2]\nstage_error_lsb = [0.1, 0.05]\n").unwrap();
    let widths = CameraConfig {
        width: 8,
        height: 4,
        bits: 2,
        n_adc: 2,
        nonlinearity: vec![],
        pixel_nonlinearity_rms: vec![],
        adc: dncal_host::model::camera::AdcConfig { stage_bits: vec![1, 1], stage_error_lsb: vec![0.0, 0.0], seed: 1, widths: vec![vec![1.0, 0.9, 1.1, 1.0]; 2], ..dncal_host::model::camera::AdcConfig::stages() },
        ..CameraConfig::default()
    };
    std::fs::write(c.join("seed-model-widths.toml"), toml::to_string(&widths).unwrap()).unwrap();
    // Fitted architectures (a SAR with a missing code, a pipeline with sub-range gains).
    std::fs::write(
        c.join("seed-model-architecture.toml"),
        "width = 8\nheight = 4\nbits = 4\nn_adc = 2\n\n[adc]\nstage_bits = [4]\nstage_error_lsb = [0.0]\n\n[[adc.architecture]]\nkind = \"sar\"\nweight_error_lsb = [0.0, 0.0, -1.5, 0.0]\n\n[[adc.architecture]]\nkind = \"pipelined\"\nstage_bits = [2, 2]\noffset_lsb = [[0.0, 0.1, -0.1, 0.2], [0.0, 0.05, 0.0, -0.05]]\nsubrange_gain_error = [0.0, 0.1, -0.1, 0.0]\n",
    )
    .unwrap();
}

/// A target's entry: whether the reader accepted the input.
type Entry = fn(&[u8]) -> bool;

const TARGETS: [(&str, Entry); 5] = [
    ("fits_histograms", fuzzing::fits_histograms),
    ("fits_linearity", fuzzing::fits_linearity),
    ("fits_lut", fuzzing::fits_lut),
    ("emva_descriptor", fuzzing::emva_descriptor),
    ("camera_toml", fuzzing::camera_toml),
];

/// Found by `fits_lut` (and so by every FITS reader): an 11-byte file starting `PK` made
/// cfitsio allocate 4 GB for the zip it declares, before reading a byte of it. Gzip's
/// declared size (the last 4 bytes) is bounded the same way.
#[test]
fn compressed_files_declaring_more_than_they_can_hold_are_refused_before_cfitsio() {
    let dir = tempfile::tempdir().unwrap();
    let zip = fuzz_dir().join("regressions/fits_lut/oom-zip-header-11-bytes");
    let mut gzip = vec![0x1f, 0x8b, 8, 0, 0, 0, 0, 0, 0, 3];
    gzip.extend_from_slice(&u32::MAX.to_le_bytes());
    let gzip_path = dir.path().join("big.fits.gz");
    std::fs::write(&gzip_path, &gzip).unwrap();
    for (path, size, declared) in [(zip, 11, 1u64 << 32), (gzip_path, 14, u32::MAX as u64)] {
        let want = format!("a compressed file of {size} bytes whose header declares {declared} bytes uncompressed");
        for e in [
            dncal_host::formats::fits::read_lut(&path).unwrap_err(),
            dncal_host::formats::fits::read_histograms(&path).unwrap_err(),
            dncal_host::formats::fits::read_linearity(&path).unwrap_err(),
        ] {
            assert!(e.to_string().contains(&want), "{e}");
        }
    }
}

/// Found by `fits_linearity`: a table HDU whose mandatory keywords cfitsio mis-checks
/// (`ffgttb` compares the status instead of setting it) made cfitsio allocate column
/// descriptors for an unread `TFIELDS`, 2^54 bytes, while counting HDUs.
#[test]
fn table_headers_cfitsio_would_mistake_for_valid_are_refused_before_it() {
    for crash in ["table-with-huge-tfields", "table-after-unreadable-naxis"] {
        let e = linearity_refusal(crash);
        assert!(e.contains("the table header at byte 11520 has \"NAXIS2  =          SIMPLE"), "{e}");
    }
    // XTENSION = 'BINTABLE' followed by text before its comment.
    let e = linearity_refusal("table-xtension-with-trailing-text");
    assert!(e.contains("the table header at byte 11520 has \"NAXIS1  ="), "{e}");
    let e = linearity_refusal("table-with-garbled-gcount");
    // Bytes outside ASCII in the PCOUNT card's comment (its value, 0, is fine: cfitsio
    // reads the value before the comment), then no GCOUNT card where it must be.
    assert!(e.contains("the table header at byte 11520 has \"") && e.ends_with("GCOUNT  =\"; a table header opens with BITPIX, NAXIS, NAXIS1, NAXIS2, PCOUNT, GCOUNT and TFIELDS (0 to 999), integers in range (cfitsio would take it for valid)"), "{e}");
    // The same file with TFIELDS = 1000000 and a valid NAXIS2.
    let dir = tempfile::tempdir().unwrap();
    let (mut huge, table) = seed_and_table();
    huge[table + 7 * 80..table + 8 * 80].copy_from_slice(format!("{:<80}", "TFIELDS =              1000000").as_bytes());
    let path = dir.path().join("huge.fits");
    std::fs::write(&path, &huge).unwrap();
    let e = dncal_host::formats::fits::read_linearity(&path).unwrap_err().to_string();
    assert!(e.contains("has \"TFIELDS =              1000000\""), "{e}");
    assert!(dncal_host::formats::fits::read_linearity(&fuzz_dir().join("corpus/fits_linearity/seed-no-mask.fits")).is_ok());
}

/// Found by `fits_linearity` in its 10-minute run: the file ends 1271 bytes into the
/// table header, after a `PCOUNT` card with bytes outside ASCII in its comment; cfitsio parsed what there
/// was and allocated 2^54 bytes. The header walk now reads a last block cut short.
#[test]
fn a_table_header_cut_by_the_end_of_the_file_is_refused_before_cfitsio() {
    let crash = linearity_regression("table-header-cut-by-the-end-of-file");
    assert_eq!(std::fs::metadata(&crash).unwrap().len(), 12791);
    let e = dncal_host::formats::fits::read_linearity(&crash).unwrap_err().to_string();
    // The PCOUNT card's value is read before its garbled comment; the card after it is
    // not GCOUNT.
    assert!(e.contains("the table header at byte 11520 has \"") && e.contains("GCOUNT  =\"; a table header opens"), "{e}");
}

/// Found by `fits_lut` under AddressSanitizer: `EXTNAME =YYYY...`, a value starting in
/// column 10 and filling the card, overran fitsio's 71-byte string buffer by one byte
/// (cfitsio copies the unquoted value with its NUL). String keys are now parsed from the
/// card: this one is not a quoted string, and the message says so.
#[test]
fn an_unquoted_string_filling_the_card_is_refused_without_a_read_past_the_buffer() {
    let crash = fuzz_dir().join("regressions/fits_lut/unquoted-string-value-from-column-10");
    let e = dncal_host::formats::fits::read_lut(&crash).unwrap_err().to_string();
    assert!(e.contains("key EXTNAME of the HDU 1 is not a quoted string: \"EXTNAME =YYYY"), "{e}");
}

/// Found by `fits_linearity` (second 10-minute run): a std of -8e-322 (a negative
/// subnormal) was refused by the f64 reader and read as -0.0, accepted, by the f32 one
/// that `diagnose` uses. Both now judge the sign at single precision: accepted by both,
/// as a zero.
#[test]
fn a_negative_subnormal_std_is_read_alike_at_both_precisions() {
    let crash = linearity_regression("std-negative-subnormal");
    let wide = dncal_host::formats::fits::read_linearity(&crash);
    let narrow = dncal_host::formats::fits::read_linearity_as::<f32>(&crash);
    assert_eq!(wide.is_ok(), narrow.is_ok(), "{:?} / {:?}", wide.as_ref().err(), narrow.as_ref().err());
    let wide = wide.unwrap();
    let tiny = wide.std.iter().copied().filter(|&v| v < 0.0).collect::<Vec<_>>();
    assert!(!tiny.is_empty() && tiny.iter().all(|&v| v > -f64::from(f32::from_bits(1))), "{tiny:?}");
    assert!(fuzzing::fits_linearity(&std::fs::read(&crash).unwrap()));
}

/// Found by `fits_linearity` (third 10-minute run): the image before the table has a byte
/// 0xDF in its `NAXIS2` card's comment; the header walk read no value there, so its data
/// size as 0, landed in the middle of the data and walked past the table, whose `NAXIS2`
/// is garbage (cfitsio then allocated 2^54 bytes). Values are now read before the comment,
/// and a walk that lands on anything but an extension checks every block after.
#[test]
fn a_comment_outside_ascii_does_not_hide_the_table_after_it() {
    let e = linearity_refusal("table-after-a-comment-outside-ascii");
    assert!(e.contains("the table header at byte 11520 has \"NAXIS2  ="), "{e}");
}

/// Found by `fits_linearity` (after the checksum change): `SIMPLE   =` (the `=` one
/// column late, which cfitsio reads) made the reader take the file for compressed and
/// skip the table-header walk; the table's `NAXIS2` holds a byte outside ASCII. Files are
/// now compressed only by their magic numbers.
#[test]
fn a_nonstandard_simple_card_does_not_skip_the_table_check() {
    let e = linearity_refusal("table-behind-a-nonstandard-simple-card");
    assert!(e.contains("the table header at byte 11520 has \"NAXIS2  =               ?    4 / length of dimension 2\""), "{e}");
}

/// Found by `fits_linearity` comparing the set opened by rows (`diagnose` beyond its
/// budget) with the whole read: an IMAGE extension with `PCOUNT = 2` (garbled) that cfitsio
/// read two values late, and cubes cut short by the file or by their own data unit that
/// the rows opener refused in its own words. All three are refused alike now; the first
/// by name.
#[test]
fn the_rows_opener_and_the_whole_read_agree_where_they_disagreed() {
    let at = linearity_regression;
    let e = dncal_host::formats::fits::read_linearity(&at("image-with-pcount-read-shifted-by-cfitsio")).unwrap_err().to_string();
    assert!(e.ends_with("the extension STD has PCOUNT = 2 and GCOUNT = 1; an image has 0 and 1 (random groups are not read)"), "{e}");
    for name in ["image-with-pcount-read-shifted-by-cfitsio", "std-cut-short-read-by-rows", "std-longer-than-its-unit-read-by-rows"] {
        let whole = dncal_host::formats::fits::read_linearity_as::<f32>(&at(name)).unwrap_err().to_string();
        let by_rows = match dncal_host::formats::fits::open_linearity_rows(&at(name)) {
            Ok(Some(o)) => o.check::<f32>().map(|_| ()).unwrap_err().to_string(),
            Ok(None) => whole.clone(),
            Err(e) => e.to_string(),
        };
        assert_eq!(by_rows, whole, "{name}");
        assert!(!whole.contains("failed to fill whole buffer") && !whole.contains("declares more data than its unit holds"), "{name}: {whole}");
    }
}

/// Found by `fits_linearity` (2026-11-26): a REFERENCE header whose `XTENSION` key reads
/// 'BINTABLE' but which cfitsio takes for another kind of HDU; fitsio's column reader
/// panicked ("Unknown error occurred") on cfitsio's answer. Refused by name now.
#[test]
fn a_table_cfitsio_reads_as_another_kind_is_refused_not_a_panic() {
    let e = linearity_refusal("table-that-cfitsio-reads-as-another-kind");
    assert!(e.ends_with("the extension REFERENCE says XTENSION = 'BINTABLE' but its header does not read as a binary table (damaged)"), "{e}");
}

/// Found by `fits_linearity` (round 15, 2026-11-26) under AddressSanitizer: the REFERENCE
/// table's `NAXIS1` card holds a form feed (0x0C) before its value. The table check read
/// past it (Rust's `trim` drops it), cfitsio's `ffc2jj` does not, `ffgttb` passed the
/// failure on unnoticed and `ffbinit` sized its column descriptors from a `TFIELDS` it
/// never read. Values are now read as cfitsio reads them (`ffpsvc`, `ffc2jj`).
#[test]
fn a_form_feed_in_a_mandatory_table_value_is_refused_before_cfitsio() {
    let e = linearity_refusal("table-with-a-form-feed-before-naxis1");
    assert!(e.contains("the table header at byte 11520 has \"NAXIS1  =      ?             8 / width of table in bytes\""), "{e}");
    // Every reader refuses it alike (the target's comparisons run, nothing accepted).
    assert!(!dncal_host::checks::fuzzing::fits_linearity(&std::fs::read(linearity_regression("table-with-a-form-feed-before-naxis1")).unwrap()));
    // A tab or a form feed right before the digits, which cfitsio's `strtoll` skips, is
    // read as cfitsio reads it: the set is accepted.
    let dir = tempfile::tempdir().unwrap();
    let (seed, table) = seed_and_table();
    for ws in ["\t", "\x0c"] {
        let mut file = seed.clone();
        let card = &mut file[table + 3 * 80..table + 4 * 80];
        assert!(card.starts_with(b"NAXIS1  ="));
        let value = card[10..30].iter().position(|&b| b != b' ').unwrap() + 10;
        card[value - 1] = ws.as_bytes()[0];
        let path = dir.path().join("ws.fits");
        std::fs::write(&path, &file).unwrap();
        assert!(dncal_host::formats::fits::read_linearity(&path).is_ok(), "{ws:?}: {:?}", dncal_host::formats::fits::read_linearity(&path).err());
    }
}

/// Found by `fits_linearity` (round 16, 2026-11-26) under AddressSanitizer, the same
/// allocation in `ffbinit`: the STD image's header ends with `END    q`, which cfitsio
/// reads as END (a keyword's name runs to its first blank), and the table check, which
/// took the first 8 columns for the name, walked past the table header after it with its
/// garbled `NAXIS2`. Names are now read as cfitsio reads them.
#[test]
fn an_end_card_with_trailing_text_does_not_hide_the_table_after_it() {
    let e = linearity_refusal("table-after-an-end-card-with-trailing-text");
    assert!(e.contains("the table header at byte 11520 has \"NAXIS2  =                 ?????z??   3"), "{e}");
}
