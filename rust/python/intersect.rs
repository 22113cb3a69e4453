//! Binding of the per-view forward intersection (`elastocap.stereo.intersection_blocks`).

use numpy::{
    PyArray1, PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray2, PyReadonlyArray3,
    PyReadonlyArray4, PyUntypedArrayMethods,
};
use pyo3::prelude::*;

use super::{c_slice, invalid_input};
use crate::camera::Camera;
use crate::intersect::{intersect_views, IntersectOptions};
use crate::rigid::rigid_motions;

/// The arrays of the intersection: points `(N, 3)`, covariances `(N, 3, 3)`, residuals
/// `(N, C, 2)`, normalised residuals `(N, C)`, used views `(N, C)`, weighted squared
/// residual sums `(N,)`, converged `(N,)`.
type IntersectArrays<'py> = (
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray3<f64>>,
    Bound<'py, PyArray3<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<bool>>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<bool>>,
);

/// Forward intersection of `obs` `(N, C, 2)` pixels (NaN where not observed) with per-view
/// covariances `cov` `(N, C, 2, 2)` (pixels squared) through C cameras given as `k`, `r`
/// `(C, 3, 3)`, `dist` `(C, D)` (OpenCV order, D in 4, 5, 8, 12, 14), `t` `(C, 3)`;
/// `step_tolerance` in world units. The algorithm: `crate::intersect`.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
fn intersect_per_view<'py>(
    py: Python<'py>,
    obs: PyReadonlyArray3<'py, f64>,
    cov: PyReadonlyArray4<'py, f64>,
    k: PyReadonlyArray3<'py, f64>,
    dist: PyReadonlyArray2<'py, f64>,
    r: PyReadonlyArray3<'py, f64>,
    t: PyReadonlyArray2<'py, f64>,
    reject: bool,
    critical: f64,
    iterations: usize,
    step_tolerance: f64,
) -> PyResult<IntersectArrays<'py>> {
    let (n, c) = (obs.shape()[0], obs.shape()[1]);
    if obs.shape()[2] != 2 || cov.shape() != [n, c, 2, 2] {
        return Err(invalid_input(format!(
            "obs must have shape (N, C, 2) and cov (N, C, 2, 2), got {:?} and {:?}",
            obs.shape(),
            cov.shape()
        )));
    }
    if c == 0
        || k.shape() != [c, 3, 3]
        || r.shape() != [c, 3, 3]
        || t.shape() != [c, 3]
        || dist.shape()[0] != c
    {
        return Err(invalid_input(format!(
            "need K, dist, R, t for each of the {c} cameras"
        )));
    }
    let width = dist.shape()[1];
    let (k, dist, r, t) = (
        c_slice(&k, "K")?,
        c_slice(&dist, "dist")?,
        c_slice(&r, "R")?,
        c_slice(&t, "t")?,
    );
    let nine = |flat: &[f64], i: usize| -> [f64; 9] { std::array::from_fn(|j| flat[9 * i + j]) };
    let cameras = (0..c)
        .map(|i| {
            Camera::new(
                nine(k, i),
                &dist[width * i..width * (i + 1)],
                nine(r, i),
                [t[3 * i], t[3 * i + 1], t[3 * i + 2]],
                1,
                1,
            )
        })
        .collect::<crate::Result<Vec<_>>>()?;
    let obs = c_slice(&obs, "obs")?.as_chunks::<2>().0;
    let cov = c_slice(&cov, "cov")?.as_chunks::<4>().0;
    let options = IntersectOptions {
        reject,
        critical,
        iterations,
        step_tolerance,
    };
    let solved = super::detach(py, || intersect_views(&cameras, obs, cov, options));
    let mut points = Vec::with_capacity(3 * n);
    let mut covariances = Vec::with_capacity(9 * n);
    let mut residuals = Vec::with_capacity(2 * n * c);
    let mut normalised = Vec::with_capacity(n * c);
    let mut used = Vec::with_capacity(n * c);
    let mut quad = Vec::with_capacity(n);
    let mut converged = Vec::with_capacity(n);
    for p in solved {
        points.extend_from_slice(&p.point);
        covariances.extend(p.covariance.iter().flatten());
        residuals.extend(p.residuals.iter().flatten());
        normalised.extend_from_slice(&p.normalised);
        used.extend_from_slice(&p.used);
        quad.push(p.quad);
        converged.push(p.converged);
    }
    Ok((
        PyArray1::from_vec(py, points).reshape([n, 3])?,
        PyArray1::from_vec(py, covariances).reshape([n, 3, 3])?,
        PyArray1::from_vec(py, residuals).reshape([n, c, 2])?,
        PyArray1::from_vec(py, normalised).reshape([n, c])?,
        PyArray1::from_vec(py, used).reshape([n, c])?,
        PyArray1::from_vec(py, quad),
        PyArray1::from_vec(py, converged),
    ))
}

/// Weighted rigid fits `b ~ R a + t` of `a`, `b` `(M, K, 3)` with `weights` `(M, K)`
/// (non-negative, a positive sum per set): `R` `(M, 3, 3)`, `t` `(M, 3)`. The algorithm:
/// `crate::rigid`.
#[pyfunction]
fn rigid_fits<'py>(
    py: Python<'py>,
    a: PyReadonlyArray3<'py, f64>,
    b: PyReadonlyArray3<'py, f64>,
    weights: PyReadonlyArray2<'py, f64>,
) -> PyResult<(Bound<'py, PyArray3<f64>>, Bound<'py, PyArray2<f64>>)> {
    let (m, k) = (a.shape()[0], a.shape()[1]);
    if a.shape()[2] != 3 || b.shape() != a.shape() || weights.shape() != [m, k] || k == 0 {
        return Err(invalid_input(format!(
            "a, b must have one shape (M, K, 3) with K > 0 and weights (M, K), got {:?}, {:?}, {:?}",
            a.shape(),
            b.shape(),
            weights.shape()
        )));
    }
    let a = c_slice(&a, "a")?.as_chunks::<3>().0;
    let b = c_slice(&b, "b")?.as_chunks::<3>().0;
    let weights = c_slice(&weights, "weights")?;
    let fits = super::detach(py, || rigid_motions(a, b, weights, k));
    let mut r = Vec::with_capacity(9 * m);
    let mut t = Vec::with_capacity(3 * m);
    for (rf, tf) in fits {
        r.extend_from_slice(&rf);
        t.extend_from_slice(&tf);
    }
    Ok((
        PyArray1::from_vec(py, r).reshape([m, 3, 3])?,
        PyArray1::from_vec(py, t).reshape([m, 3])?,
    ))
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(intersect_per_view, m)?)?;
    m.add_function(wrap_pyfunction!(rigid_fits, m)?)
}
