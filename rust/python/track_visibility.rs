//! Binding of the tracker's z-buffer test (`elastocap.tracking.visibility`).

use numpy::{PyArray1, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;

use super::{c_slice, invalid_input, rows};
use crate::track::occluded;

/// `(Q,)` bool: whether any of the `nearest` occluders (projections `occluders` (O, 2) px,
/// C-contiguous float64; `depths` (O,)) strictly within `radius` px of `points[q]` (Q, 2)
/// has a depth below `thresholds[q]` (Q,). The rule of scipy's
/// `cKDTree(occluders).query(points, k=nearest, distance_upper_bound=radius)` followed by
/// the depth test, without the tree.
#[pyfunction]
#[pyo3(signature = (occluders, depths, points, thresholds, *, radius, nearest))]
fn track_occluded<'py>(
    py: Python<'py>,
    occluders: PyReadonlyArray2<'py, f64>,
    depths: PyReadonlyArray1<'py, f64>,
    points: PyReadonlyArray2<'py, f64>,
    thresholds: PyReadonlyArray1<'py, f64>,
    radius: f64,
    nearest: usize,
) -> PyResult<Bound<'py, PyArray1<bool>>> {
    let o = rows::<2>(&occluders, "occluders")?;
    let d = c_slice(&depths, "depths")?;
    let p = rows::<2>(&points, "points")?;
    let t = c_slice(&thresholds, "thresholds")?;
    if d.len() != o.len() || t.len() != p.len() {
        return Err(invalid_input(format!(
            "depths must have one value per occluder and thresholds one per point, got {} for {} and {} for {}",
            d.len(),
            o.len(),
            t.len(),
            p.len()
        )));
    }
    if !radius.is_finite() || radius < 0.0 {
        return Err(invalid_input(format!(
            "radius must be finite and >= 0, got {radius}"
        )));
    }
    let out = PyArray1::<bool>::zeros(py, [p.len()], false);
    {
        let mut w = out.readwrite();
        let hide = w.as_slice_mut()?;
        super::detach(py, || occluded(o, d, p, t, radius, nearest, hide));
    }
    Ok(out)
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(track_occluded, m)?)
}
