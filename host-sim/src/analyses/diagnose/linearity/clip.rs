//! A black level clipped at code 0 (`black-level-clipped`): a camera that subtracts its
//! own black level (most consumer cameras' raw files, some scientific cameras' "offset
//! 0" modes) and clips what falls below. Its darkest levels' frames pile up at code 0:
//! their means are raised and their spread lowered, which the fits read as a bend at low
//! signal (`low-signal-nonlinearity`), an offset of a few DN and, where the channels or
//! ADCs differ in noise, an ADC's curvature.
//!
//! A pixel's frames at a level, Gaussian with mean `mu` and deviation `sigma` before the
//! clip, read `max(round X, 0)`: the analog values below -1/2 become code 0 through the
//! clip. It raises their mean by `E[-X; X < -1/2] = sigma phi(t) - mu Phi(-t)`,
//! `t = (mu + 1/2) / sigma` (0.2% of `sigma` at `t = 2.5`, 8% at `t = 1`, plus
//! `Phi(-t) / 2`). The measured mean and deviation are themselves clipped (the mean
//! raised, the deviation lowered), so each pixel's `(mu, sigma)` is first recovered from
//! them by inverting the censored normal's moments ([`unclipped`]). A level is clipped
//! where its pixels' biases, each in its mean's noise `s / sqrt(N)`, sum to more than 3
//! standard errors of the level's mean (`sum b / sqrt(n)`): what the level term would see
//! (a per-pixel count missed a bias of 0.2 of each pixel's noise, 13 standard errors of a
//! 64 x 64 level). Not clipped: a level where more than 1% of the pixels read below 0
//! (signed data, a dark already subtracted: a clipped camera never reads below 0), and
//! pixels that do not rise with the light (dead ones at code 0) are left out. Named where
//! the dimmest level is clipped. The clipped levels, where they are the first in the file,
//! are left out of every fit, and the set is diagnosed from the first level that is not,
//! as a set without a dark level (the offset from the response's intercept,
//! [`super::camera`]).

use statrs::function::erf::erfc;

use super::super::cubes::SetView;
use super::*;

/// A level is clipped where the clip raises its mean by more than this many standard
/// errors (its pixels' biases in their noise, summed over the square root of their
/// number).
const LEVEL_Z: f64 = 3.0;

/// The fraction of a level's pixels below 0 that makes it signed data, not clipped.
const SIGNED: f64 = 0.01;

/// What the clip did to a set: which levels, by how much.
#[derive(Debug, Clone)]
pub(super) struct Clip {
    /// Per level of the view: the clip's estimated bias of the level's mean, in its
    /// standard errors (0 where the level is signed data).
    pub z: Vec<f64>,
    /// The clipped levels that come first in the file (to be left out).
    pub leading: usize,
    /// The dimmest level (by reference).
    pub dimmest: usize,
    /// Its median mean and frame deviation as read, DN.
    pub read: (f64, f64),
    /// Its pixels' median mean and deviation before the clip, DN ([`unclipped`]).
    pub before: (f64, f64),
    /// Its median pixel's fraction of frames at code 0 through the clip.
    pub at_zero: f64,
    /// Its median pixel's bias, DN.
    pub bias_dn: f64,
    /// The median mean of the brightest clipped level as read, DN.
    pub highest_mean: f64,
}

/// `Phi(x)`, the standard normal's distribution function.
fn cdf(x: f64) -> f64 {
    0.5 * erfc(-x / std::f64::consts::SQRT_2)
}

/// `phi(x)`, the standard normal's density.
fn pdf(x: f64) -> f64 {
    (-0.5 * x * x).exp() / (2.0 * std::f64::consts::PI).sqrt()
}

/// The mean and variance of `max(Y, 0)`, `Y ~ N(t, 1)`.
fn censored_moments(t: f64) -> (f64, f64) {
    let (c, d) = (cdf(t), pdf(t));
    let m = t * c + d;
    (m, ((t * t + 1.0) * c + t * d - m * m).max(0.0))
}

/// A pixel's frames before the clip at a level where they read mean `m` and deviation
/// `s` (DN): `(mu, sigma, p0)`, the analog mean and deviation and the fraction of frames
/// at code 0 through the clip. The codes taken as `max(X, 0)` (the rounding left out),
/// `m / s` fixes `t = mu / sigma` (it rises with `t`: bisection) and `m` then `sigma`.
/// Against frames drawn, rounded and clipped (`tests`), the bias [`bias_dn`] gives at
/// the recovered values is within 11% of the true one at `sigma = 2` DN with less than
/// half the frames clipped, and up to twice it at `sigma = 1` with most of them clipped
/// (the rounding, which the model leaves out): too large, never too small, so a level is
/// left out a little early. (Modelling the rounding's half code and the indicator's
/// variance instead gave a second solution near no clip at all, which an iteration found
/// from 0.) `None` where `s` is not positive or a value is not finite.
pub(super) fn unclipped(m: f64, s: f64) -> Option<(f64, f64, f64)> {
    if !(m.is_finite() && s.is_finite() && s > 0.0) {
        return None;
    }
    let ratio = |t: f64| {
        let (mean, var) = censored_moments(t);
        mean / var.sqrt().max(1e-300)
    };
    let r = m / s;
    let t = if r >= ratio(30.0) {
        r
    } else if r <= ratio(-8.0) {
        -8.0
    } else {
        let (mut lo, mut hi) = (-8.0, 30.0);
        for _ in 0..80 {
            let mid = 0.5 * (lo + hi);
            if ratio(mid) < r {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        0.5 * (lo + hi)
    };
    let sigma = m.max(0.0) / censored_moments(t).0.max(1e-300);
    let mu = t * sigma;
    Some((mu, sigma, cdf(-(mu + 0.5) / sigma.max(1e-300))))
}

/// The clip's bias of a mean, DN, of frames `N(mu, sigma^2)` read `max(round X, 0)`:
/// `sigma phi(t) - mu Phi(-t)`, `t = (mu + 1/2) / sigma`.
pub(super) fn bias_dn(mu: f64, sigma: f64) -> f64 {
    let t = (mu + 0.5) / sigma;
    sigma * pdf(t) - mu * cdf(-t)
}

/// Fixed-point units of the biases' sums (`2^-40`): summed as integers, the same in any
/// order of blocks and threads (a float sum over blocks differed in its last digits
/// between a set held and the same set read by rows).
const FIXED: f64 = (1u64 << 40) as f64;

/// The clip of `set`, where its dimmest level is clipped; `None` where it is not.
pub(super) fn clip_of<T: Sample>(set: &SetView<'_, T>) -> Option<Clip> {
    let (nl, w, np) = (set.levels, set.width, set.frame());
    if nl == 0 {
        return None;
    }
    let nf = f64::from(set.n_frames.max(2));
    let known_bad = |p: usize| set.mask.is_some_and(|m| m[p] != 0);
    let by_voltage = |a: &usize, b: &usize| set.voltage[*a].total_cmp(&set.voltage[*b]);
    let dimmest = (0..nl).min_by(by_voltage)?;
    let brightest = (0..nl).max_by(by_voltage)?;
    // (A pixel that does not rise with the light, dead at code 0, says nothing of the
    // clip.)
    let counts = |p: usize, at: &super::super::cubes::Levels<'_, T>| !known_bad(p) && at.mean(brightest) - at.mean(dimmest) > 1.0;
    // A pixel's bias at a level, in its mean's noise, with its recovered frames.
    let bias_of = |m: f64, s: f64| unclipped(m, s).map(|(mu, sigma, p0)| (mu, sigma, p0, bias_dn(mu, sigma)));
    // Per block and level: the pixels counted, those below 0, the sum of their biases in
    // their noise (fixed point).
    let parts = set.blocks(|b| {
        let (mut counted, mut negative, mut z) = (vec![0usize; nl], vec![0usize; nl], vec![0i128; nl]);
        for p in b.rows.start * w..b.rows.end * w {
            let at = b.pixel(p);
            if !counts(p, &at) {
                continue;
            }
            for l in 0..nl {
                let (m, s) = (at.mean(l), at.std(l));
                if !(m.is_finite() && s.is_finite()) {
                    continue;
                }
                counted[l] += 1;
                negative[l] += usize::from(m < 0.0);
                if let Some((_, _, _, bias)) = bias_of(m, s) {
                    let x = bias * nf.sqrt() / s;
                    if x.is_finite() {
                        z[l] += (x.clamp(-1e12, 1e12) * FIXED).round() as i128;
                    }
                }
            }
        }
        (counted, negative, z)
    });
    let counted: Vec<usize> = (0..nl).map(|l| parts.iter().map(|p| p.0[l]).sum()).collect();
    let signed = |l: usize| parts.iter().map(|p| p.1[l]).sum::<usize>() as f64 > SIGNED * counted[l] as f64;
    let z: Vec<f64> = (0..nl)
        .map(|l| if signed(l) || counted[l] == 0 { 0.0 } else { parts.iter().map(|p| p.2[l]).sum::<i128>() as f64 / FIXED / (counted[l] as f64).sqrt() })
        .collect();
    if z[dimmest].is_nan() || z[dimmest] <= LEVEL_Z {
        return None;
    }
    let leading = z.iter().take_while(|&&z| z > LEVEL_Z).count();
    let highest = (0..nl).filter(|&l| z[l] > LEVEL_Z).max_by(by_voltage).unwrap_or(dimmest);
    // The medians over the pixels counted: the dimmest level's mean and deviation as
    // read, before the clip, its frames at code 0 and its bias in DN; the brightest
    // clipped level's mean.
    let medians = crate::infra::select::upper_medians(np, 7, &|p, f| {
        set.with_pixel(p, |at| {
            if !counts(p, &at) {
                return;
            }
            let (m, s) = (at.mean(dimmest), at.std(dimmest));
            if let Some((mu, sigma, p0, bias)) = bias_of(m, s) {
                [m, s, mu, sigma, p0, bias].iter().enumerate().for_each(|(k, &v)| f(k, v));
            }
            f(6, at.mean(highest));
        })
    });
    Some(Clip { z, leading, dimmest, read: (medians[0], medians[1]), before: (medians[2], medians[3]), at_zero: medians[4], bias_dn: medians[5], highest_mean: medians[6] })
}

impl Clip {
    /// The levels clipped, wherever they are in the file.
    pub fn clipped_levels(&self) -> usize {
        self.z.iter().filter(|&&z| z > LEVEL_Z).count()
    }

    /// The finding; `left_out` whether the leading clipped levels were left out of the
    /// diagnosis (else why not). Its significance is the clip's estimated bias of the
    /// dimmest level's mean in its standard errors (an estimate from each pixel's mean and
    /// deviation, not a test against a null: every pixel's bias is positive); its RMS
    /// before that of a unit noise with that bias shared by the level's pixels spread
    /// over them, after 1 (the levels left out).
    pub fn finding(&self, left_out: Result<(), &str>) -> Finding {
        let clipped_levels = self.clipped_levels();
        let what = match left_out {
            Ok(()) => format!(
                "{} (to {:.1} DN) {} left out of every fit and the rest diagnosed as a set without a dark level, its level 0 the file's level {} (level numbers below count from there)",
                if self.leading == 1 { "the lowest level".to_string() } else { format!("the {} lowest levels", self.leading) },
                self.highest_mean,
                if self.leading == 1 { "is" } else { "are" },
                self.leading
            ),
            Err(why) => format!("they are not left out ({why}): a bend at low signal, an offset or an ADC's curvature named below may be the clip's"),
        };
        let z = self.z[self.dimmest];
        finding(
            Effect::BlackLevelClipped,
            None,
            z,
            (1.0 + z * z / self.z.len().max(1) as f64).sqrt(),
            1.0,
            format!(
                "level {} (the dimmest) reads {:.2} DN (median) with frames {:.2} DN apart, where a Gaussian clipped at code 0 gives those from {:.2} DN and {:.2} DN: the median pixel has {:.0}% of its frames at code 0, so the camera subtracted its black level and clipped what fell below; each pixel's mean is raised by {:.3} DN (median), {:.0} standard errors of the level's mean; {} level{} clipped in all; {what}",
                self.dimmest,
                self.read.0,
                self.read.1,
                self.before.0,
                self.before.1,
                100.0 * self.at_zero,
                self.bias_dn,
                z,
                clipped_levels,
                if clipped_levels == 1 { "" } else { "s" },
            ),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{rngs::StdRng, SeedableRng};
    use rand_distr::{Distribution, Normal};

    /// Frames `N(mu, sigma^2)` read as the camera reads them (`max(round X, 0)`), many of
    /// them: their mean less `mu` is [`bias_dn`]'s (within 9% at 1 DN of noise: the
    /// rounding below -1/2 is left out; 21% at 0.7 DN), and [`bias_dn`] at what [`unclipped`] recovers from their mean and
    /// deviation is within 0.9-2.1 times the true bias (at most 0.01 DN where there is
    /// none), from fully clipped to not at all.
    #[test]
    fn the_clip_of_rounded_frames_is_recovered() {
        let mut rng = StdRng::seed_from_u64(58);
        let n = 400_000;
        for (mu, sigma) in [(-1.0, 1.0), (0.0, 1.0), (1.0, 1.0), (0.0, 2.0), (1.5, 2.0), (3.0, 2.0), (10.0, 2.0), (-3.0, 2.0), (-2.0, 1.0), (-1.0, 3.0)] {
            let g = Normal::<f64>::new(mu, sigma).unwrap();
            let codes: Vec<f64> = (0..n).map(|_| g.sample(&mut rng).round().max(0.0)).collect();
            let m = codes.iter().sum::<f64>() / n as f64;
            let s = (codes.iter().map(|c| (c - m).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt();
            let (want, got) = (m - mu, bias_dn(mu, sigma));
            assert!((got - want).abs() < 0.01 + 0.09 * want + 4.0 * s / (n as f64).sqrt(), "mu {mu}, sigma {sigma}: bias {got} against {want}");
            let (mu_hat, sigma_hat, p0) = unclipped(m, s).unwrap();
            let est = bias_dn(mu_hat, sigma_hat);
            if want > 0.05 {
                assert!((0.9..2.1).contains(&(est / want)), "mu {mu}, sigma {sigma}: ({mu_hat}, {sigma_hat}) give {est} for {want}");
            } else {
                assert!(est < 0.01 + want, "mu {mu}, sigma {sigma}: ({mu_hat}, {sigma_hat}) give {est} for {want}");
            }
            assert!((0.0..=1.0).contains(&p0));
        }
        assert_eq!(unclipped(0.0, 0.0), None);
        assert_eq!(unclipped(f64::NAN, 1.0), None);
    }
}
