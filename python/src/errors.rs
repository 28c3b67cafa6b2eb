//! Library errors as Python exceptions. The classes live in `dncal/errors.py` (each
//! derives from `DncalError` and from the built-in a Python user would catch: bad data is
//! a `ValueError`, a missing file an `OSError`, a refusal for memory a `MemoryError`);
//! the message is the CLI's, word for word.

use dncal_host::error::ErrorKind;
use dncal_host::HostError;
use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;

/// `e` as the exception of its kind.
pub fn to_py(e: HostError) -> PyErr {
    let class = match e.kind() {
        ErrorKind::Input => "InputError",
        ErrorKind::Io => "DncalIOError",
        ErrorKind::OverBudget => "OverBudgetError",
        ErrorKind::Tool => "ToolError",
    };
    raise(class, e.to_string())
}

/// An instance of `dncal.errors.<class>` with `message`.
pub fn raise(class: &str, message: String) -> PyErr {
    Python::attach(|py| {
        let made = py.import("dncal.errors").and_then(|m| m.getattr(class)).and_then(|c| c.call1((message.clone(),)));
        match made {
            Ok(instance) => PyErr::from_value(instance),
            // The package's own module is missing (the extension imported alone): the
            // message still reaches the user.
            Err(_) => PyRuntimeError::new_err(message),
        }
    })
}

/// `Result<T, HostError>` into `PyResult<T>`.
pub trait IntoPy<T> {
    fn py_err(self) -> PyResult<T>;
}

impl<T> IntoPy<T> for Result<T, HostError> {
    fn py_err(self) -> PyResult<T> {
        self.map_err(to_py)
    }
}
