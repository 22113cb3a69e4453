//! Binding of the per-frame fitting: `FitCore` keeps the workspace of one model and surface.

use std::sync::Mutex;

use numpy::{ndarray::Array2, PyUntypedArrayMethods};
use numpy::{IntoPyArray, PyArray2, PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArray3};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::elastic::ElasticCore;
use super::{c_slice, invalid_input, rows};
use crate::camera::Camera;
use crate::fit::coverage::TargetSamples;
use crate::fit::silhouette::{SilhouetteView, Window};
use crate::fit::tracks::FrameTracks;
use crate::fit::{fit_frame_with, FitOptions, FitWorkspace, FrameMetrics, FrameTargets};
use crate::grid_sample::GridField;

enum Workspace {
    Planar(FitWorkspace<2>),
    Spatial(FitWorkspace<3>),
}

/// The fitting state of an elastic model (2-D or 3-D) and its surface (SPEC 5).
#[pyclass(module = "elastocap._core", frozen)]
pub struct FitCore {
    model: Py<ElasticCore>,
    workspace: Mutex<Workspace>,
}

fn metrics_dict<'py>(py: Python<'py>, m: &FrameMetrics) -> PyResult<Bound<'py, PyDict>> {
    let metrics = PyDict::new(py);
    metrics.set_item("distance_term", m.distance_term)?;
    metrics.set_item("mean_distance", m.mean_distance)?;
    metrics.set_item("max_distance", m.max_distance)?;
    metrics.set_item("elastic_energy", m.elastic_energy)?;
    metrics.set_item("penetrating", m.penetrating)?;
    metrics.set_item("invalidated", m.invalidated)?;
    metrics.set_item("iterations", m.iterations)?;
    metrics.set_item("solver_iterations", m.solver_iterations)?;
    metrics.set_item("solver_converged", m.solver_converged)?;
    metrics.set_item("solver_seconds", m.solver_seconds)?;
    metrics.set_item("unexplained", m.unexplained)?;
    metrics.set_item("samples", m.samples)?;
    let steps = PyDict::new(py);
    for (name, seconds) in crate::fit::STEPS.iter().zip(m.step_seconds) {
        steps.set_item(name, seconds)?;
    }
    metrics.set_item("step_seconds", steps)?;
    Ok(metrics)
}

fn positions_out<const D: usize>(py: Python<'_>, x: Vec<[f64; D]>) -> Bound<'_, PyArray2<f64>> {
    let n = x.len();
    Array2::from_shape_vec((n, D), x.into_iter().flatten().collect())
        .expect("n x D positions")
        .into_pyarray(py)
}

fn indices(values: &[i64], argument: &str) -> PyResult<Vec<u32>> {
    values
        .iter()
        .map(|&i| {
            u32::try_from(i)
                .map_err(|_| invalid_input(format!("{argument} holds {i}, not a node index")))
        })
        .collect()
}

#[pymethods]
impl FitCore {
    #[new]
    fn new(
        py: Python<'_>,
        model: Py<ElasticCore>,
        surface_nodes: PyReadonlyArray1<'_, i64>,
        faces: PyReadonlyArray2<'_, i64>,
    ) -> PyResult<Self> {
        let core = model.get();
        let dim = if core.spatial().is_some() { 3 } else { 2 };
        if faces.shape()[1] != dim {
            return Err(invalid_input(format!(
                "faces must have shape (F, {dim}) for a {dim}-D model (triangles in 3-D, contour edges in 2-D), got {:?}",
                faces.shape()
            )));
        }
        let surface = indices(c_slice(&surface_nodes, "surface_nodes")?, "surface_nodes")?;
        let flat = indices(c_slice(&faces, "faces")?, "faces")?;
        let workspace = match (core.spatial(), core.planar()) {
            (Some(m), _) => {
                let faces: Vec<[u32; 3]> = flat.as_chunks::<3>().0.to_vec();
                super::detach(py, || FitWorkspace::new(m, &surface, &faces)).map(Workspace::Spatial)
            }
            (None, Some(m)) => {
                let faces: Vec<[u32; 2]> = flat.as_chunks::<2>().0.to_vec();
                super::detach(py, || FitWorkspace::new(m, &surface, &faces)).map(Workspace::Planar)
            }
            (None, None) => unreachable!("a model is 2-D or 3-D"),
        }?;
        Ok(Self {
            model,
            workspace: Mutex::new(workspace),
        })
    }

    /// Fits one frame to the signed distance `values` (nx, ny, nz) of a grid (`origin`,
    /// `spacing`; for a 2-D model nz = 1 and the plane z = origin z) from `start` (N, D):
    /// `(positions (N, D), metrics dict)`.
    #[pyo3(signature = (values, origin, spacing, start, *, stiffness = 1.0, contact = 1.0,
        max_iterations = 10, stop_fraction = 0.01, invalidate = true, self_intersection = true,
        solver_tolerance = 1e-6, solver_max_iterations = 500, matrix_free = false, coarse = true,
        hold_contacts = false, coverage = 2.0, volume = 4.0, silhouette = 0.0, views = None,
        tracks = None, track_weight = 1.0, track_sigma = 1.0, track_scale = 10.0))]
    #[allow(clippy::too_many_arguments)]
    fn fit_frame<'py>(
        &self,
        py: Python<'py>,
        values: PyReadonlyArray3<'py, f64>,
        origin: [f64; 3],
        spacing: f64,
        start: PyReadonlyArray2<'py, f64>,
        stiffness: f64,
        contact: f64,
        max_iterations: usize,
        stop_fraction: f64,
        invalidate: bool,
        self_intersection: bool,
        solver_tolerance: f64,
        solver_max_iterations: usize,
        matrix_free: bool,
        coarse: bool,
        hold_contacts: bool,
        coverage: f64,
        volume: f64,
        silhouette: f64,
        views: Option<Vec<View<'py>>>,
        tracks: Option<Tracked<'py>>,
        track_weight: f64,
        track_sigma: f64,
        track_scale: f64,
    ) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyDict>)> {
        let shape = values.shape();
        let grid = [shape[0], shape[1], shape[2]];
        let flat = c_slice(&values, "values")?;
        let field = GridField::new(flat, grid, origin, spacing)?;
        let options = FitOptions {
            stiffness,
            contact,
            max_iterations,
            stop_fraction,
            invalidate,
            self_intersection,
            solver_tolerance,
            solver_max_iterations,
            matrix_free,
            coarse,
            hold_contacts,
            coverage,
            volume,
            silhouette,
        };
        let views = views.as_deref().map(silhouette_views).transpose()?;
        let mut workspace = self
            .workspace
            .lock()
            .map_err(|_| invalid_input("a previous fit panicked; build a new FitCore".into()))?;
        let core = self.model.get();
        let mut track_distance = None;
        let (positions, m) = match (&mut *workspace, core.spatial(), core.planar()) {
            (Workspace::Spatial(w), Some(model), _) => {
                let tracks = tracks
                    .map(|t| frame_tracks(model.len(), t, track_weight, track_sigma, track_scale))
                    .transpose()?;
                let start = rows::<3>(&start, "start")?;
                let (x, m) = super::detach(py, || {
                    let samples = (coverage > 0.0)
                        .then(|| TargetSamples::from_grid(flat, grid, origin, spacing, &field))
                        .transpose()?;
                    let targets = FrameTargets {
                        samples: samples.as_ref(),
                        silhouettes: views.as_deref(),
                        tracks: tracks.as_ref(),
                    };
                    fit_frame_with(model, w, &field, &targets, start, &options)
                })?;
                track_distance = tracks.as_ref().map(|t| t.mean_mahalanobis(&x));
                (positions_out(py, x), m)
            }
            (Workspace::Planar(w), _, Some(model)) => {
                if shape[2] != 1 {
                    return Err(invalid_input(format!(
                        "a 2-D model fits to a field one voxel thick: values must have shape (nx, ny, 1), got {shape:?}"
                    )));
                }
                if tracks.is_some() {
                    return Err(invalid_input(
                        "tracks are 3-D points: a 2-D model does not take them".into(),
                    ));
                }
                let start = rows::<2>(&start, "start")?;
                let (x, m) = super::detach(py, || {
                    let samples = (coverage > 0.0)
                        .then(|| TargetSamples::from_grid(flat, grid, origin, spacing, &field))
                        .transpose()?;
                    let targets = FrameTargets {
                        samples: samples.as_ref(),
                        silhouettes: None,
                        tracks: None,
                    };
                    fit_frame_with(model, w, &field, &targets, start, &options)
                })?;
                (positions_out(py, x), m)
            }
            _ => unreachable!("the workspace matches the model's dimension"),
        };
        let metrics = metrics_dict(py, &m)?;
        if let Some(distance) = track_distance {
            metrics.set_item("track_mahalanobis", distance)?;
        }
        Ok((positions, metrics))
    }
}

/// One camera of the silhouette term: K (9, row-major), distortion (OpenCV's order), R (9,
/// row-major), t (3), its mask's signed distance in pixels, positive outside, and where it
/// lies: None for the whole image (H, W), or the image's `(width, height)`, the window's
/// first `(row, column)` and the mask's bounding box `(top, bottom, left, right)` (rows
/// and columns, inclusive) when the distance covers a window of the image only.
type View<'py> = (
    Vec<f64>,
    Vec<f64>,
    Vec<f64>,
    Vec<f64>,
    PyReadonlyArray2<'py, f64>,
    Option<Placement>,
);

/// A windowed view's image size, window origin and mask bounding box (see [`View`]).
type Placement = ((usize, usize), (usize, usize), (usize, usize, usize, usize));

/// The track term's arrays: nodes (T, k), MLS weights (T, k), tracked positions (T, 3) and
/// precisions (T, 3, 3).
type Tracked<'py> = (
    PyReadonlyArray2<'py, i64>,
    PyReadonlyArray2<'py, f64>,
    PyReadonlyArray2<'py, f64>,
    PyReadonlyArray3<'py, f64>,
);

fn frame_tracks(
    n: usize,
    (nodes, phi, targets, precisions): Tracked<'_>,
    weight: f64,
    sigma: f64,
    scale: f64,
) -> PyResult<FrameTracks<3>> {
    let k = nodes.shape()[1];
    let shapes = [phi.shape(), &precisions.shape()[1..]];
    if shapes[0] != nodes.shape() || shapes[1] != [3, 3] || targets.shape()[1] != 3 {
        return Err(invalid_input(format!(
            "tracks must be nodes (T, k), phi (T, k), positions (T, 3), precisions (T, 3, 3); got {:?}, {:?}, {:?}, {:?}",
            nodes.shape(), phi.shape(), targets.shape(), precisions.shape()
        )));
    }
    let node_list = indices(c_slice(&nodes, "track_nodes")?, "track_nodes")?;
    let phi = c_slice(&phi, "track_phi")?.to_vec();
    let targets = rows::<3>(&targets, "track_positions")?.to_vec();
    let flat = c_slice(&precisions, "track_precisions")?;
    let precisions = flat
        .as_chunks::<9>()
        .0
        .iter()
        .map(|m| [[m[0], m[1], m[2]], [m[3], m[4], m[5]], [m[6], m[7], m[8]]])
        .collect();
    Ok(FrameTracks::new(
        n, k, node_list, phi, targets, precisions, weight, sigma, scale,
    )?)
}

fn silhouette_views<'a>(views: &'a [View<'_>]) -> PyResult<Vec<SilhouetteView<'a>>> {
    views
        .iter()
        .enumerate()
        .map(|(index, (k, dist, r, t, signed, placement))| {
            let nine = |v: &[f64], name: &str| -> PyResult<[f64; 9]> {
                v.try_into().map_err(|_| {
                    invalid_input(format!("views[{index}]: {name} must hold 9 values"))
                })
            };
            let t: [f64; 3] = t[..]
                .try_into()
                .map_err(|_| invalid_input(format!("views[{index}]: t must hold 3 values")))?;
            let (rows, columns) = (signed.shape()[0], signed.shape()[1]);
            let values = c_slice(signed, "views signed distance")?;
            Ok(match *placement {
                None => {
                    let camera = Camera::new(nine(k, "K")?, dist, nine(r, "R")?, t, columns, rows)?;
                    SilhouetteView::new(camera, index, values, columns, rows)?
                }
                Some(((width, height), (row, column), (top, bottom, left, right))) => {
                    let camera = Camera::new(nine(k, "K")?, dist, nine(r, "R")?, t, width, height)?;
                    let window = Window {
                        origin: [row, column],
                        size: [rows, columns],
                        bounds: [top, bottom, left, right],
                    };
                    SilhouetteView::windowed(camera, index, values, window)?
                }
            })
        })
        .collect()
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<FitCore>()
}
