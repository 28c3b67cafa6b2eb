//! `dncal quantization`: the bias of averaged readouts (paper section 2) for a noise
//! level, the noise a bias target needs, and the paper's Fig. 1.

use std::path::{Path, PathBuf};

use rand::SeedableRng;
use serde::Serialize;

use crate::formats::report::{wrote, Report};
use crate::formats::outputs::Outputs;
use crate::formats::plots::{map_plot, Map};
use crate::analyses::quantization::{bias_erf, bias_exact_gaussian, bias_fourier, bias_map, bias_monte_carlo, sigma_for_bias, worst_bias, WorstBias};
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

/// What `dncal quantization` was asked: a noise level (directly, or as read noise and
/// gain), a bias target, a figure, or any of them together.
#[derive(Debug, Clone, Default)]
pub struct Request {
    /// Noise rms, DN.
    pub sigma: Option<f64>,
    /// Read noise, e- (with `gain_e_per_dn`, instead of `sigma`).
    pub read_noise_e: Option<f64>,
    /// Conversion gain, e-/DN.
    pub gain_e_per_dn: Option<f64>,
    /// Worst-case bias target, DN.
    pub bias: Option<f64>,
    /// Where to write Fig. 1.
    pub figure: Option<PathBuf>,
    /// Monte Carlo readouts for the check at `sigma`.
    pub samples: u64,
}

/// What `dncal quantization` answered. JSON: the one answer asked for as its own object,
/// both as `{"at_sigma": ..., "for_bias": ...}`, a figure without an answer as
/// `{"figure": ...}` (beside an answer, the figure is in the text only).
#[derive(Debug, Clone)]
pub struct QuantizationReport {
    /// The worst case at the requested noise.
    pub at_sigma: Option<SigmaReport>,
    /// The noise the requested bias needs.
    pub for_bias: Option<BiasReport>,
    /// The figure written.
    pub figure: Option<PathBuf>,
}

impl Serialize for QuantizationReport {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        match (&self.at_sigma, &self.for_bias) {
            (Some(a), None) => a.serialize(s),
            (None, Some(b)) => b.serialize(s),
            (a, b) => {
                let mut m = s.serialize_map(None)?;
                match (a, b, &self.figure) {
                    (Some(a), Some(b), _) => {
                        m.serialize_entry("at_sigma", a)?;
                        m.serialize_entry("for_bias", b)?;
                    }
                    (_, _, Some(f)) => m.serialize_entry("figure", f)?,
                    _ => {}
                }
                m.end()
            }
        }
    }
}

impl Report for QuantizationReport {
    fn text(&self) -> String {
        let mut t = wrote(self.figure.as_slice());
        match (&self.at_sigma, &self.for_bias) {
            (Some(a), None) => {
                t += &format!(
                    "noise {:.4} DN: worst-case bias {:.4e} DN at lambda mod 1 = {:.4}\n  Fourier series {:+.6e}, eq. 4 {:+.6e}, exact sum {:+.6e}, Monte Carlo {:+.6e} +- {:.1e} DN ({} readouts)\n",
                    a.sigma, a.max_abs_bias_dn, a.at_lambda_frac, a.fourier_bias_dn, a.erf_bias_dn, a.exact_bias_dn, a.monte_carlo_bias_dn, a.monte_carlo_se_dn, a.monte_carlo_samples
                );
                if a.sigma == 0.0 {
                    t += "  (without noise the bias is a sawtooth whose jump is at lambda mod 1 = 0.5: the worst case is the value beside the jump, which the other three give; a Fourier series converges to the middle of a jump, 0)\n";
                }
            }
            (None, Some(b)) => t += &format!("worst-case bias <= {} DN needs noise >= {:.4} DN\n", b.bias, b.sigma),
            (Some(a), Some(b)) => {
                t += &format!(
                    "noise {:.4} DN: worst-case bias {:.4e} DN at lambda mod 1 = {:.4}\nworst-case bias <= {} DN needs noise >= {:.4} DN\n",
                    a.sigma, a.max_abs_bias_dn, a.at_lambda_frac, b.bias, b.sigma
                )
            }
            (None, None) => {}
        }
        t
    }
}

/// Answers `request`: the noise level from read noise and gain where `sigma` is not
/// given; at least one of noise, bias or figure must be asked for.
pub fn quantization(request: &Request) -> Result<QuantizationReport, HostError> {
    let sigma = match (request.sigma, request.read_noise_e, request.gain_e_per_dn) {
        (Some(s), _, _) => Some(s),
        (None, Some(r), Some(g)) if g > 0.0 => Some(r / g),
        (None, Some(_), Some(g)) => return Err(HostError::argument("--gain-e-per-dn", format!("{g} e-/DN must be > 0"))),
        _ => None,
    };
    if sigma.is_none() && request.bias.is_none() && request.figure.is_none() {
        return Err(HostError::argument("quantization", "give --sigma (or --read-noise-e with --gain-e-per-dn), --bias or --figure"));
    }
    // The figure's file checked before any work; a refused value leaves no figure behind.
    let mut files = crate::formats::outputs::Outputs::new();
    files.expect(&request.figure)?;
    let at_sigma = sigma.map(|s| at_sigma(s, request.samples, 1)).transpose()?;
    let for_bias = request.bias.map(for_bias).transpose()?;
    if let Some(path) = &request.figure {
        figure(&mut files, path)?;
    }
    files.publish()?;
    Ok(QuantizationReport { at_sigma, for_bias, figure: request.figure.clone() })
}
