//! `dncal quantization`: the bias of averaged readouts (paper section 2) for a noise
//! level, the noise a bias target needs, and the paper's Fig. 1.

use std::path::Path;

use rand::SeedableRng;
use serde::Serialize;

use crate::outputs::Outputs;
use crate::plots::{map_plot, Map};
use crate::quantization::{bias_erf, bias_exact_gaussian, bias_fourier, bias_map, bias_monte_carlo, sigma_for_bias, worst_bias, WorstBias};
use crate::HostError;

/// The worst case at one noise level, checked three ways at the worst `lambda'`.
#[derive(Debug, Clone, Serialize)]
pub struct SigmaReport {
    /// Noise rms, DN.
    pub sigma: f64,
    /// max over lambda' of |delta|, DN (the Fourier series from sigma = 0.3 DN, eq. 4 below).
    pub max_abs_bias_dn: f64,
    /// Where, lambda' in [0, 1).
    pub at_lambda_frac: f64,
    /// delta at that lambda' from eq. 4 (signed), DN.
    pub erf_bias_dn: f64,
    /// delta from the Fourier series at that lambda' (signed), DN.
    pub fourier_bias_dn: f64,
    /// delta from the exact sum of eq. 1-2 at lambda = 2048 + lambda' on a 12-bit ADC, DN.
    pub exact_bias_dn: f64,
    /// The Monte Carlo estimate at the same lambda, DN.
    pub monte_carlo_bias_dn: f64,
    /// Its standard error, DN.
    pub monte_carlo_se_dn: f64,
    /// Readouts averaged.
    pub monte_carlo_samples: u64,
}

/// The worst case at `sigma` DN, with a Monte Carlo check of `samples` readouts.
pub fn at_sigma(sigma: f64, samples: u64, seed: u64) -> Result<SigmaReport, HostError> {
    if !(sigma.is_finite() && sigma >= 0.0) {
        return Err(HostError::Argument { flag: "--sigma".into(), message: format!("noise rms {sigma} DN must be finite and >= 0") });
    }
    let WorstBias { max_abs_bias_dn, at_lambda_frac, .. } = worst_bias(sigma);
    let lambda = 2048.0 + at_lambda_frac;
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let (mc, se) = bias_monte_carlo(lambda, sigma, 4096, samples, &mut rng);
    Ok(SigmaReport {
        sigma,
        max_abs_bias_dn,
        at_lambda_frac,
        erf_bias_dn: bias_erf(at_lambda_frac, sigma),
        fourier_bias_dn: bias_fourier(at_lambda_frac, sigma),
        exact_bias_dn: bias_exact_gaussian(lambda, sigma, 4096),
        monte_carlo_bias_dn: mc,
        monte_carlo_se_dn: se,
        monte_carlo_samples: samples,
    })
}

/// The noise a bias target needs.
#[derive(Debug, Clone, Serialize)]
pub struct BiasReport {
    /// Target worst-case |delta|, DN.
    pub bias: f64,
    /// The smallest noise rms that meets it, DN.
    pub sigma: f64,
}

/// The smallest noise rms (DN) whose worst-case bias is at most `bias` DN.
pub fn for_bias(bias: f64) -> Result<BiasReport, HostError> {
    let sigma = sigma_for_bias(bias)
        .ok_or_else(|| HostError::Argument { flag: "--bias".into(), message: format!("no noise level gives a worst-case bias of at most {bias} DN (it must be > 0)") })?;
    Ok(BiasReport { bias, sigma })
}

/// The paper's Fig. 1: |delta| over lambda' in [0, 1] and sigma in [0, 1] DN, contours at
/// 1e-1 to 1e-4 DN, staged in `files` as `path`.
pub fn figure(files: &mut Outputs, path: &Path) -> Result<(), HostError> {
    let values = bias_map(201, 201, 1.0);
    map_plot(
        files,
        path,
        &Map {
            title: "Quantization bias of the averaged readout |delta| (DN)",
            x_label: "lambda' = lambda mod 1 (DN)",
            y_label: "noise sigma (DN)",
            values: &values,
            x_range: (0.0, 1.0),
            y_range: (0.0, 1.0),
            scale_label: "|delta| (DN), log scale",
            log: true,
            contours: &[1e-1, 1e-2, 1e-3, 1e-4],
            range: None,
        },
    )
}
