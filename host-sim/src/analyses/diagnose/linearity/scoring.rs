//! What every model step of a linearity diagnosis scores with: the pixels, the level term
//! taken out of their means (where one was found), each pixel's own fits, and the good
//! pixels (not flagged bad, fitted on their even levels), which every score is over; and
//! the `pixel-nonlinearity` finding, the pixels' own fits scored against the shared model.

use super::curves::shared_curve;
use super::pixel_fits::{PixelFits, PixelStage};
use super::{finding, with_residuals};
use crate::analyses::diagnose::pixel_fit::{fit_and_score, Response, Totals};
use crate::analyses::diagnose::points::{Common, Pixels};
use crate::analyses::diagnose::records::Records;
use crate::analyses::diagnose::scores::{Cell, Scores};
use crate::analyses::diagnose::{AdcResiduals, Effect, Finding, SIGNIFICANCE};
use crate::formats::fits::Sample;

/// The pixels of a diagnosis as its model steps score them.
pub(super) struct Scoring<'a, T: Sample> {
    pub px: &'a Pixels<'a, T>,
    /// The level term, taken out of every pixel's means; `None` where none was found.
    pub common: Option<&'a dyn Common>,
    /// Each pixel's own fits (by index into `px`).
    pub fits: &'a Records<PixelFits>,
    /// The good pixels, by index into `px`: score `j` of a [`Scores`] is pixel
    /// `good.index(j)` (held or spilled as `px`'s records are).
    pub good: Records<u32>,
    /// ADCs of the camera.
    pub n_adc: usize,
    /// Levels of the set.
    pub levels: usize,
    /// The top code, DN.
    pub top: f64,
}

impl<'a, T: Sample> Scoring<'a, T> {
    pub fn new(px: &'a Pixels<'a, T>, common: Option<&'a dyn Common>, stage: &'a PixelStage, n_adc: usize, levels: usize, top: f64) -> Self {
        let good = Records::collect(px.keep(), (0..px.len()).filter(|&i| stage.is_good(i)).map(|i| i as u32));
        Scoring { px, common, fits: &stage.fits, good, n_adc, levels, top }
    }

    /// Where score `j` (pixel `good.index(j)`) is summed.
    pub fn cell(&self, j: usize) -> Cell {
        let i = self.good.index(j);
        Cell { adc: self.px.adc(i), odd: !self.px.estimating(i) }
    }

    /// The held-out scores of the response `model(i)` of each good pixel `i`, its means
    /// less `common` (a curve's fit starts from the pixel's even-level line).
    pub fn score_with(&self, common: Option<&dyn Common>, model: &(dyn Fn(usize) -> Response + Sync)) -> Scores {
        Scores::collect(self.px.keep(), self.good.len(), self.n_adc, self.levels, &|j| self.cell(j), &|j| {
            let i = self.good.index(j);
            let (ev, od) = self.px.halves(i, common);
            let m = model(i);
            let start = match m {
                Response::Curve(..) => self.fits.at(i).line(0).map_or(vec![0.0; 2], |l| l.to_vec()),
                _ => vec![0.0; m.params()],
            };
            fit_and_score(m, &start, &ev, &od)
        })
    }

    /// [`Scoring::score_with`] the level term found.
    pub fn score(&self, model: &(dyn Fn(usize) -> Response + Sync)) -> Scores {
        self.score_with(self.common, model)
    }

    /// The shared curve of the good pixels of even rows that `sel` takes, from their
    /// even levels, each at its own quartic's gain or, given `at_gain`, all at that gain
    /// (an additive common term).
    pub fn shared_of(&self, sel: &(dyn Fn(usize) -> bool + Sync), at_gain: Option<f64>) -> [f64; 3] {
        let chosen = |j: usize| {
            let i = self.good.index(j);
            (self.px.estimating(i) && sel(i)).then_some(())?;
            Some((i, at_gain.unwrap_or(self.fits.at(i).quartic(0)?.gain)))
        };
        shared_curve(self.px, self.common, self.good.len(), &chosen, self.top)
    }

    /// [`Scoring::shared_of`] each pixel at its own gain.
    pub fn curve_of(&self, sel: &(dyn Fn(usize) -> bool + Sync)) -> [f64; 3] {
        self.shared_of(sel, None)
    }
}

/// `pixel-nonlinearity`: each pixel's own quartic (scores `own`, totals `t3`) against the
/// shared model (`current`, `tcur`) on the `good` pixels' held-out levels, with how far the
/// pixels' curves depart from the shared one at their highest held-out level.
///
/// `extra` is the mean `z^2` per held-out residual under the shared model that a known
/// term leaves and each pixel's quartic would take (the light's pattern's part that looks
/// like the pixels' own curves, [`super::illumination`]): the quartics must do better
/// than that.
pub(super) fn pixel_nonlinearity<T: Sample>(s: &Scoring<'_, T>, (current, tcur): (&Scores, Totals), (own, t3): (&Scores, Totals), extra: f64) -> Option<Finding> {
    let (px, common, fits, good) = (s.px, s.common, s.fits, &s.good);
    let all = |_: Cell| true;
    let beyond = Totals { s: tcur.s - extra * tcur.n as f64, ..tcur };
    let sig = beyond.significance_to(&t3);
    if sig > SIGNIFICANCE && t3.s < beyond.s {
        // How far each pixel's quartic departs from the shared model at its highest
        // held-out level, relative to its signal there.
        let last = |s: Option<crate::analyses::diagnose::scores::Score>| s.filter(|s| s.n > 0).map(|s| f64::from(s.last_z));
        let spread = Records::from_fn(px.keep(), good.len(), |j| -> Option<f64> {
            let (a, b) = (last(own.get(j))?, last(current.get(j))?);
            let i = good.index(j);
            let q = *px.halves(i, common).1.last()?;
            let d = fits.at(i).line(0)?[0];
            Some(((b - a) * q.sigma / (q.y - d)).abs())
        });
        let mut count = 0usize;
        let sum_sq = spread.iter().flatten().inspect(|_| count += 1).map(|v| v * v).sum::<f64>();
        let rms_spread = (sum_sq / count.max(1) as f64).sqrt();
        let steps = AdcResiduals { baseline: current.by_level(&all), extended: own.by_level(&all) };
        return Some(with_residuals(steps, finding(
            Effect::PixelNonlinearity,
            None,
            sig,
            tcur.rms(),
            t3.rms(),
            format!("each pixel's own quartic (the paper's correction) beats the shared curve on held-out levels; the pixels' curves depart from it by {:.3}% rms of their signal at their highest held-out level", 100.0 * rms_spread),
        )));
    }
    None
}
