//! The whole EMVA 1288 datasheet of a set: the temporal part ([`super::datasheet`]) and
//! the spatial part ([`super::spatial`]) with its spectrograms, logarithmic histograms
//! and defect-pixel counts.

use serde::Serialize;

use super::datasheet::{PtcSummary, Release};
use super::highpass;
use super::spatial::{accumulated_percent, defect_pixels, high_pass_5x5, histogram, spatial_pair, spectrogram, Components, DefectPixels, Histogram, Nonuniformity, NONUNIFORMITY_KEYS};
use super::channels::{channels, Channel};
use super::{photon_transfer, EmvaSet, PtcPoint};
use crate::HostError;

/// Most bins of a histogram (the reference's `_histogram_Qmax`).
const HISTOGRAM_BINS: usize = 256;

/// The four spectrograms, on `N/2 + 1` (horizontal) or `M/2 + 1` (vertical) frequencies
/// `0 ..= 0.5` cycles per pixel.
#[derive(Debug, Clone, Serialize)]
pub struct Spectrograms {
    /// DSNU along the rows, DN (amplitude of the dark averaged image; Release 4.0: of
    /// the high-pass filtered one).
    pub dsnu_horizontal_dn: Vec<f64>,
    /// DSNU down the columns, DN.
    pub dsnu_vertical_dn: Vec<f64>,
    /// PRNU along the rows, % of the mean signal above dark.
    pub prnu_horizontal_pct: Vec<f64>,
    /// PRNU down the columns, %.
    pub prnu_vertical_pct: Vec<f64>,
}

/// The logarithmic histograms of the defect-pixel characterization.
#[derive(Debug, Clone, Serialize)]
pub struct DefectHistograms {
    /// Dark averaged image about its mean, DN (Release 4.0: high-pass filtered).
    pub dsnu: Histogram,
    /// Share of pixels whose |dark deviation| is at or beyond each bin, %.
    pub dsnu_accumulated: Histogram,
    /// The accumulated percentages of `dsnu_accumulated`.
    pub dsnu_accumulated_pct: Vec<f64>,
    /// High-pass filtered averaged image above dark, DN (5 x 5 box; Release 4.0: its
    /// filter, [`highpass`]).
    pub prnu: Histogram,
    /// |high-pass deviation| bins.
    pub prnu_accumulated: Histogram,
    /// Share of pixels at or beyond each bin, %.
    pub prnu_accumulated_pct: Vec<f64>,
}

/// The spatial part of the datasheet (all `None` without a spatial series).
#[derive(Debug, Clone, Default, Serialize)]
pub struct SpatialSummary {
    /// Frames averaged in the bright and dark spatial series.
    pub spatial_frames: Option<(usize, usize)>,
    /// Photons per pixel of the bright spatial series.
    pub spatial_photons: Option<f64>,
    /// DSNU and PRNU with their parts.
    #[serde(flatten)]
    pub nonuniformity: Nonuniformity,
    /// The variance components of the bright and dark series.
    pub components: Option<(Components, Components)>,
    /// Spectrograms.
    pub spectrograms: Option<Spectrograms>,
    /// Histograms.
    pub histograms: Option<DefectHistograms>,
    /// Defect-pixel counts (dncal's criteria: [`DefectPixels`]).
    pub defect_pixels: Option<DefectPixels>,
    /// Where the response has a pattern periodic in rows and columns
    /// ([`DefectPixels::cells`]: a colour filter's channels), each cell's datasheet of
    /// its own pixels ([`super::channels`]); absent without one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub channels: Option<Vec<Channel>>,
}

/// The datasheet of a set.
#[derive(Debug, Clone, Serialize)]
pub struct Datasheet {
    /// The descriptor's `v` record.
    pub version: Option<String>,
    /// Temporal part.
    #[serde(flatten)]
    pub temporal: PtcSummary,
    /// Spatial part.
    #[serde(flatten)]
    pub spatial: SpatialSummary,
}

impl Datasheet {
    /// Why the value under `key` is missing (`not measured` where no reason was given).
    pub fn why(&self, key: &str) -> &str {
        self.temporal.why.get(key).map_or("not measured", String::as_str)
    }
}

/// The whole datasheet of `set` with `release`'s definitions (the descriptor's `v`
/// record when `None`).
pub fn datasheet(set: &EmvaSet, release: Option<Release>) -> Result<Datasheet, HostError> {
    // Counted from the descriptor before any image is decoded (issue 43: two levels of
    // 16384 x 16384 images were decoded, 31-65 s, before this refusal).
    let levels = set.levels.iter().filter(|l| l.series() == Some(super::descriptor::Series::Temporal) && matches!(l.kind, super::descriptor::LevelKind::Bright { .. })).count();
    if levels < super::datasheet::MIN_LEVELS {
        return Err(HostError::Ptc { path: set.path.clone(), source: super::datasheet::PtcError::TooFewLevels { levels } });
    }
    need(set).check(&set.path, &format!("the EMVA 1288 datasheet of {} x {} pixels", set.width, set.height))?;
    datasheet_of(set, &photon_transfer(set)?, release)
}

/// Bytes per pixel the spatial part of the datasheet holds beside the two series' sums
/// ([`datasheet_of`]): the averaged and high-pass images it forms (the dark and bright
/// sums again, their means, the bright above dark, their absolute deviations, 8 each), or
/// while the defect pixels are found, their map ([`super::spatial::defect_map`]: the dark
/// mean and its selection copy, the response, each pixel's value and neighbourhood
/// median, scores and flags). Measured on the real CCD (640 x 480), the datasheet's peak
/// less the binary's own (10.7 MB): 103 bytes a pixel on 1 thread to 125 on 8, Release
/// 3.1 or 4.0, 71 to 93 of them beside the sums; counted with room, 104 (136 in all).
pub const SPATIAL_WORK_BYTES_PER_PIXEL: u64 = 104;

/// Bytes per pixel of the photon transfer ([`photon_transfer`]): per thread one level's
/// two frames, each as codes (2) and, for the one being decoded, the decoder's buffer (2).
pub fn transfer_bytes_per_pixel(threads: u64) -> u64 {
    6 * threads
}

/// What [`datasheet`] of `set` holds at most at once, from its descriptor before any
/// frame is decoded: the photon transfer's frames, or, where the set has a spatial
/// series, the larger of its two series loaded ([`super::spatial::load_bytes_per_pixel`]
/// each) and their sums with the spatial analysis ([`SPATIAL_WORK_BYTES_PER_PIXEL`]).
/// The datasheet itself (a value a quantity, spectrograms of a row's or a column's
/// length, histograms of 256 bins) is small beside it, and so are the page and plots of
/// `-o` (fixed sizes).
pub fn need(set: &EmvaSet) -> crate::infra::budget::Need {
    use crate::infra::budget::{bytes_of, threads};
    let pixels = (set.width as u64).saturating_mul(set.height as u64);
    let t = threads();
    let spatial = set.levels.iter().any(|l| l.series() == Some(super::descriptor::Series::Spatial));
    let transfer = bytes_of(pixels, transfer_bytes_per_pixel(t));
    let series = if spatial { bytes_of(pixels, (2 * super::spatial::load_bytes_per_pixel(t)).max(32 + SPATIAL_WORK_BYTES_PER_PIXEL)) } else { 0 };
    let need = crate::infra::budget::Need::new();
    match series > transfer {
        true => need.with("the spatial series and their analysis", series),
        false => need.with(format!("the photon transfer's frames ({t} levels at once)"), transfer),
    }
}

/// The datasheet of `set` from its photon-transfer `points` ([`photon_transfer`]), for a
/// caller that has them already.
pub fn datasheet_of(set: &EmvaSet, points: &[PtcPoint], release: Option<Release>) -> Result<Datasheet, HostError> {
    let release = release.unwrap_or_else(|| Release::from_version(set.version.as_deref()));
    let mut temporal = super::summarize(&set.path, points, release)?;
    let pair = spatial_pair(set)?;
    let why = &mut temporal.why;
    let k = temporal.gain_dn_per_e;
    let mut s = SpatialSummary::default();
    let Some((bright, dark)) = pair else {
        for key in NONUNIFORMITY_KEYS.into_iter().chain(["defect_pixels"]) {
            why.insert(key.into(), "no spatial series (a bright and a dark level of more than two frames)".into());
        }
        return Ok(Datasheet { version: set.version.clone(), temporal, spatial: s });
    };
    let (b, d) = (bright.components(release), dark.components(release));
    let signal = b.mean_dn - d.mean_dn;
    s.spatial_frames = Some((bright.frames, dark.frames));
    s.spatial_photons = Some(bright.photons);
    let (rows, cols) = (bright.rows, bright.cols);
    let filtered = release == Release::R4;
    if filtered && !highpass::fits(rows, cols) {
        for key in NONUNIFORMITY_KEYS {
            why.insert(key.into(), highpass::too_small(rows, cols));
        }
        s.defect_pixels = Some(defect_pixels(&bright, &dark, b.stack_var_dn2, d.stack_var_dn2));
        return Ok(Datasheet { version: set.version.clone(), temporal, spatial: s });
    }
    s.nonuniformity = Nonuniformity::of(why, &b, &d, k);
    s.components = Some((b, d));
    let defects = defect_pixels(&bright, &dark, b.stack_var_dn2, d.stack_var_dn2);
    if let Some(cells) = &defects.cells {
        s.channels = Some(channels(set, &bright, &dark, cells, release)?);
    }
    s.defect_pixels = Some(defects);

    let (lb, ld) = (bright.frames as f64, dark.frames as f64);
    // Release 4.0: spectrograms and histograms of the filtered images (section 8.1), in
    // integers SCALE times the filtered sums; Release 3.1 as the reference: unfiltered,
    // the PRNU histogram of the 5 x 5 high-pass image.
    let (dark_sum, dark_rows, dark_cols, dark_scale) = if filtered {
        let (f, r, c) = highpass::high_pass(&dark.sum, rows, cols);
        (f, r, c, ld * highpass::SCALE as f64)
    } else {
        (dark.sum.clone(), rows, cols, ld)
    };
    let (bright_sum, _, _) = if filtered { highpass::high_pass(&bright.sum, rows, cols) } else { (bright.sum.clone(), rows, cols) };
    let dark_mean_image: Vec<f64> = dark_sum.iter().map(|&v| v as f64 / dark_scale).collect();
    let bright_scale = dark_scale / ld * lb;
    let above: Vec<f64> = bright_sum.iter().zip(&dark_sum).map(|(&b, &d)| b as f64 / bright_scale - d as f64 / dark_scale).collect();
    let to_pct = |v: Vec<f64>| v.into_iter().map(|a| 100.0 * a / signal).collect::<Vec<f64>>();
    s.spectrograms = Some(Spectrograms {
        dsnu_horizontal_dn: spectrogram(&dark_mean_image, dark_rows, dark_cols, false),
        dsnu_vertical_dn: spectrogram(&dark_mean_image, dark_rows, dark_cols, true),
        prnu_horizontal_pct: to_pct(spectrogram(&above, dark_rows, dark_cols, false)),
        prnu_vertical_pct: to_pct(spectrogram(&above, dark_rows, dark_cols, true)),
    });

    // Histograms in integers, as the reference keeps them: the dark sum image, and the
    // high-pass filtered bright-minus-dark sum image (25 x the filtered value; Release
    // 4.0: both filtered, SCALE x).
    let dark_sum_mean = dark_sum.iter().sum::<i64>() as f64 / dark_sum.len().max(1) as f64;
    let mut dsnu = histogram(&dark_sum, HISTOGRAM_BINS, dark_scale);
    dsnu.bins.iter_mut().for_each(|b| *b -= dark_sum_mean / dark_scale);
    let centre = dark_sum_mean.trunc() as i64;
    let dsnu_abs: Vec<i64> = dark_sum.iter().map(|&v| (v - centre).abs()).collect();
    let dsnu_accumulated = histogram(&dsnu_abs, HISTOGRAM_BINS, dark_scale);
    // Bright minus dark as the reference forms it (sum images; equal frame counts).
    let (filtered, prnu_scale) = if filtered {
        (bright_sum.iter().zip(&dark_sum).map(|(&b, &d)| b - d).collect::<Vec<i64>>(), bright_scale)
    } else {
        let diff: Vec<i64> = bright.sum.iter().zip(&dark.sum).map(|(&b, &d)| b - d).collect();
        (high_pass_5x5(&diff, rows, cols).0, lb * 25.0)
    };
    let prnu = histogram(&filtered, HISTOGRAM_BINS, prnu_scale);
    let filtered_mean = if filtered.is_empty() { 0.0 } else { filtered.iter().sum::<i64>() as f64 / filtered.len() as f64 };
    let prnu_abs: Vec<i64> = filtered.iter().map(|&v| (v - filtered_mean.trunc() as i64).abs()).collect();
    let prnu_accumulated = histogram(&prnu_abs, HISTOGRAM_BINS, prnu_scale);
    s.histograms = Some(DefectHistograms {
        dsnu_accumulated_pct: accumulated_percent(&dsnu_accumulated),
        dsnu,
        dsnu_accumulated,
        prnu_accumulated_pct: accumulated_percent(&prnu_accumulated),
        prnu,
        prnu_accumulated,
    });
    Ok(Datasheet { version: set.version.clone(), temporal, spatial: s })
}
