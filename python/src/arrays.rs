//! numpy arrays in and out. In: an argument is viewed as the array it is (the caller
//! reads it in place or copies what it keeps), or refused with a `TypeError` (not an array, another dtype) or a
//! `ValueError` (dimensions, layout, empty) that names the argument and says what is
//! needed (an unaligned or non-contiguous buffer is refused, not copied). Out: results are new arrays that Python owns.

use numpy::ndarray::{Array, Dimension, IntoDimension};
use numpy::prelude::*;
use numpy::{dtype, Element, PyArray, PyReadonlyArray, PyUntypedArray};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;

/// `obj` (the argument `name`) as a read-only view of a C-contiguous, non-empty numpy
/// array of `T` with `D`'s dimensions, described to the user as `shape` (e.g. "(frames,
/// rows, cols)").
pub fn view<'py, T: Element, D: Dimension>(obj: &Bound<'py, PyAny>, name: &str, shape: &str) -> PyResult<PyReadonlyArray<'py, T, D>> {
    let py = obj.py();
    let want = dtype::<T>(py);
    let Ok(untyped) = obj.cast::<PyUntypedArray>() else {
        let got = obj.get_type().name().map(|n| n.to_string()).unwrap_or_else(|_| "?".into());
        return Err(PyTypeError::new_err(format!("{name}: a numpy array of {want} {shape} is needed, not {got}")));
    };
    let got = untyped.dtype();
    if !got.is_equiv_to(&want) {
        return Err(PyTypeError::new_err(format!("{name}: dtype {got}, but {want} is needed (convert with .astype(np.{want}) once the values are known to fit)")));
    }
    let ndim = D::NDIM.unwrap_or(untyped.ndim());
    if untyped.ndim() != ndim {
        return Err(PyValueError::new_err(format!("{name}: {} dimension(s) {:?}, but {ndim} {shape} are needed", untyped.ndim(), untyped.shape())));
    }
    if untyped.len() == 0 || untyped.shape().contains(&0) {
        return Err(PyValueError::new_err(format!("{name}: empty {:?}", untyped.shape())));
    }
    if !untyped.is_c_contiguous() {
        return Err(PyValueError::new_err(format!(
            "{name} is not C-contiguous (a strided view or Fortran order); it is read in place, so np.ascontiguousarray({name}) must make the copy"
        )));
    }
    // A buffer from pickle (Dask ships arrays so) or a byte offset can be misaligned for
    // T; reading it as &[T] would be undefined, so it is refused.
    if !obj.getattr("flags")?.getattr("aligned")?.extract::<bool>()? {
        return Err(PyValueError::new_err(format!("{name} is not aligned for {want}; np.require({name}, requirements=\"CA\") makes an aligned copy")));
    }
    let typed = obj.cast::<PyArray<T, D>>().map_err(|e| PyTypeError::new_err(format!("{name}: {e}")))?;
    typed.try_readonly().map_err(|e| PyValueError::new_err(format!("{name}: {e}")))
}

/// `data` (row-major) as a new numpy array of `shape`.
pub fn new<'py, T: Element, Sh: IntoDimension>(py: Python<'py>, shape: Sh, data: Vec<T>) -> PyResult<Bound<'py, PyArray<T, Sh::Dim>>> {
    let array = Array::from_shape_vec(shape, data).map_err(|e| PyValueError::new_err(e.to_string()))?;
    Ok(array.into_pyarray(py))
}

/// Rows of equal length as a 2-D array.
pub fn rows<'py, T: Element + Copy>(py: Python<'py>, rows: &[Vec<T>]) -> PyResult<Bound<'py, PyArray<T, numpy::Ix2>>> {
    let width = rows.first().map_or(0, Vec::len);
    new(py, (rows.len(), width), rows.concat())
}
