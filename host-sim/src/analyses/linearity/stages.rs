//! The analysis as stages over blocks of pixels, so that a set too large for one machine
//! (a Dask array chunked over rows and columns) gives the bits one pass over the whole
//! set gives. Most of the work is per pixel; four things are global, and each is a
//! reduction whose result does not depend on how the pixels were split:
//! 1. the mask's two medians (the flat's signal and the fit residual), over all pixels;
//! 2. the per-level medians of the good pixels that the standard correction's cubic goes
//!    through, with their counts;
//! 3. each level's mean of the good unsaturated pixels (the raw correction's divisor);
//! 4. the per-level RMS sums of the statistics.
//!
//! Medians are exact selections (any split finds the same values: [`crate::infra::select`]);
//! the sums are exact ([`ExactSum`], [`ExactRms`]), rounded once when read. The filling of
//! masked pixels from their good neighbours reaches one pixel across a block's edge: a
//! block is filled with a one-pixel halo ([`fill_cube`]).
//!
//! [`super::analyze_unsaturated`] runs the stages on the whole set as one block.

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

use super::inverse::{invert_all, poly, poly_slope};
use super::{pseudo_inverse, reason, Cube, LinearityError, LinearityReport, GLOBAL_ORDER, MAX_ORDER};
use crate::formats::fits::SetView;
use crate::infra::exact_sum::{ExactRms, ExactSum};
use crate::infra::stats::rms_finite;

/// The statistics accumulated per level, in [`LinearityReport`]'s order: raw, standard,
/// pixel-wise, random, random standard, random pixel-wise, random raw, random of the
/// level only.
pub const STATISTICS: usize = 8;

/// What the whole set fixes before a pixel is fitted: the normalized reference, the flat,
/// the order, the top code and the frames' count.
#[derive(Debug, Clone)]
pub struct Plan {
    /// Levels, dark included.
    pub levels: usize,
    /// Order of the pixel-wise polynomial (clamped to 1..=[`MAX_ORDER`]).
    pub order: usize,
    /// Normalized reference `x_l = V_l / max V`.
    pub x: Vec<f64>,
    /// Expected normalized intensity `e_l`.
    pub e: Vec<f64>,
    /// The gain (flat) level.
    pub g: usize,
    /// The top code, DN.
    pub top: f64,
    /// `1 / sqrt(frames)`: a mean's noise from the frames' deviation.
    inv_nf: f64,
}

/// Stage 1's results for a block of pixels: every pixel's fit.
#[derive(Debug, Clone)]
pub struct Fits {
    /// Unsaturated levels per pixel (a prefix from dark).
    pub valid: Vec<usize>,
    /// Coefficients, `order + 1` per pixel, pixel-major; NaN where unfitted.
    pub coef: Vec<f64>,
    /// The fit's rms residual, DN; NaN where unfitted.
    pub resid: Vec<f64>,
    /// Signal at the flat over the dark, DN.
    pub signal: Vec<f64>,
}

/// The mask's medians (stage 1's reduction), DN.
#[derive(Debug, Clone, Copy)]
pub struct MaskRule {
    /// Median of the flat's signal over the pixels of each cell of a 2 x 2 period,
    /// `(row mod 2) * 2 + column mod 2`: a colour filter's channel (a Bayer red at 0.45 of
    /// the green median was masked as "low signal", a quarter of the sensor: issue 58);
    /// on a monochrome sensor the four are the median's value within noise.
    pub signal: [f64; 4],
    /// Columns of the set (for the cell of a pixel).
    pub width: usize,
    /// Median of the fit residual over each cell, as `signal` (a channel's residual
    /// scales with its signal: a Bayer green at 1.23 of the mean crossed 10 times the
    /// median of all).
    pub resid: [f64; 4],
}

/// Whether pixel `p` counts in level `l`'s statistics: good and unsaturated there.
pub fn counted(mask: &[u8], valid: &[usize], l: usize, p: usize) -> bool {
    mask[p] == 0 && l < valid[p]
}

impl Plan {
    /// The plan of a set with reference voltages `voltage` (V, checked finite and not all
    /// zero by the caller), `bit_depth`, `n_frames` per level, the pixel-wise `order` and
    /// the flat (`None`: the level nearest half the maximum reference).
    pub fn new(voltage: &[f64], bit_depth: u32, n_frames: u32, order: usize, flat: Option<usize>) -> Plan {
        let nl = voltage.len();
        let vmax = voltage.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        let x: Vec<f64> = voltage.iter().map(|v| v / vmax).collect();
        let g = flat.filter(|l| (1..nl).contains(l)).unwrap_or_else(|| (1..nl).min_by(|&a, &b| (x[a] - 0.5).abs().total_cmp(&(x[b] - 0.5).abs())).unwrap_or(0));
        let e = x.iter().map(|xl| (xl - x[0]) / (x[g] - x[0])).collect();
        Plan { levels: nl, order: order.clamp(1, MAX_ORDER), x, e, g, top: ((1u64 << bit_depth) - 1) as f64, inv_nf: 1.0 / f64::from(n_frames.max(1)).sqrt() }
    }

    /// `order + 1`.
    pub fn k1(&self) -> usize {
        self.order + 1
    }

    /// Stage 1: every pixel's polynomial of the order in `x` through its first `valid[p]`
    /// levels (least squares, one pseudo-inverse per prefix length), the fit's rms
    /// residual, and the flat's signal.
    pub fn fit(&self, set: &SetView, valid: Vec<usize>) -> Fits {
        let (np, k1, g, x) = (set.width * set.height, self.k1(), self.g, &self.x);
        let pinv: Vec<Option<DMatrix<f64>>> = (0..=set.levels).map(|n| (n > self.order + 1).then(|| pseudo_inverse(&x[..n], self.order))).collect();
        let mut coef = vec![f64::NAN; k1 * np];
        let resid: Vec<f64> = coef
            .par_chunks_mut(k1)
            .enumerate()
            .map(|(p, a)| {
                let n = valid[p];
                let m = |l: usize| set.mean[l * np + p];
                match &pinv[n] {
                    Some(pi) if n > g => {
                        let y = DVector::from_iterator(n, (0..n).map(m));
                        a.copy_from_slice((pi * &y).as_slice());
                        rms_finite((0..n).map(|l| poly(a, x[l]) - m(l)))
                    }
                    _ => f64::NAN,
                }
            })
            .collect();
        let signal = (0..np).map(|p| set.mean[g * np + p] - set.mean[p]).collect();
        Fits { valid, coef, resid, signal }
    }

    /// Stage 2's reduction: the global cubic `x = f(m / top)` through the median good
    /// pixel of each level that more than half of the `good` pixels reach unsaturated
    /// (`medians[l]` = the median and the count of the good pixels that reach `l`).
    pub fn global(&self, medians: &[(f64, usize)], good: usize) -> Result<Vec<f64>, LinearityError> {
        let usable: Vec<usize> = (0..self.levels).filter(|&l| medians[l].0.is_finite() && medians[l].1 * 2 > good).collect();
        if usable.len() <= GLOBAL_ORDER {
            return Err(LinearityError::TooFewLevels { levels: usable.len() });
        }
        let gpinv = pseudo_inverse(&usable.iter().map(|&l| medians[l].0 / self.top).collect::<Vec<_>>(), GLOBAL_ORDER);
        Ok((&gpinv * DVector::from_iterator(usable.len(), usable.iter().map(|&l| self.x[l]))).iter().copied().collect())
    }

    /// Stage 3: per level of `set`, the exact sum and the count of the means of the counted
    /// pixels (nothing of the plan's: any block computes it alone).
    pub fn level_sums(set: &SetView, mask: &[u8], valid: &[usize]) -> Vec<(ExactSum, u64)> {
        (0..set.levels)
            .into_par_iter()
            .map(|l| {
                let mut s = ExactSum::default();
                let mut n = 0u64;
                for v in counted_means(set, mask, valid, l) {
                    s.add(v);
                    n += 1;
                }
                (s, n)
            })
            .collect()
    }

    /// Stage 4: level by level, the pixel-wise correction `x^ = P^-1(m)` then dark and
    /// gain (into the corrected cube, every pixel and level, saturated or not: the
    /// corrected images show them all; masked pixels NaN until [`fill_cube`]), and the
    /// level's [`STATISTICS`] over its counted pixels. `(valid, coef)` are the pixels'
    /// [`Fits`] (borrowed: a Dask block's arrays are read in place), `mean_l` each level's
    /// mean of the counted pixels (stage 3's reduction), `global` the standard
    /// correction's cubic.
    /// Without the cube ([`Cube::Skip`]) only the counted pixels are inverted (the same
    /// values: each pixel's inversion is its own) and no cube is allocated.
    pub fn level_pass(&self, set: &SetView, (valid, coef): (&[usize], &[f64]), mask: &[u8], global: &[f64], mean_l: &[f64], cube: Cube) -> (Vec<[ExactRms; STATISTICS]>, Option<Vec<f64>>) {
        let (np, k1, g) = (set.width * set.height, self.k1(), self.g);
        let (x, e) = (&self.x, &self.e);
        let m = |l: usize, p: usize| set.mean[l * np + p];
        let sd = |l: usize, p: usize| set.std[l * np + p];
        let fit = |p: usize| &coef[p * k1..(p + 1) * k1];
        let inversion = Inversion { coef, k1, mask, mean: set.mean, np };
        // The pixel-wise correction at the dark and at the flat, used at every level.
        let (xh0, xhg) = (inversion.level(0, x[0]), inversion.level(g, x[g]));
        let (inv_nf, inv_top) = (self.inv_nf, 1.0 / self.top);
        let f = |v: f64| poly(global, v * inv_top);
        // Each correction as `(y, y')`, what it makes of a mean and its slope; their terms
        // at the dark and the flat ([`Ends`]) once per pixel for all levels.
        let identity = |l: usize, p: usize, _: f64| (m(l, p), 1.0);
        let standard = |l: usize, p: usize, _: f64| (f(m(l, p)), poly_slope(global, m(l, p) * inv_top) * inv_top);
        let pixelwise = |_: usize, p: usize, xh: f64| (xh, 1.0 / poly_slope(fit(p), xh));
        let ends: Vec<[Ends; 3]> = (0..np)
            .into_par_iter()
            .map(|p| {
                let (s0, sg) = (sd(0, p) * inv_nf, sd(g, p) * inv_nf);
                let at = |h: &dyn Fn(usize, usize, f64) -> (f64, f64)| Ends::new(h(0, p, xh0[p]), h(g, p, xhg[p]), s0, sg);
                [at(&identity), at(&standard), at(&pixelwise)]
            })
            .collect();
        let keep = cube == Cube::Keep;
        let level = |l: usize, row: &mut [f64]| -> [ExactRms; STATISTICS] {
            let counted = |p: usize| counted(mask, valid, l, p);
            let inv_mean = 1.0 / mean_l[l];
            let mut acc: [ExactRms; STATISTICS] = Default::default();
            inversion.level_into(l, x[l], row, |p| !keep && !counted(p), |p, xh| {
                let c = dark_and_gain(xh, xh0[p], xhg[p]);
                if counted(p) {
                    let (ml, sl) = (m(l, p), sd(l, p) * inv_nf);
                    let [id, st, pw] = &ends[p];
                    let (yst, dst) = standard(l, p, xh);
                    acc[0].add(ml * inv_mean - 1.0);
                    acc[1].add(st.corrected(yst) - e[l]);
                    acc[2].add(c - e[l]);
                    acc[3].add(id.noise(ml, sl));
                    acc[4].add(st.noise(yst, dst * sl));
                    acc[5].add(pw.noise(xh, sl / poly_slope(fit(p), xh)));
                    acc[6].add(sl * inv_mean);
                    acc[7].add(sl * id.inv_span);
                }
                c
            });
            acc
        };
        // With the cube, each level is its row of it; without, a thread's one row of
        // scratch. The cube is allocated zeroed (untouched pages) and first written here,
        // by the worker threads.
        match cube {
            Cube::Keep => {
                let mut corrected = vec![0.0; self.levels * np];
                let acc = corrected.par_chunks_mut(np.max(1)).enumerate().map(|(l, row)| level(l, row)).collect();
                (acc, Some(corrected))
            }
            Cube::Skip => ((0..self.levels).into_par_iter().map_init(|| vec![0.0; np], |row, l| level(l, row)).collect(), None),
        }
    }

    /// The report from the reductions: per level the statistics' sums (stage 4), the
    /// mean of the counted pixels (stage 3), the global cubic (stage 2), and the masked
    /// and total pixels.
    pub fn report(&self, acc: &[[ExactRms; STATISTICS]], mean_l: &[f64], global: Vec<f64>, masked: usize, pixels: usize) -> LinearityReport {
        let g = self.g;
        let nan_unless = |cond: bool, v: f64| if cond { v } else { f64::NAN };
        // Statistic `i` per level, NaN where it is not defined: at the dark for all, and
        // at the flat for those the dark and gain correction makes exact.
        let col = |i: usize| -> Vec<f64> {
            acc.iter()
                .enumerate()
                .map(|(l, a)| {
                    let calibrated = l != 0 && l != g;
                    nan_unless(if matches!(i, 0 | 6 | 7) { l != 0 } else { calibrated }, a[i].rms())
                })
                .collect()
        };
        let maxf = |v: &[f64]| v.iter().filter(|x| x.is_finite()).fold(0.0f64, |a, &b| a.max(b));
        let (rms_raw, rms_standard, rms_pixelwise, rms_random) = (col(0), col(1), col(2), col(3));
        LinearityReport {
            levels: self.levels,
            pixels,
            gain_level: g,
            intensity: self.e.clone(),
            reference: self.x.clone(),
            rms_raw_max: maxf(&rms_raw),
            rms_standard_max: maxf(&rms_standard),
            rms_pixelwise_max: maxf(&rms_pixelwise),
            rms_random_max: maxf(&rms_random),
            rms_raw,
            rms_standard,
            rms_pixelwise,
            rms_random,
            rms_random_raw: col(6),
            rms_random_standard: col(4),
            rms_random_pixelwise: col(5),
            rms_random_level_only: col(7),
            level_mean_dn: mean_l.to_vec(),
            masked_pixels: masked,
            order: self.order,
            global_coefficients: global,
        }
    }
}

impl Fits {
    /// Why each pixel is left out: [`mask_of`] its fits.
    pub fn mask(&self, input: Option<&[u8]>, rule: MaskRule) -> Vec<u8> {
        mask_of(&self.signal, &self.resid, input, rule)
    }

    /// The coefficients k-major, as the FITS cube holds them: `[k * pixels + p]`.
    pub fn k_major(&self, k1: usize) -> Vec<f64> {
        let np = self.valid.len();
        (0..k1 * np).into_par_iter().map(|i| self.coef[i % np * k1 + i / np]).collect()
    }
}

/// The median of `signal` (a `width`-column image, row-major) over each cell of a 2 x 2
/// period, `(row mod 2) * 2 + column mod 2` (NaN for a cell without pixels, which no
/// pixel then asks for).
pub fn cell_medians(signal: &[f64], width: usize) -> [f64; 4] {
    let w = width.max(1);
    std::array::from_fn(|k| crate::infra::stats::median(signal.iter().enumerate().filter(|(p, _)| crate::model::camera::config::cfa_cell(p % w, p / w, 2) == k).map(|(_, &v)| v)))
}

/// Why each pixel is left out ([`reason`] bits), from its flat's `signal` and fit
/// residual `resid` ([`Fits`]): flagged in the `input` mask, a signal at the flat below
/// half the median of its cell of the 2 x 2 period, no fit, or a fit residual beyond 10 times its cell's median.
pub fn mask_of(signal: &[f64], resid: &[f64], input: Option<&[u8]>, rule: MaskRule) -> Vec<u8> {
    (0..signal.len())
        .into_par_iter()
        .map(|p| {
            let mut m = 0;
            if input.is_some_and(|i| i[p] != 0) {
                m |= reason::INPUT;
            }
            let s = signal[p];
            let w = rule.width.max(1);
            let cell = crate::model::camera::config::cfa_cell(p % w, p / w, 2);
            if s.is_nan() || s < 0.5 * rule.signal[cell] {
                m |= reason::LOW;
            }
            if resid[p].is_nan() {
                m |= reason::UNFIT;
            } else if resid[p] > 10.0 * rule.resid[cell].max(1e-12) {
                m |= reason::TREND;
            }
            m
        })
        .collect()
}

/// The means at level `l` of the pixels [`counted`] there: the values of the level's
/// median (stage 2) and mean (stage 3).
pub fn counted_means<'a>(set: &'a SetView, mask: &'a [u8], valid: &'a [usize], l: usize) -> impl Iterator<Item = f64> + 'a {
    let np = set.width * set.height;
    (0..np).filter(move |&p| counted(mask, valid, l, p)).map(move |p| set.mean[l * np + p])
}

/// Each masked pixel of every `width x height` level of `cube` set to the mean of its good
/// 8-neighbours' finite values (left as it is when none is good). A block of a larger
/// image is filled right when it comes with a one-pixel halo of its neighbours (the
/// halo's own masked pixels are then wrong, and cut off).
pub fn fill_cube(cube: &mut [f64], mask: &[u8], width: usize, height: usize) {
    let fill = GoodNeighbours::of(mask, width, height);
    cube.par_chunks_mut((width * height).max(1)).for_each(|row| fill.fill(row));
}

/// The dark and gain correction of a value `x` given the same pixel's values at the dark
/// (`x0`) and at the flat (`xg`): `(x - x0) / (xg - x0)`.
fn dark_and_gain(x: f64, x0: f64, xg: f64) -> f64 {
    (x - x0) / (xg - x0)
}

/// Each masked pixel's good 8-neighbours, in row-major order: listed once for a mask and
/// used for every image (level) it applies to.
pub(super) struct GoodNeighbours {
    /// The masked pixels.
    pixel: Vec<usize>,
    /// `of[start[i]..start[i + 1]]` are `pixel[i]`'s good neighbours.
    start: Vec<usize>,
    of: Vec<usize>,
}

impl GoodNeighbours {
    pub(super) fn of(mask: &[u8], width: usize, height: usize) -> Self {
        let mut n = GoodNeighbours { pixel: Vec::new(), start: vec![0], of: Vec::new() };
        for p in (0..width * height).filter(|&p| mask[p] != 0) {
            let (r, c) = (p / width, p % width);
            for rr in r.saturating_sub(1)..(r + 2).min(height) {
                for cc in c.saturating_sub(1)..(c + 2).min(width) {
                    let i = rr * width + cc;
                    if mask[i] == 0 {
                        n.of.push(i);
                    }
                }
            }
            n.pixel.push(p);
            n.start.push(n.of.len());
        }
        n
    }

    /// Each masked pixel of `image` set to the mean of its good neighbours' finite values.
    /// Only masked pixels are written and only good ones read, so the image is its own
    /// source (no copy of it per level).
    pub(super) fn fill(&self, image: &mut [f64]) {
        for (k, &p) in self.pixel.iter().enumerate() {
            let (mut sum, mut n) = (0.0, 0);
            for &i in &self.of[self.start[k]..self.start[k + 1]] {
                if image[i].is_finite() {
                    sum += image[i];
                    n += 1;
                }
            }
            if n > 0 {
                image[p] = sum / n as f64;
            }
        }
    }
}

/// One correction's terms at the dark and the flat for one pixel.
#[derive(Debug, Clone, Copy)]
struct Ends {
    /// The correction's value at the dark, `y_0`.
    y0: f64,
    /// `1 / (y_g - y_0)`.
    inv_span: f64,
    /// The flat's and the dark's noise through the correction's slope, `y' s`.
    sg: f64,
    s0: f64,
}

impl Ends {
    /// From `(y, y')` at the dark and at the flat and those levels' noise `s = std / sqrt(N)`.
    fn new((y0, d0): (f64, f64), (yg, dg): (f64, f64), s0: f64, sg: f64) -> Self {
        Ends { y0, inv_span: 1.0 / (yg - y0), sg: dg * sg, s0: d0 * s0 }
    }

    /// `c` of a level where the correction makes `y`.
    fn corrected(&self, y: f64) -> f64 {
        (y - self.y0) * self.inv_span
    }

    /// The noise of `c` for a level read `y` with noise `sl` through the slope:
    /// `sqrt(sl^2 + (c sg)^2 + ((1 - c) s0)^2) / (y_g - y_0)`.
    fn noise(&self, y: f64, sl: f64) -> f64 {
        let c = self.corrected(y);
        (sl * sl + (c * self.sg).powi(2) + ((1.0 - c) * self.s0).powi(2)).sqrt() * self.inv_span
    }
}

/// The pixel-wise inversion of a set's levels: pixel `p`'s polynomial is
/// `coef[p * k1..][..k1]`; masked pixels are not inverted (NaN).
struct Inversion<'a> {
    coef: &'a [f64],
    k1: usize,
    mask: &'a [u8],
    mean: &'a [f64],
    np: usize,
}

impl Inversion<'_> {
    /// `x^ = P^-1(m)` of every pixel at level `l`, Newton from the level's reference `x_l`.
    fn level(&self, l: usize, x_l: f64) -> Vec<f64> {
        const BLOCK: usize = 4096;
        let mut out = vec![0.0; self.np];
        out.par_chunks_mut(BLOCK).enumerate().for_each(|(b, chunk)| self.run(l, x_l, b * BLOCK, chunk, |_| false));
        out
    }

    /// Level `l` into `row`, each pixel's `x^` then turned into `row[p] = put(p, x^)`, in
    /// pixel order; pixels where `skip(p)` (besides the masked ones) are not inverted
    /// (NaN).
    fn level_into(&self, l: usize, x_l: f64, row: &mut [f64], skip: impl Fn(usize) -> bool, mut put: impl FnMut(usize, f64) -> f64) {
        self.run(l, x_l, 0, row, skip);
        for (p, v) in row.iter_mut().enumerate() {
            *v = put(p, *v);
        }
    }

    /// `x^` of pixels `first..first + out.len()` of level `l` into `out`; NaN for the
    /// masked ones and those where `skip(j)` (`j` counted from `first`).
    fn run(&self, l: usize, x_l: f64, first: usize, out: &mut [f64], skip: impl Fn(usize) -> bool) {
        let mean = &self.mean[l * self.np + first..];
        let coef = &self.coef[first * self.k1..];
        let mask = &self.mask[first..];
        invert_all(out, self.k1, x_l, |j, k| coef[j * self.k1 + k], |j| mean[j], |j| mask[j] != 0 || skip(j));
    }
}
