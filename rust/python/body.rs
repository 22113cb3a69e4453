//! Binding of the articulated metaball body model: `BodySkeleton` (field, state Jacobian,
//! silhouette rays, pose) and `body_fit`.

use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2,
    PyReadonlyArray3, PyUntypedArrayMethods,
};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::{c_slice, invalid_input, rows};
use crate::body::fit::{fit, FitOptions};
use crate::body::observe::Observations;
use crate::body::{self, Cutoff, Metaball, PartSpec, Skeleton};
use crate::lm::{LmOptions, LmStatus};

/// A body model in the core: parts (a tree of joint chains) and metaballs.
#[pyclass(module = "elastocap._core", frozen)]
pub struct BodySkeleton {
    skeleton: Skeleton,
}

fn indices(values: &[i64], argument: &str, bound: usize) -> PyResult<Vec<usize>> {
    values
        .iter()
        .enumerate()
        .map(|(row, &v)| match usize::try_from(v) {
            Ok(i) if i < bound => Ok(i),
            _ => Err(invalid_input(format!(
                "{argument}[{row}] = {v} is out of range: it must be in 0..{bound}"
            ))),
        })
        .collect()
}

type Rays<'py> = (
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<bool>>,
    Bound<'py, PyArray2<f64>>,
);

type PoseArrays<'py> = (Bound<'py, PyArray3<f64>>, Bound<'py, PyArray2<f64>>);

type ValuesJacobian<'py> = (Bound<'py, PyArray1<f64>>, Bound<'py, PyArray2<f64>>);

type FieldArrays<'py> = (
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray3<f64>>,
);

impl BodySkeleton {
    fn width(&self) -> usize {
        self.skeleton.n_motion + self.skeleton.n_shape()
    }
}

#[pymethods]
impl BodySkeleton {
    #[new]
    #[allow(clippy::too_many_arguments)]
    fn new(
        parent: PyReadonlyArray1<'_, i64>,
        offset: PyReadonlyArray2<'_, f64>,
        rest: PyReadonlyArray3<'_, f64>,
        axes: PyReadonlyArray2<'_, f64>,
        axis_count: PyReadonlyArray1<'_, i64>,
        ball_part: PyReadonlyArray1<'_, i64>,
        ball_centre: PyReadonlyArray2<'_, f64>,
        ball_radii: PyReadonlyArray2<'_, f64>,
    ) -> PyResult<Self> {
        let parent = c_slice(&parent, "parent")?;
        let n = parent.len();
        let offset = rows::<3>(&offset, "offset")?;
        if rest.shape() != [n, 3, 3] {
            return Err(invalid_input(format!(
                "rest must have shape ({n}, 3, 3), got {:?}",
                rest.shape()
            )));
        }
        let rest = c_slice(&rest, "rest")?.as_chunks::<9>().0;
        let axes = rows::<3>(&axes, "axes")?;
        let counts = c_slice(&axis_count, "axis_count")?;
        if offset.len() != n || counts.len() != n {
            return Err(invalid_input(format!(
                "offset and axis_count must have {n} rows like parent"
            )));
        }
        if counts.iter().any(|&c| c < 0) || counts.iter().sum::<i64>() != axes.len() as i64 {
            return Err(invalid_input(format!(
                "axis_count must be non-negative and sum to the {} rows of axes",
                axes.len()
            )));
        }
        let mut parts = Vec::with_capacity(n);
        let mut at = 0;
        for b in 0..n {
            let count = counts[b] as usize;
            parts.push(PartSpec {
                parent: match parent[b] {
                    -1 => None,
                    p => Some(indices(&[p], "parent", n)?[0]),
                },
                offset: offset[b],
                rest: std::array::from_fn(|i| std::array::from_fn(|j| rest[b][3 * i + j])),
                axes: axes[at..at + count].to_vec(),
            });
            at += count;
        }
        let part = indices(c_slice(&ball_part, "ball_part")?, "ball_part", n)?;
        let centre = rows::<3>(&ball_centre, "ball_centre")?;
        let radii = rows::<3>(&ball_radii, "ball_radii")?;
        if centre.len() != part.len() || radii.len() != part.len() {
            return Err(invalid_input(
                "ball_centre and ball_radii must have as many rows as ball_part".into(),
            ));
        }
        let balls = (0..part.len())
            .map(|i| Metaball {
                part: part[i],
                centre: centre[i],
                radii: radii[i],
            })
            .collect();
        let skeleton = Skeleton::new(parts, balls)?;
        Ok(Self { skeleton })
    }

    /// Motion parameters per frame.
    #[getter]
    fn n_motion(&self) -> usize {
        self.skeleton.n_motion
    }

    /// Shape parameters.
    #[getter]
    fn n_shape(&self) -> usize {
        self.skeleton.n_shape()
    }

    /// `(M,)`: each ball's place along its part, which the part's taper scales its section by.
    #[getter]
    fn taper_weight<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.skeleton.taper_weight.clone().into_pyarray(py)
    }

    /// `(rotations (P, 3, 3), origins (P, 3))` of the part frames.
    fn pose<'py>(
        &self,
        py: Python<'py>,
        shape: PyReadonlyArray1<'py, f64>,
        motion: PyReadonlyArray1<'py, f64>,
    ) -> PyResult<PoseArrays<'py>> {
        let pose = self
            .skeleton
            .pose(c_slice(&shape, "shape")?, c_slice(&motion, "motion")?)?;
        let n = pose.rotation.len();
        let rotations: Vec<f64> = pose
            .rotation
            .iter()
            .flat_map(|r| (0..9).map(move |k| r[(k / 3, k % 3)]))
            .collect();
        let origins: Vec<f64> = pose.origin.iter().flat_map(|o| [o.x, o.y, o.z]).collect();
        Ok((
            rotations.into_pyarray(py).reshape([n, 3, 3])?,
            origins.into_pyarray(py).reshape([n, 3])?,
        ))
    }

    /// `(F (N,), grad (N, 3), hessian (N, 3, 3))` at the points.
    fn field<'py>(
        &self,
        py: Python<'py>,
        shape: PyReadonlyArray1<'py, f64>,
        motion: PyReadonlyArray1<'py, f64>,
        points: PyReadonlyArray2<'py, f64>,
    ) -> PyResult<FieldArrays<'py>> {
        let (s, m, p) = (
            c_slice(&shape, "shape")?,
            c_slice(&motion, "motion")?,
            rows::<3>(&points, "points")?,
        );
        let (f, g, h) = super::detach(py, || body::field_at(&self.skeleton, s, m, p))?;
        let n = f.len();
        Ok((
            f.into_pyarray(py),
            g.into_flattened().into_pyarray(py).reshape([n, 3])?,
            h.into_flattened().into_pyarray(py).reshape([n, 3, 3])?,
        ))
    }

    /// `F (N,)` alone at the points (balls cut at the field's bound).
    fn values<'py>(
        &self,
        py: Python<'py>,
        shape: PyReadonlyArray1<'py, f64>,
        motion: PyReadonlyArray1<'py, f64>,
        points: PyReadonlyArray2<'py, f64>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let (s, m, p) = (
            c_slice(&shape, "shape")?,
            c_slice(&motion, "motion")?,
            rows::<3>(&points, "points")?,
        );
        let f = super::detach(py, || body::field_values(&self.skeleton, s, m, p))?;
        Ok(f.into_pyarray(py))
    }

    /// `(F (N,), J (N, n_motion + n_shape))`: the state Jacobian at fixed points.
    #[pyo3(signature = (shape, motion, points, exact=true))]
    fn jacobian<'py>(
        &self,
        py: Python<'py>,
        shape: PyReadonlyArray1<'py, f64>,
        motion: PyReadonlyArray1<'py, f64>,
        points: PyReadonlyArray2<'py, f64>,
        exact: bool,
    ) -> PyResult<ValuesJacobian<'py>> {
        let (s, m, p) = (
            c_slice(&shape, "shape")?,
            c_slice(&motion, "motion")?,
            rows::<3>(&points, "points")?,
        );
        let cutoff = if exact {
            Cutoff::Exact
        } else {
            Cutoff::Bounded
        };
        let (f, j) = super::detach(py, || body::state_jacobian(&self.skeleton, s, m, p, cutoff))?;
        let n = f.len();
        Ok((
            f.into_pyarray(py),
            j.into_pyarray(py).reshape([n, self.width()])?,
        ))
    }

    /// `(s (N,), x* (N, 3), F(x*) (N,), hit (N,), J (N, width))` of the field maximum along
    /// each ray.
    fn rays<'py>(
        &self,
        py: Python<'py>,
        shape: PyReadonlyArray1<'py, f64>,
        motion: PyReadonlyArray1<'py, f64>,
        origins: PyReadonlyArray2<'py, f64>,
        directions: PyReadonlyArray2<'py, f64>,
    ) -> PyResult<Rays<'py>> {
        let (s, m) = (c_slice(&shape, "shape")?, c_slice(&motion, "motion")?);
        let (o, r) = (
            rows::<3>(&origins, "origins")?,
            rows::<3>(&directions, "directions")?,
        );
        let (t, x, f, hit, j) =
            super::detach(py, || body::ray_jacobian(&self.skeleton, s, m, o, r))?;
        let n = t.len();
        Ok((
            t.into_pyarray(py),
            x.into_flattened().into_pyarray(py).reshape([n, 3])?,
            f.into_pyarray(py),
            hit.into_pyarray(py),
            j.into_pyarray(py).reshape([n, self.width()])?,
        ))
    }

    /// Whether each ray's field maximum reaches `threshold` (a silhouette test).
    fn rays_inside<'py>(
        &self,
        py: Python<'py>,
        shape: PyReadonlyArray1<'py, f64>,
        motion: PyReadonlyArray1<'py, f64>,
        origins: PyReadonlyArray2<'py, f64>,
        directions: PyReadonlyArray2<'py, f64>,
        threshold: f64,
    ) -> PyResult<Bound<'py, PyArray1<bool>>> {
        let (s, m) = (c_slice(&shape, "shape")?, c_slice(&motion, "motion")?);
        let (o, r) = (
            rows::<3>(&origins, "origins")?,
            rows::<3>(&directions, "directions")?,
        );
        let inside = super::detach(py, || {
            body::ray_inside(&self.skeleton, s, m, o, r, threshold)
        })?;
        Ok(inside.into_pyarray(py))
    }

    /// Fits shape and motion; returns a dict (see `elastocap.fit_body`).
    #[pyo3(signature = (observations, shape, motion, lower, upper, *, fit_shape, max_iterations, refresh_every, outlier_distance))]
    #[allow(clippy::too_many_arguments)]
    fn fit<'py>(
        &self,
        py: Python<'py>,
        observations: &Bound<'py, PyDict>,
        shape: PyReadonlyArray1<'py, f64>,
        motion: PyReadonlyArray2<'py, f64>,
        lower: PyReadonlyArray1<'py, f64>,
        upper: PyReadonlyArray1<'py, f64>,
        fit_shape: bool,
        max_iterations: usize,
        refresh_every: usize,
        outlier_distance: Option<f64>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let obs = observations_from(observations, motion.shape()[0])?;
        let options = FitOptions {
            lm: LmOptions {
                max_iterations,
                refresh_every,
                ..LmOptions::default()
            },
            fit_shape,
            outlier_distance,
        };
        let (s, m) = (c_slice(&shape, "shape")?, c_slice(&motion, "motion")?);
        let (lo, hi) = (c_slice(&lower, "lower")?, c_slice(&upper, "upper")?);
        let result = super::detach(py, || fit(&self.skeleton, &obs, s, m, (lo, hi), &options))?;
        let out = PyDict::new(py);
        let frames = obs.frames;
        out.set_item(
            "motion",
            result
                .motion
                .into_pyarray(py)
                .reshape([frames, self.skeleton.n_motion])?,
        )?;
        out.set_item("shape", result.shape.into_pyarray(py))?;
        let status = match result.report.status {
            LmStatus::CostConverged => "cost converged",
            LmStatus::StepConverged => "step converged",
            LmStatus::GradientConverged => "gradient converged",
            LmStatus::MaxIterations => "maximum iterations",
            LmStatus::NoDescent => "no descent",
        };
        out.set_item("status", status)?;
        out.set_item("iterations", result.report.iterations)?;
        out.set_item("initial_cost", result.report.initial_cost)?;
        out.set_item("final_cost", result.report.final_cost)?;
        let to_i64 = |v: Vec<usize>| v.into_iter().map(|x| x as i64).collect::<Vec<i64>>();
        out.set_item("point_part", to_i64(result.point_part).into_pyarray(py))?;
        out.set_item("point_inlier", result.point_inlier.into_pyarray(py))?;
        out.set_item("ray_part", to_i64(result.ray_part).into_pyarray(py))?;
        out.set_item("ray_inlier", result.ray_inlier.into_pyarray(py))?;
        Ok(out)
    }
}

/// Observations from a dict of arrays: `points (N, 3)`, `point_frame (N,)`, `origins`,
/// `directions`, `ray_frame`, `joints`, `joint_part`, `joint_frame`, `sigma (3,)`.
fn observations_from(d: &Bound<'_, PyDict>, frames: usize) -> PyResult<Observations> {
    fn points(d: &Bound<'_, PyDict>, key: &str) -> PyResult<Vec<[f64; 3]>> {
        let item = d
            .get_item(key)?
            .ok_or_else(|| invalid_input(format!("observations lack {key}")))?;
        let array: PyReadonlyArray2<'_, f64> = item.extract()?;
        Ok(rows::<3>(&array, key)?.to_vec())
    }
    fn index(d: &Bound<'_, PyDict>, key: &str, bound: usize) -> PyResult<Vec<usize>> {
        let item = d
            .get_item(key)?
            .ok_or_else(|| invalid_input(format!("observations lack {key}")))?;
        let array: PyReadonlyArray1<'_, i64> = item.extract()?;
        indices(c_slice(&array, key)?, key, bound)
    }
    fn optional(d: &Bound<'_, PyDict>, key: &str) -> PyResult<Vec<f64>> {
        match d.get_item(key)? {
            Some(v) if !v.is_none() => {
                let array: PyReadonlyArray1<'_, f64> = v.extract()?;
                Ok(c_slice(&array, key)?.to_vec())
            }
            _ => Ok(Vec::new()),
        }
    }
    let sigma: Vec<f64> = d
        .get_item("sigma")?
        .ok_or_else(|| invalid_input("observations lack sigma".into()))?
        .extract()?;
    if sigma.len() != 3 {
        return Err(invalid_input("sigma must hold 3 values".into()));
    }
    Ok(Observations {
        frames,
        points: points(d, "points")?,
        point_frame: index(d, "point_frame", frames)?,
        origins: points(d, "origins")?,
        directions: points(d, "directions")?,
        ray_frame: index(d, "ray_frame", frames)?,
        joints: points(d, "joints")?,
        joint_part: index(d, "joint_part", usize::MAX)?,
        joint_frame: index(d, "joint_frame", frames)?,
        joint_offset: match d.get_item("joint_offset")? {
            Some(v) if !v.is_none() => points(d, "joint_offset")?,
            _ => Vec::new(),
        },
        joint_scale: optional(d, "joint_scale")?,
        sigma: [sigma[0], sigma[1], sigma[2]],
        log_epsilon: match d.get_item("log_epsilon")? {
            Some(v) if !v.is_none() => Some(v.extract()?),
            _ => None,
        },
        point_scale: optional(d, "point_scale")?,
        ray_scale: optional(d, "ray_scale")?,
        ray_side: match d.get_item("ray_side")? {
            Some(v) if !v.is_none() => {
                let array: PyReadonlyArray1<'_, i8> = v.extract()?;
                c_slice(&array, "ray_side")?.to_vec()
            }
            _ => Vec::new(),
        },
        shape_group: match d.get_item("shape_group")? {
            Some(v) if !v.is_none() => index(d, "shape_group", usize::MAX)?,
            _ => Vec::new(),
        },
        shape_lower: optional(d, "shape_lower")?,
        shape_upper: optional(d, "shape_upper")?,
        shape_sigma: match d.get_item("shape_sigma")? {
            Some(v) if !v.is_none() => Some(v.extract()?),
            _ => None,
        },
    })
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<BodySkeleton>()?;
    Ok(())
}
