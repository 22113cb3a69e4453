//! Binding of the rigid residuals' leave-one-out fits (`elastocap.tracking.rigidity`).

use numpy::{
    PyArray1, PyArray3, PyArray4, PyArrayMethods, PyReadonlyArray2, PyReadonlyArray3,
    PyUntypedArrayMethods,
};
use pyo3::prelude::*;

use super::{c_slice, invalid_input};
use crate::track::rigid_held_out;

/// `R` `(M, K, 3, 3)` and `t` `(M, K, 3)`: for each set of `a`, `b` `(M, K, 3)` with 0/1
/// `weights` `(M, K)` and each chosen neighbour `j` whose set keeps `min_others` weight or
/// more without it, the set's rigid fit `b ~ R a + t` without `j` (the fit of `rigid_fits`,
/// to the bit); NaN for the others. The algorithm: `crate::track::rigid_held_out`.
#[pyfunction]
#[pyo3(signature = (a, b, weights, *, min_others))]
fn track_rigid_held_out<'py>(
    py: Python<'py>,
    a: PyReadonlyArray3<'py, f64>,
    b: PyReadonlyArray3<'py, f64>,
    weights: PyReadonlyArray2<'py, f64>,
    min_others: f64,
) -> PyResult<(Bound<'py, PyArray4<f64>>, Bound<'py, PyArray3<f64>>)> {
    let (m, k) = (a.shape()[0], a.shape()[1]);
    if a.shape()[2] != 3 || b.shape() != a.shape() || weights.shape() != [m, k] {
        return Err(invalid_input(format!(
            "a, b must have one shape (M, K, 3) and weights (M, K), got {:?}, {:?}, {:?}",
            a.shape(),
            b.shape(),
            weights.shape()
        )));
    }
    if min_others.is_nan() {
        return Err(invalid_input("min_others must not be NaN".to_string()));
    }
    let a = c_slice(&a, "a")?.as_chunks::<3>().0;
    let b = c_slice(&b, "b")?.as_chunks::<3>().0;
    let w = c_slice(&weights, "weights")?;
    let fits = super::detach(py, || rigid_held_out(a, b, w, k, min_others));
    let mut r = Vec::with_capacity(9 * fits.len());
    let mut t = Vec::with_capacity(3 * fits.len());
    for (rf, tf) in fits {
        r.extend_from_slice(&rf);
        t.extend_from_slice(&tf);
    }
    Ok((
        PyArray1::from_vec(py, r).reshape([m, k, 3, 3])?,
        PyArray1::from_vec(py, t).reshape([m, k, 3])?,
    ))
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(track_rigid_held_out, m)?)
}
