//! Binding of triangle rasterisation: `raster_fragments(uv, faces, width, height)`.

use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray2, PyUntypedArrayMethods,
};
use pyo3::prelude::*;

use super::{c_slice, invalid_input, rows};
use crate::raster::fragments;

type FragmentArrays<'py> = (
    Bound<'py, PyArray1<i64>>,
    Bound<'py, PyArray1<i64>>,
    Bound<'py, PyArray2<f64>>,
);

/// `(pixel (M,) int64, face (M,) int64, barycentric (M, 3) float64)`: every pixel centre
/// inside every projected triangle. `uv`: `(V, 2)` float64 pixels; `faces`: `(F, 3)` int64
/// vertex indices.
#[pyfunction]
fn raster_fragments<'py>(
    py: Python<'py>,
    uv: PyReadonlyArray2<'py, f64>,
    faces: PyReadonlyArray2<'py, i64>,
    width: usize,
    height: usize,
) -> PyResult<FragmentArrays<'py>> {
    let uv = rows::<2>(&uv, "uv")?;
    if faces.shape()[1] != 3 {
        return Err(invalid_input(format!(
            "faces must have shape (F, 3), got {:?}",
            faces.shape()
        )));
    }
    let flat = c_slice(&faces, "faces")?;
    let mut triangles = Vec::with_capacity(flat.len() / 3);
    for corners in flat.as_chunks::<3>().0 {
        if corners.iter().any(|&i| i < 0 || i as usize >= uv.len()) {
            return Err(invalid_input(format!(
                "faces refer to vertex {:?}, beyond the {} vertices of uv",
                corners,
                uv.len()
            )));
        }
        triangles.push(corners.map(|i| i as usize));
    }
    if width
        .checked_mul(height)
        .is_none_or(|n| n > i64::MAX as usize)
    {
        return Err(invalid_input(format!(
            "an image of {width} x {height} pixels is too large"
        )));
    }
    let found = super::detach(py, || fragments(uv, &triangles, width, height));
    let count = found.pixel.len();
    Ok((
        found.pixel.into_pyarray(py),
        found.face.into_pyarray(py),
        found.barycentric.into_pyarray(py).reshape([count, 3])?,
    ))
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(raster_fragments, m)?)
}
