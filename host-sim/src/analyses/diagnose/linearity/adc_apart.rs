//! Which ADCs differ from the others: the paired test over held-out pixels, the per-ADC
//! population of a per-pixel parameter, and the search that sets ADCs apart one at a time
//! (`adc-mismatch` of offset, gain or curvature).

use crate::analyses::diagnose::pixel_fit::{fit_and_score, Response};
use crate::analyses::diagnose::records::Records;
use super::scoring::Scoring;
use crate::analyses::diagnose::scores::{Cell, Scores};
use crate::analyses::diagnose::{AdcResiduals, Effect, Finding, SIGNIFICANCE};
use super::populations::population;
use super::{finding, with_residuals};
use crate::formats::fits::Sample;

/// The paired test of a shared-parameter step over independent held-out pixels:
/// `D_p` is a pixel's drop of held-out `z^2` from model A to B, and the significance is
/// `sum D / sqrt(n var D)`. Pixels are the independent units here: where pixels differ
/// beyond noise (their own curvature), the residuals of every pixel carry it and the
/// noise-only spread of `Totals` would call a chance difference between two shared curves
/// significant (it did, at 7.6 standard deviations, on a set with 1% pixel-to-pixel
/// nonlinearity and no shared bend).
///
/// Pixels are not independent where every pixel shares an error at a level (the light
/// off the reference, the black level off); that term enters every `D_p` alike and this
/// test cannot see it (a 2e-4 level error gave false `adc-mismatch` findings), so it is
/// measured and taken out first ([`super::levels`]).
pub(super) fn paired(a: &Scores, b: &Scores, sel: impl Fn(usize) -> bool) -> f64 {
    paired_sum(|| a.iter().zip(b.iter()).enumerate().filter(|(j, _)| sel(*j)).filter_map(|(_, (a, b))| Some(a?.sum_sq - b?.sum_sq)))
}

/// `sum d / sqrt(n var d)` of the paired differences `d()` gives (the same on every call:
/// counted and summed, then summed about their mean, in their order; none held).
pub(super) fn paired_sum<I: Iterator<Item = f64>>(d: impl Fn() -> I) -> f64 {
    let mut count = 0usize;
    let sum = d().inspect(|_| count += 1).sum::<f64>();
    let n = count as f64;
    if n < 3.0 {
        return 0.0;
    }
    let mean = sum / n;
    let var = d().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    mean * n / (n * var).sqrt().max(1e-300)
}

/// Visits the value of item `j`: `f(adc, odd row, value)`.
pub(super) type Values<'a> = dyn Fn(usize, &mut dyn FnMut(usize, bool, f64)) + Sync + 'a;

/// The most ADCs a linearity set's diagnosis takes apart (several passes over the pixels
/// per ADC: a column-parallel sensor's thousands would multiply the run by thousands).
pub(super) const MAX_ADCS: usize = 256;

/// An ADC whose pixels sit apart from the others' ([`adcs_apart`]).
#[derive(Debug, Clone, Copy)]
pub(super) struct Apart {
    pub(super) adc: usize,
    pub(super) significance: f64,
    /// RMS of the odd-row pixels in units of the scatter, about the centre and about their
    /// own ADC's median.
    pub(super) before: f64,
    pub(super) after: f64,
    /// The median of the other ADCs' medians, this ADC's median and the pixel scatter
    /// about each pixel's own ADC median (1.4826 MAD), all from the even rows.
    pub(super) centre: f64,
    pub(super) median: f64,
    pub(super) scatter: f64,
}

/// The ADCs whose pixels' `values` (`(adc, odd row, value)`: each pixel's dark or gain)
/// sit apart from the others', set apart one at a time as for the curvature: the most
/// significant one, then the centre (the median of the other ADCs' medians) recomputed,
/// while a majority remains; at least three ADCs. Medians and scatter from the even rows,
/// scores on the odd rows. (The centre is the median of the medians of the ADCs not yet
/// set apart, the tested one included.)
///
/// The significance is the smaller of two: the paired test over the odd-row pixels
/// ([`paired_sum`] of their drop of `z^2` from the centre to their ADC's median), and the
/// offset against its own standard error (`1.2533 s sqrt(1/n_a + 1/n_rest)`: the
/// Gaussian median's noise over the even-row pixels, the centre's taken as one median
/// over the other ADCs' pixels, which understates it by 15-18%; a skewed spread's median
/// is noisier still). The paired statistic alone does not shrink with the
/// offset: with `d_p = (m_a - c)(2 v_p - c - m_a) / s^2` it is
/// `sqrt(n) ((m_a - c) + 2 (mean(v) - m_a)) / (2 sd(v))`, so a skewed spread (the odd rows'
/// mean off the even rows' median) passed it for any offset once `n` was large: on a
/// 2048 x 2048 set an ADC was set apart for +0.001 DN at 7 standard deviations.
pub(super) fn adcs_apart(n: usize, values: &Values, n_adc: usize) -> Vec<Apart> {
    let (per_adc, _, ps) = population(n, n_adc, &|j, f| values(j, &mut |a, odd, v| if !odd { f(a, v) }));
    let mut out = Vec::new();
    if n_adc < 3 || ps.is_nan() || ps <= 0.0 {
        return out;
    }
    // Per ADC: its even-row values counted, and its odd-row values' count, sum and sum of
    // squares about its own median (every score below is a function of these: one pass
    // over the pixels, whatever the number of ADCs and rounds).
    let (mut even_count, mut odd) = (vec![0usize; n_adc], vec![(0usize, 0.0, 0.0); n_adc]);
    for j in 0..n {
        values(j, &mut |a, is_odd, v| {
            if a < n_adc && v.is_finite() {
                if is_odd {
                    let d = v - per_adc[a];
                    odd[a] = (odd[a].0 + 1, odd[a].1 + d, odd[a].2 + d * d);
                } else {
                    even_count[a] += 1;
                }
            }
        });
    }
    let mut apart = vec![false; n_adc];
    while apart.iter().filter(|&&o| !o).count() * 2 > n_adc + 1 {
        // The textbook median of the finite medians (four ADCs: the mean of the middle two).
        let pm = crate::infra::stats::median((0..n_adc).filter(|&a| !apart[a]).map(|a| per_adc[a]));
        if pm.is_nan() {
            break;
        }
        let scored: Vec<(usize, f64, f64, f64, usize)> = (0..n_adc)
            .filter(|&a| !apart[a] && odd[a].0 >= 8)
            .map(|a| {
                // With `u = v - m_a` and `o = m_a - c`: `z1 = u / s`, `z0 = (u + o) / s`,
                // and `d = z0^2 - z1^2 = o (2 u + o) / s^2`, linear in `u`.
                let (n, su, suu) = (odd[a].0 as f64, odd[a].1, odd[a].2);
                let o = per_adc[a] - pm;
                let (s1, s0) = (suu / (ps * ps), (suu + 2.0 * o * su + n * o * o) / (ps * ps));
                let var_u = ((suu - su * su / n) / (n - 1.0)).max(0.0);
                let (mean_d, sd_d) = (o * (2.0 * su / n + o) / (ps * ps), 2.0 * o.abs() * var_u.sqrt() / (ps * ps));
                let pairs = if n < 3.0 { 0.0 } else { mean_d * n.sqrt() / sd_d.max(1e-300) };
                let n_rest: usize = (0..n_adc).filter(|&b| b != a && !apart[b]).map(|b| even_count[b]).sum();
                let se = 1.2533 * ps * (1.0 / even_count[a].max(1) as f64 + 1.0 / n_rest.max(1) as f64).sqrt();
                (a, pairs.min(o.abs() / se), s0, s1, odd[a].0)
            })
            .collect();
        // (An ADC without a finite score, e.g. no finite median on its even rows, is not
        // tested: NaN sorts above every number and would end the search for the others.)
        let Some(&(a, sig, s0, s1, n)) = scored.iter().filter(|x| x.1.is_finite()).max_by(|x, y| x.1.total_cmp(&y.1)) else { break };
        if !(sig > SIGNIFICANCE && s1 < s0) {
            break;
        }
        apart[a] = true;
        out.push(Apart { adc: a, significance: sig, before: (s0 / n as f64).sqrt(), after: (s1 / n as f64).sqrt(), centre: pm, median: per_adc[a], scatter: ps });
    }
    out
}

/// `adc-mismatch` of offset and gain: each `good` pixel's dark and gain under its own
/// response `curve_for` (all its levels), and the ADCs whose pixels sit apart
/// ([`adcs_apart`]), added to their findings in `adc_findings` (one per ADC) or made into
/// new ones.
pub(super) fn adc_maps<T: Sample>(s: &Scoring<'_, T>, curve_for: &(dyn Fn(usize) -> Response + Sync), adc_findings: &mut [Option<Finding>]) {
    let (px, common, fits, good) = (s.px, s.common, s.fits, &s.good);
    let n_adc = adc_findings.len();
    // Each good pixel's dark and gain (NaN where it has no fit: left out as every
    // non-finite value is), kept as records: the selections read them in passes.
    let dg = Records::from_fn(px.keep(), good.len(), |j| {
        let i = good.index(j);
        let all = px.all(i, common);
        let start = fits.at(i).line(0).map_or(vec![0.0; 2], |l| l.to_vec());
        // (The gain per colour channel: each against its own channel's population.)
        fit_and_score(curve_for(i), &start, &all, &[]).map_or([f64::NAN; 2], |s| [s.params[0], s.params[1] / px.response(i)])
    });
    for (k, what) in [(0usize, "offset"), (1, "gain")] {
        let values = |j: usize, f: &mut dyn FnMut(usize, bool, f64)| {
            let c = s.cell(j);
            f(c.adc, c.odd, dg.at(j)[k])
        };
        for Apart { adc: a, significance: sig, before: b, after: af, centre: pm, median, scatter: ps } in adcs_apart(good.len(), &values, n_adc) {
            let unit = if k == 0 { "DN" } else { "DN at full reference" };
            let part = format!("{what}: ADC {a}'s pixels sit {:+.3} {unit} ({:+.2}%) from the other ADCs' median (pixel scatter {:.3}), pixels of odd rows scored against even rows", median - pm, 100.0 * (median - pm) / pm.abs().max(1e-12), ps);
            match &mut adc_findings[a] {
                Some(f) => {
                    f.detail = format!("{}; {part}", f.detail);
                    if sig > f.significance {
                        (f.significance, f.rms_before, f.rms_after, f.gain) = (sig, b, af, b / af);
                    }
                }
                None => adc_findings[a] = Some(finding(Effect::AdcMismatch, Some(a), sig, b, af, part)),
            }
        }
    }
}

/// `S (c2 S + c3 S^2 + c4 S^3)`: how far the shared curve `c` bends at signal `s` (a
/// fraction of full scale), as a fraction of full scale.
pub(super) fn bend(c: [f64; 3], s: f64) -> f64 {
    s * (c[0] * s + c[1] * s * s + c[2] * s * s * s)
}

/// The consensus of the ADCs not set apart (`true`): its curve and held-out scores.
pub(super) type Consensus<'a> = dyn Fn(&[bool]) -> ([f64; 3], Scores) + 'a;

/// The outcome of [`adc_curvature`].
pub(super) struct Curvature {
    /// Per ADC: set apart under its own curve.
    pub adc_own: Vec<bool>,
    /// The ADCs set apart, in the order they were.
    pub apart: Vec<usize>,
    /// Per ADC: its `adc-mismatch` (curvature) finding, if set apart.
    pub adc_findings: Vec<Option<Finding>>,
    /// The consensus curve of the ADCs not set apart, and its held-out scores.
    pub global: [f64; 3],
    pub glob: Scores,
}

/// ADC curvature: each ADC's own curve (`adc_curves`, scored as `own_curve`) against the
/// consensus of the others, on its held-out pixels (so that one bending ADC is not
/// mistaken for a shared bend). The consensus (`consensus(set apart)`: the curve of all
/// ADCs not yet set apart, and its scores) starts from all ADCs (`first`); the most significant ADC
/// above threshold is set apart and the consensus refitted, until none is left or only a
/// majority remains. Without `own_curve` (fewer than three ADCs: with two, the data
/// cannot say which one differs) none is set apart.
pub(super) fn adc_curvature(adc_curves: &[[f64; 3]], own_curve: Option<&Scores>, cell: &dyn Fn(usize) -> Cell, first: ([f64; 3], Scores), consensus: &Consensus<'_>) -> Curvature {
    let n_adc = adc_curves.len();
    let mut adc_own = vec![false; n_adc];
    let mut apart = Vec::new();
    let mut adc_findings: Vec<Option<Finding>> = vec![None; n_adc];
    let (mut global, mut glob) = first;
    while let Some(own_curve) = own_curve.filter(|_| adc_own.iter().filter(|&&o| !o).count() * 2 > n_adc + 1) {
        let tested: Vec<(usize, f64)> = (0..n_adc).filter(|&a| !adc_own[a]).map(|a| (a, paired(&glob, own_curve, |j| cell(j) == Cell { adc: a, odd: true }))).collect();
        let Some(&(a, sig)) = tested.iter().filter(|x| x.1.is_finite()).max_by(|x, y| x.1.total_cmp(&y.1)) else { break };
        if sig <= SIGNIFICANCE {
            break;
        }
        let on = |c: Cell| c == Cell { adc: a, odd: true };
        let (ta, tb) = (glob.totals(&on), own_curve.totals(&on));
        adc_own[a] = true;
        apart.push(a);
        let steps = AdcResiduals { baseline: glob.by_level(&on), extended: own_curve.by_level(&on) };
        let detail = format!(
            "curvature: ADC {a}'s response bends by {:.3}% of full scale where the others' bends by {:.3}% (held-out levels of its pixels)",
            100.0 * bend(adc_curves[a], 1.0),
            100.0 * bend(global, 1.0)
        );
        adc_findings[a] = Some(with_residuals(steps, finding(Effect::AdcMismatch, Some(a), sig, ta.rms(), tb.rms(), detail)));
        (global, glob) = consensus(&adc_own);
    }
    Curvature { adc_own, apart, adc_findings, global, glob }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    /// Four ADCs of a million pixels each with one skewed spread (an exponential tail,
    /// the odd rows' mean 0.6 above the even rows' median): none is set apart, though the
    /// paired test alone passed 5 sigma at these counts for the chance offsets of the
    /// medians; an offset of 0.05 (about 17 of the gate's standard errors) planted in ADC
    /// 2 is set apart alone, with its size.
    #[test]
    fn a_skewed_spread_is_no_adc_offset_however_many_pixels() {
        use rand_distr::{Distribution, Exp};
        let mut rng = rand::rngs::StdRng::seed_from_u64(9);
        let exp = Exp::new(0.5).unwrap();
        let draw = |rng: &mut rand::rngs::StdRng, shift: f64| -> Vec<(usize, bool, f64)> {
            (0..4_000_000).map(|p: usize| (p % 4, (p / 4) % 2 == 1, 100.0 + exp.sample(rng) + if p % 4 == 2 { shift } else { 0.0 })).collect()
        };
        let apart = |v: &[(usize, bool, f64)], n_adc| adcs_apart(v.len(), &|j, f| f(v[j].0, v[j].1, v[j].2), n_adc);
        let none = apart(&draw(&mut rng, 0.0), 4);
        assert!(none.is_empty(), "{none:?}");
        let one = apart(&draw(&mut rng, 0.05), 4);
        assert_eq!(one.iter().map(|a| a.adc).collect::<Vec<_>>(), vec![2], "{one:?}");
        assert!((one[0].median - one[0].centre - 0.05).abs() < 0.015, "{one:?}");
        // A fifth ADC with no finite value: not tested, and not in the way of ADC 2.
        let mut five = draw(&mut rng, 0.05);
        five.extend((0..1000).map(|p| (4, p % 2 == 1, if p % 2 == 1 { 101.0 } else { f64::NAN })));
        let found = apart(&five, 5);
        assert_eq!(found.iter().map(|a| a.adc).collect::<Vec<_>>(), vec![2], "{found:?}");
    }
}
