//! A black level clipped at code 0 (`black-level-clipped`): a camera that subtracts its
//! own black level (most consumer cameras' raw files, some scientific cameras' "offset
//! 0" modes) and clips what falls below. Its darkest levels' frames pile up at code 0:
//! their means are raised and their spread lowered, which the fits read as a bend at low
//! signal (`low-signal-nonlinearity`), an offset of a few DN and, where the channels or
//! ADCs differ in noise, an ADC's curvature.
//!
//! A pixel's frames at a level, Gaussian with mean `mu` and deviation `sigma` before the
//! clip, read `max(X, 0)` (to within the code's rounding: analog values below -1/2
//! become code 0 only through the clip). The clip raises their mean by
//! `sigma (phi(z) - z Phi(-z))`, `z = (mu + 1/2) / sigma`: 0.2% of `sigma` at `z = 2.5`,
//! 8% at `z = 1`. A pixel is clipped at a level where that bias, taken at its measured
//! mean and deviation (both already clipped: the bias is then understated), exceeds a
//! quarter of its mean's noise `sigma / sqrt(N)`; a level is clipped where more than 1%
//! of the pixels are. The clipped levels that come first in the file are left out of
//! every fit, and the set is diagnosed from the first level that is not, as a set without
//! a dark level (the offset from the response's intercept, [`super::camera`]).

use statrs::function::erf::erfc;

use super::super::cubes::SetView;
use super::*;

/// The fraction of a level's pixels whose clip bias must exceed a quarter of their
/// mean's noise for the level to be clipped.
const CLIPPED_PIXELS: f64 = 0.01;

/// The clip bias of a pixel's mean must exceed this many of its mean's noise.
const BIAS_NOISE: f64 = 0.25;

/// What the clip did to a set: which levels, by how much.
#[derive(Debug, Clone)]
pub(super) struct Clip {
    /// Per level of the view: the fraction of the pixels clipped.
    pub fraction: Vec<f64>,
    /// The clipped levels that come first in the file (to be left out).
    pub leading: usize,
    /// Level 0's median mean, DN.
    pub level0_mean: f64,
    /// Level 0's median frame deviation, DN.
    pub level0_sd: f64,
    /// Level 0's median clip bias, in units of its mean's noise.
    pub level0_bias: f64,
    /// The clip's bias of level 0's mean over all its pixels, in units of that mean's
    /// noise: the sum of each pixel's bias in its noise over the square root of their
    /// number (the finding's significance).
    pub level0_z: f64,
    /// The mean fraction of level 0's frames at code 0 (from the Gaussian).
    pub level0_at_zero: f64,
    /// The median mean of the brightest clipped level, DN.
    pub highest_mean: f64,
}

/// `Phi(x)`, the standard normal's distribution function.
fn cdf(x: f64) -> f64 {
    0.5 * erfc(-x / std::f64::consts::SQRT_2)
}

/// The clip's bias of a mean, in units of the frames' deviation, at `z = (mu + 1/2) /
/// sigma`: `phi(z) - z Phi(-z)`.
pub(super) fn bias_over_sigma(z: f64) -> f64 {
    (-0.5 * z * z).exp() / (2.0 * std::f64::consts::PI).sqrt() - z * cdf(-z)
}

/// Whether a pixel whose `n_frames` frames average `m` DN with deviation `s` DN is
/// clipped (its mean raised by more than [`BIAS_NOISE`] of its noise), and that bias in
/// units of the noise. A pixel whose frames all sit at code 0 is clipped.
fn clipped(m: f64, s: f64, n_frames: f64) -> Option<(bool, f64)> {
    if !(m.is_finite() && s.is_finite()) {
        return None;
    }
    if s <= 0.0 {
        // (Its bias is at least that of a pixel whose mean sits at the clip, `z = 0`.)
        return Some((m < 0.5, if m < 0.5 { bias_over_sigma(0.0) * n_frames.sqrt() } else { 0.0 }));
    }
    let b = bias_over_sigma((m + 0.5) / s) * n_frames.sqrt();
    Some((b > BIAS_NOISE, b))
}

/// The clip of `set`, where its level 0 is clipped; `None` where it is not.
pub(super) fn clip_of<T: Sample>(set: &SetView<'_, T>) -> Option<Clip> {
    let (nl, w) = (set.levels, set.width);
    let nf = f64::from(set.n_frames.max(2));
    let known_bad = |p: usize| set.mask.is_some_and(|m| m[p] != 0);
    // Per block: per level the pixels counted and clipped; level 0's means, deviations,
    // biases and frames at zero; every level's means of clipped pixels.
    struct Part {
        counted: Vec<usize>,
        clipped: Vec<usize>,
        level0: Vec<[f64; 4]>,
        means: Vec<Vec<f64>>,
    }
    let parts = set.blocks(|b| {
        let mut part = Part { counted: vec![0; nl], clipped: vec![0; nl], level0: Vec::new(), means: vec![Vec::new(); nl] };
        for p in b.rows.start * w..b.rows.end * w {
            if known_bad(p) {
                continue;
            }
            let at = b.pixel(p);
            for l in 0..nl {
                let (m, s) = (at.mean(l), at.std(l));
                let Some((is, bias)) = clipped(m, s, nf) else { continue };
                part.counted[l] += 1;
                if is {
                    part.clipped[l] += 1;
                }
                part.means[l].push(m);
                if l == 0 {
                    let at_zero = if s > 0.0 { cdf(-(m + 0.5) / s) } else { f64::from(u8::from(m < 0.5)) };
                    part.level0.push([m, s, bias, at_zero]);
                }
            }
        }
        part
    });
    let counted: Vec<usize> = (0..nl).map(|l| parts.iter().map(|p| p.counted[l]).sum()).collect();
    let fraction: Vec<f64> = (0..nl).map(|l| parts.iter().map(|p| p.clipped[l]).sum::<usize>() as f64 / counted[l].max(1) as f64).collect();
    if fraction.first().is_none_or(|&f| f <= CLIPPED_PIXELS) {
        return None;
    }
    let leading = fraction.iter().take_while(|&&f| f > CLIPPED_PIXELS).count();
    let level0: Vec<[f64; 4]> = parts.iter().flat_map(|p| p.level0.iter().copied()).collect();
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
    };
    let of0 = |k: usize| median(level0.iter().map(|r| r[k]).collect());
    let at_zero = level0.iter().map(|r| r[3]).sum::<f64>() / level0.len().max(1) as f64;
    let highest = (0..nl).filter(|&l| fraction[l] > CLIPPED_PIXELS).max_by(|&a, &b| set.voltage[a].total_cmp(&set.voltage[b])).unwrap_or(0);
    let highest_mean = median(parts.iter().flat_map(|p| p.means[highest].iter().copied()).collect());
    let level0_z = level0.iter().map(|r| r[2]).sum::<f64>() / (level0.len().max(1) as f64).sqrt();
    Some(Clip { fraction, leading, level0_mean: of0(0), level0_sd: of0(1), level0_bias: of0(2), level0_z, level0_at_zero: at_zero, highest_mean })
}

impl Clip {
    /// The levels clipped, wherever they are in the file.
    pub fn clipped_levels(&self) -> usize {
        self.fraction.iter().filter(|&&f| f > CLIPPED_PIXELS).count()
    }

    /// The finding; `left_out` whether the leading clipped levels were left out of the
    /// diagnosis (else why not). Its significance is level 0's bias over all its pixels
    /// in its noise ([`Clip::level0_z`]); its RMS before that of a unit noise with level
    /// 0's median bias on it, after 1 (the levels left out).
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
        let before = (1.0 + self.level0_bias.powi(2)).sqrt();
        finding(
            Effect::BlackLevelClipped,
            None,
            self.level0_z,
            before,
            1.0,
            format!(
                "level 0 reads {:.2} DN (median) with frames {:.2} DN apart: about {:.0}% of its frames sit at code 0, so the camera subtracted its black level and clipped what fell below; {:.0}% of level 0's pixels have means raised by more than a quarter of their noise (median {:.2} times it; over all its pixels, {:.0} standard errors of the level's mean), {} level{} clipped in all; {what}",
                self.level0_mean,
                self.level0_sd,
                100.0 * self.level0_at_zero,
                100.0 * self.fraction[0],
                self.level0_bias,
                self.level0_z,
                clipped_levels,
                if clipped_levels == 1 { "" } else { "s" },
            ),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The clip's bias against a direct sum over a fine grid of the clipped Gaussian
    /// (`E[max(X, -1/2)] + 1/2 - (mu + 1/2)` with `X ~ N(mu, 1)`, i.e. `E[max(Y, 0)] - mu'`
    /// for `Y = X + 1/2`).
    #[test]
    fn the_bias_is_the_clipped_gaussians() {
        for z in [-1.0, 0.0, 0.5, 1.0, 2.0, 2.5, 4.0] {
            let (n, lo, hi) = (400_000, z - 12.0, z + 12.0);
            let dx = (hi - lo) / n as f64;
            let mean: f64 = (0..n)
                .map(|i| {
                    let y = lo + (i as f64 + 0.5) * dx;
                    y.max(0.0) * (-0.5 * (y - z) * (y - z)).exp() / (2.0 * std::f64::consts::PI).sqrt() * dx
                })
                .sum();
            let want = mean - z;
            assert!((bias_over_sigma(z) - want).abs() < 1e-8, "z {z}: {} against {want}", bias_over_sigma(z));
        }
        assert!(bias_over_sigma(2.5) < 0.0025 && bias_over_sigma(2.5) > 0.0015);
    }

    /// The rule: a pixel 0.75 sigma above -1/2 with 8 frames is clipped; one 4 sigma above
    /// is not; one at code 0 throughout is; non-finite values are not counted.
    #[test]
    fn a_pixel_is_clipped_where_its_bias_passes_a_quarter_of_its_noise() {
        assert!(clipped(1.0, 2.0, 8.0).unwrap().0);
        assert!(!clipped(7.5, 2.0, 8.0).unwrap().0);
        assert!(clipped(0.0, 0.0, 8.0).unwrap().0);
        assert!(!clipped(60.0, 0.0, 8.0).unwrap().0);
        assert!(clipped(f64::NAN, 1.0, 8.0).is_none());
        // (At 256 frames the same pixel at 2.5 sigma: bias 0.002 sigma, noise 0.0625
        // sigma: not clipped; at 1.5 sigma, 0.029 against 0.016: clipped.)
        assert!(!clipped(4.5, 2.0, 256.0).unwrap().0);
        assert!(clipped(2.5, 2.0, 256.0).unwrap().0);
    }
}
