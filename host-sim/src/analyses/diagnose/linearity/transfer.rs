//! The photon transfer of a linearity set, and the light as a suspect in the frames'
//! spread (issue 58): a light that differs from frame to frame within a level (a
//! flickering source, a shutter's jitter, daylight) moves every pixel of a frame alike,
//! so each pixel's frames spread by the sensor's noise and by `e S`, `e` the frame's
//! relative light error and `S` the pixel's signal. The standard deviation cube then
//! holds a variance `J S^2` over the photon transfer (`J` the frames' light variance),
//! which a straight photon transfer reads as a gain too low (a consumer camera's 1-5%
//! jitter made it 4-5 times too low).
//!
//! ## The photon transfer
//! Per level and colour channel (a colour filter's cells; one without a filter): the
//! median signal `S` over the good pixels and the median frame variance `V` (over the
//! median of `chi^2`), whose noise is `V 1.2533 sqrt(2 / (N - 1)) / sqrt(n)`. Where the
//! diagnosis named a shared bend `G` (`global-nonlinearity`), `S = G(L)` is inverted for
//! the linear signal `L`: a nonlinearity of the conversion bends the photon transfer
//! too (`var = G'(L)^2 L / K`), and a straight line would read that as a gain off by
//! about `3 c2`. The model `V = r^2 + G'(L)^2 L / K`, weighted least squares.
//!
//! ## The light's jitter
//! With the jitter, `+ J (G'(L) L)^2`, refitted with each point's noise grown by the
//! jitter's own scatter between levels (the frames of a level draw their light's
//! variance with `N - 1` degrees of freedom: `sqrt(2 / (N - 1))` of it) and the
//! coefficients' errors scaled by the residuals' reduced `chi^2` where above 1. Named
//! when its t statistic passes [`SIGNIFICANCE`], the term fitted on the even levels
//! alone and on the odd levels alone is positive both times (held out by levels), and
//! it is at least 1% of the frames' variance at the brightest point (less would move
//! the gain by less than that). The held-out residuals of each model on the other half,
//! in the sensor's noise, are the finding's before and after.
//!
//! ## What it gives
//! The jitter's rms `sqrt(J)` with its standard error, and the gain and read noise of the
//! model with the jitter on all the levels (where a colour filter gives channels of
//! different signal within a level, each level's own `J_l`: what its frames drew); the
//! gain is withheld where its standard error is above 1%. A straight line over the
//! levels' medians stands in where fewer than 8 points are in the range
//! ([`super::camera`]).

use super::scoring::Scoring;
use crate::analyses::diagnose::{Effect, Finding, SIGNIFICANCE};
use crate::formats::fits::Sample;

/// What [`photon_transfer`] found of the light's jitter.
#[derive(Debug, Clone)]
pub(super) struct LightJitter {
    /// The frames' light, relative rms from frame to frame within a level.
    pub rms: f64,
    /// Its standard error.
    pub rms_se: f64,
    /// The jitter's term over its standard error in the model on all the levels.
    pub significance: f64,
    /// Held-out residuals of the frames' variance, rms in their noise: without and with
    /// the jitter.
    pub rms_before: f64,
    pub rms_after: f64,
    /// The jitter's share of the frames' variance at the brightest point fitted.
    pub share_top: f64,
    /// Conversion gain of the photon transfer with the jitter, e-/DN; `None` where its
    /// relative standard error is above [`GAIN_SE`].
    pub gain: Option<f64>,
    /// The gain's relative standard error.
    pub gain_rel_se: f64,
    /// The frames' variance over the straight signal `L` (less the intercept) at the
    /// faintest and at the brightest level fitted (pooled over the channels), DN: a
    /// sensor's photon transfer keeps it at `1 / G`.
    pub ratio: (f64, f64),
}

/// The photon transfer of a linearity set ([`photon_transfer`]).
#[derive(Debug, Clone)]
pub(super) struct PhotonTransfer {
    /// Conversion gain, e-/DN (`None` where not positive, or withheld under the light's
    /// jitter).
    pub gain: Option<f64>,
    /// The intercept (read noise squared plus a code's quantization), DN^2, with its
    /// standard error.
    pub intercept: f64,
    pub intercept_se: f64,
    /// The light's jitter, where found.
    pub jitter: Option<LightJitter>,
}

/// The largest relative standard error of a gain the model file gets.
pub(super) const GAIN_SE: f64 = 0.01;

/// One level of one channel: its median frame variance `v` (DN^2) with its noise, the
/// shot-noise regressor `u = s^2 L` and the jitter's `w = (S'(x) x)^2`.
#[derive(Debug, Clone, Copy)]
struct Point {
    level: usize,
    v: f64,
    sigma: f64,
    u: f64,
    w: f64,
    l: f64,
}

/// The median of `chi^2_(N-1) / (N-1)` for `n_frames` frames, `(1 - 2 / (9 (N-1)))^3`
/// (Wilson-Hilferty): the median of `s^2` is `sigma^2` times it (taken as 1 it read the
/// variance 0.26% low at 256 frames, and the gain with it).
pub(super) fn median_chi2(n_frames: u32) -> f64 {
    let dof = f64::from(n_frames.max(2)) - 1.0;
    (1.0 - 2.0 / (9.0 * dof)).powi(3)
}

/// The photon transfer and the light's jitter from the frames' spread (module
/// documentation), over the good pixels of `scoring`: `dark_of(i, level 0's mean)` is
/// pixel `i`'s dark level, `first` the first level with light, `limit` the signal above
/// which levels are left out (the photon transfer's range), `curve` the shared bend
/// (`global-nonlinearity`'s coefficients) where one was named. `None` where fewer than 8
/// points (levels and channels) are in the range.
pub(super) fn photon_transfer<T: Sample>(scoring: &Scoring<'_, T>, n_frames: u32, first: usize, limit: f64, curve: Option<[f64; 3]>, dark_of: &(dyn Fn(usize, f64) -> f64 + Sync)) -> Option<PhotonTransfer> {
    let top = scoring.top;
    let (px, good) = (scoring.px, &scoring.good);
    let (levels, cells) = (px.x.len(), px.cells());
    let dof = f64::from(n_frames.max(2)) - 1.0;
    let median_chi2 = median_chi2(n_frames);
    // Per level and cell: the median signal, the median variance.
    let at = |l: usize, k: usize| 2 * (l * cells + k);
    let medians = crate::infra::select::upper_medians(good.len(), 2 * levels * cells, &|j, f| {
        let i = good.index(j);
        let (valid, k) = (px.valid(i).min(levels), px.cell(i));
        px.with_levels(i, |m| {
            let dark = dark_of(i, m.mean(0));
            for l in first..valid {
                f(at(l, k), m.mean(l) - dark);
                f(at(l, k) + 1, m.std(l).powi(2));
            }
        })
    });
    let mut count = vec![0usize; cells];
    good.iter().for_each(|i| count[px.cell(i as usize)] += 1);
    // The shared bend's value and slope at a linear signal `S` (DN), `G(S)` and `G'(S)`.
    let bend = |s: f64| curve.map_or((s, 1.0), |c| {
        let t = s / top;
        (s * (1.0 + t * (c[0] + t * (c[1] + t * c[2]))), 1.0 + t * (2.0 * c[0] + t * (3.0 * c[1] + 4.0 * t * c[2])))
    });
    let mut points = Vec::new();
    for (k, &n) in count.iter().enumerate() {
        if n < 10 {
            continue;
        }
        for l in first..levels {
            let (s, v) = (medians[at(l, k)], medians[at(l, k) + 1] / median_chi2);
            if !(s.is_finite() && v.is_finite() && s <= limit) {
                break;
            }
            // The linear signal under the bend (Newton from the signal itself).
            let mut lin = s;
            for _ in 0..8 {
                let (g, d) = bend(lin);
                if d.is_nan() || d <= 0.0 {
                    break;
                }
                lin -= (g - s) / d;
            }
            let d = bend(lin).1;
            if !(s > 0.0 && lin > 0.0 && d > 0.0) {
                continue;
            }
            // The median of `n` sample variances: `V * 1.2533 sqrt(2 / dof) / sqrt(n)`.
            let sigma = v * 1.2533 * (2.0 / dof).sqrt() / (n as f64).sqrt();
            points.push(Point { level: l, v, sigma, u: d * d * lin, w: (d * lin).powi(2), l: lin });
        }
    }
    if points.len() < 8 {
        return None;
    }
    // The jitter's sample variance over `N` frames scatters by `sqrt(2 / (N - 1))` of it
    // from level to level.
    let spread = 2.0 / dof;
    let transfer = fit(&points, Model::Transfer, spread)?;
    let plain = PhotonTransfer { gain: (transfer.coef[1] > 0.0).then(|| 1.0 / transfer.coef[1]), intercept: transfer.coef[0], intercept_se: transfer.var[0].sqrt(), jitter: None };
    // The jitter's term in the model fitted on all the levels, against its standard
    // error (reweighted: each level drew its own frames' jitter, and the residuals'
    // spread scales it where above the sensor's noise): a t statistic. Held out by levels,
    // the term fitted on the even levels alone and on the odd alone must both be
    // positive, and each model's residuals on the other half (in the sensor's noise) give
    // the finding's before and after.
    let Some(all) = fit(&points, Model::Jitter, spread) else { return Some(plain) };
    let j = all.coef[2];
    let significance = j / all.var[2].sqrt();
    let (mut before, mut after, mut scored, mut halves) = (0.0, 0.0, 0usize, true);
    for h in 0..2 {
        let (fit_on, test): (Vec<Point>, Vec<Point>) = points.iter().partition(|p| p.level % 2 == h);
        let (Some(m0), Some(m1)) = (fit(&fit_on, Model::Transfer, spread), fit(&fit_on, Model::Jitter, spread)) else { return Some(plain) };
        halves &= m1.coef[2] > 0.0;
        for p in &test {
            before += ((p.v - m0.coef[0] - m0.coef[1] * p.u) / p.sigma).powi(2);
            after += ((p.v - m1.coef[0] - m1.coef[1] * p.u - m1.coef[2] * p.w) / p.sigma).powi(2);
            scored += 1;
        }
    }
    let brightest = points.iter().max_by(|a, b| a.w.total_cmp(&b.w))?;
    let share_top = j * brightest.w / brightest.v;
    if !(significance > SIGNIFICANCE && halves && share_top >= 0.01) {
        return Some(plain);
    }
    // The gain: where the channels' signals differ within a level (a colour filter), each
    // level's jitter on its own (what the frames of that level drew), else the model's.
    // (With a filter the common-jitter model's errors are too small, its channels sharing
    // each level's draw: where each level's own fails, the gain is withheld.)
    let per_level = (cells > 1).then(|| fit(&points, Model::PerLevel, spread)).flatten();
    let for_gain = per_level.as_ref().unwrap_or(&all);
    // (Where the jitter swamps the shot noise the slope may come out at or below zero:
    // not bounded at all.)
    let gain_rel_se = if for_gain.coef[1] > 0.0 && (cells == 1 || per_level.is_some()) { for_gain.var[1].sqrt() / for_gain.coef[1] } else { f64::INFINITY };
    let rms = j.sqrt();
    // Variance over the straight signal at the faintest and the brightest levels.
    let (lo, hi) = (points.iter().map(|p| p.level).min()?, points.iter().map(|p| p.level).max()?);
    let ratio_at = |level: usize| {
        let (s, n) = points.iter().filter(|p| p.level == level).fold((0.0, 0usize), |(s, n), p| (s + (p.v - for_gain.coef[0]) / p.l, n + 1));
        s / n.max(1) as f64
    };
    let gain = (gain_rel_se <= GAIN_SE).then(|| 1.0 / for_gain.coef[1]);
    let jitter = LightJitter {
        rms,
        rms_se: all.var[2].sqrt() / (2.0 * rms),
        significance,
        rms_before: (before / scored.max(1) as f64).sqrt(),
        rms_after: (after / scored.max(1) as f64).sqrt(),
        share_top,
        gain,
        gain_rel_se,
        ratio: (ratio_at(lo), ratio_at(hi)),
    };
    Some(PhotonTransfer { gain, intercept: for_gain.coef[0], intercept_se: for_gain.var[0].sqrt(), jitter: Some(jitter) })
}

impl LightJitter {
    /// The finding: the light's, with its size and what it did to the photon transfer.
    pub(super) fn finding(&self) -> Finding {
        let gain = match self.gain {
            Some(g) => format!("the gain, {g:.3} e-/DN, is the photon transfer's with the jitter's term (+- {:.2}%)", 100.0 * self.gain_rel_se),
            None if self.gain_rel_se.is_finite() => format!("the gain is withheld: with the jitter's term the photon transfer leaves it uncertain by {:.1}% (frames of equal light, or pairs of frames differenced, would give it)", 100.0 * self.gain_rel_se),
            None => "the gain is withheld: the jitter swamps the shot noise, and the photon transfer with its term does not bound the gain (frames of equal light, or pairs of frames differenced, would give it)".to_string(),
        };
        Finding {
            effect: Effect::LightJitter,
            adc: None,
            count: None,
            sigma_dn: None,
            significance: self.significance,
            rms_before: self.rms_before,
            rms_after: self.rms_after,
            gain: self.rms_before / self.rms_after,
            all_data_rms_after: None,
            detail: format!(
                "the light of each frame differs from its level's by {:.2}% rms (+- {:.2}%), alike for every pixel (a flickering source, a shutter's jitter): the frames' variance over the signal rises from {:.3} to {:.3} DN where a sensor's stays at 1 / gain, {:.0}% of the variance at the brightest level is the light's; {gain}",
                100.0 * self.rms,
                100.0 * self.rms_se,
                self.ratio.0,
                self.ratio.1,
                100.0 * self.share_top
            ),
            residuals: None,
        }
    }
}

/// The models of the frames' variance (module documentation).
#[derive(Debug, Clone, Copy, PartialEq)]
enum Model {
    /// `r^2 + u / G`.
    Transfer,
    /// `r^2 + u / G + J w`, `J` one for all levels; the noise of a point grows by the
    /// jitter's scatter between levels, `J w sqrt(2 / (N - 1))` (fitted by reweighting).
    Jitter,
    /// `r^2 + u / G + J_l w`, each level's own `J_l`: needs channels of different signal
    /// within a level.
    PerLevel,
}

/// A fitted [`Model`]: its coefficients (`[r^2, 1 / G, J...]`), the diagonal of their
/// covariance (scaled by the residuals' reduced `chi^2` where above 1), and the jitter's
/// scatter between levels.
#[derive(Debug, Clone)]
struct Fit {
    model: Model,
    coef: Vec<f64>,
    var: Vec<f64>,
    spread: f64,
}

impl Fit {
    /// The noise of point `p` under the fit (before its scale).
    fn noise(&self, p: &Point, j: f64) -> f64 {
        (p.sigma * p.sigma + if self.model == Model::Jitter { self.spread * (j.max(0.0) * p.w).powi(2) } else { 0.0 }).sqrt()
    }
}

/// Weighted least squares of the points' variance under `model` (reweighted for
/// [`Model::Jitter`]); `None` where the system is singular.
fn fit(points: &[Point], model: Model, spread: f64) -> Option<Fit> {
    let mut levels: Vec<usize> = points.iter().map(|p| p.level).collect();
    levels.sort_unstable();
    levels.dedup();
    let p = match model {
        Model::Transfer => 2,
        Model::Jitter => 3,
        Model::PerLevel => 2 + levels.len(),
    };
    if points.len() <= p {
        return None;
    }
    let column = |q: &Point, c: usize| match c {
        0 => 1.0,
        1 => q.u,
        _ if model == Model::Jitter => q.w,
        _ => if levels[c - 2] == q.level { q.w } else { 0.0 },
    };
    let mut f = Fit { model, coef: vec![0.0; p], var: vec![0.0; p], spread };
    let rounds = if model == Model::Jitter { 8 } else { 1 };
    for _ in 0..rounds {
        let j = f.coef.get(2).copied().unwrap_or(0.0);
        let sigma: Vec<f64> = points.iter().map(|q| f.noise(q, j)).collect();
        let a = nalgebra::DMatrix::from_fn(points.len(), p, |r, c| column(&points[r], c) / sigma[r]);
        let b = nalgebra::DVector::from_iterator(points.len(), points.iter().zip(&sigma).map(|(q, s)| q.v / s));
        // Columns scaled to unit norm, so that the normal matrix is well conditioned.
        let norm: Vec<f64> = (0..p).map(|c| a.column(c).norm()).collect();
        if norm.iter().any(|s| s.is_nan() || *s <= 0.0) {
            return None;
        }
        let a = nalgebra::DMatrix::from_fn(points.len(), p, |r, c| a[(r, c)] / norm[c]);
        let inv = (a.transpose() * &a).try_inverse()?;
        let beta = &inv * a.transpose() * &b;
        let chi2 = (&a * &beta - &b).norm_squared() / (points.len() - p) as f64;
        f.coef = (0..p).map(|c| beta[c] / norm[c]).collect();
        f.var = (0..p).map(|c| inv[(c, c)] * chi2.max(1.0) / (norm[c] * norm[c])).collect();
    }
    f.coef.iter().chain(&f.var).all(|v| v.is_finite()).then_some(f)
}
