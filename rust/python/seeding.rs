//! Binding of the seeding's kernel: the visual hull's test of ray samples.
//! (The correlation along a seed's line is `track_ncc_at`'s.)

use numpy::{PyArray1, PyArrayMethods, PyReadonlyArray2, PyReadonlyArray3, PyUntypedArrayMethods};
use pyo3::prelude::*;

use super::{c_slice, invalid_input, rows};
use crate::camera::DIST_LEN;
use crate::track::{hull_inside, HullCamera, HullView};

/// `(N,)` bool: whether each world point of `points` (N, 3) lies in the visual hull of the
/// cameras `r` (C, 3, 3), `t` (C, 3), `k` (C, 3, 3), `dist` (C, 12) with silhouettes `masks`
/// (C arrays (H, W) bool, each its camera's image): finite, inside every mask where that
/// camera sees it (in front, inside the image's pixel footprints; the mask read at the
/// nearest pixel), and seen by at least `min_seen` of them. Pixels as
/// `elastocap.tracking.seeding._seen_pixels`, bit for bit.
#[pyfunction]
#[pyo3(signature = (points, r, t, k, dist, masks, *, min_seen))]
#[allow(clippy::too_many_arguments)]
fn seed_hull_inside<'py>(
    py: Python<'py>,
    points: PyReadonlyArray2<'py, f64>,
    r: PyReadonlyArray3<'py, f64>,
    t: PyReadonlyArray2<'py, f64>,
    k: PyReadonlyArray3<'py, f64>,
    dist: PyReadonlyArray2<'py, f64>,
    masks: Vec<PyReadonlyArray2<'py, bool>>,
    min_seen: usize,
) -> PyResult<Bound<'py, PyArray1<bool>>> {
    use rayon::prelude::*;
    let points = rows::<3>(&points, "points")?;
    let c = masks.len();
    if r.shape() != [c, 3, 3]
        || t.shape() != [c, 3]
        || k.shape() != [c, 3, 3]
        || dist.shape() != [c, DIST_LEN]
    {
        return Err(invalid_input(format!(
            "for {c} masks r and k must have shape ({c}, 3, 3), t ({c}, 3) and dist ({c}, {DIST_LEN}), \
             got {:?}, {:?}, {:?} and {:?}",
            r.shape(),
            k.shape(),
            t.shape(),
            dist.shape()
        )));
    }
    let (rv, tv) = (c_slice(&r, "r")?, c_slice(&t, "t")?);
    let (kv, dv) = (c_slice(&k, "k")?, c_slice(&dist, "dist")?);
    let views = masks
        .iter()
        .enumerate()
        .map(|(i, mask)| {
            let shape = mask.shape();
            Ok(HullView {
                r: std::array::from_fn(|a| std::array::from_fn(|b| rv[9 * i + 3 * a + b])),
                t: std::array::from_fn(|a| tv[3 * i + a]),
                camera: HullCamera {
                    k: std::array::from_fn(|a| std::array::from_fn(|b| kv[9 * i + 3 * a + b])),
                    dist: std::array::from_fn(|a| dv[DIST_LEN * i + a]),
                    width: shape[1],
                    height: shape[0],
                },
                mask: c_slice(mask, "masks")?,
            })
        })
        .collect::<PyResult<Vec<_>>>()?;
    let inside = PyArray1::<bool>::zeros(py, points.len(), false);
    {
        let mut w = inside.readwrite();
        let out = w.as_slice_mut()?;
        super::detach(py, || {
            // Chunks: a sample's test is a few dozen operations per camera.
            out.par_chunks_mut(4096)
                .zip(points.par_chunks(4096))
                .for_each(|(o, p)| hull_inside(p, &views, min_seen, o));
        });
    }
    Ok(inside)
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(seed_hull_inside, m)?)
}
