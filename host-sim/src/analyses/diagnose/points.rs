//! A linearity set's levels as the per-pixel fits see them ([`Point`]s: reference, mean,
//! noise of the mean), computed from the set when a fit asks for them and not held: a
//! pixel's points took 1.3 KB at 41 levels, most of what `diagnose` held per pixel
//! (5.1 KB in all), and each costs a few flops to recompute against a Gauss-Newton fit.

use super::cubes::{Levels, SetView};
use super::pixel_fit::Point;
use super::records::{Keep, Records};
use super::smooth_noise::NoiseFit;
use crate::formats::fits::Sample;

/// A per-level term taken out of pixels' means: `(c, var)` in DN and DN^2 at `level` for
/// pixel `i` (an index into [`Pixels`]) read by `adc` whose own response is `shape` (read
/// once a pixel: `shape(i)`), where there is one. [`super::levels::LevelTerm`] is common
/// to the pixels (per ADC at most); the light's pattern
/// ([`super::linearity`]'s `illumination` stage) depends on where the pixel is.
pub(super) trait Common: Sync {
    fn shape(&self, i: usize) -> Option<[f64; 5]>;
    fn at(&self, level: usize, i: usize, adc: usize, shape: Option<&[f64; 5]>) -> Option<(f64, f64)>;
}

/// Which of a set's pixels a diagnosis fits: all, or those a mask leaves (their indices,
/// held or spilled as the records are).
pub(super) enum Fitted {
    All(usize),
    Listed(Records<u32>),
}

impl Fitted {
    /// The set's pixel that pixel `i` is.
    pub fn index(&self, i: usize) -> usize {
        match self {
            Fitted::All(_) => i,
            Fitted::Listed(list) => list.index(i),
        }
    }

    /// Pixels fitted.
    pub fn len(&self) -> usize {
        match self {
            Fitted::All(n) => *n,
            Fitted::Listed(list) => list.len(),
        }
    }
}

/// The pixels of a set a diagnosis fits (those not masked) and what their points need.
pub(super) struct Pixels<'a, T: Sample> {
    set: &'a SetView<'a, T>,
    /// Reference per level, `V_l / max V`.
    pub x: Vec<f64>,
    /// `(N - 1) / (N - 3)`: the mean of `1 / s^2` over Gaussian frames, relative.
    kappa: f64,
    /// Per level, the quantization's mean square error of a mean, DN^2.
    bias2: Vec<f64>,
    /// Per pixel of the set, its levels below saturation.
    valid: Records<u16>,
    /// The set's pixels fitted.
    fitted: Fitted,
    /// Where the records kept per pixel go ([`super::records`]).
    keep: Keep,
    /// A colour filter's response pattern, where the diagnosis found one: each pixel's
    /// gain meets its own channel's population ([`Pixels::response`]).
    cfa: Option<super::channels::CfaResponse>,
}

impl<'a, T: Sample> Pixels<'a, T> {
    pub fn new(set: &'a SetView<'a, T>, x: Vec<f64>, kappa: f64, bias2: Vec<f64>, valid: Records<u16>, fitted: Fitted, keep: Keep) -> Self {
        Pixels { set, x, kappa, bias2, valid, fitted, keep, cfa: None }
    }

    /// Sets the colour filter's pattern that [`Pixels::response`] divides gains by.
    pub fn set_cfa(&mut self, cfa: Option<super::channels::CfaResponse>) {
        self.cfa = cfa;
    }

    /// The relative response of pixel `i`'s colour channel (1 without a colour filter):
    /// a gain divided by it is comparable across channels.
    pub fn response(&self, i: usize) -> f64 {
        self.cfa.as_ref().map_or(1.0, |c| {
            let (col, row) = self.position(i);
            c.at(col, row)
        })
    }

    /// The colour filter's cells (1 without one): [`Pixels::cell`] is below it.
    pub fn cells(&self) -> usize {
        self.cfa.as_ref().map_or(1, |c| c.response.len().max(1))
    }

    /// The colour filter's cell of pixel `i` (`crate::model::camera::config::cfa_cell`;
    /// 0 without a filter).
    pub fn cell(&self, i: usize) -> usize {
        self.cfa.as_ref().map_or(0, |c| {
            let (col, row) = self.position(i);
            crate::model::camera::config::cfa_cell(col, row, c.period).min(c.response.len().saturating_sub(1))
        })
    }

    /// The index into the set's pixels of pixel `i`.
    pub fn index(&self, i: usize) -> usize {
        self.fitted.index(i)
    }

    /// Where the records kept per pixel go.
    pub fn keep(&self) -> &Keep {
        &self.keep
    }

    /// Pixels fitted.
    pub fn len(&self) -> usize {
        self.fitted.len()
    }

    /// ADCs of the camera.
    pub fn n_adc(&self) -> usize {
        self.set.n_adc.clamp(1, self.set.width.max(1))
    }

    /// The ADC of pixel `i`: column `c` is read by ADC `c mod n_adc`.
    pub fn adc(&self, i: usize) -> usize {
        self.adc_of(self.index(i))
    }

    /// The ADC of the set's pixel `p`.
    fn adc_of(&self, p: usize) -> usize {
        dncal_core::adc_of_column(p % self.set.width, self.n_adc())
    }

    /// Whether pixel `i` lies on an even row: those estimate shared parameters, the odd
    /// rows score them.
    pub fn estimating(&self, i: usize) -> bool {
        (self.index(i) / self.set.width).is_multiple_of(2)
    }

    /// Pixel `i`'s column and row in the set.
    pub fn position(&self, i: usize) -> (usize, usize) {
        let p = self.index(i);
        (p % self.set.width, p / self.set.width)
    }

    /// The set's width and height, pixels.
    pub fn size(&self) -> (usize, usize) {
        (self.set.width, self.set.height)
    }

    /// Levels of pixel `i` below saturation.
    pub fn valid(&self, i: usize) -> usize {
        usize::from(self.valid.at(self.index(i)))
    }

    /// The levels of pixel `i`, split: (even levels, odd levels); less the `common` term
    /// where one is given (its variance added to the noise, and the rounding of the
    /// mean's value type: [`Sample::rounding_var`]).
    pub fn halves(&self, i: usize, common: Option<&dyn Common>) -> (Vec<Point>, Vec<Point>) {
        self.points(i, common, None)
    }

    /// All levels of pixel `i`: the even ones, then the odd ones.
    pub fn all(&self, i: usize, common: Option<&dyn Common>) -> Vec<Point> {
        let (mut ev, od) = self.halves(i, common);
        ev.extend(od);
        ev
    }

    /// Pixel `i`'s frame variance fitted over its levels below saturation
    /// ([`super::smooth_noise`]), for [`Pixels::all_smoothed`].
    pub fn noise_fit(&self, i: usize) -> NoiseFit {
        let valid = self.valid(i);
        self.with_levels(i, |at| {
            let (mean, var): (Vec<f64>, Vec<f64>) = (0..valid).map(|l| (at.mean(l), at.std(l).powi(2))).unzip();
            NoiseFit::new(&mean, &var)
        })
    }

    /// [`Pixels::all`] without a term, each mean's noise from the pixel's frame variance
    /// smoothed over its levels (`noise`, [`Pixels::noise_fit`] of the same pixel): the
    /// weights of the fits to means that carry the level errors, which their own noisy
    /// variances share out unevenly between pixels. Each smoothed variance carries its
    /// own `d / (d - 2)` for its degrees of freedom in place of `kappa`.
    pub fn all_smoothed(&self, i: usize, noise: &NoiseFit) -> Vec<Point> {
        let (mut ev, od) = self.points(i, None, Some(noise));
        ev.extend(od);
        ev
    }

    fn points(&self, i: usize, common: Option<&dyn Common>, smoothed: Option<&NoiseFit>) -> (Vec<Point>, Vec<Point>) {
        let set = self.set;
        let p = self.index(i);
        let valid = usize::from(self.valid.at(p));
        let n = f64::from(set.n_frames.max(1));
        let floor = 1.0 / (12.0 * n);
        let adc = self.adc_of(p);
        let shape = common.and_then(|t| t.shape(i));
        let mut halves = (Vec::with_capacity(valid.div_ceil(2)), Vec::with_capacity(valid / 2));
        set.with_pixel(p, |at| {
            let pts = (0..valid)
                .map(|l| {
                    let (c, v) = common.and_then(|t| t.at(l, i, adc, shape.as_ref())).unwrap_or((0.0, 0.0));
                    let (m, s) = (at.mean(l), at.std(l));
                    // The noise of each mean: `kappa s^2 / N`, or the smoothed variance over `N`.
                    let noise = smoothed.map_or(self.kappa * s * s / n, |fit| fit.variance(m, s * s, set.n_frames) / n);
                    Point { level: l, x: self.x[l], y: m - c, sigma: (noise.max(floor) + self.bias2[l] + v + T::rounding_var(m)).sqrt() }
                })
                .filter(|q| q.x.is_finite() && q.y.is_finite() && q.sigma.is_finite());
            for q in pts {
                if q.level % 2 == 0 { halves.0.push(q) } else { halves.1.push(q) }
            }
        });
        halves
    }

    /// `f` of the levels of pixel `i` ([`SetView::with_pixel`]).
    pub fn with_levels<R>(&self, i: usize, f: impl FnOnce(Levels<'_, T>) -> R) -> R {
        self.set.with_pixel(self.index(i), f)
    }

    /// The raw mean of pixel `i` at `level`, DN.
    pub fn mean(&self, level: usize, i: usize) -> f64 {
        self.with_levels(i, |at| at.mean(level))
    }
}
