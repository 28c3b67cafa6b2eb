//! EMVA 1288 measurement sets: the standard's text descriptor and its images.
//!
//! ## The descriptor
//! One record a line, `#` starts a comment line:
//!
//! ```text
//! v 3.0                      version
//! n 12 640 480               bits per code, width, height (pixels)
//! b 40000.0 120.0            an illuminated level: exposure (ns in release 3.0), photons per pixel
//! i images\b_000_snap_001.png   an image of the level above (Windows separators)
//! d 40000.0                  a dark level: exposure
//! ```
//!
//! Image paths are relative to the descriptor's folder and must stay inside it: absolute
//! paths, `..` escapes and symlinks that resolve outside are rejected after
//! canonicalization, so a descriptor from elsewhere cannot make dncal read arbitrary
//! files. Every malformed line is a [`HostError::DescriptorLine`] naming the descriptor,
//! the line number and the [`DescriptorFault`].
//!
//! A level's frames are a *temporal* series when there are exactly two (a point of the
//! photon-transfer curve) and a *spatial* series when there are more (the many-frame
//! average the nonuniformities are measured on), as the standard and its reference
//! implementation classify them ([`EmvaLevel::series`]).

use std::fs::File;
use std::io::BufReader;
use std::path::{Component, Path, PathBuf};

use rayon::prelude::*;

use crate::HostError;

/// Largest frame accepted, pixels (2^28: 512 MiB of `u16`), so a corrupt `n` line cannot
/// make a caller allocate without bound.
const MAX_PIXELS: usize = 1 << 28;

/// The largest descriptor: 4 MiB is some 80 000 image records of 50 bytes, frames enough
/// for any measured set; a bigger file is not a descriptor.
pub const DESCRIPTOR_LIMIT: crate::formats::input::SizeLimit = crate::formats::input::SizeLimit { what: "EMVA 1288 descriptor", bytes: 4 << 20 };

/// What kind of level a descriptor record is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LevelKind {
    /// Illuminated (`b`): the mean number of photons per pixel during the exposure.
    Bright {
        /// Photons per pixel.
        photons: f64,
    },
    /// Dark (`d`): no illumination.
    Dark,
}

/// One illumination level and its frames.
#[derive(Debug, Clone, PartialEq)]
pub struct EmvaLevel {
    /// Bright with its photons per pixel, or dark.
    pub kind: LevelKind,
    /// Exposure time as written (ns in release 3.0).
    pub exposure: f64,
    /// The frames, canonical paths inside the descriptor's folder.
    pub images: Vec<PathBuf>,
    /// Descriptor line (1-based) of the `b` or `d` record.
    pub line: usize,
    /// Descriptor line of each entry of `images`.
    pub image_lines: Vec<usize>,
}

/// Which of the standard's two kinds of series a level's frames are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Series {
    /// Exactly two frames: a photon-transfer point (mean, and temporal variance from the
    /// difference of the two).
    Temporal,
    /// More than two frames: averaged for the spatial nonuniformities (DSNU, PRNU) and
    /// defect pixels; never a photon-transfer point (its photon count need not match the
    /// temporal levels').
    Spatial,
}

impl EmvaLevel {
    /// The kind of series (levels always have at least one frame; one frame is neither,
    /// and is refused where a series is needed).
    pub fn series(&self) -> Option<Series> {
        match self.images.len() {
            2 => Some(Series::Temporal),
            n if n > 2 => Some(Series::Spatial),
            _ => None,
        }
    }

    /// Photons per pixel, 0 for a dark level.
    pub fn photons(&self) -> f64 {
        match self.kind {
            LevelKind::Bright { photons } => photons,
            LevelKind::Dark => 0.0,
        }
    }
}

/// A parsed descriptor; every image exists, lies inside `path`'s folder and has a
/// grayscale PNG header of `width x height`.
#[derive(Debug, Clone, PartialEq)]
pub struct EmvaSet {
    /// The descriptor, as given.
    pub path: PathBuf,
    /// The `v` record (the standard's release the set was taken for), if any.
    pub version: Option<String>,
    /// Bits per code: every code is below `2^bits`.
    pub bits: u32,
    /// Pixels per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Levels in descriptor order.
    pub levels: Vec<EmvaLevel>,
}

/// A fault at `line` of descriptor `path`.
pub(crate) fn at_line(path: &Path, line: usize, fault: impl Into<DescriptorFault>) -> HostError {
    HostError::DescriptorLine { path: path.to_path_buf(), line, fault: fault.into() }
}

/// The descriptor's folder, canonical: the root every image must stay inside.
fn canonical_folder(descriptor: &Path) -> Result<PathBuf, HostError> {
    let folder = match descriptor.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    folder.canonicalize().map_err(|e| HostError::io(folder, e))
}

/// What is wrong at a line of an EMVA descriptor, or with the set it describes
/// (`HostError::DescriptorLine` adds the descriptor and the line).
#[derive(Debug, thiserror::Error)]
pub enum DescriptorFault {
    /// A record's values or the image it names.
    #[error(transparent)]
    Record(#[from] RecordFault),
    /// A `v` record of other than one token.
    #[error("version record {0:?}: expected one version")]
    Version(String),
    /// A second `n` record, or one after a level.
    #[error("the n record must come once, before any level")]
    HeaderPlace,
    /// A `b` or `d` record before the `n` record.
    #[error("level before the n record")]
    LevelBeforeHeader,
    /// An `i` record before any level.
    #[error("image before any level")]
    ImageBeforeLevel,
    /// An `i` record without a path.
    #[error("image record without a path")]
    ImageWithoutPath,
    /// A tag the format does not have.
    #[error("unknown record {0:?}")]
    Unknown(String),
    /// No `n` record in the file.
    #[error("no n record (bits, width, height)")]
    NoHeader,
    /// A level with no `i` record.
    #[error("level without images")]
    LevelWithoutImages,
    /// An image that resolves outside the descriptor's folder when it is loaded.
    #[error("image {} is outside the descriptor's folder", .0.display())]
    OutsideFolder(PathBuf),
    /// An image whose PNG data do not decode.
    #[error("image {}: {source}", .image.display())]
    Decode {
        /// The image.
        image: PathBuf,
        /// The decoder's error.
        #[source]
        source: png::DecodingError,
    },
    /// A code at or above `2^bits`.
    #[error("image {}: code {code} at pixel ({x}, {y}) does not fit {bits} bits", .image.display())]
    CodeTooLarge {
        /// The image.
        image: PathBuf,
        /// The code.
        code: u16,
        /// Its column.
        x: usize,
        /// Its row.
        y: usize,
        /// The set's bits per code.
        bits: u32,
    },
    /// The spatial series is not one bright and one dark level.
    #[error("the spatial series (levels of more than two frames) must be one bright and one dark level; found {bright} bright, {dark} dark")]
    SpatialLevels {
        /// Bright levels of more than two frames.
        bright: usize,
        /// Dark ones.
        dark: usize,
    },
    /// The spatial series' dark and bright levels differ in exposure.
    #[error("the dark spatial series has exposure {dark}, the bright one {bright}")]
    SpatialExposures {
        /// The dark level's exposure.
        dark: f64,
        /// The bright one's.
        bright: f64,
    },
    /// A photon-transfer level of fewer than two frames.
    #[error("the photon-transfer curve needs two frames per level")]
    PtcFrames,
    /// A level of one frame.
    #[error("a level needs at least two frames (two: a photon-transfer point; more: a spatial series)")]
    SingleFrame,
    /// A second two-frame level of the same exposure and photons.
    #[error("a second two-frame level with exposure {exposure} and {photons} photons (the first at line {first}): one level per exposure and photon count")]
    RepeatedLevel {
        /// Exposure.
        exposure: f64,
        /// Photons.
        photons: f64,
        /// The first level's line.
        first: usize,
    },
    /// A bright level without the dark level of its exposure.
    #[error("no two-frame dark level with exposure {exposure} (nearest {nearest})")]
    NoDark {
        /// The bright level's exposure.
        exposure: f64,
        /// The nearest dark exposure.
        nearest: f64,
    },
    /// No two-frame dark level at all.
    #[error("no two-frame dark levels at all")]
    NoDarks,
}

/// What is wrong with a record's values or the image it names.
#[derive(Debug, thiserror::Error)]
pub enum RecordFault {
    /// Too few or too many numbers.
    #[error("expected {want} numbers, found {found}")]
    Count { want: usize, found: usize },
    /// A token that is not a number.
    #[error("{0:?} is not a number")]
    NotNumber(String),
    /// A number that is negative, infinite or NaN.
    #[error("{0:?} is not a finite number >= 0")]
    NotFinite(String),
    /// The `n` record without its three values.
    #[error("expected bits, width and height, found {0} values")]
    HeaderCount(usize),
    /// A token that is not a whole number.
    #[error("{0:?} is not a whole number")]
    NotWhole(String),
    /// A bit depth outside 1 to 16.
    #[error("{0} bits: 1 to 16 supported")]
    Bits(usize),
    /// A frame that is empty or larger than any image read.
    #[error("frame of {width} x {height} pixels: must be 1 to {MAX_PIXELS} pixels")]
    Frame { width: usize, height: usize },
    /// An image path outside the descriptor's folder or not a file in it: the reason.
    #[error("{0}")]
    ImagePath(String),
    /// An image that is not the PNG the descriptor says: the reason.
    #[error("{0}")]
    Image(String),
}

/// Parses exactly `N` whitespace-separated numbers after the tag, each finite and >= 0.
fn numbers<const N: usize>(rest: &str) -> Result<[f64; N], RecordFault> {
    let tokens: Vec<&str> = rest.split_whitespace().collect();
    if tokens.len() != N {
        return Err(RecordFault::Count { want: N, found: tokens.len() });
    }
    let mut out = [0.0; N];
    for (o, t) in out.iter_mut().zip(&tokens) {
        *o = t.parse::<f64>().map_err(|_| RecordFault::NotNumber(t.to_string()))?;
        if !(o.is_finite() && *o >= 0.0) {
            return Err(RecordFault::NotFinite(t.to_string()));
        }
    }
    Ok(out)
}

/// The `n bits width height` record.
fn header(rest: &str) -> Result<(u32, usize, usize), RecordFault> {
    let tokens: Vec<&str> = rest.split_whitespace().collect();
    let [bits, width, height] = tokens[..] else {
        return Err(RecordFault::HeaderCount(tokens.len()));
    };
    let int = |t: &str| t.parse::<usize>().map_err(|_| RecordFault::NotWhole(t.to_string()));
    let (bits, width, height) = (int(bits)?, int(width)?, int(height)?);
    if !(1..=16).contains(&bits) {
        return Err(RecordFault::Bits(bits));
    }
    if width == 0 || height == 0 || width.checked_mul(height).is_none_or(|p| p > MAX_PIXELS) {
        return Err(RecordFault::Frame { width, height });
    }
    Ok((bits as u32, width, height))
}

/// Resolves an `i` record's path inside `folder` (canonical), or says why not.
fn resolve_image(folder: &Path, written: &str) -> Result<PathBuf, RecordFault> {
    let bad = RecordFault::ImagePath;
    let bytes = written.as_bytes();
    let drive = bytes.len() >= 2 && bytes[0].is_ascii_alphabetic() && bytes[1] == b':';
    if written.starts_with(['/', '\\']) || drive {
        return Err(bad(format!("image path {written:?} is absolute; it must be relative to the descriptor's folder")));
    }
    // Lexical pass: separators of either system, and no `..` above the folder.
    let mut relative = PathBuf::new();
    for part in written.split(['/', '\\']).filter(|p| !p.is_empty() && *p != ".") {
        if part == ".." {
            if !relative.pop() {
                return Err(bad(format!("image path {written:?} escapes the descriptor's folder")));
            }
        } else {
            relative.push(part);
        }
    }
    if relative.components().any(|c| !matches!(c, Component::Normal(_))) || relative.as_os_str().is_empty() {
        return Err(bad(format!("image path {written:?} is not a file name inside the descriptor's folder")));
    }
    // Canonical pass: symlinks resolved, the file must exist and stay inside.
    let canonical = folder.join(&relative).canonicalize().map_err(|e| bad(format!("image {written:?}: {e}")))?;
    if !canonical.starts_with(folder) {
        return Err(bad(format!("image {written:?} resolves to {} outside the descriptor's folder", canonical.display())));
    }
    if !canonical.is_file() {
        return Err(bad(format!("image {written:?} is not a file")));
    }
    Ok(canonical)
}

/// Opens a PNG and checks its header: grayscale, 8 or 16 bits (16 when `bits > 8`),
/// `width x height`. Returns the reader, positioned before the pixels.
fn open_png(image: &Path, bits: u32, width: usize, height: usize) -> Result<png::Reader<BufReader<File>>, RecordFault> {
    let bad = RecordFault::Image;
    // The error names the image itself.
    let file = crate::formats::input::open_regular(image).map_err(|e| bad(format!("image {e}")))?;
    let mut decoder = png::Decoder::new(BufReader::new(file));
    decoder.set_transformations(png::Transformations::IDENTITY);
    let reader = decoder.read_info().map_err(|e| bad(format!("image {}: not a PNG: {e}", image.display())))?;
    let info = reader.info();
    let depth_ok = match info.bit_depth {
        png::BitDepth::Sixteen => true,
        png::BitDepth::Eight => bits <= 8,
        _ => false,
    };
    if info.color_type != png::ColorType::Grayscale || !depth_ok {
        return Err(bad(format!(
            "image {}: {:?} {:?}-bit PNG; {bits}-bit codes need grayscale of {} bits",
            image.display(),
            info.color_type,
            info.bit_depth as u8,
            if bits <= 8 { "8 or 16" } else { "16" }
        )));
    }
    // The decoder's buffer and the codes: 4 bytes per pixel at most.
    crate::infra::budget::check(image, "the image's pixels", crate::infra::budget::bytes_of(u64::from(info.width) * u64::from(info.height), 4)).map_err(|e| bad(e.to_string()))?;
    if (info.width as usize, info.height as usize) != (width, height) {
        return Err(bad(format!(
            "image {} is {} x {} pixels; the descriptor says {width} x {height}",
            image.display(),
            info.width,
            info.height
        )));
    }
    Ok(reader)
}

/// Reads and validates an EMVA 1288 descriptor (module documentation). Every image must
/// exist inside the descriptor's folder with a matching PNG header; codes are checked by
/// [`load_image`].
pub fn read_descriptor(path: &Path) -> Result<EmvaSet, HostError> {
    let text = crate::formats::input::read_text(path, DESCRIPTOR_LIMIT)?;
    // Descriptors are written on Windows, possibly with a byte-order mark.
    let text = text.strip_prefix('\u{feff}').unwrap_or(&text);
    let folder = canonical_folder(path)?;
    let mut header_line: Option<(u32, usize, usize)> = None;
    let mut levels: Vec<EmvaLevel> = Vec::new();
    let mut version = None;
    for (index, raw) in text.lines().enumerate() {
        let line = index + 1;
        let record = raw.trim();
        if record.is_empty() || record.starts_with('#') {
            continue;
        }
        let (tag, rest) = record.split_once(char::is_whitespace).unwrap_or((record, ""));
        let rest = rest.trim();
        let fail = |fault: DescriptorFault| at_line(path, line, fault);
        match tag {
            "v" => {
                if rest.split_whitespace().count() != 1 {
                    return Err(fail(DescriptorFault::Version(record.to_string())));
                }
                version = Some(rest.to_string());
            }
            "n" => {
                if header_line.is_some() || !levels.is_empty() {
                    return Err(fail(DescriptorFault::HeaderPlace));
                }
                header_line = Some(header(rest).map_err(|f| fail(f.into()))?);
            }
            "b" | "d" => {
                if header_line.is_none() {
                    return Err(fail(DescriptorFault::LevelBeforeHeader));
                }
                let (kind, exposure) = if tag == "b" {
                    let [exposure, photons] = numbers::<2>(rest).map_err(|f| fail(f.into()))?;
                    (LevelKind::Bright { photons }, exposure)
                } else {
                    let [exposure] = numbers::<1>(rest).map_err(|f| fail(f.into()))?;
                    (LevelKind::Dark, exposure)
                };
                levels.push(EmvaLevel { kind, exposure, images: Vec::new(), line, image_lines: Vec::new() });
            }
            "i" => {
                let (Some((bits, width, height)), Some(level)) = (header_line, levels.last_mut()) else {
                    return Err(fail(DescriptorFault::ImageBeforeLevel));
                };
                if rest.is_empty() {
                    return Err(fail(DescriptorFault::ImageWithoutPath));
                }
                let image = resolve_image(&folder, rest).map_err(|f| fail(f.into()))?;
                open_png(&image, bits, width, height).map_err(|f| fail(f.into()))?;
                level.images.push(image);
                level.image_lines.push(line);
            }
            other => return Err(fail(DescriptorFault::Unknown(other.to_string()))),
        }
    }
    let Some((bits, width, height)) = header_line else {
        return Err(HostError::DescriptorFile { path: path.to_path_buf(), fault: DescriptorFault::NoHeader });
    };
    if let Some(empty) = levels.iter().find(|l| l.images.is_empty()) {
        return Err(at_line(path, empty.line, DescriptorFault::LevelWithoutImages));
    }
    Ok(EmvaSet { path: path.to_path_buf(), version, bits, width, height, levels })
}

/// Loads one frame of `set` as codes, row-major: checks that `image` lies inside the
/// descriptor's folder (again: files may have changed since [`read_descriptor`]), is a
/// grayscale PNG of the set's size, and that every code is below `2^bits`.
pub fn load_image(set: &EmvaSet, image: &Path) -> Result<Vec<u16>, HostError> {
    let line = set
        .levels
        .iter()
        .flat_map(|l| l.images.iter().zip(&l.image_lines))
        .find(|(p, _)| p.as_path() == image)
        .map(|(_, &line)| line);
    let fail = |fault: DescriptorFault| match line {
        Some(line) => at_line(&set.path, line, fault),
        None => HostError::DescriptorFile { path: image.to_path_buf(), fault },
    };
    let folder = canonical_folder(&set.path)?;
    let canonical = image.canonicalize().map_err(|e| HostError::io(image, e))?;
    if !canonical.starts_with(&folder) {
        return Err(fail(DescriptorFault::OutsideFolder(image.to_path_buf())));
    }
    let mut reader = open_png(&canonical, set.bits, set.width, set.height).map_err(|f| fail(f.into()))?;
    let mut buffer = vec![0u8; reader.output_buffer_size()];
    let frame = reader.next_frame(&mut buffer).map_err(|source| fail(DescriptorFault::Decode { image: image.to_path_buf(), source }))?;
    let pixels = set.width * set.height;
    let codes: Vec<u16> = match frame.bit_depth {
        png::BitDepth::Sixteen => buffer.chunks_exact(2).take(pixels).map(|b| u16::from_be_bytes([b[0], b[1]])).collect(),
        _ => buffer.iter().take(pixels).map(|&b| b as u16).collect(),
    };
    let limit = 1u32 << set.bits;
    if let Some((i, &code)) = codes.iter().enumerate().find(|(_, &c)| c as u32 >= limit) {
        return Err(fail(DescriptorFault::CodeTooLarge { image: image.to_path_buf(), code, x: i % set.width, y: i / set.width, bits: set.bits }));
    }
    Ok(codes)
}

/// The code histograms of the frames of `set`'s levels in two halves, per column class:
/// the levels in photon order (then exposure; dark levels first) go alternately to the
/// first and the second half; within each, column `x` counts in class `x mod classes`
/// (the pixels of one of `classes` interleaved ADCs; 1: all columns). `2^bits` bins each.
/// The data of a code-density test of the camera's ADCs held out by levels
/// (`diagnose::codes`). Every frame is read once, frames in parallel.
pub fn code_histogram_halves(set: &EmvaSet, classes: usize) -> Result<[Vec<Vec<u64>>; 2], HostError> {
    let mut order: Vec<&EmvaLevel> = set.levels.iter().collect();
    order.sort_by(|a, b| a.photons().total_cmp(&b.photons()).then(a.exposure.total_cmp(&b.exposure)));
    let half = |part: usize| -> Vec<&EmvaLevel> { order.iter().skip(part).step_by(2).copied().collect() };
    Ok([code_histograms(set, &half(0), classes)?, code_histograms(set, &half(1), classes)?])
}

/// The code histograms of every frame of `levels` of `set`, one per column class `x mod
/// classes`, `2^bits` bins (see [`code_histogram_halves`]). Frames are loaded in parallel.
pub fn code_histograms(set: &EmvaSet, levels: &[&EmvaLevel], classes: usize) -> Result<Vec<Vec<u64>>, HostError> {
    let (width, classes) = (set.width, classes.max(1));
    let images: Vec<&PathBuf> = levels.iter().flat_map(|l| l.images.iter()).collect();
    let bins = 1usize << set.bits;
    let empty = || vec![vec![0u64; bins]; classes];
    images
        .par_iter()
        .map(|image| {
            let mut h = empty();
            for (i, c) in load_image(set, image)?.into_iter().enumerate() {
                h[(i % width) % classes][c as usize] += 1;
            }
            Ok(h)
        })
        .try_reduce(empty, |mut a, b| {
            for (x, y) in a.iter_mut().zip(&b) {
                x.iter_mut().zip(y).for_each(|(x, y)| *x += y);
            }
            Ok(a)
        })
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// The real set (Basler, CC BY-SA 3.0) is read from the shared data folder beside the
    /// repository, never copied into it; `DNCAL_EMVA_DIR` overrides the folder.
    /// The real CCD's descriptor in ../shared (`DNCAL_EMVA_DIR` overrides the folder), or
    /// `None` after one line saying the test skips, where it is absent.
    pub(crate) fn real_descriptor() -> Option<PathBuf> {
        let d = std::env::var_os("DNCAL_EMVA_DIR")
            .map(PathBuf::from)
            .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/emva1288-ccd-12bit"))
            .join("EMVA1288_Data.txt");
        if d.is_file() {
            Some(d)
        } else {
            eprintln!("skipping: {} is absent", d.display());
            None
        }
    }

    #[test]
    fn parses_the_real_set() {
        let Some(real) = real_descriptor() else { return };
        let set = read_descriptor(&real).unwrap();
        assert_eq!((set.bits, set.width, set.height), (12, 640, 480));
        let bright = set.levels.iter().filter(|l| matches!(l.kind, LevelKind::Bright { .. })).count();
        let dark = set.levels.iter().filter(|l| l.kind == LevelKind::Dark).count();
        assert_eq!((bright, dark), (51, 51));
        let mut frames: Vec<usize> = set.levels.iter().map(|l| l.images.len()).collect();
        frames.sort_unstable();
        assert_eq!(frames[..100], [2; 100]);
        assert_eq!(frames[100..], [50, 50], "the spatial sets: one bright, one dark level");
        let first = &set.levels[0];
        assert_eq!((first.kind, first.exposure, first.line), (LevelKind::Bright { photons: 120.0 }, 40000.0, 18));
        assert!(first.images[0].ends_with("images/b_000_snap_001.png"));
        let codes = load_image(&set, &first.images[0]).unwrap();
        assert_eq!(codes.len(), 640 * 480);
        assert!(codes.iter().all(|&c| c < 4096));
    }

    /// A 16-bit grayscale PNG of `codes`, row-major.
    pub(crate) fn write_png(path: &Path, width: u32, height: u32, codes: &[u16]) {
        let file = File::create(path).unwrap();
        let mut encoder = png::Encoder::new(std::io::BufWriter::new(file), width, height);
        encoder.set_color(png::ColorType::Grayscale);
        encoder.set_depth(png::BitDepth::Sixteen);
        let bytes: Vec<u8> = codes.iter().flat_map(|c| c.to_be_bytes()).collect();
        encoder.write_header().unwrap().write_image_data(&bytes).unwrap();
    }

    /// A folder `set/` with 4 x 3 images `images/a.png` (codes 0..12) and `images/b.png`
    /// (all 1), a 5 x 3 `images/wide.png`, and `outside.png` beside the folder.
    pub(crate) fn scratch() -> (tempfile::TempDir, PathBuf) {
        let dir = tempfile::tempdir().unwrap();
        let set = dir.path().join("set");
        std::fs::create_dir_all(set.join("images")).unwrap();
        write_png(&set.join("images/a.png"), 4, 3, &(0..12).collect::<Vec<u16>>());
        write_png(&set.join("images/b.png"), 4, 3, &[1; 12]);
        write_png(&set.join("images/wide.png"), 5, 3, &[1; 15]);
        write_png(&dir.path().join("outside.png"), 4, 3, &[1; 12]);
        (dir, set)
    }

    /// Writes `text` as the descriptor of `set` and reads it.
    pub(crate) fn read_text(set: &Path, text: &str) -> (PathBuf, Result<EmvaSet, HostError>) {
        let descriptor = set.join("EMVA1288_Data.txt");
        std::fs::write(&descriptor, text).unwrap();
        let result = read_descriptor(&descriptor);
        (descriptor, result)
    }

    /// `result` must be a format error naming `descriptor`, `line line:` and `words`.
    pub(crate) fn assert_format_error<T: std::fmt::Debug>(descriptor: &Path, result: Result<T, HostError>, line: usize, words: &str) {
        match result {
            Err(HostError::DescriptorLine { path, line: at, fault }) => {
                assert_eq!(path, descriptor);
                assert_eq!(at, line, "{fault}");
                let message = fault.to_string();
                assert!(message.contains(words), "{message:?} should mention {words:?}");
            }
            other => panic!("expected a format error at line {line}, got {other:?}"),
        }
    }

    pub(crate) const HEAD: &str = "\u{feff}# test\r\nv 3.0\r\nn 12 4 3\r\n";

    #[test]
    fn a_small_descriptor_parses_with_windows_separators() {
        let (_dir, set) = scratch();
        let body = "b 10 5.5\r\ni images\\a.png\r\ni images/./b.png\r\n\
                    d 10\r\ni images\\..\\images\\b.png\r\ni images\\a.png\r\n";
        let (_, result) = read_text(&set, &format!("{HEAD}{body}"));
        let parsed = result.unwrap();
        assert_eq!(parsed.levels.len(), 2);
        assert_eq!(parsed.levels[0].kind, LevelKind::Bright { photons: 5.5 });
        assert_eq!(parsed.levels[0].image_lines, vec![5, 6]);
        assert_eq!(parsed.levels[1].images[0], set.join("images/b.png").canonicalize().unwrap());
        assert_eq!(load_image(&parsed, &parsed.levels[0].images[0]).unwrap(), (0..12).collect::<Vec<u16>>());
    }

    #[test]
    fn image_paths_cannot_leave_the_folder() {
        let (dir, set) = scratch();
        for (record, words) in [
            ("i ..\\outside.png", "escapes"),
            ("i images\\..\\..\\outside.png", "escapes"),
            ("i /etc/passwd", "absolute"),
            ("i \\outside.png", "absolute"),
            ("i C:\\images\\a.png", "absolute"),
        ] {
            let (descriptor, result) = read_text(&set, &format!("{HEAD}b 10 5\n{record}\n"));
            assert_format_error(&descriptor, result, 5, words);
        }
        #[cfg(unix)]
        {
            std::os::unix::fs::symlink(dir.path().join("outside.png"), set.join("images/link.png")).unwrap();
            std::os::unix::fs::symlink(dir.path(), set.join("images/up")).unwrap();
            for record in ["i images\\link.png", "i images\\up\\outside.png"] {
                let (descriptor, result) = read_text(&set, &format!("{HEAD}b 10 5\n{record}\n"));
                assert_format_error(&descriptor, result, 5, "outside the descriptor's folder");
            }
            // load_image checks again: a listed path swapped for a symlink afterwards.
            let (_, parsed) = read_text(&set, &format!("{HEAD}b 10 5\ni images\\b.png\n"));
            let parsed = parsed.unwrap();
            std::fs::remove_file(set.join("images/b.png")).unwrap();
            std::os::unix::fs::symlink(dir.path().join("outside.png"), set.join("images/b.png")).unwrap();
            assert_format_error(&parsed.path, load_image(&parsed, &parsed.levels[0].images[0]), 5, "outside");
        }
    }

    #[test]
    fn malformed_lines_are_errors_naming_the_line() {
        let (_dir, set) = scratch();
        let cases = [
            ("b abc 1.0\ni images\\a.png", 4, "not a number"),
            ("b NaN 1.0\ni images\\a.png", 4, "finite"),
            ("b 10 -1\ni images\\a.png", 4, "finite"),
            ("b 10\ni images\\a.png", 4, "expected 2 numbers"),
            ("b 10 1 2\ni images\\a.png", 4, "expected 2 numbers"),
            ("d\ni images\\a.png", 4, "expected 1 numbers"),
            ("x 10\ni images\\a.png", 4, "unknown record"),
            ("i images\\a.png", 4, "before any level"),
            ("b 10 5\ni images\\missing.png", 5, "missing.png"),
            ("b 10 5\ni images\\wide.png", 5, "5 x 3"),
            ("b 10 5\ni", 5, "without a path"),
            ("b 10 5\ni images", 5, "not a file"),
            ("b 10 5\ni images\\a.png\nn 12 4 3", 6, "before any level"),
            ("b 10 5\nd 10\ni images\\a.png", 4, "without images"),
        ];
        for (body, line, words) in cases {
            let (descriptor, result) = read_text(&set, &format!("{HEAD}{body}\n"));
            assert_format_error(&descriptor, result, line, words);
        }
        let headers = [("n 12 4", "expected bits"), ("n 17 4 3", "17 bits"), ("n 12 0 3", "0 x 3"), ("n 12 4.5 3", "whole")];
        for (header, words) in headers {
            let (descriptor, result) = read_text(&set, &format!("v 3.0\n{header}\n"));
            assert_format_error(&descriptor, result, 2, words);
        }
        let (descriptor, result) = read_text(&set, "v 3.0\n");
        assert!(matches!(result, Err(HostError::DescriptorFile { path, fault: DescriptorFault::NoHeader }) if path == descriptor));
        assert!(matches!(read_descriptor(&set.join("nothing.txt")), Err(HostError::Io { .. })));
    }

    #[test]
    fn codes_above_the_bit_depth_are_errors() {
        let (_dir, set) = scratch();
        let (descriptor, parsed) = read_text(&set, "n 3 4 3\nb 10 5\ni images\\a.png\n");
        let parsed = parsed.unwrap();
        assert_format_error(&descriptor, load_image(&parsed, &parsed.levels[0].images[0]), 3, "code 8 at pixel (0, 2)");
    }
}
