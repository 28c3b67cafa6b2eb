//! LUTs: built from code histograms (the shared or the paper's flattening), read and written in
//! every format the CLI knows (`formats::lut`), entries and weights as numpy arrays.

use std::path::PathBuf;

use dncal_host::analyses::flatten::{to_core_weights, FlattenParams, Recipe};
use dncal_host::analyses::lut::build::build_luts as build;
use dncal_host::formats::fits::AdcHistograms;
use dncal_host::formats::lut::{self, Lut, LutFormat};
use dncal_host::formats::outputs::Outputs;
use dncal_host::{HostError, Origin};
use numpy::{Ix2, PyArray, PyArray2, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::arrays;
use crate::errors::IntoPy;

/// A LUT set: per ADC, the core's entry for every code (units of 2^-11 DN) and, where
/// known, the code widths it was built from (DN).
#[pyclass(module = "dncal._dncal", name = "Lut", frozen)]
pub struct PyLut {
    pub lut: Lut,
    /// Each ADC's flattening summary (JSON, as `lut build --json` prints `adcs`), for a
    /// set built from histograms.
    summaries: Option<String>,
}

#[pymethods]
impl PyLut {
    /// The LUT set of `entries` (uint32, (adcs, codes), units of 2^-11 DN), checked as the
    /// core checks every set it loads.
    #[new]
    fn new(entries: &Bound<'_, PyAny>) -> PyResult<Self> {
        let view = arrays::view::<u32, Ix2>(entries, "entries", "(adcs, codes)")?;
        let tables: Vec<Vec<u32>> = view.as_array().rows().into_iter().map(|r| r.to_vec()).collect();
        let lut = Lut { tables, weights: None, kcor_bits: None };
        lut::validate(&lut, Origin::Argument("entries")).py_err()?;
        Ok(PyLut { lut, summaries: None })
    }

    /// The LUT set of per-code widths `weights` (float64, (adcs, codes), DN; 1 is an ideal
    /// code), rounded to the core's weight grid (2^-24 DN) as `lut build` rounds them.
    #[staticmethod]
    fn from_weights(weights: &Bound<'_, PyAny>) -> PyResult<Self> {
        let view = arrays::view::<f64, Ix2>(weights, "weights", "(adcs, codes)")?;
        let mut core = Vec::new();
        for (adc, row) in view.as_array().rows().into_iter().enumerate() {
            let w = to_core_weights(&row.to_vec()).map_err(|e| crate::errors::to_py(HostError::AdcFlatten { origin: Origin::Argument("weights"), adc, source: e }))?;
            core.push(w);
        }
        Ok(PyLut { lut: Lut::from_weights(core, Origin::Argument("weights")).py_err()?, summaries: None })
    }

    /// The entries, uint32 (adcs, codes), units of 2^-11 DN.
    #[getter]
    fn entries<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<u32>>> {
        arrays::rows(py, &self.lut.tables)
    }

    /// The code widths, float64 (adcs, codes), DN; None for a device image, which holds
    /// only the entries.
    #[getter]
    fn weights<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyArray2<f64>>>> {
        match &self.lut.weights {
            None => Ok(None),
            Some(w) => arrays::rows(py, &w.iter().map(|w| w.iter().map(|x| x.to_num::<f64>()).collect()).collect::<Vec<Vec<f64>>>()).map(Some),
        }
    }

    /// Bits per code.
    #[getter]
    fn bit_depth(&self) -> u32 {
        self.lut.bit_depth()
    }

    /// LUT units per DN of these tables, the core's for their depth: 2048 up to 12 bits,
    /// `2^(23 - bit_depth)` above (512 at 14 bits, 128 at 16), so that every entry stays
    /// below 2^23 and 512 frames sum into 32 bits.
    #[getter]
    fn units_per_dn(&self) -> f64 {
        dncal_host::infra::dims::units_per_dn(1usize << self.lut.bit_depth())
    }

    /// ADCs.
    #[getter]
    fn adcs(&self) -> usize {
        self.lut.tables.len()
    }

    /// The K-Cor scaling B (last entry 2^B - 1) of tables read from K-Cor files, else None.
    #[getter]
    fn kcor_bits(&self) -> Option<u32> {
        self.lut.kcor_bits
    }

    /// Each ADC's flattening summary, as `lut build --json` gives them under "adcs"
    /// (a list of dicts); None for a set not built from histograms.
    #[getter]
    fn summaries<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        self.summaries.as_ref().map(|text| py.import("json")?.call_method1("loads", (text,))).transpose()
    }

    /// Writes the set in `format` ("fits", "image" or "kcor", or the names `lut inspect`
    /// reports: "lut-fits", "device-image", "kcor-tables") to the files `lut convert -o
    /// OUT` writes; all or none. Returns the paths written.
    #[pyo3(signature = (out, format = "fits", kcor_bits = None))]
    fn write(&self, py: Python<'_>, out: PathBuf, format: &str, kcor_bits: Option<u32>) -> PyResult<Vec<PathBuf>> {
        let format = format_named(format)?;
        if kcor_bits.is_some() && format != LutFormat::Kcor {
            return Err(PyValueError::new_err("kcor_bits sets the scaling of K-Cor tables; give it with format=\"kcor\" only"));
        }
        let lut = &self.lut;
        py.detach(|| {
            let paths = lut::output_paths(format, &out)?;
            let mut files = Outputs::new();
            files.expect(&paths)?;
            let bits = (format == LutFormat::Kcor).then(|| kcor_bits.or(lut.kcor_bits).unwrap_or(23));
            lut::write(&mut files, lut, format, &paths, bits, Origin::Argument("lut"))?;
            files.publish()
        })
        .py_err()
    }

    fn __repr__(&self) -> String {
        format!("Lut(adcs={}, bit_depth={}, weights={})", self.lut.tables.len(), self.lut.bit_depth(), if self.lut.weights.is_some() { "yes" } else { "no" })
    }
}

/// `name` as a LUT format.
fn format_named(name: &str) -> PyResult<LutFormat> {
    match name {
        "fits" | "lut-fits" => Ok(LutFormat::Fits),
        "image" | "device-image" => Ok(LutFormat::DeviceImage),
        "kcor" | "kcor-tables" => Ok(LutFormat::Kcor),
        other => Err(PyValueError::new_err(format!("format {other:?}: one of \"fits\", \"image\", \"kcor\" is needed"))),
    }
}

/// Reads a LUT file of any format (sniffed from its first bytes, as `lut inspect` does);
/// returns the format's name and the set.
#[pyfunction]
fn read_lut(py: Python<'_>, path: PathBuf) -> PyResult<(String, PyLut)> {
    let (format, lut) = py.detach(|| lut::read(&path)).py_err()?;
    Ok((format.to_string(), PyLut { lut, summaries: None }))
}

/// Builds the LUT set of code histograms `counts` (uint64, (adcs, codes)) as `lut build`
/// does: `recipe` "shared" (its default: one illumination for all ADCs) or "paper";
/// `spline_points` and `median_window` default to the recipe's.
#[pyfunction]
#[pyo3(signature = (counts, spline_points = None, median_window = None, fixed_low_codes = 150, set_last_to_one = true, min_mean_count = 1.0, trim_below_fraction = 0.0, *, recipe = "shared"))]
#[allow(clippy::too_many_arguments)]
fn build_luts(
    py: Python<'_>,
    counts: &Bound<'_, PyAny>,
    spline_points: Option<usize>,
    median_window: Option<usize>,
    fixed_low_codes: usize,
    set_last_to_one: bool,
    min_mean_count: f64,
    trim_below_fraction: f64,
    recipe: &str,
) -> PyResult<PyLut> {
    let view = arrays::view::<u64, Ix2>(counts, "counts", "(adcs, codes)")?;
    let codes = view.shape()[1];
    if !codes.is_power_of_two() {
        return Err(PyValueError::new_err(format!("counts: {codes} codes, but an ADC of B bits has 2^B")));
    }
    let hist = AdcHistograms { bit_depth: codes.trailing_zeros(), counts: view.as_array().rows().into_iter().map(|r| r.to_vec()).collect() };
    let base = match recipe {
        "shared" => Recipe::Shared,
        "paper" => Recipe::Paper,
        other => return Err(PyValueError::new_err(format!("recipe {other:?}: expected \"shared\" or \"paper\""))),
    }
    .params();
    let params = FlattenParams {
        spline_points: spline_points.unwrap_or(base.spline_points),
        median_window: median_window.unwrap_or(base.median_window),
        fixed_low_codes,
        set_last_to_one,
        min_mean_count,
        trim_below_fraction,
        ..base
    };
    let built = py.detach(|| build(&hist, &params, Origin::Argument("counts"))).py_err()?;
    let summaries = serde_json::to_string(&built.summaries()).map_err(|e| PyValueError::new_err(e.to_string()))?;
    Ok(PyLut { lut: built.lut(), summaries: Some(summaries) })
}

/// Reads a histogram set FITS file (`simulate histograms`, `dncal adc -o`): the counts,
/// uint64 (adcs, codes), and the bit depth.
#[pyfunction]
fn read_histograms<'py>(py: Python<'py>, path: PathBuf) -> PyResult<(Bound<'py, PyArray<u64, Ix2>>, u32)> {
    let h = py.detach(|| dncal_host::formats::fits::read_histograms(&path)).py_err()?;
    Ok((arrays::rows(py, &h.counts)?, h.bit_depth))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyLut>()?;
    m.add_function(wrap_pyfunction!(read_lut, m)?)?;
    m.add_function(wrap_pyfunction!(build_luts, m)?)?;
    m.add_function(wrap_pyfunction!(read_histograms, m)?)?;
    Ok(())
}
