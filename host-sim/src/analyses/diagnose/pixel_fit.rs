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
pub(super) fn fit_and_score(model: Response, start: &[f64], fit: &[Point], test: &[Point]) -> Option<Scored> {
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
