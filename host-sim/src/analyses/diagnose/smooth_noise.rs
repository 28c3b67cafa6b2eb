//! A pixel's frame variance as a smooth function of its mean: the weights of fits to
//! means that carry errors much larger than their noise.
//!
//! Each mean of a linearity set comes with its frames' variance `s^2`, an estimate with
//! `N - 1` degrees of freedom: at 8 frames it is off by 50% rms. As a weight that is
//! harmless where the residuals are noise, but the level term's fits see every pixel's
//! means carrying the light's errors (2% of the signal, 5 times a mean's noise on a
//! consumer camera's series): weighted by their own `s^2`, each pixel's quartic took a
//! different share of them, its slope (through which the light's part is taken out of
//! it) was off by a few percent at the ends of the range, and what was left was named
//! `unexplained`, `pixel-nonlinearity`, `bad-pixels` and `adc-mismatch` on a sensor that
//! had none of them (issue 58; with the frames' variance replaced by its mean over the
//! pixels of a level, the same sets gave `level-errors` alone). So those fits weigh a
//! pixel's means by its variance fitted over all its levels, `s^2 ~ a + b m + c m^2`
//! (the photon transfer: read noise, shot noise, and a light that jitters from frame to
//! frame or a conversion that bends): at 8 frames within 12-14% rms of the true variance
//! above the darkest levels, where each level's own is 53% off.

/// The fewest levels the fit is made on; with fewer, each level keeps its own variance.
const MIN_LEVELS: usize = 6;

/// `s2` (each level's frame variance from `frames` frames, DN^2) replaced by the variance
/// a mean's residual is divided by so that its square is 1 on average: its weighted
/// least-squares fit
/// `a + b u + c u^2` in `u = m / max |m|` (`m` the levels' means, DN), iterated with
/// weights `1 / v^2` (the variance of a variance is proportional to its square), `v`
/// starting at the levels' own values (from the mean of all, the dark level, 10 times
/// quieter than the next, was weighed as one of them and its fit was off by 3 times).
/// The fit at a level has the noise of a variance of `(N - 1) / h` degrees of freedom
/// (`h` its leverage), so it is scaled by `d / (d - 2)`, the mean of `1 / X` for such an
/// estimate `X` (the dark level, about on its own, by `(N - 1) / (N - 3)` as a raw
/// variance is; the bright levels by 1.01-1.03 at 8 frames: so `E[true / smoothed]` is 1
/// within 1% above the two darkest levels, within 4% at them). Levels whose `m` or `s2` is
/// not finite are left as they are; with fewer than [`MIN_LEVELS`] usable levels, or a
/// singular fit, each usable level keeps its own value, scaled by `(N - 1) / (N - 3)`.
pub fn smooth_variance(m: &[f64], s2: &mut [f64], frames: u32) {
    let dof = f64::from(frames.max(1) - 1);
    let usable: Vec<usize> = (0..m.len().min(s2.len())).filter(|&l| m[l].is_finite() && s2[l].is_finite() && s2[l] >= 0.0).collect();
    match fitted(m, s2, &usable, dof) {
        Some(v) => usable.iter().zip(v).for_each(|(&l, v)| s2[l] = v.unwrap_or(s2[l] * inverse_mean(dof))),
        None => usable.iter().for_each(|&l| s2[l] *= inverse_mean(dof)),
    }
}

/// [`smooth_variance`]'s values at the levels `usable` (`None` at a level where the fit
/// is not positive), where the fit can be made.
fn fitted(m: &[f64], s2: &[f64], usable: &[usize], dof: f64) -> Option<Vec<Option<f64>>> {
    if usable.len() < MIN_LEVELS {
        return None;
    }
    let scale = usable.iter().map(|&l| m[l].abs()).fold(0.0, f64::max);
    let top = usable.iter().map(|&l| s2[l]).fold(0.0, f64::max);
    if !(scale > 0.0 && top > 0.0) {
        return None;
    }
    let basis = |l: usize| nalgebra::Vector3::new(1.0, m[l] / scale, (m[l] / scale).powi(2));
    // The normal matrix of weights `1 / v^2`, inverted.
    let normal = |v: &[f64]| usable.iter().zip(v).fold(nalgebra::Matrix3::<f64>::zeros(), |a, (&l, v)| a + basis(l) * basis(l).transpose() / (v * v)).try_inverse();
    // (A variance of 0 is weighed as 1e-3 of the largest. A level whose own variance
    // came out far too low can pull the fit through it and hold it there: a level in
    // 1,000 pixels at 11 levels of 8 frames, 3 in 1,000 at 41 levels of 4, none in 20,000
    // at 41 of 8, an independent review's simulation. A floor at a tenth of the
    // unweighted fit left the dark level's `E[true / smoothed]` at 1.38.)
    let mut v: Vec<f64> = usable.iter().map(|&l| s2[l].max(1e-3 * top)).collect();
    let mut fit = Vec::new();
    for _ in 0..ITERATIONS {
        let b = usable.iter().zip(&v).fold(nalgebra::Vector3::<f64>::zeros(), |b, (&l, v)| b + basis(l) * (s2[l] / (v * v)));
        let c = normal(&v)? * b;
        fit = usable.iter().map(|&l| c.dot(&basis(l))).collect();
        if !fit.iter().all(|f| f.is_finite()) {
            return None;
        }
        // (A level where the fit is not positive keeps its weight.)
        v.iter_mut().zip(&fit).filter(|(_, f)| **f > 0.0).for_each(|(v, f)| *v = *f);
    }
    // Each level's leverage `h` under the final weights: the fit there has the noise of
    // a variance of `(N - 1) / h` degrees of freedom.
    let inv = normal(&v)?;
    let leverage = usable.iter().zip(&v).map(|(&l, v)| (basis(l).transpose() * inv * basis(l))[0] / (v * v));
    Some(fit.iter().zip(leverage).map(|(&f, h)| (f > 0.0).then(|| f * inverse_mean(dof / h.clamp(1e-9, 1.0)))).collect())
}

/// `d / (d - 2)`: the mean of `1 / X` for `X` a variance estimate of `d` degrees of
/// freedom, relative (1 at `d <= 2`, where it has none).
fn inverse_mean(d: f64) -> f64 {
    if d > 2.0 { d / (d - 2.0) } else { 1.0 }
}

/// Reweighting passes of [`smooth_variance`] (6: the fits of drawn photon transfers
/// stopped changing after 4 or 5).
const ITERATIONS: usize = 6;

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{ChiSquared, Distribution};

    /// Planted photon transfers (read noise, shot noise, a jitter's `S^2` term) drawn as
    /// 8 frames' sample variances (each 53% rms off): above the two darkest levels the
    /// smoothed variance is within 20% rms of the planted and 2.5 times closer than the
    /// samples (measured first in numpy: 8-16% rms there, the dark level at its own 53%),
    /// and the planted over it is 1 on average within 1% at every level, as it is for
    /// the samples scaled by `kappa`.
    #[test]
    fn a_drawn_photon_transfer_comes_back_smooth() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(3);
        let frames = 8u32;
        let dof = f64::from(frames - 1);
        let chi = ChiSquared::new(dof).unwrap();
        let m: Vec<f64> = (0..41).map(|l| 60.0 + 90.0 * l as f64).collect();
        for (read2, gain, jitter) in [(4.0, 2.5, 0.0), (16.0, 44.0, 0.0), (4.0, 2.5, 0.01)] {
            let truth: Vec<f64> = m.iter().map(|&m| read2 + (m - 60.0) / gain + (jitter * (m - 60.0)).powi(2)).collect();
            let (mut raw_sq, mut fit_sq) = (0.0, 0.0);
            let pixels = 2000;
            let (mut inverse, mut raw_inverse) = (vec![0.0; m.len()], vec![0.0; m.len()]);
            for _ in 0..pixels {
                let raw: Vec<f64> = truth.iter().map(|t| t * chi.sample(&mut rng) / dof).collect();
                let mut fit = raw.clone();
                smooth_variance(&m, &mut fit, frames);
                for l in 0..m.len() {
                    inverse[l] += truth[l] / fit[l] / f64::from(pixels);
                    raw_inverse[l] += truth[l] / (raw[l] * dof / (dof - 2.0)) / f64::from(pixels);
                    if l >= 2 {
                        raw_sq += (raw[l] / truth[l] - 1.0).powi(2);
                        fit_sq += (fit[l] / truth[l] - 1.0).powi(2);
                    }
                }
            }
            let n = f64::from(pixels) * (m.len() - 2) as f64;
            let (raw_rms, fit_rms) = ((raw_sq / n).sqrt(), (fit_sq / n).sqrt());
            assert!(fit_rms < 0.2 && fit_rms * 2.5 < raw_rms, "{read2} {gain} {jitter}: {fit_rms} against {raw_rms}");
            // (The raw one's mean is 1 exactly; its error at a level about 1.4%, the
            // smoothed one's 0.3% above the darkest levels.)
            for l in 0..m.len() {
                let tol = if l < 2 { 0.06 } else { 0.01 };
                assert!((inverse[l] - 1.0).abs() < tol, "{read2} {gain} {jitter}, level {l}: {} (raw {})", inverse[l], raw_inverse[l]);
            }
        }
    }

    /// Too few levels and a flat zero variance keep their own values, scaled by `kappa`
    /// (`7 / 5` at 8 frames); a value that is not finite is left as it is.
    #[test]
    fn what_cannot_be_fitted_keeps_its_own() {
        let m = [1.0, 2.0, 3.0, 4.0, 5.0];
        let mut s2 = [1.0, 5.0, 2.0, 7.0, 3.0];
        smooth_variance(&m, &mut s2, 8);
        assert_eq!(s2, [1.0, 5.0, 2.0, 7.0, 3.0].map(|v| v * (7.0 / 5.0)));
        let m: Vec<f64> = (0..10).map(f64::from).collect();
        let mut zero = vec![0.0; 10];
        smooth_variance(&m, &mut zero, 8);
        assert_eq!(zero, vec![0.0; 10]);
        let mut nan = vec![2.0; 10];
        nan[3] = f64::NAN;
        smooth_variance(&m, &mut nan, 256);
        // (The others fitted: 2, scaled up by a little more than 1 for the fit's noise.)
        assert!(nan[3].is_nan() && nan.iter().enumerate().all(|(l, v)| l == 3 || (v / 2.0 - 1.0) > 0.0 && (v / 2.0 - 1.0) < 0.01), "{nan:?}");
    }
}
