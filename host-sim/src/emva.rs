//! EMVA 1288 measurement sets: the standard's text descriptor, its images, and the
//! photon-transfer curve (PTC) they give.
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
//! files. Every malformed line is a [`HostError::Format`] naming the descriptor and the
//! line number.
//!
//! ## The photon-transfer curve
//! For each illuminated level paired with the dark level of the same exposure, from the
//! first two frames `A`, `B` of each (N pixels; the standard's photon-transfer method):
//!
//! ```text
//! mean_dn = (mean A + mean B)/2 - (mean A_dark + mean B_dark)/2
//! var_dn2 = var(A - B) / 2,  var(x) = (1/N) sum (x - mean x)^2
//! ```
//!
//! The difference of two frames cancels all fixed-pattern noise, so `var_dn2` is temporal
//! noise only; the standard's linear model gives `var_dn2 - dark_var_dn2 = K mean_dn`
//! (`K` the system gain in DN per electron) and `mean_dn = K eta photons` (`eta` the
//! quantum efficiency).

use std::fs::File;
use std::io::BufReader;
use std::path::{Component, Path, PathBuf};

use rayon::prelude::*;

use crate::HostError;
use serde::Serialize;

/// Largest frame accepted, pixels (2^28: 512 MiB of `u16`), so a corrupt `n` line cannot
/// make a caller allocate without bound.
const MAX_PIXELS: usize = 1 << 28;

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

/// A parsed descriptor; every image exists, lies inside `path`'s folder and has a
/// grayscale PNG header of `width x height`.
#[derive(Debug, Clone, PartialEq)]
pub struct EmvaSet {
    /// The descriptor, as given.
    pub path: PathBuf,
    /// Bits per code: every code is below `2^bits`.
    pub bits: u32,
    /// Pixels per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Levels in descriptor order.
    pub levels: Vec<EmvaLevel>,
}

/// One point of the photon-transfer curve: an illuminated level and its dark level.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PtcPoint {
    /// Descriptor line of the illuminated level.
    pub line: usize,
    /// Descriptor line of the dark level used.
    pub dark_line: usize,
    /// Exposure time as written.
    pub exposure: f64,
    /// Photons per pixel.
    pub photons: f64,
    /// Mean signal above dark, DN.
    pub mean_dn: f64,
    /// Temporal variance of the illuminated frames, DN^2.
    pub var_dn2: f64,
    /// Mean of the dark frames, DN.
    pub dark_mean_dn: f64,
    /// Temporal variance of the dark frames, DN^2.
    pub dark_var_dn2: f64,
    /// Mean of the first illuminated frame minus the second, DN: frame-to-frame changes
    /// (light source, exposure, offset) that the variance of the difference removes.
    pub frame_diff_dn: f64,
    /// The same for the dark pair, DN.
    pub dark_frame_diff_dn: f64,
}

/// The photon-transfer characterization of a measured set (EMVA 1288 section 6 methods).
#[derive(Debug, Clone, Serialize)]
pub struct PtcSummary {
    /// Illuminated levels used.
    pub levels: usize,
    /// Saturation: the level of largest temporal variance (EMVA 1288), mean above dark, DN.
    pub saturation_dn: f64,
    /// Photons per pixel at saturation.
    pub saturation_photons: f64,
    /// Responsivity, DN per photon, from the levels below half the saturation photons.
    pub responsivity_dn_per_photon: f64,
    /// R^2 of that line.
    pub linearity_r2: f64,
    /// Overall system gain K, DN per electron: slope of (variance - dark variance) against
    /// mean above dark, over the levels up to 70% of saturation.
    pub gain_dn_per_e: f64,
    /// R^2 of that line.
    pub gain_r2: f64,
    /// Conversion gain the paper's way, electrons per DN (1/K).
    pub gain_e_per_dn: f64,
    /// Quantum efficiency, responsivity / K.
    pub quantum_efficiency: f64,
    /// Temporal dark noise, DN (at the shortest exposure's dark level).
    pub dark_noise_dn: f64,
    /// The same in electrons.
    pub dark_noise_e: f64,
}

/// Least-squares line `y = a + b x`: (a, b, R^2).
pub fn fit_line(x: &[f64], y: &[f64]) -> (f64, f64, f64) {
    let n = x.len() as f64;
    let (mx, my) = (x.iter().sum::<f64>() / n, y.iter().sum::<f64>() / n);
    let sxy: f64 = x.iter().zip(y).map(|(a, b)| (a - mx) * (b - my)).sum();
    let sxx: f64 = x.iter().map(|a| (a - mx) * (a - mx)).sum();
    let syy: f64 = y.iter().map(|b| (b - my) * (b - my)).sum();
    let slope = sxy / sxx;
    (my - slope * mx, slope, sxy * sxy / (sxx * syy))
}

/// Gain, responsivity, QE, dark noise and saturation from photon-transfer points. Needs
/// at least two levels below half saturation and two up to 70% of it: otherwise an error
/// naming `path`.
pub fn summarize(path: &Path, ptc: &[PtcPoint]) -> Result<PtcSummary, HostError> {
    let mut ptc = ptc.to_vec();
    ptc.sort_by(|a, b| a.photons.total_cmp(&b.photons));
    let too_few = |what: &str| HostError::Format { path: path.to_path_buf(), message: format!("too few illuminated levels for {what}") };
    let sat = (0..ptc.len()).max_by(|&a, &b| ptc[a].var_dn2.total_cmp(&ptc[b].var_dn2)).ok_or_else(|| too_few("a photon-transfer curve"))?;
    let (saturation_dn, saturation_photons) = (ptc[sat].mean_dn, ptc[sat].photons);
    let low: Vec<&PtcPoint> = ptc.iter().filter(|p| p.photons <= 0.5 * saturation_photons).collect();
    if low.len() < 2 {
        return Err(too_few("the linearity fit (two below half saturation)"));
    }
    let (x, y): (Vec<f64>, Vec<f64>) = low.iter().map(|p| (p.photons, p.mean_dn)).unzip();
    let (_, responsivity, linearity_r2) = fit_line(&x, &y);
    let gain_points: Vec<&PtcPoint> = ptc.iter().filter(|p| p.mean_dn <= 0.7 * saturation_dn).collect();
    if gain_points.len() < 2 {
        return Err(too_few("the gain fit (two up to 70% of saturation)"));
    }
    let (gx, gy): (Vec<f64>, Vec<f64>) = gain_points.iter().map(|p| (p.mean_dn, p.var_dn2 - p.dark_var_dn2)).unzip();
    let (_, gain, gain_r2) = fit_line(&gx, &gy);
    let shortest = ptc.iter().min_by(|a, b| a.exposure.total_cmp(&b.exposure)).ok_or_else(|| too_few("dark noise"))?;
    let dark_noise_dn = shortest.dark_var_dn2.sqrt();
    Ok(PtcSummary {
        levels: ptc.len(),
        saturation_dn,
        saturation_photons,
        responsivity_dn_per_photon: responsivity,
        linearity_r2,
        gain_dn_per_e: gain,
        gain_r2,
        gain_e_per_dn: 1.0 / gain,
        quantum_efficiency: responsivity / gain,
        dark_noise_dn,
        dark_noise_e: dark_noise_dn / gain,
    })
}

/// A format error at `line` of descriptor `path`.
fn at_line(path: &Path, line: usize, message: impl std::fmt::Display) -> HostError {
    HostError::Format { path: path.to_path_buf(), message: format!("line {line}: {message}") }
}

/// The descriptor's folder, canonical: the root every image must stay inside.
fn canonical_folder(descriptor: &Path) -> Result<PathBuf, HostError> {
    let folder = match descriptor.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    folder.canonicalize().map_err(|e| HostError::io(folder, e))
}

/// Parses exactly `N` whitespace-separated numbers after the tag, each finite and >= 0.
fn numbers<const N: usize>(rest: &str) -> Result<[f64; N], String> {
    let tokens: Vec<&str> = rest.split_whitespace().collect();
    if tokens.len() != N {
        return Err(format!("expected {N} numbers, found {}", tokens.len()));
    }
    let mut out = [0.0; N];
    for (o, t) in out.iter_mut().zip(&tokens) {
        *o = t.parse::<f64>().map_err(|_| format!("{t:?} is not a number"))?;
        if !(o.is_finite() && *o >= 0.0) {
            return Err(format!("{t:?} is not a finite number >= 0"));
        }
    }
    Ok(out)
}

/// The `n bits width height` record.
fn header(rest: &str) -> Result<(u32, usize, usize), String> {
    let tokens: Vec<&str> = rest.split_whitespace().collect();
    let [bits, width, height] = tokens[..] else {
        return Err(format!("expected bits, width and height, found {} values", tokens.len()));
    };
    let int = |t: &str| t.parse::<usize>().map_err(|_| format!("{t:?} is not a whole number"));
    let (bits, width, height) = (int(bits)?, int(width)?, int(height)?);
    if !(1..=16).contains(&bits) {
        return Err(format!("{bits} bits: 1 to 16 supported"));
    }
    if width == 0 || height == 0 || width.checked_mul(height).is_none_or(|p| p > MAX_PIXELS) {
        return Err(format!("frame of {width} x {height} pixels: must be 1 to {MAX_PIXELS} pixels"));
    }
    Ok((bits as u32, width, height))
}

/// Resolves an `i` record's path inside `folder` (canonical), or says why not.
fn resolve_image(folder: &Path, written: &str) -> Result<PathBuf, String> {
    let bytes = written.as_bytes();
    let drive = bytes.len() >= 2 && bytes[0].is_ascii_alphabetic() && bytes[1] == b':';
    if written.starts_with(['/', '\\']) || drive {
        return Err(format!("image path {written:?} is absolute; it must be relative to the descriptor's folder"));
    }
    // Lexical pass: separators of either system, and no `..` above the folder.
    let mut relative = PathBuf::new();
    for part in written.split(['/', '\\']).filter(|p| !p.is_empty() && *p != ".") {
        if part == ".." {
            if !relative.pop() {
                return Err(format!("image path {written:?} escapes the descriptor's folder"));
            }
        } else {
            relative.push(part);
        }
    }
    if relative.components().any(|c| !matches!(c, Component::Normal(_))) || relative.as_os_str().is_empty() {
        return Err(format!("image path {written:?} is not a file name inside the descriptor's folder"));
    }
    // Canonical pass: symlinks resolved, the file must exist and stay inside.
    let canonical = folder.join(&relative).canonicalize().map_err(|e| format!("image {written:?}: {e}"))?;
    if !canonical.starts_with(folder) {
        return Err(format!("image {written:?} resolves to {} outside the descriptor's folder", canonical.display()));
    }
    if !canonical.is_file() {
        return Err(format!("image {written:?} is not a file"));
    }
    Ok(canonical)
}

/// Opens a PNG and checks its header: grayscale, 8 or 16 bits (16 when `bits > 8`),
/// `width x height`. Returns the reader, positioned before the pixels.
fn open_png(image: &Path, bits: u32, width: usize, height: usize) -> Result<png::Reader<BufReader<File>>, String> {
    let file = File::open(image).map_err(|e| format!("image {}: {e}", image.display()))?;
    let mut decoder = png::Decoder::new(BufReader::new(file));
    decoder.set_transformations(png::Transformations::IDENTITY);
    let reader = decoder.read_info().map_err(|e| format!("image {}: not a PNG: {e}", image.display()))?;
    let info = reader.info();
    let depth_ok = match info.bit_depth {
        png::BitDepth::Sixteen => true,
        png::BitDepth::Eight => bits <= 8,
        _ => false,
    };
    if info.color_type != png::ColorType::Grayscale || !depth_ok {
        return Err(format!(
            "image {}: {:?} {:?}-bit PNG; {bits}-bit codes need grayscale of {} bits",
            image.display(),
            info.color_type,
            info.bit_depth as u8,
            if bits <= 8 { "8 or 16" } else { "16" }
        ));
    }
    if (info.width as usize, info.height as usize) != (width, height) {
        return Err(format!(
            "image {} is {} x {} pixels; the descriptor says {width} x {height}",
            image.display(),
            info.width,
            info.height
        ));
    }
    Ok(reader)
}

/// Reads and validates an EMVA 1288 descriptor (module documentation). Every image must
/// exist inside the descriptor's folder with a matching PNG header; codes are checked by
/// [`load_image`].
pub fn read_descriptor(path: &Path) -> Result<EmvaSet, HostError> {
    let text = std::fs::read_to_string(path).map_err(|e| HostError::io(path, e))?;
    // Descriptors are written on Windows, possibly with a byte-order mark.
    let text = text.strip_prefix('\u{feff}').unwrap_or(&text);
    let folder = canonical_folder(path)?;
    let mut header_line: Option<(u32, usize, usize)> = None;
    let mut levels: Vec<EmvaLevel> = Vec::new();
    for (index, raw) in text.lines().enumerate() {
        let line = index + 1;
        let record = raw.trim();
        if record.is_empty() || record.starts_with('#') {
            continue;
        }
        let (tag, rest) = record.split_once(char::is_whitespace).unwrap_or((record, ""));
        let rest = rest.trim();
        let fail = |message: String| at_line(path, line, message);
        match tag {
            "v" => {
                if rest.split_whitespace().count() != 1 {
                    return Err(fail(format!("version record {record:?}: expected one version")));
                }
            }
            "n" => {
                if header_line.is_some() || !levels.is_empty() {
                    return Err(fail("the n record must come once, before any level".into()));
                }
                header_line = Some(header(rest).map_err(fail)?);
            }
            "b" | "d" => {
                if header_line.is_none() {
                    return Err(fail("level before the n record".into()));
                }
                let (kind, exposure) = if tag == "b" {
                    let [exposure, photons] = numbers::<2>(rest).map_err(fail)?;
                    (LevelKind::Bright { photons }, exposure)
                } else {
                    let [exposure] = numbers::<1>(rest).map_err(fail)?;
                    (LevelKind::Dark, exposure)
                };
                levels.push(EmvaLevel { kind, exposure, images: Vec::new(), line, image_lines: Vec::new() });
            }
            "i" => {
                let (Some((bits, width, height)), Some(level)) = (header_line, levels.last_mut()) else {
                    return Err(fail("image before any level".into()));
                };
                if rest.is_empty() {
                    return Err(fail("image record without a path".into()));
                }
                let image = resolve_image(&folder, rest).map_err(fail)?;
                open_png(&image, bits, width, height).map_err(fail)?;
                level.images.push(image);
                level.image_lines.push(line);
            }
            other => return Err(fail(format!("unknown record {other:?}"))),
        }
    }
    let Some((bits, width, height)) = header_line else {
        return Err(HostError::Format { path: path.to_path_buf(), message: "no n record (bits, width, height)".into() });
    };
    if let Some(empty) = levels.iter().find(|l| l.images.is_empty()) {
        return Err(at_line(path, empty.line, "level without images"));
    }
    Ok(EmvaSet { path: path.to_path_buf(), bits, width, height, levels })
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
    let fail = |message: String| match line {
        Some(line) => at_line(&set.path, line, message),
        None => HostError::Format { path: image.to_path_buf(), message },
    };
    let folder = canonical_folder(&set.path)?;
    let canonical = image.canonicalize().map_err(|e| HostError::io(image, e))?;
    if !canonical.starts_with(&folder) {
        return Err(fail(format!("image {} is outside the descriptor's folder", image.display())));
    }
    let mut reader = open_png(&canonical, set.bits, set.width, set.height).map_err(fail)?;
    let mut buffer = vec![0u8; reader.output_buffer_size()];
    let frame = reader.next_frame(&mut buffer).map_err(|e| fail(format!("image {}: {e}", image.display())))?;
    let pixels = set.width * set.height;
    let codes: Vec<u16> = match frame.bit_depth {
        png::BitDepth::Sixteen => buffer.chunks_exact(2).take(pixels).map(|b| u16::from_be_bytes([b[0], b[1]])).collect(),
        _ => buffer.iter().take(pixels).map(|&b| b as u16).collect(),
    };
    let limit = 1u32 << set.bits;
    if let Some((i, &code)) = codes.iter().enumerate().find(|(_, &c)| c as u32 >= limit) {
        return Err(fail(format!(
            "image {}: code {code} at pixel ({}, {}) does not fit {} bits",
            image.display(),
            i % set.width,
            i / set.width,
            set.bits
        )));
    }
    Ok(codes)
}

/// The code histogram of every frame of `set` (bright and dark levels), `2^bits` bins:
/// the data of a code-density test of the camera's ADC. Frames are loaded in parallel.
pub fn code_histogram(set: &EmvaSet) -> Result<Vec<u64>, HostError> {
    let images: Vec<&PathBuf> = set.levels.iter().flat_map(|l| l.images.iter()).collect();
    let bins = 1usize << set.bits;
    images
        .par_iter()
        .map(|image| {
            let mut h = vec![0u64; bins];
            for c in load_image(set, image)? {
                h[c as usize] += 1;
            }
            Ok(h)
        })
        .try_reduce(|| vec![0u64; bins], |mut a, b| {
            a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
            Ok(a)
        })
}

/// Mean and temporal variance of a frame pair, DN and DN^2: `(mean a + mean b) / 2` and
/// `var(a - b) / 2` with the 1/N variance; and the difference of the frame means
/// `mean a - mean b`, DN, which shows frame-to-frame (common-mode) changes the pixel
/// variance removes. Sums are exact integers (i128), so the only rounding is the final
/// division.
fn pair_statistics(a: &[u16], b: &[u16]) -> (f64, f64, f64) {
    let n = a.len().min(b.len()) as i128;
    if n == 0 {
        return (f64::NAN, f64::NAN, f64::NAN);
    }
    let (mut sum, mut diff, mut diff2) = (0i128, 0i128, 0i128);
    for (&x, &y) in a.iter().zip(b) {
        let d = x as i128 - y as i128;
        sum += x as i128 + y as i128;
        diff += d;
        diff2 += d * d;
    }
    let mean = sum as f64 / (2 * n) as f64;
    let var = (n * diff2 - diff * diff) as f64 / (n * n) as f64 / 2.0;
    (mean, var, diff as f64 / n as f64)
}

/// Mean, temporal variance and frame-mean difference of a level from its first two frames.
fn level_statistics(set: &EmvaSet, level: &EmvaLevel) -> Result<(f64, f64, f64), HostError> {
    let [a, b, ..] = &level.images[..] else {
        return Err(at_line(&set.path, level.line, "the photon-transfer curve needs two frames per level"));
    };
    let (a, b) = (load_image(set, a)?, load_image(set, b)?);
    Ok(pair_statistics(&a, &b))
}

/// The photon-transfer curve: one point per illuminated level, in descriptor order, each
/// with the dark level of exactly the same exposure, compared as numbers (`40000` matches
/// `40000.0`); the first such dark level in the descriptor if there are several.
/// A level with no exact match is an error naming its line and the nearest dark
/// exposure: dark signal and noise grow with exposure, and substituting or interpolating
/// another exposure would bias both mean and variance silently. Levels with more than two
/// frames (the standard's spatial sets) use their first two, like every other level.
/// Levels are loaded in parallel.
pub fn photon_transfer(set: &EmvaSet) -> Result<Vec<PtcPoint>, HostError> {
    let darks: Vec<usize> = (0..set.levels.len()).filter(|&i| set.levels[i].kind == LevelKind::Dark).collect();
    let mut pairs = Vec::new();
    for (i, level) in set.levels.iter().enumerate() {
        if let LevelKind::Bright { photons } = level.kind {
            let Some(&dark) = darks.iter().find(|&&d| set.levels[d].exposure == level.exposure) else {
                let nearest = darks
                    .iter()
                    .map(|&d| set.levels[d].exposure)
                    .min_by(|x, y| (x - level.exposure).abs().total_cmp(&(y - level.exposure).abs()));
                let message = match nearest {
                    Some(e) => format!("no dark level with exposure {} (nearest {e})", level.exposure),
                    None => "no dark levels at all".to_string(),
                };
                return Err(at_line(&set.path, level.line, message));
            };
            pairs.push((i, dark, photons));
        }
    }
    let mut needed: Vec<usize> = pairs.iter().flat_map(|&(b, d, _)| [b, d]).collect();
    needed.sort_unstable();
    needed.dedup();
    let stats: Vec<(usize, (f64, f64, f64))> = needed
        .par_iter()
        .map(|&i| level_statistics(set, &set.levels[i]).map(|s| (i, s)))
        .collect::<Result<_, _>>()?;
    let of = |i: usize| stats.iter().find(|(j, _)| *j == i).map(|(_, s)| *s).unwrap_or((f64::NAN, f64::NAN, f64::NAN));
    Ok(pairs
        .into_iter()
        .map(|(b, d, photons)| {
            let ((mean, var, diff), (dark_mean, dark_var, dark_diff)) = (of(b), of(d));
            PtcPoint {
                line: set.levels[b].line,
                dark_line: set.levels[d].line,
                exposure: set.levels[b].exposure,
                photons,
                mean_dn: mean - dark_mean,
                var_dn2: var,
                dark_mean_dn: dark_mean,
                dark_var_dn2: dark_var,
                frame_diff_dn: diff,
                dark_frame_diff_dn: dark_diff,
            }
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The real set (Basler, CC BY-SA 3.0) is read from the shared data folder beside the
    /// repository, never copied into it; `DNCAL_EMVA_DIR` overrides the folder.
    fn real_descriptor() -> PathBuf {
        std::env::var_os("DNCAL_EMVA_DIR")
            .map(PathBuf::from)
            .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/emva1288-ccd-12bit"))
            .join("EMVA1288_Data.txt")
    }

    #[test]
    fn parses_the_real_set() {
        let set = read_descriptor(&real_descriptor()).unwrap();
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

    #[test]
    fn real_photon_transfer_is_linear_with_a_plausible_gain() {
        let set = read_descriptor(&real_descriptor()).unwrap();
        let mut ptc = photon_transfer(&set).unwrap();
        assert_eq!(ptc.len(), 51);
        assert!(ptc.iter().all(|p| p.exposure == set.levels.iter().find(|l| l.line == p.dark_line).unwrap().exposure));
        ptc.sort_by(|a, b| a.photons.total_cmp(&b.photons));
        for p in &ptc {
            eprintln!(
                "{:8.0} photons  {:8.2} DN  var {:8.3} DN^2  dark {:7.2} DN var {:.3} DN^2",
                p.photons, p.mean_dn, p.var_dn2, p.dark_mean_dn, p.dark_var_dn2
            );
        }
        let s = summarize(&set.path, &ptc).unwrap();
        eprintln!("{s:?}");
        let (r2, gain_r2, gain, qe) = (s.linearity_r2, s.gain_r2, s.gain_dn_per_e, s.quantum_efficiency);
        // Independently of the fits: K from the two lowest-signal and the two
        // highest-below-70% points, by hand.
        let usable: Vec<&PtcPoint> = ptc.iter().filter(|p| p.mean_dn <= 0.7 * s.saturation_dn).collect();
        let (p0, p1) = (usable[0], usable[usable.len() - 1]);
        let k_two_point = ((p1.var_dn2 - p1.dark_var_dn2) - (p0.var_dn2 - p0.dark_var_dn2)) / (p1.mean_dn - p0.mean_dn);
        assert!((k_two_point - gain).abs() < 0.02 * gain, "fit {gain} vs two points {k_two_point}");
        assert!(r2 > 0.9999, "linearity R^2 {r2}");
        assert!(gain_r2 > 0.999, "PTC R^2 {gain_r2}");
        assert!((0.05..1.0).contains(&gain), "gain {gain} DN/e-");
        assert!((0.1..1.0).contains(&qe), "quantum efficiency {qe}");
    }

    /// A 16-bit grayscale PNG of `codes`, row-major.
    fn write_png(path: &Path, width: u32, height: u32, codes: &[u16]) {
        let file = File::create(path).unwrap();
        let mut encoder = png::Encoder::new(std::io::BufWriter::new(file), width, height);
        encoder.set_color(png::ColorType::Grayscale);
        encoder.set_depth(png::BitDepth::Sixteen);
        let bytes: Vec<u8> = codes.iter().flat_map(|c| c.to_be_bytes()).collect();
        encoder.write_header().unwrap().write_image_data(&bytes).unwrap();
    }

    /// A folder `set/` with 4 x 3 images `images/a.png` (codes 0..12) and `images/b.png`
    /// (all 1), a 5 x 3 `images/wide.png`, and `outside.png` beside the folder.
    fn scratch() -> (tempfile::TempDir, PathBuf) {
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
    fn read_text(set: &Path, text: &str) -> (PathBuf, Result<EmvaSet, HostError>) {
        let descriptor = set.join("EMVA1288_Data.txt");
        std::fs::write(&descriptor, text).unwrap();
        let result = read_descriptor(&descriptor);
        (descriptor, result)
    }

    /// `result` must be a format error naming `descriptor`, `line line:` and `words`.
    fn assert_format_error<T: std::fmt::Debug>(descriptor: &Path, result: Result<T, HostError>, line: usize, words: &str) {
        match result {
            Err(HostError::Format { path, message }) => {
                assert_eq!(path, descriptor);
                assert!(message.starts_with(&format!("line {line}: ")), "{message}");
                assert!(message.contains(words), "{message:?} should mention {words:?}");
            }
            other => panic!("expected a format error at line {line}, got {other:?}"),
        }
    }

    const HEAD: &str = "\u{feff}# test\r\nv 3.0\r\nn 12 4 3\r\n";

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
        assert!(matches!(result, Err(HostError::Format { path, .. }) if path == descriptor));
        assert!(matches!(read_descriptor(&set.join("nothing.txt")), Err(HostError::Io { .. })));
    }

    #[test]
    fn codes_above_the_bit_depth_are_errors() {
        let (_dir, set) = scratch();
        let (descriptor, parsed) = read_text(&set, "n 3 4 3\nb 10 5\ni images\\a.png\n");
        let parsed = parsed.unwrap();
        assert_format_error(&descriptor, load_image(&parsed, &parsed.levels[0].images[0]), 3, "code 8 at pixel (0, 2)");
    }

    #[test]
    fn pair_statistics_match_hand_values() {
        // a - b = [0, 1, 2, 3]: variance 1.25, half of it 0.625; mean (10 + 4) / 8.
        assert_eq!(pair_statistics(&[1, 2, 3, 4], &[1, 1, 1, 1]), (1.75, 0.625, 1.5));
        assert_eq!(pair_statistics(&[7; 9], &[7; 9]), (7.0, 0.0, 0.0));
    }

    #[test]
    fn photon_transfer_recovers_a_planted_gain() {
        // Planted camera: QE 0.5, gain K = 0.25 DN/e-, dark offset 100 DN with 2 DN of read
        // noise, 128 x 128 pixels. Mean above dark must be K QE photons and the variance
        // K^2 QE photons + 2^2 (before the 1/12 DN^2 of rounding to codes, in both levels).
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal, Poisson};
        let (qe, gain, offset_dn, read_dn, side): (f64, f64, f64, f64, usize) = (0.5, 0.25, 100.0, 2.0, 128);
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir(dir.path().join("images")).unwrap();
        let mut rng = rand::rngs::StdRng::seed_from_u64(1288);
        let read = Normal::new(0.0, read_dn).unwrap();
        let mut text = format!("v 3.0\nn 12 {side} {side}\n");
        let levels = [(1, 0.0), (1, 4000.0), (2, 0.0), (2, 16000.0)];
        for (index, &(exposure, photons)) in levels.iter().enumerate() {
            text += &if photons > 0.0 { format!("b {exposure} {photons}\n") } else { format!("d {exposure}\n") };
            let light = Poisson::new(qe * photons).ok(); // None for a dark level
            for frame in 0..2 {
                let codes: Vec<u16> = (0..side * side)
                    .map(|_| {
                        let electrons = light.map_or(0.0, |l| l.sample(&mut rng));
                        (offset_dn + gain * electrons + read.sample(&mut rng)).round().clamp(0.0, 4095.0) as u16
                    })
                    .collect();
                let name = format!("l{index}_{frame}.png");
                write_png(&dir.path().join("images").join(&name), side as u32, side as u32, &codes);
                text += &format!("i images\\{name}\n");
            }
        }
        let descriptor = dir.path().join("EMVA1288_Data.txt");
        std::fs::write(&descriptor, text).unwrap();
        let ptc = photon_transfer(&read_descriptor(&descriptor).unwrap()).unwrap();
        assert_eq!(ptc.len(), 2);
        let n = (side * side) as f64;
        for p in &ptc {
            let (mean, var) = (gain * qe * p.photons, gain * gain * qe * p.photons + read_dn * read_dn + 1.0 / 12.0);
            // Standard errors: of the mean, sqrt(2 var / 2N) per level pair; of var(a-b)/2,
            // var sqrt(2 / N). Five of them.
            assert!((p.mean_dn - mean).abs() < 5.0 * (2.0 * var / n).sqrt(), "{p:?}");
            assert!((p.var_dn2 - var).abs() < 5.0 * var * (2.0 / n).sqrt(), "{p:?}");
            assert!((p.dark_mean_dn - offset_dn).abs() < 0.1, "{p:?}");
        }
        let k = (ptc[1].var_dn2 - ptc[0].var_dn2) / (ptc[1].mean_dn - ptc[0].mean_dn);
        assert!((k - gain).abs() < 0.01, "gain {k} DN/e-");
    }

    #[test]
    fn photon_transfer_needs_a_dark_level_of_the_same_exposure_and_two_frames() {
        let (_dir, set) = scratch();
        let body = "b 10 5\ni images\\a.png\ni images\\b.png\nd 20\ni images\\b.png\ni images\\a.png\n";
        let (descriptor, parsed) = read_text(&set, &format!("{HEAD}{body}"));
        assert_format_error(&descriptor, photon_transfer(&parsed.unwrap()), 4, "nearest 20");
        let body = "b 10 5\ni images\\a.png\nd 10\ni images\\b.png\ni images\\a.png\n";
        let (descriptor, parsed) = read_text(&set, &format!("{HEAD}{body}"));
        assert_format_error(&descriptor, photon_transfer(&parsed.unwrap()), 4, "two frames");
    }
}
