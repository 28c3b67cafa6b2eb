//! The reference of the package's speed benchmark (`python/bench/speed.py`): the core's
//! own rate on the frames a Python call corrects, timed in Rust, in the same process.

use std::time::Instant;

use dncal_core::{Corrector, Geometry, LutBanks};
use dncal_host::infra::dims::lut_set;
use dncal_host::{HostError, Origin};
use numpy::{Ix3, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::arrays;
use crate::errors::IntoPy;
use crate::luts::PyLut;

/// Seconds the core's `Corrector` takes to add `frames` (uint16 (frames, rows, cols)),
/// frame f into state f mod `states`, with `lut`: the corrector made and its sums
/// cleared before the clock starts, as `Corrector.clear()` is outside the Python timing.
#[pyfunction]
fn _core_seconds(py: Python<'_>, lut: &PyLut, frames: &Bound<'_, PyAny>, states: u8) -> PyResult<f64> {
    let view = arrays::view::<u16, Ix3>(frames, "frames", "(frames, rows, cols)")?;
    let (h, w) = (view.shape()[1], view.shape()[2]);
    let size = |v: usize| u16::try_from(v).map_err(|_| PyValueError::new_err(format!("frames: {v} does not fit 16 bits")));
    let geometry = Geometry::new(size(w)?, size(h)?, states, 0).map_err(|e| PyValueError::new_err(format!("geometry: {e}")))?;
    let codes = view.as_slice()?;
    let tables = &lut.lut.tables;
    let (n, c) = (tables.len(), tables.first().map_or(0, Vec::len));
    py.detach(|| dncal_host::dispatch_lut_dims!(n, c, Origin::Argument("lut"), time(tables, codes, geometry))).py_err()
}

fn time<const N: usize, const CODES: usize>(tables: &[Vec<u32>], codes: &[u16], geometry: Geometry) -> Result<f64, HostError> {
    let core = |e| HostError::core("bench", e);
    let mut banks = Box::new(LutBanks::new(*lut_set::<N, CODES>(tables, &Origin::Argument("lut"))?));
    // The sums written before the clock starts, as the Python corrector's are (allocated
    // and touched when it was made, zeroed by `clear()`): the same memory state for both,
    // not fresh pages the first frame would fault in.
    let mut sums = vec![1u32; geometry.sum_len()];
    sums.fill(0);
    let mut c = Corrector::new(&mut banks, geometry, &mut sums).map_err(core)?;
    let start = Instant::now();
    for (i, frame) in codes.chunks_exact(geometry.pixels()).enumerate() {
        c.begin_frame((i % geometry.states() as usize) as u8).map_err(core)?;
        c.accumulate_lines(0, frame).map_err(core)?;
        c.end_frame().map_err(core)?;
    }
    Ok(start.elapsed().as_secs_f64())
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(_core_seconds, m)?)
}
