//! Binding of voxel carving.

use numpy::{
    PyArray1, PyArray3, PyArrayMethods, PyReadonlyArray2, PyReadonlyArray3, PyUntypedArrayMethods,
};
use pyo3::prelude::*;

use super::{c_slice, invalid_input};
use crate::camera::Camera;
use crate::carve::{carve_masks, Footprint, GridSpec, Mask};

/// Row `c` of a flat array of rows of `N` (lengths are checked by the caller).
fn row<const N: usize>(flat: &[f64], c: usize) -> [f64; N] {
    std::array::from_fn(|i| flat[N * c + i])
}

/// Carves a visual hull. `k`, `r`: `(C, 3, 3)`; `dist`: `(C, 4|5|8|12|14)` (OpenCV order); `t`: `(C, 3)`;
/// `masks`: C arrays `(H, W)` uint8 (non-zero = foreground), in camera order.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
#[pyo3(signature = (masks, k, dist, r, t, origin, spacing, shape, tolerance=0, footprint="conservative"))]
fn carve<'py>(
    py: Python<'py>,
    masks: Vec<PyReadonlyArray2<'py, u8>>,
    k: PyReadonlyArray3<'py, f64>,
    dist: PyReadonlyArray2<'py, f64>,
    r: PyReadonlyArray3<'py, f64>,
    t: PyReadonlyArray2<'py, f64>,
    origin: [f64; 3],
    spacing: f64,
    shape: [usize; 3],
    tolerance: usize,
    footprint: &str,
) -> PyResult<Bound<'py, PyArray3<bool>>> {
    let footprint = match footprint {
        "conservative" => Footprint::Conservative,
        "center" => Footprint::Center,
        other => {
            return Err(invalid_input(format!(
                "footprint must be 'conservative' or 'center', got {other:?}"
            )))
        }
    };
    let n = masks.len();
    let k = c_slice(&k, "K")?;
    let width_of_dist = dist.shape()[1];
    let dist = c_slice(&dist, "dist")?;
    let r = c_slice(&r, "R")?;
    let t = c_slice(&t, "t")?;
    if k.len() != 9 * n || r.len() != 9 * n || dist.len() != width_of_dist * n || t.len() != 3 * n {
        return Err(invalid_input(format!(
            "need K, dist, R, t for each of the {n} masks"
        )));
    }
    let mut cameras = Vec::with_capacity(n);
    let mut views = Vec::with_capacity(n);
    for (c, mask) in masks.iter().enumerate() {
        let (height, width) = (mask.shape()[0], mask.shape()[1]);
        let coefficients = &dist[width_of_dist * c..width_of_dist * (c + 1)];
        let camera = Camera::new(row(k, c), coefficients, row(r, c), row(t, c), width, height)?;
        cameras.push(camera);
        views.push(Mask {
            pixels: c_slice(mask, "masks")?,
            width,
            height,
        });
    }
    let grid = GridSpec {
        origin,
        spacing,
        shape,
    };
    let occupancy = super::detach(py, || {
        carve_masks(&cameras, &views, grid, tolerance, footprint)
    })?;
    PyArray1::from_vec(py, occupancy).reshape(shape)
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(carve, m)?)
}
