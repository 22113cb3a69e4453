//! Binding of least-squares matching.

use numpy::{
    PyArray1, PyArray2, PyArray3, PyArray4, PyArrayMethods, PyReadonlyArray2, PyReadonlyArray3,
    PyUntypedArrayMethods,
};
use pyo3::prelude::*;

use super::{c_slice, invalid_input, rows};
use crate::lsm::{
    match_pair_patches, match_staged_patches, ExtraModel, ImageView, Interpolation, MatchOptions,
    MatchOutput, Stage, Warp, PARAMETERS,
};

type Matches<'py> = (
    Bound<'py, PyArray2<u8>>,
    Bound<'py, PyArray4<f64>>,
    Bound<'py, PyArray3<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<u32>>,
    Bound<'py, PyArray3<f64>>,
    Bound<'py, PyArray3<f64>>,
    Bound<'py, PyArray2<u8>>,
);

fn view<'a>(image: &'a PyReadonlyArray2<'_, f32>, argument: &str) -> PyResult<ImageView<'a>> {
    let shape = image.shape();
    Ok(ImageView {
        data: c_slice(image, argument)?,
        width: shape[1],
        height: shape[0],
    })
}

/// `(status (N, S) uint8, affine (N, S, 2, 3), radiometry (N, S, 2) [gain, offset],
/// sigma0 (N, S), correlation (N, S), iterations (N, S) uint32, covariance (N, 8S, 8S),
/// affine_centre (N, S, 2), refined (N, S) uint8)`: the last two the richer stage's record
/// (`Stage`: the converged affine match's centre, NaN where none, and the `Refined` code).
/// Images are C-contiguous float32; `initial` is `(N, S, 6)` row-major 2x3 maps;
/// `epipolar` `(N, S, 3)` lines. `weights`, the template's shape (float32), weighs its
/// pixels (weighted least squares). `threads` runs the batch on its own pool of that size.
/// `extra_iterations` > 0 refines a converged match with the richer model (`extra_warp`
/// "affine", "projective" or "quadratic", `extra_gain_gradient`, the priors' standard
/// deviations `extra_warp_sigma` px and `extra_gain_sigma`, 0 = none, `extra_fallback`:
/// the affine match where the richer one does not converge, `extra_jacobian` "search" or
/// "template", `extra_skip_correlation`: no richer stage where the affine match's
/// correlation is at least this); 0 is the affine match.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
#[pyo3(signature = (template, points, search_images, initial, epipolar=None, *, size=11,
    max_iterations=30, tolerance=0.01, max_shift=5.0, max_scale=3.0, min_texture=0.0,
    line_sigma=0.0, shift_only_iterations=1, interpolation="bicubic", threads=None, weights=None,
    extra_iterations=0, extra_warp="affine", extra_gain_gradient=false, extra_warp_sigma=0.0,
    extra_gain_sigma=0.0, extra_fallback=false, extra_jacobian="search",
    extra_skip_correlation=f64::INFINITY))]
fn lsm_match_patches<'py>(
    py: Python<'py>,
    template: PyReadonlyArray2<'py, f32>,
    points: PyReadonlyArray2<'py, f64>,
    search_images: Vec<PyReadonlyArray2<'py, f32>>,
    initial: PyReadonlyArray3<'py, f64>,
    epipolar: Option<PyReadonlyArray3<'py, f64>>,
    size: usize,
    max_iterations: usize,
    tolerance: f64,
    max_shift: f64,
    max_scale: f64,
    min_texture: f64,
    line_sigma: f64,
    shift_only_iterations: usize,
    interpolation: &str,
    threads: Option<usize>,
    weights: Option<PyReadonlyArray2<'py, f32>>,
    extra_iterations: usize,
    extra_warp: &str,
    extra_gain_gradient: bool,
    extra_warp_sigma: f64,
    extra_gain_sigma: f64,
    extra_fallback: bool,
    extra_jacobian: &str,
    extra_skip_correlation: f64,
) -> PyResult<Matches<'py>> {
    let template_view = view(&template, "template")?;
    let weights_view = weights.as_ref().map(|w| view(w, "weights")).transpose()?;
    if let Some(w) = &weights_view {
        if w.width != template_view.width || w.height != template_view.height {
            return Err(invalid_input(format!(
                "weights must have the template's shape ({}, {}), got ({}, {})",
                template_view.height, template_view.width, w.height, w.width
            )));
        }
    }
    let points_rows = rows::<2>(&points, "points")?;
    let searches = search_images
        .iter()
        .map(|image| view(image, "search_images"))
        .collect::<PyResult<Vec<_>>>()?;
    let (n, s) = (points_rows.len(), searches.len());
    if initial.shape() != [n, s, 6] {
        return Err(invalid_input(format!(
            "initial must have shape ({n}, {s}, 6), got {:?}",
            initial.shape()
        )));
    }
    let starts = c_slice(&initial, "initial")?.as_chunks::<6>().0;
    let lines = match &epipolar {
        Some(lines) => {
            if lines.shape() != [n, s, 3] {
                return Err(invalid_input(format!(
                    "epipolar must have shape ({n}, {s}, 3), got {:?}",
                    lines.shape()
                )));
            }
            Some(c_slice(lines, "epipolar")?.as_chunks::<3>().0)
        }
        None => None,
    };
    if threads == Some(0) {
        return Err(invalid_input("threads must be at least 1".into()));
    }
    let interpolation = match interpolation {
        "bilinear" => Interpolation::Bilinear,
        "bicubic" => Interpolation::Bicubic,
        other => {
            return Err(invalid_input(format!(
                "interpolation must be 'bilinear' or 'bicubic', got {other:?}"
            )))
        }
    };
    let warp = match extra_warp {
        "affine" => Warp::Affine,
        "projective" => Warp::Projective,
        "quadratic" => Warp::Quadratic,
        other => {
            return Err(invalid_input(format!(
                "extra_warp must be 'affine', 'projective' or 'quadratic', got {other:?}"
            )))
        }
    };
    let template_jacobian = match extra_jacobian {
        "search" => false,
        "template" => true,
        other => {
            return Err(invalid_input(format!(
                "extra_jacobian must be 'search' or 'template', got {other:?}"
            )))
        }
    };
    let options = MatchOptions {
        size,
        max_iterations,
        tolerance,
        max_shift,
        max_scale,
        min_texture,
        line_sigma,
        shift_only_iterations,
        interpolation,
        sandwich: true,
        extra: ExtraModel {
            iterations: extra_iterations,
            warp,
            gain_gradient: extra_gain_gradient,
            warp_sigma: extra_warp_sigma,
            gain_sigma: extra_gain_sigma,
            fallback: extra_fallback,
            template_jacobian,
            skip_correlation: extra_skip_correlation,
        },
    };
    let width = PARAMETERS * s;
    let status = PyArray2::<u8>::zeros(py, [n, s], false);
    let affine = PyArray4::<f64>::zeros(py, [n, s, 2, 3], false);
    let radiometry = PyArray3::<f64>::zeros(py, [n, s, 2], false);
    let sigma0 = PyArray2::<f64>::zeros(py, [n, s], false);
    let correlation = PyArray2::<f64>::zeros(py, [n, s], false);
    let iterations = PyArray2::<u32>::zeros(py, [n, s], false);
    let covariance = PyArray3::<f64>::zeros(py, [n, width, width], false);
    let mut stages = vec![Stage::NONE; n * s];
    {
        let mut status_w = status.readwrite();
        let mut affine_w = affine.readwrite();
        let mut radiometry_w = radiometry.readwrite();
        let mut sigma0_w = sigma0.readwrite();
        let mut correlation_w = correlation.readwrite();
        let mut iterations_w = iterations.readwrite();
        let mut covariance_w = covariance.readwrite();
        let out = MatchOutput {
            status: status_w.as_slice_mut()?,
            affine: affine_w.as_slice_mut()?.as_chunks_mut::<6>().0,
            radiometry: radiometry_w.as_slice_mut()?.as_chunks_mut::<2>().0,
            sigma0: sigma0_w.as_slice_mut()?,
            correlation: correlation_w.as_slice_mut()?,
            iterations: iterations_w.as_slice_mut()?,
            covariance: covariance_w.as_slice_mut()?,
        };
        let run = || {
            match_staged_patches(
                &template_view,
                weights_view.as_ref(),
                points_rows,
                &searches,
                starts,
                lines,
                &options,
                out,
                &mut stages,
            )
        };
        super::detach(py, || match threads {
            Some(threads) => match rayon::ThreadPoolBuilder::new().num_threads(threads).build() {
                Ok(pool) => Ok(pool.install(run)),
                Err(e) => Err(e.to_string()),
            },
            None => Ok(run()),
        })
        .map_err(pyo3::exceptions::PyRuntimeError::new_err)??;
    }
    let affine_centre = PyArray3::<f64>::zeros(py, [n, s, 2], false);
    let refined = PyArray2::<u8>::zeros(py, [n, s], false);
    {
        let mut centre_w = affine_centre.readwrite();
        let mut refined_w = refined.readwrite();
        let centres = centre_w.as_slice_mut()?.as_chunks_mut::<2>().0;
        let codes = refined_w.as_slice_mut()?;
        for ((centre, code), stage) in centres.iter_mut().zip(codes.iter_mut()).zip(&stages) {
            *centre = stage.affine;
            *code = stage.refined as u8;
        }
    }
    Ok((
        status,
        affine,
        radiometry,
        sigma0,
        correlation,
        iterations,
        covariance,
        affine_centre,
        refined,
    ))
}

type PairMatches<'py> = (
    Bound<'py, PyArray1<u8>>,
    Bound<'py, PyArray3<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<u32>>,
    Bound<'py, PyArray3<f64>>,
);

fn optional_views<'a>(
    images: &'a [Option<PyReadonlyArray2<'_, f32>>],
    argument: &str,
) -> PyResult<Vec<Option<ImageView<'a>>>> {
    images
        .iter()
        .map(|image| image.as_ref().map(|i| view(i, argument)).transpose())
        .collect()
}

/// Many patches across many camera pairs in one call (the tracker's spatial matches of a
/// frame): patch `i` around `points[i]` in `images[cameras[i, 0]]` matched into
/// `images[cameras[i, 1]]` from the start map `initial[i]` (`(N, 6)` row-major 2x3),
/// the template weighed by `weights[cameras[i, 0]]` where given. `images` (and `weights`)
/// are per camera, C-contiguous float32, `None` for a camera no patch uses. Runs in
/// parallel over patches with the GIL released; each patch's result is bit-identical to
/// `lsm_match_patches` on its pair alone (one search image, no epipolar line, no richer
/// stage). Returns `(status (N,) uint8, affine (N, 2, 3), radiometry (N, 2), sigma0 (N,),
/// correlation (N,), iterations (N,) uint32, covariance (N, 8, 8))`.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
#[pyo3(signature = (images, cameras, points, initial, *, size=11, max_iterations=30,
    tolerance=0.01, max_shift=5.0, max_scale=3.0, min_texture=0.0, shift_only_iterations=1,
    interpolation="bicubic", weights=None))]
fn lsm_match_pairs<'py>(
    py: Python<'py>,
    images: Vec<Option<PyReadonlyArray2<'py, f32>>>,
    cameras: PyReadonlyArray2<'py, i64>,
    points: PyReadonlyArray2<'py, f64>,
    initial: PyReadonlyArray2<'py, f64>,
    size: usize,
    max_iterations: usize,
    tolerance: f64,
    max_shift: f64,
    max_scale: f64,
    min_texture: f64,
    shift_only_iterations: usize,
    interpolation: &str,
    weights: Option<Vec<Option<PyReadonlyArray2<'py, f32>>>>,
) -> PyResult<PairMatches<'py>> {
    let image_views = optional_views(&images, "images")?;
    let weight_views = weights
        .as_ref()
        .map(|w| optional_views(w, "weights"))
        .transpose()?;
    let points_rows = rows::<2>(&points, "points")?;
    let n = points_rows.len();
    if cameras.shape() != [n, 2] {
        return Err(invalid_input(format!(
            "cameras must have shape ({n}, 2), got {:?}",
            cameras.shape()
        )));
    }
    let pairs = c_slice(&cameras, "cameras")?
        .as_chunks::<2>()
        .0
        .iter()
        .map(|&[r, k]| match (usize::try_from(r), usize::try_from(k)) {
            (Ok(r), Ok(k)) => Ok([r, k]),
            _ => Err(invalid_input(format!(
                "cameras must hold indices >= 0, got [{r}, {k}]"
            ))),
        })
        .collect::<PyResult<Vec<_>>>()?;
    if initial.shape() != [n, 6] {
        return Err(invalid_input(format!(
            "initial must have shape ({n}, 6), got {:?}",
            initial.shape()
        )));
    }
    let starts = c_slice(&initial, "initial")?.as_chunks::<6>().0;
    let interpolation = match interpolation {
        "bilinear" => Interpolation::Bilinear,
        "bicubic" => Interpolation::Bicubic,
        other => {
            return Err(invalid_input(format!(
                "interpolation must be 'bilinear' or 'bicubic', got {other:?}"
            )))
        }
    };
    // `lsm_match_patches`' defaults for everything not given here: no line, no richer stage.
    let options = MatchOptions {
        size,
        max_iterations,
        tolerance,
        max_shift,
        max_scale,
        min_texture,
        line_sigma: 0.0,
        shift_only_iterations,
        interpolation,
        sandwich: true,
        extra: ExtraModel {
            iterations: 0,
            warp: Warp::Affine,
            gain_gradient: false,
            warp_sigma: 0.0,
            gain_sigma: 0.0,
            fallback: false,
            template_jacobian: false,
            skip_correlation: f64::INFINITY,
        },
    };
    let status = PyArray1::<u8>::zeros(py, [n], false);
    let affine = PyArray3::<f64>::zeros(py, [n, 2, 3], false);
    let radiometry = PyArray2::<f64>::zeros(py, [n, 2], false);
    let sigma0 = PyArray1::<f64>::zeros(py, [n], false);
    let correlation = PyArray1::<f64>::zeros(py, [n], false);
    let iterations = PyArray1::<u32>::zeros(py, [n], false);
    let covariance = PyArray3::<f64>::zeros(py, [n, PARAMETERS, PARAMETERS], false);
    let mut stages = vec![Stage::NONE; n];
    {
        let mut status_w = status.readwrite();
        let mut affine_w = affine.readwrite();
        let mut radiometry_w = radiometry.readwrite();
        let mut sigma0_w = sigma0.readwrite();
        let mut correlation_w = correlation.readwrite();
        let mut iterations_w = iterations.readwrite();
        let mut covariance_w = covariance.readwrite();
        let out = MatchOutput {
            status: status_w.as_slice_mut()?,
            affine: affine_w.as_slice_mut()?.as_chunks_mut::<6>().0,
            radiometry: radiometry_w.as_slice_mut()?.as_chunks_mut::<2>().0,
            sigma0: sigma0_w.as_slice_mut()?,
            correlation: correlation_w.as_slice_mut()?,
            iterations: iterations_w.as_slice_mut()?,
            covariance: covariance_w.as_slice_mut()?,
        };
        super::detach(py, || {
            match_pair_patches(
                &image_views,
                weight_views.as_deref(),
                &pairs,
                points_rows,
                starts,
                &options,
                out,
                &mut stages,
            )
        })?;
    }
    Ok((
        status,
        affine,
        radiometry,
        sigma0,
        correlation,
        iterations,
        covariance,
    ))
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(lsm_match_patches, m)?)?;
    m.add_function(wrap_pyfunction!(lsm_match_pairs, m)?)
}
