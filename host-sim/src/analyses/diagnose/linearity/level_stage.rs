//! Errors every pixel shares at a level (`level-errors`, `low-signal-nonlinearity`, and
//! per ADC `adc-dnl`), measured first: found, they are taken out of every pixel's means
//! before any model of the response ([`crate::analyses::diagnose::levels`] measures the term).

use crate::analyses::diagnose::levels::{held_out_rms, level_term, wald, Block, LevelTerm, Series, Shape};
use crate::analyses::diagnose::points::Pixels;
use crate::analyses::diagnose::{Effect, Finding, SIGNIFICANCE};
use super::{finding, with_residuals};
use crate::formats::fits::Sample;

/// The level term to take out of every pixel's means, whether it was accepted (or a
/// departure at the lowest signals handled), and what it was named.
pub(super) struct LevelStage {
    pub(super) term: LevelTerm,
    pub(super) accepted: bool,
    pub(super) findings: Vec<Finding>,
    /// Where `level-errors` was named and its light part is two series that disagree,
    /// the step its finding gives ([`LevelTerm::series`]).
    pub(super) series: Option<Series>,
    /// Where `level-errors` was named: the relative rms of its light part, as its
    /// finding gives it.
    pub(super) light_rel: Option<f64>,
}

/// What a `level-errors` finding measured, for [`Measured`](crate::analyses::diagnose::Measured).
#[derive(Default)]
pub(super) struct Named {
    series: Option<Series>,
    light_rel: Option<f64>,
}

/// Measures and names the errors every pixel of `px` shares at its `nl` levels.
pub(super) fn level_stage<T: Sample>(px: &Pixels<T>, nl: usize) -> LevelStage {
    // Errors every pixel shares at a level (the light off the reference, the black level
    // off) first: found, they are taken out of every pixel's means before any model.
    let mut levels_term = level_term(px, &vec![false; nl]);
    let mut findings = Vec::new();
    let mut named = Named::default();
    let accepted = |t: &LevelTerm| {
        let (before, after) = held_out_rms(&t.by_level);
        t.significance > SIGNIFICANCE && after < before
    };
    // A departure every pixel shares at the lowest signals (a charge loss, an offset
    // between dark and light frames). A quartic over all levels spreads it over the
    // range: as a level term it left its quartic projection in every pixel (a curvature
    // that passed for `global-nonlinearity`), and beside level errors it passed for them
    // (a 10 DN charge loss beside 0.4 DN of black-level errors was `level-errors` only).
    // So where a common term is found, the levels below 10% of the top signal are tested
    // left out of the pixels' fits: alone, the departure is named by the term's shape,
    // beside level errors by a test of those levels with levels as the units against the
    // level errors measured above; named, the term there is what the others' quartics
    // leave.
    let top_signal = levels_term.signal.iter().copied().filter(|s| s.is_finite()).fold(0.0, f64::max);
    let below = |f: f64| -> Vec<bool> { levels_term.signal.iter().map(|&s| s.is_finite() && s < f * top_signal).collect() };
    let count = |v: &[bool]| v.iter().filter(|&&b| b).count();
    let (low, guard) = (below(0.1), below(0.2));
    let room = count(&low) >= 2 && nl - count(&low) >= 11;
    let smooth_or_low = matches!(levels_term.shape, Shape::Random | Shape::LowSignal { .. });
    if accepted(&levels_term) && levels_term.per_adc.is_none() && smooth_or_low && room {
        let skipped = level_term(px, &low);
        // (A term taken per ADC without its `adc-dnl` finding would hide the ADCs.)
        if skipped.per_adc.is_none() {
            let low_finding = if let Shape::LowSignal { .. } = levels_term.shape {
                Some(level_finding(&levels_term, &mut named))
            } else {
                let sig = wald(&skipped, px, &|_| true, Block::Levels(&low));
                let (before, after) = held_out_rms(&skipped.skipped_by_level);
                (sig > SIGNIFICANCE && after < before).then(|| {
                    let lows = count(&low);
                    with_residuals(skipped.skipped_by_level.clone(), finding(
                        Effect::LowSignalNonlinearity,
                        None,
                        sig,
                        before,
                        after,
                        format!("every pixel departs alike from the quartic through its other levels at the {lows} levels below 10% of the top signal (their common departure against the level errors measured above them, levels as the units): an offset between dark and light or a charge loss; taken out of every pixel's means there"),
                    ))
                })
            };
            // Where no departure is named the term over all the levels is taken out, and
            // named here; the levels below 10% are left out of the shared bend's test with
            // levels as the units (`skip`), which an unnamed departure there could pass. The
            // term the others' quartics leave there is extrapolated, and taken out through
            // each pixel's slope it left 2% light errors up to 2.2 times the noise at the
            // lowest level on 8 frames (issue 58); with the whole term in the bend's test
            // too, a 5 DN charge loss beside 0.4 DN black-level errors was a false
            // `global-nonlinearity` on 2 of 20 sets (an independent review's emulation
            // found it), 0 with those levels left out.
            match low_finding {
                None => {
                    findings.push(level_finding(&levels_term, &mut named));
                    levels_term.skip = low.clone();
                }
                Some(low_finding) => {
                    // Level errors beside a named departure are judged above 20% of the
                    // top signal, and the term is the one from there: a charge loss's tail
                    // reaches the first levels above 10%, and the quartic's ripple there
                    // made `level-errors` of 7-20 DN losses alone (and left a 10 DN loss
                    // a 5 sigma `global-nonlinearity`). With too few levels above 20%, or
                    // a term there taken per ADC, the one above 10% (at 13 levels a
                    // re-review found the whole test skipped).
                    let above = (count(&guard) > count(&low) && nl - count(&guard) >= 11).then(|| level_term(px, &guard));
                    let level_errors = above.filter(|t| t.per_adc.is_none()).unwrap_or(skipped);
                    let named_errors = (accepted(&level_errors) && level_errors.shape == Shape::Random).then(|| level_finding(&level_errors, &mut named));
                    let errors_found = named_errors.is_some();
                    findings.push(low_finding);
                    findings.extend(named_errors);
                    levels_term = level_errors;
                    // Where the levels above show no errors of their own, only the term below 20%
                    // of the top signal is taken out (the departure and its tail).
                    if !errors_found {
                        levels_term.keep_only(|l| guard[l]);
                    }
                }
            }
        }
    }
    let handled = levels_term.skip.iter().any(|&s| s);
    let level_accepted = accepted(&levels_term) || handled;
    // Where the ADCs' own terms differ, the error is (at least partly) the ADCs': their
    // integral nonlinearity at the codes their pixels read. Named per ADC, and the common
    // part is not called the light's (the ADCs' mean DN error is common too).
    for (a, &t) in levels_term.adc_significance.iter().enumerate().filter(|(_, t)| **t > SIGNIFICANCE) {
        let (before, after) = held_out_rms(&levels_term.adc_by_level[a]);
        findings.push(with_residuals(levels_term.adc_by_level[a].clone(), finding(
            Effect::AdcDnl,
            Some(a),
            t,
            before,
            after,
            format!("ADC {a}'s pixels are off alike at some levels, unlike the other ADCs' (its departure from the common level term agrees between even and odd rows at {t:.1} standard deviations): the ADC's integral nonlinearity (DN error) at the codes its pixels read, which a linearity set sees only as level means; its own term is taken out of its pixels' means"),
        )));
    }
    // Beside the ADCs' own terms the common term holds their mean DN error too, which a
    // level's code sets, not its light: not named the light's there. (Naming it where
    // its variance grows as the signal squared, z > 3, was tried and reverted after an
    // independent review: ADC errors that grow with the code passed it on 4 of 12 sets
    // without any light error; the light's part common to every ADC is the next test.)
    if !handled && level_accepted && levels_term.per_adc.is_none() {
        findings.push(level_finding(&levels_term, &mut named));
    }
    LevelStage { term: levels_term, accepted: level_accepted, findings, series: named.series, light_rel: named.light_rel }
}

/// The common level term's finding, named by its shape: random errors of the
/// measurement (`named` then holds its light part and the two series it is, where it is), or a
/// response every pixel shares that no quartic follows.
pub(super) fn level_finding(term: &LevelTerm, named: &mut Named) -> Finding {
    let (before, after) = held_out_rms(&term.by_level);
    let (effect, detail) = match term.shape {
        Shape::Random => (Effect::LevelErrors, format!(
            "every pixel is off alike at some levels, beyond any smooth response, uncorrelated from level to level and spread over the range: light {:.2e} rms (relative) off the reference detector and black level {:.3} DN rms (odd rows' level residuals against the even rows' estimate){}; taken out of every pixel's means (the light's part scaled by each pixel's local slope, the black level's by its ADC's); their smooth part cannot be told from a shared nonlinearity: a shared curve takes it, and is named only if it stands out against the level errors too",
            term.light_rel,
            term.black_dn,
            {
                named.light_rel = Some(term.light_rel);
                named.series = term.series();
                let series = &named.series;
                let adcs = if term.per_adc.is_some() { "; beside the ADCs' own terms (taken out per ADC), whose mean DN error the black level's part also holds" } else { "" };
                format!("{}{adcs}", series.as_ref().map_or(String::new(), |s| s.text()))
            },
        )),
        Shape::LowSignal { share } => (Effect::LowSignalNonlinearity, format!(
            "every pixel departs alike from any smooth response at the lowest signals: {:.0}% of the agreement between even and odd rows lies in the lowest 10% of the range (an offset or a charge loss); taken out of every pixel's means",
            100.0 * share
        )),
        Shape::Correlated { rho } => (Effect::Unexplained, format!(
            "every pixel departs alike from any smooth response, correlated from level to level (lag-1 correlation {rho:.2} over the levels by signal): a shared response no quartic follows, not random level errors; taken out of every pixel's means"
        )),
    };
    with_residuals(term.by_level.clone(), finding(effect, None, term.significance, before, after, detail))
}

