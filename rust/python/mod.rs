//! Thin Python bindings: extract and check arrays, release the GIL around the core,
//! map errors, return numpy arrays. No algorithm lives here.

mod body;
mod camera;
mod carve;
mod efg;
mod elastic;
mod errors;
mod fit;
mod intersect;
mod lsm;
mod mesh;
mod mls;
mod neighbors;
mod polar;
mod pool;
mod raster;
mod sdf;
mod seeding;
mod snake;
mod solve;
mod track;
mod track_rigid;
mod track_views;
mod track_visibility;

use numpy::{Element, PyReadonlyArray, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;

pub(crate) use errors::invalid_input;
pub(crate) use pool::detach;

/// The data of a C-contiguous array. (`as_slice` alone also accepts Fortran order, whose
/// data would then be read transposed.)
pub(crate) fn c_slice<'a, T: Element, Dim: numpy::ndarray::Dimension>(
    array: &'a PyReadonlyArray<'_, T, Dim>,
    argument: &str,
) -> PyResult<&'a [T]> {
    let contiguous = || invalid_input(format!("{argument} must be C-contiguous"));
    if !array.is_c_contiguous() {
        return Err(contiguous());
    }
    array.as_slice().map_err(|_| contiguous())
}

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
    Ok(c_slice(array, argument)?.as_chunks::<D>().0)
}

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    pool::register();
    errors::register(m)?;
    fit::register(m)?;
    body::register(m)?;
    carve::register(m)?;
    raster::register(m)?;
    efg::register(m)?;
    elastic::register(m)?;
    mls::register(m)?;
    neighbors::register(m)?;
    polar::register(m)?;
    sdf::register(m)?;
    solve::register(m)?;
    camera::register(m)?;
    snake::register(m)?;
    lsm::register(m)?;
    mesh::register(m)?;
    track::register(m)?;
    seeding::register(m)?;
    track_views::register(m)?;
    track_visibility::register(m)?;
    track_rigid::register(m)?;
    intersect::register(m)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;

    Ok(())
}
