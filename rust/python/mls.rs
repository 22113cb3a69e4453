//! Binding of the MLS shape functions at the nodes.

use numpy::{
    PyArray1, PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2,
    PyUntypedArrayMethods,
};
use pyo3::prelude::*;

use super::{c_slice, invalid_input, rows};
use crate::mls::shape_functions_into;

type Outputs<'py> = (
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray3<f64>>,
    Bound<'py, PyArray1<f64>>,
    usize,
);

/// Neighbour indices as `u32`, or an error naming the first one outside `0..n`.
fn neighbor_indices(flat: &[i64], k: usize, n: usize) -> PyResult<Vec<u32>> {
    flat.iter()
        .enumerate()
        .map(|(at, &index)| match u32::try_from(index) {
            Ok(i) if (i as usize) < n => Ok(i),
            _ => Err(invalid_input(format!(
                "neighbors[{}, {}] = {index} is not a point index: it must be in 0..{n}",
                at / k,
                at % k
            ))),
        })
        .collect()
}

/// Runs the core into output arrays that numpy allocates.
fn run<'py, const D: usize, const M: usize>(
    py: Python<'py>,
    points: &PyReadonlyArray2<'py, f64>,
    neighbors: &[u32],
    k: usize,
    support: &[f64],
) -> PyResult<Outputs<'py>> {
    let points = rows::<D>(points, "points")?;
    let n = points.len();
    let phi = PyArray2::<f64>::zeros(py, [n, k], false);
    let grad = PyArray3::<f64>::zeros(py, [n, k, D], false);
    let used = PyArray1::<f64>::zeros(py, [n], false);
    let repaired = {
        let mut phi = phi.readwrite();
        let mut grad = grad.readwrite();
        let mut used = used.readwrite();
        let (phi, used) = (phi.as_slice_mut()?, used.as_slice_mut()?);
        let grad = grad.as_slice_mut()?.as_chunks_mut::<D>().0;
        super::detach(py, || {
            shape_functions_into::<D, M>(points, neighbors, k, support, phi, grad, used)
        })?
    };
    Ok((phi, grad, used, repaired))
}

/// `(phi (N, k), grad (N, k, D), support_used (N,), repaired_count)` of C-contiguous
/// `points (N, D)` float64, `neighbors (N, k)` int64 (each row holding its node) and
/// `support (N,)` float64, D = 2 or 3.
#[pyfunction]
fn mls_shape_functions<'py>(
    py: Python<'py>,
    points: PyReadonlyArray2<'py, f64>,
    neighbors: PyReadonlyArray2<'py, i64>,
    support: PyReadonlyArray1<'py, f64>,
) -> PyResult<Outputs<'py>> {
    let n = points.shape()[0];
    let [rows_given, k] = [neighbors.shape()[0], neighbors.shape()[1]];
    if rows_given != n {
        return Err(invalid_input(format!(
            "neighbors must have shape (N, k) with N = {n} rows like points, got {:?}",
            neighbors.shape()
        )));
    }
    c_slice(&points, "points")?;
    let flat = c_slice(&neighbors, "neighbors")?;
    let support = c_slice(&support, "support")?;
    let neighbors = neighbor_indices(flat, k.max(1), n)?;
    match points.shape()[1] {
        2 => run::<2, 3>(py, &points, &neighbors, k, support),
        3 => run::<3, 4>(py, &points, &neighbors, k, support),
        d => Err(invalid_input(format!(
            "points must have shape (N, 2) or (N, 3), got (N, {d})"
        ))),
    }
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(mls_shape_functions, m)?)
}
