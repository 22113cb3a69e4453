//! Binding of the tracker's batched correlation: every camera's candidates in one call.

use numpy::{PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArray3};
use pyo3::prelude::*;

use super::track::{candidate_rows, view};
use super::{c_slice, invalid_input};
use crate::track::ncc_at_cameras;

/// `(N, K)` correlation of the template patch around each of `points` (N, 2) in
/// `templates[cameras[i]]` with the patch of `searches[cameras[i]]` around each of its
/// `candidates` (N, K, 2); NaN where a patch leaves its image or is flat. Row for row
/// `track_ncc_at` of the row's camera, in one parallel pass over all rows. Images
/// C-contiguous float32, `cameras` (N,) int64 indices into both lists.
#[pyfunction]
#[pyo3(signature = (templates, points, searches, candidates, cameras, *, size=11))]
fn track_ncc_at_cameras<'py>(
    py: Python<'py>,
    templates: Vec<PyReadonlyArray2<'py, f32>>,
    points: PyReadonlyArray2<'py, f64>,
    searches: Vec<PyReadonlyArray2<'py, f32>>,
    candidates: PyReadonlyArray3<'py, f64>,
    cameras: PyReadonlyArray1<'py, i64>,
    size: usize,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let t = templates
        .iter()
        .map(|image| view(image, "templates"))
        .collect::<PyResult<Vec<_>>>()?;
    let s = searches
        .iter()
        .map(|image| view(image, "searches"))
        .collect::<PyResult<Vec<_>>>()?;
    let (p, cand, k) = candidate_rows(&points, &candidates, size)?;
    let n = p.len();
    let index = c_slice(&cameras, "cameras")?
        .iter()
        .map(|&c| {
            usize::try_from(c).map_err(|_| invalid_input(format!("cameras must be >= 0, got {c}")))
        })
        .collect::<PyResult<Vec<usize>>>()?;
    let scores = PyArray2::<f64>::zeros(py, [n, k], false);
    {
        let mut w = scores.readwrite();
        let out = w.as_slice_mut()?;
        super::detach(py, || ncc_at_cameras(&t, &s, &index, p, cand, size, out))?;
    }
    Ok(scores)
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(track_ncc_at_cameras, m)?)
}
