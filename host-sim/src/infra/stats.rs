//! The few statistics every part of the crate uses: medians, robust scatter, RMS, a
//! straight-line fit. One copy each, so that "the median" means one thing per use.
//!
//! Two medians, on purpose:
//! - [`median`] averages the two middle values of an even count: the textbook median, the
//!   one a user recomputes with numpy (`np.median`). Reported summaries (spreads over
//!   noise realizations, benchmark timings, per-level corrections) use it.
//! - [`upper_median`] is the value at index `n / 2` of the sorted values, found by
//!   selection in O(n): always a sample value, and the robust centre of the per-level
//!   and per-pixel statistics of `diagnose` and the EMVA spatial analysis, whose
//!   findings and tests were calibrated with it. For odd counts the two agree; for even
//!   counts they differ by half the gap between the middle values.

/// The median of the finite values of `v` (mean of the two middle ones for an even
/// count); NaN when there are none.
pub fn median(v: impl IntoIterator<Item = f64>) -> f64 {
    let mut v: Vec<f64> = v.into_iter().filter(|x| x.is_finite()).collect();
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    let (_, &mut hi, _) = v.select_nth_unstable_by(n / 2, f64::total_cmp);
    if n % 2 == 1 {
        return hi;
    }
    // The lower middle is the largest value left of the upper one after selection.
    let lo = v[..n / 2].iter().copied().fold(f64::NEG_INFINITY, f64::max);
    0.5 * (lo + hi)
}

/// The upper median of the finite values of `v`: the value at index `n / 2` of their
/// sorted order (see the module's note); NaN when there are none.
pub fn upper_median(v: impl IntoIterator<Item = f64>) -> f64 {
    let mut v: Vec<f64> = v.into_iter().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return f64::NAN;
    }
    let mid = v.len() / 2;
    *v.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// Robust centre and scatter of `v`: the upper median and 1.4826 x the upper median of
/// the absolute deviations from it (the MAD scaled to a Gaussian's standard deviation).
pub fn robust(v: &[f64]) -> (f64, f64) {
    let centre = upper_median(v.iter().copied());
    (centre, 1.4826 * upper_median(v.iter().map(|x| (x - centre).abs())))
}

/// Mean of `v`; NaN for an empty slice.
pub fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

/// Variance of `v` about its mean, divided by the count (numpy's `var`, ddof 0); NaN for
/// an empty slice.
pub fn variance(v: &[f64]) -> f64 {
    let m = mean(v);
    v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / v.len() as f64
}

/// Mean of the squares of `v`; 0 for an empty slice.
pub fn mean_sq(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64
}

/// Root mean square of `v`; 0 for an empty slice.
pub fn rms(v: &[f64]) -> f64 {
    mean_sq(v).sqrt()
}

/// Largest absolute value of `v`; 0 for an empty slice.
pub fn max_abs(v: &[f64]) -> f64 {
    v.iter().fold(0.0, |m: f64, e| m.max(e.abs()))
}

/// Root mean square of the finite values of `v`; NaN when there are none (a quantity
/// undefined everywhere, such as a relative error at a level of zero signal).
pub fn rms_finite(v: impl IntoIterator<Item = f64>) -> f64 {
    v.into_iter().fold(RmsSum::default(), |mut acc, x| {
        acc.add(x);
        acc
    })
    .rms()
}

/// [`rms_finite`] one value at a time: for a pass that accumulates several RMS at once.
#[derive(Debug, Clone, Copy, Default)]
pub struct RmsSum {
    sum: f64,
    n: usize,
}

impl RmsSum {
    /// Counts `v` if it is finite.
    pub fn add(&mut self, v: f64) {
        if v.is_finite() {
            self.sum += v * v;
            self.n += 1;
        }
    }

    /// The RMS of the values counted; NaN when there are none.
    pub fn rms(self) -> f64 {
        if self.n == 0 { f64::NAN } else { (self.sum / self.n as f64).sqrt() }
    }
}

/// Least-squares line `y = a + b x`: (a, b, R^2). NaN where `x` has no spread.
pub fn fit_line(x: &[f64], y: &[f64]) -> (f64, f64, f64) {
    let n = x.len() as f64;
    let (mx, my) = (x.iter().sum::<f64>() / n, y.iter().sum::<f64>() / n);
    let sxy: f64 = x.iter().zip(y).map(|(a, b)| (a - mx) * (b - my)).sum();
    let sxx: f64 = x.iter().map(|a| (a - mx) * (a - mx)).sum();
    let syy: f64 = y.iter().map(|b| (b - my) * (b - my)).sum();
    let slope = sxy / sxx;
    (my - slope * mx, slope, sxy * sxy / (sxx * syy))
}

/// Least squares `x b = y` (rows of `x` the observations), by SVD: `None` when the
/// system has no rows or the solver fails.
pub fn lstsq(x: &[Vec<f64>], y: &[f64]) -> Option<Vec<f64>> {
    let p = x.first()?.len();
    let a = nalgebra::DMatrix::from_fn(x.len(), p, |r, c| x[r][c]);
    let b = nalgebra::DVector::from_column_slice(y);
    a.svd(true, true).solve(&b, 1e-10).ok().map(|s| s.iter().copied().collect())
}

/// The cubic trend of a table `y` of `y.len()` codes in `x = k / (codes - 1)`,
/// `p0 + p1 x + p2 x^2 + p3 x^3`, least squares over the codes `fitted`: `None` when the
/// fit fails or gives a value that is not finite. (The K-Cor tables' response curve,
/// `lut inspect` and `adc --from-luts`.)
pub fn cubic_fit(y: &[f64], fitted: std::ops::RangeInclusive<usize>) -> Option<[f64; 4]> {
    let n = y.len();
    let rows: Vec<Vec<f64>> = fitted.clone().filter(|&k| k < n).map(|k| (0..4).map(|p| cubic_x(k, n).powi(p)).collect()).collect();
    let ys: Vec<f64> = fitted.filter(|&k| k < n).map(|k| y[k]).collect();
    let c = lstsq(&rows, &ys).filter(|c| c.len() == 4 && c.iter().all(|v| v.is_finite()))?;
    Some([c[0], c[1], c[2], c[3]])
}

/// `x = k / (codes - 1)` of [`cubic_fit`].
pub fn cubic_x(k: usize, codes: usize) -> f64 {
    k as f64 / (codes.max(2) - 1) as f64
}

/// The cubic `c` of [`cubic_fit`] at code k of `codes`.
pub fn cubic_at(c: &[f64; 4], k: usize, codes: usize) -> f64 {
    let x = cubic_x(k, codes);
    c[0] + x * (c[1] + x * (c[2] + x * c[3]))
}

/// The cubic `c`'s largest departure from the straight line through its ends (codes 0
/// and `codes - 1`), over all codes, DN: how far a response curve bends.
pub fn cubic_bow(c: &[f64; 4], codes: usize) -> f64 {
    let (a, b) = (cubic_at(c, 0, codes), cubic_at(c, codes.saturating_sub(1), codes));
    (0..codes).map(|k| (cubic_at(c, k, codes) - (a + (b - a) * cubic_x(k, codes))).abs()).fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The naive definitions: sort everything, index.
    fn sorted(v: &[f64]) -> Vec<f64> {
        let mut s: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
        s.sort_by(f64::total_cmp);
        s
    }

    proptest! {
        #[test]
        fn the_medians_match_sorting(v in proptest::collection::vec(prop_oneof![-1e6..1e6f64, Just(f64::NAN)], 0..60)) {
            let s = sorted(&v);
            let n = s.len();
            if n == 0 {
                prop_assert!(median(v.clone()).is_nan() && upper_median(v).is_nan());
            } else {
                let want = if n % 2 == 1 { s[n / 2] } else { 0.5 * (s[n / 2 - 1] + s[n / 2]) };
                prop_assert_eq!(median(v.clone()), want);
                prop_assert_eq!(upper_median(v), s[n / 2]);
            }
        }
    }

    #[test]
    fn the_two_medians_differ_only_for_even_counts() {
        assert_eq!(median([3.0, 1.0, 2.0]), 2.0);
        assert_eq!(upper_median([3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median([4.0, 1.0, 3.0, 2.0]), 2.5);
        assert_eq!(upper_median([4.0, 1.0, 3.0, 2.0]), 3.0);
    }

    #[test]
    fn robust_scatter_of_a_symmetric_set_is_its_scaled_mad() {
        // Deviations from 10: 0, 1, 1, 2, 2 -> MAD 1.
        let (c, s) = robust(&[10.0, 9.0, 11.0, 8.0, 12.0]);
        assert_eq!(c, 10.0);
        assert!((s - 1.4826).abs() < 1e-12);
    }

    #[test]
    fn rms_and_line_fit_against_closed_forms() {
        assert!((rms(&[3.0, 4.0]) - (12.5f64).sqrt()).abs() < 1e-12);
        assert_eq!(rms(&[]), 0.0);
        assert!((rms_finite([3.0, f64::NAN, 4.0]) - (12.5f64).sqrt()).abs() < 1e-12);
        assert!(rms_finite([f64::INFINITY]).is_nan());
        let x = [0.0, 1.0, 2.0, 3.0];
        let (a, b, r2) = fit_line(&x, &x.map(|v| 3.0 + 0.5 * v));
        assert!((a - 3.0).abs() < 1e-12 && (b - 0.5).abs() < 1e-12 && (r2 - 1.0).abs() < 1e-12);
    }
}
