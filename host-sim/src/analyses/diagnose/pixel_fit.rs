//! Per-pixel fits of a linearity set: the level response models a pixel can follow
//! ([`Response`]), a weighted Gauss-Newton fit on one half of its levels scored on the
//! other ([`fit_and_score`]), and the sums over pixels that the catalogue's tests compare
//! ([`Totals`]). Shared by the catalogue ([`super::linearity`]) and the level term
//! ([`super::levels`]), which both fit pixels and neither owns the fit.

use nalgebra::{DMatrix, DVector};

/// A level response model of one pixel.
#[derive(Debug, Clone, Copy)]
pub(super) enum Response {
    /// `sum_k a_k x^k`, k = 0..=order.
    Poly(usize),
    /// `d + G(g x)` with the signal-domain curve `c` (c2, c3, c4) and top code `t`.
    Curve([f64; 3], f64),
    /// `d + g x + G(g0 x) - g0 x`: the same curve at one gain `g0` for every pixel, an
    /// additive term common to all (the smooth part of level errors, which does not
    /// scale with a pixel's gain: in the signal domain, a smooth part of random errors
    /// with large cancelling coefficients left 2.4 times the noise at the top level).
    Common([f64; 3], f64, f64),
}

impl Response {
    pub(super) fn params(self) -> usize {
        match self {
            Response::Poly(o) => o + 1,
            Response::Curve(..) | Response::Common(..) => 2,
        }
    }

    /// Value at `x` and its gradient in the parameters.
    pub(super) fn eval(self, p: &[f64], x: f64, grad: &mut [f64]) -> f64 {
        match self {
            Response::Poly(o) => {
                let mut v = 0.0;
                let mut xk = 1.0;
                for k in 0..=o {
                    grad[k] = xk;
                    v += p[k] * xk;
                    xk *= x;
                }
                v
            }
            Response::Curve(c, t) => {
                let s = p[1] * x;
                let u = s / t;
                let shape = 1.0 + c[0] * u + c[1] * u * u + c[2] * u * u * u;
                let slope = 1.0 + 2.0 * c[0] * u + 3.0 * c[1] * u * u + 4.0 * c[2] * u * u * u;
                grad[0] = 1.0;
                grad[1] = x * slope;
                p[0] + s * shape
            }
            Response::Common(c, t, g0) => {
                let u = g0 * x / t;
                grad[0] = 1.0;
                grad[1] = x;
                p[0] + p[1] * x + g0 * x * u * (c[0] + c[1] * u + c[2] * u * u)
            }
        }
    }
}

/// One level of one pixel: reference, mean, noise of the mean.
#[derive(Debug, Clone, Copy)]
pub(super) struct Point {
    pub level: usize,
    pub x: f64,
    pub y: f64,
    pub sigma: f64,
}

/// A pixel's fit on one half and its score on the other.
#[derive(Debug, Clone)]
pub(super) struct Scored {
    pub params: Vec<f64>,
    /// Weighted residual sum of squares on the fitted half.
    pub chi2_fit: f64,
    /// Held-out normalized residuals, (level, z), compact (every model keeps one per
    /// pixel and level: they are most of the memory; f32 keeps z to 1e-7).
    pub z: Vec<Z>,
    /// `tr C` and `tr C^2` of the held-out residuals' null covariance.
    pub tr: f64,
    pub tr2: f64,
}

/// One held-out normalized residual: level and `z`.
#[derive(Debug, Clone, Copy)]
pub(super) struct Z(u16, f32);

impl Z {
    pub(super) fn level(self) -> usize {
        usize::from(self.0)
    }

    pub(super) fn z(self) -> f64 {
        f64::from(self.1)
    }
}

impl Scored {
    pub(super) fn sum_sq(&self) -> f64 {
        self.z.iter().map(|v| v.z() * v.z()).sum()
    }
}

/// Weighted Gauss-Newton fit of `model` to `fit` (from `start`), scored on `test`.
/// `None` when there are too few points or the normal matrix is singular.
///
/// Models of up to [`MAX_PARAMS`] parameters (all of the catalogue's) are solved on the
/// stack, by Householder reflections of up to 64 rows at a time ([`Triangle`]); larger ones by [`fit_and_score_dense`], the
/// heap-allocated QR this replaced (which took a third of a diagnosis in allocations and
/// forming `Q`) and which the tests hold it to.
pub(super) fn fit_and_score(model: Response, start: &[f64], fit: &[Point], test: &[Point]) -> Option<Scored> {
    let np = model.params();
    if np > MAX_PARAMS || start.len() != np {
        return fit_and_score_dense(model, start, fit, test);
    }
    if fit.len() <= np {
        return None;
    }
    let mut p = [0.0; MAX_PARAMS];
    p[..np].copy_from_slice(start);
    // A polynomial (or a curve of fixed shape plus dark and gain) is linear in its
    // parameters: one step from any start is its least-squares solution, and its
    // factor does not depend on where it is taken.
    let iterations = if matches!(model, Response::Curve(..)) { 8 } else { 1 };
    let mut factor = None;
    for _ in 0..iterations {
        let t = Triangle::of(model, &p[..np], fit)?;
        let step = t.solve()?;
        p.iter_mut().zip(&step[..np]).for_each(|(a, d)| *a += d);
        let converged = step[..np].iter().zip(&p).all(|(d, a)| d.abs() <= 1e-12 * a.abs().max(1.0));
        factor = Some(t);
        if converged {
            break;
        }
    }
    // The factor at the parameters reached (a curve's moved with its last step).
    let t = match factor {
        Some(t) if !matches!(model, Response::Curve(..)) => t,
        _ => Triangle::of(model, &p[..np], fit)?,
    };
    t.solve()?;
    let mut grad = [0.0; MAX_PARAMS];
    let chi2_fit = fit
        .iter()
        .map(|q| {
            let r = (q.y - model.eval(&p[..np], q.x, &mut grad[..np])) / q.sigma;
            r * r
        })
        .sum();
    // The held-out residuals' null covariance: `C = I + J_t A^-1 J_t^T` with `A = R^T R`,
    // so `tr C = n + |W|^2` and `tr C^2 = n + 2 |W|^2 + |W^T W|^2` (Frobenius) for
    // `W = J_t R^-1`, a row `w = R^-T j` at a time.
    let (mut tr_m, mut gram) = (0.0, [[0.0; MAX_PARAMS]; MAX_PARAMS]);
    let mut z = Vec::with_capacity(test.len());
    for q in test {
        let v = model.eval(&p[..np], q.x, &mut grad[..np]);
        z.push(Z(u16::try_from(q.level).unwrap_or(u16::MAX), ((q.y - v) / q.sigma) as f32));
        let mut row = [0.0; MAX_PARAMS];
        row[..np].iter_mut().zip(&grad[..np]).for_each(|(r, g)| *r = g / q.sigma);
        let w = t.forward(&row);
        for a in 0..np {
            tr_m += w[a] * w[a];
            for b in 0..np {
                gram[a][b] += w[a] * w[b];
            }
        }
    }
    let tr_m2: f64 = gram.iter().flatten().map(|g| g * g).sum();
    let n = test.len() as f64;
    Some(Scored { params: p[..np].to_vec(), chi2_fit, z, tr: n + tr_m, tr2: n + 2.0 * tr_m + tr_m2 })
}

/// The most parameters [`fit_and_score`] solves on the stack: the quartic's five.
pub(super) const MAX_PARAMS: usize = 5;

/// The upper-triangular factor `R` of a weighted least-squares problem `J step = r` and
/// `Q^T r`, by Householder reflections of the rows held on the stack a chunk at a time
/// (each chunk reduced below the factor so far): the factor nalgebra's QR gives (up to the
/// signs of its rows), without the heap or `Q`. (Givens rotations a row at a time, a
/// square root and two divisions for every row and parameter, took 21% of a diagnosis.)
struct Triangle {
    np: usize,
    r: [[f64; MAX_PARAMS]; MAX_PARAMS],
    qtr: [f64; MAX_PARAMS],
}

/// Rows a chunk of [`Triangle::of`] holds, the factor's included: a linearity set's 41
/// levels in one.
const CHUNK: usize = 64;

impl Triangle {
    /// The factor of `model` at parameters `p` through `pts` (rows `grad / sigma`, right
    /// side `(y - value) / sigma`); `None` where a row is not finite (a diverging step).
    fn of(model: Response, p: &[f64], pts: &[Point]) -> Option<Triangle> {
        let np = p.len();
        // Column-major: the parameters' columns, then the right side's.
        let mut a = [[0.0; CHUNK]; MAX_PARAMS + 1];
        let mut grad = [0.0; MAX_PARAMS];
        // Rows `0..np` hold the factor so far (zero before the first chunk).
        let mut rows = np;
        for q in pts {
            if rows == CHUNK {
                Self::reduce(&mut a, np, rows)?;
                rows = np;
            }
            let v = model.eval(p, q.x, &mut grad[..np]);
            let rhs = (q.y - v) / q.sigma;
            if !(rhs.is_finite() && grad[..np].iter().all(|g| (g / q.sigma).is_finite())) {
                return None;
            }
            for k in 0..np {
                a[k][rows] = grad[k] / q.sigma;
            }
            a[np][rows] = rhs;
            rows += 1;
        }
        Self::reduce(&mut a, np, rows)?;
        let mut t = Triangle { np, r: [[0.0; MAX_PARAMS]; MAX_PARAMS], qtr: [0.0; MAX_PARAMS] };
        // (`a` is column-major, `r` row-major.)
        for (i, (row, qtr)) in t.r.iter_mut().zip(&mut t.qtr).enumerate().take(np) {
            for (j, column) in a.iter().enumerate().take(np).skip(i) {
                row[j] = column[i];
            }
            *qtr = a[np][i];
        }
        Some(t)
    }

    /// Householder reflections of the first `rows` rows of `a` (`np` columns and the right
    /// side): its first `np` rows become `R` and `Q^T r`, the rest is left behind. `None`
    /// where a column's norm overflows (entries of 1e154 or more: a diverging step),
    /// which nalgebra's QR met as an infinite diagonal and no fit.
    fn reduce(a: &mut [[f64; CHUNK]; MAX_PARAMS + 1], np: usize, rows: usize) -> Option<()> {
        for j in 0..np.min(rows) {
            let norm = a[j][j..rows].iter().map(|v| v * v).sum::<f64>().sqrt();
            if !norm.is_finite() {
                return None;
            }
            // (A zero column stays zero: `R`'s diagonal there is 0, and no fit.)
            if norm == 0.0 {
                continue;
            }
            // The reflection taking column `j` below the diagonal to `alpha e_j`, `v` of
            // `H = I - 2 v v^T / v^T v` in place of the column.
            let alpha = if a[j][j] > 0.0 { -norm } else { norm };
            a[j][j] -= alpha;
            let vv: f64 = a[j][j..rows].iter().map(|v| v * v).sum();
            if !vv.is_finite() {
                return None;
            }
            let (head, tail) = a.split_at_mut(j + 1);
            let v = &head[j][j..rows];
            for col in tail.iter_mut().take(np - j) {
                let tau = 2.0 * v.iter().zip(&col[j..rows]).map(|(v, c)| v * c).sum::<f64>() / vv;
                col[j..rows].iter_mut().zip(v).for_each(|(c, v)| *c -= tau * v);
            }
            head[j][j] = alpha;
            head[j][j + 1..rows].iter_mut().for_each(|v| *v = 0.0);
        }
        Some(())
    }

    /// The least-squares step `R^-1 Q^T r`; `None` where `R` is near singular (a
    /// diagonal at most 1e-12 of the largest: repeated or nearly equal references, a
    /// pixel whose levels cannot fix its parameters), as the SVD's cut-off made it.
    fn solve(&self) -> Option<[f64; MAX_PARAMS]> {
        let np = self.np;
        let diagonal = (0..np).map(|k| self.r[k][k].abs());
        if diagonal.clone().any(f64::is_nan) {
            return None;
        }
        let (lo, hi) = diagonal.fold((f64::INFINITY, 0.0f64), |(lo, hi), d| (lo.min(d), hi.max(d)));
        if !(hi.is_finite() && lo > 1e-12 * hi) {
            return None;
        }
        let mut x = [0.0; MAX_PARAMS];
        for k in (0..np).rev() {
            let tail: f64 = (k + 1..np).map(|j| self.r[k][j] * x[j]).sum();
            x[k] = (self.qtr[k] - tail) / self.r[k][k];
        }
        Some(x)
    }

    /// `R^-T v`: forward substitution through `R^T`.
    fn forward(&self, v: &[f64; MAX_PARAMS]) -> [f64; MAX_PARAMS] {
        let mut w = [0.0; MAX_PARAMS];
        for k in 0..self.np {
            let head: f64 = (0..k).map(|j| self.r[j][k] * w[j]).sum();
            w[k] = (v[k] - head) / self.r[k][k];
        }
        w
    }
}

/// [`fit_and_score`] by nalgebra's heap-allocated Householder QR, for models of more than
/// [`MAX_PARAMS`] parameters (and the oracle of its tests).
pub(super) fn fit_and_score_dense(model: Response, start: &[f64], fit: &[Point], test: &[Point]) -> Option<Scored> {
    let np = model.params();
    if fit.len() <= np {
        return None;
    }
    let mut p = start.to_vec();
    let mut grad = vec![0.0; np];
    let jacobian = |p: &[f64], pts: &[Point], grad: &mut [f64]| -> (DMatrix<f64>, DVector<f64>) {
        let mut j = DMatrix::zeros(pts.len(), np);
        let mut r = DVector::zeros(pts.len());
        for (i, q) in pts.iter().enumerate() {
            let v = model.eval(p, q.x, grad);
            r[i] = (q.y - v) / q.sigma;
            for k in 0..np {
                j[(i, k)] = grad[k] / q.sigma;
            }
        }
        (j, r)
    };
    // A polynomial is linear in its parameters: one step from any start is its least-squares
    // solution (a second one moved the parameters by 1e-13 of themselves and cost a third
    // of the run).
    let iterations = if matches!(model, Response::Curve(..)) { 8 } else { 1 };
    for _ in 0..iterations {
        let (j, r) = jacobian(&p, fit, &mut grad);
        // A diverging Gauss-Newton step must not reach the factorization with a NaN.
        if !(j.iter().all(|v| v.is_finite()) && r.iter().all(|v| v.is_finite())) {
            return None;
        }
        // Least squares by Householder QR (`R step = Q^T r`): as stable as the SVD for
        // these full-rank systems at a fraction of its cost; a singular `R` (a pixel
        // whose levels cannot fix its parameters) is no fit, as the inverse below would be.
        let qr = j.qr();
        let rr = qr.r();
        // Near-singular (repeated or nearly equal references): no fit, as the SVD's
        // cut-off at 1e-12 of the largest singular value made it before.
        let diag = rr.diagonal().map(f64::abs);
        if diag.min().is_nan() || diag.min() <= 1e-12 * diag.max() {
            return None;
        }
        let step = rr.solve_upper_triangular(&(qr.q().transpose() * &r))?;
        p.iter_mut().zip(step.iter()).for_each(|(a, d)| *a += d);
        if step.iter().zip(&p).all(|(d, a)| d.abs() <= 1e-12 * a.abs().max(1.0)) {
            break;
        }
    }
    let (jf, rf) = jacobian(&p, fit, &mut grad);
    let (jt, rt) = jacobian(&p, test, &mut grad);
    let a_inv = (jf.transpose() * &jf).try_inverse()?;
    let m = a_inv * (jt.transpose() * &jt);
    let n = test.len() as f64;
    let tr_m = m.trace();
    Some(Scored {
        params: p,
        chi2_fit: rf.norm_squared(),
        z: test.iter().zip(rt.iter()).map(|(q, &z)| Z(u16::try_from(q.level).unwrap_or(u16::MAX), z as f32)).collect(),
        tr: n + tr_m,
        tr2: n + 2.0 * tr_m + (&m * &m).trace(),
    })
}


/// Sums over pixels of held-out `z^2`, `tr C`, `tr C^2`, and the count of residuals.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Totals {
    pub s: f64,
    pub e: f64,
    pub v: f64,
    pub n: usize,
}

impl Totals {
    pub(super) fn plus(&self, o: &Totals) -> Totals {
        Totals { s: self.s + o.s, e: self.e + o.e, v: self.v + o.v, n: self.n + o.n }
    }
    pub(super) fn rms(&self) -> f64 {
        (self.s / self.n.max(1) as f64).sqrt()
    }
    /// How far `self` (the simpler model) lies above what `richer` leaves by chance, in
    /// `richer`'s null spread.
    pub(super) fn significance_to(&self, richer: &Totals) -> f64 {
        (self.s - richer.s.max(richer.e)) / richer.v.sqrt().max(1e-300)
    }
    pub(super) fn excess(&self) -> f64 {
        (self.s - self.e) / self.v.sqrt().max(1e-300)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points at references rising by `steps` from 0 to below 1 (a set's levels: distinct),
    /// means of a smooth response plus `noise` (fractions of each point's sigma), sigmas
    /// of a few DN.
    fn points(steps: &[f64], coeffs: &[f64; 5], noise: &[f64], sigmas: &[f64]) -> Vec<Point> {
        let total: f64 = steps.iter().sum();
        let xs: Vec<f64> = steps.iter().scan(0.0, |at, s| Some(std::mem::replace(at, *at + s) / total)).collect();
        xs
            .iter()
            .enumerate()
            .map(|(level, &x)| {
                let y = coeffs.iter().rev().fold(0.0, |acc, c| acc * x + c);
                let sigma = sigmas[level % sigmas.len()];
                Point { level, x, y: y + noise[level % noise.len()] * sigma, sigma }
            })
            .collect()
    }

    /// `a` and `b` agree to `tol` of `scale` (or of themselves, where larger).
    fn close(a: f64, b: f64, scale: f64, tol: f64) -> bool {
        (a - b).abs() <= tol * scale.max(a.abs()).max(b.abs())
    }

    /// The held-out covariance's traces as the definition has them: `C = I + J_t A^-1
    /// J_t^T`, `A = J_f^T J_f`, built whole and traced.
    fn traces_naive(model: Response, p: &[f64], fit: &[Point], test: &[Point]) -> (f64, f64) {
        let np = model.params();
        let jac = |pts: &[Point]| {
            let mut grad = vec![0.0; np];
            DMatrix::from_fn(pts.len(), np, |i, k| {
                model.eval(p, pts[i].x, &mut grad);
                grad[k] / pts[i].sigma
            })
        };
        let (jf, jt) = (jac(fit), jac(test));
        let a_inv = (jf.transpose() * &jf).try_inverse().unwrap();
        let c = DMatrix::identity(test.len(), test.len()) + &jt * a_inv * jt.transpose();
        (c.trace(), (&c * &c).trace())
    }

    /// The condition number of `J_f^T J_f` (the squared ratio of `J_f`'s extreme singular
    /// values).
    fn condition_of_normal_matrix(model: Response, p: &[f64], fit: &[Point]) -> f64 {
        let np = model.params();
        let mut grad = vec![0.0; np];
        let j = DMatrix::from_fn(fit.len(), np, |i, k| {
            model.eval(p, fit[i].x, &mut grad);
            grad[k] / fit[i].sigma
        });
        let sv = j.singular_values();
        (sv.max() / sv.min()).powi(2)
    }

    proptest::proptest! {
        /// The stack solver gives what the heap QR gives (parameters, fit chi^2, held-out
        /// residuals and traces), and the traces are those of the covariance built whole:
        /// for every model of the catalogue, on random references (12 to 199 of them: the
        /// stack's chunks of 64 rows one after another), responses, noise and weights.
        #[test]
        fn the_stack_fit_is_the_dense_fit(
            steps in proptest::collection::vec(0.2f64..1.0, 12..200),
            c in proptest::array::uniform5(-50.0f64..50.0),
            gain in 500.0f64..4000.0,
            noise in proptest::collection::vec(-3.0f64..3.0, 1..42),
            sigmas in proptest::collection::vec(0.2f64..20.0, 1..42),
            model in 0usize..5,
            split in 0usize..2,
        ) {
            let coeffs = [c[0] + 100.0, gain, c[2], c[3], c[4]];
            let pts = points(&steps, &coeffs, &noise, &sigmas);
            let (fit, test): (Vec<Point>, Vec<Point>) = if split == 0 {
                pts.iter().partition(|q| q.level % 2 == 0)
            } else {
                (pts.clone(), Vec::new())
            };
            let bend = [0.02, -0.01, 0.005];
            let (model, start) = match model {
                0 => (Response::Poly(1), vec![0.0; 2]),
                1 => (Response::Poly(2), vec![0.0; 3]),
                2 => (Response::Poly(4), vec![0.0; 5]),
                3 => (Response::Curve(bend, 4095.0), vec![coeffs[0], gain]),
                _ => (Response::Common(bend, 4095.0, gain), vec![0.0; 2]),
            };
            let (ours, dense) = (fit_and_score(model, &start, &fit, &test), fit_and_score_dense(model, &start, &fit, &test));
            // Distinct references: both fit, or neither.
            proptest::prop_assert_eq!(ours.is_some(), dense.is_some());
            let (Some(ours), Some(dense)) = (ours, dense) else { return Ok(()) };
            let scale = coeffs.iter().map(|c| c.abs()).fold(0.0, f64::max);
            for (a, b) in ours.params.iter().zip(&dense.params) {
                proptest::prop_assert!(close(*a, *b, scale, 1e-7), "{:?} vs {:?}", ours.params, dense.params);
            }
            proptest::prop_assert!(close(ours.chi2_fit, dense.chi2_fit, 1.0, 1e-7));
            proptest::prop_assert_eq!(ours.z.len(), dense.z.len());
            for (a, b) in ours.z.iter().zip(&dense.z) {
                proptest::prop_assert_eq!(a.level(), b.level());
                proptest::prop_assert!(close(a.z(), b.z(), 1.0, 1e-5), "z {} vs {}", a.z(), b.z());
            }
            // The traces go through `A^-1`, which the dense fit and the definition invert
            // whole: they agree to the rounding of `A`'s condition number. (With sigmas
            // 400 times apart, held-out levels of 1e5 times a fitted one's weight gave
            // traces of 3e4 that differed in their tenth digit: the sigmas here are 100
            // times apart at most, a pixel's from dark to the top level are 10-30.) A run
            // on 2026-12-05 found a case past 1e-14 x the condition number: six fitted
            // levels of a quadratic with sigmas 5-17 and 0.2, held-out ones of 0.2. The
            // stack's traces came 1.1e-8 (relative) from the dense fit's, which agree with
            // the definition's to 1e-14 only because both invert the same `J^T J`. The two
            // factors `R` (the stack's and nalgebra's QR) differ by 1.4e-14 on the smallest
            // diagonal (measured), and held-out rows of 25-85 times the weight of five of
            // the six fitted ones carry that about 10^6-fold into the traces: both are
            // right to their factor's rounding. Hence 1e-8 and 1e-12 x the condition.
            let tol = 1e-8f64.max(1e-12 * condition_of_normal_matrix(model, &ours.params, &fit));
            proptest::prop_assert!(close(ours.tr, dense.tr, 1.0, tol) && close(ours.tr2, dense.tr2, 1.0, tol), "{} {} vs {} {}", ours.tr, ours.tr2, dense.tr, dense.tr2);
            if !test.is_empty() {
                let (tr, tr2) = traces_naive(model, &ours.params, &fit, &test);
                proptest::prop_assert!(close(ours.tr, tr, 1.0, tol) && close(ours.tr2, tr2, 1.0, tol), "{} {} vs {} {}", ours.tr, ours.tr2, tr, tr2);
            }
        }
    }

    /// A noiseless quartic is recovered to rounding, whatever the weights; with its
    /// references all equal, or fewer points than parameters, there is no fit.
    #[test]
    fn a_noiseless_quartic_is_recovered_and_degenerate_levels_are_none() {
        let coeffs = [101.5, 3000.0, -40.0, 12.5, -3.0];
        let pts = points(&[1.0; 21], &coeffs, &[0.0], &[0.3, 2.0, 7.0]);
        let s = fit_and_score(Response::Poly(4), &[0.0; 5], &pts, &[]).unwrap();
        for (a, b) in s.params.iter().zip(&coeffs) {
            assert!((a - b).abs() < 1e-9 * 3000.0, "{:?}", s.params);
        }
        assert!(s.chi2_fit < 1e-12);
        let flat: Vec<Point> = pts.iter().map(|q| Point { x: 0.5, ..*q }).collect();
        assert!(fit_and_score(Response::Poly(4), &[0.0; 5], &flat, &[]).is_none());
        assert!(fit_and_score(Response::Poly(4), &[0.0; 5], &pts[..5], &[]).is_none());
    }
}
