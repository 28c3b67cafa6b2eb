//! The camera model: photons to codes, pixel by pixel, as docs/model.md derives.
//!
//! For pixel `i` in column `c` receiving `N_p` photons in a frame:
//!
//! ```text
//! mean signal     mu_i = QE N_p g_i + d_i           g_i = f_i (1 + N(0, prnu_rms))   (PRNU; f_i the [cfa] cell's response, else 1)
//!                                                   d_i = dark_e + N(0, dsnu_rms_e), >= 0 (DSNU)
//! photoelectrons  n    ~ Poisson(mu_i),  clipped at the full well FW
//! nonlinearity    y    = FW p_i(n / FW),  p_i(x) = x + sum_m a_{m,i} x^m   (m = 2, 3, ...)
//! read noise      y'   = y + N(0, read_noise_e)
//! analog DN       v    = y' / K + offset_dn          K = gain_e_per_dn
//! code            k    = max { k : T_k <= v }        T from ADC c mod N (see [`adc`])
//! ```
//!
//! Bad pixels are hot (always the top code) or dead (`g_i = 0`). The same model is
//! evaluated two ways: sampled line by line ([`sample`]) for streaming, and as exact code
//! probabilities for a given mean signal ([`exact`]) where means and variances must be
//! free of sampling noise.

pub mod adc;
pub mod architecture;
pub mod calibration;
pub mod config;
pub mod draws;
pub mod exact;
pub mod nested;
pub mod pixels;
pub mod sample;

pub use adc::AdcTransfer;
pub use architecture::Architecture;
pub use config::{AdcConfig, AdcModel, CameraConfig, ConfigError};
pub use pixels::{PixelMaps, PixelState};
pub use sample::Sampler;

/// A camera: its configuration, one ADC per ADC index, and its pixel maps.
pub struct Camera {
    /// The parameters.
    pub config: CameraConfig,
    /// ADC `a` reads columns `c` with `c mod n_adc == a`.
    pub adcs: Vec<AdcTransfer>,
    /// Per-pixel gain, dark, nonlinearity and defects.
    pub pixels: PixelMaps,
}

impl Camera {
    /// Builds the camera of `config` (validated): ADCs from the fitted architectures, the
    /// measured widths, or drawn from the ADC model; pixel maps from the seed.
    pub fn new(config: CameraConfig) -> Result<Self, ConfigError> {
        config.validate()?;
        let adcs = if !config.adc.architecture.is_empty() {
            config.adc.architecture.iter().map(|a| AdcTransfer::from_architecture(a, config.bits)).collect::<Result<Vec<_>, _>>()?
        } else if config.adc.widths.is_empty() {
            (0..config.n_adc).map(|a| AdcTransfer::from_model(&config.adc, config.bits, a)).collect::<Result<Vec<_>, _>>()?
        } else {
            config.adc.widths.iter().map(|w| AdcTransfer::from_widths(w)).collect::<Result<Vec<_>, _>>()?
        };
        let pixels = PixelMaps::generate(&config);
        Ok(Camera { config, adcs, pixels })
    }

    /// The ADC of column `column`.
    #[inline]
    pub fn adc_of(&self, column: usize) -> &AdcTransfer {
        &self.adcs[dncal_core::adc_of_column(column, self.adcs.len())]
    }

    /// The noiseless response: photoelectrons `n` (already clipped or not) to electrons
    /// after the nonlinearity of pixel coefficients `a` (a2, a3, ...).
    #[inline]
    pub fn response_e(&self, n: f64, a: &[f64]) -> f64 {
        let fw = self.config.full_well_e;
        let x = n.min(fw) / fw;
        let mut xm = x;
        let mut p = x;
        for &am in a {
            xm *= x;
            p += am * xm;
        }
        fw * p
    }
}
