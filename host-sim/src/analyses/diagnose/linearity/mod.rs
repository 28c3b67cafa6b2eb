//! Linearity sets: per-pixel mean and standard-deviation frames at levels from dark to
//! saturation, with a linear reference detector (`docs/formats.md`).
//!
//! ## Data, noise and the held-out split
//! Pixel `p` at level `l` reads the mean `m_lp` of `N` frames with standard deviation
//! `s_lp`; `x_l = V_l / max V` is the reference. The noise of a mean is
//! `sigma_lp^2 = kappa s_lp^2 / N` (at least `1 / (12 N)`, one code's quantization), with
//! `kappa = (N - 1) / (N - 3)`: the mean of `1 / s^2` for Gaussian frames, so that
//! `E[z^2] = 1` exactly when the model is right (without it 256 frames bias `mean z^2` by
//! 0.8%, which is 30 standard deviations over a 64 x 64 region). Saturated levels are left
//! out per pixel ([`crate::analyses::linearity::unsaturated_levels`]). **Held out by levels:** every
//! per-pixel fit uses the even levels (dark included), every score the odd ones.
//!
//! ## Models of the level response (per pixel, in order)
//! - **baseline**: `m = d + g x`, per-pixel dark and gain (weighted least squares).
//! - **`adc-mismatch`** (curvature): ADC `a` gets its own shared curve (below), tested
//!   first so that one bending ADC is not mistaken for a shared bend. The ADC whose own
//!   curve beats the consensus (the curve of the ADCs not yet set apart) most
//!   significantly is set apart, the consensus refitted, and so on while a majority
//!   remains; at least three ADCs are needed (with two the data cannot say which differs).
//! - **`global-nonlinearity`**: `m = d + G(g x)` with one curve for all pixels in the
//!   signal domain, `G(S) = S (1 + c2 S/T + c3 (S/T)^2 + c4 (S/T)^3)`, `T` the top code
//!   (a nonlinearity of the pixel's voltage swing acts on its own signal, so pixels of
//!   different gain bend at different `x`; a curve in `x` scaled by `g` would leave that
//!   as false pixel-to-pixel structure). The `c_k` come from one least-squares fit over
//!   pixels ([`shared_curve`]); `d, g` per pixel by Gauss-Newton.
//! - **`pixel-nonlinearity`**: each pixel's own quartic (the paper's correction).
//!
//! **Shared parameters are held out by pixels**: curves and population medians are
//! estimated on the pixels of even rows and scored on those of odd rows, with a paired
//! test over pixels (`sum D_p / sqrt(n var D_p)`, `D_p` a pixel's drop of held-out
//! `z^2`), because pixels that differ beyond noise (their own curvature, their own gain)
//! would make a shared fit look good on its own sample. **Per-pixel parameters are held
//! out by levels**: the step to the pixel's own quartic is accepted when
//! `(S_A - max(S_B, E_B)) / SD_B > 5` and `S_B < S_A`, with `S` the sum of held-out `z^2`
//! and `E_B`, `SD_B` its exact null mean and spread under B: per pixel
//! `tr C = n + tr M`, `tr C^2 = n + 2 tr M + tr M^2`, `M = (J_f^T W J_f)^-1 J_t^T W J_t`
//! (the test noise plus that of the pixel's own fitted parameters). What remains is
//! `unexplained` when `(S - E) / SD > 5`; its detail names the worst levels and the RMS
//! by ADC.
//!
//! ## Maps: dark and gain across pixels
//! The baseline also says every pixel's dark and gain come from one population (DSNU,
//! PRNU). Per pixel, `d` and `g` under the accepted curve (all levels); per ADC their
//! median on even rows. **`adc-mismatch`** (offset or gain): odd-row pixels scored
//! against the median of the other ADCs' medians and against their own ADC's, in units
//! of the pixel scatter (1.4826 MAD about the ADC medians), by the paired test; set apart
//! one ADC at a time as for the curvature. One finding per ADC collects its parts.
//!
//! ## Bad pixels
//! **`bad-pixels`**: pixels the model cannot follow, flagged independently on the even
//! and on the odd levels and counted when both agree: fewer than 3 unsaturated levels
//! (stuck, hot), the pixel's own quartic failing its levels (`chi^2` tail below 1e-6:
//! kinks, jumps), a gain outside 0.5-1.5 of the median (dead, as [`crate::analyses::linearity`]
//! masks), a dark level more than 10 robust sigma off (hot). The before/after RMS is over
//! the odd-level dark and gain against the population plus the held-out levels of each
//! pixel's own quartic, with and without the pixels flagged on the even levels alone (held out: every score is
//! of the odd levels).
//!
//! ## What the measurement adds
//! **`level-errors`** ([`super::levels`]): errors every pixel shares at a level, measured
//! first and taken out of every pixel's means; the shared bend must then also stand out
//! against them with levels as the units. **`excess-noise`**: what remains is a noise
//! scaled by one factor (measured on even rows, the odd rows within 5 sigma with it, the
//! pixels' held-out sums not overdispersed) rather than `unexplained` structure.
//!
//! Pixels in the set's MASK are known bad: they are left out and not counted.
//! `insufficient-noise` compares the median dark noise with the quantization bias.
//!
//! ## Where
//! [`level_stage`] (the common level term), [`pixel_fits`] (each pixel's own fits, the
//! bad-pixel flags and `bad-pixels`, `pixel-nonlinearity`), [`curves`] (shared curves),
//! [`adc_apart`] (the paired test, ADC populations, `adc-mismatch` of offset and gain),
//! [`remainder`] (`excess-noise`, `unexplained`), [`camera`] (what the set measures of
//! the camera, the quantization floor); this file runs them in order.

mod adc_apart;
mod camera;
mod cfa;
pub(super) mod clip;
pub use camera::NoDark;
mod curves;
mod illumination;
mod transfer;
pub(crate) use illumination::grid_bytes as illumination_bytes;
mod level_stage;
mod pixel_fits;
mod populations;
mod remainder;
mod scoring;

use super::levels::{wald, Block};
use super::pixel_fit::{Response, Totals};
use super::records::{Keep, Records, Writer};
use super::points::{Common, Fitted, Pixels};
use super::scores::{Cell, Scores};
use super::*;
use super::cubes::SetView;
use crate::formats::fits::{LinearityRows, LinearitySet, Sample};
use crate::analyses::linearity::saturated_at;
use adc_apart::{adc_curvature, adc_maps, bend, paired, Curvature, MAX_ADCS};
use camera::{measure_camera, quantization_floor};
use scoring::Scoring;
use level_stage::{level_stage, LevelStage};
use pixel_fits::{PixelStage, LINEAR, QUARTIC};
use scoring::pixel_nonlinearity;
use remainder::remainder;
use illumination::{illumination_change, Found};

fn with_residuals(r: AdcResiduals, mut f: Finding) -> Finding {
    f.residuals = Some(r);
    f
}

fn finding(effect: Effect, adc: Option<usize>, significance: f64, before: f64, after: f64, detail: String) -> Finding {
    Finding { effect, adc, count: None, sigma_dn: None, significance, rms_before: before, rms_after: after, gain: before / after, all_data_rms_after: None, detail, residuals: None }
}

/// The set checked (enough levels and frames, positive reference, noise known, at most
/// [`MAX_ADCS`] ADCs) and its pixels as the diagnosis reads them: the masked ones left
/// out, each mean's noise with the quantization floor; and the number of ADCs.
fn prepare<'a, T: Sample>(set: &'a SetView<'a, T>, keep: Keep) -> Result<(Pixels<'a, T>, usize), DiagnoseError> {
    let (nl, np) = (set.levels, set.frame());
    if nl < 11 {
        return Err(DiagnoseError::TooFewLevels { levels: nl });
    }
    if nl > usize::from(u16::MAX) {
        return Err(DiagnoseError::TooManyLevels { levels: nl });
    }
    if set.n_frames < 4 {
        return Err(DiagnoseError::TooFewFrames { frames: set.n_frames });
    }
    let nf = f64::from(set.n_frames);
    let kappa = if set.n_frames > 3 { (nf - 1.0) / (nf - 3.0) } else { 1.0 };
    let vmax = set.voltage.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    if vmax.is_nan() || vmax <= 0.0 {
        return Err(DiagnoseError::Reference);
    }
    let distinct = crate::analyses::linearity::run::distinct_voltages(set.voltage);
    if distinct < 11 {
        return Err(DiagnoseError::DistinctLevels { distinct });
    }
    let x: Vec<f64> = set.voltage.iter().map(|v| v / vmax).collect();
    // One pass over the blocks of rows, level by level within each (the cubes are
    // level-major): each pixel's levels below saturation, as
    // [`crate::analyses::linearity::unsaturated_levels`] finds them, and how many of the finite
    // deviations are zero: the upper median of them is at most 0 when more than half are
    // (counted: a sorted copy of the cube was 4 bytes per value more at its peak).
    let top = ((1u64 << set.bit_depth) - 1) as f64;
    // (Indices of pixels are kept as `u32`.)
    if u32::try_from(np).is_err() {
        return Err(DiagnoseError::TooManyPixels { pixels: np, max: u32::MAX as usize });
    }
    let valid = Writer::<u16>::new(&keep, np);
    let counts = set.blocks(|b| {
        let pixels = b.rows.start * set.width..b.rows.end * set.width;
        let mut v = vec![nl as u16; pixels.len()];
        let (mut zero, mut finite) = (0usize, 0usize);
        for l in 0..nl {
            for (v, p) in v.iter_mut().zip(pixels.clone()) {
                let at = b.pixel(p);
                let s = at.std(l);
                if s.is_finite() {
                    finite += 1;
                    zero += usize::from(s <= 0.0);
                }
                if usize::from(*v) == nl && saturated_at(l, top, |k| at.mean(k), |k| at.std(k)) {
                    *v = l as u16;
                }
            }
        }
        valid.put(pixels.start, &v);
        (zero, finite)
    });
    let valid = valid.finish();
    let (zero, finite) = counts.iter().fold((0, 0), |(z, n), b| (z + b.0, n + b.1));
    if finite > 0 && zero > finite / 2 {
        return Err(DiagnoseError::NoNoise);
    }
    let known_bad = |p: usize| set.mask.is_some_and(|m| m[p] != 0);
    // (More ADCs than columns read as one per column: column `c` is ADC `c` either way.)
    let n_adc = set.n_adc.clamp(1, set.width.max(1));
    if n_adc > MAX_ADCS {
        return Err(DiagnoseError::TooManyAdcs { n_adc: set.n_adc, max: MAX_ADCS });
    }
    let fitted = match set.mask {
        Some(m) if m.iter().any(|&b| b != 0) => Fitted::Listed(Records::collect(&keep, (0..np).filter(|&p| !known_bad(p)).map(|p| p as u32))),
        _ => Fitted::All(np),
    };
    let bias2 = quantization_floor(set, fitted.len(), &|i| fitted.index(i));
    Ok((Pixels::new(set, x, kappa, bias2, valid, fitted, keep), n_adc))
}

/// The baseline on all the data (`base`: the linear model's held-out scores), overall
/// and per ADC.
fn baseline(base: &Scores, n_adc: usize) -> Baseline {
    let adcs = (0..n_adc)
        .map(|a| {
            let t = base.totals(&|c| c.adc == a);
            AdcBaseline { adc: a, codes_scored: t.n, rms: t.rms(), by_residue: Vec::new() }
        })
        .collect();
    Baseline {
        kind: "linearity-set".into(),
        model: "linear response with per-pixel dark and gain from one population, shot and read noise".into(),
        adcs,
        rms: base.totals(&|_| true).rms(),
    }
}

/// Diagnoses a linearity set held in memory; `accuracy_dn` is the averaging accuracy the
/// `insufficient-noise` check asks for.
pub fn diagnose_linearity<T: Sample>(set: &LinearitySet<T>, accuracy_dn: f64) -> Result<Diagnosis, DiagnoseError> {
    diagnose_kept(&mut SetView::held(set), Keep::held(), accuracy_dn)
}

/// [`diagnose_linearity`] with the per-pixel records (each pixel's fits, its scores
/// under each model and the rest: about 340 bytes a pixel) in temporary files, a block
/// of each per thread in memory ([`super::records`]). The same diagnosis, number for
/// number.
pub fn diagnose_linearity_spilled<T: Sample>(set: &LinearitySet<T>, accuracy_dn: f64) -> Result<Diagnosis, DiagnoseError> {
    diagnose_kept(&mut SetView::held(set), Keep::spilled(), accuracy_dn)
}

/// [`diagnose_linearity`] of a set read from its file by blocks of `rows` rows (`None`:
/// blocks of a few MiB), the records spilled where `spill` says: the memory of the
/// values is a block per thread, the file is read once a pass. The same diagnosis,
/// number for number, as of the set held as `f32`.
pub fn diagnose_linearity_rows(file: &LinearityRows, rows: Option<usize>, spill: bool, accuracy_dn: f64) -> Result<Diagnosis, DiagnoseError> {
    let mut set = SetView::<f32>::rows(file, rows);
    let d = diagnose_kept(&mut set, if spill { Keep::spilled() } else { Keep::held() }, accuracy_dn);
    match set.failed() {
        Some(message) => Err(DiagnoseError::Read { message }),
        None => d.map(|d| Diagnosis { block_rows: set.block_rows(), ..d }),
    }
}

/// [`diagnose_set`] with its records kept as `keep` says; a failed spill file ends it
/// with that failure.
///
/// A black level clipped at code 0 first ([`clip`]): named, and where its clipped levels
/// come first in the file and at least [`MIN_AFTER_CLIP`] levels of 11 distinct
/// references are left, the set diagnosed from the first level that is not clipped.
fn diagnose_kept<T: Sample>(set: &mut SetView<'_, T>, keep: Keep, accuracy_dn: f64) -> Result<Diagnosis, DiagnoseError> {
    let clip = clip::clip_of(set);
    let clip_finding = clip.as_ref().map(|c| {
        let left = set.levels - c.leading;
        let distinct = crate::analyses::linearity::run::distinct_voltages(&set.voltage[c.leading..]);
        let why = if c.leading < c.clipped_levels() {
            Err("the clipped levels are not the first in the file")
        } else if left < MIN_AFTER_CLIP || distinct < 11 {
            Err("too few levels would be left")
        } else {
            Ok(())
        };
        if why.is_ok() {
            set.skip_levels(c.leading);
        }
        c.finding(why)
    });
    let d = diagnose_set(set, keep.clone(), accuracy_dn).map(|mut d| {
        d.findings.splice(0..0, clip_finding);
        d
    });
    if keep.spills() {
        super::records::release();
    }
    match keep.failed() {
        Some(message) => Err(DiagnoseError::Read { message }),
        None => d.map(|d| Diagnosis { records_spilled: keep.spills(), ..d }),
    }
}

/// The diagnosis of a set however it is read.
///
/// The steps run in the catalogue's order (module documentation), each in its module,
/// each scoring through one [`Scoring`] (the pixels, the level term, their fits); what
/// stays here is the shared response (ADC curvature, `global-nonlinearity`), whose steps
/// hand each other their held-out scores (each accepted model is the next one's
/// baseline), and the assembly of the report.
/// What a set whose reference is a relative exposure (`EXPOSURE`, `t / N^2`) cannot say.
pub const EXPOSURE_NOTE: &str = "absolute quantum efficiency: the reference is a relative exposure (EXPOSURE, t / N^2), not a measure of the light, so it says nothing of the photons a pixel received; gain, noise and linearity need only the light's ratios, and the shutter's, the aperture's and the source's errors are the light's (level-errors, light-jitter), named with their sizes";

/// The fewest levels a set left after its clipped levels are taken out is diagnosed on
/// (of the held-out split's 12, with one to spare).
const MIN_AFTER_CLIP: usize = 13;

fn diagnose_set<T: Sample>(set: &SetView<'_, T>, keep: Keep, accuracy_dn: f64) -> Result<Diagnosis, DiagnoseError> {
    let (mut px, n_adc) = prepare(set, keep)?;
    // A colour filter's pattern first: every later population is per channel.
    let cfa::CfaStage { response: cfa, finding: cfa_finding, note: cfa_note } = cfa::cfa_stage(&px, set.keys.bayer);
    px.set_cfa(cfa.clone());
    let px = px;
    let (nl, top) = (set.levels, ((1u64 << set.bit_depth) - 1) as f64);
    let adc_of = |i: usize| px.adc(i);
    // Shared parameters (curves, population medians) are estimated on the pixels of even
    // rows and scored on those of odd rows: a pixel's own curvature or gain is common to
    // its even and odd levels, so scoring a shared fit on its own pixels would reward it
    // for following their sample.
    let estimating = |i: usize| px.estimating(i);
    // Errors every pixel shares at a level (the light off the reference, the black level
    // off) first: found, they are taken out of every pixel's means before any model.
    let LevelStage { term: levels_term, accepted: level_accepted, mut findings, series, light_rel } = level_stage(&px, nl);
    let level_common: Option<&dyn Common> = (level_accepted || levels_term.per_adc.is_some()).then_some(&levels_term as &dyn Common);
    // Then the light's pattern changing between levels, held out by rows.
    let pattern = illumination_change(&px, level_common, &levels_term, &levels_term.signal);
    // From here every pixel's points are its means less the terms found.
    let common: Option<&dyn Common> = match &pattern {
        Some(found) => Some(&found.term),
        None => level_common,
    };
    let (mut pattern_finding, pattern_rms) = match pattern.as_ref() {
        Some(Found { finding, rms, .. }) => (Some(finding.clone()), Some(*rms)),
        None => (None, None),
    };

    // Each pixel's own fits, the population of dark and gain, the bad-pixel flags.
    let stage = PixelStage::new(&px, common, n_adc);
    let s = Scoring::new(&px, common, &stage, n_adc, nl, top);
    let (quartic, linear) = (QUARTIC, LINEAR);

    // Shared curves from the good pixels' even-level quartics.
    let adc_curves: Vec<[f64; 3]> = (0..n_adc).map(|a| s.curve_of(&|i| adc_of(i) == a)).collect();
    let all_curve = s.curve_of(&|_| true);
    if all_curve.iter().any(|c| !c.is_finite()) {
        return Err(DiagnoseError::NoPixelFits);
    }
    let (good, cell) = (&s.good, |j: usize| s.cell(j));
    let all = |_: Cell| true;
    let base = s.score(&|_| linear);
    // The baseline proper leaves the level term in the means: the scale every model step
    // is measured on ([`Finding::all_data_rms_after`]), starting here.
    let raw = common.is_some().then(|| s.score_with(None, &|_| linear));
    let baseline = baseline(raw.as_ref().unwrap_or(&base), n_adc);
    let baseline_by_level = raw.as_ref().unwrap_or(&base).by_level(&all);
    drop(raw);
    let level_findings = findings.len();
    // ADC curvature first: each ADC's own curve against the consensus of the others, on
    // its held-out pixels (so that one bending ADC is not mistaken for a shared bend).
    // The consensus is the curve of all ADCs not yet set apart; the most significant ADC
    // above threshold is set apart and the consensus refitted, until none is left or
    // only a majority remains. It needs three ADCs at least: with two, the data cannot
    // say which one differs.
    let own_curve = (n_adc >= 3).then(|| s.score(&|i| Response::Curve(adc_curves[adc_of(i)], top)));
    let first = (all_curve, s.score(&|_| Response::Curve(all_curve, top)));
    let Curvature { adc_own, apart, mut adc_findings, global, glob } = adc_curvature(&adc_curves, own_curve.as_ref(), &cell, first, &|own| {
        let global = s.curve_of(&|i| !own[adc_of(i)]);
        (global, s.score(&|_| Response::Curve(global, top)))
    });
    // The shared bend, fitted on and scored over the pixels of the ADCs that follow the
    // consensus.
    let follows = |c: Cell| !adc_own[c.adc] && c.odd;
    let (tb0, tb1) = (base.totals(&follows), glob.totals(&follows));
    let paired_sig = paired(&base, &glob, |j| follows(cell(j)));
    // With levels as the units too: a chance smooth part of level errors is common to
    // every pixel and passes the test over pixels.
    let level_sig = wald(&levels_term, &px, &|i| stage.is_good(i) && !adc_own[adc_of(i)], Block::Bend);
    let sig = paired_sig.min(level_sig);
    let global_accepted = sig > SIGNIFICANCE && tb1.s < tb0.s;
    // Where level errors were found, the shared curve stays in the model either way: it
    // takes their smooth part (named `global-nonlinearity` only when it stands out).
    let absorb = level_accepted && !global_accepted;
    let g0 = crate::infra::select::upper_medians(good.len(), 1, &|j, f| {
        let i = good.index(j);
        if let Some(q) = stage.fits.at(i).quartic(0).filter(|_| estimating(i) && !adc_own[adc_of(i)]) {
            f(0, q.gain);
        }
    })[0];
    let smooth = if absorb { s.shared_of(&|i| !adc_own[adc_of(i)], Some(g0)) } else { [0.0; 3] };
    let follower_model = if global_accepted {
        Response::Curve(global, top)
    } else if absorb && smooth.iter().all(|c| c.is_finite()) {
        Response::Common(smooth, top, g0)
    } else {
        linear
    };
    let followed = matches!(follower_model, Response::Common(..)).then(|| s.score(&|_| follower_model));
    if global_accepted {
        let steps = AdcResiduals { baseline: base.by_level(&follows), extended: glob.by_level(&follows) };
        findings.push(with_residuals(steps, finding(
            Effect::GlobalNonlinearity,
            None,
            sig,
            tb0.rms(),
            tb1.rms(),
            format!(
                "all pixels bend alike in their own signal S: G(S) = S (1 + {:.3e} S/T + {:.3e} (S/T)^2 + {:.3e} (S/T)^3), T = {top}; {:.2}% of the signal at half scale, {:.2}% at full scale",
                global[0], global[1], global[2], 100.0 * bend(global, 0.5) / 0.5, 100.0 * bend(global, 1.0)
            ),
        )));
    }
    let follower = match (follower_model, &followed) {
        (Response::Curve(..), _) => &glob,
        (Response::Common(..), Some(f)) => f,
        _ => &base,
    };
    let mut current = Scores::per_adc(&|a| if adc_own[a] { own_curve.as_ref().unwrap_or(follower) } else { follower }, &|j| adc_of(good.index(j)), good.len(), n_adc);
    let mut tcur = current.totals(&all);
    // The all-data scale of the steps so far, in the order of the model: the level term
    // (with the smooth part a shared curve takes of it where no bend is named), each ADC
    // set apart under its own curve, the shared bend.
    let others = followed.as_ref().unwrap_or(&base);
    let others_rms = others.totals(&all).rms();
    if common.is_some() {
        findings[..level_findings].iter_mut().for_each(|f| f.all_data_rms_after = Some(others_rms));
    }
    if let Some(own_curve) = &own_curve {
        // On all the data: the ADCs set apart so far under their own curves, the others
        // under `others`.
        for (k, &a) in apart.iter().enumerate() {
            let with_own = (0..n_adc).fold(Totals::default(), |t, b| t.plus(&if apart[..=k].contains(&b) { own_curve } else { others }.totals(&|c| c.adc == b)));
            if let Some(f) = adc_findings[a].as_mut() {
                f.all_data_rms_after = Some(with_own.rms());
            }
        }
    }
    if let Some(f) = findings[level_findings..].iter_mut().find(|f| f.effect == Effect::GlobalNonlinearity) {
        f.all_data_rms_after = Some(tcur.rms());
    }
    // (What `current` took of them is copied.)
    drop((glob, own_curve, followed));
    // Pixel-to-pixel nonlinearity: each pixel's own quartic.
    let own = s.score(&|_| quartic);
    let t3 = own.totals(&all);
    let mut final_params = linear.params();
    let unattributed = |params: usize| pattern.as_ref().map_or(0.0, |p| p.unattributed(params));
    if let Some(mut f) = pixel_nonlinearity(&s, (&current, tcur), (&own, t3), unattributed(linear.params())) {
        f.all_data_rms_after = Some(t3.rms());
        findings.push(f);
        current = own;
        tcur = t3;
        final_params = quartic.params();
    }
    // Maps: each good pixel's dark and gain under the shared curve (all its levels), the
    // population estimated on even rows and scored on odd rows.
    let curve_for = |i: usize| {
        let a = adc_of(i);
        if adc_own[a] { Response::Curve(adc_curves[a], top) } else { follower_model }
    };
    adc_maps(&s, &curve_for, &mut adc_findings);
    // Listed in the order they entered the model: the ADCs set apart under their own
    // curves right after the level term (before the shared bend), the others' offset and
    // gain (tested on the maps) after the per-pixel steps.
    let curved: Vec<Finding> = apart.iter().filter_map(|&a| adc_findings[a].take()).collect();
    findings.splice(level_findings..level_findings, curved);
    // (The pattern entered the model right after the level term.)
    if let Some(mut f) = pattern_finding.take() {
        f.all_data_rms_after = Some(others_rms);
        findings.insert(level_findings, f);
    }
    findings.extend(adc_findings.into_iter().flatten());
    findings.extend(stage.finding(&px));
    // Noise: the dark level's temporal noise against the quantization bias.
    let (mut measured, dark_noise, jitter) = measure_camera(&s, set.n_frames, stage.bad_count(), global_accepted.then_some(global));
    // The light's jitter is of the measurement, found in the frames' spread: after the
    // level term, which takes what it does to the means.
    findings.extend(jitter.as_ref().map(|j| j.finding()));
    measured.illumination_change_rms = pattern_rms;
    measured.light_series_step = series.map(|s| s.step);
    measured.light_level_rms = light_rel;
    measured.reference = set.keys.reference;
    measured.cfa = cfa;
    findings.extend(insufficient_noise("median dark noise", dark_noise, accuracy_dn));
    findings.extend(remainder(&s, &current, tcur, unattributed(final_params)));
    // (The colour filter is named first: found before the level term, on the raw means,
    // and tested on maps, not on the residuals' scale.)
    findings.splice(0..0, cfa_finding);
    let exposure = (set.keys.reference == crate::formats::fits::Reference::Exposure).then(|| EXPOSURE_NOTE.to_string());
    let unread = set.keys.bayer_unread.then(|| "cfa-pattern: the file declares a colour layout (BAYERPAT) that is not one of the four 2 x 2 Bayer layouts, or a ROWORDER that is neither TOP-DOWN nor BOTTOM-UP (an X-Trans filter's 6 x 6?): the cells' colours are not named; the pattern is found from the pixels alone".to_string());
    let not_tested = measured.no_dark.iter().map(|n| n.note(measured.offset_dn, measured.read_noise_dn)).chain(cfa_note).chain(exposure).chain(unread).collect();
    Ok(Diagnosis {
        not_tested,
        measured,
        code_density: None,
        code_residuals: None,
        adc_linearity: None,
        adc_architecture: None,
        curve_per_dn: global_accepted.then(|| vec![global[0] / top, global[1] / (top * top), global[2] / (top * top * top)]),
        baseline,
        findings,
        unexplained_rms: tcur.rms(),
        residuals: vec![AdcResiduals { baseline: baseline_by_level, extended: current.by_level(&all) }],
        block_rows: None,
        records_spilled: false,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::hidden::{linearity_set, pick, Hidden, Plant};
    use rand::SeedableRng;

    fn named(d: &Diagnosis) -> Vec<(String, Option<usize>)> {
        let mut v: Vec<(String, Option<usize>)> = d.findings.iter().map(|f| (f.effect.to_string(), f.adc)).collect();
        v.sort();
        v
    }

    #[test]
    fn clean_linearity_sets_give_no_finding_in_19_of_20_seeds() {
        let mut alarms = 0;
        let seeds: u64 = std::env::var("DNCAL_CLEAN_SEEDS").ok().and_then(|v| v.parse().ok()).unwrap_or(20);
        for seed in 0..seeds {
            let d = diagnose_linearity(&linearity_set(&Plant::default(), &[], seed), 0.01).unwrap();
            if !d.findings.is_empty() {
                alarms += 1;
                eprintln!("seed {seed}: {:#?}", d.findings);
            }
            // Held-out residuals of a 2-parameter fit on 21 levels: E z^2 = 1 + ~2/21.
            assert!((d.baseline.rms - (1.0f64 + 2.0 / 21.0).sqrt()).abs() < 0.02, "seed {seed}: baseline rms {}", d.baseline.rms);
        }
        assert!(alarms * 20 <= seeds, "{alarms} false alarms in {seeds} clean seeds");
    }

    /// `diagnose` holds a set's cubes as f32 (half the memory): on a 256 x 256 set with
    /// two planted effects it names what the f64 set names, with every number within
    /// 1e-3 of it (the f32 rounding moves a mean by 2^-24 of itself; a clip boundary that
    /// a value crosses moves a level's estimate by about one pixel's share).
    #[test]
    fn an_f32_set_gives_the_findings_of_the_f64_set() {
        let mut gen = rand::rngs::StdRng::seed_from_u64(5);
        let hidden = pick(&mut gen, 4, 2);
        let set = linearity_set(&Plant { width: 256, height: 256, ..Plant::default() }, &hidden, 17);
        let narrow = LinearitySet::<f32> {
            bit_depth: set.bit_depth,
            n_adc: set.n_adc,
            n_frames: set.n_frames,
            width: set.width,
            height: set.height,
            levels: set.levels,
            mean: set.mean.iter().map(|&v| v as f32).collect(),
            std: set.std.iter().map(|&v| v as f32).collect(),
            voltage: set.voltage.clone(),
            mask: set.mask.clone(),
            keys: set.keys,
        };
        let (wide, narrow) = (diagnose_linearity(&set, 0.01).unwrap(), diagnose_linearity(&narrow, 0.01).unwrap());
        assert!(!wide.findings.is_empty(), "{hidden:?}: nothing found");
        assert_eq!(named(&wide), named(&narrow), "{hidden:?}");
        for (a, b) in wide.findings.iter().zip(&narrow.findings) {
            for (x, y) in [(a.significance, b.significance), (a.rms_before, b.rms_before), (a.rms_after, b.rms_after)] {
                assert!((x - y).abs() <= 1e-3 * x.abs().max(1.0), "{}: {x} (f64) against {y} (f32)", a.effect);
            }
        }
        assert!((wide.unexplained_rms - narrow.unexplained_rms).abs() < 1e-6 * wide.unexplained_rms);
    }

    #[test]
    fn hidden_linearity_effects_are_named_blind() {
        let mut gen = rand::rngs::StdRng::seed_from_u64(77);
        let seeds: u64 = std::env::var("DNCAL_SEEDS").ok().and_then(|v| v.parse().ok()).unwrap_or(24);
        for seed in 0..seeds {
            let hidden = pick(&mut gen, 4, 1 + (seed % 2) as usize);
            let d = diagnose_linearity(&linearity_set(&Plant::default(), &hidden, 1000 + seed), 0.01).unwrap();
            let mut want: Vec<(String, Option<usize>)> = hidden.iter().map(|h| (h.expected().0.to_string(), h.expected().1)).collect();
            want.sort();
            assert_eq!(named(&d), want, "seed {seed}, hidden {hidden:?}: {:#?}", d.findings);
            for f in &d.findings {
                assert!(f.gain > 1.1, "seed {seed}: {f:?}");
            }
            for h in &hidden {
                if let Hidden::BadPixels { count } = h {
                    let got = d.findings.iter().find_map(|f| f.count).unwrap();
                    assert!((got as f64 - *count as f64).abs() <= 0.2 * *count as f64, "seed {seed}: {got} bad pixels for {count}");
                }
            }
        }
    }
}

#[cfg(test)]
mod lab_tests;

#[cfg(test)]
mod rows_tests;

#[cfg(test)]
mod bad_input_tests {
    use super::*;
    use crate::model::hidden::{linearity_set, Plant};

    /// Valid files with pathological content: a clear error or a diagnosis, never a panic
    /// or a non-finite number in a finding.
    #[test]
    fn pathological_sets_give_an_error_or_a_finite_diagnosis() {
        let small = Plant { width: 6, height: 5, levels: 12, ..Plant::default() };
        let base = linearity_set(&small, &[], 3);
        let mut cases: Vec<(&str, LinearitySet)> = vec![
            ("as drawn", base.clone()),
            ("all masked", LinearitySet { mask: Some(vec![1; 30]), ..base.clone() }),
            ("one frame", LinearitySet { n_frames: 1, ..base.clone() }),
            ("zero noise", LinearitySet { std: vec![0.0; base.std.len()], ..base.clone() }),
            ("nan means", LinearitySet { mean: vec![f64::NAN; base.mean.len()], ..base.clone() }),
            ("all at the top code", LinearitySet { mean: vec![4095.0; base.mean.len()], ..base.clone() }),
            ("zero voltages", LinearitySet { voltage: vec![0.0; base.levels], ..base.clone() }),
            ("nan voltages", LinearitySet { voltage: vec![f64::NAN; base.levels], ..base.clone() }),
            ("equal voltages", LinearitySet { voltage: vec![1.0; base.levels], ..base.clone() }),
            ("one ADC", LinearitySet { n_adc: 1, ..base.clone() }),
            ("two ADCs", LinearitySet { n_adc: 2, ..base.clone() }),
            ("more ADCs than columns", LinearitySet { n_adc: 8, ..base.clone() }),
            // (Was a 48 GB allocation: every per-ADC table sized by NADC.)
            ("two billion ADCs", LinearitySet { n_adc: 2_000_000_000, ..base.clone() }),
        ];
        let few = Plant { width: 4, height: 4, levels: 8, ..Plant::default() };
        cases.push(("eight levels", linearity_set(&few, &[], 1)));
        let flat = LinearitySet { mean: base.mean.iter().enumerate().map(|(i, _)| 100.0 + (i % 30) as f64).collect(), ..base.clone() };
        cases.push(("no response", flat));
        // Where the set lacks what a test needs, the error says which.
        let expected = |what: &str| match what {
            "one frame" => Some(DiagnoseError::TooFewFrames { frames: 1 }),
            "zero noise" => Some(DiagnoseError::NoNoise),
            "zero voltages" | "nan voltages" => Some(DiagnoseError::Reference),
            "equal voltages" => Some(DiagnoseError::DistinctLevels { distinct: 1 }),
            "eight levels" => Some(DiagnoseError::TooFewLevels { levels: 8 }),
            "all masked" => Some(DiagnoseError::NoPixelFits),
            _ => None,
        };
        for (what, set) in cases {
            // Spilled, the same outcome (the records' flag aside), and no panic either.
            let json = |d: &Result<Diagnosis, DiagnoseError>| match d {
                Ok(d) => serde_json::to_value(Diagnosis { records_spilled: false, ..d.clone() }).unwrap().to_string(),
                Err(e) => e.to_string(),
            };
            let held = diagnose_linearity(&set, 0.01);
            assert_eq!(json(&diagnose_linearity_spilled(&set, 0.01)), json(&held), "{what}");
            match (held, expected(what)) {
                (Ok(d), None) => {
                    for f in &d.findings {
                        assert!(f.significance.is_finite() && f.rms_before.is_finite() && f.rms_after.is_finite(), "{what}: {f:?}");
                    }
                }
                (Err(e), want) => assert!(want.as_ref().is_none_or(|w| *w == e), "{what}: {e}, expected {want:?}"),
                (Ok(_), Some(want)) => panic!("{what}: diagnosed, expected {want}"),
            }
        }
    }
}

