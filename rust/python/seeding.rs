//! Binding of the seeding's kernels: the correlation along a seed's line, and the visual
//! hull's test of ray samples in one camera.

use numpy::{
    PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArray3,
    PyUntypedArrayMethods,
};
use pyo3::prelude::*;

use super::{c_slice, invalid_input, rows};
use crate::camera::DIST_LEN;
use crate::lsm::ImageView;
use crate::track::{line_ncc, HullCamera};

fn view<'a>(image: &'a PyReadonlyArray2<'_, f32>, argument: &str) -> PyResult<ImageView<'a>> {
    let shape = image.shape();
    Ok(ImageView {
        data: c_slice(image, argument)?,
        width: shape[1],
        height: shape[0],
    })
}

/// `(N, K)` correlation of the template patch (side `size`) around each of `points` (N, 2)
/// in `template` with the patch of `search` around each of that point's `candidates`
/// (N, K, 2; bilinear); NaN where a patch leaves its image or is flat. The same numbers,
/// bit for bit, as `track_ncc_at` (several candidates' sums interleaved: faster).
#[pyfunction]
#[pyo3(signature = (template, points, search, candidates, *, size=11))]
fn seed_line_ncc<'py>(
    py: Python<'py>,
    template: PyReadonlyArray2<'py, f32>,
    points: PyReadonlyArray2<'py, f64>,
    search: PyReadonlyArray2<'py, f32>,
    candidates: PyReadonlyArray3<'py, f64>,
    size: usize,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    use rayon::prelude::*;
    let t = view(&template, "template")?;
    let s = view(&search, "search")?;
    let p = rows::<2>(&points, "points")?;
    let n = p.len();
    let shape = candidates.shape();
    if shape[0] != n || shape[2] != 2 {
        return Err(invalid_input(format!(
            "candidates must have shape ({n}, K, 2), got {shape:?}"
        )));
    }
    if size < 3 || size % 2 == 0 || size > 255 {
        return Err(invalid_input(format!(
            "size must be an odd integer from 3 to 255, got {size}"
        )));
    }
    let k = shape[1];
    let cand = c_slice(&candidates, "candidates")?.as_chunks::<2>().0;
    let scores = PyArray2::<f64>::zeros(py, [n, k], false);
    {
        let mut w = scores.readwrite();
        let out = w.as_slice_mut()?;
        super::detach(py, || {
            if k > 0 {
                out.par_chunks_mut(k).enumerate().for_each(|(i, row)| {
                    line_ncc(&t, p[i], &s, &cand[i * k..(i + 1) * k], size, row)
                });
            }
        });
    }
    Ok(scores)
}

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
    m.add_function(wrap_pyfunction!(seed_line_ncc, m)?)?;
    m.add_function(wrap_pyfunction!(seed_hull_held, m)?)
}
