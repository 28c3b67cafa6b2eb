//! A code-density test of one ADC from frames taken under *lumpy* illumination: the code
//! histogram of all the frames of a photon-transfer set (each level a peak a few DN to a
//! few tens of DN wide, gaps between the levels).
//!
//! The histogram sets' flattening ([`crate::flatten`]: a 50-point spline and a 21-code
//! running median) assumes a density smooth over tens of codes, which peaks of 6 DN rms
//! are not. Here the smooth density at code k is a local polynomial (Savitzky-Golay:
//! degree [`DEGREE`] over `k +- HALF` codes) of the counts, which follows such peaks
//! while averaging a code-to-code pattern over 2 HALF + 1 codes.
//!
//! Held out as for histogram sets: the counts are split by binomial thinning into two
//! independent Poisson halves A and B of the same expectation.
//! - **baseline** (ideal ADC): `E0_k = s sum_j L_j A_(k+j)`, variance
//!   `E0_k + s^2 sum_j L_j^2 A_(k+j)` (B's Poisson noise and the smoother's).
//! - **`adc-dnl`**: the widths are A's counts over the smooth density, so `E1_k = s A_k`,
//!   variance `s A_k (1 + s)`.
//!
//! Scored: codes whose whole window has at least 20 counts in A (peaks, not gaps) that
//! vary by less than a factor [`MAX_SPAN`] (a peak the quartic can follow), away from
//! code 0 and the top code. Accepted when `(mean z0^2 - mean z1^2) / sqrt(2/N) > 5`.
//! The widths are reported by code residue (mod 2 to 512), the periods of ADC structure.

use rand::SeedableRng;
use rand_distr::{Binomial, Distribution};

use super::*;

/// Degree of the local polynomial.
pub const DEGREE: usize = 4;
/// Half window of the local polynomial, codes.
pub const HALF: usize = 8;
/// The largest ratio of counts across a scored code's window.
pub const MAX_SPAN: f64 = 4.0;

/// What the code-density test measured.
#[derive(Debug, Clone, Serialize)]
pub struct CodeDensity {
    /// Codes scored.
    pub codes_scored: usize,
    /// Held-out RMS of the normalized residual, ideal ADC.
    pub rms_baseline: f64,
    /// Held-out RMS with the measured code widths.
    pub rms_widths: f64,
    /// RMS of the widths' departure from 1 (relative): the class pattern's and the
    /// code-to-code spread beyond it, the counts' Poisson noise taken out.
    pub width_rms: f64,
    /// Structure of the baseline residual by code residue, strongest first.
    pub by_residue: Vec<ResidueStructure>,
    /// Width of each class `k mod m` for the strongest modulus up to 16 (the mean measured
    /// ratio unfolded from the smoother's share of the pattern, mean 1).
    pub class_widths: Vec<f64>,
    /// Every code's width (for the model file): the class width of the strongest period,
    /// plus where scored the code's own departure, shrunk by its noise.
    #[serde(skip)]
    pub widths: Vec<f64>,
}

/// The Savitzky-Golay weights `L_j`, j = -HALF..=HALF: the value at 0 of the least-squares
/// polynomial of degree [`DEGREE`] through the window.
fn smoothing_weights() -> Vec<f64> {
    let n = 2 * HALF + 1;
    let x = nalgebra::DMatrix::from_fn(n, DEGREE + 1, |r, c| (r as f64 - HALF as f64).powi(c as i32));
    let pinv = (x.transpose() * &x).try_inverse().expect("a Vandermonde matrix of distinct points") * x.transpose();
    pinv.row(0).iter().copied().collect()
}

/// The widths of a pattern of period `m = ratios.len()` from the mean measured ratios
/// `r_c = A_k / smooth_k` of each class: the smoother's window holds the pattern too
/// (17 codes are not a whole number of periods), so `smooth_k` carries
/// `sum_d Lt_d w_(c+d)` of it, `Lt_d` the weights summed per residue `d`. Solved for `w`
/// by fixed-point iteration, `w_c = r_c sum_d Lt_d w_(c+d)`, normalized to mean 1.
/// Without this the real CCD's period-4 widths read 1.038 1.059 0.994 0.918.
fn unfold_period(ratios: &[f64], l: &[f64]) -> Vec<f64> {
    let m = ratios.len();
    let mut lt = vec![0.0; m];
    for (j, w) in l.iter().enumerate() {
        lt[(j + m * HALF - HALF) % m] += w;
    }
    let mut w = ratios.to_vec();
    for _ in 0..200 {
        let mut next: Vec<f64> = (0..m).map(|c| ratios[c] * (0..m).map(|d| lt[d] * w[(c + d) % m]).sum::<f64>()).collect();
        let mean = next.iter().sum::<f64>() / m as f64;
        next.iter_mut().for_each(|v| *v /= mean);
        let change = next.iter().zip(&w).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        w = next;
        if change < 1e-12 {
            break;
        }
    }
    w
}

/// The test on `counts` (one ADC's code histogram); `seed` drives the split.
pub fn diagnose_code_density(counts: &[u64], adc: usize, seed: u64) -> Result<(Vec<Finding>, AdcResiduals, CodeDensity), String> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let a: Vec<u64> = counts.iter().map(|&c| if c == 0 { 0 } else { Binomial::new(c, 0.5).map(|d| d.sample(&mut rng)).unwrap_or(c / 2) }).collect();
    let b: Vec<u64> = counts.iter().zip(&a).map(|(c, a)| c - a).collect();
    let l = smoothing_weights();
    let top = counts.len().saturating_sub(1);
    // Inside the peaks, and only where the density changes by less than a factor
    // [`MAX_SPAN`] across the window: a quartic cannot follow a peak much narrower than
    // the window (the real CCD's dark peak, 3 DN rms, left residuals of 150 sigma).
    let codes: Vec<usize> = (HALF + 1..top.saturating_sub(HALF))
        .filter(|&k| {
            let w = &a[k - HALF..=k + HALF];
            let (lo, hi) = (w.iter().min().copied().unwrap_or(0), w.iter().max().copied().unwrap_or(0));
            lo >= 20 && (hi as f64) <= MAX_SPAN * lo as f64
        })
        .collect();
    if codes.len() < 64 {
        return Err(format!("only {} codes lie inside illuminated peaks with 20 or more counts; the code-density test needs 64", codes.len()));
    }
    let smooth = |k: usize| -> (f64, f64) {
        (0..l.len()).fold((0.0, 0.0), |(v, var), j| {
            let c = a[k + j - HALF] as f64;
            (v + l[j] * c, var + l[j] * l[j] * c)
        })
    };
    let sa: f64 = codes.iter().map(|&k| a[k] as f64).sum();
    let sb: f64 = codes.iter().map(|&k| b[k] as f64).sum();
    let s = sb / sa;
    let (mut z0, mut z1, mut widths, mut noise) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for &k in &codes {
        let (m, var_m) = smooth(k);
        let e0 = (s * m).max(1e-9);
        z0.push((b[k] as f64 - e0) / (e0 + s * s * var_m).sqrt());
        let e1 = s * a[k] as f64;
        z1.push((b[k] as f64 - e1) / (e1 * (1.0 + s)).sqrt());
        widths.push(a[k] as f64 / m.max(1e-9));
        // The Poisson variance of that ratio: the smooth density holds the code's own count
        // with weight `L_0` (and `sum L_j^2 = L_0`), which takes that share of the noise
        // and of a width of the code's own.
        noise.push((1.0 - l[HALF]) * a[k] as f64 / (m * m).max(1e-18));
    }
    let n = codes.len() as f64;
    let sd = (2.0 / n).sqrt();
    let (m0, m1) = (mean_sq(&z0), mean_sq(&z1));
    let structure = by_residue(&codes, &z0);
    let strongest = structure.iter().find(|r| r.modulus <= 16).map_or(4, |r| r.modulus);
    let ratios: Vec<f64> = (0..strongest)
        .map(|c| {
            let v: Vec<f64> = codes.iter().zip(&widths).filter(|(k, _)| *k % strongest == c).map(|(_, w)| *w).collect();
            v.iter().sum::<f64>() / v.len().max(1) as f64
        })
        .collect();
    let class_widths = unfold_period(&ratios, &l);
    // Each measured width carries its count's Poisson noise (1.9% rms for an ideal ADC at
    // the tests' counts, all of it in the model file before this): the spread beyond the
    // class pattern and the noise is `tau^2`, each code's width is shrunk toward its
    // class's by `tau^2 / (tau^2 + var)` (empirical Bayes), and the rms reported is the
    // pattern's and `tau`'s, the noise taken out.
    let own = 1.0 - l[HALF];
    let off = |j: usize, k: usize| widths[j] - ratios[k % strongest];
    let tau2 = (codes.iter().enumerate().map(|(j, &k)| off(j, k).powi(2) - noise[j]).sum::<f64>() / n).max(0.0) / own;
    // The class means carry the noise of their codes too.
    let class_noise = (0..strongest)
        .map(|c| {
            let v: Vec<f64> = codes.iter().zip(&noise).filter(|(k, _)| *k % strongest == c).map(|(_, v)| *v / own).collect();
            v.iter().sum::<f64>() / (v.len() as f64).powi(2).max(1.0)
        })
        .sum::<f64>()
        / strongest as f64;
    let pattern2 = ((0..counts.len()).map(|k| (class_widths[k % strongest] - 1.0).powi(2)).sum::<f64>() / counts.len().max(1) as f64 - class_noise).max(0.0);
    let width_rms = (pattern2 + tau2).sqrt();
    let mut all_widths: Vec<f64> = (0..counts.len()).map(|k| class_widths[k % strongest]).collect();
    for (j, &k) in codes.iter().enumerate() {
        all_widths[k] = (class_widths[k % strongest] + tau2 / (tau2 + noise[j] / own).max(1e-300) * off(j, k)).max(1e-6);
    }
    let mut findings = Vec::new();
    let significance = (m0 - m1) / sd;
    let accepted = significance > SIGNIFICANCE && m1 < m0;
    if accepted {
        findings.push(Finding {
            residuals: Some(AdcResiduals::over(&codes, &z0, &z1)),
            effect: "adc-dnl".into(),
            adc: Some(adc),
            count: None,
            sigma_dn: None,
            significance,
            rms_before: m0.sqrt(),
            rms_after: m1.sqrt(),
            gain: (m0 / m1).sqrt(),
            detail: format!(
                "code density of all frames: widths differ from uniform by {:.2}% rms ({:.2}% the pattern by code mod {strongest}, {:.2}% code to code beyond it; the counts' Poisson noise taken out) over {} codes inside the illuminated peaks (fitted on one binomial half of the counts, scored on the other); strongest structure mod {} (chi^2 {:.1} per class), mean widths by code mod {strongest}: {}",
                100.0 * width_rms,
                100.0 * pattern2.sqrt(),
                100.0 * tau2.sqrt(),
                codes.len(),
                structure[0].modulus,
                structure[0].chi2_per_class,
                class_widths.iter().map(|w| format!("{w:.3}")).collect::<Vec<_>>().join(" ")
            ),
        });
    }
    let z_final = if accepted { &z1 } else { &z0 };
    findings.extend(unexplained_by_residue(adc, &codes, z_final, "code density: "));
    let residuals = AdcResiduals::over(&codes, &z0, z_final);
    Ok((findings, residuals, CodeDensity { codes_scored: codes.len(), rms_baseline: m0.sqrt(), rms_widths: m1.sqrt(), width_rms, by_residue: structure, widths: all_widths, class_widths }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::exact::phi;
    use rand::Rng;
    use rand_distr::Poisson;

    /// A photon-transfer set's code histogram: 50 levels from 60 to 3900 DN, each a
    /// Gaussian peak of the read noise (3 DN), shot noise (K = 0.25 DN/e-) and a 1% PRNU
    /// spread, 600,000 samples per level (two 640 x 480 frames), through an ADC of code
    /// widths `widths` (transition into code k at `-1/2 + sum_(j<k) w_j`).
    fn lumpy(widths: &[f64], seed: u64) -> Vec<u64> {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let mut edge = vec![f64::NEG_INFINITY];
        let mut t = -0.5;
        for w in &widths[..widths.len() - 1] {
            t += w;
            edge.push(t);
        }
        edge.push(f64::INFINITY);
        let levels: Vec<(f64, f64)> = (0..50)
            .map(|i| {
                let mu = 60.0 + 3840.0 * (i as f64 / 49.0).powf(1.3);
                (mu, (9.0 + 0.25 * mu + (0.01 * mu).powi(2)).sqrt())
            })
            .collect();
        (0..widths.len())
            .map(|k| {
                let p: f64 = levels.iter().map(|&(mu, s)| phi((edge[k + 1] - mu) / s) - phi((edge[k] - mu) / s)).sum();
                let lambda = 600_000.0 * p;
                if lambda > 0.0 { Poisson::new(lambda).map(|d| d.sample(&mut rng) as u64).unwrap_or(0) } else { 0 }
            })
            .collect()
    }

    #[test]
    fn an_ideal_adc_under_lumpy_light_gives_no_finding_in_19_of_20_seeds() {
        let mut alarms = 0;
        for seed in 0..20 {
            let (f, _, cd) = diagnose_code_density(&lumpy(&[1.0; 4096], seed), 0, seed).unwrap();
            if !f.is_empty() {
                alarms += 1;
                eprintln!("seed {seed}: {f:?}");
            }
            assert!((cd.rms_baseline - 1.0).abs() < 0.05, "seed {seed}: {}", cd.rms_baseline);
            // The widths for the model: no Poisson noise passed for DN error (1.9% rms
            // before the noise was taken out; the strongest period picked from noise
            // leaves up to 0.9% in the reported rms).
            let rms = (cd.widths.iter().map(|w| (w - 1.0).powi(2)).sum::<f64>() / cd.widths.len() as f64).sqrt();
            assert!(cd.width_rms < 0.01 && rms < 0.006, "seed {seed}: width rms {} reported, {rms} in the model", cd.width_rms);
        }
        assert!(alarms <= 1, "{alarms} alarms");
    }

    #[test]
    fn a_hidden_periodic_dnl_is_named_with_its_period_and_widths() {
        let mut gen = rand::rngs::StdRng::seed_from_u64(3);
        for seed in 0..10u64 {
            // A pattern of period 4 (as the real CCD shows) of 1% to 4% amplitude, plus
            // 1% random widths.
            let amp = gen.random_range(0.01..0.04);
            let pattern = [1.0 + amp, 1.0 + amp / 2.0, 1.0 - amp / 2.0, 1.0 - amp];
            let normal = rand_distr::Normal::new(0.0, 0.01).unwrap();
            let widths: Vec<f64> = (0..4096).map(|k| pattern[k % 4] + normal.sample(&mut gen)).collect();
            let (f, _, cd) = diagnose_code_density(&lumpy(&widths, seed), 0, seed).unwrap();
            assert_eq!(f.len(), 1, "seed {seed}, amp {amp}: {f:?}");
            assert_eq!((f[0].effect.as_str(), f[0].adc), ("adc-dnl", Some(0)));
            assert!(f[0].gain > 1.1 && (f[0].rms_after - 1.0).abs() < 0.1, "{:?}", f[0]);
            assert_eq!(cd.class_widths.len() % 4, 0, "{cd:?}");
            // Pattern rms 0.79 amp, and the 1% random widths.
            let truth = ((0.790569 * amp).powi(2) + 1e-4).sqrt();
            assert!((cd.width_rms / truth - 1.0).abs() < 0.15, "seed {seed}: width rms {} for {truth}", cd.width_rms);
            for (c, w) in cd.class_widths.iter().enumerate() {
                assert!((w - pattern[c % 4]).abs() < 0.1 * amp + 0.003, "seed {seed}: class {c} width {w} vs {}", pattern[c % 4]);
            }
        }
    }
}
