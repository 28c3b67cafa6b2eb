//! `illumination-change`: the light's spatial pattern changes from level to level (a
//! lamp or LED whose emission pattern moves with its current or temperature, a diffuser
//! that settles), while the reference diode, which sees the total light, does not see
//! it. Each pixel then reads `S (1 + phi_l(x, y))` with `phi_l` smooth over the sensor and
//! different at every level: no per-pixel response follows it (the paper's Fig. 8, where
//! the pixel-wise correction stays well above the random noise, is what it does; see
//! `docs/paper.md`).
//!
//! ## Measured first, held out by rows
//! Like the level term, the pattern is measured before any model of the pixels and taken
//! out of every pixel's means. On the pixels of each half of the rows apart, a joint fit:
//! each pixel's quartic through all its levels and, per level, a smooth field (the cosine
//! modes `cos(pi kx u) cos(pi ky v)`, up to 10 half cycles a side, without the constant)
//! fitted to the relative residuals `r / S` summed in a grid of bins (each weighted by
//! `(S / sigma)^2`, about their weighted mean: what is common to all pixels is the level
//! term's), alternated three times (the quartics take a pattern's part that is a quartic in
//! the reference at every pixel; each round gives the field the rest). A pixel's means then
//! lose `S phi_l(x, y)` of the field the **other** half of the rows fitted, and gain that
//! fit's variance: the field that corrects a pixel is fitted without it. (The signal `S`
//! it is scaled by is the pixel's quadratic through all its levels, as for the level term's
//! light part: a leverage of the pixel's own held-out levels on its correction of order
//! the field times 3 / 41. And an even-row pixel is corrected with the odd rows' field, so
//! the shared curves estimated on even rows afterwards carry that much of the odd rows.)
//!
//! The test: the two halves' fields agree beyond their noise, `T = sum_l f_e . A_o f_o`
//! against `sqrt(sum_l s_o^2 f_e^T A_o f_e)` (given the even rows' field, the odd rows'
//! sums are independent of it), the smaller of the two directions; and each pixel's
//! quartic scored on its odd levels does better with the pattern taken out than without.
//! A random-per-pixel effect (noise, each pixel's own curve) has no projection on smooth
//! modes; a per-level one common to all pixels is centred away.

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

use super::pixel_fits::QUARTIC;
use super::{finding, with_residuals};
use crate::analyses::diagnose::pixel_fit::fit_and_score;
use crate::analyses::diagnose::points::{Common, Pixels};
use crate::analyses::diagnose::{AdcResiduals, Effect, Finding, SIGNIFICANCE};
use crate::formats::fits::Sample;

/// Rounds of the joint fit.
const ROUNDS: usize = 3;
/// Residuals beyond this many sigma (a bad pixel's kink, not yet flagged) take no part in a
/// field.
const CLIP: f64 = 6.0;

/// Bins a side at most.
const BINS: usize = 24;
/// Highest cosine order (half cycles over the side) a side: the bench's patterns of up to
/// about 4 cycles a side leave 0.3% of their variance outside the modes to order 10, 0.8%
/// to order 8, 5% to order 6 (which left a false `excess-noise` beside a 2e-4 change).
const ORDER: usize = 10;
/// Bytes the bins' sums may take over all tasks.
const BUDGET: usize = 64 << 20;

/// The bins over the sensor and the smooth modes over them.
struct Grid {
    width: usize,
    height: usize,
    bx: usize,
    by: usize,
    /// The modes' orders `(kx, ky)`, the constant left out.
    orders: Vec<(usize, usize)>,
    /// `cos(pi k (x + 0.5) / width)` per order `k` and column `x`, and per row likewise.
    cos_x: Vec<Vec<f64>>,
    cos_y: Vec<Vec<f64>>,
    /// Per half of the rows (even, odd) and bin (row-major), the modes' mean over the
    /// bin's pixels of that half: what a bin's sum of a field sees.
    basis: [Vec<DVector<f64>>; 2],
}

/// The bins a side and the highest cosine orders of the grid of a `width x height` set
/// with `levels` levels, or `None` where it is too small for a smooth field to be told
/// from its bins.
fn sizes(width: usize, height: usize, levels: usize) -> Option<((usize, usize), (usize, usize))> {
    // The sums are 16 bytes a bin, level and half of the rows, per task.
    let most = BUDGET / (levels.max(1) * 2 * 16 * crate::analyses::diagnose::TASKS);
    let side = BINS.min(most.isqrt());
    // (Each bin needs rows of both parities.)
    let (bx, by) = (side.min(width), side.min(height / 2));
    // (At most half as many modes as bins a side, so that the fit has bins to spare.)
    let (kx, ky) = (ORDER.min(bx.saturating_sub(1) / 2), ORDER.min(by.saturating_sub(1) / 2));
    (kx > 0 && ky > 0).then_some(((bx, by), (kx, ky)))
}

/// Bytes [`illumination_change`] holds at once for a `width x height` set of `levels`
/// levels, whatever its pixels: the bins' sums of every task and their total (16 bytes a
/// bin, level and half of the rows each; at most [`BUDGET`] over the tasks; the tasks now
/// run two a thread at a time, so this is at most what they hold), each level's
/// two halves' normal matrices and vectors, fields and the variances they add at each
/// bin and their row functions ([`Grid::separable`]), the modes' means over each bin, and
/// the cosines (measured before the row functions: 56 MB of a 64 x 64 x 41 set's 59 MB
/// peak beyond the binary's own; here 58 MiB, 72 MiB at 2048 x 2048).
pub(crate) fn grid_bytes(width: usize, height: usize, levels: usize) -> u64 {
    let Some(((bx, by), (kx, ky))) = sizes(width, height, levels) else { return 0 };
    let (bins, modes, levels) = ((bx * by) as u64, ((kx + 1) * (ky + 1) - 1) as u64, levels as u64);
    let sums = (crate::analyses::diagnose::TASKS as u64 + 1) * levels * 2 * (bins * 16 + 16);
    let halves = levels * 2 * 8 * (modes * modes + 4 * modes + bins + ((ky + 1) * width) as u64);
    let basis = 2 * bins * modes * 8;
    let cosines = 8 * ((kx + 1) * width + (ky + 1) * height) as u64;
    sums + halves + basis + cosines
}

impl Grid {
    /// The grid of a `width x height` set with `levels` levels, or `None` where it is too
    /// small for a smooth field to be told from its bins.
    fn new(width: usize, height: usize, levels: usize) -> Option<Grid> {
        let ((bx, by), (kx, ky)) = sizes(width, height, levels)?;
        let orders: Vec<(usize, usize)> = (0..=ky).flat_map(|q| (0..=kx).map(move |p| (p, q))).filter(|&(p, q)| p + q > 0).collect();
        let pi = std::f64::consts::PI;
        let cosines = |orders: usize, n: usize| -> Vec<Vec<f64>> { (0..=orders).map(|k| (0..n).map(|x| (pi * k as f64 * (x as f64 + 0.5) / n as f64).cos()).collect()).collect() };
        let (cos_x, cos_y) = (cosines(kx, width), cosines(ky, height));
        let mut grid = Grid { width, height, bx, by, orders, cos_x, cos_y, basis: [Vec::new(), Vec::new()] };
        for odd in 0..2 {
            grid.basis[odd] = (0..by)
                .flat_map(|j| (0..bx).map(move |i| (i, j)))
                .map(|(i, j)| {
                    let columns: Vec<usize> = (0..width).filter(|&x| x * bx / width == i).collect();
                    let rows: Vec<usize> = (0..height).filter(|&y| y * by / height == j && y % 2 == odd).collect();
                    let mean = |c: &[f64], at: &[usize]| at.iter().map(|&k| c[k]).sum::<f64>() / at.len().max(1) as f64;
                    DVector::from_iterator(grid.orders.len(), grid.orders.iter().map(|&(p, q)| mean(&grid.cos_x[p], &columns) * mean(&grid.cos_y[q], &rows)))
                })
                .collect();
        }
        Some(grid)
    }

    fn bins(&self) -> usize {
        self.bx * self.by
    }

    fn modes(&self) -> usize {
        self.orders.len()
    }

    /// The bin of the pixel at column `x`, row `y`.
    fn bin(&self, x: usize, y: usize) -> usize {
        (y * self.by / self.height) * self.bx + x * self.bx / self.width
    }

    /// The field of coefficients `f` at the pixel at column `x`, row `y`: every mode's
    /// term (the oracle of [`Grid::at_rows`]).
    #[cfg(test)]
    fn at(&self, f: &DVector<f64>, x: usize, y: usize) -> f64 {
        self.orders.iter().zip(f.iter()).map(|(&(p, q), c)| c * self.cos_x[p][x] * self.cos_y[q][y]).sum()
    }

    /// The field of coefficients `f` summed over its column orders, per row order `q` and
    /// column `x`: `g_q(x) = sum_p f_pq cos(pi p (x + 0.5) / width)`, `(ky + 1) x width`.
    /// The field at a pixel is then `sum_q cos_y[q][y] g_q(x)` ([`Grid::at_rows`]): 11
    /// terms where the modes are 120 (a 128 x 128 x 41 diagnosis spent 27% of its time
    /// summing the modes at every pixel and level, in every pass).
    fn separable(&self, f: &DVector<f64>) -> Vec<f64> {
        let mut rows = vec![0.0; self.cos_y.len() * self.width];
        for (&(p, q), c) in self.orders.iter().zip(f.iter()) {
            for (r, cx) in rows[q * self.width..][..self.width].iter_mut().zip(&self.cos_x[p]) {
                *r += c * cx;
            }
        }
        rows
    }

    /// The field whose row functions are `rows` ([`Grid::separable`]) at column `x`, row
    /// `y`.
    fn at_rows(&self, rows: &[f64], x: usize, y: usize) -> f64 {
        self.cos_y.iter().enumerate().map(|(q, c)| c[y] * rows[q * self.width + x]).sum()
    }
}

/// One task's sums: per level, half of the rows and bin, the weight and the weighted
/// relative residual; per level and half, the weighted square and the count.
struct Sums {
    w: Vec<f64>,
    wr: Vec<f64>,
    sq: Vec<(f64, u32)>,
}

impl Sums {
    fn new(levels: usize, bins: usize) -> Sums {
        Sums { w: vec![0.0; levels * 2 * bins], wr: vec![0.0; levels * 2 * bins], sq: vec![(0.0, 0); levels * 2] }
    }

    fn add(mut self, o: &Sums) -> Sums {
        self.w.iter_mut().zip(&o.w).for_each(|(a, b)| *a += b);
        self.wr.iter_mut().zip(&o.wr).for_each(|(a, b)| *a += b);
        self.sq.iter_mut().zip(&o.sq).for_each(|(a, b)| *a = (a.0 + b.0, a.1 + b.1));
        self
    }
}

/// Per level, the sum of held-out `z^2` and the count, without and with the pattern.
type ByLevel = Vec<[(f64, u32); 2]>;

/// One level's half of the rows as the field's fit sees it: the normal matrix and
/// vector of the modes about their weighted mean, that mean, and the residuals'
/// variance per unit weight.
#[derive(Clone)]
struct Half {
    a: DMatrix<f64>,
    c: DVector<f64>,
    mean_mode: DVector<f64>,
    var: f64,
}

impl Half {
    fn of(grid: &Grid, odd: usize, w: &[f64], wr: &[f64], (sq, count): (f64, u32)) -> Option<Half> {
        let k = grid.modes();
        let (mut c, mut bsum) = (DVector::zeros(k), DVector::zeros(k));
        let (mut total_w, mut total) = (0.0, 0.0);
        let used: Vec<usize> = (0..grid.bins()).filter(|&b| w[b] > 0.0).collect();
        if used.len() < k + 2 || count < 2 {
            return None;
        }
        // The normal matrix `sum_b w_b basis_b basis_b^T` as one product `S S^T` of the
        // bins' modes scaled by `sqrt(w_b)` (a bin's rank-one updates, one after another,
        // were 10% of a 128 x 128 x 41 diagnosis).
        let mut scaled = DMatrix::zeros(k, used.len());
        for (j, &b) in used.iter().enumerate() {
            let basis = &grid.basis[odd][b];
            scaled.column_mut(j).axpy(w[b].sqrt(), basis, 0.0);
            c.axpy(wr[b], basis, 1.0);
            bsum.axpy(w[b], basis, 1.0);
            total_w += w[b];
            total += wr[b];
        }
        if total_w <= 0.0 {
            return None;
        }
        let mut a = &scaled * scaled.transpose();
        let mean_mode = bsum / total_w;
        a.ger(-total_w, &mean_mode, &mean_mode, 1.0);
        c.axpy(-total, &mean_mode, 1.0);
        let var = (sq - total * total / total_w) / f64::from(count - 1);
        Some(Half { a, c, mean_mode, var })
    }
}

/// One level's field fitted on one half of the rows: its modes' coefficients (relative
/// change of the light), the modes' weighted mean over that half's pixels, and per bin
/// of the other half the variance the fit adds to a correction there (`b^T A^-1 b`, `b`
/// the bin's mean modes about this half's mean: they vary little within a bin), made in
/// the last round only, the one whose fields correct the held-out pixels.
#[derive(Clone)]
struct Field {
    f: DVector<f64>,
    /// `f`'s row functions ([`Grid::separable`]).
    rows: Vec<f64>,
    mean_mode: DVector<f64>,
    /// Per bin of the other half (empty before the last round).
    added: Vec<f64>,
    /// Per half of the rows a correction lands on (even, odd): `f`'s mean over the pixels
    /// it corrects there, `f . mean_mode` of that half's field (this one's where that half
    /// has none), made once a level and round, not at every pixel ([`Pattern::change`]).
    about: [f64; 2],
}

impl Field {
    /// The field of one level's half `h` (fitted on rows of parity `odd`): one step from
    /// `before` (the round before's, zero in the first), with the variance it adds at each
    /// bin of the other half where `added` is asked (`b^T A^-1 b = |L^-1 b|^2` for the
    /// Cholesky factor `L` of the normal matrix: one triangular solve for all the bins, where
    /// the inverse times each bin's modes took a third of a 128 x 128 diagnosis). `None`
    /// where the normal matrix is not positive definite.
    fn step(grid: &Grid, odd: usize, h: &Half, before: Option<&Field>, added: bool) -> Option<Field> {
        let chol = h.a.clone().cholesky()?;
        let mut f = chol.solve(&h.c);
        if let Some(b) = before {
            f += &b.f;
        }
        let added = if added {
            let bins = &grid.basis[1 - odd];
            let mut centred = DMatrix::from_fn(h.c.len(), bins.len(), |k, b| bins[b][k] - h.mean_mode[k]);
            if !chol.l_dirty().solve_lower_triangular_mut(&mut centred) {
                return None;
            }
            centred.column_iter().map(|y| h.var.max(1.0) * y.norm_squared()).collect()
        } else {
            Vec::new()
        };
        let rows = grid.separable(&f);
        Some(Field { f, rows, mean_mode: h.mean_mode.clone(), added, about: [0.0; 2] })
    }
}

/// The light's pattern per level, as a term every pixel's means lose, with the level term
/// where one was found.
pub(super) struct Pattern<'a, T: Sample> {
    px: &'a Pixels<'a, T>,
    /// The level term, where one was found.
    level: Option<&'a dyn Common>,
    /// The pixels' quadratics through all their levels (the level term's).
    shapes: &'a dyn Common,
    grid: Grid,
    /// Per level, the field fitted on (even, odd) rows.
    fields: Vec<[Option<Field>; 2]>,
    /// Whether a pixel loses the other half's field (held out) or its own half's (while
    /// the halves are fitted).
    cross: bool,
    /// Once the fields are final: [`Pattern::change`] of every level and pixel (`level *
    /// pixels + i`), where it fits [`crate::infra::recorded::most_bytes`] (24 bytes each:
    /// 16 MB at 128 x 128 x 41, 64 MB at 256 x 256). Every pass after the stage reads the
    /// field at every point; summed again each time (11 terms) it was 8% of a diagnosis.
    held: Option<Vec<Option<(f64, f64)>>>,
}

impl<T: Sample> Pattern<'_, T> {
    /// The relative change of the light at pixel `i`'s position at `level`, and the variance
    /// of its estimate there.
    fn change(&self, level: usize, i: usize) -> Option<(f64, f64)> {
        if let Some(held) = &self.held {
            return held.get(level * self.px.len() + i).copied().flatten();
        }
        let (x, y) = self.px.position(i);
        let own = y % 2;
        let from = if self.cross { 1 - own } else { own };
        let fields = self.fields.get(level)?;
        let field = fields[from].as_ref()?;
        // About the field's mean over the pixels it corrects (the level term's part), or
        // over those it was fitted on where that half has no fit.
        let mean = field.about[own];
        let var = if self.cross { field.added[self.grid.bin(x, y)] } else { 0.0 };
        Some((self.grid.at_rows(&field.rows, x, y) - mean, var))
    }

    /// Holds [`Pattern::change`] of every level and pixel (the fields final, held out)
    /// where it fits; the same values, read instead of summed.
    fn hold(&mut self) {
        let (n, nl) = (self.px.len(), self.fields.len());
        let fits = n.checked_mul(nl).and_then(|k| k.checked_mul(size_of::<Option<(f64, f64)>>())).is_some_and(|b| b <= crate::infra::recorded::most_bytes());
        if fits {
            let table = (0..n * nl).into_par_iter().map(|k| self.change(k / n, k % n)).collect();
            self.held = Some(table);
        }
    }

    /// The pattern's change of pixel `i`'s mean at `level`, DN, for its quadratic `shape`.
    fn field_dn(&self, level: usize, i: usize, shape: Option<&[f64; 5]>) -> f64 {
        let dn = self.change(level, i).map_or(0.0, |c| c.0 * self.signal(level, shape));
        if dn.is_finite() { dn } else { 0.0 }
    }

    /// A pixel's signal at `level` (its quadratic `shape` above its dark level), DN.
    fn signal(&self, level: usize, shape: Option<&[f64; 5]>) -> f64 {
        let x = self.px.x.get(level).copied().unwrap_or(f64::NAN);
        shape.map_or(0.0, |q| q[1..].iter().rev().fold(0.0, |acc, a| acc * x + a) * x)
    }
}

impl<T: Sample> Common for Pattern<'_, T> {
    fn shape(&self, i: usize) -> Option<[f64; 5]> {
        self.shapes.shape(i)
    }

    /// The level term's `(c, var)` and the pattern's: the relative change times the pixel's
    /// signal there (its quadratic above its dark level).
    fn at(&self, level: usize, i: usize, adc: usize, shape: Option<&[f64; 5]>) -> Option<(f64, f64)> {
        let (c, v) = self.level.and_then(|t| t.at(level, i, adc, shape)).unwrap_or((0.0, 0.0));
        let signal = self.signal(level, shape);
        let (change, var) = self.change(level, i).unwrap_or((0.0, 0.0));
        let (c, v) = (c + change * signal, v + var * signal * signal);
        (c.is_finite() && v.is_finite()).then_some((c, v))
    }
}

/// The pattern found and its finding (with the relative rms it measured).
pub(super) struct Found<'a, T: Sample> {
    pub term: Pattern<'a, T>,
    pub finding: Finding,
    /// The field's relative rms at the levels above 20% of the top signal.
    pub rms: f64,
    /// The field's mean square in the held-out residuals' noise.
    field_z2: f64,
    /// Levels of the set.
    levels: usize,
}

impl<T: Sample> Found<'_, T> {
    /// The mean `z^2` per held-out residual that the pattern leaves in a model of
    /// `params` parameters a pixel: the pattern's part that a pixel's quartic took while
    /// the field was fitted (a smooth pattern that is a quartic in the reference at every
    /// pixel cannot be told from a smooth change of the pixels' own curves; for fields
    /// independent between levels, 5 of the levels' worth), less what the model's own
    /// parameters take of it (its dark and gain; all of it for the quartic).
    pub fn unattributed(&self, params: usize) -> f64 {
        let p = QUARTIC.params();
        p.saturating_sub(params) as f64 / self.levels.saturating_sub(p).max(1) as f64 * self.field_z2
    }
}

/// Measures the light's pattern per level on `px` (less the level term `level` where one
/// was found; the quadratics of `shapes`; `signal` the mean signal per level, DN) and tests
/// it; `None` where the set is too small for it or nothing stands out.
pub(super) fn illumination_change<'a, T: Sample>(px: &'a Pixels<'a, T>, level: Option<&'a dyn Common>, shapes: &'a dyn Common, signal: &[f64]) -> Option<Found<'a, T>> {
    let (w, h) = px.size();
    let nl = px.x.len();
    let grid = Grid::new(w, h, nl)?;
    let nb = grid.bins();
    let at = |l: usize, odd: usize| (l * 2 + odd) * nb;
    let mut term = Pattern { px, level, shapes, grid, fields: vec![[None, None]; nl], cross: false, held: None };
    let mut halves: Vec<[Option<Half>; 2]> = vec![[None, None]; nl];
    let n = px.len();
    let chunk = n.div_ceil(crate::analyses::diagnose::TASKS).max(1);
    for round in 0..ROUNDS {
        // (What the fields add to a held-out correction is needed of the last round's only.)
        let last = round + 1 == ROUNDS;
        // Each pixel's quartic through all its levels, less the field so far; its
        // relative residuals summed by bins, in a fixed split of the pixels (the same
        // sums on every run, however the threads fall). The tasks run a few at a time,
        // each group's sums added in task order as it ends: the same sums as all tasks'
        // added at the end, where 64 tasks' sums held at once were 97 MB of fresh pages
        // at 128 x 128 x 41 and their faults (a zero page copied on its first write, and
        // the other core's TLB flushed) 8% of a diagnosis.
        let tasks: Vec<usize> = (0..n.div_ceil(chunk)).collect();
        let mut sums = Sums::new(nl, nb);
        for group in tasks.chunks(2 * rayon::current_num_threads()) {
            let parts: Vec<Sums> = group
                .par_iter()
                .map(|&t| {
                    let mut sums = Sums::new(nl, nb);
                    for i in t * chunk..((t + 1) * chunk).min(n) {
                        let points = px.all(i, Some(&term));
                        let Some(fit) = fit_and_score(QUARTIC, &[0.0; 5], &points, &[]) else { continue };
                        let (x, y) = px.position(i);
                        let (b, odd) = (term.grid.bin(x, y), y % 2);
                        let mut grad = [0.0; 5];
                        for q in &points {
                            let v = QUARTIC.eval(&fit.params, q.x, &mut grad);
                            let (r, s) = (q.y - v, v - fit.params[0]);
                            if !(s > 0.0 && (r / q.sigma).abs() < CLIP) {
                                continue;
                            }
                            let (weight, rel) = ((s / q.sigma).powi(2), r / s);
                            sums.w[at(q.level, odd) + b] += weight;
                            sums.wr[at(q.level, odd) + b] += weight * rel;
                            let e = &mut sums.sq[q.level * 2 + odd];
                            *e = (e.0 + weight * rel * rel, e.1 + 1);
                        }
                    }
                    sums
                })
                .collect();
            sums = parts.iter().fold(sums, |a, b| a.add(b));
        }
        // Each level's two halves apart (in parallel over the levels: each is a 120 x 120
        // normal matrix and its factorization), then each field's mean over the pixels of
        // either half it corrects.
        // (In place: the round before's halves and fields go as this round's come.)
        let (grid, fields) = (&term.grid, &mut term.fields);
        halves.par_iter_mut().zip(fields.par_iter_mut()).enumerate().for_each(|(l, (level_halves, level_fields))| {
            for odd in 0..2 {
                let span = at(l, odd)..at(l, odd) + nb;
                let half = Half::of(grid, odd, &sums.w[span.clone()], &sums.wr[span], sums.sq[l * 2 + odd]);
                level_fields[odd] = half.as_ref().and_then(|h| Field::step(grid, odd, h, level_fields[odd].as_ref(), last));
                level_halves[odd] = half;
            }
            let modes: [Option<DVector<f64>>; 2] = [0, 1].map(|own| level_fields[own].as_ref().map(|f| f.mean_mode.clone()));
            for field in level_fields.iter_mut().flatten() {
                field.about = [0, 1].map(|own| field.f.dot(modes[own].as_ref().unwrap_or(&field.mean_mode)));
            }
        });
    }
    // The halves' fields agree: each direction's T in its null spread.
    let mut agreement = [(0.0, 0.0); 2];
    for (hs, fs) in halves.iter().zip(&term.fields) {
        let ([Some(he), Some(ho)], [Some(fe), Some(fo)]) = (hs, fs) else { continue };
        for (into, (h, mine, theirs)) in agreement.iter_mut().zip([(ho, &fo.f, &fe.f), (he, &fe.f, &fo.f)]) {
            let a_theirs = &h.a * theirs;
            into.0 += a_theirs.dot(mine);
            into.1 += h.var * a_theirs.dot(theirs);
        }
    }
    // Each pixel's quartic took 5 of its levels' worth of the residuals the fields were
    // fitted to, and correlates them across levels: the null spread is widened by
    // `nl / (nl - 5)` (1.14 in variance at 41 levels). A spread that is not positive
    // and finite (no level with both halves, noise-free data) is no finding.
    let widen = nl as f64 / nl.saturating_sub(QUARTIC.params()).max(1) as f64;
    if agreement.iter().any(|&(t, v)| !(t.is_finite() && v.is_finite() && v > 0.0)) {
        return None;
    }
    let sig = agreement.iter().map(|&(t, v)| t / (widen * v).sqrt()).fold(f64::INFINITY, f64::min);
    if !sig.is_finite() || sig <= SIGNIFICANCE {
        return None;
    }
    // Held out: each pixel's quartic fitted on its even levels, scored on its odd ones,
    // with and without the other half's pattern.
    term.cross = true;
    term.hold();
    let scored = |common: Option<&dyn Common>, i: usize| {
        let (ev, od) = px.halves(i, common);
        fit_and_score(QUARTIC, &[0.0; 5], &ev, &od)
    };
    // And the field's mean square in each held-out residual's noise. Per level, the sums
    // of z^2 and counts without and with the pattern, in the fixed split of the pixels.
    let parts: Vec<(ByLevel, f64)> = (0..n.div_ceil(chunk))
        .into_par_iter()
        .map(|t| {
            let mut by_level = vec![[(0.0, 0u32); 2]; nl];
            let mut field_sq = 0.0;
            for i in t * chunk..((t + 1) * chunk).min(n) {
                let (Some(without), Some(with)) = (scored(level, i), scored(Some(&term), i)) else { continue };
                for (k, s) in [without, with].iter().enumerate() {
                    for z in &s.z {
                        let e = &mut by_level[z.level()][k];
                        *e = (e.0 + z.z() * z.z(), e.1 + 1);
                    }
                }
                let shape = shapes.shape(i);
                field_sq += px.halves(i, level).1.iter().map(|q| (term.field_dn(q.level, i, shape.as_ref()) / q.sigma).powi(2)).sum::<f64>();
            }
            (by_level, field_sq)
        })
        .collect();
    let mut by_level = vec![[(0.0, 0u32); 2]; nl];
    for (part, _) in &parts {
        for (into, from) in by_level.iter_mut().zip(part) {
            for k in 0..2 {
                into[k] = (into[k].0 + from[k].0, into[k].1 + from[k].1);
            }
        }
    }
    let field_sq: f64 = parts.iter().map(|p| p.1).sum();
    let total = |k: usize| by_level.iter().fold((0.0, 0u32), |a, l| (a.0 + l[k].0, a.1 + l[k].1));
    let rms = |(s, n): (f64, u32)| (s / f64::from(n.max(1))).sqrt();
    let (before, after) = (rms(total(0)), rms(total(1)));
    let field_z2 = field_sq / f64::from(total(0).1.max(1));
    let curve = |k: usize| by_level.iter().enumerate().filter(|(_, l)| l[k].1 > 0).map(|(l, e)| (l, rms(e[k]))).collect();
    let residuals = AdcResiduals { baseline: curve(0), extended: curve(1) };
    if after.is_nan() || after >= before {
        return None;
    }
    // The field's size relative to the signal: the product of the two halves' fields
    // (their noise independent, so it averages out of the product) over the bins, at the
    // levels above 20% of the top signal.
    let top = signal.iter().copied().filter(|s| s.is_finite()).fold(0.0, f64::max);
    let mut rel = (0.0f64, 0.0f64);
    for (l, fs) in term.fields.iter().enumerate() {
        let [Some(fe), Some(fo)] = fs else { continue };
        if !(top > 0.0 && signal.get(l).is_some_and(|&s| s >= 0.2 * top)) {
            continue;
        }
        for basis in &term.grid.basis[0] {
            let centred = basis - &fe.mean_mode;
            rel.0 += centred.dot(&fe.f) * centred.dot(&fo.f);
            rel.1 += 1.0;
        }
    }
    let rms = (rel.0 / rel.1.max(1.0)).max(0.0).sqrt();
    let finding = with_residuals(residuals, finding(
        Effect::IlluminationChange,
        None,
        sig,
        before,
        after,
        format!(
            "the light's spatial pattern changes from level to level, unseen by the reference detector: a smooth field per level (cosine modes to {} x {} half cycles over the sensor, summed in a {} x {} grid of bins, fitted with each pixel's quartic) agrees between even and odd rows at {sig:.1} standard deviations; relative rms {rms:.2e} at the levels above 20% of the top signal ([bench] illumination_change_rms); no per-pixel response follows it; taken out of every pixel's means (the field of the other half of the rows), each pixel's quartic on its held-out levels {before:.3} -> {after:.3}",
            term.grid.cos_x.len() - 1,
            term.grid.cos_y.len() - 1,
            term.grid.bx,
            term.grid.by,
        ),
    ));
    Some(Found { term, finding, rms, field_z2, levels: nl })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The modes are orthogonal over the pixels (cosines at the pixels' centres: the
    /// discrete cosine transform's), so the normal matrix is well conditioned; a bin's
    /// mean modes are the mean of its pixels' (a naive sum).
    #[test]
    fn the_modes_are_orthogonal_over_the_bins() {
        let g = Grid::new(64, 64, 41).unwrap();
        assert_eq!((g.bx, g.by, g.modes()), (24, 24, 120));
        // Pixel by pixel, the modes are the 2-D DCT-II's: orthogonal. (Each mode's value
        // at every pixel once: evaluated afresh for every pair, this test took minutes.)
        let values: Vec<Vec<f64>> = (0..g.modes())
            .map(|p| {
                let e_p = DVector::from_fn(g.modes(), |k, _| f64::from(u8::from(k == p)));
                (0..64).flat_map(|y| (0..64).map(move |x| (x, y))).map(|(x, y)| g.at(&e_p, x, y)).collect()
            })
            .collect();
        for p in 0..g.modes() {
            for q in 0..g.modes() {
                let dot: f64 = values[p].iter().zip(&values[q]).map(|(a, b)| a * b).sum();
                if p == q {
                    assert!(dot > 0.2 * 4096.0, "mode {p}: {dot}");
                } else {
                    assert!(dot.abs() < 1e-9, "modes {p}, {q}: {dot}");
                }
            }
        }
    }

    /// The field from its row functions is every mode's sum, to 1e-12 of the field's
    /// scale, at every pixel of an odd-sized grid with random coefficients.
    #[test]
    fn the_separable_field_is_the_sum_of_its_modes() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(59);
        for (w, h) in [(64, 64), (50, 37), (130, 97)] {
            let g = Grid::new(w, h, 41).unwrap();
            let f = DVector::from_fn(g.modes(), |_, _| rng.random_range(-1e-3..1e-3));
            let rows = g.separable(&f);
            for y in 0..h {
                for x in 0..w {
                    assert!((g.at_rows(&rows, x, y) - g.at(&f, x, y)).abs() < 1e-12 * 1e-3, "{w} x {h} at ({x}, {y})");
                }
            }
        }
    }

    #[test]
    fn a_bins_modes_are_its_pixels_mean() {
        let g = Grid::new(50, 37, 41).unwrap();
        for odd in 0..2 {
            for b in [0, 7, g.bins() - 1] {
                let pixels: Vec<(usize, usize)> = (0..37).flat_map(|y| (0..50).map(move |x| (x, y))).filter(|&(x, y)| g.bin(x, y) == b && y % 2 == odd).collect();
                assert!(!pixels.is_empty());
                for k in 0..g.modes() {
                    let e = DVector::from_fn(g.modes(), |m, _| f64::from(u8::from(m == k)));
                    let naive = pixels.iter().map(|&(x, y)| g.at(&e, x, y)).sum::<f64>() / pixels.len() as f64;
                    assert!((g.basis[odd][b][k] - naive).abs() < 1e-12, "bin {b}, mode {k}");
                }
            }
        }
    }

    /// What a field adds at each bin of the other half, by its triangular solve, is the
    /// definition's `var b^T A^-1 b` with `A` inverted whole; and the field is the normal
    /// equations' solution plus the round before's.
    #[test]
    fn the_added_variance_is_the_inverse_quadratic_form() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(60);
        let g = Grid::new(50, 37, 41).unwrap();
        for odd in 0..2 {
            let w: Vec<f64> = (0..g.bins()).map(|_| rng.random_range(0.5..2.0)).collect();
            let wr: Vec<f64> = w.iter().map(|w| w * rng.random_range(-1e-3..1e-3)).collect();
            let h = Half::of(&g, odd, &w, &wr, (4.0, 900)).unwrap();
            let before = Field::step(&g, odd, &h, None, false).unwrap();
            assert!(before.added.is_empty());
            let f = Field::step(&g, odd, &h, Some(&before), true).unwrap();
            let inverse = h.a.clone().try_inverse().unwrap();
            let solution = &inverse * &h.c;
            for k in 0..g.modes() {
                assert!((f.f[k] - 2.0 * solution[k]).abs() < 1e-9 * solution.amax(), "mode {k}");
            }
            assert_eq!(f.added.len(), g.bins());
            for (b, added) in g.basis[1 - odd].iter().zip(&f.added) {
                let d = b - &h.mean_mode;
                let naive = h.var.max(1.0) * (&inverse * &d).dot(&d);
                assert!((added - naive).abs() <= 1e-9 * naive.abs(), "{added} vs {naive}");
            }
        }
    }

    /// A set too small for the field, or with so many levels that the bins would not fit
    /// their budget, has no grid.
    #[test]
    fn small_sets_have_no_grid() {
        assert!(Grid::new(6, 5, 12).is_none());
        assert!(Grid::new(64, 64, 60_000).is_none());
        let g = Grid::new(64, 64, 400).unwrap();
        assert!(g.bins() * 400 * 2 * 16 * crate::analyses::diagnose::TASKS <= BUDGET);
    }
}
