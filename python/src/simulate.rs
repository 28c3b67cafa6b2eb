//! The camera simulator and the EMVA 1288 datasheet from Python: the sets the CLI's
//! `simulate` writes, as arrays (so a notebook can plant an effect and look for it), and
//! frames of the camera model under uniform light.

use std::path::PathBuf;

use dncal_host::analyses::emva::run::emva as emva_sheet;
use dncal_host::model::camera::calibration::{LinearityParams, RampParams};
use dncal_host::model::camera::{Camera, CameraConfig};
use dncal_host::formats::fits::Reference;
use dncal_host::model::sets::{camera_from, frames_of, linearity_set_of};
use dncal_host::Subject;
use numpy::{PyArray1, PyArray2, PyArray3};
use pyo3::prelude::*;

use crate::arrays;
use crate::errors::IntoPy;

/// The camera of `config` (a TOML file), or the built-in one.
fn camera(config: Option<PathBuf>) -> PyResult<Camera> {
    match config {
        Some(path) => CameraConfig::from_toml_file(&path).and_then(|c| camera_from(c, path.as_path().into())).py_err(),
        None => camera_from(CameraConfig::default(), Subject::DefaultCamera.into()).py_err(),
    }
}

/// The camera's configuration (the TOML's keys) as JSON.
#[pyfunction]
#[pyo3(signature = (camera = None))]
fn camera_json(camera: Option<PathBuf>) -> PyResult<String> {
    let cam = self::camera(camera)?;
    serde_json::to_string(&cam.config).map_err(|e| pyo3::exceptions::PyValueError::new_err(e.to_string()))
}

/// `dncal simulate linearity`'s set in memory: (mean (levels, rows, cols) DN, std, reference
/// (levels,): V, or s where it is an exposure, mask uint8 (rows, cols), frames, bit_depth,
/// n_adc, the colour layout from the region's first pixel (`BAYERPAT`: "GBRG", ...) or
/// None, what the reference measures ("photodiode" or "exposure")), as the FITS file
/// `dncal simulate linearity` writes says. `roi` is (width, height, column, row), default
/// the paper's region.
#[pyfunction]
#[pyo3(signature = (levels = 41, frames = 256, roi = None, seed = 41, camera = None))]
#[allow(clippy::type_complexity)]
fn simulate_linearity<'py>(
    py: Python<'py>,
    levels: usize,
    frames: u32,
    roi: Option<(usize, usize, usize, usize)>,
    seed: u64,
    camera: Option<PathBuf>,
) -> PyResult<(Bound<'py, PyArray3<f64>>, Bound<'py, PyArray3<f64>>, Bound<'py, PyArray1<f64>>, Bound<'py, PyArray2<u8>>, u32, u32, usize, Option<String>, &'static str)> {
    let cam = self::camera(camera)?;
    let paper = LinearityParams::paper(&cam);
    let roi = roi.map_or(paper.roi, |(w, h, x, y)| (x, y, w, h));
    let p = LinearityParams { levels, frames, roi, seed, ..paper };
    let set = py.detach(|| linearity_set_of(&cam, &p)).py_err()?;
    let (l, h, w) = (set.levels, set.height, set.width);
    Ok((
        arrays::new(py, (l, h, w), set.mean)?,
        arrays::new(py, (l, h, w), set.std)?,
        arrays::new(py, l, set.voltage)?,
        arrays::new(py, (h, w), set.mask.unwrap_or_else(|| vec![0; h * w]))?,
        set.n_frames,
        set.bit_depth,
        set.n_adc,
        set.keys.bayer.map(|b| b.to_string()),
        match set.keys.reference {
            Reference::Photodiode => "photodiode",
            Reference::Exposure => "exposure",
        },
    ))
}

/// `dncal simulate histograms`' counts in memory, uint64 (adcs, codes), the ramps of the
/// CLI's defaults with `seed`.
#[pyfunction]
#[pyo3(signature = (seed = 4, camera = None))]
fn simulate_histograms<'py>(py: Python<'py>, seed: u64, camera: Option<PathBuf>) -> PyResult<Bound<'py, PyArray2<u64>>> {
    let cam = self::camera(camera)?;
    let ramp = RampParams { seed, ..RampParams::default() };
    let counts = py.detach(|| cam.ramp_histograms(&ramp, |_| ()));
    arrays::rows(py, &counts)
}

/// `n` frames of the camera under uniform light of `photons` per pixel and frame, uint16
/// (n, rows, cols) of the region `roi` (width, height, column, row; default the whole
/// sensor); frame f drawn with the seed `dncal stream` gives frame f of `seed`.
#[pyfunction]
#[pyo3(signature = (n, photons, roi = None, seed = 1, camera = None))]
fn simulate_frames<'py>(py: Python<'py>, n: usize, photons: f64, roi: Option<(usize, usize, usize, usize)>, seed: u64, camera: Option<PathBuf>) -> PyResult<Bound<'py, PyArray3<u16>>> {
    let cam = self::camera(camera)?;
    let (w, h, x, y) = roi.unwrap_or((cam.config.width, cam.config.height, 0, 0));
    let codes = py.detach(|| frames_of(&cam, n, photons, (x, y, w, h), seed)).py_err()?;
    arrays::new(py, (n, h, w), codes)
}

/// `dncal emva DESCRIPTOR --json`: the EMVA 1288 datasheet of a set, as JSON.
#[pyfunction]
#[pyo3(signature = (descriptor, release = None))]
fn emva_json(py: Python<'_>, descriptor: PathBuf, release: Option<String>) -> PyResult<String> {
    let release = release.map(|r| dncal_host::analyses::emva::Release::parse(&r)).transpose().map_err(|e| crate::errors::raise("InputError", format!("release: {e}")))?;
    let summary = py.detach(|| emva_sheet(&descriptor, release, None)).py_err()?;
    serde_json::to_string(&summary).map_err(|e| pyo3::exceptions::PyValueError::new_err(e.to_string()))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(camera_json, m)?)?;
    m.add_function(wrap_pyfunction!(simulate_linearity, m)?)?;
    m.add_function(wrap_pyfunction!(simulate_histograms, m)?)?;
    m.add_function(wrap_pyfunction!(simulate_frames, m)?)?;
    m.add_function(wrap_pyfunction!(emva_json, m)?)?;
    Ok(())
}
