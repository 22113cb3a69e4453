//! Bindings of the distance transform and of grid sampling.

use numpy::{
    PyArray1, PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray2, PyReadonlyArray3,
    PyUntypedArrayMethods,
};
use pyo3::prelude::*;

use super::{c_slice, rows};
use crate::grid_sample::{sample_points, GridField};
use crate::sdf::signed_distance as core_signed_distance;

fn shape3(shape: &[usize]) -> [usize; 3] {
    [shape[0], shape[1], shape[2]]
}

/// Signed distance (world units, negative inside) of a C-contiguous bool occupancy grid.
#[pyfunction]
fn signed_distance<'py>(
    py: Python<'py>,
    occupancy: PyReadonlyArray3<'py, bool>,
    spacing: [f64; 3],
) -> PyResult<Bound<'py, PyArray3<f64>>> {
    let shape = shape3(occupancy.shape());
    let flat = c_slice(&occupancy, "occupancy")?;
    let sdf = super::detach(py, || core_signed_distance(flat, shape, spacing))?;
    PyArray1::from_vec(py, sdf).reshape(shape)
}

type Samples<'py> = (Bound<'py, PyArray1<f64>>, Option<Bound<'py, PyArray2<f64>>>);

/// Trilinear samples (and gradients) of a grid field at `(N, 3)` world points.
#[pyfunction]
#[pyo3(signature = (values, origin, spacing, points, gradient=false))]
fn sample_grid<'py>(
    py: Python<'py>,
    values: PyReadonlyArray3<'py, f64>,
    origin: [f64; 3],
    spacing: f64,
    points: PyReadonlyArray2<'py, f64>,
    gradient: bool,
) -> PyResult<Samples<'py>> {
    let shape = shape3(values.shape());
    let flat = c_slice(&values, "values")?;
    let field = GridField::new(flat, shape, origin, spacing)?;
    let p = rows::<3>(&points, "points")?;
    let n = p.len();
    let out_values = PyArray1::<f64>::zeros(py, n, false);
    let out_gradients = gradient.then(|| PyArray2::<f64>::zeros(py, [n, 3], false));
    {
        let mut v = out_values.readwrite();
        let mut g = out_gradients.as_ref().map(|g| g.readwrite());
        let v = v.as_slice_mut()?;
        let g = match g.as_mut() {
            Some(g) => Some(g.as_slice_mut()?.as_chunks_mut::<3>().0),
            None => None,
        };
        super::detach(py, || sample_points(&field, p, v, g))?;
    }
    Ok((out_values, out_gradients))
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(signed_distance, m)?)?;
    m.add_function(wrap_pyfunction!(sample_grid, m)?)
}
