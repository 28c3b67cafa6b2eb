//! The characterizations and `diagnose`: each returns the JSON the CLI's `--json`
//! prints for the same input (the Python side parses it into a dict), and the pixel-wise
//! linearity fit also its per-pixel arrays.

use std::path::PathBuf;

use dncal_host::analyses::diagnose::run::{diagnose as diagnose_file, DiagnoseParams};
use dncal_host::analyses::flatten::FlattenParams;
use dncal_host::analyses::linearity::run::{fit, linearity};
use dncal_host::analyses::linearity::{Cube, MAX_ORDER};
use dncal_host::analyses::quantization::run::{quantization as quantization_report, Request};
use dncal_host::formats::fits::{check_linearity, SetView};
use dncal_host::Origin;
use numpy::{Ix1, Ix2, Ix3, PyArray2, PyArray3, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use serde::Serialize;

use crate::arrays;
use crate::errors::{raise, IntoPy};

/// `value` as the JSON `--json` prints (compact).
fn json(value: &impl Serialize) -> PyResult<String> {
    serde_json::to_string(value).map_err(|e| PyValueError::new_err(e.to_string()))
}

/// `dncal diagnose PATH --json` (any input kind), as JSON.
#[pyfunction]
#[pyo3(signature = (path, seed = 1, block_rows = None, spill = false, spline_points = 50, median_window = 21, fixed_low_codes = 150, set_last_to_one = true))]
#[allow(clippy::too_many_arguments)]
fn diagnose_json(
    py: Python<'_>,
    path: PathBuf,
    seed: u64,
    block_rows: Option<usize>,
    spill: bool,
    spline_points: usize,
    median_window: usize,
    fixed_low_codes: usize,
    set_last_to_one: bool,
) -> PyResult<String> {
    let flatten = FlattenParams { spline_points, median_window, fixed_low_codes, set_last_to_one, ..FlattenParams::default() };
    let params = DiagnoseParams { flatten, seed, block_rows, spill };
    let summary = py.detach(|| diagnose_file(&path, &params, None)).py_err()?;
    json(&summary)
}

/// `dncal linearity PATH --json` of a linearity set file, as JSON.
#[pyfunction]
#[pyo3(signature = (path, order = 4, flat_level = None))]
fn linearity_file_json(py: Python<'_>, path: PathBuf, order: usize, flat_level: Option<usize>) -> PyResult<String> {
    let summary = py.detach(|| linearity(&path, order, flat_level, &[], None)).py_err()?;
    json(&summary)
}

/// `dncal quantization --sigma S --json` (or `--bias B`), as JSON.
#[pyfunction]
#[pyo3(signature = (sigma = None, bias = None, read_noise_e = None, gain_e_per_dn = None, samples = 1_000_000))]
fn quantization_json(py: Python<'_>, sigma: Option<f64>, bias: Option<f64>, read_noise_e: Option<f64>, gain_e_per_dn: Option<f64>, samples: u64) -> PyResult<String> {
    let request = Request { sigma, read_noise_e, gain_e_per_dn, bias, figure: None, samples };
    let report = py.detach(|| quantization_report(&request)).py_err()?;
    json(&report)
}

/// The pixel-wise linearity analysis of a set in memory: `mean` and `std` float64
/// (levels, rows, cols) in DN, level 0 dark; `voltage` float64 (levels,) the reference
/// photodiode, V; `frames` averaged per level; `mask` uint8 (rows, cols), 1 = bad.
/// Returns (report JSON, coefficients (order + 1, rows, cols), mask reasons (rows, cols),
/// corrected cube (levels, rows, cols) or None).
#[pyfunction]
#[pyo3(signature = (mean, std, voltage, frames, order = 4, flat_level = None, mask = None, bit_depth = 12, n_adc = 4, keep_corrected = true))]
#[allow(clippy::too_many_arguments)]
#[allow(clippy::type_complexity)]
fn fit_linearity<'py>(
    py: Python<'py>,
    mean: &Bound<'py, PyAny>,
    std: &Bound<'py, PyAny>,
    voltage: &Bound<'py, PyAny>,
    frames: u32,
    order: usize,
    flat_level: Option<usize>,
    mask: Option<&Bound<'py, PyAny>>,
    bit_depth: u32,
    n_adc: usize,
    keep_corrected: bool,
) -> PyResult<(String, Bound<'py, PyArray3<f64>>, Bound<'py, PyArray2<u8>>, Option<Bound<'py, PyArray3<f64>>>)> {
    if !(1..=MAX_ORDER).contains(&order) {
        return Err(PyValueError::new_err(format!("order {order}: the pixel-wise polynomial order must be 1 to {MAX_ORDER}")));
    }
    let m = arrays::view::<f64, Ix3>(mean, "mean", "(levels, rows, cols)")?;
    let s = arrays::view::<f64, Ix3>(std, "std", "(levels, rows, cols)")?;
    let v = arrays::view::<f64, Ix1>(voltage, "voltage", "(levels,)")?;
    let (levels, height, width) = (m.shape()[0], m.shape()[1], m.shape()[2]);
    if s.shape() != m.shape() {
        return Err(PyValueError::new_err(format!("std: shape {:?}, but mean is {:?}", s.shape(), m.shape())));
    }
    if v.shape()[0] != levels {
        return Err(PyValueError::new_err(format!("voltage: {} values for {levels} levels", v.shape()[0])));
    }
    let mask = mask.map(|obj| arrays::view::<u8, Ix2>(obj, "mask", "(rows, cols)")).transpose()?;
    if let Some(k) = &mask {
        if k.shape() != [height, width] {
            return Err(PyValueError::new_err(format!("mask: shape {:?}, but frames are {height} x {width}", k.shape())));
        }
    }
    // The arrays read in place: the analysis borrows them.
    let set = SetView {
        bit_depth,
        n_adc,
        n_frames: frames,
        width,
        height,
        levels,
        mean: m.as_slice()?,
        std: s.as_slice()?,
        voltage: v.as_slice()?,
        mask: mask.as_ref().map(|k| k.as_slice()).transpose()?,
        keys: Default::default(),
    };
    check_linearity(&set).map_err(|fault| raise("InputError", format!("linearity set: {fault}")))?;
    let cube = if keep_corrected { Cube::Keep } else { Cube::Skip };
    let (report, px, _) = py.detach(|| fit(&set, &Origin::Argument("linearity set"), order, flat_level, cube)).py_err()?;
    let k1 = px.coeffs.len() / (width * height);
    let coeffs = arrays::new(py, (k1, height, width), px.coeffs)?;
    let mask = arrays::new(py, (height, width), px.mask)?;
    let corrected = px.corrected.map(|c| arrays::new(py, (levels, height, width), c)).transpose()?;
    Ok((json(&report)?, coeffs, mask, corrected))
}

/// Sets the memory budget, bytes (the CLI's `--max-memory`): work that would need more
/// is refused before anything is allocated (`OverBudgetError`).
#[pyfunction]
fn set_memory_budget(bytes: u64) {
    dncal_host::infra::budget::set_limit(bytes);
}

/// The memory budget in force, bytes (default: 3/4 of the memory the process can have: physical memory, ulimit -v / -d and the cgroup limit, less what is in use).
#[pyfunction]
fn memory_budget() -> u64 {
    dncal_host::infra::budget::limit()
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(set_memory_budget, m)?)?;
    m.add_function(wrap_pyfunction!(memory_budget, m)?)?;
    m.add_function(wrap_pyfunction!(diagnose_json, m)?)?;
    m.add_function(wrap_pyfunction!(linearity_file_json, m)?)?;
    m.add_function(wrap_pyfunction!(quantization_json, m)?)?;
    m.add_function(wrap_pyfunction!(fit_linearity, m)?)?;
    Ok(())
}
