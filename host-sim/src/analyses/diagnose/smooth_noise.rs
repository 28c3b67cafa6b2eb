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
/// a mean's residual is divided by so that its square is 1 on average
/// ([`NoiseFit::new`], then [`NoiseFit::variance`] at each level).
#[cfg(test)]
pub fn smooth_variance(m: &[f64], s2: &mut [f64], frames: u32) {
    let fit = NoiseFit::new(m, s2);
    m.iter().zip(s2.iter_mut()).for_each(|(&m, s2)| *s2 = fit.variance(m, *s2, frames));
}

/// A pixel's frame variance fitted over its levels, kept (80 bytes) so that the passes
/// that weigh its means fit it once: about 13 passes a pixel refitted it, 12% of a
/// 128 x 128 x 41 diagnosis. (Kept in single precision, its values were up to 0.7% off
/// the fit's where the dark level is a thousand times quieter than the next and holds the
/// fit: its coefficients cancel there.)
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct NoiseFit {
    /// `max |m|` over the levels fitted, DN; NaN where there is no fit (each level then
    /// keeps its own variance, scaled by `kappa`).
    scale: f64,
    /// `a, b, c` of `a + b u + c u^2`, DN^2, `u = m / scale`.
    coef: [f64; 3],
    /// The inverse of the normal matrix under the final weights, its upper triangle by
    /// rows (`00 01 02 11 12 22`), for each level's leverage.
    inv: [f64; 6],
}

impl NoiseFit {
    /// No fit: every level keeps its own variance.
    pub const NONE: NoiseFit = NoiseFit { scale: f64::NAN, coef: [f64::NAN; 3], inv: [f64::NAN; 6] };

    /// The weighted least-squares fit of `a + b u + c u^2` to `s2` (each level's frame
    /// variance, DN^2) in `u = m / max |m|` (`m` the levels' means, DN), iterated with
    /// weights `1 / v^2` (the variance of a variance is proportional to its square), `v`
    /// starting at the levels' own values (from the mean of all, the dark level, 10 times
    /// quieter than the next, was weighed as one of them and its fit was off by 3 times).
    /// Levels whose `m` or `s2` is not finite take no part; with fewer than
    /// [`MIN_LEVELS`] of them, or a singular fit, [`NoiseFit::NONE`].
    ///
    /// A level whose own variance came out far too low can pull the fit through it and
    /// hold it there, as its own variance would weigh it. Drawn photon transfers (20,000
    /// pixels each) with a level where the fit is below a fifth of the truth: 0.55-0.8%
    /// of pixels at 8 frames (11 to 41 levels), 2.5% at 41 levels of 4 frames; with each
    /// level's own variance times `kappa`, 5.5-19% and 60%. Fitting again without a level
    /// that the fit through the others ruled out (its leave-one-out value, 1e-4 tails
    /// with that value's own noise counted) did not lower those shares (0.7-3.8%): the
    /// others' value, under the held fit's weights, is held too. Not kept.
    pub fn new(m: &[f64], s2: &[f64]) -> NoiseFit {
        let usable: Vec<(f64, f64)> = m.iter().zip(s2).map(|(&m, &s)| (m, s)).filter(|(m, s)| m.is_finite() && s.is_finite() && *s >= 0.0).collect();
        if usable.len() < MIN_LEVELS {
            return NoiseFit::NONE;
        }
        let scale = usable.iter().map(|(m, _)| m.abs()).fold(0.0, f64::max);
        let top = usable.iter().map(|(_, s)| *s).fold(0.0, f64::max);
        if !(scale > 0.0 && top > 0.0) {
            return NoiseFit::NONE;
        }
        let points: Vec<(f64, f64)> = usable.iter().map(|&(m, s)| (m / scale, s)).collect();
        reweighted(&points, top).map_or(NoiseFit::NONE, |fit| NoiseFit { scale, ..fit })
    }

    /// The smoothed variance at a level of mean `m` and own frame variance `s2` from
    /// `frames` frames, DN^2: the fit there, which has the noise of a variance of
    /// `(N - 1) / h` degrees of freedom (`h` the level's leverage), scaled by `d / (d - 2)`,
    /// the mean of `1 / X` for such an estimate `X` (the dark level, about on its own, by
    /// `(N - 1) / (N - 3)` as a raw variance is; the bright levels by 1.01-1.03 at 8
    /// frames: so `E[true / smoothed]` is 1 within 1% above the two darkest levels, within
    /// 4% at them). A level whose `m` or `s2` is not finite keeps its `s2`; one where there
    /// is no fit or the fit is not positive, its `s2` scaled by `(N - 1) / (N - 3)`.
    pub fn variance(&self, m: f64, s2: f64, frames: u32) -> f64 {
        if !(m.is_finite() && s2.is_finite() && s2 >= 0.0) {
            return s2;
        }
        let dof = f64::from(frames.max(1) - 1);
        // (Without a fit the scale is NaN, and so is the fit.)
        let u = m / self.scale;
        let f = self.at(u);
        // (Not positive, or NaN.)
        if f.is_nan() || f <= 0.0 {
            return s2 * inverse_mean(dof);
        }
        // The weight at the level is `1 / f^2`.
        let h = self.quad(u) / (f * f);
        f * inverse_mean(dof / h.clamp(1e-9, 1.0))
    }

    /// The fit at `u`, DN^2.
    fn at(&self, u: f64) -> f64 {
        let [a, b, c] = self.coef;
        a + u * (b + u * c)
    }

    /// `[1 u u^2] inv [1 u u^2]^T`: the fit's variance at `u` over the weight there.
    fn quad(&self, u: f64) -> f64 {
        let [i00, i01, i02, i11, i12, i22] = self.inv;
        i00 + u * (2.0 * i01 + u * (2.0 * i02 + i11 + u * (2.0 * i12 + u * i22)))
    }
}

impl super::records::Record for NoiseFit {
    const BYTES: usize = 80;
    const LOST: NoiseFit = NoiseFit::NONE;
    fn put(&self, out: &mut super::records::Put<'_>) {
        std::iter::once(self.scale).chain(self.coef).chain(self.inv).for_each(|v| out.f64(v));
    }
    fn take(from: &mut super::records::Take<'_>) -> NoiseFit {
        let scale = from.f64();
        let coef = [(); 3].map(|_| from.f64());
        let inv = [(); 6].map(|_| from.f64());
        NoiseFit { scale, coef, inv }
    }
}

/// The reweighted fit through the `points` `(u, s2)` (`top` the largest `s2`), in the
/// units of `u` (`scale` 1); `None` where it is singular or not finite.
fn reweighted(points: &[(f64, f64)], top: f64) -> Option<NoiseFit> {
    // The normal matrix of weights `1 / v^2` from the weighted power sums of `u`,
    // inverted, and the coefficients.
    let solve = |v: &[f64]| {
        let (mut p, mut r) = ([0.0; 5], [0.0; 3]);
        for (&(u, s), &v) in points.iter().zip(v) {
            let w = 1.0 / (v * v);
            let (u2, u3) = (u * u, u * u * u);
            p[0] += w;
            p[1] += w * u;
            p[2] += w * u2;
            p[3] += w * u3;
            p[4] += w * u2 * u2;
            r[0] += w * s;
            r[1] += w * s * u;
            r[2] += w * s * u2;
        }
        let inv = nalgebra::Matrix3::new(p[0], p[1], p[2], p[1], p[2], p[3], p[2], p[3], p[4]).try_inverse()?;
        let c = inv * nalgebra::Vector3::from(r);
        Some(NoiseFit { scale: 1.0, coef: [c[0], c[1], c[2]], inv: [inv[(0, 0)], inv[(0, 1)], inv[(0, 2)], inv[(1, 1)], inv[(1, 2)], inv[(2, 2)]] })
    };
    // (A variance of 0 is weighed as 1e-3 of the largest. A floor at a tenth of the
    // unweighted fit left the dark level's `E[true / smoothed]` at 1.38.)
    let mut v: Vec<f64> = points.iter().map(|(_, s)| s.max(1e-3 * top)).collect();
    let mut coef = [0.0; 3];
    for _ in 0..ITERATIONS {
        let fit = solve(&v)?;
        coef = fit.coef;
        if !points.iter().all(|&(u, _)| fit.at(u).is_finite()) {
            return None;
        }
        // (A level where the fit is not positive keeps its weight.)
        v.iter_mut().zip(points).map(|(v, &(u, _))| (v, fit.at(u))).filter(|(_, f)| *f > 0.0).for_each(|(v, f)| *v = f);
    }
    // The inverse under the final weights, for each level's leverage.
    Some(NoiseFit { coef, ..solve(&v)? })
}

/// `d / (d - 2)`: the mean of `1 / X` for `X` a variance estimate of `d` degrees of
/// freedom, relative (1 at `d <= 2`, where it has none).
fn inverse_mean(d: f64) -> f64 {
    if d > 2.0 { d / (d - 2.0) } else { 1.0 }
}

/// Reweighting passes of the fit (6: the fits of drawn photon transfers stopped
/// changing after 4 or 5).
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

    /// A fit reads back from its 80 bytes bit for bit, and so does no fit.
    #[test]
    fn a_kept_fit_reads_back_as_written() {
        let m: Vec<f64> = (0..10).map(|l| 60.0 + 400.0 * f64::from(l)).collect();
        let s2: Vec<f64> = m.iter().enumerate().map(|(l, m)| 4.0 + m / 2.5 * if l % 2 == 0 { 0.9 } else { 1.1 }).collect();
        for fit in [NoiseFit::new(&m, &s2), NoiseFit::NONE] {
            let back = super::super::records::round_trip(fit);
            let bits = |f: NoiseFit| (f.scale.to_bits(), f.coef.map(f64::to_bits), f.inv.map(f64::to_bits));
            assert_eq!(bits(back), bits(fit));
        }
        assert!(NoiseFit::new(&m, &s2).scale == 3660.0 && NoiseFit::NONE.variance(60.0, 2.0, 8) == 2.0 * 7.0 / 5.0);
    }
}
