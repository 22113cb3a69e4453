//! Binding of point tracking: one frame of every camera, and correlation at candidates.

use numpy::{
    IntoPyArray, PyArray2, PyArray3, PyArray4, PyArrayMethods, PyReadonlyArray2, PyReadonlyArray3,
    PyUntypedArrayMethods,
};
use pyo3::prelude::*;

use super::{c_slice, invalid_input, rows};
use crate::lsm::{ImageView, Interpolation, MatchOptions};
use crate::track::{
    box_search_scores, ncc_at, ncc_at_decisive, track_cameras, CameraFrames, CameraStep,
    TrackOptions,
};

/// A C-contiguous float32 image as the core reads it.
pub(super) fn view<'a>(
    image: &'a PyReadonlyArray2<'_, f32>,
    argument: &str,
) -> PyResult<ImageView<'a>> {
    let shape = image.shape();
    Ok(ImageView {
        data: c_slice(image, argument)?,
        width: shape[1],
        height: shape[0],
    })
}

type Step<'py> = (
    Bound<'py, PyArray3<f64>>,
    Bound<'py, PyArray2<u8>>,
    Bound<'py, PyArray4<f64>>,
    Bound<'py, PyArray2<f64>>,
);

/// `(positions (C, N, 2), flags (C, N) uint8, covariance (C, N, 2, 2), correlation (C, N))`
/// for C cameras' previous and current images (C-contiguous float32) and the points'
/// positions `last` and `before` (C, N, 2) in the previous two frames. `weights`, when
/// given, is `(previous_weights, current_weights)`: per camera a float32 image of the
/// frame's size with the template pixels' weights (the silhouette masks, 0 to 1).
/// `weighted_box`: the box search correlates with the previous frame's weights too (a
/// template whose weights are all 1 is searched as without).
#[pyfunction]
#[allow(clippy::too_many_arguments)]
#[pyo3(signature = (previous, current, last, before, *, size=11, radius=4,
    min_correlation=0.8, forward_backward=0.3, max_iterations=15, min_texture=0.0,
    shift_only_iterations=1, weights=None, weighted_box=false))]
fn track_step<'py>(
    py: Python<'py>,
    previous: Vec<PyReadonlyArray2<'py, f32>>,
    current: Vec<PyReadonlyArray2<'py, f32>>,
    last: PyReadonlyArray3<'py, f64>,
    before: PyReadonlyArray3<'py, f64>,
    size: usize,
    radius: usize,
    min_correlation: f64,
    forward_backward: f64,
    max_iterations: usize,
    min_texture: f64,
    shift_only_iterations: usize,
    weights: Option<(
        Vec<PyReadonlyArray2<'py, f32>>,
        Vec<PyReadonlyArray2<'py, f32>>,
    )>,
    weighted_box: bool,
) -> PyResult<Step<'py>> {
    let c = previous.len();
    if current.len() != c {
        return Err(invalid_input(format!(
            "current must hold {c} images (one per camera of previous), got {}",
            current.len()
        )));
    }
    let shape = last.shape();
    if shape.len() != 3 || shape[0] != c || shape[2] != 2 || before.shape() != shape {
        return Err(invalid_input(format!(
            "last and before must have shape ({c}, N, 2), got {:?} and {:?}",
            shape,
            before.shape()
        )));
    }
    let n = shape[1];
    let prev = previous
        .iter()
        .map(|i| view(i, "previous"))
        .collect::<PyResult<Vec<_>>>()?;
    let cur = current
        .iter()
        .map(|i| view(i, "current"))
        .collect::<PyResult<Vec<_>>>()?;
    let weight_views = match &weights {
        Some((before_w, now_w)) => {
            if before_w.len() != c || now_w.len() != c {
                return Err(invalid_input(format!(
                    "weights must hold two lists of {c} images (one per camera), got {} and {}",
                    before_w.len(),
                    now_w.len()
                )));
            }
            let mut pairs = Vec::with_capacity(c);
            for k in 0..c {
                let (a, b) = (view(&before_w[k], "weights")?, view(&now_w[k], "weights")?);
                for (w, image) in [(&a, &prev[k]), (&b, &cur[k])] {
                    if w.width != image.width || w.height != image.height {
                        return Err(invalid_input(format!(
                            "weights of camera {k} must have the shape of its images, ({}, {}), got ({}, {})",
                            image.height, image.width, w.height, w.width
                        )));
                    }
                }
                pairs.push([a, b]);
            }
            Some(pairs)
        }
        None => None,
    };
    let last_rows = c_slice(&last, "last")?.as_chunks::<2>().0;
    let before_rows = c_slice(&before, "before")?.as_chunks::<2>().0;
    let options = TrackOptions {
        matching: MatchOptions {
            size,
            max_iterations,
            max_shift: (size / 2) as f64,
            min_texture,
            // SPEC 7's bilinear resampling: a quarter of bicubic's samples, and its bias
            // (hundredths of a pixel on sharp texture) is far below the tracker's error
            // on smooth printed textures (tenths).
            interpolation: Interpolation::Bilinear,
            shift_only_iterations,
            ..MatchOptions::default()
        },
        radius,
        min_correlation,
        forward_backward,
        weighted_box,
    };
    let positions = PyArray3::<f64>::zeros(py, [c, n, 2], false);
    let flags = PyArray2::<u8>::zeros(py, [c, n], false);
    let covariance = PyArray4::<f64>::zeros(py, [c, n, 2, 2], false);
    let correlation = PyArray2::<f64>::zeros(py, [c, n], false);
    {
        let mut positions_w = positions.readwrite();
        let mut flags_w = flags.readwrite();
        let mut covariance_w = covariance.readwrite();
        let mut correlation_w = correlation.readwrite();
        let positions_s = positions_w.as_slice_mut()?.as_chunks_mut::<2>().0;
        let flags_s = flags_w.as_slice_mut()?;
        let covariance_s = covariance_w.as_slice_mut()?.as_chunks_mut::<4>().0;
        let correlation_s = correlation_w.as_slice_mut()?;
        let cameras: Vec<CameraFrames<'_>> = (0..c)
            .map(|k| CameraFrames {
                previous: prev[k],
                current: cur[k],
                weights: weight_views.as_ref().map(|w| w[k]),
            })
            .collect();
        super::detach(py, || {
            track_cameras(
                &cameras,
                last_rows,
                before_rows,
                &options,
                CameraStep {
                    positions: positions_s,
                    flags: flags_s,
                    covariance: covariance_s,
                    correlation: correlation_s,
                },
            )
        })?;
    }
    Ok((positions, flags, covariance, correlation))
}

/// The rows of a correlation at candidates: `points` (N, 2), `candidates` (N, K, 2) as
/// `N K` rows, and `K`; checked, with the patch side `size`.
pub(super) fn candidate_rows<'a>(
    points: &'a PyReadonlyArray2<'_, f64>,
    candidates: &'a PyReadonlyArray3<'_, f64>,
    size: usize,
) -> PyResult<(&'a [[f64; 2]], &'a [[f64; 2]], usize)> {
    let p = rows::<2>(points, "points")?;
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
    let cand = c_slice(candidates, "candidates")?.as_chunks::<2>().0;
    Ok((p, cand, shape[1]))
}

/// `(N, K)` correlation of the template patch around each of `points` (N, 2) with the
/// patch of `search` around each of its `candidates` (N, K, 2); NaN where a patch leaves
/// its image or is flat. With `decide = (min_correlation, uniqueness)` (seeding's test)
/// only the scores that can decide that test are exact, the others -inf: in a row whose
/// best is below `min_correlation` any score may be -inf, in another a score below the
/// best minus `uniqueness` may be (`ncc_at_decisive`).
#[pyfunction]
#[pyo3(signature = (template, points, search, candidates, *, size=11, decide=None))]
fn track_ncc_at<'py>(
    py: Python<'py>,
    template: PyReadonlyArray2<'py, f32>,
    points: PyReadonlyArray2<'py, f64>,
    search: PyReadonlyArray2<'py, f32>,
    candidates: PyReadonlyArray3<'py, f64>,
    size: usize,
    decide: Option<(f64, f64)>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    use rayon::prelude::*;
    let t = view(&template, "template")?;
    let s = view(&search, "search")?;
    let (p, cand, k) = candidate_rows(&points, &candidates, size)?;
    let n = p.len();
    let scores = PyArray2::<f64>::zeros(py, [n, k], false);
    {
        let mut w = scores.readwrite();
        let out = w.as_slice_mut()?;
        super::detach(py, || {
            if k > 0 {
                out.par_chunks_mut(k)
                    .enumerate()
                    .for_each(|(i, row)| match decide {
                        Some((least, margin)) => ncc_at_decisive(
                            &t,
                            p[i],
                            &s,
                            &cand[i * k..(i + 1) * k],
                            size,
                            least,
                            margin,
                            row,
                        ),
                        None => ncc_at(&t, p[i], &s, &cand[i * k..(i + 1) * k], size, row),
                    });
            }
        });
    }
    Ok(scores)
}

/// The tracker's box search of one point: the template patch (side `size`) around
/// `point` in `template` searched in `search` over integer shifts up to `radius` around
/// `prediction`; `weights` (an image of `template`'s shape, 0 to 1) weighs the template's
/// pixels (the weighted correlation). `None` when a patch leaves its image or the template
/// is flat, else `(centre (2,), score, scores (2 radius + 1, 2 radius + 1))`: the sub-pixel
/// best centre, its correlation, and the correlation at every shift (row: shift down).
#[pyfunction]
#[allow(clippy::too_many_arguments)]
#[pyo3(signature = (template, point, search, prediction, *, size=15, radius=6, weights=None))]
fn track_box_search<'py>(
    py: Python<'py>,
    template: PyReadonlyArray2<'py, f32>,
    point: [f64; 2],
    search: PyReadonlyArray2<'py, f32>,
    prediction: [f64; 2],
    size: usize,
    radius: usize,
    weights: Option<PyReadonlyArray2<'py, f32>>,
) -> PyResult<Option<([f64; 2], f64, Bound<'py, PyArray2<f64>>)>> {
    let t = view(&template, "template")?;
    let s = view(&search, "search")?;
    if size < 3 || size % 2 == 0 || size > 255 {
        return Err(invalid_input(format!(
            "size must be an odd integer from 3 to 255, got {size}"
        )));
    }
    if radius > 64 {
        return Err(invalid_input(format!(
            "radius must be at most 64 pixels, got {radius}"
        )));
    }
    let w = match &weights {
        Some(w) => {
            let w = view(w, "weights")?;
            if w.width != t.width || w.height != t.height {
                return Err(invalid_input(format!(
                    "weights must have the template's shape, ({}, {}), got ({}, {})",
                    t.height, t.width, w.height, w.width
                )));
            }
            Some(w)
        }
        None => None,
    };
    let found = super::detach(py, || {
        box_search_scores(&t, point, &s, prediction, size, radius, w.as_ref())
    });
    Ok(match found {
        None => None,
        Some((best, scores)) => {
            let shifts = 2 * radius + 1;
            let array = scores.into_pyarray(py).reshape([shifts, shifts])?;
            Some((best.centre, best.score, array))
        }
    })
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(track_box_search, m)?)?;
    m.add_function(wrap_pyfunction!(track_step, m)?)?;
    m.add_function(wrap_pyfunction!(track_ncc_at, m)?)
}
