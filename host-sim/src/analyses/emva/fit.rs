//! The three straight-line fits EMVA 1288 uses, in closed form.

pub use crate::infra::stats::fit_line;

/// Least-squares line through the origin `y = b x` (the standard's fits of the system
/// gain and the responsivity): `b = sum x y / sum x^2`. NaN where every `x` is 0.
pub fn fit_origin(x: &[f64], y: &[f64]) -> f64 {
    let sxy: f64 = x.iter().zip(y).map(|(a, b)| a * b).sum();
    let sxx: f64 = x.iter().map(|a| a * a).sum();
    sxy / sxx
}

/// The linearity fit of EMVA 1288 (Release 3.1 eq. 45): the line `y = a x + b` that
/// minimizes the squared *relative* deviations `sum ((y - a x - b) / y)^2`, so that every
/// level weighs the same in percent. Returns `(a, b)`; NaN where the normal equations are
/// singular (fewer than two distinct `x / y`).
pub fn fit_relative(x: &[f64], y: &[f64]) -> (f64, f64) {
    // Weighted least squares with weights 1/y^2: normal equations in the sums below.
    let (mut s_xy, mut s_xy2, mut s_x2y2, mut s_y, mut s_y2) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for (&x, &y) in x.iter().zip(y) {
        s_xy += x / y;
        s_xy2 += x / (y * y);
        s_x2y2 += (x / y) * (x / y);
        s_y += 1.0 / y;
        s_y2 += 1.0 / (y * y);
    }
    let b = (s_xy * s_xy2 - s_x2y2 * s_y) / (s_xy2 * s_xy2 - s_x2y2 * s_y2);
    let a = (s_xy - b * s_xy2) / s_x2y2;
    (a, b)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fits_recover_planted_lines() {
        let x = [1.0, 2.0, 4.0, 8.0];
        let (a, b, r2) = fit_line(&x, &x.map(|v| 3.0 + 0.5 * v));
        assert!((a - 3.0).abs() < 1e-12 && (b - 0.5).abs() < 1e-12 && (r2 - 1.0).abs() < 1e-12);
        assert!((fit_origin(&x, &x.map(|v| 0.25 * v)) - 0.25).abs() < 1e-15);
        let (a, b) = fit_relative(&x, &x.map(|v| 2.0 * v + 1.0));
        assert!((a - 2.0).abs() < 1e-12 && (b - 1.0).abs() < 1e-12, "{a} {b}");
    }

    /// The relative fit against a naive minimization: its residual sum of squares must be
    /// no larger than at any nearby (a, b).
    #[test]
    fn relative_fit_minimizes_relative_deviations() {
        let x = [10.0, 20.0, 35.0, 50.0, 80.0];
        let y = [21.0, 39.5, 72.0, 99.0, 163.0];
        let cost = |a: f64, b: f64| x.iter().zip(&y).map(|(x, y)| ((y - a * x - b) / y).powi(2)).sum::<f64>();
        let (a, b) = fit_relative(&x, &y);
        let best = cost(a, b);
        for da in [-1e-3, 0.0, 1e-3] {
            for db in [-1e-2, 0.0, 1e-2] {
                assert!(cost(a + da, b + db) >= best - 1e-15, "({da}, {db})");
            }
        }
    }
}
