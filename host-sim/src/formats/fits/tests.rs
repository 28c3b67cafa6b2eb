//! The FITS readers and writers against hand-made files and each other.

use std::path::PathBuf;

use super::*;

/// A key for hand-made test files.
enum Key {
    Int(i64),
    Str(&'static str),
    Float(f64),
}
use Key::{Float, Int, Str};

fn keys(out: &mut FitsWriter, keys: &[(&str, Key)]) {
    for (name, value) in keys {
        match value {
            Int(v) => out.key(name, *v),
            Str(v) => out.key(name, *v),
            Float(v) => out.key(name, *v),
        }
        .unwrap();
    }
}

/// A one-HDU file with any primary image and keys, bypassing every check.
fn image_file<T: WriteImage>(path: &Path, data_type: ImageType, dims: &[usize], data: &[T], with: &[(&str, Key)]) {
    let mut out = FitsWriter::create(path, path, data_type, dims).unwrap();
    keys(&mut out, with);
    out.image(data).unwrap();
    out.finish().unwrap();
}

/// BITDEPTH 2 (4 codes), 2 ADCs.
fn adc_keys_2x4() -> Vec<(&'static str, Key)> {
    vec![("BITDEPTH", Int(2)), ("NADC", Int(2)), ("ADCMAP", Str("COLMOD"))]
}

fn without(mut k: Vec<(&'static str, Key)>, name: &str) -> Vec<(&'static str, Key)> {
    k.retain(|(n, _)| *n != name);
    k
}

fn with(mut k: Vec<(&'static str, Key)>, name: &'static str, value: Key) -> Vec<(&'static str, Key)> {
    k.retain(|(n, _)| *n != name);
    k.push((name, value));
    k
}

/// The message of a `Format` error or a typed [`Fault`], after checking it names `path`.
fn format_message<T: std::fmt::Debug>(result: Result<T, HostError>, path: &Path) -> String {
    match result {
        Err(HostError::Format { path: p, message }) => {
            assert_eq!(p, path, "error names the wrong file: {message}");
            message
        }
        Err(HostError::FitsContent { path: p, source }) => {
            assert_eq!(p, path, "error names the wrong file: {source}");
            source.to_string()
        }
        other => panic!("expected a format error for {}, got {other:?}", path.display()),
    }
}

fn assert_rejects<T: std::fmt::Debug>(result: Result<T, HostError>, path: &Path, expected: &str) {
    let message = format_message(result, path);
    assert!(message.contains(expected), "message {message:?} does not contain {expected:?}");
}

fn files_in(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).collect();
    v.sort();
    v
}

fn histograms() -> AdcHistograms {
    // Distinct in every ADC and code, with both ends of the signed 64-bit range's
    // non-negative half, so a transposed or truncated read cannot pass.
    let mut counts: Vec<Vec<u64>> = (0..3u64).map(|a| (0..16u64).map(|k| 1000 * a + k * k).collect()).collect();
    counts[2][15] = i64::MAX as u64;
    AdcHistograms { bit_depth: 4, counts }
}

fn linearity(mask: bool) -> LinearitySet {
    let (width, height, levels) = (5, 3, 4);
    let mean = (0..levels * height * width).map(|i| 100.0 + 0.25 * i as f64).collect();
    let std = (0..levels * height * width).map(|i| 0.5 + 0.125 * (i % 7) as f64).collect();
    LinearitySet {
        bit_depth: 12,
        n_adc: 4,
        n_frames: 64,
        width,
        height,
        levels,
        mean,
        std,
        voltage: vec![0.0, 0.5, 1.0, 1.5],
        mask: mask.then(|| (0..width * height).map(|i| u8::from(i % 4 == 1)).collect()),
        keys: Default::default(),
    }
}

fn lut() -> LutTables {
    let mut tables: Vec<Vec<u32>> =
        (0..4u32).map(|a| (0..8u32).map(|k| (2 * k + 1) * 1024 + a).collect()).collect();
    tables[3][7] = u32::MAX;
    tables[0][0] = 0;
    LutTables { frac_bits: 11, tables, weights: None, kcor_bits: None }
}

#[test]
fn histograms_round_trip_as_bitpix_64_without_primary_extname() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("h.fits");
    write_histograms(&path, &histograms()).unwrap();
    assert_eq!(read_histograms(&path).unwrap(), histograms());
    let mut r = FitsReader::open(&path).unwrap();
    assert_eq!(r.required_int(0, PRIMARY, "BITPIX").unwrap(), 64);
    assert_eq!(r.key::<String>(0, PRIMARY, "EXTNAME").unwrap(), None);
}

#[test]
fn histograms_read_from_every_integer_bitpix() {
    let dir = tempfile::tempdir().unwrap();
    // (type, largest value it holds): the unsigned types exercise BZERO.
    let types = [
        (ImageType::UnsignedByte, 255),
        (ImageType::Byte, 127),
        (ImageType::Short, 32_767),
        (ImageType::UnsignedShort, 65_535),
        (ImageType::Long, i64::from(i32::MAX)),
        (ImageType::UnsignedLong, i64::from(u32::MAX)),
        (ImageType::LongLong, i64::MAX),
    ];
    for (i, (data_type, top)) in types.into_iter().enumerate() {
        let path = dir.path().join(format!("h{i}.fits"));
        let data = [0, 1, 2, 3, 4, 5, 6, top];
        image_file(&path, data_type, &[2, 4], &data, &adc_keys_2x4());
        let h = read_histograms(&path).unwrap();
        let expected = vec![vec![0, 1, 2, 3], vec![4, 5, 6, top as u64]];
        assert_eq!((h.bit_depth, h.counts), (2, expected), "{data_type:?}");
    }
}

#[test]
fn histograms_reject_bad_images() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("h.fits");
    image_file(&p, ImageType::Double, &[2, 4], &[1.0f64; 8], &adc_keys_2x4());
    assert_rejects(read_histograms(&p), &p, "floating-point image (BITPIX = -64)");
    image_file(&p, ImageType::Float, &[2, 4], &[1.0f32; 8], &adc_keys_2x4());
    assert_rejects(read_histograms(&p), &p, "floating-point image (BITPIX = -32)");
    image_file(&p, ImageType::Long, &[2, 4], &[1, 2, 3, 4, 5, 6, -7, 8], &adc_keys_2x4());
    assert_rejects(read_histograms(&p), &p, "count -7 at ADC 1, code 2 is negative");
    image_file(&p, ImageType::Long, &[2, 3], &[1; 6], &adc_keys_2x4());
    assert_rejects(read_histograms(&p), &p, "NAXIS1 = 3 codes, BITDEPTH = 2 needs 2^2 = 4");
    image_file(&p, ImageType::Long, &[3, 4], &[1; 12], &adc_keys_2x4());
    assert_rejects(read_histograms(&p), &p, "NAXIS2 = 3 rows, NADC = 2");
    image_file(&p, ImageType::Long, &[1, 2, 4], &[1; 8], &adc_keys_2x4());
    assert_rejects(read_histograms(&p), &p, "NAXIS = 3, expected 2");
    image_file(&p, ImageType::Long, &[8], &[1; 8], &adc_keys_2x4());
    assert_rejects(read_histograms(&p), &p, "NAXIS = 1, expected 2");
}

#[test]
fn histograms_reject_missing_and_bad_keys() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("h.fits");
    for name in ["BITDEPTH", "NADC", "ADCMAP"] {
        image_file(&p, ImageType::Long, &[2, 4], &[1; 8], &without(adc_keys_2x4(), name));
        assert_rejects(read_histograms(&p), &p, &format!("missing key {name} in the primary HDU"));
    }
    let cases = [
        ("ADCMAP", Str("ROWMOD"), "ADCMAP = 'ROWMOD'"),
        ("ADCMAP", Int(4), "key ADCMAP of the primary HDU is not a quoted string: \"ADCMAP  =                    4\""),
        ("BITDEPTH", Int(0), "BITDEPTH = 0, must be 1 to 16"),
        ("BITDEPTH", Int(17), "BITDEPTH = 17, must be 1 to 16"),
        ("BITDEPTH", Int(-3), "BITDEPTH = -3"),
        ("BITDEPTH", Float(2.5), "BITDEPTH of the primary HDU is 2.5, not an integer"),
        ("BITDEPTH", Str("two"), "key BITDEPTH of the primary HDU"),
        ("NADC", Int(0), "NADC = 0, must be at least 1"),
    ];
    for (name, value, expected) in cases {
        image_file(&p, ImageType::Long, &[2, 4], &[1; 8], &with(adc_keys_2x4(), name, value));
        assert_rejects(read_histograms(&p), &p, expected);
    }
}

#[test]
fn each_kind_of_file_is_named_to_a_reader_of_another() {
    let dir = tempfile::tempdir().unwrap();
    let (h, l, s) = (dir.path().join("h.fits"), dir.path().join("l.fits"), dir.path().join("s.fits"));
    write_histograms(&h, &histograms()).unwrap();
    write_lut(&l, &lut()).unwrap();
    write_linearity(&s, &linearity(true)).unwrap();
    // Every wrong pairing of the three kinds, each message naming what the file is.
    let (hist, lin, lutk) = ("a histogram set (", "a linearity set (", "a LUT FITS (");
    for (message, starts, not) in [
        (format_message(read_histograms(&l), &l), lutk, "a histogram set"),
        (format_message(read_histograms(&s), &s), lin, "a histogram set"),
        (format_message(read_lut(&h), &h), hist, "a LUT FITS"),
        (format_message(read_lut(&s), &s), lin, "a LUT FITS"),
        (format_message(read_linearity(&h), &h), hist, "a linearity set"),
        (format_message(read_linearity(&l), &l), lutk, "a linearity set"),
    ] {
        assert!(message.starts_with(&format!("this is {starts}")) && message.ends_with(&format!("), not {not}")), "{message}");
    }
    // And each reads its own.
    assert!(read_histograms(&h).is_ok() && read_lut(&l).is_ok() && read_linearity(&s).is_ok());
}

#[test]
fn histogram_writer_rejects_bad_sets_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("h.fits");
    let ragged = AdcHistograms { bit_depth: 2, counts: vec![vec![1; 4], vec![1; 3]] };
    assert_rejects(write_histograms(&p, &ragged), &p, "ADC 1 has 3 codes, bit depth 2 needs 2^2 = 4");
    let empty = AdcHistograms { bit_depth: 2, counts: vec![] };
    assert_rejects(write_histograms(&p, &empty), &p, "no ADCs");
    for bits in [0, 17, 64, u32::MAX] {
        let h = AdcHistograms { bit_depth: bits, counts: vec![vec![1; 4]] };
        assert_rejects(write_histograms(&p, &h), &p, &format!("bit depth {bits}, must be 1 to 16"));
    }
    let huge = AdcHistograms { bit_depth: 1, counts: vec![vec![0, u64::MAX]] };
    assert_rejects(write_histograms(&p, &huge), &p, "count 18446744073709551615 (ADC 0, code 1)");
    assert_eq!(files_in(dir.path()), Vec::<PathBuf>::new());
}

#[test]
fn linearity_round_trips_with_and_without_mask() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("lin.fits");
    for mask in [true, false] {
        write_linearity(&p, &linearity(mask)).unwrap();
        assert_eq!(read_linearity(&p).unwrap(), linearity(mask));
    }
}

/// A colour sensor's layout goes out as the convention's four keys and comes back; a
/// region of interest from an odd column has the layout shifted.
#[test]
fn a_bayer_layout_round_trips_as_bayerpat() {
    use crate::formats::bayer::Bayer;
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("lin.fits");
    for b in Bayer::ALL {
        let set = LinearitySet { keys: SetKeys { bayer: Some(b), ..SetKeys::default() }, ..linearity(false) };
        write_linearity(&p, &set).unwrap();
        assert_eq!(read_linearity(&p).unwrap(), set);
    }
}

/// A relative exposure goes out as column `EXPOSURE` and comes back as one; a table
/// written by another with `EXPOSURE` (any case) is read so.
#[test]
fn an_exposure_reference_round_trips_as_its_column() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lin.fits");
    let set = LinearitySet { keys: SetKeys { reference: Reference::Exposure, ..SetKeys::default() }, ..linearity(true) };
    write_linearity(&path, &set).unwrap();
    assert_eq!(read_linearity(&path).unwrap(), set);
    let mut p = parts();
    p.reference = Some(("exposure", vec![0.0, 1e-3, 2e-3, 4e-3]));
    write_parts(&path, &p);
    let read = read_linearity(&path).unwrap();
    assert_eq!((read.keys.reference, read.voltage), (Reference::Exposure, vec![0.0, 1e-3, 2e-3, 4e-3]));
}

/// `BAYERPAT` as others write it: offsets shift the layout (of either sign, modulo 2),
/// `ROWORDER = 'BOTTOM-UP'` starts it at the last stored row (on 3 rows, the first's
/// parity; on 4, the other's); a layout or row order that is none is read as declared and
/// unread (an X-Trans camera's files read); an offset that is not an integer is refused
/// naming the file and the key.
#[test]
fn bayerpat_is_read_with_its_offsets_and_row_order() {
    use crate::formats::bayer::Bayer;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lin.fits");
    let read = |extra: Vec<(&'static str, Key)>, rows: usize| {
        let mut p = parts();
        for (name, value) in extra {
            p.keys = with(p.keys, name, value);
        }
        if rows != 3 {
            let (levels, width) = (4, 5);
            let n = levels * rows * width;
            p.cube = vec![levels, rows, width];
            p.mean = (0..n).map(|i| 100.0 + 0.25 * i as f64).collect();
            p.std = Some((vec![levels, rows, width], vec![1.0; n]));
            p.mask = None;
        }
        write_parts(&path, &p);
        read_linearity(&path).map(|s| s.keys.bayer)
    };
    assert_eq!(read(vec![], 3).unwrap(), None);
    assert_eq!(read(vec![("BAYERPAT", Str("rggb"))], 3).unwrap(), Some(Bayer::Rggb));
    assert_eq!(read(vec![("BAYERPAT", Str("RGGB")), ("XBAYROFF", Int(1))], 3).unwrap(), Some(Bayer::Grbg));
    assert_eq!(read(vec![("BAYERPAT", Str("RGGB")), ("YBAYROFF", Int(-1))], 3).unwrap(), Some(Bayer::Gbrg));
    assert_eq!(read(vec![("BAYERPAT", Str("RGGB")), ("XBAYROFF", Int(1)), ("YBAYROFF", Int(1))], 3).unwrap(), Some(Bayer::Bggr));
    assert_eq!(read(vec![("BAYERPAT", Str("RGGB")), ("ROWORDER", Str("TOP-DOWN"))], 4).unwrap(), Some(Bayer::Rggb));
    assert_eq!(read(vec![("BAYERPAT", Str("RGGB")), ("ROWORDER", Str("BOTTOM-UP"))], 3).unwrap(), Some(Bayer::Rggb));
    assert_eq!(read(vec![("BAYERPAT", Str("RGGB")), ("ROWORDER", Str("BOTTOM-UP"))], 4).unwrap(), Some(Bayer::Gbrg));
    // (Labels the numbers do not depend on: an X-Trans layout, a blank one, an unknown
    // row order read, the first two as declared and unread.)
    let unread = |extra: Vec<(&'static str, Key)>| {
        read(extra, 3).unwrap();
        read_linearity(&path).unwrap().keys
    };
    let xtrans = unread(vec![("BAYERPAT", Str("GGRGGBGGBGGRBRGRBGGGBGGRGGRGGBRBGBRG"))]);
    assert_eq!((xtrans.bayer, xtrans.bayer_unread), (None, true));
    assert!(unread(vec![("BAYERPAT", Str("RGGB")), ("ROWORDER", Str("LEFT"))]).bayer_unread);
    assert_eq!(unread(vec![("BAYERPAT", Str("  "))]), SetKeys::default());
    assert_rejects(read(vec![("BAYERPAT", Str("RGGB")), ("XBAYROFF", Float(0.5))], 3), &path, "key XBAYROFF of the primary HDU is 0.5, not an integer");
}

#[test]
fn linearity_writer_rejects_bad_sets_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("lin.fits");
    type Edit = fn(&mut LinearitySet);
    let cases: [(Edit, &str); 13] = [
        (|s| s.mean[17] = f64::NAN, "mean is NaN at level 1, row 0, column 2"),
        (|s| s.mean[0] = f64::INFINITY, "mean is inf at level 0, row 0, column 0"),
        (|s| s.std[59] = f64::NAN, "std is NaN at level 3, row 2, column 4"),
        (|s| s.std[6] = -0.5, "std is negative (-0.5) at level 0, row 1, column 1"),
        (|s| s.voltage[2] = f64::NEG_INFINITY, "reference voltage is -inf at level 2"),
        (|s| s.voltage.push(2.0), "5 reference voltages for 4 levels"),
        (|s| s.mean.truncate(59), "mean holds 59 values, 5 x 3 x 4 (columns x rows x levels) needs 60"),
        (|s| s.std.push(1.0), "std holds 61 values"),
        (|s| s.mask = Some(vec![0; 14]), "mask holds 14 values, 5 x 3 frames need 15"),
        (|s| s.mask.as_mut().unwrap()[7] = 2, "mask value 2 at row 1, column 2 is not 0 or 1"),
        (|s| s.n_frames = 0, "NFRAMES must be at least 1"),
        (|s| s.n_adc = 0, "NADC must be at least 1"),
        (|s| s.width = 0, "is empty or too large"),
    ];
    for (edit, expected) in cases {
        let mut set = linearity(true);
        edit(&mut set);
        assert_rejects(write_linearity(&p, &set), &p, expected);
    }
    assert_eq!(files_in(dir.path()), Vec::<PathBuf>::new());
}

/// The HDUs of a linearity file, to be broken one at a time.
struct Parts {
    keys: Vec<(&'static str, Key)>,
    cube: Vec<usize>,
    mean: Vec<f64>,
    std: Option<(Vec<usize>, Vec<f64>)>,
    mask: Option<(Vec<usize>, Vec<i64>)>,
    /// (column name, values)
    reference: Option<(&'static str, Vec<f64>)>,
}

fn parts() -> Parts {
    let s = linearity(true);
    Parts {
        keys: with(with(adc_keys_2x4(), "BITDEPTH", Int(12)), "NFRAMES", Int(64)),
        cube: vec![4, 3, 5],
        mean: s.mean,
        std: Some((vec![4, 3, 5], s.std)),
        mask: Some((vec![3, 5], vec![0; 15])),
        reference: Some(("VOLTAGE", s.voltage)),
    }
}

fn write_parts(path: &Path, p: &Parts) {
    let mut out = FitsWriter::create(path, path, ImageType::Double, &p.cube).unwrap();
    keys(&mut out, &p.keys);
    out.image(&p.mean).unwrap();
    if let Some((dims, std)) = &p.std {
        out.add_image("STD", ImageType::Double, dims).unwrap();
        out.image(std).unwrap();
    }
    if let Some((dims, mask)) = &p.mask {
        out.add_image("MASK", ImageType::UnsignedByte, dims).unwrap();
        out.image(mask).unwrap();
    }
    if let Some((column, voltage)) = &p.reference {
        out.add_table("REFERENCE", column, "V", voltage).unwrap();
    }
    out.finish().unwrap();
}

#[test]
fn linearity_reader_rejects_bad_files() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lin.fits");
    write_parts(&path, &parts());
    read_linearity(&path).unwrap();
    type Edit = fn(&mut Parts);
    let cases: [(Edit, &str); 17] = [
        (|p| p.std = None, "missing extension STD"),
        (|p| p.reference = None, "missing extension REFERENCE"),
        (|p| p.reference = Some(("VOLTS", vec![0.0; 4])), "the extension REFERENCE has no column VOLTAGE (a reference photodiode's voltage, V) or EXPOSURE (a relative exposure, t / N^2)"),
        (
            |p| p.reference = Some(("VOLTAGE", vec![0.0; 3])),
            "extension REFERENCE has 3 rows, the cube has 4 levels",
        ),
        (|p| p.reference = Some(("VOLTAGE", vec![0.0, 1.0, f64::NAN, 2.0])), "reference voltage is NaN at level 2"),
        (
            |p| p.std = Some((vec![4, 5, 3], vec![1.0; 60])),
            "extension STD is 3 x 5 x 4 but the primary cube is 5 x 3 x 4",
        ),
        (|p| p.std = Some((vec![3, 3, 5], vec![1.0; 45])), "extension STD is 5 x 3 x 3"),
        (|p| p.std = Some((vec![60], vec![1.0; 60])), "extension STD has NAXIS = 1, expected 3"),
        (|p| p.mask = Some((vec![5, 3], vec![0; 15])), "extension MASK is 3 x 5 but frames are 5 x 3"),
        (|p| p.mask.as_mut().unwrap().1[7] = 3, "mask value 3 at row 1, column 2 is not 0 or 1"),
        (|p| p.mean[17] = f64::NAN, "mean is NaN at level 1, row 0, column 2"),
        (|p| p.std.as_mut().unwrap().1[6] = -1.0, "std is negative (-1) at level 0, row 1, column 1"),
        (|p| p.std.as_mut().unwrap().1[0] = f64::INFINITY, "std is inf at level 0, row 0, column 0"),
        (|p| p.keys.retain(|(n, _)| *n != "NFRAMES"), "missing key NFRAMES in the primary HDU"),
        (|p| p.keys = with(std::mem::take(&mut p.keys), "NFRAMES", Int(0)), "NFRAMES = 0"),
        (|p| p.keys.retain(|(n, _)| *n != "ADCMAP"), "missing key ADCMAP"),
        (|p| p.cube = vec![60], "the primary HDU has NAXIS = 1, expected 3"),
    ];
    for (edit, expected) in cases {
        let mut p = parts();
        edit(&mut p);
        write_parts(&path, &p);
        assert_rejects(read_linearity(&path), &path, expected);
        // A set opened to be read by rows (`diagnose` beyond its memory budget) is
        // refused with the words of the whole read, as f32.
        assert_eq!(by_rows(&path), read_linearity_as::<f32>(&path).unwrap_err().to_string());
    }
    // With two faults, the one the whole read names: a negative deviation before one
    // that is not finite, a bad mean and a missing REFERENCE, a bad mean and a mask of
    // the wrong shape, a bad deviation and a bad mask value.
    let two: [(Edit, &str); 4] = [
        (|p| (p.std.as_mut().unwrap().1[1], p.std.as_mut().unwrap().1[40]) = (-1.0, f64::NAN), "std is NaN at level 2, row 2, column 0"),
        (|p| (p.mean[3], p.reference) = (f64::NAN, None), "missing extension REFERENCE"),
        (|p| (p.mean[3], p.mask) = (f64::INFINITY, Some((vec![5, 3], vec![0; 15]))), "extension MASK is 3 x 5"),
        (|p| (p.std.as_mut().unwrap().1[2], p.mask.as_mut().unwrap().1[7]) = (-2.0, 3), "std is negative (-2) at level 0, row 0, column 2"),
    ];
    for (edit, expected) in two {
        let mut p = parts();
        edit(&mut p);
        write_parts(&path, &p);
        assert_rejects(read_linearity_as::<f32>(&path), &path, expected);
        assert_eq!(by_rows(&path), read_linearity_as::<f32>(&path).unwrap_err().to_string());
    }
    // Past f32's range: infinite as f32, as cfitsio converts it.
    let mut p = parts();
    p.mean[23] = 1e300;
    write_parts(&path, &p);
    // As f64 finite, and no mean of 12-bit codes (issue 43).
    assert_rejects(read_linearity(&path), &path, "mean 1e300 at level 1, row 1, column 3 is no mean of 12-bit codes (allowed -4096 to 8192: one code range either side)");
    assert_rejects(read_linearity_as::<f32>(&path), &path, "mean is inf at level 1, row 1, column 3");
    assert_eq!(by_rows(&path), read_linearity_as::<f32>(&path).unwrap_err().to_string());
    // Issue 43's reproducer: means near -9.3e18 (a wrong BZERO) reached the plots as a
    // signal and panicked in the color map; both readers, and the reader by rows, refuse
    // them in the same words. The edges of the range are taken.
    let mut p = parts();
    p.mean[5] = -9.3e18;
    write_parts(&path, &p);
    let expected = "mean -9.3e18 at level 0, row 1, column 0 is no mean of 12-bit codes (allowed -4096 to 8192: one code range either side)";
    assert_rejects(read_linearity(&path), &path, expected);
    assert_rejects(read_linearity_as::<f32>(&path), &path, expected);
    assert_eq!(by_rows(&path), read_linearity_as::<f32>(&path).unwrap_err().to_string());
    let mut p = parts();
    (p.mean[5], p.mean[6]) = (-4096.0, 8192.0);
    write_parts(&path, &p);
    read_linearity(&path).unwrap();
    assert!(open_linearity_rows(&path).unwrap().unwrap().check::<f32>().is_ok());
}

/// Issue 56: a set whose `NADC` exceeds its columns (65, 1000 or 2e9 on 16 or 64) was
/// read as if each column were its own ADC. Both whole readers and the reader by rows
/// refuse it in the same words, naming both numbers; `NADC` equal to the columns reads
/// back the values written; the writer refuses what the readers refuse.
#[test]
fn linearity_sets_with_more_adcs_than_columns_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lin.fits");
    let (height, levels) = (2, 3);
    for width in [16usize, 64] {
        let cube = levels * height * width;
        let mean: Vec<f64> = (0..cube).map(|i| 100.0 + 0.5 * i as f64).collect();
        let with_adcs = |n_adc: i64| Parts {
            keys: with(parts().keys, "NADC", Int(n_adc)),
            cube: vec![levels, height, width],
            mean: mean.clone(),
            std: Some((vec![levels, height, width], vec![1.5; cube])),
            mask: None,
            reference: Some(("VOLTAGE", vec![0.0, 0.5, 1.0])),
        };
        for n_adc in [width as i64 + 1, 65, 1000, 2_000_000_000] {
            write_parts(&path, &with_adcs(n_adc));
            let expected = format!("NADC = {n_adc} but the frames have {width} columns; column c is read by ADC c mod NADC, so at most {width} ADCs");
            assert_eq!(format_message(read_linearity(&path), &path), expected);
            assert_eq!(format_message(read_linearity_as::<f32>(&path), &path), expected);
            assert_eq!(by_rows(&path), format!("{}: {expected}", path.display()));
        }
        write_parts(&path, &with_adcs(width as i64));
        let set = read_linearity(&path).unwrap();
        assert_eq!((set.n_adc, set.width, &set.mean), (width, width, &mean));
        assert!(open_linearity_rows(&path).unwrap().unwrap().check::<f32>().is_ok());
        let written = dir.path().join("written.fits");
        assert_rejects(write_linearity(&written, &LinearitySet { n_adc: width + 1, ..set.clone() }), &written, &format!("NADC = {} but the frames have {width} columns", width + 1));
        assert!(!written.exists());
        write_linearity(&written, &set).unwrap();
        assert_eq!(read_linearity(&written).unwrap(), set);
        std::fs::remove_file(&written).unwrap();
    }
}

/// The refusal of a set opened by rows (at open or when its values are checked), as f32.
fn by_rows(path: &Path) -> String {
    match open_linearity_rows(path) {
        Err(e) => e.to_string(),
        Ok(None) => panic!("{}: an uncompressed float set is read by rows", path.display()),
        Ok(Some(o)) => o.check::<f32>().map(|_| ()).unwrap_err().to_string(),
    }
}

#[test]
fn lut_round_trips_as_uint32_with_bzero() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("lut.fits");
    write_lut(&p, &lut()).unwrap();
    assert_eq!(read_lut(&p).unwrap(), lut());
    let mut r = FitsReader::open(&p).unwrap();
    assert_eq!(r.required_int(0, PRIMARY, "BITPIX").unwrap(), 32);
    assert_eq!(r.key::<f64>(0, PRIMARY, "BZERO").unwrap(), Some(2_147_483_648.0));
    assert_eq!(r.required_int(0, PRIMARY, "FRACBITS").unwrap(), 11);
    assert_eq!(r.required_int(0, PRIMARY, "BITDEPTH").unwrap(), 3);
    // With the weights extension and the K-Cor scaling.
    let mut with = lut();
    with.weights = Some((0..4u32).map(|a| (0..8u32).map(|k| (1 << 24) + 1000 * k + a).collect()).collect());
    with.kcor_bits = Some(23);
    write_lut(&p, &with).unwrap();
    assert_eq!(read_lut(&p).unwrap(), with);
    // Weights of the wrong shape are refused before anything is written.
    let q = dir.path().join("bad.fits");
    with.weights.as_mut().unwrap()[2].pop();
    assert!(write_lut(&q, &with).is_err() && !q.exists());
}

#[test]
fn lut_reader_and_writer_reject_bad_tables() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("lut.fits");
    let k = || with(adc_keys_2x4(), "FRACBITS", Int(11));
    image_file(&p, ImageType::LongLong, &[2, 4], &[0, 1, 2, 3, 4, 5, 6, 1i64 << 32], &k());
    assert_rejects(read_lut(&p), &p, "entry 4294967296 at ADC 1, code 3 is outside 0 to 2^32 - 1");
    image_file(&p, ImageType::Long, &[2, 4], &[0, -1, 2, 3, 4, 5, 6, 7], &k());
    assert_rejects(read_lut(&p), &p, "entry -1 at ADC 0, code 1");
    image_file(&p, ImageType::Double, &[2, 4], &[0.5f64; 8], &k());
    assert_rejects(read_lut(&p), &p, "floating-point image");
    image_file(&p, ImageType::Long, &[2, 4], &[0; 8], &with(k(), "FRACBITS", Int(12)));
    assert_rejects(read_lut(&p), &p, "FRACBITS = 12, dncal LUT entries of 2-bit codes have 11 fractional bits");
    image_file(&p, ImageType::Long, &[2, 8], &[0; 16], &k());
    assert_rejects(read_lut(&p), &p, "NAXIS1 = 8 codes, BITDEPTH = 2 needs 2^2 = 4");

    let w = dir.path().join("w.fits");
    let bad_frac = LutTables { frac_bits: 12, ..lut() };
    assert_rejects(write_lut(&w, &bad_frac), &w, "12 fractional bits; dncal LUT entries of 3-bit codes have 11");
    let odd = LutTables { frac_bits: 11, tables: vec![vec![0; 6]], weights: None, kcor_bits: None };
    assert_rejects(write_lut(&w, &odd), &w, "tables of 6 entries");
    let one_code = LutTables { frac_bits: 11, tables: vec![vec![0; 1]], weights: None, kcor_bits: None };
    assert_rejects(write_lut(&w, &one_code), &w, "bit depth 0");
    let ragged = LutTables { frac_bits: 11, tables: vec![vec![0; 4], vec![0; 2]], weights: None, kcor_bits: None };
    assert_rejects(write_lut(&w, &ragged), &w, "ADC 1 has 2 entries");
    let none = LutTables { frac_bits: 11, tables: vec![], weights: None, kcor_bits: None };
    assert_rejects(write_lut(&w, &none), &w, "tables of 0 entries");
    assert!(!w.exists());
}

/// Every cut of a good file is an error naming it, even one in the last block's
/// padding (the HDU declares whole blocks); never a panic or other data.
fn check_truncations<T: std::fmt::Debug>(path: &Path, read: fn(&Path) -> Result<T, HostError>) {
    read(path).unwrap();
    let bytes = std::fs::read(path).unwrap();
    assert_eq!(bytes.len() % 2880, 0);
    let cut_path = path.with_extension("cut.fits");
    let cuts =
        (0..bytes.len()).step_by(173).chain((0..bytes.len()).step_by(2880)).chain([1, 79, 80, bytes.len() - 1]);
    for cut in cuts {
        std::fs::write(&cut_path, &bytes[..cut]).unwrap();
        match read(&cut_path) {
            Ok(v) => panic!("cut at {cut} of {} read as {v:?}", bytes.len()),
            Err(e) => {
                format_message(Err::<(), _>(e), &cut_path);
            }
        }
    }
}

#[test]
fn truncated_files_are_errors_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let (h, lin, l) = (dir.path().join("h.fits"), dir.path().join("lin.fits"), dir.path().join("lut.fits"));
    write_histograms(&h, &histograms()).unwrap();
    write_linearity(&lin, &linearity(true)).unwrap();
    write_lut(&l, &lut()).unwrap();
    check_truncations(&h, read_histograms);
    check_truncations(&lin, read_linearity);
    check_truncations(&l, read_lut);
    // The message says what happened.
    let bytes = std::fs::read(&h).unwrap();
    std::fs::write(&h, &bytes[..2880]).unwrap();
    assert_rejects(read_histograms(&h), &h, "truncated?");
}

#[test]
fn foreign_and_missing_files_are_errors_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("notes.fits");
    let contents: [&[u8]; 4] = [b"", b"this is not a FITS file\n", &[0u8; 5760], b"\x89PNG\r\n\x1a\n0000"];
    for bytes in contents {
        std::fs::write(&p, bytes).unwrap();
        assert_rejects(read_histograms(&p), &p, "not a readable FITS file");
        assert_rejects(read_linearity(&p), &p, "not a readable FITS file");
        assert_rejects(read_lut(&p), &p, "not a readable FITS file");
    }
    let missing = dir.path().join("missing.fits");
    assert!(matches!(read_histograms(&missing), Err(HostError::Io { path, .. }) if path == missing));
    assert!(matches!(read_lut(dir.path()), Err(HostError::NotRegular { kind: "directory", .. })));
}

#[cfg(unix)]
#[test]
fn names_cfitsio_would_parse_are_files_like_any_other() {
    use std::os::unix::ffi::OsStrExt;
    let dir = tempfile::tempdir().unwrap();
    let other = AdcHistograms { bit_depth: 1, counts: vec![vec![7, 8]] };
    let names: [&[u8]; 9] = [
        b"h.fits[1]",
        b"h.fits+1",
        b"h(2).fits",
        b"h.fits(x.fits)",
        b"!h.fits",
        b"-",
        b"stdin",
        b"mem://x",
        b"h\xff.fits",
    ];
    for sub in ["plain", "run[1]", "run(2)", "-"] {
        let d = dir.path().join(sub);
        std::fs::create_dir_all(d.join("mem:")).unwrap();
        // The file cfitsio would read instead for h.fits[1], h.fits+1, ...
        write_histograms(&d.join("h.fits"), &histograms()).unwrap();
        for name in names {
            let file = d.join(std::ffi::OsStr::from_bytes(name));
            write_histograms(&file, &other).unwrap();
            assert_eq!(read_histograms(&file).unwrap(), other, "{}", file.display());
        }
        assert_eq!(read_histograms(&d.join("h.fits")).unwrap(), histograms());
        // Nothing else was made: no temporaries, no files cfitsio made up.
        assert_eq!(std::fs::read_dir(&d).unwrap().count(), names.len() + 1, "{}", d.display());
    }
}

#[test]
fn split_tform_reads_repeat_and_type() {
    assert_eq!(split_tform("D"), (Some(1), Some('D')));
    assert_eq!(split_tform("1D "), (Some(1), Some('D')));
    assert_eq!(split_tform("10A"), (Some(10), Some('A')));
    assert_eq!(split_tform("1PD(5)"), (Some(1), Some('P')));
    assert_eq!(split_tform(""), (Some(1), None));
    assert_eq!(split_tform("99999999999999999999999E"), (None, Some('E')));
}

/// String values as the FITS standard (4.2.1) writes them, each card padded to 80.
#[test]
fn string_cards_read_as_the_standard_defines_them() {
    let card = |text: &str| format!("{text:<80}").into_bytes();
    assert_eq!(string_from_card(&card("XTENSION= 'IMAGE   '           / IMAGE extension")).as_deref(), Some("IMAGE"));
    assert_eq!(string_from_card(&card("EXTNAME = 'O''HARA'")).as_deref(), Some("O'HARA"));
    assert_eq!(string_from_card(&card("EXTNAME = '  lead'")).as_deref(), Some("  lead"));
    assert_eq!(string_from_card(&card("EXTNAME = ''")).as_deref(), Some(""));
    assert_eq!(string_from_card(&card("EXTNAME =    'late start' / still a value")).as_deref(), Some("late start"));
    assert_eq!(string_from_card(&card("EXTNAME = 'a/b' / the slash is inside the quotes")).as_deref(), Some("a/b"));
    // Bytes outside ASCII in the comment do not touch the value.
    let mut odd = card("EXTNAME = 'STD     '           / comment");
    odd[60] = 0xDF;
    assert_eq!(string_from_card(&odd).as_deref(), Some("STD"));
    assert_eq!(printable(b"A\nB\x00C   "), "A?B?C");
    for bad in ["EXTNAME = unquoted", "EXTNAME =YYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYYY", "EXTNAME = 'never closed", "EXTNAME   'no equals'", "SHORT"] {
        assert_eq!(string_from_card(&card(bad)), None, "{bad}");
    }
}

/// The checksums of float images verified as they are read directly
/// ([`reader::FitsReader::open_deferring`], [`direct`]) give cfitsio's own verdict
/// (`ffvcks` at open) on every damaged copy of a linearity file: one bit flipped at every
/// byte of the primary header and every 7th byte of the rest (headers, values and
/// padding alike), the same message or none.
#[test]
fn checksums_verified_while_reading_give_cfitsios_verdicts() {
    use reader::FitsReader;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("l.fits");
    write_linearity(&path, &linearity(true)).unwrap();
    let clean = std::fs::read(&path).unwrap();
    let oracle = |p: &Path| FitsReader::open(p).err().map(|e| e.to_string());
    let ours = |p: &Path| -> Option<String> {
        let run = || -> Result<usize, HostError> {
            // Every float image deferred, however small.
            let mut r = FitsReader::open_with(p, Some(0))?;
            let hdus: Vec<usize> = r.deferred.iter().map(|d| d.hdu).collect();
            for &h in &hdus {
                match r.image(h, "cube", 3) {
                    Ok(image) => drop(r.float_pixels::<f64>(&image)?),
                    // A damaged header: verified without its data read.
                    Err(_) => r.verify_deferred(h)?,
                }
            }
            r.finish()?;
            Ok(hdus.len())
        };
        run().err().map(|e| e.to_string())
    };
    assert_eq!((oracle(&path), ours(&path)), (None, None));
    // Both cubes are deferred on the clean file: the fast path is what is compared.
    let mut r = FitsReader::open_with(&path, Some(0)).unwrap();
    assert_eq!(r.deferred.iter().map(|d| d.hdu).collect::<Vec<_>>(), [0, 1]);
    let image = r.image(0, "cube", 3).unwrap();
    let direct: Vec<f64> = r.float_pixels(&image).unwrap();
    assert_eq!(direct, linearity(true).mean, "the values read directly");
    let (mut failures, mut damaged) = (0, 0);
    let copy = dir.path().join("damaged.fits");
    // Every byte of the primary header (each kind of card: keys, CHECKSUM, DATASUM,
    // END and its blanks), every 7th byte elsewhere.
    for at in (0..2880).chain((2880..clean.len()).step_by(7)) {
        let mut bytes = clean.clone();
        bytes[at] ^= 1 << (at % 8);
        std::fs::write(&copy, &bytes).unwrap();
        // Where cfitsio cannot open the file at all, its status for some damaged cards
        // depends on memory it did not initialize: byte 171 (`NAXIS   = (`...) gave 205
        // ("string missing closing quote") from one call site and 212 ("illegal NAXIS
        // keyword value") from the other, each every time, in a debug build only. Both
        // are the refusal at open: compared as such.
        let at_open = |m: &Option<String>| m.as_ref().map(|m| m.split(": cfitsio ").next().unwrap_or(m).to_string());
        let (want, got) = (oracle(&copy), ours(&copy));
        let unopened = |m: &Option<String>| m.as_ref().is_some_and(|m| m.contains(": not a readable FITS file: cfitsio "));
        if unopened(&want) && unopened(&got) {
            assert_eq!(at_open(&got), at_open(&want), "byte {at} (block {}) flipped", at / 2880);
            damaged += 1;
            continue;
        }
        assert_eq!(got, want, "byte {at} (block {}) flipped", at / 2880);
        damaged += 1;
        failures += usize::from(want.is_some_and(|m| m.contains("fails its checksum")));
    }
    // A flipped value is not seen at open: its check waits for the direct read.
    let mut bytes = clean.clone();
    bytes[2880 + 5] ^= 1;
    std::fs::write(&copy, &bytes).unwrap();
    assert_eq!(FitsReader::open_with(&copy, Some(0)).unwrap().deferred.len(), 2);
    assert!(ours(&copy).is_some_and(|m| m.ends_with(&oracle(&copy).unwrap()[copy.display().to_string().len()..])));
    // Most flips are caught by the checksums (some break the header first).
    assert!(failures * 2 > damaged, "{failures} checksum failures of {damaged}");
}

/// Floats read directly and converted as they are read ([`direct::read_values`]) are
/// cfitsio's, value for value, bit for bit: f64 narrowed to f32 (rounding, overflow to
/// infinity, subnormals, NaN, -0), f32 widened, each as stored.
#[test]
fn floats_read_directly_are_cfitsios_in_every_conversion() {
    use reader::FitsReader;
    let dir = tempfile::tempdir().unwrap();
    let special = [0.0, -0.0, 1.0 / 3.0, -2.5e-8, 1e300, -1e300, 1e-310, 3.4028235677973366e38, f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 16_777_217.0, 0.1];
    let mut x = 0x9e37_79b9_7f4a_7c15u64;
    let mut values: Vec<f64> = special.to_vec();
    values.extend((0..2000).map(|_| {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        f64::from_bits(x)
    }));
    let path = dir.path().join("floats.fits");
    for (stored, data_type) in [(8, ImageType::Double), (4, ImageType::Float)] {
        let mut w = writer::FitsWriter::create(&path, &path, data_type, &[values.len()]).unwrap();
        match stored {
            8 => w.image(&values).unwrap(),
            _ => w.image(&values.iter().map(|&v| v as f32).collect::<Vec<f32>>()).unwrap(),
        }
        w.finish().unwrap();
        let theirs = |r: &mut FitsReader| {
            let image = r.image(0, "image", 1).unwrap();
            (r.pixels::<f32>(&image).unwrap(), r.pixels::<f64>(&image).unwrap())
        };
        let (want32, want64) = theirs(&mut FitsReader::open(&path).unwrap());
        for (as_f32, as_f64) in [(true, false), (false, true)] {
            let mut r = FitsReader::open_with(&path, Some(0)).unwrap();
            assert_eq!(r.deferred.len(), 1, "the image is read directly");
            let image = r.image(0, "image", 1).unwrap();
            let bits32 = |v: &[f32]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
            let bits64 = |v: &[f64]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
            if as_f32 {
                assert_eq!(bits32(&r.float_pixels::<f32>(&image).unwrap()), bits32(&want32), "stored {stored} bytes, read as f32");
            }
            if as_f64 {
                assert_eq!(bits64(&r.float_pixels::<f64>(&image).unwrap()), bits64(&want64), "stored {stored} bytes, read as f64");
            }
            r.finish().unwrap();
        }
    }
}
