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
//! out per pixel ([`crate::linearity::unsaturated_levels`]). **Held out by levels:** every
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
//! kinks, jumps), a gain outside 0.5-1.5 of the median (dead, as [`crate::linearity`]
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

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;
use statrs::distribution::{ChiSquared, ContinuousCDF};

use super::levels::{held_out_rms, level_term, wald, Block, LevelTerm, Shape};
use super::pixel_fit::{fit_and_score, Point, Response};
use super::points::{Common, Pixels};
use super::scores::{Cell, Scores};
use super::*;
use crate::fits::{LinearitySet, Sample};
use crate::linearity::unsaturated_levels;
use crate::stats::{robust, upper_median};

/// The paired test of a shared-parameter step over independent held-out pixels:
/// `D_p` is a pixel's drop of held-out `z^2` from model A to B, and the significance is
/// `sum D / sqrt(n var D)`. Pixels are the independent units here: where pixels differ
/// beyond noise (their own curvature), the residuals of every pixel carry it and the
/// noise-only spread of `Totals` would call a chance difference between two shared curves
/// significant (it did, at 7.6 standard deviations, on a set with 1% pixel-to-pixel
/// nonlinearity and no shared bend).
///
/// Pixels are not independent where every pixel shares an error at a level (the light
/// off the reference, the black level off); that term enters every `D_p` alike and this
/// test cannot see it (a 2e-4 level error gave false `adc-mismatch` findings), so it is
/// measured and taken out first ([`super::levels`]).
fn paired(a: &Scores, b: &Scores, sel: impl Fn(usize) -> bool) -> f64 {
    let d: Vec<f64> = a.per.iter().zip(&b.per).enumerate().filter(|(j, _)| sel(*j)).filter_map(|(_, (a, b))| Some(a.as_ref()?.sum_sq - b.as_ref()?.sum_sq)).collect();
    paired_sum(&d)
}

/// `sum d / sqrt(n var d)` of the paired differences `d`.
fn paired_sum(d: &[f64]) -> f64 {
    let n = d.len() as f64;
    if n < 3.0 {
        return 0.0;
    }
    let mean = d.iter().sum::<f64>() / n;
    let var = d.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    mean * n / (n * var).sqrt().max(1e-300)
}

/// Per-ADC medians of `(adc, value)`, their median as the centre (one odd ADC does not
/// move it), and the robust scatter about each value's own ADC median (the
/// pixel-to-pixel spread alone).
fn population(values: impl Iterator<Item = (usize, f64)>, n_adc: usize) -> (Vec<f64>, f64, f64) {
    let v: Vec<(usize, f64)> = values.collect();
    let mut by_adc = vec![Vec::new(); n_adc];
    v.iter().filter(|(a, _)| *a < n_adc).for_each(|&(a, x)| by_adc[a].push(x));
    let per: Vec<f64> = by_adc.into_iter().map(upper_median).collect();
    // The textbook median here (four ADCs: the mean of the middle two), not the upper one.
    let centre = crate::stats::median(per.iter().copied());
    let dev: Vec<f64> = v.iter().map(|(a, x)| x - per[*a]).collect();
    (per.clone(), centre, robust(&dev).1)
}

fn with_residuals(r: AdcResiduals, mut f: Finding) -> Finding {
    f.residuals = Some(r);
    f
}

fn finding(effect: &str, adc: Option<usize>, significance: f64, before: f64, after: f64, detail: String) -> Finding {
    Finding { effect: effect.into(), adc, count: None, sigma_dn: None, significance, rms_before: before, rms_after: after, gain: before / after, detail, residuals: None }
}

/// The common level term's finding, named by its shape: random errors of the
/// measurement, or a response every pixel shares that no quartic follows.
fn level_finding(term: &LevelTerm) -> Finding {
    let (before, after) = held_out_rms(&term.by_level);
    let (effect, detail) = match term.shape {
        Shape::Random => ("level-errors", format!(
            "every pixel is off alike at some levels, beyond any smooth response, uncorrelated from level to level and spread over the range: light {:.2e} rms (relative) off the reference detector and black level {:.3} DN rms (odd rows' level residuals against the even rows' estimate); taken out of every pixel's means (the light's part scaled by each pixel's local slope, the black level's by its ADC's); their smooth part cannot be told from a shared nonlinearity: a shared curve takes it, and is named only if it stands out against the level errors too",
            term.light_rel, term.black_dn
        )),
        Shape::LowSignal { share } => ("low-signal-nonlinearity", format!(
            "every pixel departs alike from any smooth response at the lowest signals: {:.0}% of the agreement between even and odd rows lies in the lowest 10% of the range (an offset or a charge loss); taken out of every pixel's means",
            100.0 * share
        )),
        Shape::Correlated { rho } => ("unexplained", format!(
            "every pixel departs alike from any smooth response, correlated from level to level (lag-1 correlation {rho:.2} over the levels by signal): a shared response no quartic follows, not random level errors; taken out of every pixel's means"
        )),
    };
    with_residuals(term.by_level.clone(), finding(effect, None, term.significance, before, after, detail))
}

/// Per level, the mean square error a mean of quantized frames carries beyond what their
/// spread shows ([`crate::quantization::mean_square_bias`] at the analog noise behind the
/// pixels' mean frame variance, [`crate::quantization::sigma_from_quantized_variance`]):
/// 1/12 DN^2 where every frame reads one code, negligible from 0.5 DN of noise. Without
/// it a set with 0.1 DN of noise gave `bad-pixels` at 950 sigma and `unexplained` at 800
/// (its means were taken to be good to 1/sqrt(12 N) of a code); with the median frame
/// deviation taken for the analog noise (0.3 DN read for 0.17), `unexplained` at 98.
fn quantization_floor<T: Sample>(set: &LinearitySet<T>, pixels: &[usize]) -> Vec<f64> {
    let np = set.width * set.height;
    (0..set.levels)
        .map(|l| {
            let s: Vec<f64> = pixels.iter().map(|&p| set.std[l * np + p].into()).filter(|v: &f64| v.is_finite()).collect();
            // Noisy or hot pixels out: they are not the level's noise.
            let cut = 5.0 * upper_median(s.clone()).max(0.0) + 1.0;
            let kept: Vec<f64> = s.into_iter().filter(|&v| v <= cut).collect();
            let v = kept.iter().map(|v| v * v).sum::<f64>() / kept.len().max(1) as f64;
            crate::quantization::mean_square_bias(crate::quantization::sigma_from_quantized_variance(v))
        })
        .collect()
}

/// The shared signal-domain curve `c` of the pixels `(even levels, gain)`: the least-squares
/// fit of `m = d_p + b_p x + sum_k c_k S^(k+2) / T^(k+1)`, `S = g_p x`, with every pixel's
/// own dark and slope free (projected out per pixel, then one 3 x 3 system).
///
/// The gains `g_p` must not carry the pixel's own curvature: they are the linear
/// coefficients of the pixels' quartics (a bend goes into the quadratic term there). With
/// the slopes of straight-line fits, which do carry it, 0.6% rms of pixel-to-pixel
/// curvature with no shared part gave a shared curve that a held-out test accepted at 7.7
/// standard deviations (errors in variables). And not the medians of the quartics'
/// coefficients either: those are nearly collinear and too noisy (0.5-1 DN of shared error
/// per level on a 64 x 64 set, an 'unexplained' excess of 13 standard deviations).
fn shared_curve<T: Sample>(px: &Pixels<T>, common: Option<&dyn Common>, pixels: &[(usize, f64)], top: f64) -> [f64; 3] {
    let (n, r) = pixels
        .par_iter()
        .filter(|(_, g)| g.is_finite())
        .map(|&(i, g)| {
            let pts = px.halves(i, common).0;
            let k = pts.len();
            if k <= 3 {
                return (DMatrix::zeros(3, 3), DVector::zeros(3));
            }
            let x = DMatrix::from_fn(k, 2, |i, j| if j == 0 { 1.0 / pts[i].sigma } else { pts[i].x / pts[i].sigma });
            let u = DMatrix::from_fn(k, 3, |i, j| (g * pts[i].x / top).powi(j as i32 + 2) * top / pts[i].sigma);
            let y = DVector::from_iterator(k, pts.iter().map(|q| q.y / q.sigma));
            // Residual maker of the pixel's own [1, x] columns.
            let Some(inv) = (x.transpose() * &x).try_inverse() else { return (DMatrix::zeros(3, 3), DVector::zeros(3)) };
            let q = DMatrix::identity(k, k) - &x * inv * x.transpose();
            let qu = &q * &u;
            (qu.transpose() * &qu, qu.transpose() * (&q * y))
        })
        .reduce(|| (DMatrix::zeros(3, 3), DVector::zeros(3)), |a, b| (a.0 + b.0, a.1 + b.1));
    match n.try_inverse() {
        Some(inv) => {
            let sol = inv * r;
            [sol[0], sol[1], sol[2]]
        }
        None => [f64::NAN; 3],
    }
}

/// The camera parameters a linearity set measures (for the model file): conversion gain
/// and read noise from the pixels' temporal variance against their signal (median over
/// pixels per level, corrected for the median of `chi^2`, a line over the levels below
/// 70% of the range: `var = r^2 + 1/12 + S / G`), dark level and DSNU, PRNU (both about
/// each pixel's own ADC), full scale and whether it is a saturation, the fraction of bad
/// pixels, and the
/// pixel-to-pixel rms of the quadratic response term from the *covariance* of the
/// pixels' even-level and odd-level quartics (their noises are independent, so the
/// covariance over pixels is the spread of the true terms alone).
fn measure_camera<T: Sample>(px: &Pixels<T>, good: &[usize], fits: &[PixelFits], n_frames: u32, top: f64, bad: usize) -> Measured {
    let levels = px.x.len();
    // The median of `s^2` is `sigma^2` times the median of `chi^2_(N-1) / (N-1)`,
    // `(1 - 2 / (9 (N-1)))^3` (Wilson-Hilferty): 0.26% low at 256 frames, and the gain
    // with it.
    let dof = f64::from(n_frames.max(2)) - 1.0;
    let median_chi2 = (1.0 - 2.0 / (9.0 * dof)).powi(3);
    let n_adc = px.n_adc();
    // Pixel-to-pixel spreads about each pixel's own ADC's median: an ADC offset or gain is
    // an `adc-mismatch`, not DSNU or PRNU.
    let about_own_adc = |v: &[(usize, f64)]| -> (f64, f64) {
        let (_, centre, scatter) = population(v.iter().copied(), n_adc);
        (centre, scatter)
    };
    let (mut s, mut v) = (Vec::new(), Vec::new());
    let dark = upper_median(good.iter().map(|&i| px.mean(0, i)));
    for l in 1..levels {
        let on: Vec<usize> = good.iter().copied().filter(|&i| l < px.valid(i)).collect();
        if on.len() * 2 < good.len() {
            break;
        }
        let signal = upper_median(on.iter().map(|&i| px.mean(l, i) - px.mean(0, i)));
        if signal > 0.7 * (top - dark) {
            break;
        }
        s.push(signal);
        v.push(upper_median(on.iter().map(|&i| px.std(l, i).powi(2))) / median_chi2);
    }
    let (gain, read) = if s.len() >= 3 {
        let (a, b, _) = crate::emva::fit_line(&s, &v);
        ((b > 0.0).then(|| 1.0 / b), Some((a - 1.0 / 12.0).max(0.0).sqrt()))
    } else {
        (None, None)
    };
    // DSNU from the dark frames themselves, less their own noise; PRNU from the signal at
    // the level nearest half scale (fitted intercepts and slopes would absorb part of each
    // pixel's own curvature: they read 2.1 DN of DSNU where the camera had 0.9).
    let n_frames = f64::from(n_frames.max(1));
    let (_, d_scatter) = about_own_adc(&good.iter().map(|&i| (px.adc(i), px.mean(0, i))).collect::<Vec<_>>());
    let d_noise = upper_median(good.iter().map(|&i| px.std(0, i).powi(2) / n_frames)) / median_chi2;
    let half = s.iter().enumerate().min_by(|a, b| (a.1 - 0.5 * s.last().copied().unwrap_or(0.0) / 0.7).abs().total_cmp(&(b.1 - 0.5 * s.last().copied().unwrap_or(0.0) / 0.7).abs())).map_or(1, |(j, _)| j + 1);
    let sig_half: Vec<(usize, f64)> = good.iter().copied().filter(|&i| half < px.valid(i)).map(|i| (px.adc(i), px.mean(half, i) - px.mean(0, i))).collect();
    let (gm, gs) = about_own_adc(&sig_half);
    let b2: Vec<(f64, f64)> = good
        .iter()
        .filter_map(|&i| {
            let [a, b] = &fits[i].quartic;
            let (a, b) = (a.as_ref()?, b.as_ref()?);
            Some((a.b2 / a.gain.powi(2), b.b2 / b.gain.powi(2)))
        })
        .filter(|(a, b)| a.is_finite() && b.is_finite())
        .collect();
    let n = b2.len() as f64;
    let (ma, mb) = (b2.iter().map(|v| v.0).sum::<f64>() / n, b2.iter().map(|v| v.1).sum::<f64>() / n);
    let cov = b2.iter().map(|v| (v.0 - ma) * (v.1 - mb)).sum::<f64>() / (n - 1.0);
    Measured {
        gain_e_per_dn: gain,
        read_noise_dn: read,
        offset_dn: Some(dark),
        full_scale_dn: Some(upper_median(good.iter().copied().filter(|&i| px.valid(i) > 1).map(|i| px.mean(px.valid(i) - 1, i) - px.mean(0, i)))),
        saturated: good.iter().filter(|&&i| px.valid(i) < levels).count() * 2 > good.len(),
        prnu_rms: Some(gs / gm),
        dsnu_dn: Some((d_scatter.powi(2) - d_noise).max(0.0).sqrt()),
        pixel_b2_rms_per_dn: (n > 10.0).then(|| cov.max(0.0).sqrt()),
        bad_fraction: Some(bad as f64 / px.len().max(1) as f64),
    }
}

/// A pixel's quartic on one half of its levels, what the catalogue reads of it: its
/// linear and quadratic coefficients, the `chi^2` of its fit, and the sum of its
/// held-out `z^2` on the other half with their count.
#[derive(Debug, Clone, Copy)]
struct Quartic {
    gain: f64,
    b2: f64,
    chi2_fit: f64,
    held_sq: f64,
    held_n: u16,
}

/// A pixel's fits on each half of its levels (even, odd): its quartic and its straight
/// line (dark DN, gain DN per reference unit), and the points each half had.
#[derive(Debug, Clone, Copy)]
struct PixelFits {
    quartic: [Option<Quartic>; 2],
    line: [Option<[f64; 2]>; 2],
    points: [u16; 2],
}

/// Why a pixel is flagged bad.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum BadPixel {
    /// Fewer than 3 unsaturated levels, or no fit: stuck, or hot at saturation.
    Stuck,
    /// Its own quartic fails its levels (kinks, jumps).
    Shape,
    /// A gain outside 0.5-1.5 of its ADC's median (dead).
    Gain,
    /// A dark level more than 10 robust sigma off (hot).
    Dark,
}

/// The most ADCs a linearity set's diagnosis takes apart (several passes over the pixels
/// per ADC: a column-parallel sensor's thousands would multiply the run by thousands).
const MAX_ADCS: usize = 256;

/// An ADC whose pixels sit apart from the others' ([`adcs_apart`]).
#[derive(Debug, Clone, Copy)]
struct Apart {
    adc: usize,
    significance: f64,
    /// RMS of the odd-row pixels in units of the scatter, about the centre and about their
    /// own ADC's median.
    before: f64,
    after: f64,
    /// The median of the other ADCs' medians, this ADC's median and the pixel scatter
    /// about each pixel's own ADC median (1.4826 MAD), all from the even rows.
    centre: f64,
    median: f64,
    scatter: f64,
}

/// The ADCs whose pixels' `values` (`(adc, odd row, value)`: each pixel's dark or gain)
/// sit apart from the others', set apart one at a time as for the curvature: the most
/// significant one, then the centre (the median of the other ADCs' medians) recomputed,
/// while a majority remains; at least three ADCs. Medians and scatter from the even rows,
/// scores on the odd rows. (The centre is the median of the medians of the ADCs not yet
/// set apart, the tested one included.)
///
/// The significance is the smaller of two: the paired test over the odd-row pixels
/// ([`paired_sum`] of their drop of `z^2` from the centre to their ADC's median), and the
/// offset against its own standard error (`1.2533 s sqrt(1/n_a + 1/n_rest)`: the
/// Gaussian median's noise over the even-row pixels, the centre's taken as one median
/// over the other ADCs' pixels, which understates it by 15-18%; a skewed spread's median
/// is noisier still). The paired statistic alone does not shrink with the
/// offset: with `d_p = (m_a - c)(2 v_p - c - m_a) / s^2` it is
/// `sqrt(n) ((m_a - c) + 2 (mean(v) - m_a)) / (2 sd(v))`, so a skewed spread (the odd rows'
/// mean off the even rows' median) passed it for any offset once `n` was large: on a
/// 2048 x 2048 set an ADC was set apart for +0.001 DN at 7 standard deviations.
fn adcs_apart(values: &[(usize, bool, f64)], n_adc: usize) -> Vec<Apart> {
    let (per_adc, _, ps) = population(values.iter().filter(|v| !v.1).map(|v| (v.0, v.2)), n_adc);
    let mut out = Vec::new();
    if n_adc < 3 || ps.is_nan() || ps <= 0.0 {
        return out;
    }
    // Per ADC: its even-row values counted, and its odd-row values' count, sum and sum of
    // squares about its own median (every score below is a function of these: one pass
    // over the pixels, whatever the number of ADCs and rounds).
    let (mut even_count, mut odd) = (vec![0usize; n_adc], vec![(0usize, 0.0, 0.0); n_adc]);
    for &(a, is_odd, v) in values.iter().filter(|v| v.0 < n_adc && v.2.is_finite()) {
        if is_odd {
            let d = v - per_adc[a];
            odd[a] = (odd[a].0 + 1, odd[a].1 + d, odd[a].2 + d * d);
        } else {
            even_count[a] += 1;
        }
    }
    let mut apart = vec![false; n_adc];
    while apart.iter().filter(|&&o| !o).count() * 2 > n_adc + 1 {
        // The textbook median of the finite medians (four ADCs: the mean of the middle two).
        let pm = crate::stats::median((0..n_adc).filter(|&a| !apart[a]).map(|a| per_adc[a]));
        if pm.is_nan() {
            break;
        }
        let scored: Vec<(usize, f64, f64, f64, usize)> = (0..n_adc)
            .filter(|&a| !apart[a] && odd[a].0 >= 8)
            .map(|a| {
                // With `u = v - m_a` and `o = m_a - c`: `z1 = u / s`, `z0 = (u + o) / s`,
                // and `d = z0^2 - z1^2 = o (2 u + o) / s^2`, linear in `u`.
                let (n, su, suu) = (odd[a].0 as f64, odd[a].1, odd[a].2);
                let o = per_adc[a] - pm;
                let (s1, s0) = (suu / (ps * ps), (suu + 2.0 * o * su + n * o * o) / (ps * ps));
                let var_u = ((suu - su * su / n) / (n - 1.0)).max(0.0);
                let (mean_d, sd_d) = (o * (2.0 * su / n + o) / (ps * ps), 2.0 * o.abs() * var_u.sqrt() / (ps * ps));
                let pairs = if n < 3.0 { 0.0 } else { mean_d * n.sqrt() / sd_d.max(1e-300) };
                let n_rest: usize = (0..n_adc).filter(|&b| b != a && !apart[b]).map(|b| even_count[b]).sum();
                let se = 1.2533 * ps * (1.0 / even_count[a].max(1) as f64 + 1.0 / n_rest.max(1) as f64).sqrt();
                (a, pairs.min(o.abs() / se), s0, s1, odd[a].0)
            })
            .collect();
        // (An ADC without a finite score, e.g. no finite median on its even rows, is not
        // tested: NaN sorts above every number and would end the search for the others.)
        let Some(&(a, sig, s0, s1, n)) = scored.iter().filter(|x| x.1.is_finite()).max_by(|x, y| x.1.total_cmp(&y.1)) else { break };
        if !(sig > SIGNIFICANCE && s1 < s0) {
            break;
        }
        apart[a] = true;
        out.push(Apart { adc: a, significance: sig, before: (s0 / n as f64).sqrt(), after: (s1 / n as f64).sqrt(), centre: pm, median: per_adc[a], scatter: ps });
    }
    out
}

/// Diagnoses a linearity set; `accuracy_dn` is the averaging accuracy the
/// `insufficient-noise` check asks for.
pub fn diagnose_linearity<T: Sample>(set: &LinearitySet<T>, accuracy_dn: f64) -> Result<Diagnosis, String> {
    let (nl, np) = (set.levels, set.width * set.height);
    if nl < 11 {
        return Err(format!("{nl} levels: the held-out split needs at least 11 (a quartic on the even levels and one on the odd ones)"));
    }
    if nl > usize::from(u16::MAX) {
        return Err(format!("{nl} levels: at most {} are diagnosed (levels are indexed in 16 bits)", u16::MAX));
    }
    if set.n_frames < 4 {
        return Err(format!("{} frames per level: the noise of a mean from the frames' standard deviation needs at least 4", set.n_frames));
    }
    let nf = f64::from(set.n_frames);
    let kappa = if set.n_frames > 3 { (nf - 1.0) / (nf - 3.0) } else { 1.0 };
    let top = ((1u64 << set.bit_depth) - 1) as f64;
    let vmax = set.voltage.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    if vmax.is_nan() || vmax <= 0.0 {
        return Err("the reference voltages are not positive".into());
    }
    let x: Vec<f64> = set.voltage.iter().map(|v| v / vmax).collect();
    let valid = unsaturated_levels(set);
    // The upper median of the finite deviations is at most 0 when more than half of them
    // are (counted: a sorted copy of the cube was 4 bytes per value more at its peak).
    let (zero, finite) = set.std.iter().map(|&v| v.into()).filter(|v: &f64| v.is_finite()).fold((0usize, 0usize), |(z, n), v| (z + usize::from(v <= 0.0), n + 1));
    if finite > 0 && zero > finite / 2 {
        return Err("the standard deviations are zero at most pixels and levels: the noise of the means is unknown".into());
    }
    let known_bad = |p: usize| set.mask.as_ref().is_some_and(|m| m[p] != 0);
    // (More ADCs than columns read as one per column: column `c` is ADC `c` either way.)
    let n_adc = set.n_adc.clamp(1, set.width.max(1));
    if n_adc > MAX_ADCS {
        return Err(format!("NADC = {}: the per-ADC tests are for at most {MAX_ADCS} pipelined ADCs (their work grows with the ADCs times the pixels); a set with NADC = 1 is diagnosed pixel by pixel", set.n_adc));
    }
    let pixels: Vec<usize> = (0..np).filter(|&p| !known_bad(p)).collect();
    let bias2 = quantization_floor(set, &pixels);
    let px = Pixels::new(set, x, kappa, bias2, valid, pixels);
    let n = px.len();
    let adc_of = |i: usize| px.adc(i);
    // Shared parameters (curves, population medians) are estimated on the pixels of even
    // rows and scored on those of odd rows: a pixel's own curvature or gain is common to
    // its even and odd levels, so scoring a shared fit on its own pixels would reward it
    // for following their sample.
    let estimating = |i: usize| px.estimating(i);
    // Errors every pixel shares at a level (the light off the reference, the black level
    // off) first: found, they are taken out of every pixel's means before any model.
    let mut levels_term = level_term(&px, &vec![false; nl]);
    let mut findings = Vec::new();
    let accepted = |t: &LevelTerm| {
        let (before, after) = held_out_rms(&t.by_level);
        t.significance > SIGNIFICANCE && after < before
    };
    // A departure every pixel shares at the lowest signals (a charge loss, an offset
    // between dark and light frames). A quartic over all levels spreads it over the
    // range: as a level term it left its quartic projection in every pixel (a curvature
    // that passed for `global-nonlinearity`), and beside level errors it passed for them
    // (a 10 DN charge loss beside 0.4 DN of black-level errors was `level-errors` only).
    // So where a common term is found, the levels below 10% of the top signal are left
    // out of the pixels' fits and the term there is what the others' quartics leave;
    // alone, the departure is named by the term's shape, beside level errors by a test of
    // those levels with levels as the units against the level errors measured above.
    let top_signal = levels_term.signal.iter().copied().filter(|s| s.is_finite()).fold(0.0, f64::max);
    let below = |f: f64| -> Vec<bool> { levels_term.signal.iter().map(|&s| s.is_finite() && s < f * top_signal).collect() };
    let count = |v: &[bool]| v.iter().filter(|&&b| b).count();
    let (low, guard) = (below(0.1), below(0.2));
    let room = count(&low) >= 2 && nl - count(&low) >= 11;
    let smooth_or_low = matches!(levels_term.shape, Shape::Random | Shape::LowSignal { .. });
    if accepted(&levels_term) && levels_term.per_adc.is_none() && smooth_or_low && room {
        let skipped = level_term(&px, &low);
        // (A term taken per ADC without its `adc-dnl` finding would hide the ADCs.)
        if skipped.per_adc.is_none() {
            let low_finding = if let Shape::LowSignal { .. } = levels_term.shape {
                Some(level_finding(&levels_term))
            } else {
                let sig = wald(&skipped, &px, &|_| true, Block::Levels(&low));
                let (before, after) = held_out_rms(&skipped.skipped_by_level);
                (sig > SIGNIFICANCE && after < before).then(|| {
                    let lows = count(&low);
                    with_residuals(skipped.skipped_by_level.clone(), finding(
                        "low-signal-nonlinearity",
                        None,
                        sig,
                        before,
                        after,
                        format!("every pixel departs alike from the quartic through its other levels at the {lows} levels below 10% of the top signal (their common departure against the level errors measured above them, levels as the units): an offset between dark and light or a charge loss; taken out of every pixel's means there"),
                    ))
                })
            };
            let (term, errors_found) = match low_finding {
                Some(low_finding) => {
                    // Level errors beside a named departure are judged above 20% of the
                    // top signal, and the term is the one from there: a charge loss's tail
                    // reaches the first levels above 10%, and the quartic's ripple there
                    // made `level-errors` of 7-20 DN losses alone (and left a 10 DN loss
                    // a 5 sigma `global-nonlinearity`). With too few levels above 20%, or
                    // a term there taken per ADC, the one above 10% (at 13 levels a
                    // re-review found the whole test skipped).
                    let above = (count(&guard) > count(&low) && nl - count(&guard) >= 11).then(|| level_term(&px, &guard));
                    let level_errors = above.filter(|t| t.per_adc.is_none()).unwrap_or(skipped);
                    let named_errors = (accepted(&level_errors) && level_errors.shape == Shape::Random).then(|| level_finding(&level_errors));
                    let found = named_errors.is_some();
                    findings.push(low_finding);
                    findings.extend(named_errors);
                    (level_errors, found)
                }
                None => {
                    findings.push(level_finding(&levels_term));
                    (skipped, true)
                }
            };
            levels_term = term;
            // Where the levels above show no errors of their own, only the term below 20%
            // of the top signal is taken out (the departure and its tail).
            if !errors_found {
                levels_term.keep_only(|l| guard[l]);
            }
        }
    }
    let handled = levels_term.skip.iter().any(|&s| s);
    let level_accepted = accepted(&levels_term) || handled;
    // Where the ADCs' own terms differ, the error is (at least partly) the ADCs': their
    // integral nonlinearity at the codes their pixels read. Named per ADC, and the common
    // part is not called the light's (the ADCs' mean DN error is common too).
    for (a, &t) in levels_term.adc_significance.iter().enumerate().filter(|(_, t)| **t > SIGNIFICANCE) {
        let (before, after) = held_out_rms(&levels_term.adc_by_level[a]);
        findings.push(with_residuals(levels_term.adc_by_level[a].clone(), finding(
            "adc-dnl",
            Some(a),
            t,
            before,
            after,
            format!("ADC {a}'s pixels are off alike at some levels, unlike the other ADCs' (its departure from the common level term agrees between even and odd rows at {t:.1} standard deviations): the ADC's integral nonlinearity (DN error) at the codes its pixels read, which a linearity set sees only as level means; its own term is taken out of its pixels' means"),
        )));
    }
    if !handled && level_accepted && levels_term.per_adc.is_none() {
        findings.push(level_finding(&levels_term));
    }
    // From here every pixel's points are its means less the term, where one was found.
    let common: Option<&dyn Common> = (level_accepted || levels_term.per_adc.is_some()).then_some(&levels_term as &dyn Common);
    let halves = |i: usize| px.halves(i, common);

    // Each pixel's quartic on either half (the shapes for the shared curves, and the
    // bad-pixel test of the pixel's own response) and its straight line (dark and gain
    // for the maps: their parameters only).
    let quartic = Response::Poly(crate::linearity::PIXEL_ORDER);
    let zero5 = [0.0; 5];
    let linear = Response::Poly(1);
    let fits: Vec<PixelFits> = (0..n)
        .into_par_iter()
        .map(|i| {
            let (ev, od) = halves(i);
            let q = |a: &[Point], b: &[Point]| {
                fit_and_score(quartic, &zero5, a, b).map(|s| Quartic { gain: s.params[1], b2: s.params[2], chi2_fit: s.chi2_fit, held_sq: s.sum_sq(), held_n: s.z.len() as u16 })
            };
            let l = |a: &[Point]| fit_and_score(linear, &[0.0; 2], a, &[]).map(|s| [s.params[0], s.params[1]]);
            PixelFits { quartic: [q(&ev, &od), q(&od, &ev)], line: [l(&ev), l(&od)], points: [ev.len() as u16, od.len() as u16] }
        })
        .collect();
    // The population of dark (k = 0) and gain (k = 1) from the even-level fits, for the
    // bad-pixel flags.
    let pop_of = |k: usize| population((0..n).filter(|&i| estimating(i)).filter_map(|i| Some((adc_of(i), fits[i].line[0]?[k]))), n_adc);
    let (dark_pop, gain_pop) = ((pop_of(0).1, pop_of(0).2), (pop_of(1).1, pop_of(1).2));
    // Each pixel is flagged against its own ADC's medians (an ADC offset is an
    // `adc-mismatch`, not a quarter of the sensor gone bad; a review found 1018 such
    // "bad pixels" with a 3 DN ADC offset and 0.2 DN of DSNU).
    let (dark_adc, gain_adc) = (pop_of(0).0, pop_of(1).0);
    let own_adc = |v: &[f64], i: usize, fallback: f64| v.get(adc_of(i)).copied().filter(|x| x.is_finite()).unwrap_or(fallback);
    // Bad pixels, flagged in each half independently.
    let tail = |chi2: f64, dof: usize| dof > 0 && ChiSquared::new(dof as f64).map(|c| c.sf(chi2) < 1e-6).unwrap_or(false);
    let bad_in = |i: usize, half: usize| -> Option<BadPixel> {
        let f = &fits[i];
        let (Some(q), Some(l)) = (f.quartic[half], f.line[half]) else { return Some(BadPixel::Stuck) };
        let points = usize::from(f.points[half]);
        if points < 3 {
            return Some(BadPixel::Stuck);
        }
        if tail(q.chi2_fit, points.saturating_sub(quartic.params())) {
            return Some(BadPixel::Shape);
        }
        let g_own = own_adc(&gain_adc, i, gain_pop.0);
        if !(l[1] > 0.5 * g_own && l[1] < 1.5 * g_own) {
            return Some(BadPixel::Gain);
        }
        if (l[0] - own_adc(&dark_adc, i, dark_pop.0)).abs() > 10.0 * dark_pop.1.max(1e-9) {
            return Some(BadPixel::Dark);
        }
        None
    };
    // The flags on the even levels (for the held-out bad-pixel score) and on both.
    let flagged_even: Vec<Option<BadPixel>> = (0..n).map(|i| bad_in(i, 0)).collect();
    let bad: Vec<Option<BadPixel>> = (0..n)
        .map(|i| match (flagged_even[i], bad_in(i, 1)) {
            (Some(a), Some(_)) => Some(a),
            _ => None,
        })
        .collect();
    let is_good = |i: usize| bad[i].is_none() && fits[i].quartic[0].is_some() && fits[i].line[0].is_some();

    // Shared curves from the good pixels' even-level quartics.
    // `at_gain`: every pixel at that gain (an additive common term), else its own.
    let shared_of = |sel: &dyn Fn(usize) -> bool, at_gain: Option<f64>| -> [f64; 3] {
        let chosen: Vec<(usize, f64)> = (0..n).filter(|&i| is_good(i) && estimating(i) && sel(i)).filter_map(|i| Some((i, at_gain.unwrap_or(fits[i].quartic[0]?.gain)))).collect();
        shared_curve(&px, common, &chosen, top)
    };
    let curve_of = |sel: &dyn Fn(usize) -> bool| shared_of(sel, None);
    let adc_curves: Vec<[f64; 3]> = (0..n_adc).map(|a| curve_of(&|i| adc_of(i) == a)).collect();
    let mut global = curve_of(&|_| true);
    if global.iter().any(|c| !c.is_finite()) {
        return Err("no pixel has enough unsaturated levels to fit".into());
    }
    let good: Vec<usize> = (0..n).filter(|&i| is_good(i)).collect();
    let cell = |j: usize| Cell { adc: adc_of(good[j]), odd: !estimating(good[j]) };
    let score_all = |model: &(dyn Fn(usize) -> Response + Sync)| -> Scores {
        Scores::collect(good.len(), n_adc, nl, &cell, &|j| {
            let i = good[j];
            let (ev, od) = halves(i);
            let m = model(i);
            let start = match m {
                Response::Curve(..) => fits[i].line[0].map_or(vec![0.0; 2], |l| l.to_vec()),
                _ => vec![0.0; m.params()],
            };
            fit_and_score(m, &start, &ev, &od)
        })
    };
    let all = |_: Cell| true;
    let base = score_all(&|_| linear);
    let t0 = base.totals(&all);
    let bend = |c: [f64; 3], s: f64| s * (c[0] * s + c[1] * s * s + c[2] * s * s * s);
    // ADC curvature first: each ADC's own curve against the consensus of the others, on
    // its held-out pixels (so that one bending ADC is not mistaken for a shared bend).
    // The consensus is the curve of all ADCs not yet set apart; the most significant ADC
    // above threshold is set apart and the consensus refitted, until none is left or
    // only a majority remains. It needs three ADCs at least: with two, the data cannot
    // say which one differs.
    let mut adc_own = vec![false; n_adc];
    let mut adc_findings: Vec<Option<Finding>> = vec![None; n_adc];
    let own_curve = (n_adc >= 3).then(|| score_all(&|i| Response::Curve(adc_curves[adc_of(i)], top)));
    let mut glob = score_all(&|_| Response::Curve(global, top));
    while let Some(own_curve) = own_curve.as_ref().filter(|_| adc_own.iter().filter(|&&o| !o).count() * 2 > n_adc + 1) {
        let tested: Vec<(usize, f64)> = (0..n_adc).filter(|&a| !adc_own[a]).map(|a| (a, paired(&glob, own_curve, |j| cell(j) == Cell { adc: a, odd: true }))).collect();
        let Some(&(a, sig)) = tested.iter().filter(|x| x.1.is_finite()).max_by(|x, y| x.1.total_cmp(&y.1)) else { break };
        if sig <= SIGNIFICANCE {
            break;
        }
        let on = |c: Cell| c == Cell { adc: a, odd: true };
        let (ta, tb) = (glob.totals(&on), own_curve.totals(&on));
        adc_own[a] = true;
        let steps = AdcResiduals { baseline: glob.by_level(&on), extended: own_curve.by_level(&on) };
        adc_findings[a] = Some(with_residuals(steps, finding(
            "adc-mismatch",
            Some(a),
            sig,
            ta.rms(),
            tb.rms(),
            format!("curvature: ADC {a}'s response bends by {:.3}% of full scale where the others' bends by {:.3}% (held-out levels of its pixels)", 100.0 * bend(adc_curves[a], 1.0), 100.0 * bend(global, 1.0)),
        )));
        global = curve_of(&|i| !adc_own[adc_of(i)]);
        glob = score_all(&|_| Response::Curve(global, top));
    }
    // The shared bend, fitted on and scored over the pixels of the ADCs that follow the
    // consensus.
    let follows = |c: Cell| !adc_own[c.adc] && c.odd;
    let (tb0, tb1) = (base.totals(&follows), glob.totals(&follows));
    let paired_sig = paired(&base, &glob, |j| follows(cell(j)));
    // With levels as the units too: a chance smooth part of level errors is common to
    // every pixel and passes the test over pixels.
    let level_sig = wald(&levels_term, &px, &|i| is_good(i) && !adc_own[adc_of(i)], Block::Bend);
    let sig = paired_sig.min(level_sig);
    let global_accepted = sig > SIGNIFICANCE && tb1.s < tb0.s;
    // Where level errors were found, the shared curve stays in the model either way: it
    // takes their smooth part (named `global-nonlinearity` only when it stands out).
    let absorb = level_accepted && !global_accepted;
    let g0 = upper_median(good.iter().filter(|&&i| estimating(i) && !adc_own[adc_of(i)]).filter_map(|&i| Some(fits[i].quartic[0]?.gain)));
    let smooth = if absorb { shared_of(&|i| !adc_own[adc_of(i)], Some(g0)) } else { [0.0; 3] };
    let follower_model = if global_accepted {
        Response::Curve(global, top)
    } else if absorb && smooth.iter().all(|c| c.is_finite()) {
        Response::Common(smooth, top, g0)
    } else {
        linear
    };
    let followed = matches!(follower_model, Response::Common(..)).then(|| score_all(&|_| follower_model));
    if global_accepted {
        let steps = AdcResiduals { baseline: base.by_level(&follows), extended: glob.by_level(&follows) };
        findings.push(with_residuals(steps, finding(
            "global-nonlinearity",
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
    let mut current = Scores::per_adc(&|a| if adc_own[a] { own_curve.as_ref().unwrap_or(follower) } else { follower }, &|j| adc_of(good[j]), good.len(), n_adc);
    // (What `current` took of them is copied.)
    drop((glob, own_curve, followed));
    let mut tcur = current.totals(&all);
    // Pixel-to-pixel nonlinearity: each pixel's own quartic.
    let own = score_all(&|_| quartic);
    let t3 = own.totals(&all);
    let sig = tcur.significance_to(&t3);
    if sig > SIGNIFICANCE && t3.s < tcur.s {
        // How far each pixel's quartic departs from the shared model at its highest
        // held-out level, relative to its signal there.
        let last = |s: &Option<super::scores::Score>| s.filter(|s| s.n > 0).map(|s| f64::from(s.last_z));
        let spread: Vec<f64> = (0..good.len())
            .into_par_iter()
            .filter_map(|j| {
                let (a, b) = (last(&own.per[j])?, last(&current.per[j])?);
                let i = good[j];
                let q = *halves(i).1.last()?;
                let d = fits[i].line[0]?[0];
                Some(((b - a) * q.sigma / (q.y - d)).abs())
            })
            .collect();
        let rms_spread = (spread.iter().map(|v| v * v).sum::<f64>() / spread.len().max(1) as f64).sqrt();
        let steps = AdcResiduals { baseline: current.by_level(&all), extended: own.by_level(&all) };
        findings.push(with_residuals(steps, finding(
            "pixel-nonlinearity",
            None,
            sig,
            tcur.rms(),
            t3.rms(),
            format!("each pixel's own quartic (the paper's correction) beats the shared curve on held-out levels; the pixels' curves depart from it by {:.3}% rms of their signal at their highest held-out level", 100.0 * rms_spread),
        )));
        current = own;
        tcur = t3;
    }
    // Maps: each good pixel's dark and gain under the shared curve (all its levels), the
    // population estimated on even rows and scored on odd rows.
    let curve_for = |i: usize| {
        let a = adc_of(i);
        if adc_own[a] { Response::Curve(adc_curves[a], top) } else { follower_model }
    };
    let dg: Vec<Option<[f64; 2]>> = good
        .par_iter()
        .map(|&i| {
            let all = px.all(i, common);
            let start = fits[i].line[0].map_or(vec![0.0; 2], |l| l.to_vec());
            fit_and_score(curve_for(i), &start, &all, &[]).map(|s| [s.params[0], s.params[1]])
        })
        .collect();
    for (k, what) in [(0usize, "offset"), (1, "gain")] {
        let values: Vec<(usize, bool, f64)> = good.iter().zip(&dg).filter_map(|(&i, v)| Some((adc_of(i), !estimating(i), v.as_ref()?[k]))).collect();
        for Apart { adc: a, significance: sig, before: b, after: af, centre: pm, median, scatter: ps } in adcs_apart(&values, n_adc) {
            let unit = if k == 0 { "DN" } else { "DN at full reference" };
            let part = format!("{what}: ADC {a}'s pixels sit {:+.3} {unit} ({:+.2}%) from the other ADCs' median (pixel scatter {:.3}), pixels of odd rows scored against even rows", median - pm, 100.0 * (median - pm) / pm.abs().max(1e-12), ps);
            match &mut adc_findings[a] {
                Some(f) => {
                    f.detail = format!("{}; {part}", f.detail);
                    if sig > f.significance {
                        (f.significance, f.rms_before, f.rms_after, f.gain) = (sig, b, af, b / af);
                    }
                }
                None => adc_findings[a] = Some(finding("adc-mismatch", Some(a), sig, b, af, part)),
            }
        }
    }
    findings.extend(adc_findings.into_iter().flatten());
    // Bad pixels: scored on the odd levels' dark and gain against the population, plus
    // the held-out level residuals of the pixel's own quartic.
    let flagged: Vec<usize> = (0..n).filter(|&i| bad[i].is_some()).collect();
    if !flagged.is_empty() {
        // A pixel's sum of squares and count of scores.
        let map_z = |i: usize| -> (f64, usize) {
            match (&fits[i].line[1], &fits[i].quartic[0]) {
                (Some(l), Some(q)) => {
                    let z = [(l[0] - own_adc(&dark_adc, i, dark_pop.0)) / dark_pop.1.max(1e-9), (l[1] - own_adc(&gain_adc, i, gain_pop.0)) / gain_pop.1.max(1e-9)];
                    (z[0] * z[0] + z[1] * z[1] + q.held_sq, 2 + usize::from(q.held_n))
                }
                // Stuck: its raw dark level against the population.
                _ => (((px.mean(0, i) - own_adc(&dark_adc, i, dark_pop.0)) / dark_pop.1.max(1e-9)).powi(2), 1),
            }
        };
        // Scored held out: the pixels set apart are those flagged on the even levels alone,
        // and every score is of the odd levels (the odd-level fit's dark and gain, the
        // even-level quartic's residuals there); the count needs both halves.
        let (mut s_all, mut n_all, mut s_ok, mut n_ok) = (0.0, 0usize, 0.0, 0usize);
        for (i, even) in flagged_even.iter().enumerate() {
            let (s, len) = map_z(i);
            s_all += s;
            n_all += len;
            if even.is_none() {
                s_ok += s;
                n_ok += len;
            }
        }
        let (before, after) = ((s_all / n_all.max(1) as f64).sqrt(), (s_ok / n_ok.max(1) as f64).sqrt());
        let kinds = |k: BadPixel| flagged.iter().filter(|&&i| bad[i] == Some(k)).count();
        // The significance is that of the set-apart pixels' odd-level excess over what
        // noise leaves in them (one per residual).
        let removed = (n_all - n_ok) as f64;
        let significance = (s_all - s_ok - removed) / (2.0 * n_all as f64).sqrt();
        if significance > SIGNIFICANCE {
            let mut f = finding(
                "bad-pixels",
                None,
                significance,
                before,
                after,
                format!(
                    "{} pixels the model cannot follow, flagged independently on even and odd levels: {} stuck or hot at saturation, {} whose own quartic fails its levels, {} with a gain outside 0.5-1.5 of the median, {} with a dark level beyond 10 robust sigma",
                    flagged.len(), kinds(BadPixel::Stuck), kinds(BadPixel::Shape), kinds(BadPixel::Gain), kinds(BadPixel::Dark)
                ),
            );
            f.count = Some(flagged.len());
            findings.push(f);
        }
    }
    // Noise: the dark level's temporal noise against the quantization bias.
    let dark_noise = upper_median(good.iter().map(|&i| px.std(0, i)));
    let measured = measure_camera(&px, &good, &fits, set.n_frames, top, bad.iter().filter(|b| b.is_some()).count());
    findings.extend(insufficient_noise("median dark noise", dark_noise, accuracy_dn));
    // The noise model off by one factor everywhere (frames that are not independent) is
    // not structure: the factor is measured on the pixels of even rows and the odd rows
    // scored with it; only what that leaves is `unexplained`.
    let (te, to) = (current.totals(&|c| !c.odd), current.totals(&|c| c.odd));
    let k2 = te.s / te.e.max(1e-300);
    // The factor's own noise (the even rows are as many as the odd ones) is in the
    // denominator: without it the null spread was 1.4, not 1.
    let rescaled = (to.s - k2 * to.e) / (k2 * (to.v + (to.e / te.e.max(1e-300)).powi(2) * te.v).sqrt()).max(1e-300);
    // And alike at every pixel: under a scaled noise each odd-row pixel's held-out sum
    // `S_p` scatters about `k^2 tr C_p` by `k^2 sqrt(2 tr C_p^2)`; structure confined to
    // some pixels (subtle bad pixels) overdisperses it. `(X - G) / sqrt(c G)` over the
    // `G` pixels, `c = 2 + 12 / n` the variance of one term for `n` held-out levels.
    let (mut x_sum, mut g, mut n_sum) = (0.0, 0.0, 0.0);
    for (s, _) in current.per.iter().zip(&good).filter(|(_, &i)| !estimating(i)) {
        if let Some(s) = s {
            let (tr, tr2) = (f64::from(s.tr), f64::from(s.tr2));
            x_sum += (s.sum_sq - k2 * tr).powi(2) / (k2 * k2 * 2.0 * tr2).max(1e-300);
            g += 1.0;
            n_sum += f64::from(s.n);
        }
    }
    let dispersion = if g > 0.0 { (x_sum - g) / ((2.0 + 12.0 * g / n_sum.max(1.0)) * g).sqrt() } else { 0.0 };
    let noise_only = tcur.excess() > SIGNIFICANCE && k2 > 1.0 && rescaled <= SIGNIFICANCE && dispersion <= SIGNIFICANCE;
    if noise_only {
        let rms = current.by_level(&all);
        let scaled = rms.iter().map(|&(l, r)| (l, r / k2.sqrt())).collect();
        findings.push(with_residuals(AdcResiduals { baseline: rms, extended: scaled }, finding(
            "excess-noise",
            None,
            tcur.excess(),
            to.rms(),
            to.rms() / k2.sqrt(),
            format!(
                "the means scatter {:.3} times more than the frames' standard deviations say ({:+.1}% of variance), alike at every level and pixel: frames that are not independent (drift or 1/f noise within a level); measured on even rows, odd rows then {rescaled:.1} standard deviations from their null",
                k2.sqrt(),
                100.0 * (k2 - 1.0)
            ),
        )));
    }
    if tcur.excess() > SIGNIFICANCE && !noise_only {
        findings.push(finding(
            "unexplained",
            None,
            tcur.excess(),
            tcur.rms(),
            tcur.rms(),
            {
                // Where: the levels with the largest mean z^2 over pixels (and their mean
                // DN over the pixels scored there: every held-out point has its z), and
                // per ADC.
                let mut dn = vec![(0.0, 0usize); nl];
                for (s, &i) in current.per.iter().zip(&good) {
                    if s.is_some() {
                        for q in halves(i).1 {
                            dn[q.level].0 += px.mean(q.level, i);
                            dn[q.level].1 += 1;
                        }
                    }
                }
                let mut levels: Vec<(usize, f64, f64)> = current.by_level(&all).into_iter().map(|(l, rms)| (l, rms * rms, dn[l].0 / dn[l].1.max(1) as f64)).collect();
                levels.sort_by(|a, b| b.1.total_cmp(&a.1));
                let worst: Vec<String> = levels.iter().take(3).map(|(l, m, dn)| format!("level {l} ({dn:.0} DN): mean z^2 {m:.2}")).collect();
                let per_adc: Vec<String> = (0..n_adc).map(|a| format!("{:.3}", current.totals(&|c| c.adc == a).rms())).collect();
                format!(
                    "held-out levels still scatter {:.3} times their noise (null {:.3}) under the extended model; not a noise scaled alike everywhere (odd rows {rescaled:.1} standard deviations beyond the even rows' factor {:.3}, pixel-to-pixel dispersion {dispersion:.1}); worst {}; RMS by ADC {}",
                    tcur.rms(),
                    (tcur.e / tcur.n.max(1) as f64).sqrt(),
                    k2.sqrt(),
                    worst.join(", "),
                    per_adc.join(" / ")
                )
            },
        ));
    }
    Ok(Diagnosis {
        not_tested: Vec::new(),
        measured,
        code_density: None,
        code_residuals: None,
        curve_per_dn: global_accepted.then(|| vec![global[0] / top, global[1] / (top * top), global[2] / (top * top * top)]),
        baseline: Baseline {
            kind: "linearity-set".into(),
            model: "linear response with per-pixel dark and gain from one population, shot and read noise".into(),
            adcs: (0..n_adc)
                .map(|a| {
                    let t = base.totals(&|c| c.adc == a);
                    AdcBaseline { adc: a, codes_scored: t.n, rms: t.rms(), by_residue: Vec::new() }
                })
                .collect(),
            rms: t0.rms(),
        },
        findings,
        unexplained_rms: tcur.rms(),
        residuals: vec![AdcResiduals { baseline: base.by_level(&all), extended: current.by_level(&all) }],
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hidden::{linearity_set, pick, Hidden, Plant};
    use rand::SeedableRng;

    fn named(d: &Diagnosis) -> Vec<(String, Option<usize>)> {
        let mut v: Vec<(String, Option<usize>)> = d.findings.iter().map(|f| (f.effect.clone(), f.adc)).collect();
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

    /// Four ADCs of a million pixels each with one skewed spread (an exponential tail,
    /// the odd rows' mean 0.6 above the even rows' median): none is set apart, though the
    /// paired test alone passed 5 sigma at these counts for the chance offsets of the
    /// medians; an offset of 0.05 (about 17 of the gate's standard errors) planted in ADC
    /// 2 is set apart alone, with its size.
    #[test]
    fn a_skewed_spread_is_no_adc_offset_however_many_pixels() {
        use rand_distr::{Distribution, Exp};
        let mut rng = rand::rngs::StdRng::seed_from_u64(9);
        let exp = Exp::new(0.5).unwrap();
        let draw = |rng: &mut rand::rngs::StdRng, shift: f64| -> Vec<(usize, bool, f64)> {
            (0..4_000_000).map(|p: usize| (p % 4, (p / 4) % 2 == 1, 100.0 + exp.sample(rng) + if p % 4 == 2 { shift } else { 0.0 })).collect()
        };
        let none = adcs_apart(&draw(&mut rng, 0.0), 4);
        assert!(none.is_empty(), "{none:?}");
        let one = adcs_apart(&draw(&mut rng, 0.05), 4);
        assert_eq!(one.iter().map(|a| a.adc).collect::<Vec<_>>(), vec![2], "{one:?}");
        assert!((one[0].median - one[0].centre - 0.05).abs() < 0.015, "{one:?}");
        // A fifth ADC with no finite value: not tested, and not in the way of ADC 2.
        let mut five = draw(&mut rng, 0.05);
        five.extend((0..1000).map(|p| (4, p % 2 == 1, if p % 2 == 1 { 101.0 } else { f64::NAN })));
        let found = adcs_apart(&five, 5);
        assert_eq!(found.iter().map(|a| a.adc).collect::<Vec<_>>(), vec![2], "{found:?}");
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
#[path = "linearity_lab_tests.rs"]
mod lab_tests;

#[cfg(test)]
mod bad_input_tests {
    use super::*;
    use crate::hidden::{linearity_set, Plant};

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
        for (what, set) in cases {
            match diagnose_linearity(&set, 0.01) {
                Ok(d) => {
                    for f in &d.findings {
                        assert!(f.significance.is_finite() && f.rms_before.is_finite() && f.rms_after.is_finite(), "{what}: {f:?}");
                    }
                }
                Err(e) => assert!(!e.is_empty(), "{what}"),
            }
        }
    }
}

