//! Per-level errors common to every pixel of a linearity set: the light at a level off
//! from what the reference detector says (source flicker the diode does not see), the
//! black level off at one acquisition. In a lab they are the rule, and a test over pixels
//! cannot see them: every pixel carries the same error, so a shared curve that follows a
//! chance part of it looks significant pixel after pixel (an independent review found
//! false `adc-mismatch` findings at 27 standard deviations for 2e-4 of light error).
//!
//! ## What can be told apart
//! With one reference, a level error that is smooth in the signal is a shared
//! nonlinearity: no analysis of one set separates them. What can be seen is the part that
//! is *not* smooth: each pixel's own quartic over all its levels takes every smooth
//! response, and what its residuals share at a level is the level's error (seen through
//! the quartic's projection). Drawn independently on the pixels of even rows and of odd
//! rows, the two estimates `c_e`, `c_o` agree only if the error is real; their agreement
//! `T = sum_l a_l b_l / sqrt(tr(A B))` (`a`, `b` the estimates in their own noise,
//! `A`, `B` their correlation over levels, about the projection's, `tr(A B)` about
//! `L^2 / (L - 5)` for `L` levels) is the test. Where it is accepted, the even rows'
//! estimate is taken out of every pixel's means before any model is fitted.
//!
//! An ADC's DN error looks the same from one ADC: its pixels' means are off at a level by
//! its integral nonlinearity at the codes they read. So each ADC's departure from the
//! common term is tested the same way (even rows against odd rows); where one stands out
//! the term is taken per ADC, and the caller names those ADCs `adc-dnl` instead of calling
//! the common part the light's.
//!
//! The smooth part of random level errors stays and looks like a shared bend, so the
//! shared bend is also tested with levels as the units ([`wald`] with [`Block::Bend`]): the
//! pixels' common residual from straight lines, fitted by `1, x, .., x^4` with each
//! level's variance its noise plus the level-error variance measured here, and the bend
//! terms `x^2 .. x^4` accepted by a Wald test. The variance of the level errors is read
//! from `E[c_e c_o]` against the signal: `tau^2 = tau_black^2 + tau_light^2 S^2`.
//!
//! Every fit and mean here weighs a pixel's means by its frame variance smoothed over its
//! levels ([`Pixels::all_smoothed`]), not by each mean's own: the means carry the level
//! errors, which can be several times their noise, and each pixel's noisy weights gave
//! each pixel a different share of them.

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;
use statrs::distribution::ContinuousCDF;

use super::pixel_fit::{fit_and_score, Point, Response};
use super::points::{Common, Pixels};
use super::records::{Put, Record, Records, Take};
use super::smooth_noise::NoiseFit;
use crate::formats::fits::Sample;
use super::AdcResiduals;

/// Held out by level, over the levels `on`: the odd rows' estimate in its noise, and its
/// difference from the even rows' in theirs.
fn held_out_by_level(est: &[[(f64, f64); 2]], on: impl Fn(usize) -> bool) -> AdcResiduals {
    let ok = |l: usize, h: &[(f64, f64); 2]| on(l) && h.iter().all(|(c, v)| c.is_finite() && *v > 0.0);
    AdcResiduals {
        baseline: est.iter().enumerate().filter(|(l, h)| ok(*l, h)).map(|(l, h)| (l, h[1].0 / h[1].1.sqrt())).collect(),
        extended: est.iter().enumerate().filter(|(l, h)| ok(*l, h)).map(|(l, h)| (l, (h[1].0 - h[0].0) / (h[1].1 + h[0].1).sqrt())).collect(),
    }
}

/// RMS of the held-out residuals before and after a level term ([`held_out_by_level`]).
pub(super) fn held_out_rms(r: &AdcResiduals) -> (f64, f64) {
    let rms = |v: &[(usize, f64)]| (v.iter().map(|(_, z)| z * z).sum::<f64>() / v.len().max(1) as f64).sqrt();
    (rms(&r.baseline), rms(&r.extended))
}

/// The agreement of two independent estimates over levels, each in its own noise
/// (`(a_l, b_l)`): `sum a b / sqrt(tr(A B))`, `tr(A B)` about `L^2 / (L - 5)` after the
/// quartic's projection; 0 with 8 levels or fewer.
fn agreement(pairs: &[(f64, f64)]) -> f64 {
    let n = pairs.len() as f64;
    if pairs.len() > 8 { pairs.iter().map(|(a, b)| a * b).sum::<f64>() / (n / (n - 5.0).sqrt()) } else { 0.0 }
}

/// Pixels a level's estimate needs.
const MIN_PIXELS: usize = 10;

/// The common per-level term of a set.
#[derive(Debug)]
pub(super) struct LevelTerm {
    /// Per level, the common residual of the estimating (even-row) pixels, DN, and its
    /// variance, DN^2 (NaN where a level has too few pixels).
    pub c: Vec<f64>,
    pub var: Vec<f64>,
    /// The agreement of the two in standard deviations.
    pub significance: f64,
    /// Per ADC, when the ADCs' own terms differ beyond noise (an ADC's integral
    /// nonlinearity at the codes its pixels read, not the light): each ADC's term from
    /// the estimating pixels `(c, var)` per level, and per ADC the agreement of its
    /// departure from the common term between even and odd rows, in standard deviations.
    pub per_adc: Option<Vec<Vec<(f64, f64)>>>,
    pub adc_significance: Vec<f64>,
    /// Held out by level, common and per ADC, over the levels the tests use: the odd
    /// rows' estimate in its noise, and its difference from the even rows' in theirs
    /// ([`held_out_rms`] for their RMS); the same over the skipped levels.
    pub by_level: AdcResiduals,
    pub adc_by_level: Vec<AdcResiduals>,
    pub skipped_by_level: AdcResiduals,
    /// The levels that took no part in the fits and tests (their term extrapolated), or
    /// with a term over all levels, those left out of the shared bend's test ([`wald`]).
    pub(super) skip: Vec<bool>,
    /// The level errors' spread: light (relative, rms) and black level (DN, rms), and the
    /// covariance of the estimates of their squares (black^2 in DN^2, light^2).
    pub light_rel: f64,
    pub black_dn: f64,
    tau_cov: [[f64; 2]; 2],
    /// Each pixel's quartic, quadratic and line over all its levels (index into the
    /// caller's pixels; held or spilled), the reference per level, and per level the
    /// median over pixels of their quadratics' slopes there, DN per reference unit: a
    /// level's error moves a pixel's mean by its local slope (the light's part) or its
    /// ADC's (the black level's), and an ADC that bends changes its slope along the range
    /// (one gain per pixel left a 1% bend beside large level errors reading as `adc-dnl`
    /// in 8 of 12 sets). A quadratic's slope, not the quartic's: at the ends of the range
    /// the quartic's is about 5 times noisier (its slope's variance there goes as
    /// `sum_k (2k + 1) (k (k + 1) / 2)^2` over its degrees, 1,200 against 48), and 2%
    /// light errors taken out through it left 4-7% more than the noise.
    fits: Records<LevelFit>,
    x: Vec<f64>,
    slope_median: Vec<f64>,
    /// Per ADC and level, the median of its pixels' slope ratios ([`LevelTerm::slope_ratio`]).
    pub adc_ratio: Vec<Vec<f64>>,
    /// What the term looks like over the levels (random errors, or a response).
    pub shape: Shape,
    /// Mean signal per level, DN above dark.
    pub signal: Vec<f64>,
}

/// The shape of the common term over the levels, ordered by signal: level errors are
/// independent from level to level and spread over the range; a response every pixel
/// shares (a charge loss at low signal) is neither.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Shape {
    /// Spread over the range, uncorrelated from level to level.
    Random,
    /// More than 70% of the agreement of the halves (in their noise) in the lowest 10% of
    /// the signal.
    LowSignal { share: f64 },
    /// Correlated from level to level beyond 4 / sqrt(L).
    Correlated { rho: f64 },
}

/// The slope of `sum_k q_k x^k` at `x`.
fn slope(q: &[f64; 5], x: f64) -> f64 {
    q[1] + x * (2.0 * q[2] + x * (3.0 * q[3] + x * 4.0 * q[4]))
}

/// A polynomial's slope at `x` over the median slope `m` there (1 where either is unknown).
fn slope_over(q: Option<&[f64; 5]>, x: f64, m: f64) -> f64 {
    let r = q.map_or(f64::NAN, |q| slope(q, x) / m);
    if r.is_finite() && m > 0.0 { r } else { 1.0 }
}

/// Two groups of levels whose light differs by a step ([`LevelTerm::series`]): two
/// exposure series that disagree.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Series {
    /// The brighter group's mean relative light error less the dimmer's (about its light
    /// over the dimmer's, less 1).
    pub step: f64,
    /// Its standard error.
    pub step_se: f64,
    /// The levels of the brighter group (ascending), and of the dimmer.
    pub high: Vec<usize>,
    pub low: Vec<usize>,
    /// The rms of a level's light error within its group (relative).
    pub within: f64,
}

impl Series {
    /// What the level errors' finding says of it.
    pub fn text(&self) -> String {
        let parity = |v: &[usize], odd: bool| v.iter().all(|l| (l % 2 == 1) == odd);
        let name = |v: &[usize]| {
            if parity(v, true) {
                "the odd levels".to_string()
            } else if parity(v, false) {
                "the even levels".to_string()
            } else {
                let shown: Vec<String> = v.iter().take(12).map(|l| l.to_string()).collect();
                format!("levels {}{}", shown.join(", "), if v.len() > 12 { ", ..." } else { "" })
            }
        };
        format!(
            "; its light part falls into two groups of levels, {} {:.2}% +- {:.2}% brighter than {} (each level within {:.2e} of its group): two series that disagree (a light that drifted between them, an aperture or shutter off its mark), the light's, not the sensor's",
            name(&self.high),
            100.0 * self.step,
            100.0 * self.step_se,
            name(&self.low),
            self.within
        )
    }
}

/// The fewest levels each group of [`LevelTerm::series`] needs: 3, and a quarter of
/// the levels (a few outlying levels, a flash during one of them, are not a series: with
/// 10% of the levels at 10 times the others' scatter, groups of 3 were named in 8% of 37
/// levels, an independent review's simulation).
fn series_min(levels: usize) -> usize {
    (levels / 4).max(3)
}

/// Two groups of levels: `(high levels, low levels, step, its standard error, scatter
/// within)`, relative light errors.
type Split = (Vec<usize>, Vec<usize>, f64, f64, f64);

/// The split of `rel` (each level's relative light error and its index) into two groups
/// of [`series_min`] levels or more where the step between their means, over the scatter
/// within them, is largest: `(high levels, low levels, step, its standard error, scatter
/// within)`, where the step is at least 6 times the scatter within and 10 standard errors.
/// Random Gaussian errors split so give a step about 3 times the scatter (its 99.9th
/// percentile 5.8 at 15 levels, 4.1 at 40; the review's simulation).
fn two_groups(mut rel: Vec<(f64, usize)>) -> Option<Split> {
    let n = rel.len();
    let least = series_min(n);
    if n < 2 * least + 2 {
        return None;
    }
    rel.sort_by(|a, b| a.0.total_cmp(&b.0));
    let stats = |v: &[(f64, usize)]| {
        let m = v.iter().map(|r| r.0).sum::<f64>() / v.len() as f64;
        (m, v.iter().map(|r| (r.0 - m).powi(2)).sum::<f64>())
    };
    let (k, step, within) = (least..=n - least)
        .map(|k| {
            let ((ml, sl), (mh, sh)) = (stats(&rel[..k]), stats(&rel[k..]));
            (k, mh - ml, ((sl + sh) / (n - 2) as f64).sqrt())
        })
        .max_by(|a, b| (a.1 / a.2).total_cmp(&(b.1 / b.2)))?;
    let se = within * (1.0 / k as f64 + 1.0 / (n - k) as f64).sqrt();
    if !(step > 6.0 * within && step > 10.0 * se) {
        return None;
    }
    let levels = |v: &[(f64, usize)]| {
        let mut l: Vec<usize> = v.iter().map(|r| r.1).collect();
        l.sort_unstable();
        l
    };
    Some((levels(&rel[k..]), levels(&rel[..k]), step, se, within))
}

impl LevelTerm {
    /// The level errors' light part as two groups of levels, where it is that: each
    /// level's relative light error (its term over its median slope times its reference,
    /// at levels above 10% of the top signal, where the black level's part is small),
    /// split by [`two_groups`]. Two series that disagree by more than their own level
    /// errors give a step far above the scatter within.
    pub fn series(&self) -> Option<Series> {
        let top = self.signal.iter().cloned().filter(|s| s.is_finite()).fold(0.0, f64::max);
        let rel: Vec<(f64, usize)> = (0..self.c.len())
            .filter(|&l| !self.skip.get(l).copied().unwrap_or(false) && self.signal[l] > 0.1 * top)
            .filter_map(|l| {
                let scale = self.x.get(l)? * self.slope_median.get(l)?;
                let r = self.c[l] / scale;
                (r.is_finite() && scale > 0.0).then_some((r, l))
            })
            .collect();
        let (high, low, step, step_se, within) = two_groups(rel)?;
        Some(Series { step, step_se, high, low, within })
    }

    /// The slope at `level` of a pixel's own quadratic `q` (as a quartic's coefficients)
    /// over the median pixel's there (1 where either is unknown).
    pub fn slope_ratio(&self, q: Option<&[f64; 5]>, level: usize) -> f64 {
        let (Some(&x), Some(&m)) = (self.x.get(level), self.slope_median.get(level)) else { return 1.0 };
        slope_over(q, x, m)
    }

    /// Only the levels `on` keep their term (a departure at the lowest signals accepted
    /// where the level errors are not).
    pub fn keep_only(&mut self, on: impl Fn(usize) -> bool) {
        for l in (0..self.c.len()).filter(|&l| !on(l)) {
            (self.c[l], self.var[l]) = (0.0, 0.0);
        }
        for a in self.per_adc.iter_mut().flatten() {
            a.iter_mut().enumerate().filter(|(l, _)| !on(*l)).for_each(|(_, cv)| *cv = (0.0, 0.0));
        }
    }

    /// The light's share of the variance at level `l`.
    fn light_share(&self, l: usize) -> f64 {
        let s = self.signal.get(l).copied().unwrap_or(0.0);
        let t = self.tau2(s);
        if t > 0.0 { (self.light_rel * s).powi(2) / t } else { 0.0 }
    }

    /// `tau^2` at signal `s`: the variance of one level's error, DN^2.
    fn tau2(&self, s: f64) -> f64 {
        self.black_dn.powi(2) + (self.light_rel * s).powi(2)
    }

    /// The variance of the estimate of `tau^2` at signal `s`, DN^4.
    fn tau2_var(&self, s: f64) -> f64 {
        quadratic_form([1.0, s * s], &self.tau_cov).max(0.0)
    }
}

/// `v^T c v`: the variance of `v . x` for estimates `x` of covariance `c`.
fn quadratic_form(v: [f64; 2], c: &[[f64; 2]; 2]) -> f64 {
    v[0] * (c[0][0] * v[0] + c[0][1] * v[1]) + v[1] * (c[1][0] * v[0] + c[1][1] * v[1])
}

impl Common for LevelTerm {
    /// The pixel's quadratic through all its levels (its slopes scale the light's part).
    fn shape(&self, i: usize) -> Option<[f64; 5]> {
        self.fits.at(i).slopes
    }

    /// `(c, var)` at `level` for a pixel on `adc` of quadratic `shape`, from the estimating
    /// pixels, when there is one: the ADC's own where the ADCs differ; the light's share
    /// scaled by the pixel's slope there against the pixels the term came from (a fixed
    /// DN amount left an ADC with 3% more gain a residual that read as `adc-dnl`).
    fn at(&self, level: usize, _i: usize, adc: usize, shape: Option<&[f64; 5]>) -> Option<(f64, f64)> {
        let ratio = self.slope_ratio(shape, level);
        let adc_ratio = self.adc_ratio.get(adc).and_then(|r| r.get(level)).copied().unwrap_or(1.0);
        // The black level's part goes through the ADC's gain (an analog offset ahead of
        // it), the light's through the pixel's; a per-ADC term already carries its ADC's.
        let (c, v, base, black) = match &self.per_adc {
            Some(per) => {
                let (c, v) = *per.get(adc)?.get(level)?;
                (c, v, adc_ratio, 1.0)
            }
            None => (*self.c.get(level)?, *self.var.get(level)?, 1.0, adc_ratio),
        };
        let f = self.light_share(level);
        let scale = (1.0 - f) * black + f * ratio / base;
        (c.is_finite() && v.is_finite() && scale.is_finite()).then_some((c * scale, v * scale * scale))
    }
}

/// A clipped mean of one cell: the weighted mean `c` of its `(r, sigma)`, DN, after a
/// 5-robust-sigma clip in `r / sigma` (bad pixels not yet flagged must not make a level
/// error), its variance from the scatter, DN^2 (both NaN with fewer than [`MIN_PIXELS`]
/// values, before or after the clip), and the values the cell had.
#[derive(Debug, Clone, Copy)]
struct Clipped {
    c: f64,
    var: f64,
    count: usize,
}

/// A pixel's fits through its levels, where it has them: its quartic `sum_k q_k x^k`
/// (whose residuals the term is made of), its quadratic (whose slopes scale the light's
/// part of the term) and its straight line (dark DN, DN per reference unit; [`wald`]
/// tests what the lines leave), all or none; and its frame variance over its levels, by
/// which each pass weighs its means ([`Pixels::all_smoothed`]).
#[derive(Debug, Clone, Copy)]
struct LevelFit {
    quartic: Option<[f64; 5]>,
    /// The quadratic as a quartic's coefficients (the last two 0).
    slopes: Option<[f64; 5]>,
    line: Option<[f64; 2]>,
    noise: NoiseFit,
}

/// Bytes a pixel's level fits take held (the budget's `RECORD_BYTES` counts them).
#[cfg(test)]
pub(super) const LEVEL_FIT_BYTES: usize = std::mem::size_of::<LevelFit>();

impl Record for LevelFit {
    const BYTES: usize = 1 + 10 * 8 + NoiseFit::BYTES;
    const LOST: LevelFit = LevelFit { quartic: None, slopes: None, line: None, noise: NoiseFit::NONE };
    fn put(&self, out: &mut Put<'_>) {
        out.u8(u8::from(self.quartic.is_some()) | u8::from(self.line.is_some()) << 1 | u8::from(self.slopes.is_some()) << 2);
        let slopes = self.slopes.unwrap_or([f64::NAN; 5]);
        self.quartic.unwrap_or([f64::NAN; 5]).into_iter().chain(slopes[..3].iter().copied()).chain(self.line.unwrap_or([f64::NAN; 2])).for_each(|v| out.f64(v));
        self.noise.put(out);
    }
    fn take(from: &mut Take<'_>) -> Self {
        let fitted = from.u8();
        let quartic = [(); 5].map(|_| from.f64());
        let slopes = [from.f64(), from.f64(), from.f64(), 0.0, 0.0];
        let line = [from.f64(), from.f64()];
        let noise = NoiseFit::take(from);
        LevelFit { quartic: (fitted & 1 == 1).then_some(quartic), slopes: (fitted & 4 == 4).then_some(slopes), line: (fitted & 2 == 2).then_some(line), noise }
    }
}

/// Visits the residuals of pixel `i`: calls `f(cell, r, sigma)` for each.
type Visit<'a> = dyn Fn(usize, &mut dyn FnMut(usize, f64, f64)) + Sync + 'a;

/// The clipped means of `cells` cells over the residuals of `n` pixels, in passes over
/// the pixels (their residuals are recomputed, not held): the robust centre and spread
/// of every cell's `z = r / sigma` ([`crate::infra::select::robust`], exact, a histogram per
/// cell), then the weighted sums of what the clip keeps, then their scatter about the
/// mean.
fn clipped_means(n: usize, cells: usize, visit: &Visit) -> Vec<Clipped> {
    // Six passes over the same residuals: recorded once, as far as they fit, and read
    // back by each ([`crate::infra::recorded`]; the same values in the same order, so the
    // same sums).
    crate::infra::recorded::within(n, &|i, f| visit(i, &mut |k, r, s| f(k, (r, s))), |v| clipped_means_of(n, cells, &|i, f| v(i, &mut |k, (r, s)| f(k, r, s))))
}

/// [`clipped_means`] in its passes over `visit`.
fn clipped_means_of(n: usize, cells: usize, visit: &Visit) -> Vec<Clipped> {
    let clip = crate::infra::select::robust_replayed(n, cells, &|i, f| visit(i, &mut |k, r, s| f(k, r / s)));
    let clip: Vec<(f64, f64)> = clip.into_iter().map(|(m, sd)| (m, 5.0 * sd.max(1e-12))).collect();
    let kept = |k: usize, r: f64, s: f64| clip[k].0.is_finite() && (r / s - clip[k].0).abs() <= clip[k].1;
    // Per cell: values, kept values, `sum 1 / s^2`, `sum r / s^2`; then the scatter.
    let sums = |first: bool, c: &[f64]| -> Vec<[f64; 4]> {
        // Task sums added in task order ([`super::TASKS`]).
        let t = super::TASKS.clamp(1, n.max(1));
        let parts: Vec<Vec<[f64; 4]>> = (0..t)
            .into_par_iter()
            .map(|task| {
                let mut acc = vec![[0.0; 4]; cells];
                for i in (task * n / t)..((task + 1) * n / t) {
                    visit(i, &mut |k, r, s| {
                        let a = &mut acc[k];
                        if first {
                            a[0] += 1.0;
                        }
                        if kept(k, r, s) {
                            if first {
                                a[1] += 1.0;
                                a[2] += s.powi(-2);
                                a[3] += r / (s * s);
                            } else {
                                a[1] += ((r - c[k]) / (s * s)).powi(2);
                            }
                        }
                    });
                }
                acc
            })
            .collect();
        parts.into_iter().fold(vec![[0.0; 4]; cells], |mut a, b| {
            a.iter_mut().zip(&b).for_each(|(x, y)| (0..4).for_each(|j| x[j] += y[j]));
            a
        })
    };
    let first = sums(true, &[]);
    let enough = |a: &[f64; 4]| a[0] as usize >= MIN_PIXELS && a[1] as usize >= MIN_PIXELS;
    let c: Vec<f64> = first.iter().map(|a| if enough(a) { a[3] / a[2] } else { f64::NAN }).collect();
    let scatter = sums(false, &c);
    (0..cells)
        .map(|k| {
            let [count, m, w, _] = first[k];
            let var = if c[k].is_finite() { scatter[k][1] / (w * w) * m / (m - 1.0) } else { f64::NAN };
            Clipped { c: c[k], var, count: count as usize }
        })
        .collect()
}

/// Per pixel, weighed by its smoothed variances: its quartic and its straight line
/// through its levels not skipped (`skip`), and its quadratic through all its levels (its
/// slopes are taken at every level, the skipped ones too).
fn pixel_fits<T: Sample>(px: &Pixels<T>, skip: &[bool]) -> Records<LevelFit> {
    let skipped = |l: usize| skip.get(l).copied().unwrap_or(false);
    let (quartic, quadratic, line) = (Response::Poly(4), Response::Poly(2), Response::Poly(1));
    Records::from_fn(px.keep(), px.len(), |i| {
        let noise = px.noise_fit(i);
        let all = px.all_smoothed(i, &noise);
        let used: Vec<Point> = all.iter().copied().filter(|p| !skipped(p.level)).collect();
        match (fit_and_score(quartic, &[0.0; 5], &used, &[]), fit_and_score(quadratic, &[0.0; 3], &all, &[]), fit_and_score(line, &[0.0; 2], &used, &[])) {
            (Some(q), Some(s), Some(l)) => LevelFit {
                quartic: q.params.get(..5).and_then(|p| p.try_into().ok()),
                slopes: s.params.get(..3).map(|p| [p[0], p[1], p[2], 0.0, 0.0]),
                line: Some([l.params[0], l.params[1]]),
                noise,
            },
            _ => LevelFit::LOST,
        }
    })
}

/// `tau^2 = black^2 + light^2 S^2`, the variance of the level errors, from the halves'
/// products `E[c_e c_o]` over the levels `both` (level, even z, odd z) with the per-level
/// estimates `est` and signals `signal`: (black^2 DN^2, light^2, their covariance).
fn fit_tau(both: &[(usize, f64, f64)], est: &[[(f64, f64); 2]], signal: &[f64]) -> (f64, f64, [[f64; 2]; 2]) {
    let nl = both.len() as f64;
    let (mut black2, mut light2) = (0.0, 0.0);
    let mut tau_cov = [[0.0; 2]; 2];
    if both.len() > 8 {
        let scale = nl / (nl - 5.0);
        for _ in 0..4 {
            let rows: Vec<(f64, f64, f64)> = both
                .iter()
                .map(|&(l, ..)| {
                    let s2 = signal[l].powi(2);
                    let t = (black2 + light2 * s2) / scale;
                    (est[l][0].0 * est[l][1].0, s2, 1.0 / ((t + est[l][0].1) * (t + est[l][1].1) + t * t))
                })
                .collect();
            // The weighted fit on the columns `cols` (0: black, 1: light), as (black^2,
            // light^2) and their covariance.
            let fit = |cols: &[usize]| -> ([f64; 2], [[f64; 2]; 2]) {
                let k = cols.len();
                let b = DMatrix::from_fn(rows.len(), k, |i, j| if cols[j] == 0 { rows[i].2.sqrt() } else { rows[i].1 * rows[i].2.sqrt() });
                let y = DVector::from_iterator(rows.len(), rows.iter().map(|r| r.0 * r.2.sqrt()));
                let (mut beta, mut cov) = ([0.0; 2], [[0.0; 2]; 2]);
                if let Some(inv) = (b.transpose() * &b).try_inverse() {
                    let sol = &inv * b.transpose() * y;
                    for (j, &cj) in cols.iter().enumerate() {
                        beta[cj] = sol[j];
                        for (m, &cm) in cols.iter().enumerate() {
                            cov[cj][cm] = inv[(j, m)];
                        }
                    }
                }
                (beta, cov)
            };
            // Where one square comes out negative it is taken as 0 and the other refitted
            // alone; the covariance stays the pair's (the clamp does not make the estimate
            // surer: 0 DN of black level beside 1 DN planted gave a test against it 6 sigma).
            let (terms, cov) = fit(&[0, 1]);
            let terms = match (terms[0] >= 0.0, terms[1] >= 0.0) {
                (true, true) => terms,
                (true, false) => fit(&[0]).0,
                (false, true) => fit(&[1]).0,
                (false, false) => [0.0; 2],
            };
            (black2, light2) = (terms[0].max(0.0) * scale, terms[1].max(0.0) * scale);
            tau_cov = cov.map(|r| r.map(|c| c * scale * scale));
        }
    }
    (black2, light2, tau_cov)
}

/// The shape of the level term over the levels `both` (level, even z, odd z) ordered by
/// `signal`: how the mean estimate runs from level to level. Random errors are
/// uncorrelated from level to level (after the quartic's projection, about -1/L); a
/// response is not.
fn level_shape(both: &[(usize, f64, f64)], signal: &[f64]) -> Shape {
    let nl = both.len() as f64;
    let mut ordered: Vec<(f64, f64, f64)> = both.iter().map(|&(l, a, b)| (signal[l], a * b, 0.5 * (a + b))).collect();
    ordered.sort_by(|x, y| x.0.total_cmp(&y.0));
    let top = ordered.last().map_or(0.0, |o| o.0);
    let total: f64 = ordered.iter().map(|o| o.1).sum();
    let low: f64 = ordered.iter().filter(|o| o.0 < 0.1 * top).map(|o| o.1).sum();
    let lows = ordered.iter().filter(|o| o.0 < 0.1 * top).count();
    let m2: f64 = ordered.iter().map(|o| o.2 * o.2).sum();
    let rho = ordered.windows(2).map(|w| w[0].2 * w[1].2).sum::<f64>() / m2.max(1e-300);
    // A departure at the lowest signals puts most of the halves' agreement there (a
    // charge loss of 0.5 DN: 82%); random errors spread it, though in noise units the
    // quiet low levels weigh about six times more (random black-level errors reached
    // 52% in 1 of 100 sets, hence 70%). Beside level errors the share is diluted: see
    // [`Block::Levels`].
    if total > 0.0 && lows >= 2 && low / total > 0.7 {
        Shape::LowSignal { share: low / total }
    } else if nl > 8.0 && rho > 4.0 / nl.sqrt() {
        Shape::Correlated { rho }
    } else {
        Shape::Random
    }
}

/// Each ADC's departure from the common term, even rows against odd rows (its variance
/// about `v_a - v`: the common term holds the ADC's own pixels), from the per-ADC
/// estimates `adc_est`, the common `est` and each ADC's slope ratio per level.
fn adc_departures(adc_est: &[Vec<[(f64, f64); 2]>], est: &[[(f64, f64); 2]], adc_ratio: &[Vec<f64>], skipped: &dyn Fn(usize) -> bool) -> Vec<f64> {
    let levels = est.len();
    adc_est
        .iter()
        .enumerate()
        .map(|(ai, a)| {
            // The common term as this ADC's pixels would see it: light and black level
            // both through the ADC's gain (a 3% ADC gain beside 1 DN of black-level
            // errors read as `adc-dnl` in 14 of 16 sets when only the light's share was
            // scaled).
            let d: Vec<(f64, f64)> = (0..levels)
                .filter(|&l| !skipped(l))
                .filter_map(|l| {
                    let scale = adc_ratio[ai][l];
                    let side = |h: usize| {
                        let ((ca, va), (c, v)) = (a[l][h], est[l][h]);
                        let var = va - v * scale * scale;
                        (ca.is_finite() && c.is_finite() && var > 0.0).then(|| (ca - c * scale) / var.sqrt())
                    };
                    Some((side(0)?, side(1)?))
                })
                .collect();
            agreement(&d)
        })
        .collect()
}

/// Per level, the pixels' mean colour-channel response ([`Pixels::response`]) weighted
/// by `1 / sigma^2` of their points as the term's means weigh them, over all the pixels
/// with a quartic and per ADC (`[a * levels + l]`); all 1 without a colour filter.
fn mean_response<T: Sample>(px: &Pixels<T>, fits: &Records<LevelFit>, levels: usize, n_adc: usize) -> (Vec<f64>, Vec<f64>) {
    if px.cells() == 1 {
        return (vec![1.0; levels], vec![1.0; levels * n_adc]);
    }
    let n = px.len();
    // Sums of `w` and `w r` per level (first `levels`) and per ADC and level, in chunks
    // summed in a fixed order ([`super::TASKS`]).
    let chunk = n.div_ceil(super::TASKS).max(1);
    let parts: Vec<Vec<(f64, f64)>> = (0..n.div_ceil(chunk))
        .into_par_iter()
        .map(|c| {
            let mut acc = vec![(0.0, 0.0); levels * (1 + n_adc)];
            for i in c * chunk..((c + 1) * chunk).min(n) {
                let fit = fits.at(i);
                if fit.quartic.is_none() {
                    continue;
                }
                let (r, a) = (px.response(i), px.adc(i));
                for p in px.all_smoothed(i, &fit.noise).iter().filter(|p| p.level < levels && p.sigma > 0.0) {
                    let w = 1.0 / (p.sigma * p.sigma);
                    for k in [p.level, levels + a * levels + p.level] {
                        acc[k] = (acc[k].0 + w, acc[k].1 + w * r);
                    }
                }
            }
            acc
        })
        .collect();
    let mean = |k: usize| {
        let (w, wr) = parts.iter().fold((0.0, 0.0), |(w, wr), p| (w + p[k].0, wr + p[k].1));
        if w > 0.0 { wr / w } else { 1.0 }
    };
    ((0..levels).map(mean).collect(), (0..levels * n_adc).map(|k| mean(levels + k)).collect())
}

/// Estimates the common per-level term from every pixel's levels, the pixels of even rows
/// against those of odd rows ([`Pixels::estimating`]). Levels with `skip[l]` take no part
/// in the pixels' fits or in the tests: their term is what the fits of the others leave
/// there (a departure at the lowest signals, which a quartic over all levels spreads over
/// the range where it passes for level errors).
pub(super) fn level_term<T: Sample>(px: &Pixels<T>, skip: &[bool]) -> LevelTerm {
    let levels = skip.len();
    let (n, n_adc, x) = (px.len(), px.n_adc(), &px.x);
    let skipped = |l: usize| skip.get(l).copied().unwrap_or(false);
    let quartic = Response::Poly(4);
    let fits = pixel_fits(px, skip);
    // The pixels' local slopes at each level, each over its colour channel's response:
    // one population (a colour filter's channels are not its outliers).
    // (Medians by exact selection in passes over the pixels' fits: [`crate::infra::select`].)
    let slope_norm = crate::infra::select::upper_medians(n, x.len(), &|i, f| {
        if let Some(q) = fits.at(i).slopes {
            let r = px.response(i);
            x.iter().enumerate().for_each(|(l, &xl)| f(l, slope(&q, xl) / r));
        }
    });
    // The term is a mean of residuals that scale with each pixel's slope, so its light's
    // part goes with the channels' mean response, weighted as the term's means weigh the
    // pixels: the median slope is the channel-free median times it (a median over a Bayer
    // filter's channels fell on one of them, and two ADCs' terms departed from the common
    // one as `adc-dnl`). 1 without a filter.
    let (response_all, response_adc) = mean_response(px, &fits, levels, n_adc);
    let slope_median: Vec<f64> = slope_norm.iter().enumerate().map(|(l, m)| m * response_all.get(l).copied().unwrap_or(1.0)).collect();
    // Per level, each ADC's median slope ratio, channel-free, times its channels' mean
    // response over all the pixels'.
    let ratios = crate::infra::select::upper_medians(n, levels * n_adc, &|i, f| {
        let (q, a, r) = (fits.at(i).slopes, px.adc(i), px.response(i));
        (0..levels).for_each(|l| f(l * n_adc + a, slope_over(q.as_ref(), x[l], slope_norm[l]) / r));
    });
    let ratios: Vec<f64> = (0..levels * n_adc).map(|k| ratios[k] * response_adc[(k % n_adc) * levels + k / n_adc] / response_all[k / n_adc]).collect();
    let adc_ratio: Vec<Vec<f64>> = (0..n_adc).map(|a| (0..levels).map(|l| Some(ratios[l * n_adc + a]).filter(|r| r.is_finite()).unwrap_or(1.0)).collect()).collect();
    // Each pixel's quartic residuals on all its levels, recomputed per pass: (level,
    // residual DN, sigma DN, the quartic's signal there above its dark).
    let quartic_residuals = |i: usize, f: &mut dyn FnMut(usize, f64, f64, f64)| {
        let fit = fits.at(i);
        let Some(q) = &fit.quartic else { return };
        let mut grad = [0.0; 5];
        let at0 = quartic.eval(q, 0.0, &mut grad);
        for p in px.all_smoothed(i, &fit.noise).iter().filter(|p| p.level < levels) {
            let v = quartic.eval(q, p.x, &mut grad);
            f(p.level, p.y - v, p.sigma, v - at0);
        }
    };
    let half = |i: usize| usize::from(!px.estimating(i));
    // Cells: per level and half, then per ADC, level and half.
    let adc_cell = |a: usize, l: usize, h: usize| 2 * levels + 2 * (a * levels + l) + h;
    let means = clipped_means(n, 2 * levels * (1 + n_adc), &|i, f| {
        let (a, h) = (px.adc(i), half(i));
        quartic_residuals(i, &mut |l, r, s, _| {
            f(2 * l + h, r, s);
            f(adc_cell(a, l, h), r, s);
        })
    });
    let est: Vec<[(f64, f64); 2]> = (0..levels).map(|l| [0, 1].map(|h| (means[2 * l + h].c, means[2 * l + h].var))).collect();
    let adc_est: Vec<Vec<[(f64, f64); 2]>> = (0..n_adc).map(|a| (0..levels).map(|l| [0, 1].map(|h| (means[adc_cell(a, l, h)].c, means[adc_cell(a, l, h)].var))).collect()).collect();
    // The signal per level: the median over pixels of their quartics' signal there.
    let signal = crate::infra::select::upper_medians(n, levels, &|i, f| quartic_residuals(i, &mut |l, _, _, sig| f(l, sig)));
    // Agreement of the halves, over the levels where both have an estimate.
    let both: Vec<(usize, f64, f64)> = (0..levels)
        .filter(|&l| !skipped(l) && est[l].iter().all(|(c, v)| c.is_finite() && *v > 0.0))
        .map(|l| (l, est[l][0].0 / est[l][0].1.sqrt(), est[l][1].0 / est[l][1].1.sqrt()))
        .collect();
    let significance = agreement(&both.iter().map(|&(_, a, b)| (a, b)).collect::<Vec<_>>());
    // tau^2 = black^2 + light^2 S^2 from E[c_e c_o] (the noises are independent), each
    // product weighted by its variance `(t + v_e)(t + v_o) + t^2` at the current `tau^2`
    // (`t`), iterated from `t = 0`; scaled back through the quartic's projection
    // (L / (L - 5)). Weighted by the noises alone, the quiet low levels carried the fit:
    // its `tau^2` had the spread of a few levels', and a test against it at the low levels
    // passed 5 sigma in 4 of 300 sets of level errors alone.
    let (black2, light2, tau_cov) = fit_tau(&both, &est, &signal);
    // The shape over the levels ordered by signal: how the mean estimate runs from level
    // to level. Random errors are uncorrelated from level to level (after the quartic's
    // projection, about -1/L); a response is not.
    let shape = level_shape(&both, &signal);
    // Each ADC's departure from the common term, even rows against odd rows (its variance
    // about `v_a - v`: the common term holds the ADC's own pixels).
    let adc_significance = if n_adc >= 2 { adc_departures(&adc_est, &est, &adc_ratio, &skipped) } else { Vec::new() };
    let per_adc = adc_significance.iter().any(|&t| t > super::SIGNIFICANCE).then(|| adc_est.iter().map(|a| a.iter().map(|h| h[0]).collect()).collect());
    let by_level = held_out_by_level(&est, |l| !skipped(l));
    let skipped_by_level = held_out_by_level(&est, skipped);
    let adc_by_level: Vec<AdcResiduals> = adc_est.iter().map(|a| held_out_by_level(a, |l| !skipped(l))).collect();
    LevelTerm {
        by_level,
        adc_by_level,
        skipped_by_level,
        skip: skip.to_vec(),
        c: est.iter().map(|e| e[0].0).collect(),
        var: est.iter().map(|e| e[0].1).collect(),
        significance,
        per_adc,
        adc_significance,
        light_rel: light2.sqrt(),
        black_dn: black2.sqrt(),
        tau_cov,
        fits,
        x: x.to_vec(),
        slope_median,
        adc_ratio,
        shape,
        signal,
    }
}

/// What [`wald`] tests beyond `1, x, .., x^4`.
#[derive(Debug, Clone, Copy)]
pub(super) enum Block<'a> {
    /// The bend: the `x^2 .. x^4` terms.
    Bend,
    /// A free offset at each level `l` with `on[l]` (a departure at those levels that no
    /// quartic through the others follows).
    Levels(&'a [bool]),
}

/// A shared response with levels as the units: the common residual of the selected
/// pixels' straight lines (`sel` on the index into the pixels), fitted by `1, x, .., x^4`
/// and the `block`'s terms with each level's variance the noise of the mean plus the
/// level errors' `tau^2`, and the Wald statistic of the block against `F(k, L - p)` (`k`
/// tested of `p` terms) as a one-sided normal deviate.
pub(super) fn wald<T: Sample>(term: &LevelTerm, px: &Pixels<T>, sel: &(dyn Fn(usize) -> bool + Sync), block: Block) -> f64 {
    let x = &term.x;
    let levels = x.len();
    // Each ADC's clipped mean, then their plain mean: one clip over all pixels cut an
    // ADC whose line bends away from the others' at some levels and not at others (a
    // false low-signal departure at 12 sigma beside a 1.4% ADC curvature), and weights
    // that change from level to level would mix the ADCs' curves into no polynomial.
    // With too few pixels per ADC for their own clipped means (a 6 x 6 sensor), one
    // clip over all (it turned the bend's test off: no row, significance 0).
    let n_adc = px.n_adc();
    let mut counts = vec![0usize; n_adc];
    (0..px.len()).filter(|&i| sel(i)).for_each(|i| counts[px.adc(i)] += 1);
    let pooled = counts.iter().any(|&c| c > 0 && c < 2 * MIN_PIXELS);
    let group = |i: usize| if pooled { 0 } else { px.adc(i) };
    let line = Response::Poly(1);
    let per = clipped_means(px.len(), n_adc * levels, &|i, f| {
        let fit = term.fits.at(i);
        let Some(p) = fit.line.filter(|_| sel(i)) else { return };
        let mut grad = [0.0; 2];
        for q in px.all_smoothed(i, &fit.noise).iter().filter(|q| q.level < levels) {
            f(group(i) * levels + q.level, q.y - line.eval(&p, q.x, &mut grad), q.sigma);
        }
    });
    // The groups with residuals at any level.
    let groups: Vec<usize> = (0..n_adc).filter(|&g| (0..levels).any(|l| per[g * levels + l].count > 0)).collect();
    let rows: Vec<(usize, f64, f64, f64)> = (0..levels)
        .filter_map(|l| {
            let each: Vec<(f64, f64)> = groups.iter().map(|&g| (per[g * levels + l].c, per[g * levels + l].var)).collect();
            let k = each.len() as f64;
            let (c, v) = (each.iter().map(|e| e.0).sum::<f64>() / k, each.iter().map(|e| e.1).sum::<f64>() / (k * k));
            // A block of levels is tested against an upper bound of the level errors'
            // variance there (estimate plus twice its standard error): it is extrapolated
            // from the levels above, and black-level errors beside larger light errors rest
            // on a few of them (with the estimate alone, 4 of 300 sets of level errors
            // alone passed 5 sigma at the lowest levels).
            let s = term.signal[l];
            let bound = if matches!(block, Block::Levels(_)) { 2.0 * term.tau2_var(s).sqrt() } else { 0.0 };
            let u = v + term.tau2(s) + bound;
            // The skipped levels take part only in the test of their own departure.
            let used = matches!(block, Block::Levels(_)) || !term.skip.get(l).copied().unwrap_or(false);
            (used && c.is_finite() && u > 0.0 && x[l].is_finite()).then_some((l, x[l], c, u))
        })
        .collect();
    let free: Vec<usize> = match block {
        Block::Bend => Vec::new(),
        Block::Levels(on) => rows.iter().map(|r| r.0).filter(|&l| on.get(l).copied().unwrap_or(false)).collect(),
    };
    let (cols, tested) = match block {
        Block::Bend => (5, 2..5),
        Block::Levels(_) => (5 + free.len(), 5..5 + free.len()),
    };
    let k = tested.len();
    if k == 0 || rows.len() < cols + 3 {
        return 0.0;
    }
    let n = rows.len();
    let b = DMatrix::from_fn(n, cols, |i, j| {
        let (l, xl, _, u) = rows[i];
        let v = if j < 5 { xl.powi(j as i32) } else { f64::from(u8::from(free[j - 5] == l)) };
        v / u.sqrt()
    });
    let y = DVector::from_iterator(n, rows.iter().map(|r| r.2 / r.3.sqrt()));
    if !(b.iter().all(|v| v.is_finite()) && y.iter().all(|v| v.is_finite())) {
        return 0.0;
    }
    let Some(cov) = (b.transpose() * &b).try_inverse() else { return 0.0 };
    let beta = &cov * b.transpose() * y;
    let part = beta.rows(tested.start, k).into_owned();
    let Some(inv) = cov.view((tested.start, tested.start), (k, k)).into_owned().try_inverse() else { return 0.0 };
    let chi2 = (part.transpose() * inv * &part)[(0, 0)];
    // Against F(k, L - p), not chi^2_k: the level errors' variance is itself estimated
    // from those levels (with chi^2_3, 2 of 600 sets with large level errors and no bend
    // passed 5 sigma). As a one-sided normal deviate; past f64's tail, Wilson-Hilferty.
    let dof = (n - cols) as f64;
    let kf = k as f64;
    let p = statrs::distribution::FisherSnedecor::new(kf, dof).map(|f| f.sf(chi2 / kf)).unwrap_or(f64::NAN);
    if p.is_finite() && p > 1e-300 {
        -statrs::distribution::Normal::standard().inverse_cdf(p.min(0.5))
    } else {
        let h = 2.0 / (9.0 * kf);
        ((chi2 / kf).cbrt() - (1.0 - h)) / h.sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`two_groups`] on drawn level errors: Gaussian ones (8-40 levels, 2,000 draws
    /// each) and ones with a tenth of the levels at 10 times the scatter are split into
    /// series in at most 1% of draws (0.5% at 8 levels by the review's simulation); a
    /// step of 20 times the scatter between interleaved halves is found, its groups the
    /// halves and its size within 10%.
    #[test]
    fn two_groups_are_named_for_a_step_and_seldom_for_noise() {
        use rand::{rngs::StdRng, Rng, SeedableRng};
        use rand_distr::{Distribution, Normal};
        let mut rng = StdRng::seed_from_u64(59);
        let unit = Normal::new(0.0, 1.0).unwrap();
        for n in [8usize, 12, 15, 20, 30, 40] {
            for outliers in [false, true] {
                let draws = 2000;
                let named = (0..draws)
                    .filter(|_| {
                        let rel: Vec<(f64, usize)> = (0..n).map(|l| (unit.sample(&mut rng) * if outliers && rng.random_bool(0.1) { 10.0 } else { 1.0 }, l)).collect();
                        two_groups(rel).is_some()
                    })
                    .count();
                assert!(named * 100 <= draws, "{n} levels, outliers {outliers}: {named} of {draws}");
            }
            let rel: Vec<(f64, usize)> = (0..n).map(|l| (unit.sample(&mut rng) + if l % 2 == 1 { 20.0 } else { 0.0 }, l)).collect();
            let (high, low, step, se, _) = two_groups(rel).unwrap_or_else(|| panic!("{n} levels: no step"));
            assert!(high.iter().all(|l| l % 2 == 1) && low.iter().all(|l| l % 2 == 0) && high.len() + low.len() == n);
            assert!((step / 20.0 - 1.0).abs() < 0.1 && se < 1.0, "{n} levels: step {step} +- {se}");
        }
    }

    /// The clipped means with the residuals recorded once are those of six passes over
    /// the visit itself, bit for bit (outliers clipped, a cell with too few pixels NaN);
    /// and the centre is the clipped weighted mean worked by hand.
    #[test]
    fn clipped_means_recorded_are_the_passes_over_the_visit() {
        let n = 3000;
        // Pixel i: cell i % 3 at r = a smooth spread with every 50th an outlier, sigma
        // from 1 to 2; cell 3 only from the first 5 pixels (below MIN_PIXELS).
        let r = |i: usize| if i % 50 == 7 { 1e3 } else { ((i * 7919) % 1000) as f64 / 500.0 - 1.0 };
        let s = |i: usize| 1.0 + (i % 11) as f64 / 10.0;
        let visits = std::sync::atomic::AtomicUsize::new(0);
        let visit = |i: usize, f: &mut dyn FnMut(usize, f64, f64)| {
            visits.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            f(i % 3, r(i), s(i));
            if i < 5 {
                f(3, r(i), s(i));
            }
        };
        let recorded = clipped_means(n, 4, &visit);
        // Each pixel visited once, on the recording's pass; the passes over the visit
        // itself visit each pixel four times (the median and the deviation one pass each
        // here, their cells' 1 000 values sampled whole, then the two sums).
        assert_eq!(visits.swap(0, std::sync::atomic::Ordering::Relaxed), n);
        let passes = clipped_means_of(n, 4, &visit);
        assert_eq!(visits.load(std::sync::atomic::Ordering::Relaxed), 4 * n);
        for (a, b) in recorded.iter().zip(&passes) {
            assert_eq!((a.c.to_bits(), a.var.to_bits(), a.count), (b.c.to_bits(), b.var.to_bits(), b.count));
        }
        assert!(recorded[3].c.is_nan() && recorded[3].count == 5);
        // By hand: cell 0 without its outliers (all beyond 5 robust deviations), weighted 1 / s^2.
        let kept: Vec<usize> = (0..n).filter(|i| i % 3 == 0 && i % 50 != 7).collect();
        let (w, wr) = kept.iter().fold((0.0, 0.0), |(w, wr), &i| (w + s(i).powi(-2), wr + r(i) / (s(i) * s(i))));
        assert!((recorded[0].c - wr / w).abs() < 1e-12, "{} against {}", recorded[0].c, wr / w);
        assert_eq!(recorded[0].count, 1000);
    }

    /// A pixel's level fits spilled and read back: both, neither, or a line alone, the
    /// values bit for bit.
    #[test]
    fn level_fits_read_back_as_written() {
        let q = [1.0, -0.0, 2.5e-300, -7.0, f64::MAX];
        let s = [4.0, -1e-300, 9.5, 0.0, 0.0];
        let m: Vec<f64> = (0..8).map(f64::from).collect();
        let noise = NoiseFit::new(&m, &[1.0, 2.0, 3.5, 4.0, 5.0, 6.5, 7.0, 8.0]);
        for f in [LevelFit { quartic: Some(q), slopes: Some(s), line: Some([3.0, -4.0]), noise }, LevelFit::LOST, LevelFit { quartic: None, slopes: None, line: Some([0.5, 0.25]), noise: NoiseFit::NONE }, LevelFit { quartic: None, slopes: Some(s), line: None, noise }] {
            let back = super::super::records::round_trip(f);
            // (The noise fit by what it gives at a level, its own bytes tested beside it.)
            let bits = |f: LevelFit| (f.quartic.map(|q| q.map(f64::to_bits)), f.slopes.map(|q| q.map(f64::to_bits)), f.line.map(|l| l.map(f64::to_bits)), f.noise.variance(3.0, 2.0, 8).to_bits());
            assert_eq!(bits(back), bits(f));
        }
    }

    #[test]
    fn the_variance_of_tau2_is_the_quadratic_form_by_hand() {
        // v = (1, s^2) at s = 2; both off-diagonal terms differ so that each is seen:
        // 1*4*1 + 1*1.5*4 + 4*0.5*1 + 4*9*4 = 156.
        assert_eq!(quadratic_form([1.0, 4.0], &[[4.0, 1.5], [0.5, 9.0]]), 156.0);
        // Against nalgebra's product.
        let (v, c) = (nalgebra::Vector2::new(0.3, -2.0), nalgebra::Matrix2::new(2.0, -0.7, -0.7, 5.0));
        let want = (v.transpose() * c * v)[(0, 0)];
        assert!((quadratic_form([0.3, -2.0], &[[2.0, -0.7], [-0.7, 5.0]]) - want).abs() < 1e-12);
    }
}
