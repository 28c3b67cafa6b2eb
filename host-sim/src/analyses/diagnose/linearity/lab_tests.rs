//! The catalogue's tests on simulated laboratory linearity sets with planted effects
//! (`crate::model::hidden`): what each planted effect must be named as, and what must not be.

use super::*;
use crate::model::hidden::{linearity_set, Hidden, Plant};

fn names(d: &Diagnosis) -> Vec<String> {
    d.findings.iter().map(|f| format!("{}{}", f.effect, f.adc.map_or(String::new(), |a| format!(" {a}")))).collect()
}

/// Noise too low to average below a code: `insufficient-noise`, and the means'
/// quantization errors (which the frames' spread does not show) not taken for
/// structure.
#[test]
fn quantization_limited_sets_are_insufficient_noise_only() {
    let plant = Plant { width: 32, height: 32, read_dn: 0.1, gain_e_per_dn: 1e5, frames: 64, quantized: true, ..Plant::default() };
    for seed in 0..3 {
        let d = diagnose_linearity(&linearity_set(&plant, &[], 400 + seed), 0.01).unwrap();
        assert_eq!(names(&d), vec!["insufficient-noise"], "seed {seed}: {:#?}", d.findings);
        // And a 2% bend is still seen through the quantization.
        let d = diagnose_linearity(&linearity_set(&plant, &[Hidden::GlobalNonlinearity { c2: 0.02 }], 410 + seed), 0.01).unwrap();
        let mut got = names(&d);
        got.sort();
        assert_eq!(got, vec!["global-nonlinearity", "insufficient-noise"], "seed {seed}: {:#?}", d.findings);
    }
}

/// The camera parameters written to the model file come back as planted (defaults:
/// 44 e-/DN, 4 DN read noise, 1% PRNU, 1 DN DSNU, no saturation), with an ADC's
/// offset and gain off that must not pass for DSNU or PRNU.
#[test]
fn measured_camera_parameters_are_the_planted_ones() {
    let plant = Plant::default();
    for seed in 0..3 {
        let hidden = [Hidden::AdcOffset { adc: 1, dn: 3.0 }, Hidden::AdcGain { adc: 2, rel: 0.03 }];
        let m = diagnose_linearity(&linearity_set(&plant, &hidden, 600 + seed), 0.01).unwrap().measured;
        // (ADC 2's gain 3% high makes its pixels' e-/DN 3% low: the camera's one gain,
        // over all the pixels, is within 1.5% of the others'.)
        let g = m.gain_e_per_dn.unwrap();
        assert!((g / plant.gain_e_per_dn - 1.0).abs() < 0.015, "seed {seed}: gain {g}");
        let r = m.read_noise_dn.unwrap();
        assert!((r - plant.read_dn).abs() < 0.05, "seed {seed}: read noise {r}");
        let p = m.prnu_rms.unwrap();
        assert!((p / plant.prnu - 1.0).abs() < 0.05, "seed {seed}: PRNU {p}");
        let d = m.dsnu_dn.unwrap();
        assert!((d / plant.dsnu_dn - 1.0).abs() < 0.05, "seed {seed}: DSNU {d}");
        assert!(!m.saturated, "seed {seed}: nothing saturates at {} DN", plant.full_dn + plant.offset_dn);
    }
    let bright = Plant { full_dn: 4500.0, ..plant };
    assert!(diagnose_linearity(&linearity_set(&bright, &[], 9), 0.01).unwrap().measured.saturated);
}

/// Level errors alone (light off the reference, black level off, per level) are
/// named `level-errors` and do not pass for an ADC mismatch or a shared bend.
#[test]
fn level_errors_alone_are_level_errors() {
    let seeds: u64 = std::env::var("DNCAL_SEEDS").ok().and_then(|v| v.parse().ok()).unwrap_or(6);
    for seed in 0..seeds {
        let h = match seed % 3 {
            0 => Hidden::LevelErrors { rel_rms: 2e-4, offset_dn: 0.0 },
            1 => Hidden::LevelErrors { rel_rms: 0.0, offset_dn: 0.4 },
            _ => Hidden::LevelErrors { rel_rms: 1e-3, offset_dn: 1.0 },
        };
        let d = diagnose_linearity(&linearity_set(&Plant::default(), std::slice::from_ref(&h), 500 + seed), 0.01).unwrap();
        assert_eq!(names(&d), vec!["level-errors".to_string()], "seed {seed}, {h:?}: {:#?}", d.findings);
        // (Random level errors are not two series.)
        assert_eq!(d.measured.light_series_step, None, "seed {seed}, {h:?}: {}", d.findings[0].detail);
    }
}

/// Issue 58: level errors of a consumer camera's size (2% rms light errors, 2.5 e-/DN,
/// 8 frames a level, so a level's error is 5 times its mean's noise at the top) are the
/// light's and nothing of the sensor: on 6 seeds `level-errors` with its size within 20%
/// of the drawn errors' rms, and at most `unexplained` beside it (2 of the 6, at 6.5 and
/// 10 sigma: 1.05-1.06 times the noise where the true reference leaves 1.025). Before the
/// level term's fits weighed each mean by its pixel's smoothed variance, took the light's
/// part out through a quadratic's slopes and kept the term over all levels where no
/// departure at the lowest is named, the same sets gave `unexplained` on all 6 (up to
/// 2.2 times the noise), `adc-mismatch` on 2, `pixel-nonlinearity` and `bad-pixels` on 1.
#[test]
fn consumer_sized_level_errors_are_the_lights_alone() {
    use rand::SeedableRng;
    use rand_distr::Distribution;
    let plant = Plant { gain_e_per_dn: 2.5, read_dn: 2.0, frames: 8, ..Plant::default() };
    let mut unexplained = 0;
    for seed in 0..6u64 {
        let d = diagnose_linearity(&linearity_set(&plant, &[Hidden::LevelErrors { rel_rms: 0.02, offset_dn: 0.0 }], 7000 + seed), 0.01).unwrap();
        let got = names(&d);
        assert!(got.contains(&"level-errors".to_string()) && got.iter().all(|n| n == "level-errors" || n == "unexplained"), "seed {seed}: {:#?}", d.findings);
        unexplained += usize::from(got.len() > 1);
        // (The generator draws the light's errors first from the set's seed.)
        let mut rng = rand::rngs::StdRng::seed_from_u64(7000 + seed);
        let unit = rand_distr::Normal::new(0.0, 1.0).unwrap();
        let drawn: Vec<f64> = (0..plant.levels).map(|_| 0.02 * unit.sample(&mut rng)).collect();
        let (got, want) = (d.measured.light_level_rms.unwrap(), crate::infra::stats::rms(&drawn));
        assert!((got / want - 1.0).abs() < 0.2, "seed {seed}: light errors {got} against {want} drawn");
    }
    assert!(unexplained <= 2, "unexplained on {unexplained} of 6");
}

/// An ADC's gain off beside light errors (both within the blind test's ranges): the
/// light's part of the level term scales with each pixel's gain, so the ADC is an
/// `adc-mismatch` and not also an `adc-dnl` (16 of 20 seeds were, when the term was
/// one DN amount for all pixels).
#[test]
fn light_errors_scale_with_the_pixels_gain() {
    for seed in 0..9 {
        // Light only, black only, both.
        let lab = [Hidden::LevelErrors { rel_rms: 5e-4, offset_dn: 0.0 }, Hidden::LevelErrors { rel_rms: 0.0, offset_dn: 1.0 }, Hidden::LevelErrors { rel_rms: 5e-4, offset_dn: 1.0 }][seed as usize % 3].clone();
        let hidden = [Hidden::AdcGain { adc: 1, rel: 0.03 }, lab];
        let d = diagnose_linearity(&linearity_set(&Plant::default(), &hidden, 820 + seed), 0.01).unwrap();
        let mut got = names(&d);
        got.sort();
        assert_eq!(got, vec!["adc-mismatch 1", "level-errors"], "seed {seed}: {:#?}", d.findings);
    }
}

/// An ADC that bends beside large level errors: its slope, and so its share of each
/// level's error, changes with the signal; the level term follows each ADC's local
/// slope, so the ADC is an `adc-mismatch` and not also an `adc-dnl` (8 of 12 sets
/// were, with one gain per ADC).
#[test]
fn level_errors_follow_a_bending_adcs_slope() {
    let seeds: u64 = std::env::var("DNCAL_SEEDS").ok().and_then(|v| v.parse().ok()).unwrap_or(6);
    for seed in 0..seeds {
        let e = if seed % 2 == 0 { 0.01 } else { -0.01 };
        let hidden = [Hidden::AdcCurvature { adc: (seed % 4) as usize, e }, Hidden::LevelErrors { rel_rms: 1e-3, offset_dn: 1.0 }];
        let d = diagnose_linearity(&linearity_set(&Plant::default(), &hidden, 880 + seed), 0.01).unwrap();
        let mut got = names(&d);
        got.sort();
        assert_eq!(got, vec![format!("adc-mismatch {}", seed % 4), "level-errors".to_string()], "seed {seed}: {:#?}", d.findings);
    }
}

/// A charge loss every pixel shares at low signal is the camera's
/// `low-signal-nonlinearity`, not the measurement's `level-errors` (it was, 40 of 40,
/// before the term's shape was looked at; losses of 7-20 DN were also `level-errors`,
/// from their tail above 10% of the signal, until level errors beside a low departure
/// were judged above 20%).
#[test]
fn a_shared_charge_loss_is_low_signal_nonlinearity() {
    for (seed, dn) in [0.5, 1.0, 2.0, 5.0, 10.0, 20.0].into_iter().enumerate() {
        let d = diagnose_linearity(&linearity_set(&Plant::default(), &[Hidden::ChargeLoss { dn }], 840 + seed as u64), 0.01).unwrap();
        assert_eq!(names(&d), vec!["low-signal-nonlinearity"], "{dn} DN: {:#?}", d.findings);
        // And with 13 levels (too few above 20% of the signal for the term there).
        let few = Plant { levels: 13, ..Plant::default() };
        let d = diagnose_linearity(&linearity_set(&few, &[Hidden::ChargeLoss { dn: dn.max(5.0) }], 850 + seed as u64), 0.01).unwrap();
        assert_eq!(names(&d), vec!["low-signal-nonlinearity"], "13 levels, {dn} DN: {:#?}", d.findings);
    }
}

/// A large charge loss beside level errors: both named (the low levels are left out
/// of the pixels' fits and their departure tested against the level errors above;
/// with one quartic over all levels the loss spread over the range and 10 DN beside
/// 0.4 DN of black-level errors was `level-errors` only). Smaller losses are named less
/// often (measured rates in docs/diagnose.md): a 1 DN loss is about twice one level's
/// black-level error.
#[test]
fn a_large_charge_loss_beside_level_errors_is_named() {
    for seed in 0..6 {
        let lab = [Hidden::LevelErrors { rel_rms: 0.0, offset_dn: 0.4 }, Hidden::LevelErrors { rel_rms: 3e-4, offset_dn: 0.0 }, Hidden::LevelErrors { rel_rms: 3e-4, offset_dn: 0.4 }][seed as usize % 3].clone();
        let d = diagnose_linearity(&linearity_set(&Plant::default(), &[Hidden::ChargeLoss { dn: 20.0 }, lab.clone()], 1860 + seed), 0.01).unwrap();
        let mut got = names(&d);
        got.sort();
        assert_eq!(got, vec!["level-errors", "low-signal-nonlinearity"], "seed {seed}, {lab:?}: {:#?}", d.findings);
    }
}

/// A small charge loss beside level errors, not named, leaves no bend behind: the
/// levels below 10% are left out of the shared bend's test with levels as the units (a
/// 5 DN loss beside 0.4 DN black errors gave a false `global-nonlinearity` in 5 of 12
/// sets, a review, when the term's quartic projection stayed in every pixel; taking the
/// term out over all levels with those levels in the bend's test, 2 of 20; with them left
/// out, 0 of 20, and before issue 58 the term below 10% was the one extrapolated from
/// the levels above).
#[test]
fn a_small_charge_loss_beside_level_errors_makes_no_bend() {
    for seed in 0..6 {
        let hidden = [Hidden::ChargeLoss { dn: 5.0 }, Hidden::LevelErrors { rel_rms: 0.0, offset_dn: 0.4 }];
        let d = diagnose_linearity(&linearity_set(&Plant::default(), &hidden, 1880 + seed), 0.01).unwrap();
        let got = names(&d);
        assert!(got.iter().all(|n| n == "level-errors" || n == "low-signal-nonlinearity") && got.contains(&"level-errors".to_string()), "seed {seed}: {:#?}", d.findings);
    }
}

/// A sensor too small for each ADC's own clipped means still has its shared bend
/// tested with levels as the units (one clip over all pixels): a 4% bend on 6 x 6
/// pixels was not named when the test had no rows.
#[test]
fn a_small_sensors_bend_is_named() {
    let plant = Plant { width: 6, height: 6, ..Plant::default() };
    for seed in 0..4 {
        let d = diagnose_linearity(&linearity_set(&plant, &[Hidden::GlobalNonlinearity { c2: 0.04 }], 1890 + seed), 0.01).unwrap();
        assert!(names(&d).contains(&"global-nonlinearity".to_string()), "seed {seed}: {:#?}", d.findings);
    }
}

/// Large level errors and no bend: no shared bend named (the bend's test against the
/// level errors uses an F reference: their variance is estimated from the levels).
#[test]
fn large_level_errors_make_no_bend() {
    let seeds: u64 = std::env::var("DNCAL_SEEDS").ok().and_then(|v| v.parse().ok()).unwrap_or(8);
    for seed in 0..seeds {
        let d = diagnose_linearity(&linearity_set(&Plant::default(), &[Hidden::LevelErrors { rel_rms: 1e-3, offset_dn: 1.0 }], 860 + seed), 0.01).unwrap();
        assert_eq!(names(&d), vec!["level-errors"], "seed {seed}: {:#?}", d.findings);
    }
}

/// Means noisier than the frames say, by 5% of variance alike everywhere, are
/// `excess-noise`, with or without a real effect beside them; 2% is nothing.
#[test]
fn excess_noise_is_noise_not_structure() {
    for seed in 0..3 {
        let run = |e: f64, h: &[Hidden]| {
            let mut got = names(&diagnose_linearity(&linearity_set(&Plant { excess_noise: e, ..Plant::default() }, h, 980 + seed), 0.01).unwrap());
            got.sort();
            got
        };
        assert_eq!(run(0.05, &[]), vec!["excess-noise"], "seed {seed}");
        assert_eq!(run(0.05, &[Hidden::PixelNonlinearity { rms: 0.002 }]), vec!["excess-noise", "pixel-nonlinearity"], "seed {seed}");
        assert!(run(0.02, &[]).is_empty(), "seed {seed}");
    }
}

/// Structure in some pixels, each below the bad-pixel threshold, is `unexplained`: the
/// pixel-to-pixel dispersion keeps it from passing for a scaled noise (without that
/// check 300 pixels jumping by 0.5 DN rms were taken for 5% of excess noise).
#[test]
fn subtle_pixels_are_unexplained_not_excess_noise() {
    for seed in 0..3 {
        let d = diagnose_linearity(&linearity_set(&Plant::default(), &[Hidden::SubtleBad { count: 300, dn: 0.5 }], 960 + seed), 0.01).unwrap();
        assert_eq!(names(&d), vec!["unexplained"], "seed {seed}: {:#?}", d.findings);
    }
}

/// Level errors do not hide the camera's own effects at the low end of the blind
/// test's amplitudes, nor make them look like something else.
#[test]
fn level_errors_leave_the_cameras_effects_visible() {
    let lab = Hidden::LevelErrors { rel_rms: 3e-4, offset_dn: 0.4 };
    let cases = [
        (Hidden::GlobalNonlinearity { c2: 0.01 }, "global-nonlinearity"),
        (Hidden::GlobalNonlinearity { c2: -0.012 }, "global-nonlinearity"),
        (Hidden::PixelNonlinearity { rms: 0.002 }, "pixel-nonlinearity"),
        (Hidden::AdcCurvature { adc: 1, e: 0.005 }, "adc-mismatch 1"),
        (Hidden::AdcGain { adc: 2, rel: -0.01 }, "adc-mismatch 2"),
        (Hidden::AdcOffset { adc: 3, dn: 1.0 }, "adc-mismatch 3"),
        (Hidden::BadPixels { count: 10 }, "bad-pixels"),
    ];
    for (seed, (h, name)) in cases.iter().enumerate() {
        let d = diagnose_linearity(&linearity_set(&Plant::default(), &[h.clone(), lab.clone()], 700 + seed as u64), 0.01).unwrap();
        let mut want = vec![name.to_string(), "level-errors".to_string()];
        want.sort();
        let mut got = names(&d);
        got.sort();
        assert_eq!(got, want, "{h:?}: {:#?}", d.findings);
    }
}

/// The all-data scale ([`Finding::all_data_rms_after`]) runs from the baseline to what is
/// left: a planted effect the model then describes exactly brings the held-out RMS over
/// all the data from far above to the closed form of a correct model (a 2-parameter fit
/// per pixel scored on 21 held-out levels: `E z^2 = 1 + 2/21`, as for a clean set), and
/// the model's last step is what is left unexplained.
#[test]
fn the_all_data_scale_runs_from_the_baseline_to_what_is_left() {
    let correct = (1.0f64 + 2.0 / 21.0).sqrt();
    let cases = [
        (Hidden::GlobalNonlinearity { c2: 0.02 }, "global-nonlinearity", Some(correct)),
        (Hidden::AdcCurvature { adc: 2, e: 0.01 }, "adc-mismatch 2", Some(correct)),
        (Hidden::LevelErrors { rel_rms: 1e-3, offset_dn: 1.0 }, "level-errors", Some(correct)),
        // Each pixel's own quartic: more parameters, no closed form; below the baseline.
        (Hidden::PixelNonlinearity { rms: 0.005 }, "pixel-nonlinearity", None),
    ];
    for (seed, (h, name, expected)) in cases.into_iter().enumerate() {
        let d = diagnose_linearity(&linearity_set(&Plant::default(), std::slice::from_ref(&h), 950 + seed as u64), 0.01).unwrap();
        assert_eq!(names(&d), vec![name.to_string()], "{h:?}: {:#?}", d.findings);
        let after = d.findings[0].all_data_rms_after.unwrap_or_else(|| panic!("{h:?}: no all-data RMS"));
        assert!(d.baseline.rms > 1.2 * after, "{h:?}: baseline {} against {after} after", d.baseline.rms);
        if let Some(e) = expected {
            assert!((after - e).abs() < 0.02, "{h:?}: {after} after, a correct model gives {e}");
        }
        // (Level errors: with the smooth part of them that a shared curve takes.)
        assert!((after - d.unexplained_rms).abs() < 1e-12 * after, "{h:?}: last step {after}, unexplained {}", d.unexplained_rms);
    }
}

/// Two effects, one ADC's own bend and a shared bend, enter in that order: the findings
/// are listed so, and the all-data RMS falls at each step to the model's remainder.
#[test]
fn findings_are_listed_in_the_order_they_enter_the_model() {
    let hidden = [Hidden::AdcCurvature { adc: 2, e: 0.01 }, Hidden::GlobalNonlinearity { c2: 0.02 }];
    let d = diagnose_linearity(&linearity_set(&Plant::default(), &hidden, 970), 0.01).unwrap();
    assert_eq!(names(&d), vec!["adc-mismatch 2".to_string(), "global-nonlinearity".to_string()], "{:#?}", d.findings);
    let steps: Vec<f64> = std::iter::once(d.baseline.rms).chain(d.findings.iter().map(|f| f.all_data_rms_after.unwrap())).collect();
    assert!(steps.windows(2).all(|w| w[1] < w[0]), "{steps:?}");
    assert!((steps[2] - (1.0f64 + 2.0 / 21.0).sqrt()).abs() < 0.02, "{steps:?}");
}

/// Two runs on the same set give the same diagnosis number for number: sums over pixels
/// are taken in a fixed order whichever thread did what (`TASKS`; before, significances
/// differed at 1e-9 between runs).
#[test]
fn a_diagnosis_is_the_same_number_for_number_on_every_run() {
    let plant = Plant { width: 48, height: 48, ..Plant::default() };
    let set = linearity_set(&plant, &[Hidden::GlobalNonlinearity { c2: 0.02 }], 77);
    let runs: Vec<String> = (0..8).map(|_| serde_json::to_string(&diagnose_linearity(&set, 0.01).unwrap()).unwrap()).collect();
    for (k, run) in runs.iter().enumerate().skip(1) {
        assert_eq!(run, &runs[0], "run {k}");
    }
}

/// The bad-pixels finding's RMS after is that of the pixels left, whose held-out
/// residuals are noise: near 1, and below the RMS with the bad pixels in (a mutant that
/// took the remainder instead of the mean of the squares survived every test).
#[test]
fn bad_pixels_leave_the_others_at_their_noise() {
    let d = diagnose_linearity(&linearity_set(&Plant::default(), &[Hidden::BadPixels { count: 10 }], 1234), 0.01).unwrap();
    let f = d.findings.iter().find(|f| f.effect == Effect::BadPixels).expect("bad pixels named");
    assert!((0.8..1.3).contains(&f.rms_after), "{f:#?}");
    assert!(f.rms_before > f.rms_after, "{f:#?}");
}

/// The light's pattern changing between levels (the paper's bench, `docs/paper.md`) is
/// `illumination-change` alone, alone and beside each pixel's own curve, with its size
/// measured as planted (within 15%: the part a pixel's quartic takes while the field is
/// fitted is not in it) and a gain on the held-out residuals. Larger (4e-4 on this
/// 64 x 64 set), the pattern's part that no model can tell from the pixels' own curves
/// stands out by itself (`docs/diagnose.md`): it is still named, and measured.
#[test]
fn a_changing_illumination_is_named_and_measured() {
    for (seed, rms) in [(0u64, 2e-4), (1, 3e-4), (2, 4e-4)] {
        for with_pixels in [false, true] {
            let mut hidden = vec![Hidden::IlluminationChange { rms }];
            if with_pixels {
                hidden.push(Hidden::PixelNonlinearity { rms: 0.005 });
            }
            let d = diagnose_linearity(&linearity_set(&Plant::default(), &hidden, 900 + seed), 0.01).unwrap();
            let mut got = names(&d);
            got.sort();
            let want: Vec<&str> = if with_pixels { vec!["illumination-change", "pixel-nonlinearity"] } else { vec!["illumination-change"] };
            if rms <= 3e-4 {
                assert_eq!(got, want, "{hidden:?}: {:#?}", d.findings);
            }
            let f = d.findings.iter().find(|f| f.effect == Effect::IlluminationChange).unwrap_or_else(|| panic!("{hidden:?}: {:#?}", d.findings));
            let measured = d.measured.illumination_change_rms.unwrap();
            assert!((measured / rms - 1.0).abs() < 0.15, "{hidden:?}: measured {measured:.3e}");
            assert!(f.gain > 1.2, "{hidden:?}: {f:?}");
        }
    }
}

/// The pattern changes the model file: `[bench] illumination_change_rms` is what the
/// diagnosis measured, and a set without it leaves it at zero.
#[test]
fn the_measured_pattern_goes_into_the_model() {
    let set = linearity_set(&Plant::default(), &[Hidden::IlluminationChange { rms: 3e-4 }], 930);
    let d = diagnose_linearity(&set, 0.01).unwrap();
    let model = crate::analyses::diagnose::model::linearity_model(&set, &d);
    assert_eq!(Some(model.bench.illumination_change_rms), d.measured.illumination_change_rms);
    let clean = linearity_set(&Plant::default(), &[], 931);
    let d = diagnose_linearity(&clean, 0.01).unwrap();
    assert_eq!(crate::analyses::diagnose::model::linearity_model(&clean, &d).bench.illumination_change_rms, 0.0);
}

/// Issue 58: a colour filter (the consumer camera's Bayer responses: one channel at 0.55
/// of the mean, the green pair at 1.23) is `cfa-pattern` with each channel's response
/// within 2% of the planted one (relative to their mean), and nothing else: no channel
/// called bad, no ADC mismatch from ADCs that read different colours, PRNU within a
/// channel as planted. With true bad pixels beside it, those are found (their count, not
/// a quarter of the sensor). With one ADC (a consumer camera) and with four.
#[test]
fn a_colour_filter_is_a_pattern_not_bad_pixels() {
    let planted = [1.23, 0.99, 0.55, 1.23];
    let unit = planted.iter().sum::<f64>() / 4.0;
    for seed in 0..4u64 {
        let n_adc = if seed % 2 == 0 { 1 } else { 4 };
        // (Full scale lowered so that the green pair stays below the top code.)
        let plant = Plant { n_adc, full_dn: 2800.0, ..Plant::default() };
        for bad in [0usize, 12] {
            let mut hidden = vec![Hidden::Cfa { response: planted }];
            if bad > 0 {
                hidden.push(Hidden::BadPixels { count: bad });
            }
            let d = diagnose_linearity(&linearity_set(&plant, &hidden, 5800 + seed), 0.01).unwrap();
            let mut got = names(&d);
            got.sort();
            let want: Vec<&str> = if bad > 0 { vec!["bad-pixels", "cfa-pattern"] } else { vec!["cfa-pattern"] };
            assert_eq!(got, want, "seed {seed}, {n_adc} ADCs, {bad} bad: {:#?}", d.findings);
            let cfa = d.measured.cfa.as_ref().expect("the pattern is measured");
            assert_eq!(cfa.period, 2);
            for (k, (r, p)) in cfa.response.iter().zip(planted).enumerate() {
                assert!((r / (p / unit) - 1.0).abs() < 0.02, "seed {seed}: cell {k}: {r} against {}", p / unit);
            }
            if bad > 0 {
                let f = d.findings.iter().find(|f| f.effect == Effect::BadPixels).unwrap();
                let count = f.count.unwrap();
                assert!((bad - 2..=bad + 2).contains(&count), "seed {seed}: {count} bad pixels of {bad}: {f:#?}");
            }
            let prnu = d.measured.prnu_rms.unwrap();
            assert!((prnu / plant.prnu - 1.0).abs() < 0.1, "seed {seed}: PRNU {prnu} within a channel against {}", plant.prnu);
            let f = d.findings.iter().find(|f| f.effect == Effect::CfaPattern).unwrap();
            assert!(f.detail.contains("a Bayer filter's green, layout GxxG"), "{}", f.detail);
        }
    }
}

/// The null of `cfa-pattern`: no pattern named on clean sets, nor where the columns
/// alone (an ADC's gain) or the rows alone differ, which a colour filter does not explain.
#[test]
fn columns_or_rows_alone_are_not_a_colour_filter() {
    for seed in 0..6u64 {
        let hidden: Vec<Hidden> = match seed % 3 {
            0 => vec![],
            1 => vec![Hidden::AdcGain { adc: 1, rel: 0.03 }],
            // Even and odd rows apart by 4% (a two-sided readout): rows alone.
            _ => vec![Hidden::Cfa { response: [1.02, 1.02, 0.98, 0.98] }],
        };
        let d = diagnose_linearity(&linearity_set(&Plant::default(), &hidden, 5900 + seed), 0.01).unwrap();
        assert!(d.findings.iter().all(|f| f.effect != Effect::CfaPattern), "seed {seed} {hidden:?}: {:#?}", d.findings);
        assert!(d.measured.cfa.is_none());
    }
    // Rows 20% apart times the odd columns' ADCs 10% off: a product, whose ratios have an
    // interaction (z = 9 on this 64 x 64 set before the test took logarithms) and whose
    // logarithms have none.
    for seed in 0..2u64 {
        let hidden = [Hidden::Cfa { response: [1.1, 1.1, 0.9, 0.9] }, Hidden::AdcGain { adc: 1, rel: 0.1 }, Hidden::AdcGain { adc: 3, rel: 0.1 }];
        let d = diagnose_linearity(&linearity_set(&Plant::default(), &hidden, 5910 + seed), 0.01).unwrap();
        assert!(d.findings.iter().all(|f| f.effect != Effect::CfaPattern), "seed {seed}: {:#?}", d.findings);
    }
}

/// A Bayer filter beside one ADC's 3% gain (four column ADCs): the pattern stays 2 x 2
/// (a 4 x 4 "filter" took the ADCs' gains when the larger period was tested on what it
/// added without its interaction: a review found it so on every seed) and the gain is
/// named as `adc-mismatch`.
#[test]
fn a_colour_filter_beside_an_adcs_gain_stays_2_by_2() {
    let plant = Plant { full_dn: 2800.0, ..Plant::default() };
    for seed in 0..3u64 {
        let hidden = [Hidden::Cfa { response: [1.23, 0.99, 0.55, 1.23] }, Hidden::AdcGain { adc: 1, rel: 0.03 }];
        let d = diagnose_linearity(&linearity_set(&plant, &hidden, 5920 + seed), 0.01).unwrap();
        assert_eq!(d.measured.cfa.as_ref().map(|c| c.period), Some(2), "seed {seed}: {:#?}", d.findings);
        assert!(d.findings.iter().any(|f| f.effect == Effect::AdcMismatch && f.adc == Some(1)), "seed {seed}: {:#?}", d.findings);
    }
}

/// Issue 58: a set whose level 0 is not dark (the shortest of a series of exposures, at
/// 10% and 30% of the largest) says so, and its offset is the response's intercept at
/// zero reference, the planted 60 DN within 3 of its standard errors (and not level 0's
/// mean, 420 DN above it at 10%); the gain within 2%; the read noise either within 10%
/// of the planted 4 DN or withheld with a bound above it; no DSNU. A set with a dark
/// level gives no such note.
#[test]
fn a_set_without_a_dark_level_says_so_and_fits_the_offset() {
    for (seed, start) in [(0u64, 0.1), (1, 0.3), (2, 0.1)] {
        let plant = Plant { reference_start: start, ..Plant::default() };
        let d = diagnose_linearity(&linearity_set(&plant, &[], 5810 + seed), 0.01).unwrap();
        let m = &d.measured;
        let nd = m.no_dark.as_ref().unwrap_or_else(|| panic!("start {start}: no note: {m:?}"));
        assert!((nd.reference - start).abs() < 1e-12);
        let offset = m.offset_dn.unwrap();
        assert!((offset - plant.offset_dn).abs() < 3.0 * nd.offset_se_dn + 0.05, "start {start}: offset {offset} +- {}", nd.offset_se_dn);
        assert!(nd.offset_se_dn < 0.5, "{nd:?}");
        let g = m.gain_e_per_dn.unwrap();
        assert!((g / plant.gain_e_per_dn - 1.0).abs() < 0.02, "start {start}: gain {g}");
        match (m.read_noise_dn, nd.read_bound_dn) {
            (Some(r), None) => assert!((r / plant.read_dn - 1.0).abs() < 0.1, "start {start}: read {r}"),
            (None, Some(b)) => assert!(b > plant.read_dn, "start {start}: bound {b}"),
            other => panic!("start {start}: {other:?}"),
        }
        assert_eq!(m.dsnu_dn, None);
        assert!(d.not_tested.iter().any(|n| n.starts_with("dark level: none in this set")), "{:?}", d.not_tested);
        assert!(d.findings.is_empty(), "start {start}: {:#?}", d.findings);
    }
    let d = diagnose_linearity(&linearity_set(&Plant::default(), &[], 5813), 0.01).unwrap();
    assert!(d.measured.no_dark.is_none() && d.not_tested.is_empty(), "{:?}", d.not_tested);
}

/// Issue 58, the loop closed: a camera model with a Bayer filter (`[cfa]`) simulated as
/// `simulate linearity` does (128 x 128 of the default camera, 41 levels), diagnosed:
/// `cfa-pattern` with each cell within 2% of the model's (relative to their mean), PRNU
/// within a channel within 10% of the model's 1%; the model file written from it carries
/// the measured cells, which a camera built from it applies.
#[test]
fn a_camera_models_colour_filter_comes_back_from_its_set() {
    use crate::model::camera::{config::CfaConfig, Camera, CameraConfig};
    let cells = vec![1.2, 1.0, 0.6, 1.2];
    let config = CameraConfig { cfa: Some(CfaConfig { period: 2, cells: cells.clone(), bayer: Some(crate::formats::bayer::Bayer::Gbrg) }), bad_pixel_fraction: 0.0, ..CameraConfig::default() };
    let camera = Camera::new(config.clone()).unwrap();
    let p = crate::model::camera::calibration::LinearityParams { overshoot: 0.8, ..crate::model::camera::calibration::LinearityParams::paper(&camera) };
    let set = crate::model::sets::linearity_set_of(&camera, &p).unwrap();
    // The set's layout is the sensor's from the region's first pixel.
    let layout = crate::formats::bayer::Bayer::Gbrg.shifted(p.roi.0, p.roi.1);
    assert_eq!(set.keys.bayer, Some(layout));
    let d = diagnose_linearity(&set, 0.01).unwrap();
    let f = d.findings.iter().find(|f| f.effect == Effect::CfaPattern).unwrap_or_else(|| panic!("{:#?}", d.findings));
    assert!(f.detail.contains(&format!("the file declares {layout} (BAYERPAT)")) && f.detail.contains("its greens respond alike"), "{}", f.detail);
    assert!(d.findings.iter().all(|f| f.effect != Effect::BadPixels && f.effect != Effect::AdcMismatch), "{:#?}", d.findings);
    let measured = d.measured.cfa.clone().unwrap();
    let unit = cells.iter().sum::<f64>() / 4.0;
    for (k, (m, c)) in measured.response.iter().zip(&cells).enumerate() {
        assert!((m / (c / unit) - 1.0).abs() < 0.02, "cell {k}: {m} against {}", c / unit);
    }
    let prnu = d.measured.prnu_rms.unwrap();
    assert!((prnu / config.prnu_rms - 1.0).abs() < 0.1, "PRNU {prnu}");
    let model = crate::analyses::diagnose::model::linearity_model(&set, &d);
    let carried = model.cfa.clone().expect("the model carries the filter");
    assert_eq!((carried.period, &carried.cells, carried.bayer), (2, &measured.response, Some(layout)));
    // A layout declared a column off is said to be so; one declared on a monochrome
    // sensor is a note, not a finding.
    let off = LinearitySet { keys: crate::formats::fits::SetKeys { bayer: Some(layout.shifted(1, 0)), ..set.keys }, ..set.clone() };
    let d_off = diagnose_linearity(&off, 0.01).unwrap();
    let f = d_off.findings.iter().find(|f| f.effect == Effect::CfaPattern).unwrap();
    assert!(f.detail.contains("not its greens: the layout is off by a row or a column"), "{}", f.detail);
    assert_eq!(d_off.measured.cfa.as_ref().map(|c| c.bayer), Some(None), "a layout the pixels say is off is not carried");
    let mono = LinearitySet { keys: set.keys, ..linearity_set(&Plant::default(), &[], 5817) };
    let d_mono = diagnose_linearity(&mono, 0.01).unwrap();
    assert!(d_mono.findings.is_empty(), "{:#?}", d_mono.findings);
    assert!(d_mono.not_tested.iter().any(|n| n.starts_with(&format!("cfa-pattern: the file declares a {layout} colour filter (BAYERPAT), but its channels respond alike"))), "{:?}", d_mono.not_tested);
    let rebuilt = Camera::new(model).unwrap();
    // (A pixel of the red cell, row 1 column 0, against one of the green: their ratio.)
    let ratio = rebuilt.pixels.gain[rebuilt.config.width] / rebuilt.pixels.gain[0];
    assert!((ratio / (measured.response[2] / measured.response[0]) - 1.0).abs() < 0.1, "{ratio}");
}

/// Issue 58, a consumer camera's series as a camera model gives it: the reference a
/// relative exposure (`[bench] reference = "exposure"`, written as `EXPOSURE`), each
/// level's light off it by 2% rms (the shutter, the aperture) and each frame's by 1%
/// (`level_error_rms`, `frame_jitter_rms`), simulated as `simulate linearity` does and
/// diagnosed over ten seeds on a sensor without effects of its own (32 frames a level):
/// both named as the light's on every seed where no false `adc-dnl` took the common term
/// (one seed of the ten), the level errors' size within 20% of what no
/// quartic takes of the drawn errors and the jitter's within 20% of the planted; the note
/// that no absolute QE follows; the model file carries the bench. Nothing else named on 8
/// of the 10: on 2 an ADC's curvature or term departs (a false `adc-mismatch`,
/// `adc-dnl`), the known limit of level errors this large (docs/diagnose.md).
#[test]
fn an_exposure_series_with_shutter_errors_and_jitter_is_the_lights() {
    use crate::formats::fits::Reference;
    use crate::model::camera::{calibration::light_errors, Camera, CameraConfig};
    let mut with_others = 0;
    for seed in 0..10u64 {
        // (A sensor without effects of its own: ideal ADCs, a straight response, no bad
        // pixels.)
        let mut config = CameraConfig { bad_pixel_fraction: 0.0, nonlinearity: vec![], pixel_nonlinearity_rms: vec![], ..CameraConfig::default() };
        config.adc = crate::model::camera::AdcConfig::ideal(config.bits);
        config.bench.illumination_change_rms = 0.0;
        config.bench.level_error_rms = 0.02;
        config.bench.frame_jitter_rms = 0.01;
        config.bench.reference = Reference::Exposure;
        config.bench.seed = 900 + seed;
        let camera = Camera::new(config.clone()).unwrap();
        let paper = crate::model::camera::calibration::LinearityParams::paper(&camera);
        let (x0, y0, _, _) = paper.roi;
        let p = crate::model::camera::calibration::LinearityParams { frames: 32, overshoot: 0.8, roi: (x0, y0, 64, 64), seed: 41 + seed, ..paper };
        let set = crate::model::sets::linearity_set_of(&camera, &p).unwrap();
        assert_eq!(set.keys.reference, Reference::Exposure);
        // (The oracle of the size: the errors the camera drew, in DN at each level's light
        // `x`, less the quartic in `x` that fits them best (no analysis can tell that part
        // from the response), back over `x`, at the levels above 10% of the light, scaled
        // up by the projection's `L / (L - 5)`; the per-frame jitter's mean adds its part.)
        let nl = p.levels;
        let x: Vec<f64> = (0..nl).map(|l| l as f64 / (nl - 1) as f64).collect();
        let dn: Vec<f64> = (0..nl).map(|l| light_errors(&config.bench, l, p.frames as usize)).map(|(e, j)| e + j.iter().sum::<f64>() / j.len() as f64).zip(&x).map(|(e, x)| e * x).collect();
        let a = nalgebra::DMatrix::from_fn(nl, 5, |i, k| x[i].powi(k as i32));
        let fit = a.clone().svd(true, true).solve(&nalgebra::DVector::from_vec(dn.clone()), 1e-12).unwrap();
        let left = nalgebra::DVector::from_vec(dn) - a * fit;
        let rel: Vec<f64> = (0..nl).filter(|&l| x[l] > 0.1).map(|l| left[l] / x[l]).collect();
        let drawn_rms = crate::infra::stats::rms(&rel) * (nl as f64 / (nl as f64 - 5.0)).sqrt();
        let d = diagnose_linearity(&set, 0.01).unwrap();
        let got = names(&d);
        // (Where a false `adc-dnl` takes the common term per ADC, the light's part is not
        // named: the catalog's rule beside ADCs' own terms, the open problem.)
        let adc_terms = got.iter().any(|n| n.starts_with("adc-dnl"));
        assert!((adc_terms || got.contains(&"level-errors".to_string())) && got.contains(&"light-jitter".to_string()), "seed {seed}: {:#?}", d.findings);
        let others: Vec<&String> = got.iter().filter(|n| *n != "level-errors" && *n != "light-jitter").collect();
        // (The known limit, docs/diagnose.md: beside level errors this large an ADC's
        // term or curvature sometimes departs; measured 2 seeds of these 10.)
        assert!(others.iter().all(|n| n.starts_with("adc-mismatch") || n.starts_with("adc-dnl")), "seed {seed}: {got:?}");
        with_others += usize::from(!others.is_empty());
        let m = &d.measured;
        let jitter = m.light_jitter_rms.unwrap();
        assert!((jitter / 0.01 - 1.0).abs() < 0.2, "seed {seed}: jitter {jitter}");
        assert_eq!(m.reference, Reference::Exposure);
        assert!(d.not_tested.iter().any(|n| n == super::EXPOSURE_NOTE), "{:?}", d.not_tested);
        let model = crate::analyses::diagnose::model::linearity_model(&set, &d);
        assert_eq!((model.bench.reference, model.bench.frame_jitter_rms), (Reference::Exposure, jitter));
        if let Some(level) = m.light_level_rms {
            assert!((level / drawn_rms - 1.0).abs() < 0.2, "seed {seed}: level errors {level} against {drawn_rms} drawn");
            assert_eq!(model.bench.level_error_rms, level);
        }
    }
    assert!(with_others <= 2, "{with_others} of 10 seeds name an ADC effect the sensor does not have");
}

/// Issue 58: a light that jitters from frame to frame (alike for every pixel) is named
/// `light-jitter` with its size within 20%, and nothing of the sensor is named (the
/// jitter's part of the means is the light's `level-errors`); the gain is the planted one
/// within 3% where the photon transfer with the jitter's term bounds it to 1%, else
/// withheld with the reason. A straight photon transfer read the jitter as a gain far
/// too low.
#[test]
fn a_jittering_light_is_the_lights_and_the_gain_survives_it() {
    // (Planted jitter, frames a level.)
    let cases = [(0.0015, 256u32), (0.01, 64), (0.03, 16), (0.0015, 256), (0.02, 8)];
    let mut bounded = 0;
    for (seed, &(rms, frames)) in cases.iter().enumerate() {
        let plant = Plant { frames, ..Plant::default() };
        let d = diagnose_linearity(&linearity_set(&plant, &[Hidden::LightJitter { rms }], 5900 + seed as u64), 0.01).unwrap();
        let mut got = names(&d);
        got.retain(|n| n != "level-errors");
        assert_eq!(got, vec!["light-jitter"], "seed {seed}, jitter {rms}: {:#?}", d.findings);
        let m = &d.measured;
        let j = m.light_jitter_rms.unwrap();
        assert!((j / rms - 1.0).abs() < 0.2, "seed {seed}: jitter {j} for {rms}");
        // (And in the JSON, beside what was not measured left out.)
        let json = serde_json::to_value(&d).unwrap();
        assert_eq!(json["measured"]["light_jitter_rms"].as_f64(), Some(j));
        assert!(json["measured"].get("dsnu_dn").is_some() && json["measured"].get("illumination_change_rms").is_none(), "{}", json["measured"]);
        let f = d.findings.iter().find(|f| f.effect == Effect::LightJitter).unwrap();
        match m.gain_e_per_dn {
            Some(g) => {
                assert!((g / plant.gain_e_per_dn - 1.0).abs() < 0.03, "seed {seed}: gain {g}: {}", f.detail);
                bounded += 1;
            }
            None => assert!(f.detail.contains("the gain is withheld"), "{}", f.detail),
        }
    }
    // (The smallest jitter leaves the gain bounded: both ways are tested.)
    assert!(bounded >= 1 && bounded < cases.len(), "{bounded} gains of {}", cases.len());
}

/// Issue 58: a consumer-like Bayer camera (2.5 e-/DN, 8 frames a level) under a light
/// that jitters by 1% from frame to frame: the filter, the light's level errors and its
/// jitter, nothing of the ADCs (the level term through the channels' mean response: by
/// the slopes' median over all the channels, ADCs 0 and 2, which read the 1.23 and the
/// 0.55 channels, departed from it as `adc-dnl` at 19 and 17 sigma).
#[test]
fn a_colour_filter_under_a_jittering_light_names_no_adc() {
    let plant = Plant { gain_e_per_dn: 2.5, read_dn: 2.0, frames: 8, ..Plant::default() };
    for seed in 0..3u64 {
        let hidden = [Hidden::LightJitter { rms: 0.01 }, Hidden::Cfa { response: [1.23, 0.99, 0.55, 1.23] }];
        let d = diagnose_linearity(&linearity_set(&plant, &hidden, 77 + seed * 1000), 0.01).unwrap();
        let mut got = names(&d);
        got.retain(|n| n != "level-errors");
        assert_eq!(got, vec!["cfa-pattern", "light-jitter"], "seed {seed}: {:#?}", d.findings);
    }
}

/// Issue 58: a consumer-like camera (2.5 e-/DN, 2 DN read noise, 8 frames a level,
/// every frame drawn and rounded) that subtracted its black level and clips at code 0:
/// `black-level-clipped` alone (where the fits read it as `low-signal-nonlinearity`,
/// an ADC's curvature and an offset of 0.75 DN), the clipped levels left out and the
/// offset the intercept's, 0 within its error; the same camera with its black level at
/// 60 DN names nothing. Read from its file by blocks of rows, the same diagnosis.
#[test]
fn a_black_level_clipped_at_zero_is_named_and_its_levels_left_out() {
    let consumer = Plant { gain_e_per_dn: 2.5, read_dn: 2.0, frames: 8, quantized: true, ..Plant::default() };
    for seed in 0..3u64 {
        let plant = Plant { offset_dn: 0.0, ..consumer.clone() };
        let set = linearity_set(&plant, &[], 6200 + seed);
        let d = diagnose_linearity(&set, 0.01).unwrap();
        assert_eq!(names(&d), vec!["black-level-clipped"], "seed {seed}: {:#?}", d.findings);
        let f = &d.findings[0];
        assert!(f.detail.contains("the lowest level (to") && f.detail.contains("is left out") && f.significance > 5.0, "seed {seed}: {}", f.detail);
        let m = &d.measured;
        let nd = m.no_dark.as_ref().unwrap_or_else(|| panic!("seed {seed}: no dark-level note: {m:?}"));
        let offset = m.offset_dn.unwrap();
        assert!(offset.abs() < 3.0 * nd.offset_se_dn + 0.05, "seed {seed}: offset {offset} +- {}", nd.offset_se_dn);
        let g = m.gain_e_per_dn.unwrap();
        assert!((g / plant.gain_e_per_dn - 1.0).abs() < 0.03, "seed {seed}: gain {g}");
        if seed == 0 {
            let dir = tempfile::tempdir().unwrap();
            let path = dir.path().join("clipped.fits");
            crate::formats::fits::write_linearity(&path, &set).unwrap();
            let held = diagnose_linearity(&crate::formats::fits::read_linearity_as::<f32>(&path).unwrap(), 0.01).unwrap();
            let rows = crate::formats::fits::open_linearity_rows(&path).unwrap().unwrap().check::<f32>().unwrap();
            let mut got = diagnose_linearity_rows(&rows, Some(5), false, 0.01).unwrap();
            got.block_rows = None;
            assert_eq!(serde_json::to_string(&got).unwrap(), serde_json::to_string(&held).unwrap());
        }
        let d = diagnose_linearity(&linearity_set(&consumer, &[], 6210 + seed), 0.01).unwrap();
        assert!(d.findings.is_empty(), "seed {seed}, black level at 60 DN: {:#?}", d.findings);
        if seed == 1 {
            // The levels in the file brightest first: named, not left out (only a prefix
            // of the file can be), and said so.
            let mut reversed = set.clone();
            let np = set.width * set.height;
            for (l, r) in (0..set.levels).rev().enumerate() {
                reversed.mean[l * np..(l + 1) * np].copy_from_slice(&set.mean[r * np..(r + 1) * np]);
                reversed.std[l * np..(l + 1) * np].copy_from_slice(&set.std[r * np..(r + 1) * np]);
                reversed.voltage[l] = set.voltage[r];
            }
            let d = diagnose_linearity(&reversed, 0.01).unwrap();
            let f = d.findings.iter().find(|f| f.effect == Effect::BlackLevelClipped).unwrap_or_else(|| panic!("reversed: {:#?}", d.findings));
            assert!(f.detail.contains(&format!("level {} (the dimmest)", set.levels - 1)) && f.detail.contains("they are not left out (the clipped levels are not the first in the file)"), "{}", f.detail);
        }
    }
    // Signed data (a dark subtracted, nothing clipped: the means of the dark level spread
    // about 0, below it too) are not clipped.
    let signed = Plant { offset_dn: 0.0, gain_e_per_dn: 2.5, read_dn: 2.0, frames: 8, ..Plant::default() };
    let d = diagnose_linearity(&linearity_set(&signed, &[], 6220), 0.01).unwrap();
    assert!(d.findings.iter().all(|f| f.effect != Effect::BlackLevelClipped), "{:#?}", d.findings);
}

/// Issue 58: a consumer camera's two exposure series interleaved in reference, the second's
/// light 1-3% off the first's (daylight that drifted, an aperture off its mark), with and
/// without small random level errors: `level-errors` with the step named as two series
/// (the odd levels against the even) within 20%, and no sensor effect; the scientific
/// camera of the lab likewise.
#[test]
fn two_series_that_disagree_are_the_lights() {
    let consumer = Plant { gain_e_per_dn: 2.5, read_dn: 2.0, frames: 8, ..Plant::default() };
    let cases = [(0.03, 0.0), (0.01, 2e-4), (-0.02, 0.0), (0.015, 1e-3)];
    for (seed, &(rel, random)) in cases.iter().enumerate() {
        for plant in [Plant::default(), consumer.clone()] {
            let mut hidden = vec![Hidden::SeriesDrift { rel }];
            if random > 0.0 {
                hidden.push(Hidden::LevelErrors { rel_rms: random, offset_dn: 0.0 });
            }
            let d = diagnose_linearity(&linearity_set(&plant, &hidden, 6100 + seed as u64), 0.01).unwrap();
            let label = format!("seed {seed}, step {rel}, {} e-/DN", plant.gain_e_per_dn);
            let step = d.measured.light_series_step.unwrap_or_else(|| panic!("{label}: no series: {:#?}", d.findings));
            assert!((step / rel.abs() - 1.0).abs() < 0.2, "{label}: step {step}");
            let f = d.findings.iter().find(|f| f.effect == Effect::LevelErrors).unwrap();
            let (high, low) = if rel > 0.0 { ("odd", "even") } else { ("even", "odd") };
            assert!(f.detail.contains(&format!("the {high} levels {:.2}%", 100.0 * step)) && f.detail.contains(&format!("brighter than the {low} levels")), "{label}: {}", f.detail);
            // (Nothing of the sensor. At a 3% step the level term leaves the brightest
            // levels' residuals at 1.1 times their noise, `unexplained`: the term is
            // scaled by each pixel's quartic slope, noisy at the ends of the range.)
            let sensor: Vec<String> = d.findings.iter().filter(|f| f.effect.in_model() != crate::analyses::diagnose::InModel::OfTheMeasurement && f.effect != Effect::Unexplained).map(|f| f.effect.to_string()).collect();
            assert!(sensor.is_empty(), "{label}: {sensor:?}: {:#?}", d.findings);
        }
    }
}
