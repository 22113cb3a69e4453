//! Binding of the seeding's kernels: the visual hull's test of ray samples and the depth
//! search along a seed's ray. (The correlation along a seed's line is `track_ncc_at`'s.)

use numpy::{
    PyArray1, PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2,
    PyReadonlyArray3, PyUntypedArrayMethods,
};
use pyo3::prelude::*;

use super::{c_slice, invalid_input, rows};
use crate::camera::DIST_LEN;
use crate::track::{
    hull_depths, hull_inside, hull_pixels, line_peak, line_pixels, Away, DepthGrid, HullCamera,
    HullView,
};

/// Camera `i` of the flat arrays `r` (C x 9), `t` (C x 3), `k` (C x 9), `dist` (C x 12)
/// with a `width x height` image and its mask (empty where only pixels are wanted).
#[allow(clippy::too_many_arguments)]
fn view_of<'a>(
    r: &[f64],
    t: &[f64],
    k: &[f64],
    dist: &[f64],
    i: usize,
    width: usize,
    height: usize,
    mask: &'a [bool],
) -> HullView<'a> {
    HullView {
        r: std::array::from_fn(|a| std::array::from_fn(|b| r[9 * i + 3 * a + b])),
        t: std::array::from_fn(|a| t[3 * i + a]),
        camera: HullCamera {
            k: std::array::from_fn(|a| std::array::from_fn(|b| k[9 * i + 3 * a + b])),
            dist: std::array::from_fn(|a| dist[DIST_LEN * i + a]),
            width,
            height,
        },
        mask,
    }
}

/// The hull's cameras from the arrays (checked: one pose, intrinsics and lens per mask).
fn hull_views<'a>(
    r: &'a PyReadonlyArray3<'_, f64>,
    t: &'a PyReadonlyArray2<'_, f64>,
    k: &'a PyReadonlyArray3<'_, f64>,
    dist: &'a PyReadonlyArray2<'_, f64>,
    masks: &'a [PyReadonlyArray2<'_, bool>],
) -> PyResult<Vec<HullView<'a>>> {
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
    let (rv, tv) = (c_slice(r, "r")?, c_slice(t, "t")?);
    let (kv, dv) = (c_slice(k, "k")?, c_slice(dist, "dist")?);
    masks
        .iter()
        .enumerate()
        .map(|(i, mask)| {
            let shape = mask.shape();
            Ok(view_of(
                rv,
                tv,
                kv,
                dv,
                i,
                shape[1],
                shape[0],
                c_slice(mask, "masks")?,
            ))
        })
        .collect()
}

/// One camera from the arrays `r` (3, 3), `t` (3,), `k` (3, 3), `dist` (12,) (checked) with
/// a `width x height` image and no mask: the pixels' camera of `seed_pixels` and
/// `seed_line_pixels`.
fn one_view<'a>(
    r: &'a PyReadonlyArray2<'_, f64>,
    t: &'a PyReadonlyArray1<'_, f64>,
    k: &'a PyReadonlyArray2<'_, f64>,
    dist: &'a PyReadonlyArray1<'_, f64>,
    width: usize,
    height: usize,
) -> PyResult<HullView<'a>> {
    if r.shape() != [3, 3] || t.len() != 3 || k.shape() != [3, 3] || dist.len() != DIST_LEN {
        return Err(invalid_input(format!(
            "r and k must have shape (3, 3), t (3,) and dist ({DIST_LEN},), got {:?}, {:?}, {:?} and {:?}",
            r.shape(),
            k.shape(),
            t.shape(),
            dist.shape()
        )));
    }
    let (rv, tv) = (c_slice(r, "r")?, c_slice(t, "t")?);
    let (kv, dv) = (c_slice(k, "k")?, c_slice(dist, "dist")?);
    Ok(view_of(rv, tv, kv, dv, 0, width, height, &[]))
}

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
    let views = hull_views(&r, &t, &k, &dist, &masks)?;
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

/// The depth search of the rays `origins`, `dirs` (M, 3; finite) through the visual hull
/// of the cameras (as `seed_hull_inside`): the ray's first run through the hull on the
/// depths `coarse` (K,), widened by `step` on both ends, sampled at `fractions` (D,) of
/// it: `(fine (M, D, 3) world points, inside (M, D) bool)`, inside all false for a ray
/// that never enters the hull. numpy's `_hull_depths` before "seedfast1", bit for bit.
#[pyfunction]
#[pyo3(signature = (origins, dirs, coarse, fractions, step, r, t, k, dist, masks, *, min_seen))]
#[allow(clippy::too_many_arguments)]
fn seed_hull_depths<'py>(
    py: Python<'py>,
    origins: PyReadonlyArray2<'py, f64>,
    dirs: PyReadonlyArray2<'py, f64>,
    coarse: PyReadonlyArray1<'py, f64>,
    fractions: PyReadonlyArray1<'py, f64>,
    step: f64,
    r: PyReadonlyArray3<'py, f64>,
    t: PyReadonlyArray2<'py, f64>,
    k: PyReadonlyArray3<'py, f64>,
    dist: PyReadonlyArray2<'py, f64>,
    masks: Vec<PyReadonlyArray2<'py, bool>>,
    min_seen: usize,
) -> PyResult<(Bound<'py, PyArray3<f64>>, Bound<'py, PyArray2<bool>>)> {
    use rayon::prelude::*;
    let origins = rows::<3>(&origins, "origins")?;
    let dirs = rows::<3>(&dirs, "dirs")?;
    if dirs.len() != origins.len() {
        return Err(invalid_input(format!(
            "origins and dirs must hold as many rays, got {} and {}",
            origins.len(),
            dirs.len()
        )));
    }
    let coarse = c_slice(&coarse, "coarse")?;
    let fractions = c_slice(&fractions, "fractions")?;
    if coarse.len() < 2 || fractions.is_empty() {
        return Err(invalid_input(format!(
            "coarse needs 2 depths at least and fractions 1, got {} and {}",
            coarse.len(),
            fractions.len()
        )));
    }
    let views = hull_views(&r, &t, &k, &dist, &masks)?;
    let grid = DepthGrid {
        coarse,
        fractions,
        step,
        views: &views,
        min_seen,
    };
    let (m, d) = (origins.len(), fractions.len());
    let fine = PyArray3::<f64>::zeros(py, [m, d, 3], false);
    let inside = PyArray2::<bool>::zeros(py, [m, d], false);
    {
        let mut fw = fine.readwrite();
        let mut iw = inside.readwrite();
        let fine_out = fw.as_slice_mut()?.as_chunks_mut::<3>().0;
        let inside_out = iw.as_slice_mut()?;
        super::detach(py, || {
            // Rays in groups: a ray's search is ~100-200 hull tests.
            const RAYS: usize = 16;
            fine_out
                .par_chunks_mut(RAYS * d)
                .zip(inside_out.par_chunks_mut(RAYS * d))
                .zip(origins.par_chunks(RAYS).zip(dirs.par_chunks(RAYS)))
                .for_each(|((f, i), (o, dr))| hull_depths(o, dr, &grid, f, i));
        });
    }
    Ok((fine, inside))
}

/// `(uv (N, 2), seen (N,))`: the pixels of world points `points` (N, 3) in the camera
/// `r` (3, 3), `t` (3,), `k` (3, 3), `dist` (12,) with a `width x height` image, and whether
/// each is seen (in front, inside the pixel footprints). `Camera.project`'s pixels wherever
/// they are finite, bit for bit (the hull test's arithmetic, `seed_hull_inside`).
#[pyfunction]
#[pyo3(signature = (points, r, t, k, dist, *, width, height))]
#[allow(clippy::too_many_arguments)]
fn seed_pixels<'py>(
    py: Python<'py>,
    points: PyReadonlyArray2<'py, f64>,
    r: PyReadonlyArray2<'py, f64>,
    t: PyReadonlyArray1<'py, f64>,
    k: PyReadonlyArray2<'py, f64>,
    dist: PyReadonlyArray1<'py, f64>,
    width: usize,
    height: usize,
) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyArray1<bool>>)> {
    use rayon::prelude::*;
    let points = rows::<3>(&points, "points")?;
    let view = one_view(&r, &t, &k, &dist, width, height)?;
    let n = points.len();
    let uv = PyArray2::<f64>::zeros(py, [n, 2], false);
    let seen = PyArray1::<bool>::zeros(py, n, false);
    {
        let mut uw = uv.readwrite();
        let mut sw = seen.readwrite();
        let uv_out = uw.as_slice_mut()?.as_chunks_mut::<2>().0;
        let seen_out = sw.as_slice_mut()?;
        super::detach(py, || {
            uv_out
                .par_chunks_mut(4096)
                .zip(seen_out.par_chunks_mut(4096))
                .zip(points.par_chunks(4096))
                .for_each(|((u, s), p)| hull_pixels(p, &view, u, s));
        });
    }
    Ok((uv, seen))
}

/// `uv (T, D, 2)`: the pixels of the seed rays' samples `points[rows]` (M, D, 3; `rows`
/// (T,) indices into M) in the partner camera `r`, `t`, `k`, `dist` with a `width x height`
/// image, after numpy's `nan_to_num`, and `-1e6` (both coordinates) where the sample is not
/// `inside` (M, D) the hull: the line `track_ncc_at` scores, in one parallel call (numpy
/// gathered, cleaned, projected (`seed_pixels`) and masked them on one core).
#[pyfunction]
#[pyo3(signature = (points, inside, rows, r, t, k, dist, *, width, height))]
#[allow(clippy::too_many_arguments)]
fn seed_line_pixels<'py>(
    py: Python<'py>,
    points: PyReadonlyArray3<'py, f64>,
    inside: PyReadonlyArray2<'py, bool>,
    rows: PyReadonlyArray1<'py, i64>,
    r: PyReadonlyArray2<'py, f64>,
    t: PyReadonlyArray1<'py, f64>,
    k: PyReadonlyArray2<'py, f64>,
    dist: PyReadonlyArray1<'py, f64>,
    width: usize,
    height: usize,
) -> PyResult<Bound<'py, PyArray3<f64>>> {
    use rayon::prelude::*;
    let [m, d, three] = [points.shape()[0], points.shape()[1], points.shape()[2]];
    if three != 3 || inside.shape() != [m, d] {
        return Err(invalid_input(format!(
            "points must have shape (M, D, 3) and inside (M, D), got {:?} and {:?}",
            points.shape(),
            inside.shape()
        )));
    }
    let samples = c_slice(&points, "points")?.as_chunks::<3>().0;
    let held = c_slice(&inside, "inside")?;
    let picked = c_slice(&rows, "rows")?;
    if let Some(&bad) = picked.iter().find(|&&i| i < 0 || i as usize >= m) {
        return Err(invalid_input(format!(
            "rows must index the {m} rays, got {bad}"
        )));
    }
    let view = one_view(&r, &t, &k, &dist, width, height)?;
    let uv = PyArray3::<f64>::zeros(py, [picked.len(), d, 2], false);
    if d > 0 {
        let mut uw = uv.readwrite();
        let out = uw.as_slice_mut()?.as_chunks_mut::<2>().0;
        super::detach(py, || {
            // Rays in groups of 16 (~1,500 samples a task), each with its own scratch.
            const RAYS: usize = 16;
            out.par_chunks_mut(RAYS * d)
                .zip(picked.par_chunks(RAYS))
                .for_each(|(o, group)| {
                    let (mut finite, mut seen) = (Vec::with_capacity(d), Vec::with_capacity(d));
                    for (o, &i) in o.chunks_exact_mut(d).zip(group) {
                        let i = i as usize;
                        let ray = i * d..(i + 1) * d;
                        line_pixels(
                            &samples[ray.clone()],
                            &held[ray],
                            &view,
                            o,
                            (&mut finite, &mut seen),
                        );
                    }
                });
        });
    }
    Ok(uv)
}

/// `(best (T,) int64, peak (T,), second (T,))` of each line's `scores` (T, D; NaN or
/// infinite where not scored): the first index of the largest finite score, that score
/// (-inf if none), and the largest finite local maximum away from it (-inf if none): more
/// than `width` samples apart, or with `pixels`, more than `pixels` apart in the partner's
/// image by `uv` (T, D, 2). `seed_points`' numpy chain, to the bit, in parallel.
#[pyfunction]
#[pyo3(signature = (scores, *, width, uv=None, pixels=None))]
#[allow(clippy::type_complexity)]
fn seed_line_peaks<'py>(
    py: Python<'py>,
    scores: PyReadonlyArray2<'py, f64>,
    width: usize,
    uv: Option<PyReadonlyArray3<'py, f64>>,
    pixels: Option<f64>,
) -> PyResult<(
    Bound<'py, PyArray1<i64>>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<f64>>,
)> {
    use rayon::prelude::*;
    let [t, d] = [scores.shape()[0], scores.shape()[1]];
    let values = c_slice(&scores, "scores")?;
    let (away, lines): (Away, &[[f64; 2]]) = match (pixels, &uv) {
        (None, _) => (Away::Samples(width), &[]),
        (Some(p), Some(uv)) if uv.shape() == [t, d, 2] => {
            (Away::Pixels(p), c_slice(uv, "uv")?.as_chunks::<2>().0)
        }
        (Some(_), _) => {
            return Err(invalid_input(format!(
                "pixels needs uv of shape ({t}, {d}, 2), got {:?}",
                uv.as_ref().map(|u| u.shape().to_vec())
            )))
        }
    };
    if d == 0 {
        return Err(invalid_input(
            "scores must have a sample a line at least".to_string(),
        ));
    }
    let best = PyArray1::<i64>::zeros(py, t, false);
    let peak = PyArray1::<f64>::zeros(py, t, false);
    let second = PyArray1::<f64>::zeros(py, t, false);
    {
        let (mut bw, mut pw, mut sw) = (best.readwrite(), peak.readwrite(), second.readwrite());
        let (bo, po, so) = (bw.as_slice_mut()?, pw.as_slice_mut()?, sw.as_slice_mut()?);
        super::detach(py, || {
            // Lines in groups of 64 (~6,000 scores a task).
            const LINES: usize = 64;
            bo.par_chunks_mut(LINES)
                .zip(po.par_chunks_mut(LINES))
                .zip(so.par_chunks_mut(LINES))
                .enumerate()
                .for_each(|(g, ((b, p), s))| {
                    for (j, ((b, p), s)) in b.iter_mut().zip(p).zip(s).enumerate() {
                        let i = g * LINES + j;
                        let line = &values[i * d..(i + 1) * d];
                        let pixels = if lines.is_empty() {
                            &[][..]
                        } else {
                            &lines[i * d..(i + 1) * d]
                        };
                        let (bi, pi, si) = line_peak(line, pixels, away);
                        (*b, *p, *s) = (bi as i64, pi, si);
                    }
                });
        });
    }
    Ok((best, peak, second))
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(seed_hull_inside, m)?)?;
    m.add_function(wrap_pyfunction!(seed_hull_depths, m)?)?;
    m.add_function(wrap_pyfunction!(seed_pixels, m)?)?;
    m.add_function(wrap_pyfunction!(seed_line_pixels, m)?)?;
    m.add_function(wrap_pyfunction!(seed_line_peaks, m)?)
}
