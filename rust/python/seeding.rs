//! Binding of the seeding's kernel: the visual hull's test of ray samples in one camera.
//! (The correlation along a seed's line is `track_ncc_at`'s.)

use numpy::{PyArray1, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;

use super::{c_slice, invalid_input, rows};
use crate::camera::DIST_LEN;
use crate::track::HullCamera;

/// `(held (N,), seen (N,))` bool for camera coordinates `x` (N, 3) of one camera with
/// intrinsics `k` (3, 3) and distortion `dist` (12,) and its mask (H, W) bool: seen = in
/// front and inside the image's pixel footprints, held = the mask at the nearest pixel
/// where seen, true elsewhere. Pixels as `elastocap.tracking.seeding._seen_pixels`, bit
/// for bit.
#[pyfunction]
fn seed_hull_held<'py>(
    py: Python<'py>,
    x: PyReadonlyArray2<'py, f64>,
    k: PyReadonlyArray2<'py, f64>,
    dist: PyReadonlyArray1<'py, f64>,
    mask: PyReadonlyArray2<'py, bool>,
) -> PyResult<(Bound<'py, PyArray1<bool>>, Bound<'py, PyArray1<bool>>)> {
    use rayon::prelude::*;
    let x = rows::<3>(&x, "x")?;
    if k.shape() != [3, 3] || dist.len() != DIST_LEN {
        return Err(invalid_input(format!(
            "k must have shape (3, 3) and dist ({DIST_LEN},), got {:?} and {:?}",
            k.shape(),
            dist.shape()
        )));
    }
    let kv = c_slice(&k, "k")?;
    let dv = c_slice(&dist, "dist")?;
    let shape = mask.shape();
    let camera = HullCamera {
        k: std::array::from_fn(|i| std::array::from_fn(|j| kv[3 * i + j])),
        dist: std::array::from_fn(|i| dv[i]),
        width: shape[1],
        height: shape[0],
    };
    let m = c_slice(&mask, "mask")?;
    let n = x.len();
    let mut held = vec![false; n];
    let mut seen = vec![false; n];
    super::detach(py, || {
        // Chunks: the per-sample work is a few dozen operations.
        held.par_chunks_mut(4096)
            .zip(seen.par_chunks_mut(4096))
            .zip(x.par_chunks(4096))
            .for_each(|((h, s), x)| {
                for ((h, s), &x) in h.iter_mut().zip(s.iter_mut()).zip(x) {
                    (*h, *s) = camera.held(x, m);
                }
            });
    });
    Ok((PyArray1::from_vec(py, held), PyArray1::from_vec(py, seen)))
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(seed_hull_held, m)?)
}
