//! `dncal kcor-model`: the K-Coronagraph model of the paper's section 4 (Figs. 4 and 5),
//! without and with a LUT built through the core from a 1%-noisy histogram.

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::camera::Camera;
use crate::commands::lut::{inspect, tables_from_weights};
use crate::flatten::to_core_weights;
use crate::kcor::{noisy_weights, run, KcorParams, KcorResult};
use crate::plots::{map_plot, Map};
use crate::HostError;

/// What `kcor-model` prints: the result without its grids, and the figures.
#[derive(Debug, Serialize)]
pub struct KcorSummary {
    /// The run (grids skipped in JSON: they are in the figures).
    #[serde(flatten)]
    pub result: KcorResult,
    /// Where the LUT came from.
    pub lut_source: String,
    /// Figures written.
    pub figures: Vec<PathBuf>,
}

/// Runs the model on ADC `p.adc` of `camera` and, with `out_dir`, writes
/// `kcor_raw.png` and `kcor_lut.png`. The LUT is the table of that ADC in `lut_file` (a
/// LUT FITS or device image, e.g. from `dncal adc` on measured histograms) or, without
/// it, the paper's: the ADC's true widths with `p.lut_noise` relative noise per code.
pub fn kcor_model(camera: &Camera, p: &KcorParams, lut_file: Option<&Path>, out_dir: Option<&Path>) -> Result<KcorSummary, HostError> {
    let adc = camera.adcs.get(p.adc).ok_or_else(|| HostError::Format { path: "--adc".into(), message: format!("ADC {} does not exist; the camera has {}", p.adc, camera.adcs.len()) })?;
    if !(p.exposure_s > 0.0 && p.exposure_s.is_finite() && p.fill > 0.0 && p.fill <= 1.0 && p.lut_noise >= 0.0 && p.flat_fraction > 0.0 && p.flat_fraction <= 1.0 && p.q_fraction > 0.0 && p.q_fraction <= 1.0) {
        return Err(HostError::Format { path: "arguments".into(), message: "need exposure > 0, 0 < fill <= 1, 0 < flat fraction <= 1, 0 < q fraction <= 1 and LUT noise >= 0".into() });
    }
    let entries: Vec<u32> = match lut_file {
        Some(path) => {
            let l = inspect(path)?;
            let table = l.adcs.into_iter().nth(p.adc).ok_or_else(|| HostError::Format { path: path.into(), message: format!("no table for ADC {}", p.adc) })?;
            if table.entries.len() != adc.codes() {
                return Err(HostError::Format { path: path.into(), message: format!("{} codes, the camera's ADC has {}", table.entries.len(), adc.codes()) });
            }
            table.entries
        }
        None => {
            let source = Path::new("K-Cor LUT weights");
            let w = to_core_weights(&noisy_weights(adc, p.lut_noise, p.seed)).map_err(|e| HostError::Format { path: source.into(), message: e.to_string() })?;
            tables_from_weights(&[w], source)?.0.remove(0)
        }
    };
    let lut: Vec<f64> = entries.iter().map(|&e| e as f64 / 2048.0).collect();
    let result = run(camera, adc, &lut, p);
    let mut figures = Vec::new();
    if let Some(dir) = out_dir {
        std::fs::create_dir_all(dir).map_err(|e| HostError::io(dir, e))?;
        let i_max = result.i_bsun.last().copied().unwrap_or(1.0);
        for (name, grid, title) in [
            ("kcor_raw.png", &result.dq_raw, "K-Cor model: |systematic error in Q| (B_sun), raw ADC"),
            ("kcor_lut.png", &result.dq_lut, "K-Cor model: |systematic error in Q| (B_sun), with the LUT"),
        ] {
            let path = dir.join(name);
            map_plot(
                &path,
                &Map {
                    title,
                    x_label: "Stokes I (B_sun)",
                    y_label: "Stokes Q (B_sun)",
                    values: grid,
                    x_range: (0.0, i_max),
                    y_range: (result.q_bsun.first().copied().unwrap_or(-i_max), result.q_bsun.last().copied().unwrap_or(i_max)),
                    scale_label: "log10 |dQ| (B_sun)",
                    log: true,
                    contours: &[1e-8, 1e-9, 1e-10],
                },
            )?;
            figures.push(path);
        }
    }
    let lut_source = match lut_file {
        Some(f) => f.display().to_string(),
        None => format!("true code widths with {}% Gaussian noise per code", 100.0 * p.lut_noise),
    };
    Ok(KcorSummary { result, lut_source, figures })
}
