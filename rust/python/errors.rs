//! The exception hierarchy and the one place where core errors become Python exceptions.
//!
//! `ElastocapError` is the root; `InvalidInputError` is also a `ValueError` (bad input);
//! `ConvergenceError` is for numerical failure.

use pyo3::exceptions::{PyException, PyValueError};
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{PyDict, PyTuple, PyType};

use crate::Error;

pyo3::create_exception!(
    elastocap,
    ElastocapError,
    PyException,
    "Root of every error elastocap raises."
);
pyo3::create_exception!(
    elastocap,
    ConvergenceError,
    ElastocapError,
    "A numerical method did not converge or met a singular system."
);

static INVALID_INPUT: PyOnceLock<Py<PyType>> = PyOnceLock::new();

/// `class InvalidInputError(ElastocapError, ValueError)`: pyo3 declares single-base
/// exceptions only, so this one is made by calling `type` once.
fn invalid_input_type(py: Python<'_>) -> PyResult<&Bound<'_, PyType>> {
    let ty = INVALID_INPUT.get_or_try_init(py, || -> PyResult<Py<PyType>> {
        let bases = PyTuple::new(
            py,
            [
                py.get_type::<ElastocapError>(),
                py.get_type::<PyValueError>(),
            ],
        )?;
        let namespace = PyDict::new(py);
        namespace.set_item("__module__", "elastocap")?;
        namespace.set_item(
            "__doc__",
            "Bad input: wrong shape, dtype or value. Also a ValueError.",
        )?;
        let ty = py
            .get_type::<PyType>()
            .call1(("InvalidInputError", bases, namespace))?;
        Ok(ty.cast_into::<PyType>()?.unbind())
    })?;
    Ok(ty.bind(py))
}

/// An `InvalidInputError` carrying `message`.
pub(crate) fn invalid_input(message: String) -> PyErr {
    Python::attach(|py| match invalid_input_type(py) {
        Ok(ty) => PyErr::from_type(ty.clone(), message),
        Err(e) => e,
    })
}

pub(crate) fn from_core(_py: Python<'_>, error: Error) -> PyErr {
    if error.is_invalid_input() {
        invalid_input(error.to_string())
    } else {
        ElastocapError::new_err(error.to_string())
    }
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("ElastocapError", py.get_type::<ElastocapError>())?;
    m.add("ConvergenceError", py.get_type::<ConvergenceError>())?;
    m.add("InvalidInputError", invalid_input_type(py)?)?;
    Ok(())
}
