//! Thin Python bindings: extract and check arrays, release the GIL around the core,
//! map errors, return numpy arrays. No algorithm lives here.

mod carve;
mod errors;
mod neighbors;
mod polar;
mod sdf;

use numpy::{PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;

use crate::Error;
pub(crate) use errors::invalid_input;

/// Rows of a C-contiguous `(N, D)` float64 array as `&[[f64; D]]`.
pub(crate) fn rows<'a, const D: usize>(
    array: &'a PyReadonlyArray2<'_, f64>,
    argument: &str,
) -> PyResult<&'a [[f64; D]]> {
    if array.shape()[1] != D {
        return Err(invalid_input(format!(
            "{argument} must have shape (N, {D}), got {:?}",
            array.shape()
        )));
    }
    let flat = array
        .as_slice()
        .map_err(|_| invalid_input(format!("{argument} must be C-contiguous")))?;
    Ok(flat.as_chunks::<D>().0)
}

/// Maps a core error onto the exception hierarchy.
pub(crate) fn to_py(py: Python<'_>, error: Error) -> PyErr {
    errors::from_core(py, error)
}

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    errors::register(m)?;
    carve::register(m)?;
    neighbors::register(m)?;
    polar::register(m)?;
    sdf::register(m)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;

    Ok(())
}
