//! Errors as Python sees them: `DwslamError` with the Rust message (its whole chain of
//! causes), `ValueError` for a bad argument.

use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;

pyo3::create_exception!(
    _dwslam,
    DwslamError,
    PyRuntimeError,
    "An error of dwslam (a file it cannot read, a map it cannot load, a run that failed); the \
     message is the one `dwslam` prints."
);

/// An error of the Rust side as a Python exception, with its whole chain of causes.
pub(crate) fn py_err(e: anyhow::Error) -> PyErr {
    DwslamError::new_err(format!("{e:#}"))
}
