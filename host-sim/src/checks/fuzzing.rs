//! Entry points of the fuzz targets (`fuzz/`, issue 18), shared with the corpus replay
//! test (`tests/fuzz_corpus.rs`) so that both run the same code. Not an API.
//!
//! Each takes the fuzzer's bytes, writes them where the reader expects a file (a fresh
//! temporary directory, under `TMPDIR`), and calls the reader as the commands do. A
//! reader may refuse anything with an `Err`; it must never panic. Where a reader accepts,
//! the target also checks what must then hold:
//!
//! - `fits_histograms`: the analysis reader accepts only what the plain one does, and a
//!   set that was read writes and reads back unchanged;
//! - `fits_linearity`: the `f32` reader accepts only what the `f64` one does, and a set
//!   read writes and reads back unchanged;
//! - `fits_lut`: `lut inspect` (which also takes device images) never panics, and a LUT's
//!   `WEIGHTS` go through the core's table builder;
//! - `emva_descriptor`: every frame of an accepted set loads (or is refused) and its codes
//!   fit the set's bits, and the code histograms of the set are computed;
//! - `camera_toml`: an accepted config validates, serializes and parses back equal, and
//!   builds the camera model (on at most 64 x 64 pixels: the sensor size is bounded by
//!   validation and costs only memory).
//!
//! - `analysis_linearity`, `analysis_histograms`, `analysis_lut` (issue 43): what the
//!   reader accepts goes on through the analyses that read it, with their figures and
//!   files (`linearity`, `diagnose`, `lut build`, `lut inspect`, `kcor-model --lut`): no
//!   panic, an error of one line, and no report text showing a non-finite number as a
//!   result ([`non_finite_word`]).
//!
//! The EMVA input is several files in one: the descriptor, then each image after a line
//! [`EMVA_FILE_SEPARATOR`]; the images are written as `f1.png`, `f2.png`, ... beside the
//! descriptor, which names them in its `i` records.

use std::path::{Path, PathBuf};

use crate::model::camera::{Camera, CameraConfig};
use crate::analyses::emva::{code_histogram_halves, load_image, read_descriptor};
use crate::formats::fits;

/// Separates the files of an `emva_descriptor` input.
pub const EMVA_FILE_SEPARATOR: &[u8] = b"\n--8<--\n";

/// The largest frame whose images the EMVA target loads, pixels: larger ones (up to the
/// descriptor's limit of 2^28) only cost memory and time.
const EMVA_MAX_LOADED_PIXELS: usize = 1 << 20;

/// A fresh directory for one input; removed when dropped.
fn scratch() -> tempfile::TempDir {
    tempfile::Builder::new().prefix("dncal-fuzz").tempdir().expect("a temporary directory")
}

/// `bytes` as the file `name` in `dir`.
fn write_input(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, bytes).expect("writing the fuzz input");
    path
}

/// The `fits_histograms` target; whether the reader accepted the input (so do the others).
pub fn fits_histograms(bytes: &[u8]) -> bool {
    let dir = scratch();
    let path = write_input(dir.path(), "histograms.fits", bytes);
    let read = fits::read_histograms(&path);
    if let Ok(for_analysis) = fits::read_histograms_for_analysis(&path) {
        assert_eq!(read.as_ref().ok(), Some(&for_analysis), "the analysis reader accepted what the plain one refused");
    }
    let Ok(set) = read else { return false };
    let out = dir.path().join("written.fits");
    if fits::write_histograms(&out, &set).is_ok() {
        assert_eq!(fits::read_histograms(&out).expect("a written set reads back"), set);
    }
    true
}

/// The `fits_linearity` target.
pub fn fits_linearity(bytes: &[u8]) -> bool {
    let dir = scratch();
    let path = write_input(dir.path(), "linearity.fits", bytes);
    let read = fits::read_linearity(&path);
    let narrow = fits::read_linearity_as::<f32>(&path);
    if narrow.is_ok() {
        assert!(read.is_ok(), "the f32 reader accepted what the f64 one refused: {:?}", read.err());
    }
    by_rows_agrees(&path, &narrow);
    let Ok(set) = read else { return false };
    let out = dir.path().join("written.fits");
    fits::write_linearity(&out, &set).expect("a set that was read can be written");
    assert_eq!(fits::read_linearity(&out).expect("a written set reads back"), set);
    true
}

/// A set opened to be read by rows (`diagnose` beyond its budget) is refused as the f32
/// whole read refuses it, word for word, or accepted with the same values row by row.
fn by_rows_agrees(path: &Path, narrow: &Result<fits::LinearitySet<f32>, crate::HostError>) {
    let rows = match fits::open_linearity_rows(path) {
        Ok(None) => return,
        Ok(Some(o)) => o.check::<f32>(),
        Err(e) => Err(e),
    };
    match (&rows, narrow) {
        (Err(a), Err(b)) => assert_eq!(a.to_string(), b.to_string(), "the readers refuse differently"),
        (Ok(r), Ok(set)) => {
            let (mut mean, mut std, mut bytes) = (Vec::new(), Vec::new(), Vec::new());
            let plane = set.width * set.height;
            for row in 0..set.height {
                r.read_rows(row..row + 1, &mut mean, &mut std, &mut bytes).expect("rows of a checked set read");
                for l in 0..set.levels {
                    let at = l * plane + row * set.width;
                    let same = |a: &[f32], b: &[f32]| a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits());
                    assert!(same(&mean[l * set.width..][..set.width], &set.mean[at..][..set.width]) && same(&std[l * set.width..][..set.width], &set.std[at..][..set.width]), "row {row}, level {l} read by rows differs");
                }
            }
        }
        (a, b) => panic!("one reader accepts, the other refuses: by rows {:?}, whole {:?}", a.as_ref().err(), b.as_ref().err()),
    }
}

/// The `fits_lut` target.
pub fn fits_lut(bytes: &[u8]) -> bool {
    let dir = scratch();
    let path = write_input(dir.path(), "lut.fits", bytes);
    let read = fits::read_lut(&path);
    if let Ok(lut) = &read {
        if let Some(raw) = &lut.weights {
            let weights: Vec<Vec<dncal_core::Weight>> =
                raw.iter().map(|w| w.iter().map(|&b| dncal_core::Weight::from_bits(b)).collect()).collect();
            let _ = crate::formats::lut::tables_from_weights(&weights, &path.as_path().into());
        }
    }
    // The LUT home's reader also takes device images and K-Cor tables, and refuses
    // tables the core would not load; what it reads it can write in every format.
    let home = crate::formats::lut::read(&path);
    if let Ok((_, lut)) = &home {
        for format in crate::formats::lut::LutFormat::ALL {
            if let Ok(paths) = crate::formats::lut::output_paths(format, &dir.path().join("out")) {
                let mut files = crate::formats::outputs::Outputs::new();
                let _ = crate::formats::lut::write(&mut files, lut, format, &paths, None, &path);
            }
        }
    }
    read.is_ok() || home.is_ok()
}

/// The `emva_descriptor` target.
pub fn emva_descriptor(bytes: &[u8]) -> bool {
    let dir = scratch();
    let mut parts = split(bytes, EMVA_FILE_SEPARATOR);
    let descriptor = write_input(dir.path(), "EMVA1288_Data.txt", parts.next().unwrap_or_default());
    for (k, image) in parts.enumerate() {
        write_input(dir.path(), &format!("f{}.png", k + 1), image);
    }
    let Ok(set) = read_descriptor(&descriptor) else { return false };
    if set.width * set.height > EMVA_MAX_LOADED_PIXELS {
        return true;
    }
    let mut all_loaded = true;
    for image in set.levels.iter().flat_map(|l| &l.images) {
        match load_image(&set, image) {
            Ok(codes) => {
                assert_eq!(codes.len(), set.width * set.height, "{}", image.display());
                assert!(codes.iter().all(|&c| u32::from(c) < 1 << set.bits), "a code above 2^bits - 1 was loaded");
            }
            Err(_) => all_loaded = false,
        }
    }
    let halves = code_histogram_halves(&set, 4);
    if all_loaded {
        let [a, b] = halves.expect("frames that load make histograms");
        let frames = set.levels.iter().map(|l| l.images.len()).sum::<usize>();
        let counted: u64 = a.iter().chain(&b).flatten().sum();
        assert_eq!(counted, (frames * set.width * set.height) as u64, "every pixel of every frame is counted once");
    }
    true
}

/// The parts of `bytes` between separators.
fn split<'a>(bytes: &'a [u8], separator: &'a [u8]) -> impl Iterator<Item = &'a [u8]> {
    let mut rest = Some(bytes);
    std::iter::from_fn(move || {
        let r = rest?;
        match r.windows(separator.len()).position(|w| w == separator) {
            Some(at) => {
                rest = Some(&r[at + separator.len()..]);
                Some(&r[..at])
            }
            None => {
                rest = None;
                Some(r)
            }
        }
    })
}

/// The `camera_toml` target.
pub fn camera_toml(bytes: &[u8]) -> bool {
    let dir = scratch();
    let path = write_input(dir.path(), "camera.toml", bytes);
    let Ok(mut config) = CameraConfig::from_toml_file(&path) else { return false };
    assert_eq!(config.validate(), Ok(()), "an accepted config does not validate");
    if let Ok(text) = toml::to_string(&config) {
        let back: CameraConfig = toml::from_str(&text).unwrap_or_else(|e| panic!("a written config does not parse: {e}\n{text}"));
        assert_eq!(back, config, "a config changed through TOML");
    }
    config.width = config.width.min(64);
    config.height = config.height.min(64);
    // Twelve 16-bit ADCs at most, as the config's size limit allows for measured widths.
    if config.n_adc << config.bits <= 12 << 16 {
        let _ = Camera::new(config);
    }
    true
}

/// Where a report's text shows a number that is not one (`NaN`, `inf`, `-inf`, also as a
/// ratio `infx` or a percentage): the word, if any. A report prints results, and a
/// non-finite value is no result (issue 43: "infx less", a perfect correction of zeros).
pub fn non_finite_word(text: &str) -> Option<String> {
    text.split_whitespace()
        .map(|w| w.trim_matches(|c: char| ",;:()[]{}'\"".contains(c)))
        .find(|w| {
            let number = w.trim_end_matches(['x', '%']);
            number.parse::<f64>().is_ok_and(|v| !v.is_finite())
        })
        .map(String::from)
}

/// Panics with `what` if `text` shows a non-finite number ([`non_finite_word`]).
fn assert_finite_text(what: &str, text: &str) {
    if let Some(w) = non_finite_word(text) {
        panic!("{what} printed {w:?} as a result:\n{text}");
    }
}

/// Most values (pixels x levels, or codes) an analysis target runs its analyses on: the
/// formats bound a file's declarations by its bytes, the analyses' time is the fuzzer's.
const ANALYSIS_MAX_VALUES: usize = 1 << 16;

/// The `analysis_linearity` target (issue 43): a linearity set the reader accepts goes
/// through `linearity` with its figures and FITS outputs (and the held-out orders), and,
/// where small, through `diagnose` with its report: never a panic, and every report's
/// text without a non-finite number; an error is one line naming the file.
pub fn analysis_linearity(bytes: &[u8]) -> bool {
    let dir = scratch();
    let path = write_input(dir.path(), "linearity.fits", bytes);
    let Ok(set) = fits::read_linearity(&path) else { return false };
    if set.width * set.height * set.levels > ANALYSIS_MAX_VALUES {
        return true;
    }
    let out = dir.path().join("linearity");
    match crate::formats::outputs::staged(Some(&out), |o| crate::analyses::linearity::run::linearity(&path, 4, None, &[3, 4], o)) {
        Ok(s) => {
            use crate::formats::report::Report;
            let r = &s.report;
            for (name, v) in [("rms_raw_max", r.rms_raw_max), ("rms_standard_max", r.rms_standard_max), ("rms_pixelwise_max", r.rms_pixelwise_max), ("rms_random_max", r.rms_random_max), ("paper_fig8.distance", s.paper_fig8.distance)] {
                assert!(v.is_finite(), "linearity reported {name} = {v}");
            }
            assert_finite_text("linearity", &s.text());
        }
        Err(e) => assert_one_line(&e),
    }
    if set.width * set.height <= 256 {
        let params = crate::analyses::diagnose::run::DiagnoseParams { flatten: Default::default(), seed: 1, block_rows: None, spill: false };
        let out = dir.path().join("diagnose");
        match crate::formats::outputs::staged(Some(&out), |o| crate::analyses::diagnose::run::diagnose(&path, &params, o)) {
            Ok(s) => {
                use crate::formats::report::Report;
                assert_finite_text("diagnose", &s.text());
            }
            Err(e) => assert_one_line(&e),
        }
    }
    true
}

/// The `analysis_histograms` target (issue 43): a histogram set the analysis reader
/// accepts goes through `lut build` (the LUT files and the IEEE 1241 test) and `diagnose`
/// with its report and figures.
pub fn analysis_histograms(bytes: &[u8]) -> bool {
    let dir = scratch();
    let path = write_input(dir.path(), "histograms.fits", bytes);
    let Ok(set) = fits::read_histograms_for_analysis(&path) else { return false };
    if set.counts.iter().map(Vec::len).sum::<usize>() > ANALYSIS_MAX_VALUES {
        return true;
    }
    use crate::formats::report::Report;
    match crate::analyses::lut::run::build(&path, &dir.path().join("cal"), &Default::default(), None) {
        Ok(s) => assert_finite_text("lut build", &s.text()),
        Err(e) => assert_one_line(&e),
    }
    let params = crate::analyses::diagnose::run::DiagnoseParams { flatten: Default::default(), seed: 1, block_rows: None, spill: false };
    match crate::formats::outputs::staged(Some(&dir.path().join("diagnose")), |o| crate::analyses::diagnose::run::diagnose(&path, &params, o)) {
        Ok(s) => assert_finite_text("diagnose", &s.text()),
        Err(e) => assert_one_line(&e),
    }
    true
}

/// The `analysis_lut` target (issue 43): a LUT (any format) the reader accepts goes
/// through `lut inspect` and `kcor-model --lut` with its two maps.
pub fn analysis_lut(bytes: &[u8]) -> bool {
    use crate::formats::report::Report;
    let dir = scratch();
    let path = write_input(dir.path(), "lut.fits", bytes);
    let Ok(inspected) = crate::formats::lut::inspect::inspect(&path) else { return false };
    assert_finite_text("lut inspect", &inspected.text());
    static CAMERA: std::sync::OnceLock<Camera> = std::sync::OnceLock::new();
    let camera = CAMERA.get_or_init(|| Camera::new(CameraConfig { width: 16, height: 16, ..CameraConfig::default() }).expect("the default camera on 16 x 16 pixels"));
    let adc = inspected.adcs.len().saturating_sub(1).min(camera.adcs.len() - 1);
    let p = crate::analyses::kcor::KcorParams { adc, steps: 8, ..Default::default() };
    match crate::formats::outputs::staged(Some(&dir.path().join("kcor")), |o| crate::analyses::kcor::run::kcor_model(camera, &p, Some(&path), 1, o)) {
        Ok(s) => assert_finite_text("kcor-model", &s.text()),
        Err(e) => assert_one_line(&e),
    }
    true
}

/// An error is one line (the commands print it after `dncal: error: `).
fn assert_one_line(e: &crate::HostError) {
    let m = e.to_string();
    assert!(!m.is_empty() && !m.contains('\n'), "an error of more or less than one line: {m:?}");
}
