//! What the extended model leaves: a noise scaled by one factor everywhere
//! (`excess-noise`: frames that are not independent) or structure (`unexplained`, with
//! the worst levels and the RMS by ADC).

use crate::analyses::diagnose::pixel_fit::Totals;
use super::scoring::Scoring;
use crate::analyses::diagnose::scores::{Cell, Scores};
use crate::analyses::diagnose::{AdcResiduals, Effect, Finding, SIGNIFICANCE};
use super::{finding, with_residuals};
use crate::formats::fits::Sample;

/// The finding for what `current` (the accepted model's held-out scores of the good
/// pixels, totals `tcur`) leaves, if anything stands out, beyond `extra`: the mean `z^2`
/// per held-out residual of a term found that no model can attribute (the light's
/// pattern's part that looks like each pixel's own curve, [`super::illumination`]).
pub(super) fn remainder<T: Sample>(s: &Scoring<'_, T>, current: &Scores, tcur: Totals, extra: f64) -> Option<Finding> {
    let (px, common, good, n_adc, nl) = (s.px, s.common, &s.good, s.n_adc, s.levels);
    let all = |_: Cell| true;
    let mut out = None;
    // The noise model off by one factor everywhere (frames that are not independent) is
    // not structure: the factor is measured on the pixels of even rows and the odd rows
    // scored with it; only what that leaves is `unexplained`.
    // (A known structure of mean square `extra` adds it to each residual's expectation
    // and `4 extra` to the variance of its square.)
    let widen = |t: Totals| Totals { e: t.e + extra * t.n as f64, v: t.v + 4.0 * extra * t.n as f64, ..t };
    let tcur = widen(tcur);
    let (te, to) = (widen(current.totals(&|c| !c.odd)), widen(current.totals(&|c| c.odd)));
    let k2 = te.s / te.e.max(1e-300);
    // The factor's own noise (the even rows are as many as the odd ones) is in the
    // denominator: without it the null spread was 1.4, not 1.
    let rescaled = (to.s - k2 * to.e) / (k2 * (to.v + (to.e / te.e.max(1e-300)).powi(2) * te.v).sqrt()).max(1e-300);
    // And alike at every pixel: under a scaled noise each odd-row pixel's held-out sum
    // `S_p` scatters about `k^2 tr C_p` by `k^2 sqrt(2 tr C_p^2)`; structure confined to
    // some pixels (subtle bad pixels) overdisperses it. `(X - G) / sqrt(c G)` over the
    // `G` pixels, `c = 2 + 12 / n` the variance of one term for `n` held-out levels.
    let (mut x_sum, mut g, mut n_sum) = (0.0, 0.0, 0.0);
    for (s, _) in current.iter().zip(good.iter()).filter(|&(_, i)| !px.estimating(i as usize)) {
        if let Some(s) = s {
            let n = f64::from(s.n);
            let (tr, tr2) = (f64::from(s.tr) + extra * n, f64::from(s.tr2) + 2.0 * extra * n);
            x_sum += (s.sum_sq - k2 * tr).powi(2) / (k2 * k2 * 2.0 * tr2).max(1e-300);
            g += 1.0;
            n_sum += f64::from(s.n);
        }
    }
    let dispersion = if g > 0.0 { (x_sum - g) / ((2.0 + 12.0 * g / n_sum.max(1.0)) * g).sqrt() } else { 0.0 };
    let noise_only = tcur.excess() > SIGNIFICANCE && k2 > 1.0 && rescaled <= SIGNIFICANCE && dispersion <= SIGNIFICANCE;
    if noise_only {
        let rms = current.by_level(&all);
        let scaled = rms.iter().map(|&(l, r)| (l, r / k2.sqrt())).collect();
        let f = with_residuals(AdcResiduals { baseline: rms, extended: scaled }, finding(
            Effect::ExcessNoise,
            None,
            tcur.excess(),
            to.rms(),
            to.rms() / k2.sqrt(),
            format!(
                "the means scatter {:.3} times more than the frames' standard deviations say ({:+.1}% of variance), alike at every level and pixel: frames that are not independent (drift or 1/f noise within a level); measured on even rows, odd rows then {rescaled:.1} standard deviations from their null",
                k2.sqrt(),
                100.0 * (k2 - 1.0)
            ),
        ));
        // (The residuals stay as they are: the noise they are divided by is what changes,
        // by a factor measured on half of them. No all-data value.)
        out = Some(f);
    }
    if tcur.excess() > SIGNIFICANCE && !noise_only {
        out = Some(finding(
            Effect::Unexplained,
            None,
            tcur.excess(),
            tcur.rms(),
            tcur.rms(),
            {
                // Where: the levels with the largest mean z^2 over pixels (and their mean
                // DN over the pixels scored there: every held-out point has its z), and
                // per ADC.
                let mut dn = vec![(0.0, 0usize); nl];
                for (s, i) in current.iter().zip(good.iter()) {
                    let i = i as usize;
                    if s.is_some() {
                        for q in px.halves(i, common).1 {
                            dn[q.level].0 += px.mean(q.level, i);
                            dn[q.level].1 += 1;
                        }
                    }
                }
                let mut levels: Vec<(usize, f64, f64)> = current.by_level(&all).into_iter().map(|(l, rms)| (l, rms * rms, dn[l].0 / dn[l].1.max(1) as f64)).collect();
                levels.sort_by(|a, b| b.1.total_cmp(&a.1));
                let worst: Vec<String> = levels.iter().take(3).map(|(l, m, dn)| format!("level {l} ({dn:.0} DN): mean z^2 {m:.2}")).collect();
                let per_adc: Vec<String> = (0..n_adc).map(|a| format!("{:.3}", current.totals(&|c| c.adc == a).rms())).collect();
                format!(
                    "held-out levels still scatter {:.3} times their noise (null {:.3}) under the extended model; not a noise scaled alike everywhere (odd rows {rescaled:.1} standard deviations beyond the even rows' factor {:.3}, pixel-to-pixel dispersion {dispersion:.1}); worst {}; RMS by ADC {}",
                    tcur.rms(),
                    (tcur.e / tcur.n.max(1) as f64).sqrt(),
                    k2.sqrt(),
                    worst.join(", "),
                    per_adc.join(" / ")
                )
            },
        ));
    }
    out
}
