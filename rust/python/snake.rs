//! Binding of the active contour: `active_contour(image, init, ...)`.

use numpy::{IntoPyArray, PyArray2, PyArrayMethods, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;

use super::{c_slice, rows};
use crate::snake::{active_contour, SnakeOptions, SnakeStatus};

/// `(points (M, 2), status, iterations, resamplings)`; `points` is `(0, 2)` when collapsed.
#[pyfunction]
#[pyo3(name = "active_contour")]
#[pyo3(signature = (image, init, *, alpha, beta, gamma, kappa, max_move, spacing, min_spacing, max_spacing, max_iterations, tolerance, window, min_area))]
#[allow(clippy::too_many_arguments)]
fn active_contour_py<'py>(
    py: Python<'py>,
    image: PyReadonlyArray2<'py, f64>,
    init: PyReadonlyArray2<'py, f64>,
    alpha: f64,
    beta: f64,
    gamma: f64,
    kappa: f64,
    max_move: f64,
    spacing: f64,
    min_spacing: f64,
    max_spacing: f64,
    max_iterations: usize,
    tolerance: f64,
    window: usize,
    min_area: f64,
) -> PyResult<(Bound<'py, PyArray2<f64>>, &'static str, usize, usize)> {
    let (height, width) = (image.shape()[0], image.shape()[1]);
    let values = c_slice(&image, "image")?;
    let init = rows::<2>(&init, "init")?;
    let options = SnakeOptions {
        alpha,
        beta,
        gamma,
        kappa,
        max_move,
        spacing,
        min_spacing,
        max_spacing,
        max_iterations,
        tolerance,
        window: window.max(1),
        min_area,
    };
    let result = super::detach(py, || active_contour(values, width, height, init, &options))?;
    let status = match result.status {
        SnakeStatus::Converged => "converged",
        SnakeStatus::MaxIterations => "maximum iterations",
        SnakeStatus::Collapsed => "collapsed",
    };
    let n = result.points.len();
    let points = result
        .points
        .into_flattened()
        .into_pyarray(py)
        .reshape([n, 2])?;
    Ok((points, status, result.iterations, result.resamplings))
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(active_contour_py, m)?)?;
    Ok(())
}
