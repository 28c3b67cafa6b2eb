//! `dncal stream`: frames from the camera model through the core, against the float
//! reference ([`crate::checks::streaming`]).

use std::path::Path;
use std::sync::Arc;

use dncal_core::Weight;

use crate::model::camera::Camera;
use crate::analyses::lut::build::build_luts;
use crate::infra::progress::{bar, stage};
use crate::formats::fits::read_histograms_for_analysis_planned;
use crate::analyses::flatten::{to_core_weights, FlattenParams};
use crate::checks::streaming::{run_stream, StreamParams, StreamReport};
use crate::infra::roi::RoiSpec;
use crate::HostError;

/// The weights of a perfect calibration: each ADC's true code widths, normalized.
pub fn oracle_weights(camera: &Camera) -> Result<Vec<Vec<Weight>>, HostError> {
    camera
        .adcs
        .iter()
        .map(|a| to_core_weights(&a.normalized_widths()).map_err(|source| HostError::Weights { subject: crate::Subject::CameraAdcWidths, source }))
        .collect()
}

/// Why a histogram set or a recorded frame cube cannot be streamed through the camera;
/// `HostError::StreamInput` wraps it with the file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum StreamInputFault {
    /// A histogram set of another camera.
    #[error("{adcs} ADCs of {bits} bits, but the camera has {camera_adcs} ADCs of {camera_bits} bits")]
    Adcs {
        /// The set's ADCs.
        adcs: usize,
        /// The set's bit depth.
        bits: u32,
        /// The camera's ADCs.
        camera_adcs: usize,
        /// The camera's bit depth.
        camera_bits: u32,
    },
    /// Frames that, placed at the ROI's corner, reach outside the sensor.
    #[error("{width}x{height} frames at ({x}, {y}) do not fit the {sensor_width}x{sensor_height} sensor")]
    OutsideSensor {
        /// The frames' width, pixels.
        width: usize,
        /// The frames' height, pixels.
        height: usize,
        /// The ROI's first column.
        x: usize,
        /// The ROI's first row.
        y: usize,
        /// The sensor's width, pixels.
        sensor_width: usize,
        /// The sensor's height, pixels.
        sensor_height: usize,
    },
    /// A frame width the stream's header cannot carry.
    #[error("the frame width does not fit 16 bits")]
    WidthOver16Bits,
    /// A frame height the stream's header cannot carry.
    #[error("the frame height does not fit 16 bits")]
    HeightOver16Bits,
    /// More frames than the stream counts.
    #[error("too many frames")]
    TooManyFrames,
}

/// Streams with LUTs from `hist` (flattened as `lut build` does) or, without it, from
/// the camera's true code widths.
pub fn stream(camera: &Camera, hist: Option<&Path>, flatten: &FlattenParams, params: &StreamParams) -> Result<StreamReport, HostError> {
    let weights = match hist {
        Some(path) => {
            // The camera's ADCs and bits, the core's, and the memory budget, from the
            // header before the counts are read.
            let h = read_histograms_for_analysis_planned(path, |shape| {
                if shape.n_adc != camera.config.n_adc || shape.bit_depth != camera.config.bits {
                    return Err(HostError::StreamInput {
                        path: path.into(),
                        fault: StreamInputFault::Adcs { adcs: shape.n_adc, bits: shape.bit_depth, camera_adcs: camera.config.n_adc, camera_bits: camera.config.bits },
                    });
                }
                crate::analyses::lut::build::plan_luts(path, shape)
            })?;
            build_luts(&h, flatten, path)?.weights
        }
        None => oracle_weights(camera)?,
    };
    stage(&format!("streaming {} frames of {} x {} through the {}", params.frames, params.width, params.height, match params.engine { crate::checks::streaming::Engine::Core => "core", crate::checks::streaming::Engine::Fpga(_) => "FPGA model and the core" }));
    let pb = bar(params.frames as u64, "streaming frames");
    let report = run_stream(camera, &weights, params, |n| pb.set_position(n));
    pb.finish_and_clear();
    report
}

/// `params` for a part of the sensor: the ROI `roi` (`WxH+X+Y`) and, with `frames_from`,
/// the recorded frames of that FITS cube instead of the camera model (its size and frame
/// count replace the ROI's and `params.frames`, placed at the ROI's corner).
pub fn placed(camera: &Camera, mut params: StreamParams, roi: Option<RoiSpec>, frames_from: Option<&Path>) -> Result<StreamParams, HostError> {
    let fit = |flag: &str, v: usize| u16::try_from(v).map_err(|_| HostError::argument(flag, format!("{v} does not fit 16 bits")));
    if let Some(r) = roi {
        let (w, h, x, y) = r.parts();
        (params.width, params.height, params.first_column, params.first_row) = (fit("--roi", w)?, fit("--roi", h)?, fit("--roi", x)?, fit("--roi", y)?);
    }
    if let Some(path) = frames_from {
        let cube = crate::formats::fits::read_frames(path)?;
        let (x, y) = (params.first_column as usize, params.first_row as usize);
        if x + cube.width > camera.config.width || y + cube.height > camera.config.height {
            return Err(HostError::StreamInput { path: path.into(), fault: StreamInputFault::OutsideSensor { width: cube.width, height: cube.height, x, y, sensor_width: camera.config.width, sensor_height: camera.config.height } });
        }
        let fault = |fault| HostError::StreamInput { path: path.into(), fault };
        params.width = u16::try_from(cube.width).map_err(|_| fault(StreamInputFault::WidthOver16Bits))?;
        params.height = u16::try_from(cube.height).map_err(|_| fault(StreamInputFault::HeightOver16Bits))?;
        params.frames = u32::try_from(cube.frames).map_err(|_| fault(StreamInputFault::TooManyFrames))?;
        params.recorded = Some(Arc::new(cube));
    }
    Ok(params)
}
