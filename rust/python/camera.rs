//! Binding of the camera projection the carving uses (to check it against OpenCV).

use numpy::{PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;
use rayon::prelude::*;

use super::{c_slice, invalid_input, rows};
use crate::camera::Camera;

/// Pixels `(N, 2)` of world points `(N, 3)` through one camera; NaN rows for points behind
/// it or beyond its fold radius. `k`, `r`: `(3, 3)`; `dist`: 4, 5, 8, 12 or 14 OpenCV
/// coefficients; `t`: `(3,)`.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
fn camera_project<'py>(
    py: Python<'py>,
    points: PyReadonlyArray2<'py, f64>,
    k: PyReadonlyArray2<'py, f64>,
    dist: PyReadonlyArray1<'py, f64>,
    r: PyReadonlyArray2<'py, f64>,
    t: PyReadonlyArray1<'py, f64>,
    width: usize,
    height: usize,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let matrix = |a: &PyReadonlyArray2<'py, f64>, name: &str| -> PyResult<[f64; 9]> {
        let flat = c_slice(a, name)?;
        flat.try_into()
            .map_err(|_| invalid_input(format!("{name} must have shape (3, 3)")))
    };
    let (k, r) = (matrix(&k, "K")?, matrix(&r, "R")?);
    let t: [f64; 3] = c_slice(&t, "t")?
        .try_into()
        .map_err(|_| invalid_input("t must have shape (3,)".to_string()))?;
    let camera = Camera::new(k, c_slice(&dist, "dist")?, r, t, width, height)?;
    let points = rows::<3>(&points, "points")?;
    let uv: Vec<[f64; 2]> = super::detach(py, || {
        points
            .par_iter()
            .map(|p| camera.project(p).unwrap_or([f64::NAN; 2]))
            .collect()
    });
    let flat: Vec<f64> = uv.into_iter().flatten().collect();
    numpy::PyArray1::from_vec(py, flat).reshape([points.len(), 2])
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(camera_project, m)?)
}
