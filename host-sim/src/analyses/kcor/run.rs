//! `dncal kcor-model`: the K-Coronagraph model of the paper's section 4 (Figs. 4 and 5),
//! without and with a LUT built through the core from a 1%-noisy histogram.

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::model::camera::Camera;
use crate::formats::lut::{tables_from_weights, LutFault};
use crate::formats::report::{wrote, Report};
use crate::analyses::flatten::to_core_weights;
use crate::analyses::kcor::{noisy_weights, run_luts, KcorParams, KcorResult};
use crate::formats::plots::{map_plot, Map};
use crate::formats::outputs::OutDir;
use crate::HostError;

/// What `kcor-model` prints: the result without its grids, and the figures.
#[derive(Debug, Serialize)]
pub struct KcorSummary {
    /// The run (grids skipped in JSON: they are in the figures).
    #[serde(flatten)]
    pub result: KcorResult,
    /// Where the LUT came from.
    pub lut_source: String,
    /// With `realizations > 1` (the paper's noisy LUT only): one row per noise seed, the
    /// first being the run above. A single realization's reduction is one draw of a
    /// random variable; this is its spread.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub realizations: Vec<Realization>,
    /// Figures written.
    pub figures: Vec<PathBuf>,
}

impl Report for KcorSummary {
    fn text(&self) -> String {
        let r = &self.result;
        let mut t = format!(
            "K-Cor model, ADC {}, {} ms frames: {:.4e} e-/s per B_sun per pixel, 1 DN in a state = {:.3e} B_sun in Q; I up to {:.3e} B_sun\n",
            r.params.adc,
            // The frame time as given in ms (rounded to the ns: the product of the
            // ms -> s division and back would print 0.7000000000000001).
            (r.params.exposure_s * 1e9).round() / 1e6,
            r.electrons_per_s_per_bsun,
            r.bsun_per_dn,
            r.i_max_bsun
        );
        t += &format!(
            "max |systematic error in Q|: {:.3e} B_sun raw, {:.3e} B_sun with the LUT ({}): {:.1}x less\n",
            r.max_abs_sys_err_bsun_raw, r.max_abs_sys_err_bsun_lut, self.lut_source, r.reduction
        );
        t += &format!("rms  |systematic error in Q|: {:.3e} B_sun raw, {:.3e} B_sun with the LUT: {:.1}x less\n", r.rms_sys_err_bsun_raw, r.rms_sys_err_bsun_lut, r.rms_reduction);
        if !self.realizations.is_empty() {
            let spread = |f: fn(&Realization) -> f64| {
                let v: Vec<f64> = self.realizations.iter().map(f).collect();
                let (lo, hi) = v.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
                (lo, crate::infra::stats::median(v), hi)
            };
            let (a, b, c) = spread(|x| x.reduction);
            let (d, e, f) = spread(|x| x.rms_reduction);
            t += &format!(
                "over {} noise realizations: reduction of max |dQ| {a:.2}x / {b:.2}x / {c:.2}x, of rms dQ {d:.2}x / {e:.2}x / {f:.2}x (min / median / max)\n",
                self.realizations.len()
            );
        }
        t + &wrote(&self.figures)
    }
}

/// One noise realization of the paper's LUT.
#[derive(Debug, Clone, Serialize)]
pub struct Realization {
    /// Seed of the per-code noise.
    pub seed: u64,
    /// max |dQ| with this LUT, B_sun.
    pub max_abs_sys_err_bsun_lut: f64,
    /// rms dQ over the grid with this LUT, B_sun.
    pub rms_sys_err_bsun_lut: f64,
    /// Raw over LUT, max |dQ|.
    pub reduction: f64,
    /// Raw over LUT, rms dQ.
    pub rms_reduction: f64,
}

/// One LUT's Fig. 5 figure beside what its counts allow (issue 57): the reduction of the
/// largest |dQ| with this LUT, and the same with "limit" LUTs, the ADC's true widths
/// with the counts' own relative noise per code (`p.lut_noise`, `1/sqrt(counts per
/// code)`), median over several draws (one draw's reduction scatters by +-30%).
#[derive(Debug, Clone, Serialize)]
pub struct AgainstLimit {
    /// Raw over LUT, max |dQ|.
    pub reduction: f64,
    /// The limit's reduction, median over the draws.
    pub limit_reduction: f64,
    /// Each draw's reduction (seeds `p.seed`, `p.seed + 1`, ...).
    pub limit_draws: Vec<f64>,
    /// Relative noise per code of the limit's widths.
    pub lut_noise: f64,
    /// `reduction / limit_reduction`: 1 is all the counts allow.
    pub ratio_to_limit: f64,
    /// The codes below which the LUT's recipe leaves the widths at one (the paper's first
    /// 150: the ramps' histograms there hold the dark pedestal, not a smooth light).
    pub fixed_low_codes: usize,
    /// The limit with those codes at one too, median over as many draws: what the counts
    /// allow a recipe that does not calibrate them. Far below `limit_reduction` where the
    /// ADC's DN error below `fixed_low_codes` is what the small-Q states read (their dark
    /// level is there).
    pub limit_fixed_low_reduction: f64,
}

impl AgainstLimit {
    /// The limit in words, for every report that shows one: "the counts allow Mx (...):
    /// R of the limit; Kx with codes below N at one, as the LUT has them".
    pub fn limit_text(&self) -> String {
        format!(
            "the counts allow {:.1}x (true widths with {:.3}% noise a code, median of {}): {:.2} of the limit; {:.1}x with codes below {} at one, as the LUT has them",
            self.limit_reduction,
            100.0 * self.lut_noise,
            self.limit_draws.len(),
            self.ratio_to_limit,
            self.limit_fixed_low_reduction,
            self.fixed_low_codes
        )
    }
}

/// [`AgainstLimit`] of `table` (core entries of ADC `p.adc` of `camera`, e.g. a LUT
/// built from its ramps with its codes below `fixed_low_codes` left at one) with `draws`
/// limit LUTs, and as many with those codes at one, in one pass of the model (the
/// readouts' distributions are shared by all the LUTs).
pub fn against_limit(camera: &Camera, p: &KcorParams, table: &[u32], draws: usize, fixed_low_codes: usize) -> Result<AgainstLimit, HostError> {
    let adc = checked_adc(camera, p)?;
    if table.len() != adc.codes() || draws == 0 {
        return Err(HostError::argument("LUT against the limit", format!("{} entries for an ADC of {} codes, {draws} draws", table.len(), adc.codes())));
    }
    let mut luts = vec![table_dn(table)];
    for fixed in [0, fixed_low_codes] {
        for r in 0..draws as u64 {
            luts.push(table_dn(&noisy_table(adc, p.lut_noise, p.seed.wrapping_add(r), fixed)?));
        }
    }
    let refs: Vec<&[f64]> = luts.iter().map(|l| l.as_slice()).collect();
    let results = run_luts(camera, adc, &refs, p);
    let limit_draws: Vec<f64> = results[1..=draws].iter().map(|r| r.reduction).collect();
    let limit_reduction = crate::infra::stats::median(limit_draws.clone());
    let limit_fixed_low_reduction = crate::infra::stats::median(results[draws + 1..].iter().map(|r| r.reduction));
    let reduction = results[0].reduction;
    Ok(AgainstLimit { reduction, limit_reduction, limit_draws, lut_noise: p.lut_noise, ratio_to_limit: reduction / limit_reduction, fixed_low_codes, limit_fixed_low_reduction })
}

/// ADC `adc`'s table of the LUT file `path` (any format), validated as the core loads
/// it and refused unless it has `codes` entries.
fn table_of(path: &Path, adc: usize, codes: usize) -> Result<Vec<u32>, HostError> {
    let (_, lut) = crate::formats::lut::read(path)?;
    crate::formats::lut::validate(&lut, path)?;
    let table = lut.tables.into_iter().nth(adc).ok_or_else(|| HostError::lut(path, LutFault::NoTableForAdc { adc }))?;
    if table.len() != codes {
        return Err(HostError::lut(path, LutFault::CodesDiffer { codes: table.len(), camera_codes: codes }));
    }
    Ok(table)
}

/// `kcor-model --lut L --limit-from H`: the model's run with the LUT (taken as built with
/// the default 150 fixed low codes: a LUT file does not say its recipe), and the LUT beside
/// the limit of the counts of the histogram set `H` it was built from.
#[derive(Debug, Serialize)]
pub struct WithLimit {
    /// The run with the LUT.
    #[serde(flatten)]
    pub summary: KcorSummary,
    /// The histogram set whose counts set the limit's noise.
    pub limit_from: PathBuf,
    /// The LUT's reduction beside the limit's.
    pub against_limit: AgainstLimit,
}

impl Report for WithLimit {
    fn text(&self) -> String {
        let a = &self.against_limit;
        self.summary.text()
            + &format!(
                "the counts of {} allow {:.1}x (true widths with {:.3}% noise a code, 1/sqrt(counts), median of {} draws): this LUT reaches {:.2} of that limit\n",
                self.limit_from.display(),
                a.limit_reduction,
                100.0 * a.lut_noise,
                a.limit_draws.len(),
                a.ratio_to_limit
            )
    }
}

/// Draws of the limit's LUT whose median [`AgainstLimit`] reports (`adc`, `lut build
/// --truth`, `kcor-model --limit-from`): one draw's reduction scatters by about 30%.
pub const LIMIT_DRAWS: usize = 5;

/// The relative noise per code of widths measured from `counts` over `codes`:
/// `1/sqrt(mean counts per code)`, or `None` below one count a code (no limit to set).
pub fn counts_noise(counts: &[u64], codes: std::ops::Range<usize>) -> Option<f64> {
    let per_code = counts.get(codes.clone())?.iter().map(|&c| c as f64).sum::<f64>() / codes.len().max(1) as f64;
    (per_code >= 1.0).then(|| 1.0 / per_code.sqrt())
}

/// [`kcor_model`] with the LUT in `lut_file`, and [`against_limit`] with the noise of the
/// counts of `hist` (the histogram set the LUT was built from: its ADC `p.adc` over the
/// codes a default `lut build` calibrates, as `adc` takes them), [`LIMIT_DRAWS`] draws.
/// The LUT runs through the model twice (once for the figures, once beside the limit's
/// draws).
pub fn kcor_model_with_limit(camera: &Camera, p: &KcorParams, lut_file: &Path, hist: &Path, out: Option<OutDir<'_>>) -> Result<WithLimit, HostError> {
    let adc = checked_adc(camera, p)?;
    let codes = crate::analyses::flatten::FlattenParams::default().calibrated_codes(adc.codes());
    let set = crate::formats::fits::read_histograms(hist)?;
    let counts = set.counts.get(p.adc).ok_or_else(|| HostError::argument("--limit-from", format!("{} holds {} ADCs: no ADC {}", hist.display(), set.n_adc(), p.adc)))?;
    if counts.len() != adc.codes() {
        return Err(HostError::argument("--limit-from", format!("{} has {} codes per ADC, the camera's ADC {} has {}", hist.display(), counts.len(), p.adc, adc.codes())));
    }
    let noise = counts_noise(counts, codes.clone())
        .ok_or_else(|| HostError::argument("--limit-from", format!("{}: under one count a code in ADC {} over codes {}..{}: no limit to set", hist.display(), p.adc, codes.start, codes.end)))?;
    let table = table_of(lut_file, p.adc, adc.codes())?;
    let summary = kcor_model(camera, p, Some(lut_file), 1, out)?;
    let against_limit = against_limit(camera, &KcorParams { lut_noise: noise, ..p.clone() }, &table, LIMIT_DRAWS, codes.start)?;
    Ok(WithLimit { summary, limit_from: hist.into(), against_limit })
}

/// ADC `p.adc` of `camera`, once `p` is a grid the model can run and the camera leaves
/// that ADC room for a signal above dark.
fn checked_adc<'a>(camera: &'a Camera, p: &KcorParams) -> Result<&'a crate::model::camera::AdcTransfer, HostError> {
    let adc = camera.adcs.get(p.adc).ok_or_else(|| HostError::Argument { flag: "--adc".into(), message: format!("ADC {} does not exist; the camera has {}", p.adc, camera.adcs.len()) })?;
    if !(p.exposure_s > 0.0 && p.exposure_s.is_finite() && p.fill > 0.0 && p.fill <= 1.0 && p.lut_noise >= 0.0 && p.flat_fraction > 0.0 && p.flat_fraction <= 1.0 && p.q_fraction > 0.0 && p.q_fraction <= 1.0) {
        return Err(HostError::argument("--exposure-ms / --q-fraction / --lut-noise", "need exposure > 0, 0 < fill <= 1, 0 < flat fraction <= 1, 0 < q fraction <= 1 and LUT noise >= 0"));
    }
    // A dark level at the top code (or the full well) leaves no state a signal: every
    // error would be 0 and every reduction 0/0 (it printed "infx less").
    // (Less than one DN of room is none: every state would read the same codes.)
    let room_e = crate::analyses::kcor::signal_room_e(camera, adc);
    if room_e.is_nan() || room_e < camera.config.gain_e_per_dn {
        let c = &camera.config;
        return Err(HostError::invalid(
            crate::Subject::CameraConfig,
            format!(
                "the dark level ({:.4e} e- = {:.1} DN with the offset) fills ADC {}'s range (top code {}) or the full well ({:.4e} e-): no room for a signal",
                c.dark_e,
                c.dark_e / c.gain_e_per_dn + c.offset_dn,
                p.adc,
                adc.codes() - 1,
                c.full_well_e
            ),
        ));
    }
    Ok(adc)
}

/// The paper's LUT of `adc`: its true widths with `noise` relative noise per code (seed
/// `seed`), those below code `fixed_low` at one (then normalized as a recipe's are),
/// through the core's rounding.
fn noisy_table(adc: &crate::model::camera::AdcTransfer, noise: f64, seed: u64, fixed_low: usize) -> Result<Vec<u32>, HostError> {
    let mut w = noisy_weights(adc, noise, seed);
    let n = w.len();
    if fixed_low > 0 && fixed_low < n - 1 {
        // As the recipe leaves them (flatten.rs, step 5): the low codes and the top at
        // exactly one, the others scaled so that all sum to the number of codes.
        w.iter_mut().take(fixed_low).for_each(|x| *x = 1.0);
        let fitted: f64 = w[fixed_low..n - 1].iter().sum();
        let scale = (n - fixed_low - 1) as f64 / fitted;
        w[fixed_low..n - 1].iter_mut().for_each(|x| *x *= scale);
    }
    let w = to_core_weights(&w).map_err(|source| HostError::Weights { subject: crate::Subject::KcorLutWeights, source })?;
    Ok(tables_from_weights(&[w], &crate::Subject::KcorLutWeights.into())?.0.remove(0))
}

/// A table's entries in DN.
fn table_dn(table: &[u32]) -> Vec<f64> {
    table.iter().map(|&e| crate::infra::dims::units_to_dn(e.into(), table.len())).collect()
}

/// Creates `dir` and checks the two maps [`kcor_model`] writes there, before anything is
/// computed.
pub fn expect_figures(files: &mut crate::formats::outputs::Outputs, dir: &Path) -> Result<(), HostError> {
    files.create_dir(dir)?;
    files.expect(["kcor_raw.png", "kcor_lut.png"].map(|n| dir.join(n)))
}

/// Runs the model on ADC `p.adc` of `camera` and, with `out`, stages `kcor_raw.png` and
/// `kcor_lut.png` in its directory (published by the caller). The LUT is the table of that ADC in `lut_file` (a
/// LUT FITS or device image, e.g. from `dncal adc` on measured histograms) or, without
/// it, the paper's: the ADC's true widths with `p.lut_noise` relative noise per code, in
/// `realizations` draws (seeds `p.seed`, `p.seed + 1`, ...; the figures show the first).
pub fn kcor_model(camera: &Camera, p: &KcorParams, lut_file: Option<&Path>, realizations: usize, mut out: Option<OutDir<'_>>) -> Result<KcorSummary, HostError> {
    let adc = checked_adc(camera, p)?;
    if realizations == 0 || (realizations > 1 && lut_file.is_some()) {
        return Err(HostError::Argument { flag: "--realizations".into(), message: "need at least 1, and more than 1 only for the noisy LUT (not with --lut)".into() });
    }
    if let Some(o) = out.as_mut() {
        expect_figures(o.files, o.dir)?;
    }
    let entries: Vec<u32> = match lut_file {
        Some(path) => table_of(path, p.adc, adc.codes())?,
        None => noisy_table(adc, p.lut_noise, p.seed, 0)?,
    };
    let mut luts: Vec<Vec<f64>> = vec![table_dn(&entries)];
    for r in 1..realizations as u64 {
        luts.push(table_dn(&noisy_table(adc, p.lut_noise, p.seed.wrapping_add(r), 0)?));
    }
    let lut_refs: Vec<&[f64]> = luts.iter().map(|l| l.as_slice()).collect();
    let mut results = run_luts(camera, adc, &lut_refs, p);
    let realizations: Vec<Realization> = if realizations > 1 {
        results
            .iter()
            .enumerate()
            .map(|(r, x)| Realization {
                seed: p.seed.wrapping_add(r as u64),
                max_abs_sys_err_bsun_lut: x.max_abs_sys_err_bsun_lut,
                rms_sys_err_bsun_lut: x.rms_sys_err_bsun_lut,
                reduction: x.reduction,
                rms_reduction: x.rms_reduction,
            })
            .collect()
    } else {
        Vec::new()
    };
    let result = results.swap_remove(0);
    let mut figures = Vec::new();
    if let Some(OutDir { files, dir }) = out {
        let maps = MagnitudeMaps::of(&result);
        for (name, map) in maps.maps(&result) {
            let path = dir.join(name);
            map_plot(files, &path, &map)?;
            figures.push(path);
        }
    }
    let lut_source = match lut_file {
        Some(f) => f.display().to_string(),
        None => format!("true code widths with {}% Gaussian noise per code", 100.0 * p.lut_noise),
    };
    Ok(KcorSummary { result, lut_source, realizations, figures })
}

/// The fraction of the maps' non-zero magnitudes left below the colour scale's bottom.
const SCALE_PERCENTILE: f64 = 0.01;

/// The paper's Figs. 4 and 5 as drawn: the magnitude `|dQ|` of the signed errors (a
/// negative error is as large as a positive one), on one log scale for both maps (they
/// are compared) from the largest `|dQ|` of either down to the smallest non-zero one
/// but the 1% smallest ([`SCALE_PERCENTILE`]; at most six decades): the colours span the
/// values the maps hold. A magnitude below the bottom is drawn at the bottom colour,
/// only an error of exactly 0 in grey.
struct MagnitudeMaps {
    raw: Vec<Vec<f64>>,
    lut: Vec<Vec<f64>>,
    range: Option<(f64, f64)>,
}

impl MagnitudeMaps {
    fn of(r: &KcorResult) -> Self {
        let abs = |g: &[Vec<f64>]| -> Vec<Vec<f64>> { g.iter().map(|row| row.iter().map(|v| v.abs()).collect()).collect() };
        let (raw, lut) = (abs(&r.dq_raw), abs(&r.dq_lut));
        let mut nonzero: Vec<f64> = raw.iter().chain(&lut).flatten().copied().filter(|v| v.is_finite() && *v > 0.0).collect();
        nonzero.sort_by(f64::total_cmp);
        let range = match (nonzero.get((SCALE_PERCENTILE * nonzero.len() as f64) as usize), nonzero.last()) {
            (Some(&bottom), Some(&top)) if top > bottom => Some((bottom.max(top * 1e-6), top)),
            (_, Some(&top)) => Some((top * 1e-6, top)),
            _ => None,
        };
        MagnitudeMaps { raw, lut, range }
    }

    /// The two maps with their file names.
    fn maps<'a>(&'a self, r: &KcorResult) -> [(&'static str, Map<'a>); 2] {
        let i_max = r.i_bsun.last().copied().unwrap_or(1.0);
        let y_range = (r.q_bsun.first().copied().unwrap_or(-i_max), r.q_bsun.last().copied().unwrap_or(i_max));
        let map = |values: &'a [Vec<f64>], title: &'a str| Map {
            title,
            x_label: "Stokes I (B_sun)",
            y_label: "Stokes Q (B_sun)",
            values,
            x_range: (0.0, i_max),
            y_range,
            scale_label: "|dQ| (B_sun), log scale",
            log: true,
            contours: &[1e-8, 1e-9, 1e-10],
            range: self.range,
        };
        [
            ("kcor_raw.png", map(&self.raw, "K-Cor model: |systematic error in Q| (B_sun), raw ADC; grey: exactly 0")),
            ("kcor_lut.png", map(&self.lut, "K-Cor model: |systematic error in Q| (B_sun), with the LUT; grey: exactly 0")),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::formats::plots::{map_scale, shade, Shade};
    use crate::model::camera::CameraConfig;

    /// A dark level above the top code: a clear refusal, not a run whose every error is 0
    /// and whose reduction is 0/0; a dark level just inside the range still runs.
    #[test]
    fn a_dark_level_that_fills_the_range_is_refused() {
        let full = Camera::new(CameraConfig { dark_e: 1e7, ..CameraConfig::default() }).unwrap();
        let e = kcor_model(&full, &KcorParams::default(), None, 1, None).unwrap_err().to_string();
        assert!(e.contains("fills ADC 3's range") && e.contains("no room for a signal"), "{e}");
        let config = CameraConfig::default();
        let adc = &Camera::new(config.clone()).unwrap().adcs[3];
        // The dark level half a DN below the top code (offset included): refused too.
        let dark_e = ((adc.codes() - 1) as f64 - 0.5 - config.offset_dn) * config.gain_e_per_dn;
        let almost = Camera::new(CameraConfig { dark_e, ..config.clone() }).unwrap();
        assert!(kcor_model(&almost, &KcorParams::default(), None, 1, None).is_err());
        // 200 DN of room: runs, and every number it prints is finite.
        let dark_e = ((adc.codes() - 1) as f64 - 200.0 - config.offset_dn) * config.gain_e_per_dn;
        let room = Camera::new(CameraConfig { dark_e, ..config }).unwrap();
        let r = kcor_model(&room, &KcorParams { steps: 8, ..KcorParams::default() }, None, 1, None).unwrap();
        let j = serde_json::to_value(&r).unwrap().to_string();
        assert!(!j.contains("null") && !j.contains("inf") && !j.contains("NaN"), "{j}");
    }

    /// Figs. 4 and 5 as drawn: every cell whose error is not 0 is coloured (never the grey
    /// of "none"), negative errors included, and the scale's top is the largest |dQ| of
    /// either map (computed here from the signed grids).
    #[test]
    fn the_maps_show_every_errors_magnitude_from_the_largest() {
        let camera = Camera::new(CameraConfig::default()).unwrap();
        let r = kcor_model(&camera, &KcorParams { steps: 24, ..KcorParams::default() }, None, 1, None).unwrap().result;
        let signed = r.dq_raw.iter().chain(&r.dq_lut).flatten().copied().filter(|v| v.is_finite());
        assert!(signed.clone().any(|v| v < 0.0) && signed.clone().any(|v| v > 0.0), "the test needs errors of both signs");
        let top = signed.map(f64::abs).fold(0.0, f64::max);
        let maps = MagnitudeMaps::of(&r);
        for ((name, map), grid) in maps.maps(&r).iter().zip([&r.dq_raw, &r.dq_lut]) {
            let scale = map_scale(map);
            assert_eq!(scale.1, top.log10(), "{name}: the scale's top");
            for (row, signed_row) in map.values.iter().zip(grid.iter()) {
                for (&v, &dq) in row.iter().zip(signed_row) {
                    let s = shade(map, scale, v);
                    match dq {
                        d if d.is_nan() => assert_eq!(s, Shade::Missing),
                        0.0 => assert_eq!(s, Shade::Below),
                        d => assert!(matches!(s, Shade::Scale(_)), "{name}: dQ {d:e} drawn {s:?}"),
                    }
                }
            }
        }
    }

    /// Issue 44: the colour scale spans the values the maps hold. Its bottom is a value
    /// of the maps (counted here, independently, from the signed grids): at most 1% of the
    /// non-zero magnitudes lie below it, and it is above the smallest one where the
    /// maps' range is wider than that percentile (the old scale reached six decades below
    /// the top, 1e-14 under data from 1e-10).
    #[test]
    fn the_colour_scale_spans_the_maps_values() {
        let camera = Camera::new(CameraConfig::default()).unwrap();
        let r = kcor_model(&camera, &KcorParams { steps: 24, ..KcorParams::default() }, None, 1, None).unwrap().result;
        let magnitudes: Vec<f64> = r.dq_raw.iter().chain(&r.dq_lut).flatten().filter(|v| v.is_finite() && **v != 0.0).map(|v| v.abs()).collect();
        let smallest = magnitudes.iter().copied().fold(f64::INFINITY, f64::min);
        let maps = MagnitudeMaps::of(&r);
        let (lo, hi) = map_scale(&maps.maps(&r)[0].1);
        let bottom = 10f64.powf(lo);
        let below = magnitudes.iter().filter(|&&m| m < bottom * (1.0 - 1e-12)).count();
        assert!(below as f64 <= 0.01 * magnitudes.len() as f64 + 1.0, "{below} of {} below the scale", magnitudes.len());
        assert!(bottom > smallest, "bottom {bottom:e}, smallest {smallest:e}");
        assert!(hi - lo < 6.0, "{} decades", hi - lo);
    }
}
