//! What a linearity set measures of the camera (for the model file), and the
//! quantization floor of the means its noise model needs.

use rayon::prelude::*;

use crate::analyses::diagnose::cubes::SetView;
use crate::analyses::diagnose::records::Records;
use super::scoring::Scoring;
use crate::analyses::diagnose::Measured;
use super::transfer::{median_chi2, photon_transfer, LightJitter};
use super::populations::populations;
use crate::formats::fits::Sample;

/// Per level, the mean square error a mean of quantized frames carries beyond what their
/// spread shows ([`crate::analyses::quantization::mean_square_bias`] at the analog noise behind the
/// pixels' mean frame variance, [`crate::analyses::quantization::sigma_from_quantized_variance`]):
/// 1/12 DN^2 where every frame reads one code, negligible from 0.5 DN of noise. Without
/// it a set with 0.1 DN of noise gave `bad-pixels` at 950 sigma and `unexplained` at 800
/// (its means were taken to be good to 1/sqrt(12 N) of a code); with the median frame
/// deviation taken for the analog noise (0.3 DN read for 0.17), `unexplained` at 98.
///
/// Over the `n` pixels fitted, `pixel(i)` being the set's pixel that pixel `i` is.
pub(super) fn quantization_floor<T: Sample>(set: &SetView<'_, T>, n: usize, pixel: &(dyn Fn(usize) -> usize + Sync)) -> Vec<f64> {
    let nl = set.levels;
    // Per level, the finite deviations; their upper median (exact, in passes over the
    // pixels: [`crate::infra::select`]) sets the cut.
    let finite = |i: usize, f: &mut dyn FnMut(usize, f64)| {
        set.with_pixel(pixel(i), |at| (0..nl).map(|l| (l, at.std(l))).filter(|(_, v)| v.is_finite()).for_each(|(l, v)| f(l, v)))
    };
    // Noisy or hot pixels out: they are not the level's noise.
    let cut: Vec<f64> = crate::infra::select::upper_medians(n, nl, &finite).into_iter().map(|m| 5.0 * m.max(0.0) + 1.0).collect();
    // Their mean square below the cut, summed in a fixed order ([`crate::analyses::diagnose::TASKS`]).
    let chunk = n.div_ceil(crate::analyses::diagnose::TASKS).max(1);
    let parts: Vec<Vec<(f64, usize)>> = (0..n.div_ceil(chunk))
        .into_par_iter()
        .map(|c| {
            let mut acc = vec![(0.0, 0usize); nl];
            for i in c * chunk..((c + 1) * chunk).min(n) {
                finite(i, &mut |l, v| {
                    if v <= cut[l] {
                        acc[l] = (acc[l].0 + v * v, acc[l].1 + 1);
                    }
                });
            }
            acc
        })
        .collect();
    (0..nl)
        .map(|l| {
            let (sum, count) = parts.iter().fold((0.0, 0), |(s, k), p| (s + p[l].0, k + p[l].1));
            let v = sum / count.max(1) as f64;
            crate::analyses::quantization::mean_square_bias(crate::analyses::quantization::sigma_from_quantized_variance(v))
        })
        .collect()
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
///
/// A set whose level 0 is not at zero reference ([`DARK_REFERENCE`]) has no dark level
/// (issue 58: a consumer camera's series of exposures, level 0 the shortest, read as dark
/// gave its mean for the offset and its shot noise for read noise): each pixel's dark is
/// then its even-level line's intercept at zero reference, the offset their median with
/// its standard error, the signals are over that intercept (level 0 included), the read
/// noise is the photon transfer's intercept only where it stands 2 standard errors above
/// zero (else its upper bound is given), and DSNU is not measured ([`NoDark`]).
///
/// Also the median dark noise, DN (the good pixels' temporal deviation at level 0; without
/// a dark level the read noise where measured, else level 0's deviation, an upper bound).
///
/// Where the frames' spread holds the light's jitter ([`super::transfer`]), the gain and
/// read noise are those of the photon transfer with its term (the gain withheld where
/// that leaves it uncertain by more than 1%, with a note), and the jitter's finding is
/// returned with the notes.
pub(super) fn measure_camera<T: Sample>(scoring: &Scoring<'_, T>, n_frames: u32, bad: usize, curve: Option<[f64; 3]>) -> (Measured, f64, Option<LightJitter>) {
    let (px, good, fits, top) = (scoring.px, &scoring.good, scoring.fits, scoring.top);
    let levels = px.x.len();
    let has_dark = px.x.first().is_some_and(|&x| x.abs() <= DARK_REFERENCE);
    // A pixel's dark level: its level 0, or without a dark level its line's intercept.
    let dark_of = |i: usize, level0: f64| if has_dark { level0 } else { fits.at(i).line(0).map_or(f64::NAN, |l| l[0]) };
    let first = usize::from(has_dark);
    let median_chi2 = median_chi2(n_frames);
    let n_adc = px.n_adc();
    // The medians over the good pixels, exact, in passes over them ([`crate::infra::select`]):
    // cell 0 the dark level, 1 the dark frames' variance of a mean, 2 the signal at the
    // last unsaturated level, then per level the signal and the frames' variance, and
    // last the dark frames' deviation.
    let (dark_cell, noise_cell, full_cell, signal_cell, var_cell) = (0, 1, 2, |l: usize| 3 + 2 * l, |l: usize| 4 + 2 * l);
    let dark_std_cell = 2 * levels + 3;
    let nf = f64::from(n_frames.max(1));
    let medians = crate::infra::select::upper_medians(good.len(), 2 * levels + 4, &|j, f| {
        let i = good.index(j);
        let valid = px.valid(i);
        px.with_levels(i, |at| {
            let dark = dark_of(i, at.mean(0));
            f(dark_cell, dark);
            f(noise_cell, at.std(0).powi(2) / nf);
            f(dark_std_cell, at.std(0));
            if valid > 1 {
                f(full_cell, at.mean(valid - 1) - dark);
            }
            for l in first..valid.min(levels) {
                f(signal_cell(l), at.mean(l) - dark);
                f(var_cell(l), at.std(l).powi(2));
            }
        })
    });
    let (mut s, mut v) = (Vec::new(), Vec::new());
    let dark = medians[dark_cell];
    let mut on = vec![0usize; levels];
    good.iter().for_each(|i| on[..px.valid(i as usize).min(levels)].iter_mut().for_each(|n| *n += 1));
    for l in first..levels {
        if on[l] * 2 < good.len() {
            break;
        }
        let signal = medians[signal_cell(l)];
        if signal > 0.7 * (top - dark) {
            break;
        }
        s.push(signal);
        v.push(medians[var_cell(l)] / median_chi2);
    }
    // The photon transfer through the shared bend, with the light's jitter where found
    // ([`super::transfer`]); the straight line over the medians where it has too few
    // points.
    let transfer = photon_transfer(scoring, n_frames, first, 0.7 * (top - dark), curve, &dark_of);
    let jitter = transfer.as_ref().and_then(|t| t.jitter.clone());
    // Without a dark level the intercept is an extrapolation: the read noise is kept
    // where it is bounded away from zero, else its upper bound is given.
    let read_of = |intercept: f64, se: f64| {
        let read2 = intercept - 1.0 / 12.0;
        if has_dark || read2 > 2.0 * se { (Some(read2.max(0.0).sqrt()), None) } else { (None, Some((read2 + 2.0 * se).max(0.0).sqrt())) }
    };
    let (gain, (read, read_bound)) = if let Some(t) = &transfer {
        (t.gain, read_of(t.intercept, t.intercept_se))
    } else if s.len() >= 3 {
        let (a, b, _) = crate::analyses::emva::fit_line(&s, &v);
        ((b > 0.0).then(|| 1.0 / b), read_of(a, intercept_se(&s, &v, a, b)))
    } else {
        (None, (None, None))
    };
    // DSNU from the dark frames themselves, less their own noise; PRNU from the signal at
    // the level nearest half scale (fitted intercepts and slopes would absorb part of each
    // pixel's own curvature: they read 2.1 DN of DSNU where the camera had 0.9).
    let d_noise = medians[noise_cell] / median_chi2;
    let half = s.iter().enumerate().min_by(|a, b| (a.1 - 0.5 * s.last().copied().unwrap_or(0.0) / 0.7).abs().total_cmp(&(b.1 - 0.5 * s.last().copied().unwrap_or(0.0) / 0.7).abs())).map_or(1, |(j, _)| j + first);
    // Per good pixel its dark mean and its signal at `half` (NaN past its unsaturated
    // levels: left out), kept as records for the passes of the selections.
    let own = Records::from_fn(px.keep(), good.len(), |j| {
        let i = good.index(j);
        // (The signal per colour channel: PRNU within a channel.)
        px.with_levels(i, |at| {
            let dark = dark_of(i, at.mean(0));
            [dark, if half < px.valid(i) { (at.mean(half) - dark) / px.response(i) } else { f64::NAN }]
        })
    });
    // Pixel-to-pixel spreads about each pixel's own ADC's median: an ADC offset or gain is
    // an `adc-mismatch`, not DSNU or PRNU.
    let [(_, _, d_scatter), (_, gm, gs)] = populations(good.len(), n_adc, &|j, f| {
        let (v, adc) = (own.at(j), px.adc(good.index(j)));
        f(0, adc, v[0]);
        f(1, adc, v[1]);
    });
    drop(own);
    // The pixels' quadratic terms on either half, `b2 / gain^2`, where both are finite;
    // their means, then their covariance (two passes in pixel order).
    let b2 = |j: usize| -> Option<(f64, f64)> {
        let f = fits.at(good.index(j));
        let (a, b) = (f.quartic(0)?, f.quartic(1)?);
        Some((a.b2 / a.gain.powi(2), b.b2 / b.gain.powi(2))).filter(|(a, b)| a.is_finite() && b.is_finite())
    };
    let pairs = || (0..good.len()).filter_map(b2);
    // (Each sum from -0.0, as `Sum` takes them.)
    let (count, sa, sb) = pairs().fold((0usize, -0.0, -0.0), |(k, a, b), v| (k + 1, a + v.0, b + v.1));
    let n = count as f64;
    let (ma, mb) = (sa / n, sb / n);
    let cov = pairs().map(|v| (v.0 - ma) * (v.1 - mb)).sum::<f64>() / (n - 1.0);
    // The pixels' spread of signal holds each mean's temporal noise, `V / N` at `half`
    // (less the light's jitter, alike for every pixel): taken out of the PRNU (a
    // consumer camera's few frames a level made it 0.45-0.58% for 0.30-0.34%).
    let temporal = {
        let (sh, vh) = (medians[signal_cell(half)], medians[var_cell(half)] / median_chi2);
        let light = jitter.as_ref().map_or(0.0, |j| (j.rms * sh).powi(2));
        ((vh - light).max(0.0) / nf).sqrt() / sh
    };
    let prnu = gs / gm;
    let prnu = if temporal.is_finite() { (prnu * prnu - temporal * temporal).max(0.0).sqrt() } else { prnu };
    let measured = Measured {
        gain_e_per_dn: gain,
        read_noise_dn: read,
        offset_dn: Some(dark),
        full_scale_dn: Some(medians[full_cell]),
        // (Those unsaturated at the last level are all but the saturated.)
        saturated: (good.len() - on.last().copied().unwrap_or(good.len())) * 2 > good.len(),
        prnu_rms: Some(prnu),
        // (Without dark frames the intercepts' spread holds their fits' errors: not DSNU.)
        dsnu_dn: has_dark.then(|| (d_scatter.powi(2) - d_noise).max(0.0).sqrt()),
        pixel_b2_rms_per_dn: (n > 10.0).then(|| cov.max(0.0).sqrt()),
        bad_fraction: Some(bad as f64 / px.len().max(1) as f64),
        // (Measured by `illumination-change`, where it is found.)
        illumination_change_rms: None,
        cfa: None,
        no_dark: (!has_dark).then(|| NoDark { reference: px.x[0], offset_se_dn: 1.2533 * d_scatter / (good.len().max(1) as f64).sqrt(), read_bound_dn: read_bound }),
        light_jitter_rms: jitter.as_ref().map(|j| j.rms),
        light_series_step: None,
        // (Set with the level term's finding, and from the set's keys.)
        light_level_rms: None,
        reference: Default::default(),
    };
    let noise = if has_dark { medians[dark_std_cell] } else { read.unwrap_or(medians[dark_std_cell]) };
    (measured, noise, jitter)
}

/// The largest reference of a level 0 that is a dark level, as a fraction of the largest
/// (a photodiode's dark reading is not exactly zero).
pub const DARK_REFERENCE: f64 = 1e-3;

/// What a set without a dark level gives of its dark ([`measure_camera`]).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct NoDark {
    /// Level 0's reference over the largest.
    pub reference: f64,
    /// Standard error of the offset (the median of the pixels' intercepts: `1.2533 sd /
    /// sqrt(n)`), DN; the intercepts' extrapolation below level 0 is not in it.
    pub offset_se_dn: f64,
    /// Where the photon transfer's intercept does not bound the read noise: its upper
    /// bound (intercept plus 2 standard errors), DN.
    pub read_bound_dn: Option<f64>,
}

impl NoDark {
    /// The note a diagnosis gives.
    pub fn note(&self, offset_dn: Option<f64>, read_dn: Option<f64>) -> String {
        let offset = offset_dn.map_or("not measured".to_string(), |o| format!("{o:.2} +- {:.2} DN", self.offset_se_dn));
        let read = match (read_dn, self.read_bound_dn) {
            (Some(r), _) => format!("read noise {r:.2} DN from the photon transfer's intercept"),
            (None, Some(b)) => format!("read noise not bounded by the data (below {b:.2} DN at 2 standard errors)"),
            (None, None) => "read noise not measured".to_string(),
        };
        format!(
            "dark level: none in this set (level 0's reference is {:.3} of the largest, not zero): the offset is each pixel's response extrapolated to zero reference, median {offset}; {read}; DSNU and the dark frames' noise are not measured",
            self.reference
        )
    }
}

/// Standard error of the intercept `a` of the least-squares line `y = a + b x`.
fn intercept_se(x: &[f64], y: &[f64], a: f64, b: f64) -> f64 {
    let n = x.len() as f64;
    if n < 3.0 {
        return f64::INFINITY;
    }
    let mx = x.iter().sum::<f64>() / n;
    let sxx: f64 = x.iter().map(|v| (v - mx).powi(2)).sum();
    let res2: f64 = x.iter().zip(y).map(|(x, y)| (y - a - b * x).powi(2)).sum::<f64>() / (n - 2.0);
    (res2 * (1.0 / n + mx * mx / sxx)).sqrt()
}
