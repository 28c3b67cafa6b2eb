//! `dncal linearity FILE`: the paper's section 5 on a linearity set: raw, standard and
//! pixel-wise corrections compared as RMS residual per level (Fig. 8), with the
//! coefficients, mask and corrected images written as FITS.

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::fits::{read_linearity, write_cube, write_pixel_correction, PixelCorrection};
use crate::linearity::{analyze, LinearityReport, MAX_ORDER};
use crate::plots::{line_plot_paired, Series};
use crate::HostError;

/// What `linearity` prints.
#[derive(Debug, Serialize)]
pub struct LinearitySummary {
    /// The input.
    pub input: PathBuf,
    /// The analysis.
    #[serde(flatten)]
    pub report: LinearityReport,
    /// Wall time of the analysis (fit, inversion, statistics), s.
    pub analysis_s: f64,
    /// Files written.
    pub outputs: Vec<PathBuf>,
}

/// Analyzes `input`; with `out_dir`, writes `coefficients.fits` (cube and MASK),
/// `corrected.fits` (pixel-wise corrected normalized intensities, masked pixels filled)
/// and `linearity_rms.png`.
pub fn linearity(input: &Path, order: usize, out_dir: Option<&Path>) -> Result<LinearitySummary, HostError> {
    if !(1..=MAX_ORDER).contains(&order) {
        return Err(HostError::Format { path: "--order".into(), message: format!("{order}: the pixel-wise polynomial order must be 1 to {MAX_ORDER}") });
    }
    let set = read_linearity(input)?;
    if set.levels < order + 3 {
        return Err(HostError::Format { path: input.into(), message: format!("{} levels; an order-{order} fit needs at least {}", set.levels, order + 3) });
    }
    if set.voltage.iter().any(|v| !(v.is_finite() && *v >= 0.0)) || set.voltage.iter().cloned().fold(0.0, f64::max) <= 0.0 {
        return Err(HostError::Format { path: input.into(), message: "REFERENCE VOLTAGE must be finite, >= 0 and not all zero".into() });
    }
    let start = std::time::Instant::now();
    let (report, px) = analyze(&set, order);
    let analysis_s = start.elapsed().as_secs_f64();
    let mut outputs = Vec::new();
    if let Some(dir) = out_dir {
        std::fs::create_dir_all(dir).map_err(|e| HostError::io(dir, e))?;
        let c = dir.join("coefficients.fits");
        let pc = PixelCorrection { coeffs: &px.coeffs, mask: &px.mask, width: set.width, height: set.height, order, bit_depth: set.bit_depth, n_adc: set.n_adc };
        write_pixel_correction(&c, &pc)?;
        let k = dir.join("corrected.fits");
        write_cube(&k, &px.corrected, set.levels, set.width, set.height, "normalized intensity")?;
        let fig = dir.join("linearity_rms.png");
        let series = |label: &str, v: &[f64]| Series {
            label: label.into(),
            points: report.reference.iter().zip(v).filter(|(_, y)| y.is_finite() && **y > 0.0).map(|(&x, &y)| (x, y.log10())).collect(),
        };
        line_plot_paired(
            &fig,
            "RMS residual (solid) and random noise (dashed), log10: the paper's Fig. 8",
            "normalized intensity (reference voltage / maximum)",
            "log10 RMS",
            &[
                series("raw", &report.rms_raw),
                series("standard: global cubic, dark, gain", &report.rms_standard),
                series(&format!("pixel-wise order {}, dark, gain", report.order), &report.rms_pixelwise),
                series("raw: random", &report.rms_random_raw),
                series("standard: random", &report.rms_random_standard),
                series("pixel-wise: random", &report.rms_random_pixelwise),
            ],
            1,
            3,
        )?;
        outputs.extend([c, k, fig]);
    }
    Ok(LinearitySummary { input: input.into(), report, analysis_s, outputs })
}
