//! The core's correction on numpy frames: `Corrector` owns the LUT banks and the
//! per-state sums ([`dncal_host::infra::frame_sums::FrameSums`]) and adds frames read in
//! place, the GIL released while the core works.

use dncal_core::Geometry;
use dncal_host::infra::frame_sums::FrameSums;
use dncal_host::Origin;
use numpy::{Ix2, Ix3, PyArray1, PyArray3, PyUntypedArrayMethods};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::arrays;
use crate::errors::IntoPy;
use crate::luts::PyLut;

/// Per-state sums of LUT-corrected frames (the co-processor's datapath, bit for bit).
#[pyclass(module = "dncal._dncal", name = "Corrector")]
pub struct PyCorrector {
    sums: FrameSums,
    /// Frames added since the last clear, all states: the state of the next frame when
    /// none is given is this modulo the states (frame f in state f mod states).
    added: u64,
    /// Where the last frames added were read from (the array's data pointer), so that a
    /// test can see they were read in place.
    last_input_address: usize,
    /// Seconds the core took inside the last `add` (timed in Rust around the core's work
    /// alone): the reference of the speed benchmark, on the same buffers as the call.
    last_core_seconds: f64,
}

#[pymethods]
impl PyCorrector {
    /// A corrector with `lut` over frames of `height` x `width` pixels whose first column
    /// is sensor column `first_column` (it decides the ADC of each pixel), summed into
    /// `states` modulation states (1 to 8).
    #[new]
    #[pyo3(signature = (lut, states, height, width, first_column = 0))]
    fn new(lut: &PyLut, states: u8, height: u16, width: u16, first_column: u16) -> PyResult<Self> {
        let geometry = Geometry::new(width, height, states, first_column).map_err(|e| PyValueError::new_err(format!("geometry: {e}")))?;
        let sums = FrameSums::new(&lut.lut.tables, Origin::Argument("lut"), geometry).py_err()?;
        Ok(PyCorrector { sums, added: 0, last_input_address: 0, last_core_seconds: 0.0 })
    }

    /// Adds frames of raw codes (uint16, C-contiguous): one frame (rows, cols) or a stack
    /// (frames, rows, cols). `state` (one frame) or `states` (one per frame of a stack)
    /// says which sum each goes into; without them frame f since the last clear goes into
    /// state f mod states. Returns the frames added.
    #[pyo3(signature = (frames, state = None, states = None))]
    fn add(&mut self, py: Python<'_>, frames: &Bound<'_, PyAny>, state: Option<u8>, states: Option<Vec<u8>>) -> PyResult<usize> {
        let g = self.sums.geometry();
        let ndim = frames.cast::<numpy::PyUntypedArray>().map(|a| a.ndim()).unwrap_or(0);
        let view3;
        let view2;
        let (codes, n, rows, cols): (&[u16], usize, usize, usize) = match ndim {
            2 => {
                view2 = arrays::view::<u16, Ix2>(frames, "frames", "(rows, cols)")?;
                let (rows, cols) = (view2.shape()[0], view2.shape()[1]);
                (view2.as_slice().map_err(|e| PyValueError::new_err(e.to_string()))?, 1, rows, cols)
            }
            _ => {
                view3 = arrays::view::<u16, Ix3>(frames, "frames", "(frames, rows, cols) or one frame (rows, cols)")?;
                let (n, rows, cols) = (view3.shape()[0], view3.shape()[1], view3.shape()[2]);
                (view3.as_slice().map_err(|e| PyValueError::new_err(e.to_string()))?, n, rows, cols)
            }
        };
        if (rows, cols) != (g.height() as usize, g.width() as usize) {
            return Err(PyValueError::new_err(format!("frames: {rows} x {cols} pixels, but the corrector sums {} x {}", g.height(), g.width())));
        }
        let states_of: Vec<u8> = match (state, states) {
            (Some(_), Some(_)) => return Err(PyTypeError::new_err("give state (one frame) or states (one per frame), not both")),
            (Some(s), None) if n == 1 => vec![s],
            (Some(_), None) => return Err(PyTypeError::new_err("state is for one frame; give states (one per frame) for a stack")),
            (None, Some(v)) if v.len() == n => v,
            (None, Some(v)) => return Err(PyValueError::new_err(format!("states: {} values for {n} frames", v.len()))),
            (None, None) => (0..n as u64).map(|i| ((self.added + i) % g.states() as u64) as u8).collect(),
        };
        self.last_input_address = codes.as_ptr() as usize;
        let sums = &mut self.sums;
        let seconds = py.detach(|| {
            let start = std::time::Instant::now();
            sums.add_frames(codes, &states_of).map(|()| start.elapsed().as_secs_f64())
        });
        self.last_core_seconds = seconds.py_err()?;
        self.added += n as u64;
        Ok(n)
    }

    /// The sums, uint32 (states, rows, cols), units of 2^-11 DN (a copy).
    #[getter]
    fn sums<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray3<u32>>> {
        let g = self.sums.geometry();
        arrays::new(py, (g.states() as usize, g.height() as usize, g.width() as usize), self.sums.sums().to_vec())
    }

    /// Frames added to each state, uint32 (states,).
    #[getter]
    fn frames_per_state<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<u32>> {
        PyArray1::from_vec(py, self.sums.frames_per_state())
    }

    /// The core's counters: codes above the top code, additions that clipped at 2^32 - 1
    /// (only past 512 frames of a state), frames.
    #[getter]
    fn status<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let s = self.sums.status();
        let d = PyDict::new(py);
        d.set_item("out_of_range_codes", s.out_of_range_codes)?;
        d.set_item("saturated_additions", s.saturated_additions)?;
        d.set_item("rejected_lines", s.rejected_lines)?;
        d.set_item("incomplete_frames", s.incomplete_frames)?;
        d.set_item("frames", s.frames)?;
        Ok(d)
    }

    /// (states, rows, cols, first_column).
    #[getter]
    fn geometry(&self) -> (u8, u16, u16, u16) {
        let g = self.sums.geometry();
        (g.states(), g.height(), g.width(), g.first_column())
    }

    /// The data address of the frames last added (for checking they were read in place).
    #[getter]
    fn _last_input_address(&self) -> usize {
        self.last_input_address
    }

    /// Seconds the core's own work took inside the last `add` (for the speed benchmark).
    #[getter]
    fn _last_core_seconds(&self) -> f64 {
        self.last_core_seconds
    }

    /// Zeroes the sums, frame counts and counters, as after a readout.
    fn clear(&mut self) {
        self.added = 0;
        self.sums.clear();
    }

    fn __repr__(&self) -> String {
        let (states, h, w, x) = self.geometry();
        format!("Corrector(states={states}, height={h}, width={w}, first_column={x}, frames={:?})", self.sums.frames_per_state())
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyCorrector>()
}
