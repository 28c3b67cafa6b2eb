//! Histogram sets.
//!
//! The baseline is an ideal ADC: under any illumination that is smooth on the scale of a
//! few codes, the expected count of code k is the smooth density times the code's width 1.
//! The data are split by binomial thinning: each recorded count `c_k` is divided into
//! `A_k ~ Binomial(c_k, 1/2)` and `B_k = c_k - A_k`, two *independent* Poisson histograms
//! of the same expectation. Every model is fitted on A and scored on B.
//!
//! - **baseline** (ideal ADC): the paper's flattening of A ([`crate::flatten`]) gives the
//!   smooth density `S_k` (the 50-point spline) and its slow correction (the 21-code running
//!   median `med_k`); the prediction is `E0_k = s S_k med_k` with `s = sum B / sum A`, and
//!   the normalized residual `z0_k = (B_k - E0_k) / sqrt(E0_k (1 + s pi / (2 w)))`: B's
//!   Poisson noise plus that of the running median of A (the median of `w` samples has
//!   `pi / (2 w)` of their variance; the spline's is negligible). Without that term clean
//!   data scored 1.035 instead of 1.
//! - **`adc-dnl`** (code widths differ from uniform): the widths are A's flattened
//!   histogram, `w_k = A_k / (S_k med_k)`, so `E1_k = s A_k`; its variance adds A's Poisson
//!   noise: `z1_k = (B_k - s A_k) / sqrt(s A_k (1 + s))`.
//!
//! With `N` scored codes and a correct model `mean z^2` is 1 with standard deviation
//! `sqrt(2/N)`. A finding's *significance* is `(mean z0^2 - mean z1^2) / sqrt(2/N)`; it is
//! accepted above 5 when it also lowers the held-out RMS. What remains is `unexplained`
//! when its `mean z^2` exceeds 1 by more than 5 `sqrt(2/N)`.
//!
//! Where the structure sits is reported for the baseline residual: by code residue mod
//! 2, 4, ..., 512 (the periods of pipelined-ADC stages), as `chi^2` per residue class of
//! the class means of `z0` (1 for noise).

use rand::SeedableRng;
use rand_distr::{Binomial, Distribution};

use super::*;
use crate::fits::AdcHistograms;
use crate::flatten::{flatten_histogram, FlattenParams};

/// Diagnoses a histogram set; `seed` drives the binomial split.
pub fn diagnose_histograms(h: &AdcHistograms, flatten: &FlattenParams, seed: u64) -> Result<Diagnosis, DiagnoseError> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mut adcs = Vec::new();
    let mut findings = Vec::new();
    let mut residuals = Vec::new();
    let (mut all0, mut all_final) = (Vec::new(), Vec::new());
    // Per ADC the sums of the held-out z^2 without and with its code widths.
    let mut dnl_steps = Vec::new();
    for (adc, counts) in h.counts.iter().enumerate() {
        let a: Vec<u64> = counts.iter().map(|&c| if c == 0 { 0 } else { Binomial::new(c, 0.5).map(|d| d.sample(&mut rng)).unwrap_or(c / 2) }).collect();
        let b: Vec<u64> = counts.iter().zip(&a).map(|(c, a)| c - a).collect();
        let trimmed = trimmed_params(flatten);
        let f = flatten_histogram(&a, &trimmed).map_err(|source| DiagnoseError::Flatten { adc, source })?;
        // Scored codes: fitted, with a usable smooth expectation, and away from the ends
        // of the fit by a median window plus a knot interval, where the smooth fit cannot
        // follow the edges of the illumination (that is not the ADC's doing).
        let fit = &f.fit_codes;
        let margin = trimmed.median_window + (fit.end - fit.start) / trimmed.spline_points.saturating_sub(3).max(1);
        let codes: Vec<usize> = (fit.start + margin..fit.end.saturating_sub(margin))
            .filter(|&k| f.normalized[k].is_finite() && f.normalized[k] > 0.0 && a[k] > 0 && f.spline[k] > 20.0)
            .collect();
        if codes.len() < 16 {
            return Err(DiagnoseError::TooFewCodes { adc, codes: codes.len() });
        }
        let sa: f64 = codes.iter().map(|&k| a[k] as f64).sum();
        let sb: f64 = codes.iter().map(|&k| b[k] as f64).sum();
        let s = sb / sa;
        // The running median of A's noisy quotient carries noise of its own: the variance of
        // the median of w samples is (pi / 2) / w of theirs (large-w limit).
        let median_var = std::f64::consts::FRAC_PI_2 / trimmed.median_window.max(1) as f64;
        let z0: Vec<f64> = codes
            .iter()
            .map(|&k| {
                let e0 = s * a[k] as f64 / f.normalized[k];
                (b[k] as f64 - e0) / (e0 * (1.0 + s * median_var)).sqrt()
            })
            .collect();
        let z1: Vec<f64> = codes
            .iter()
            .map(|&k| {
                let e1 = s * a[k] as f64;
                (b[k] as f64 - e1) / (e1 * (1.0 + s)).sqrt()
            })
            .collect();
        let n = codes.len() as f64;
        let sd = (2.0 / n).sqrt();
        let (m0, m1) = (mean_sq(&z0), mean_sq(&z1));
        let structure = by_residue(&codes, &z0);
        adcs.push(AdcBaseline { adc, codes_scored: codes.len(), rms: m0.sqrt(), by_residue: structure.clone() });
        let significance = (m0 - m1) / sd;
        let accepted = significance > SIGNIFICANCE && m1 < m0;
        let z_final = if accepted { &z1 } else { &z0 };
        if accepted {
            let widths: Vec<f64> = codes.iter().map(|&k| f.normalized[k] - 1.0).collect();
            let top = &structure[0];
            findings.push(Finding {
                residuals: Some(AdcResiduals::over(&codes, &z0, &z1)),
                effect: Effect::AdcDnl,
                adc: Some(adc),
                count: None,
                sigma_dn: None,
                significance,
                rms_before: m0.sqrt(),
                rms_after: m1.sqrt(),
                gain: (m0 / m1).sqrt(),
                // Filled in below, once every ADC's baseline is scored.
                all_data_rms_after: None,
                detail: format!(
                    "code widths differ from uniform by {:.2}% rms over {} codes (fitted on one half of the counts, scored on the other); strongest residue structure mod {} (chi^2 {:.1} per class)",
                    100.0 * (mean_sq(&widths)).sqrt(),
                    codes.len(),
                    top.modulus,
                    top.chi2_per_class
                ),
            });
        }
        findings.extend(unexplained_by_residue(adc, &codes, z_final, ""));
        dnl_steps.push((m0 * n, m1 * n));
        all0.extend_from_slice(&z0);
        all_final.extend_from_slice(z_final);
        residuals.push(AdcResiduals::over(&codes, &z0, z_final));
    }
    // On the all-data scale the findings replace, in their order, one ADC's baseline sum by
    // its sum with the code widths.
    let mut sum: f64 = dnl_steps.iter().map(|s| s.0).sum();
    for f in findings.iter_mut().filter(|f| f.effect == Effect::AdcDnl) {
        let (before, after) = f.adc.map_or((0.0, 0.0), |a| dnl_steps[a]);
        sum += after - before;
        f.all_data_rms_after = Some((sum / all0.len().max(1) as f64).sqrt());
    }
    Ok(Diagnosis {
        not_tested: Vec::new(),
        measured: Measured::default(),
        code_density: None,
        code_residuals: None,
        curve_per_dn: None,
        baseline: Baseline { kind: "histogram-set".into(), model: "ideal ADC, illumination smooth over a few codes, Poisson counts".into(), adcs, rms: mean_sq(&all0).sqrt() },
        findings,
        unexplained_rms: mean_sq(&all_final).sqrt(),
        residuals,
        block_rows: None,
        records_spilled: false,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::exact::phi;
    use crate::camera::{AdcConfig, PipelinedAdc};
    use rand::Rng;
    use rand_distr::Poisson;

    /// CDF of a uniform density on [a, b] blurred by a Gaussian of rms s (an illumination
    /// ramp seen through noise): smooth on the scale of codes.
    fn ramp_cdf(v: f64, a: f64, b: f64, s: f64) -> f64 {
        let g = |x: f64| x * phi(x / s) + s * (-(x * x) / (2.0 * s * s)).exp() / (2.0 * std::f64::consts::PI).sqrt();
        (g(v - a) - g(v - b)) / (b - a)
    }

    /// Measured histograms of `adcs` under the ramp, `per_code` expected counts per code.
    fn measure(adcs: &[PipelinedAdc], per_code: f64, seed: u64) -> AdcHistograms {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let codes = adcs[0].codes();
        let (a, b, s) = (100.0, codes as f64 - 60.0, 8.0);
        let total = per_code * (b - a);
        let counts = adcs
            .iter()
            .map(|adc| {
                (0..codes)
                    .map(|k| {
                        let lo = if k == 0 { 0.0 } else { ramp_cdf(adc.level(k), a, b, s) };
                        let hi = if k == codes - 1 { 1.0 } else { ramp_cdf(adc.level(k + 1), a, b, s) };
                        let lambda = total * (hi - lo).max(0.0);
                        if lambda > 0.0 { Poisson::new(lambda).map(|d| d.sample(&mut rng) as u64).unwrap_or(0) } else { 0 }
                    })
                    .collect()
            })
            .collect();
        AdcHistograms { bit_depth: codes.trailing_zeros(), counts }
    }

    fn params(bits: u32) -> FlattenParams {
        FlattenParams { fixed_low_codes: 150 >> (12 - bits), ..FlattenParams::default() }
    }

    #[test]
    fn clean_histograms_give_no_finding_in_19_of_20_seeds() {
        let ideal: Vec<PipelinedAdc> = (0..4).map(|_| PipelinedAdc::ideal(10)).collect();
        let mut false_alarms = 0;
        for seed in 0..20 {
            let h = measure(&ideal, 20_000.0, seed);
            let d = diagnose_histograms(&h, &params(10), seed).unwrap();
            if !d.findings.is_empty() {
                false_alarms += 1;
                eprintln!("seed {seed}: {:?}", d.findings);
            }
            assert!((d.baseline.rms - 1.0).abs() < 0.1, "seed {seed}: baseline rms {}", d.baseline.rms);
        }
        assert!(false_alarms <= 1, "{false_alarms} of 20 clean seeds gave findings");
    }

    #[test]
    fn a_hidden_dnl_is_named_on_its_adc_only() {
        // A seeded generator hides stage-mismatch DNL in one random ADC, at a random
        // amplitude a careful scientist would see: stage errors of 0.025 to 0.1 LSB give
        // code widths of about 0.75% to 5% rms (measured for these stage sizes), against
        // 2e4 counts per code (0.7% Poisson noise per code, 1% per half).
        let mut gen = rand::rngs::StdRng::seed_from_u64(5);
        for seed in 0..24u64 {
            let hidden = gen.random_range(0..4usize);
            let amp = gen.random_range(0.025..0.1);
            let cfg = AdcConfig { stage_bits: vec![4, 3, 3], stage_error_lsb: vec![amp, amp / 2.0, amp / 4.0], seed: 1000 + seed, ..Default::default() };
            let adcs: Vec<PipelinedAdc> = (0..4).map(|i| if i == hidden { PipelinedAdc::from_config(&cfg, 10, i).unwrap() } else { PipelinedAdc::ideal(10) }).collect();
            let h = measure(&adcs, 20_000.0, seed);
            let d = diagnose_histograms(&h, &params(10), seed).unwrap();
            let named: Vec<(String, Option<usize>)> = d.findings.iter().map(|f| (f.effect.to_string(), f.adc)).collect();
            assert_eq!(named, vec![("adc-dnl".to_string(), Some(hidden))], "seed {seed} (amp {amp}): {:?}", d.findings);
            let f = &d.findings[0];
            assert!(f.gain > 1.2, "seed {seed}: gain {}", f.gain);
            assert!((f.rms_after - 1.0).abs() < 0.1, "seed {seed}: after {}", f.rms_after);
            // On all the data (the four ADCs' held-out codes, recounted from the figures'
            // residuals): the hidden ADC's codes under the widths, the others' baseline.
            let sq = |pick: &dyn Fn(&AdcResiduals) -> &Vec<(usize, f64)>| d.residuals.iter().flat_map(|r| pick(r).iter().map(|p| p.1 * p.1)).collect::<Vec<f64>>();
            let (before, after) = (sq(&|r| &r.baseline), sq(&|r| &r.extended));
            let rms = |v: &[f64]| (v.iter().sum::<f64>() / v.len() as f64).sqrt();
            let all = f.all_data_rms_after.unwrap();
            assert!((all - rms(&after)).abs() < 1e-12 && (d.baseline.rms - rms(&before)).abs() < 1e-12, "seed {seed}: {all} after, {} before", d.baseline.rms);
            assert!(all < d.baseline.rms && (all - d.unexplained_rms).abs() < 1e-12, "seed {seed}: {all}");
        }
    }
}
