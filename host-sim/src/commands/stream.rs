//! `dncal stream`: frames from the camera model through the core, against the float
//! reference ([`crate::streaming`]).

use std::path::Path;

use dncal_core::Weight;

use crate::camera::Camera;
use crate::commands::lut::build_luts;
use crate::commands::progress::{bar, stage};
use crate::fits::read_histograms_for_analysis;
use crate::flatten::{to_core_weights, FlattenParams};
use crate::streaming::{run_stream, StreamParams, StreamReport};
use crate::HostError;

/// The weights of a perfect calibration: each ADC's true code widths, normalized.
pub fn oracle_weights(camera: &Camera) -> Result<Vec<Vec<Weight>>, HostError> {
    camera
        .adcs
        .iter()
        .map(|a| to_core_weights(&a.normalized_widths()).map_err(|e| HostError::Format { path: "camera ADC widths".into(), message: e.to_string() }))
        .collect()
}

/// Streams with LUTs from `hist` (flattened as `lut build` does) or, without it, from
/// the camera's true code widths.
pub fn stream(camera: &Camera, hist: Option<&Path>, flatten: &FlattenParams, params: &StreamParams) -> Result<StreamReport, HostError> {
    let weights = match hist {
        Some(path) => {
            let h = read_histograms_for_analysis(path)?;
            if h.counts.len() != camera.config.n_adc || h.bit_depth != camera.config.bits {
                return Err(HostError::Format {
                    path: path.into(),
                    message: format!("{} ADCs of {} bits, but the camera has {} ADCs of {} bits", h.counts.len(), h.bit_depth, camera.config.n_adc, camera.config.bits),
                });
            }
            build_luts(&h, flatten, path)?.weights
        }
        None => oracle_weights(camera)?,
    };
    stage(&format!("streaming {} frames of {} x {} through the {}", params.frames, params.width, params.height, match params.engine { crate::streaming::Engine::Core => "core", crate::streaming::Engine::Fpga(_) => "FPGA model and the core" }));
    let pb = bar(params.frames as u64, "streaming frames");
    let report = run_stream(camera, &weights, params, |n| pb.set_position(n));
    pb.finish_and_clear();
    report
}
