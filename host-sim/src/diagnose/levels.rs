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
//! shared bend is also tested with levels as the units ([`smooth_significance`]): the
//! pixels' common residual from straight lines, fitted by `1, x, .., x^4` with each
//! level's variance its noise plus the level-error variance measured here, and the bend
//! terms `x^2 .. x^4` accepted by a Wald test. The variance of the level errors is read
//! from `E[c_e c_o]` against the signal: `tau^2 = tau_black^2 + tau_light^2 S^2`.

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;
use statrs::distribution::ContinuousCDF;

use super::linearity::{fit_and_score, median, robust, Point, Response};
use super::AdcResiduals;

/// Held out by level: the odd rows' estimate in its noise, and its difference from the
/// even rows' in theirs.
fn held_out_by_level(est: &[[(f64, f64); 2]]) -> AdcResiduals {
    let ok = |h: &[(f64, f64); 2]| h.iter().all(|(c, v)| c.is_finite() && *v > 0.0);
    AdcResiduals {
        baseline: est.iter().enumerate().filter(|(_, h)| ok(h)).map(|(l, h)| (l, h[1].0 / h[1].1.sqrt())).collect(),
        extended: est.iter().enumerate().filter(|(_, h)| ok(h)).map(|(l, h)| (l, (h[1].0 - h[0].0) / (h[1].1 + h[0].1).sqrt())).collect(),
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

/// One level's residuals `(r, sigma)` from the pixels of even rows and of odd rows.
type Halves = [Vec<(f64, f64)>; 2];

/// Pixels a level's estimate needs.
const MIN_PIXELS: usize = 10;

/// The common per-level term of a set.
#[derive(Debug, Clone)]
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
    /// Held out by level, common and per ADC: the odd rows' estimate in its noise, and
    /// its difference from the even rows' in theirs ([`held_out_rms`] for their RMS).
    pub by_level: AdcResiduals,
    pub adc_by_level: Vec<AdcResiduals>,
    /// The level errors' spread: light (relative, rms) and black level (DN, rms).
    pub light_rel: f64,
    pub black_dn: f64,
    /// Each pixel's gain over the median (index into the caller's pixels; 1 where it has
    /// no fit), and each ADC's median of it: the light's part of the term scales with it.
    pub gain_ratio: Vec<f64>,
    pub adc_gain_ratio: Vec<f64>,
    /// What the term looks like over the levels (random errors, or a response).
    pub shape: Shape,
    /// Mean signal per level, DN above dark.
    pub signal: Vec<f64>,
    /// Per pixel (index into the caller's pixels), its straight line's residuals on all
    /// levels: (level, residual DN, sigma DN).
    pub line_residuals: Vec<Vec<(usize, f64, f64)>>,
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

impl LevelTerm {
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

    /// `(c, var)` at `level` for a pixel on `adc` with gain ratio `ratio`, from the
    /// estimating pixels, when there is one: the ADC's own where the ADCs differ; the
    /// light's share scaled by the pixel's gain against the pixels the term came from (a
    /// fixed DN amount left an ADC with 3% more gain a residual that read as `adc-dnl`).
    pub fn at(&self, level: usize, adc: usize, ratio: f64) -> Option<(f64, f64)> {
        let adc_ratio = self.adc_gain_ratio.get(adc).copied().unwrap_or(1.0);
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

/// The weighted mean of `(r, sigma)` after a 5-robust-sigma clip in `r / sigma` (bad
/// pixels not yet flagged must not make a level error), and its variance from the
/// scatter.
fn clipped_mean(v: &[(f64, f64)]) -> (f64, f64) {
    if v.len() < MIN_PIXELS {
        return (f64::NAN, f64::NAN);
    }
    let z: Vec<f64> = v.iter().map(|(r, s)| r / s).collect();
    let (m, sd) = robust(&z);
    let keep: Vec<&(f64, f64)> = v.iter().zip(&z).filter(|(_, z)| (*z - m).abs() <= 5.0 * sd.max(1e-12)).map(|(p, _)| p).collect();
    let n = keep.len() as f64;
    if keep.len() < MIN_PIXELS {
        return (f64::NAN, f64::NAN);
    }
    let w: f64 = keep.iter().map(|(_, s)| s.powi(-2)).sum();
    let c = keep.iter().map(|(r, s)| r / (s * s)).sum::<f64>() / w;
    let var = keep.iter().map(|(r, s)| ((r - c) / (s * s)).powi(2)).sum::<f64>() / (w * w) * n / (n - 1.0);
    (c, var)
}

/// Estimates the common per-level term from every pixel's levels (`data[i]` = even and
/// odd levels of pixel `i`), the pixels with `estimating(i)` against the others.
/// `adc[i]` is pixel `i`'s ADC, of `n_adc`.
pub(super) fn level_term(data: &[(Vec<Point>, Vec<Point>)], estimating: &(dyn Fn(usize) -> bool + Sync), adc: &[usize], n_adc: usize, levels: usize) -> LevelTerm {
    let quartic = Response::Poly(4);
    let line = Response::Poly(1);
    // Per pixel: its quartic's and its straight line's residuals on all its levels.
    type Residuals = (Vec<(usize, f64, f64, f64)>, Vec<(usize, f64, f64)>, f64);
    let fits: Vec<Residuals> = data
        .par_iter()
        .map(|(ev, od)| {
            let all: Vec<Point> = ev.iter().chain(od).copied().collect();
            let (Some(q), Some(l)) = (fit_and_score(quartic, &[0.0; 5], &all, &[]), fit_and_score(line, &[0.0; 2], &all, &[])) else {
                return (Vec::new(), Vec::new(), f64::NAN);
            };
            let mut grad = [0.0; 5];
            let at0 = quartic.eval(&q.params, 0.0, &mut grad);
            let quart = all
                .iter()
                .map(|p| {
                    let v = quartic.eval(&q.params, p.x, &mut grad);
                    (p.level, p.y - v, p.sigma, v - at0)
                })
                .collect();
            let lin = all.iter().map(|p| (p.level, p.y - line.eval(&l.params, p.x, &mut grad), p.sigma)).collect();
            (quart, lin, q.params[1])
        })
        .collect();
    let g_median = median(fits.iter().map(|f| f.2).collect());
    let gain_ratio: Vec<f64> = fits.iter().map(|f| if f.2.is_finite() && g_median > 0.0 { f.2 / g_median } else { 1.0 }).collect();
    let adc_gain_ratio: Vec<f64> = (0..n_adc).map(|a| median(gain_ratio.iter().zip(adc).filter(|(_, &b)| b == a).map(|(r, _)| *r).collect())).map(|r| if r.is_finite() { r } else { 1.0 }).collect();
    let mut per: Vec<Halves> = vec![[Vec::new(), Vec::new()]; levels];
    let mut by_adc: Vec<Vec<Halves>> = vec![vec![[Vec::new(), Vec::new()]; levels]; n_adc];
    let mut signal: Vec<Vec<f64>> = vec![Vec::new(); levels];
    for (i, (quart, ..)) in fits.iter().enumerate() {
        let half = usize::from(!estimating(i));
        for &(l, r, s, sig) in quart {
            if l < levels {
                per[l][half].push((r, s));
                if let Some(a) = by_adc.get_mut(adc[i]) {
                    a[l][half].push((r, s));
                }
                signal[l].push(sig);
            }
        }
    }
    let est: Vec<[(f64, f64); 2]> = per.par_iter().map(|h| [clipped_mean(&h[0]), clipped_mean(&h[1])]).collect();
    let signal: Vec<f64> = signal.into_iter().map(median).collect();
    // Agreement of the halves, over the levels where both have an estimate.
    let both: Vec<(usize, f64, f64)> = (0..levels)
        .filter(|&l| est[l].iter().all(|(c, v)| c.is_finite() && *v > 0.0))
        .map(|l| (l, est[l][0].0 / est[l][0].1.sqrt(), est[l][1].0 / est[l][1].1.sqrt()))
        .collect();
    let nl = both.len() as f64;
    let significance = agreement(&both.iter().map(|&(_, a, b)| (a, b)).collect::<Vec<_>>());
    // tau^2 = black^2 + light^2 S^2 from E[c_e c_o] (the noises are independent), weighted
    // by the products' noise; scaled back through the quartic's projection (L / (L - 5)).
    let (mut black2, mut light2) = (0.0, 0.0);
    if both.len() > 8 {
        let rows: Vec<(f64, f64, f64)> = both.iter().map(|&(l, ..)| (est[l][0].0 * est[l][1].0, signal[l].powi(2), 1.0 / (est[l][0].1 * est[l][1].1))).collect();
        let fit = |cols: &[usize]| -> Vec<f64> {
            let k = cols.len();
            let b = DMatrix::from_fn(rows.len(), k, |i, j| if cols[j] == 0 { rows[i].2.sqrt() } else { rows[i].1 * rows[i].2.sqrt() });
            let y = DVector::from_iterator(rows.len(), rows.iter().map(|r| r.0 * r.2.sqrt()));
            b.svd(true, true).solve(&y, 1e-12).map(|s| s.iter().copied().collect()).unwrap_or(vec![0.0; k])
        };
        let both_terms = fit(&[0, 1]);
        (black2, light2) = match (both_terms[0] >= 0.0, both_terms[1] >= 0.0) {
            (true, true) => (both_terms[0], both_terms[1]),
            (true, false) => (fit(&[0])[0].max(0.0), 0.0),
            (false, true) => (0.0, fit(&[1])[0].max(0.0)),
            (false, false) => (0.0, 0.0),
        };
        let scale = nl / (nl - 5.0);
        (black2, light2) = (black2 * scale, light2 * scale);
    }
    // The shape over the levels ordered by signal: where the halves agree (their
    // products), and how the mean estimate runs from level to level.
    let shape = {
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
        // 52% in 1 of 100 sets, hence 70%). Random errors are uncorrelated from level to
        // level (after the quartic's projection, about -1/L); a response is not.
        if total > 0.0 && lows >= 2 && low / total > 0.7 {
            Shape::LowSignal { share: low / total }
        } else if nl > 8.0 && rho > 4.0 / nl.sqrt() {
            Shape::Correlated { rho }
        } else {
            Shape::Random
        }
    };
    // Each ADC's departure from the common term, even rows against odd rows (its variance
    // about `v_a - v`: the common term holds the ADC's own pixels).
    let adc_est: Vec<Vec<[(f64, f64); 2]>> = by_adc.par_iter().map(|a| a.iter().map(|h| [clipped_mean(&h[0]), clipped_mean(&h[1])]).collect()).collect();
    let adc_significance: Vec<f64> = if n_adc >= 2 {
        adc_est
            .iter()
            .enumerate()
            .map(|(ai, a)| {
                // The common term as this ADC's pixels would see it: light and black level
                // both through the ADC's gain (a 3% ADC gain beside 1 DN of black-level
                // errors read as `adc-dnl` in 14 of 16 sets when only the light's share was
                // scaled).
                let scale = adc_gain_ratio[ai];
                let d: Vec<(f64, f64)> = (0..levels)
                    .filter_map(|l| {
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
    } else {
        Vec::new()
    };
    let per_adc = adc_significance.iter().any(|&t| t > super::SIGNIFICANCE).then(|| adc_est.iter().map(|a| a.iter().map(|h| h[0]).collect()).collect());
    let by_level = held_out_by_level(&est);
    let adc_by_level: Vec<AdcResiduals> = adc_est.iter().map(|a| held_out_by_level(a)).collect();
    LevelTerm {
        by_level,
        adc_by_level,
        c: est.iter().map(|e| e[0].0).collect(),
        var: est.iter().map(|e| e[0].1).collect(),
        significance,
        per_adc,
        adc_significance,
        light_rel: light2.sqrt(),
        black_dn: black2.sqrt(),
        gain_ratio,
        adc_gain_ratio,
        shape,
        signal,
        line_residuals: fits.into_iter().map(|f| f.1).collect(),
    }
}

/// The shared bend with levels as the units: the common residual of the selected pixels'
/// straight lines (`sel` on the index into the pixels), fitted by `1, x, .., x^4` with
/// each level's variance the noise of the mean plus the level errors' `tau^2`, and the
/// Wald statistic of the `x^2 .. x^4` terms against `F(3, L - 5)` as a one-sided normal
/// deviate. `x` is the reference per level.
pub(super) fn smooth_significance(term: &LevelTerm, x: &[f64], sel: &(dyn Fn(usize) -> bool + Sync)) -> f64 {
    let levels = x.len();
    let mut per: Vec<Vec<(f64, f64)>> = vec![Vec::new(); levels];
    for (_, res) in term.line_residuals.iter().enumerate().filter(|(i, _)| sel(*i)) {
        for &(l, r, s) in res {
            if l < levels {
                per[l].push((r, s));
            }
        }
    }
    let rows: Vec<(f64, f64, f64)> = (0..levels)
        .filter_map(|l| {
            let (c, v) = clipped_mean(&per[l]);
            let u = v + term.tau2(term.signal[l]);
            (c.is_finite() && u > 0.0 && x[l].is_finite()).then_some((x[l], c, u))
        })
        .collect();
    if rows.len() < 8 {
        return 0.0;
    }
    let n = rows.len();
    let b = DMatrix::from_fn(n, 5, |i, k| rows[i].0.powi(k as i32) / rows[i].2.sqrt());
    let y = DVector::from_iterator(n, rows.iter().map(|r| r.1 / r.2.sqrt()));
    if !(b.iter().all(|v| v.is_finite()) && y.iter().all(|v| v.is_finite())) {
        return 0.0;
    }
    let Some(cov) = (b.transpose() * &b).try_inverse() else { return 0.0 };
    let beta = &cov * b.transpose() * y;
    let bend = beta.rows(2, 3).into_owned();
    let Some(inv) = cov.view((2, 2), (3, 3)).into_owned().try_inverse() else { return 0.0 };
    let chi2 = (bend.transpose() * inv * &bend)[(0, 0)];
    // Against F(3, L - 5), not chi^2_3: the level errors' variance is itself estimated
    // from those levels (with chi^2_3, 2 of 600 sets with large level errors and no bend
    // passed 5 sigma). As a one-sided normal deviate; past f64's tail, Wilson-Hilferty.
    let dof = (n - 5) as f64;
    let k = 3.0;
    let p = statrs::distribution::FisherSnedecor::new(k, dof).map(|f| f.sf(chi2 / k)).unwrap_or(f64::NAN);
    if p.is_finite() && p > 1e-300 {
        -statrs::distribution::Normal::standard().inverse_cdf(p.min(0.5))
    } else {
        let h = 2.0 / (9.0 * k);
        ((chi2 / k).cbrt() - (1.0 - h)) / h.sqrt()
    }
}
