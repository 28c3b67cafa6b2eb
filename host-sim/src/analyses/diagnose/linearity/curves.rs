//! The shared signal-domain curve of a group of pixels (`global-nonlinearity`, and each
//! ADC's own curve for `adc-mismatch`).

use nalgebra::{DMatrix, DVector};

use crate::analyses::diagnose::points::{Common, Pixels};
use crate::analyses::diagnose::tasks::picked_tasks;
use crate::formats::fits::Sample;

/// The shared signal-domain curve `c` of the pixels `(pixel, gain)` that `pixels(j)`
/// takes of `0..n`, from their even levels: the least-squares fit of
/// `m = d_p + b_p x + sum_k c_k S^(k+2) / T^(k+1)`, `S = g_p x`, with every pixel's own
/// dark and slope free (projected out per pixel, then one 3 x 3 system).
///
/// The gains `g_p` must not carry the pixel's own curvature: they are the linear
/// coefficients of the pixels' quartics (a bend goes into the quadratic term there). With
/// the slopes of straight-line fits, which do carry it, 0.6% rms of pixel-to-pixel
/// curvature with no shared part gave a shared curve that a held-out test accepted at 7.7
/// standard deviations (errors in variables). And not the medians of the quartics'
/// coefficients either: those are nearly collinear and too noisy (0.5-1 DN of shared error
/// per level on a 64 x 64 set, an 'unexplained' excess of 13 standard deviations).
pub(super) fn shared_curve<T: Sample>(px: &Pixels<T>, common: Option<&dyn Common>, n: usize, pixels: &(dyn Fn(usize) -> Option<(usize, f64)> + Sync), top: f64) -> [f64; 3] {
    let zero = || (DMatrix::zeros(3, 3), DVector::zeros(3));
    let add = |a: (DMatrix<f64>, DVector<f64>), b: (DMatrix<f64>, DVector<f64>)| (a.0 + b.0, a.1 + b.1);
    // Summed in pixel order within a task and in task order across them (`TASKS` runs
    // of the pixels taken).
    let parts: Vec<(DMatrix<f64>, DVector<f64>)> = picked_tasks(n, pixels, |chunk| {
        chunk.filter(|(_, g)| g.is_finite()).map(|(i, g)| {
            let pts = px.halves(i, common).0;
            let k = pts.len();
            if k <= 3 {
                return (DMatrix::zeros(3, 3), DVector::zeros(3));
            }
            let x = DMatrix::from_fn(k, 2, |i, j| if j == 0 { 1.0 / pts[i].sigma } else { pts[i].x / pts[i].sigma });
            let u = DMatrix::from_fn(k, 3, |i, j| (g * pts[i].x / top).powi(j as i32 + 2) * top / pts[i].sigma);
            let y = DVector::from_iterator(k, pts.iter().map(|q| q.y / q.sigma));
            // Residual maker of the pixel's own [1, x] columns.
            let Some(inv) = (x.transpose() * &x).try_inverse() else { return (DMatrix::zeros(3, 3), DVector::zeros(3)) };
            let q = DMatrix::identity(k, k) - &x * inv * x.transpose();
            let qu = &q * &u;
            (qu.transpose() * &qu, qu.transpose() * (&q * y))
        }).fold(zero(), add)
    });
    let (n, r) = parts.into_iter().fold(zero(), add);
    match n.try_inverse() {
        Some(inv) => {
            let sol = inv * r;
            [sol[0], sol[1], sol[2]]
        }
        None => [f64::NAN; 3],
    }
}
