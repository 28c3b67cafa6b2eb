//! The temporal series of an EMVA 1288 set: the photon-transfer curve.
//!
//! Every two-frame level (a temporal series, [`Series::Temporal`]) that is illuminated is
//! one point, paired with the two-frame dark level of exactly the same exposure. From the
//! two frames `A`, `B` of each (N pixels; EMVA 1288 Release 3.1 eqs. 29-30, as its
//! reference implementation computes them):
//!
//! ```text
//! mu_y      = (mean A + mean B) / 2
//! sigma_y^2 = var(A - B) / 2,  var(x) = (1/N) sum (x - mean x)^2
//! ```
//!
//! The difference of two frames cancels all fixed-pattern noise, so `sigma_y^2` is
//! temporal noise only; taking the variance about the difference's own mean removes a
//! change of the whole frame between the two exposures (the reference subtracts the
//! squared mean difference, which is the same number). The many-frame spatial series
//! never enter the curve: their stated photon count need not match the pair levels', and
//! the standard measures them for the nonuniformities only.

use rayon::prelude::*;

use super::descriptor::{at_line, DescriptorFault};
use super::{load_image, EmvaLevel, EmvaSet, LevelKind, Series};
use crate::HostError;

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
    /// Share of the illuminated frames' pixels at the top code `2^bits - 1`: Release 4.0
    /// defines saturation by this overflow (0.1-0.2% of the pixels).
    pub top_fraction: f64,
    /// The top code, `2^bits - 1`, DN.
    pub top_dn: f64,
}

/// The statistics of a frame pair.
#[derive(Debug, Clone, Copy, PartialEq)]
struct PairStatistics {
    /// `(mean a + mean b) / 2`, DN.
    mean: f64,
    /// `var(a - b) / 2` with the 1/N variance, DN^2.
    var: f64,
    /// `mean a - mean b`, DN.
    diff: f64,
    /// Share of the 2N codes at `top`.
    top_fraction: f64,
}

/// Mean and temporal variance of a frame pair; the difference of the frame means shows
/// frame-to-frame (common-mode) changes that the variance of the difference removes.
/// Sums are exact integers (i128), so the only rounding is the final division.
/// `columns`, if given, selects the pixels used: one flag per column of a row (the images
/// are rows of `columns.len()` pixels), or one per pixel (its length the image's).
fn pair_statistics(a: &[u16], b: &[u16], top: u16, columns: Option<&[bool]>) -> PairStatistics {
    let used = |i: usize| columns.is_none_or(|c| c.get(i % c.len().max(1)).copied().unwrap_or(false));
    pair_statistics_by(a, b, top, 1, &|i| used(i).then_some(0))[0]
}

/// [`pair_statistics`] of each class of pixels: `class(i)` is pixel `i`'s class, below
/// `classes`, or `None` to leave it out (a class without pixels gives NaN statistics).
/// One pass over the pair for all the classes: a colour camera's channels
/// ([`photon_transfer_cells`]).
fn pair_statistics_by(a: &[u16], b: &[u16], top: u16, classes: usize, class: &(dyn Fn(usize) -> Option<usize> + Sync)) -> Vec<PairStatistics> {
    // (Pixels, sum, difference, squared difference, codes at the top.)
    let mut acc = vec![(0i128, 0i128, 0i128, 0i128, 0u64); classes];
    for (i, (&x, &y)) in a.iter().zip(b).enumerate() {
        let Some(k) = class(i).filter(|&k| k < classes) else { continue };
        let d = x as i128 - y as i128;
        let t = &mut acc[k];
        t.0 += 1;
        t.1 += x as i128 + y as i128;
        t.2 += d;
        t.3 += d * d;
        t.4 += u64::from(x == top) + u64::from(y == top);
    }
    acc.into_iter()
        .map(|(n, sum, diff, diff2, at_top)| match n {
            0 => PairStatistics { mean: f64::NAN, var: f64::NAN, diff: f64::NAN, top_fraction: f64::NAN },
            n => PairStatistics {
                mean: sum as f64 / (2 * n) as f64,
                var: (n * diff2 - diff * diff) as f64 / (n * n) as f64 / 2.0,
                diff: diff as f64 / n as f64,
                top_fraction: at_top as f64 / (2 * n) as f64,
            },
        })
        .collect()
}

/// The statistics of a level's first two frames.
fn level_statistics(set: &EmvaSet, level: &EmvaLevel, classes: &Classes) -> Result<Vec<PairStatistics>, HostError> {
    let [a, b, ..] = &level.images[..] else {
        return Err(at_line(&set.path, level.line, DescriptorFault::PtcFrames));
    };
    let (a, b) = (load_image(set, a)?, load_image(set, b)?);
    let top = ((1u32 << set.bits) - 1) as u16;
    Ok(match classes {
        Classes::Selected(columns) => vec![pair_statistics(&a, &b, top, *columns)],
        Classes::Cells(period) => pair_statistics_by(&a, &b, top, period * period, &|i| Some(cell_of(i, set.width, *period))),
    })
}

/// The pixels a photon-transfer curve is taken of.
enum Classes<'a> {
    /// The pixels `keep` selects (see [`photon_transfer_selected`]), or all: one curve.
    Selected(Option<&'a [bool]>),
    /// Each cell of a pattern of this period in rows and columns: a curve each.
    Cells(usize),
}

/// The cell `(row mod p) * p + column mod p` of pixel `i` of rows of `width` pixels.
fn cell_of(i: usize, width: usize, p: usize) -> usize {
    (i / width.max(1) % p) * p + i % width.max(1) % p
}

/// The photon-transfer curve: one point per illuminated temporal level, sorted by photons
/// (then exposure), each with the temporal dark level of exactly the same exposure,
/// compared as numbers (`40000` matches `40000.0`); a second temporal level of the same
/// exposure and photon count (dark or bright) is an error. A level with no exact match is an error naming its
/// line and the nearest dark exposure: dark signal and noise grow with exposure, and
/// substituting or interpolating another exposure would bias both mean and variance
/// silently. A level of one frame is an error; spatial series (more than two frames) are
/// left out. Levels are loaded in parallel.
pub fn photon_transfer(set: &EmvaSet) -> Result<Vec<PtcPoint>, HostError> {
    Ok(photon_transfer_of(set, &Classes::Selected(None))?.swap_remove(0))
}

/// The photon-transfer curve of each cell of a pattern of `period` pixels in rows and
/// columns (a colour filter's channels: EMVA 1288 characterizes a colour camera's
/// channels apart), `(row mod period) * period + column mod period`; the frames are
/// decoded once for all of them. Each curve is [`photon_transfer`]'s of that cell's
/// pixels alone, as the standard's subsampled channel images give it.
pub fn photon_transfer_cells(set: &EmvaSet, period: usize) -> Result<Vec<Vec<PtcPoint>>, HostError> {
    photon_transfer_of(set, &Classes::Cells(period.max(1)))
}

/// The photon-transfer curve of the pixels selected by `keep`: one flag per column of
/// the set (the same in every row), or one per pixel (row-major). `diagnose` leaves out
/// the columns of an ADC whose code widths it named (that ADC's integral nonlinearity
/// moves its level means) and the defect pixels it confirmed (a hot pixel that
/// saturates at the bright levels bent 40 pixels' share of the means into a false
/// `global-nonlinearity`).
pub fn photon_transfer_selected(set: &EmvaSet, keep: &[bool]) -> Result<Vec<PtcPoint>, HostError> {
    if !(keep.len() == set.width || keep.len() == set.width * set.height) || !keep.contains(&true) {
        return Err(HostError::Format {
            path: set.path.clone(),
            message: format!("a selection of {} flags, {} set, for {} columns of {} pixels", keep.len(), keep.iter().filter(|c| **c).count(), set.width, set.width * set.height),
        });
    }
    Ok(photon_transfer_of(set, &Classes::Selected(Some(keep)))?.swap_remove(0))
}

/// The curves of [`Classes`]: one for `Selected`, one a cell for `Cells`.
fn photon_transfer_of(set: &EmvaSet, classes: &Classes) -> Result<Vec<Vec<PtcPoint>>, HostError> {
    if let Some(single) = set.levels.iter().find(|l| l.series().is_none()) {
        return Err(at_line(&set.path, single.line, DescriptorFault::SingleFrame));
    }
    let temporal = |i: &usize| set.levels[*i].series() == Some(Series::Temporal);
    // One temporal level per (exposure, photons), as the reference implementation
    // requires: a repeated one would be a second measurement of the same point, which
    // the standard's fits do not expect (and which photon counts copied by mistake make).
    let keys: Vec<usize> = (0..set.levels.len()).filter(temporal).collect();
    for (n, &i) in keys.iter().enumerate() {
        let (a, pa) = (&set.levels[i], set.levels[i].photons());
        if let Some(&j) = keys[..n].iter().find(|&&j| set.levels[j].exposure == a.exposure && set.levels[j].photons() == pa) {
            return Err(at_line(&set.path, a.line, DescriptorFault::RepeatedLevel { exposure: a.exposure, photons: pa, first: set.levels[j].line }));
        }
    }
    let darks: Vec<usize> = (0..set.levels.len()).filter(temporal).filter(|&i| set.levels[i].kind == LevelKind::Dark).collect();
    let mut pairs = Vec::new();
    for (i, level) in set.levels.iter().enumerate().filter(|(i, _)| temporal(i)) {
        if let LevelKind::Bright { photons } = level.kind {
            let Some(&dark) = darks.iter().find(|&&d| set.levels[d].exposure == level.exposure) else {
                let nearest = darks
                    .iter()
                    .map(|&d| set.levels[d].exposure)
                    .min_by(|x, y| (x - level.exposure).abs().total_cmp(&(y - level.exposure).abs()));
                let fault = match nearest {
                    Some(nearest) => DescriptorFault::NoDark { exposure: level.exposure, nearest },
                    None => DescriptorFault::NoDarks,
                };
                return Err(at_line(&set.path, level.line, fault));
            };
            pairs.push((i, dark, photons));
        }
    }
    let mut needed: Vec<usize> = pairs.iter().flat_map(|&(b, d, _)| [b, d]).collect();
    needed.sort_unstable();
    needed.dedup();
    let stats: Vec<(usize, Vec<PairStatistics>)> = needed
        .par_iter()
        .map(|&i| level_statistics(set, &set.levels[i], classes).map(|s| (i, s)))
        .collect::<Result<_, _>>()?;
    let curves = match classes {
        Classes::Selected(_) => 1,
        Classes::Cells(p) => p * p,
    };
    Ok((0..curves).map(|k| curve(set, &pairs, &stats, k)).collect())
}

/// The curve of class `k` of the levels' statistics `stats`, one point a pair of an
/// illuminated level and its dark level (`pairs`: their indices and the photons).
fn curve(set: &EmvaSet, pairs: &[(usize, usize, f64)], stats: &[(usize, Vec<PairStatistics>)], k: usize) -> Vec<PtcPoint> {
    const MISSING: PairStatistics = PairStatistics { mean: f64::NAN, var: f64::NAN, diff: f64::NAN, top_fraction: f64::NAN };
    let of = |i: usize| stats.iter().find(|(j, _)| *j == i).and_then(|(_, s)| s.get(k).copied()).unwrap_or(MISSING);
    let mut points: Vec<PtcPoint> = pairs
        .iter()
        .map(|&(b, d, photons)| {
            let (bright, dark) = (of(b), of(d));
            PtcPoint {
                line: set.levels[b].line,
                dark_line: set.levels[d].line,
                exposure: set.levels[b].exposure,
                photons,
                mean_dn: bright.mean - dark.mean,
                var_dn2: bright.var,
                dark_mean_dn: dark.mean,
                dark_var_dn2: dark.var,
                frame_diff_dn: bright.diff,
                dark_frame_diff_dn: dark.diff,
                top_fraction: bright.top_fraction,
                top_dn: ((1u32 << set.bits) - 1) as f64,
            }
        })
        .collect();
    points.sort_by(|a, b| a.photons.total_cmp(&b.photons).then(a.exposure.total_cmp(&b.exposure)));
    points
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analyses::emva::descriptor::tests::{assert_format_error, read_text, real_descriptor, scratch, write_png, HEAD};
    use crate::analyses::emva::{read_descriptor, summarize, Release};

    #[test]
    fn real_photon_transfer_is_linear_with_a_plausible_gain() {
        let Some(real) = real_descriptor() else { return };
        let set = read_descriptor(&real).unwrap();
        let mut ptc = photon_transfer(&set).unwrap();
        assert_eq!(ptc.len(), 50, "51 illuminated levels, one of them the 50-frame spatial series");
        assert!(ptc.iter().all(|p| p.exposure == set.levels.iter().find(|l| l.line == p.dark_line).unwrap().exposure));
        ptc.sort_by(|a, b| a.photons.total_cmp(&b.photons));
        for p in &ptc {
            eprintln!(
                "{:8.0} photons  {:8.2} DN  var {:8.3} DN^2  dark {:7.2} DN var {:.3} DN^2",
                p.photons, p.mean_dn, p.var_dn2, p.dark_mean_dn, p.dark_var_dn2
            );
        }
        let s = summarize(&set.path, &ptc, Release::R3).unwrap();
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


    #[test]
    fn pair_statistics_match_hand_values() {
        // a - b = [0, 1, 2, 3]: variance 1.25, half of it 0.625; mean (10 + 4) / 8.
        assert_eq!(pair_statistics(&[1, 2, 3, 4], &[1, 1, 1, 1], 4, None), PairStatistics { mean: 1.75, var: 0.625, diff: 1.5, top_fraction: 0.125 });
        // Rows of two columns, the first column only: a = 1, 3 and b = 1, 1.
        assert_eq!(pair_statistics(&[1, 2, 3, 4], &[1, 1, 1, 1], 4, Some(&[true, false])), PairStatistics { mean: 1.5, var: 0.5, diff: 1.0, top_fraction: 0.0 });
        assert!(pair_statistics(&[1, 2], &[1, 2], 4, Some(&[false, false])).mean.is_nan());
        assert_eq!(pair_statistics(&[7; 9], &[7; 9], 4095, None), PairStatistics { mean: 7.0, var: 0.0, diff: 0.0, top_fraction: 0.0 });
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
    }}
