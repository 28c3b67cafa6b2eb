//! Planted ADCs through a ramp or a sine, Poisson counts, and what the test must name.

use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Poisson};

use super::*;

/// Counts of an ADC of code widths `widths` (codes 0 and top open: they take the ramp's
/// overdrive, three codes' worth each) under a linear ramp of `per_code` samples per LSB.
fn ramp_counts(widths: &[f64], per_code: f64, seed: u64) -> Vec<u64> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let n = widths.len();
    (0..n)
        .map(|k| {
            let lambda = if k == 0 || k == n - 1 { 3.0 * per_code } else { per_code * widths[k] };
            if lambda > 0.0 { Poisson::new(lambda).unwrap().sample(&mut rng) as u64 } else { 0 }
        })
        .collect()
}

/// Counts under a sine `C + A sin(theta)` (theta uniform) overdriving the range by 8 LSB
/// at both ends, `total` samples: the arcsine probability of each code's interval.
fn sine_counts(widths: &[f64], total: f64, seed: u64) -> Vec<u64> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let n = widths.len();
    // Transition into code k at T_k = 1/2 + sum_{0<j<k} w_j (k >= 1).
    let mut t = vec![f64::NEG_INFINITY; n + 1];
    let mut acc = 0.5;
    for k in 1..n {
        t[k] = acc;
        acc += widths[k];
    }
    t[n] = f64::INFINITY;
    let (c, a) = (n as f64 / 2.0, n as f64 / 2.0 + 8.0);
    let cdf = |x: f64| if x <= c - a { 0.0 } else if x >= c + a { 1.0 } else { 0.5 + ((x - c) / a).asin() / std::f64::consts::PI };
    (0..n)
        .map(|k| {
            let lambda = total * (cdf(t[k + 1]) - cdf(t[k]));
            if lambda > 0.0 { Poisson::new(lambda).unwrap().sample(&mut rng) as u64 } else { 0 }
        })
        .collect()
}

/// RP2040-like widths: codes 511 mod 1024 `wide` LSB, the others sharing what is left so
/// the range keeps its size, and `missing` codes of width 0.
fn planted(bits: u32, wide: f64, missing: &[usize]) -> Vec<f64> {
    let n = 1usize << bits;
    let mut w = vec![1.0; n];
    let wide_codes: Vec<usize> = (1..n - 1).filter(|k| k % 1024 == 511).collect();
    for &k in &wide_codes {
        w[k] = wide;
    }
    for &k in missing {
        w[k] = 0.0;
    }
    let extra: f64 = w[1..n - 1].iter().map(|x| x - 1.0).sum();
    let others = (n - 2 - wide_codes.len() - missing.len()) as f64;
    for (k, x) in w.iter_mut().enumerate() {
        if k > 0 && k < n - 1 && !wide_codes.contains(&k) && !missing.contains(&k) {
            *x -= extra / others;
        }
    }
    w
}

fn codes_of(v: &[CodeWidth]) -> Vec<usize> {
    v.iter().map(|c| c.code).collect()
}

#[test]
fn planted_wide_and_missing_codes_are_named_by_number_at_50_to_100_counts() {
    let mut gen = rand::rngs::StdRng::seed_from_u64(38);
    for seed in 0..8u64 {
        let per_code = gen.random_range(50.0..100.0);
        let wide = gen.random_range(8.0..10.0);
        let w = planted(12, wide, &[2047]);
        let t = analyse(&ramp_counts(&w, per_code, seed), Density::Ramp, &FlattenParams::default()).unwrap();
        let named_wide: Vec<usize> = t.named.iter().filter(|c| c.kind == Some(CodeKind::Wide)).map(|c| c.code).collect();
        assert_eq!(named_wide, vec![511, 1535, 2559, 3583], "seed {seed}, {per_code} counts, {wide} LSB: {:?}", t.named);
        assert_eq!(codes_of(&t.missing), vec![2047], "seed {seed}");
        assert!(t.named.iter().all(|c| c.kind != Some(CodeKind::Narrow)), "seed {seed}: {:?}", t.named);
        // The wide codes' widths within 4 sigma of the planted one (on the test's own LSB).
        let lsb = w[1..4095].iter().sum::<f64>() / 4094.0;
        for c in t.named.iter().filter(|c| c.kind == Some(CodeKind::Wide)) {
            assert!(((1.0 + c.dnl_lsb) - wide / lsb).abs() < 4.0 * c.sigma_lsb, "seed {seed}: {c:?} for {wide}");
        }
        // The resolution stated from the counts: 1/sqrt(E).
        assert!((t.resolution.dnl_sigma_lsb - 1.0 / per_code.sqrt()).abs() < 0.01 / per_code.sqrt() + 2e-3, "{:?}", t.resolution);
        assert!(t.resolution.sentence().contains("at 3 sigma"));
        // The worst list starts with the four wide codes, then the missing code.
        let worst: Vec<usize> = codes_of(&t.worst[..5]);
        assert_eq!(&worst[4..], &[2047]);
        // Recurrence: the four wide codes at 511 mod 1024, below the bit-9 carry.
        let r = t.structure.recurrences.iter().find(|r| r.kind == structure::Side::Wide).expect("a recurrence");
        assert_eq!((r.period, r.residue, r.codes.len(), r.repetitions, r.below_carry_into_bit), (1024, 511, 4, 4, Some(9)), "{r:?}");
    }
}

#[test]
fn an_ideal_adc_has_no_named_code_at_50_counts_in_any_of_20_seeds() {
    for (seed, per_code) in (0..20u64).zip([50.0, 100.0].into_iter().cycle()) {
        let counts = ramp_counts(&[1.0; 4096], per_code, 100 + seed);
        for density in [Density::Ramp, Density::Smooth] {
            let p = FlattenParams { fixed_low_codes: 1, ..FlattenParams::default() };
            let t = analyse(&counts, density, &p).unwrap();
            assert!(t.named.is_empty(), "seed {seed} {density:?}: {:?}", t.named);
            assert!(t.structure.fundamental_period.is_none(), "seed {seed} {density:?}: {:?}", t.structure.periods);
            assert!(!t.structure.sar.as_ref().unwrap().explains, "seed {seed} {density:?}: {:?}", t.structure.sar);
            // DNL scatters as the counts' noise says: rms of DNL/sigma near 1.
            let z: Vec<f64> = t.dnl_lsb.iter().zip(&t.dnl_sigma_lsb).map(|(d, s)| d / s).collect();
            let rms = crate::infra::stats::rms(&z);
            assert!((0.9..1.1).contains(&rms), "seed {seed} {density:?}: {rms}");
            // Independent counts: the INL scatters as its noise says (a bridge's rms over
            // its own expected rms: about 0.3 to 2 in any one draw), not far below.
            if density == Density::Ramp {
                let r = t.resolution.inl_over_noise.unwrap();
                assert!(r > SUB_POISSON && !t.resolution.sentence().contains("not independent"), "seed {seed}: {r}");
            }
        }
    }
}

#[test]
fn too_few_counts_are_refused_with_the_reason() {
    let counts = ramp_counts(&[1.0; 1024], 0.5, 1);
    let e = analyse(&counts, Density::Ramp, &FlattenParams::default()).unwrap_err();
    assert!(matches!(e, TestError::TooFewCounts { mean } if mean < 1.0), "{e}");
    assert!(e.to_string().contains("1/sqrt(counts)"), "{e}");
    // Five counts a code are analysed: nothing is named, and an empty code is listed as
    // inconclusive rather than missing (e^-5 = 0.7% for an ideal code).
    let mut counts = ramp_counts(&[1.0; 1024], 5.0, 2);
    counts[300] = 0;
    let t = analyse(&counts, Density::Ramp, &FlattenParams::default()).unwrap();
    assert!(t.missing.is_empty() && t.empty_inconclusive.iter().any(|c| c.code == 300), "{:?}", t.empty_inconclusive);
    assert!(t.resolution.missing_needs_counts > 20.0);
    assert!(matches!(analyse(&[1, 2, 3], Density::Ramp, &FlattenParams::default()), Err(TestError::Length { len: 3 })));
}

#[test]
fn dnl_and_inl_follow_their_definitions_on_exact_counts() {
    // Counts exactly proportional to known widths (10^6 a code): DNL is w / mean - 1 and
    // end-point INL the running sum, by hand.
    let n = 256;
    let w: Vec<f64> = (0..n).map(|k| 1.0 + 0.3 * ((k as f64) * 0.37).sin()).collect();
    let counts: Vec<u64> = (0..n).map(|k| (1e6 * w[k]).round() as u64).collect();
    let t = analyse(&counts, Density::Ramp, &FlattenParams::default()).unwrap();
    assert_eq!((t.first_code, t.last_code), (1, n - 2));
    let mean = (1..n - 1).map(|k| counts[k] as f64).sum::<f64>() / (n - 2) as f64;
    let mut inl = 0.0;
    for (i, k) in (1..n - 1).enumerate() {
        assert!((t.dnl_lsb[i] - (counts[k] as f64 / mean - 1.0)).abs() < 1e-12);
        assert!((t.inl_endpoint_lsb[i] - inl).abs() < 1e-9, "{k}: {} vs {inl}", t.inl_endpoint_lsb[i]);
        inl += counts[k] as f64 / mean - 1.0;
    }
    assert!(t.inl_endpoint_lsb.last().unwrap().abs() < 1e-9);
    // Best-fit INL is the end-point INL less its own least-squares line, by the normal
    // equations written out here.
    let y = &t.inl_endpoint_lsb;
    let n = y.len() as f64;
    let (sx, sy) = ((0..y.len()).map(|j| j as f64).sum::<f64>(), y.iter().sum::<f64>());
    let (sxx, sxy) = ((0..y.len()).map(|j| (j * j) as f64).sum::<f64>(), y.iter().enumerate().map(|(j, v)| j as f64 * v).sum::<f64>());
    let b = (n * sxy - sx * sy) / (n * sxx - sx * sx);
    let a = (sy - b * sx) / n;
    assert!(y.iter().enumerate().zip(&t.inl_bestfit_lsb).all(|((j, v), got)| (v - a - b * j as f64 - got).abs() < 1e-9));
}

#[test]
fn the_sine_test_reads_an_ideal_adc_flat_and_names_a_missing_code() {
    for seed in 0..4u64 {
        // About 100 counts a code in mid range (the arcsine density is pi/2 lower there
        // than its mean... and higher near the ends).
        let mut w = vec![1.0; 4096];
        let t = analyse(&sine_counts(&w, 100.0 * 4096.0 * std::f64::consts::FRAC_PI_2, seed), Density::Sine, &FlattenParams::default()).unwrap();
        assert!(t.named.is_empty(), "seed {seed}: {:?}", t.named);
        let z: Vec<f64> = t.dnl_lsb.iter().zip(&t.dnl_sigma_lsb).map(|(d, s)| d / s).collect();
        assert!((0.9..1.1).contains(&crate::infra::stats::rms(&z)), "seed {seed}: {}", crate::infra::stats::rms(&z));
        w[1023] = 0.0;
        w[1024] = 2.0;
        let t = analyse(&sine_counts(&w, 100.0 * 4096.0 * std::f64::consts::FRAC_PI_2, seed), Density::Sine, &FlattenParams::default()).unwrap();
        assert_eq!(codes_of(&t.missing), vec![1023], "seed {seed}");
        let wide: Vec<usize> = t.named.iter().filter(|c| c.kind == Some(CodeKind::Wide)).map(|c| c.code).collect();
        assert_eq!(wide, vec![1024], "seed {seed}: {:?}", t.named);
    }
}

#[test]
fn periodic_patterns_of_64_to_2048_codes_are_found_at_their_period() {
    for (i, period) in [64usize, 128, 256, 512, 1024, 2048].into_iter().enumerate() {
        // A pattern of period P, below what names single codes at 400 counts (sigma
        // 0.05): random widths of 0.1 LSB rms repeated every P codes, plus, for P up to
        // 1024, a sawtooth of 0.075 LSB rms with a step (a cubic detrend, needed against
        // slow trends, takes most of a sawtooth seen only twice); and 0.02 LSB of
        // random widths that do not repeat.
        let mut rng = rand::rngs::StdRng::seed_from_u64(i as u64);
        let normal = rand_distr::Normal::new(0.0, 1.0).unwrap();
        let repeated: Vec<f64> = (0..period).map(|_| 0.1 * normal.sample(&mut rng)).collect();
        let saw = if period <= 1024 { 0.26 } else { 0.0 };
        let w: Vec<f64> = (0..4096).map(|k| 1.0 + repeated[k % period] + saw * (((k % period) as f64 / period as f64) - 0.5) + 0.02 * normal.sample(&mut rng)).collect();
        let t = analyse(&ramp_counts(&w, 400.0, i as u64), Density::Ramp, &FlattenParams::default()).unwrap();
        assert_eq!(t.structure.fundamental_period, Some(period), "{period}: {:?}", t.structure.periods);
        let p = t.structure.periods.iter().find(|p| p.period == period).unwrap();
        let rms = if period <= 1024 { 0.125 } else { 0.1 };
        assert!(p.explained > 0.7 && (p.pattern_rms_lsb / rms - 1.0).abs() < 0.3, "{period}: {p:?}");
        // The periods below explain at most half of it (a sawtooth of period P has a
        // quarter of its variance in its even harmonics, which are of period P/2).
        assert!(t.structure.periods.iter().filter(|q| q.period < period).all(|q| q.explained < 0.5 * p.explained), "{period}: {:?}", t.structure.periods);
        assert!(t.structure.lines().iter().any(|l| l.contains(&format!("period {period} codes"))));
    }
}

#[test]
fn sar_weight_errors_are_fitted_and_named_by_bit() {
    let mut gen = rand::rngs::StdRng::seed_from_u64(1241);
    for seed in 0..8u64 {
        // One bit from 5 to 11 with a weight error of 0.5 to 1.5 LSB (or -0.5 to -0.95); the
        // others ideal; 100 counts a code.
        let bit = gen.random_range(5..12u32);
        // (Not below -1: a code cannot be narrower than nothing; a real SAR's codes then
        // overlap, which this linear model of the levels does not describe.)
        let err = if gen.random_bool(0.5) { gen.random_range(0.5..1.5) } else { -gen.random_range(0.5..0.95) };
        let weights: Vec<f64> = (0..12).map(|j| (1u64 << j) as f64 + if j == bit { err } else { 0.0 }).collect();
        let level = |k: usize| (0..12).map(|j| ((k >> j) & 1) as f64 * weights[j]).sum::<f64>();
        let w: Vec<f64> = (0..4096).map(|k| if k == 4095 { 1.0 } else { level(k + 1) - level(k) }).collect();
        let t = analyse(&ramp_counts(&w, 100.0, seed), Density::Ramp, &FlattenParams::default()).unwrap();
        let sar = t.structure.sar.as_ref().unwrap();
        let named: Vec<u32> = sar.named_bits().iter().map(|c| c.bit).collect();
        assert_eq!(named, vec![bit], "seed {seed} bit {bit} err {err}: {:?}", sar.carries);
        let c = sar.carries.iter().find(|c| c.bit == bit).unwrap();
        assert_eq!(c.codes, 1 << (11 - bit));
        // The codes below the carry are err wider (on the mean width's scale, err / 4094
        // less), and the weight error attributed to the bit is err.
        assert!((c.dnl_lsb - err).abs() < 4.0 * c.sigma_lsb + 0.01, "seed {seed}: {c:?} for {err}");
        assert!((c.weight_error_lsb - err).abs() < 4.0 * c.weight_sigma_lsb + 0.01, "seed {seed}: {c:?} for {err}");
        if bit < 11 {
            // A depth of two or more codes is held out, and explains the DNL beyond noise.
            assert!(sar.explains && c.halves_z.unwrap() > 5.0, "seed {seed} bit {bit} err {err}: {sar:?}");
            assert!(t.structure.headline().unwrap().contains(&format!("bit-{bit} weight error")), "{:?}", t.structure.headline());
        } else {
            // The MSB's one code cannot be held out: it is named as a code.
            assert!(!sar.explains, "{sar:?}");
            assert!(t.named.iter().any(|c| c.code == 2047), "{:?}", t.named);
        }
    }
}

/// Independent code widths (uniform in 0.5..1.5 LSB, sd 0.29) give a SAR nothing to
/// explain and no period, at 12 and 16 bits and 100 counts a code: the widths' spread
/// is in every depth's and class's mean (at 16 bits two codes, 0.5 LSB off the mean by
/// chance, were named a bit-14 weight error at 5.6 sigma and "explained" the DNL). A
/// SAR planted under the same spread is still named: the spread is the null, not a
/// blindfold.
#[test]
fn independent_code_widths_are_no_sar_and_no_period() {
    for (bits, seeds) in [(12u32, 0..6u64), (16, 0..4)] {
        for seed in seeds {
            let mut rng = rand::rngs::StdRng::seed_from_u64(900 + seed);
            let n = 1usize << bits;
            let w: Vec<f64> = (0..n).map(|_| rng.random_range(0.5..1.5)).collect();
            let t = analyse(&ramp_counts(&w, 100.0, seed), Density::Ramp, &FlattenParams::default()).unwrap();
            let sar = t.structure.sar.as_ref().unwrap();
            assert!(!sar.explains && sar.named_bits().is_empty(), "{bits} bits, seed {seed}: {:?}", sar.named_bits());
            assert_eq!(t.structure.fundamental_period, None, "{bits} bits, seed {seed}");
            let worst = t.structure.periods.iter().map(|p| p.z).fold(f64::NEG_INFINITY, f64::max);
            assert!(worst < 8.0, "{bits} bits, seed {seed}: period z {worst}");
        }
    }
    // Bit 9 of a 12-bit SAR 3 LSB heavy, under the same independent widths.
    let mut rng = rand::rngs::StdRng::seed_from_u64(77);
    let weights: Vec<f64> = (0..12).map(|j| (1u64 << j) as f64 + if j == 9 { 3.0 } else { 0.0 }).collect();
    let level = |k: usize| (0..12).map(|j| ((k >> j) & 1) as f64 * weights[j]).sum::<f64>();
    let w: Vec<f64> = (0..4096).map(|k| if k == 4095 { 1.0 } else { (level(k + 1) - level(k)) * rng.random_range(0.75..1.25) }).collect();
    let t = analyse(&ramp_counts(&w, 400.0, 5), Density::Ramp, &FlattenParams::default()).unwrap();
    let sar = t.structure.sar.as_ref().unwrap();
    assert!(sar.explains, "{:?}", sar.carries);
    assert_eq!(sar.named_bits().iter().map(|c| c.bit).collect::<Vec<_>>(), vec![9], "{:?}", sar.carries);
}

#[test]
fn counts_of_a_stepped_ramp_are_told_from_independent_ones() {
    // A staircase of 8 samples a code, sampled once a step: each code's count is its
    // width over the step, rounded by where its edges fall, never a Poisson draw.
    let widths: Vec<f64> = (0..1024).map(|k| 1.0 + 0.2 * ((k as f64) * 0.7).sin()).collect();
    let mut edges = vec![0.0];
    for w in &widths[..1023] {
        edges.push(edges.last().unwrap() + w);
    }
    let counts: Vec<u64> = (0..1024).map(|k| if k == 1023 { 10 } else { ((edges[k + 1] * 8.0).floor() - (edges[k] * 8.0).floor()) as u64 }).collect();
    let t = analyse(&counts, Density::Ramp, &FlattenParams::default()).unwrap();
    let r = t.resolution.inl_over_noise.unwrap();
    assert!(r < SUB_POISSON, "{r}");
    assert!(t.resolution.sentence().contains("not independent"), "{}", t.resolution.sentence());
}
