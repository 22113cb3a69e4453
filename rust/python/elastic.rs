//! Binding of the element-free elastic model: `ElasticCore` (2-D or 3-D).

use numpy::ndarray::{Array2, Array3};
use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyArray3, PyReadonlyArray1, PyReadonlyArray2,
    PyReadonlyArray3, PyUntypedArrayMethods,
};
use pyo3::prelude::*;

use super::{c_slice, invalid_input, rows};
use crate::efg::{Block, Material, Plane};
use crate::elastic::{ElasticModel, Rotation, RotationFit};

enum Model {
    Planar(ElasticModel<2>),
    Spatial(ElasticModel<3>),
}

/// Runs `$body` with `$m` bound to the model of either dimension and `D` to its dimension.
macro_rules! dispatch {
    ($model:expr, $m:ident, $d:ident => $body:expr) => {
        match $model {
            Model::Planar($m) => {
                const $d: usize = 2;
                $body
            }
            Model::Spatial($m) => {
                const $d: usize = 3;
                $body
            }
        }
    };
}

/// An element-free elastic model (SPEC 4): nodes, neighbours, MLS gradients, volumes,
/// material and rotation mode.
#[pyclass(module = "elastocap._core", frozen)]
pub struct ElasticCore {
    model: Model,
}

fn parse_rotation(rotation: &str) -> PyResult<Rotation> {
    match rotation {
        "rhs" => Ok(Rotation::Rhs),
        "warped" => Ok(Rotation::Warped),
        "none" => Ok(Rotation::Linear),
        other => Err(invalid_input(format!(
            "rotation must be \"rhs\", \"warped\" or \"none\", got {other:?}"
        ))),
    }
}

fn parse_plane(plane: &str) -> PyResult<Plane> {
    match plane {
        "strain" => Ok(Plane::Strain),
        "stress" => Ok(Plane::Stress),
        other => Err(invalid_input(format!(
            "plane must be \"strain\" or \"stress\", got {other:?}"
        ))),
    }
}

fn blocks<const D: usize>(
    array: &PyReadonlyArray3<'_, f64>,
    n: usize,
    argument: &str,
) -> PyResult<Vec<Block<D>>> {
    if array.shape() != [n, D, D] {
        return Err(invalid_input(format!(
            "{argument} must have shape (N, D, D) = ({n}, {D}, {D}), got {:?}",
            array.shape()
        )));
    }
    Ok(c_slice(array, argument)?
        .as_chunks::<D>()
        .0
        .chunks_exact(D)
        .map(|r| std::array::from_fn(|a| r[a]))
        .collect())
}

fn positions<'a, const D: usize>(
    array: &'a PyReadonlyArray2<'_, f64>,
    n: usize,
    argument: &str,
) -> PyResult<&'a [[f64; D]]> {
    if array.shape() != [n, D] {
        return Err(invalid_input(format!(
            "{argument} must have shape (N, D) = ({n}, {D}), got {:?}",
            array.shape()
        )));
    }
    rows::<D>(array, argument)
}

fn rows_out<'py, const D: usize>(py: Python<'py>, v: Vec<[f64; D]>) -> Bound<'py, PyArray2<f64>> {
    let n = v.len();
    Array2::from_shape_vec((n, D), v.into_iter().flatten().collect())
        .expect("n x D values")
        .into_pyarray(py)
}

fn blocks_out<'py, const D: usize>(py: Python<'py>, v: Vec<Block<D>>) -> Bound<'py, PyArray3<f64>> {
    let n = v.len();
    Array3::from_shape_vec((n, D, D), v.into_iter().flatten().flatten().collect())
        .expect("n x D x D values")
        .into_pyarray(py)
}

type Csr<'py> = (
    Bound<'py, PyArray1<i64>>,
    Bound<'py, PyArray1<i64>>,
    Bound<'py, PyArray1<f64>>,
);

impl ElasticCore {
    /// The 3-D model, if this is one.
    pub(super) fn spatial(&self) -> Option<&ElasticModel<3>> {
        match &self.model {
            Model::Spatial(m) => Some(m),
            Model::Planar(_) => None,
        }
    }

    /// The 2-D model, if this is one.
    pub(super) fn planar(&self) -> Option<&ElasticModel<2>> {
        match &self.model {
            Model::Planar(m) => Some(m),
            Model::Spatial(_) => None,
        }
    }
}

#[pymethods]
impl ElasticCore {
    #[new]
    #[pyo3(signature = (nodes, k, volumes, youngs, poisson, plane = "strain", rotation = "rhs", rotation_fit = "gradient", stabilization = 0.0))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        nodes: PyReadonlyArray2<'_, f64>,
        k: usize,
        volumes: PyReadonlyArray1<'_, f64>,
        youngs: f64,
        poisson: f64,
        plane: &str,
        rotation: &str,
        rotation_fit: &str,
        stabilization: f64,
    ) -> PyResult<Self> {
        let fit = match rotation_fit {
            "gradient" => RotationFit::Gradient,
            "weighted" => RotationFit::Weighted,
            other => {
                return Err(invalid_input(format!(
                    "rotation_fit must be \"gradient\" or \"weighted\", got {other:?}"
                )))
            }
        };
        let material = Material {
            youngs,
            poisson,
            plane: parse_plane(plane)?,
        };
        let rotation = parse_rotation(rotation)?;
        let volumes = c_slice(&volumes, "volumes")?.to_vec();
        let model = match nodes.shape()[1] {
            2 => {
                let rest = rows::<2>(&nodes, "nodes")?.to_vec();
                Model::Planar(super::detach(py, || {
                    ElasticModel::new(rest, k, volumes, &material, rotation, fit)?
                        .with_stabilization(stabilization)
                })?)
            }
            3 => {
                let rest = rows::<3>(&nodes, "nodes")?.to_vec();
                Model::Spatial(super::detach(py, || {
                    ElasticModel::new(rest, k, volumes, &material, rotation, fit)?
                        .with_stabilization(stabilization)
                })?)
            }
            d => {
                return Err(invalid_input(format!(
                    "nodes must have shape (N, 2) or (N, 3), got (N, {d})"
                )))
            }
        };
        Ok(Self { model })
    }

    /// Dimension D (2 or 3).
    #[getter]
    fn dim(&self) -> usize {
        dispatch!(&self.model, _m, D => D)
    }

    /// Strength of the consistency penalty (0: none).
    #[getter]
    fn stabilization(&self) -> f64 {
        dispatch!(&self.model, m, _D => m.stabilization())
    }

    /// Number of nodes.
    #[getter]
    fn n_nodes(&self) -> usize {
        dispatch!(&self.model, m, _D => m.len())
    }

    /// Rest positions (N, D).
    #[getter]
    fn nodes<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        dispatch!(&self.model, m, _D => rows_out(py, m.rest().to_vec()))
    }

    /// Neighbour lists (N, k), each row starting with its node.
    #[getter]
    fn neighbors<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<i64>> {
        dispatch!(&self.model, m, _D => {
            let values = m.neighbors().iter().map(|&i| i64::from(i)).collect();
            Array2::from_shape_vec((m.len(), m.k()), values)
                .expect("n x k neighbours")
                .into_pyarray(py)
        })
    }

    /// MLS gradients (N, k, D) in the order of `neighbors`.
    #[getter]
    fn grad<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray3<f64>> {
        dispatch!(&self.model, m, D => {
            let values = m.grad().iter().flatten().copied().collect();
            Array3::from_shape_vec((m.len(), m.k(), D), values)
                .expect("n x k x D gradients")
                .into_pyarray(py)
        })
    }

    /// Support radii (N,).
    #[getter]
    fn support<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        dispatch!(&self.model, m, _D => PyArray1::from_slice(py, m.support()))
    }

    /// Nodal volumes (N,).
    #[getter]
    fn volumes<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        dispatch!(&self.model, m, _D => PyArray1::from_slice(py, m.volumes()))
    }

    /// Per-node rotations R_p (N, D, D) at positions (N, D).
    fn rotations<'py>(
        &self,
        py: Python<'py>,
        positions: PyReadonlyArray2<'py, f64>,
    ) -> PyResult<Bound<'py, PyArray3<f64>>> {
        dispatch!(&self.model, m, D => {
            let x = self::positions::<D>(&positions, m.len(), "positions")?;
            let r = super::detach(py, || m.rotations(x))?;
            Ok(blocks_out(py, r))
        })
    }

    /// Elastic energy at positions (N, D) with rotations (N, D, D).
    fn energy(
        &self,
        py: Python<'_>,
        positions: PyReadonlyArray2<'_, f64>,
        rotations: PyReadonlyArray3<'_, f64>,
    ) -> PyResult<f64> {
        dispatch!(&self.model, m, D => {
            let x = self::positions::<D>(&positions, m.len(), "positions")?;
            let r = blocks::<D>(&rotations, m.len(), "rotations")?;
            Ok(super::detach(py, || m.energy(x, &r))?)
        })
    }

    /// Elastic forces (N, D) at positions (N, D), rotations (N, D, D) held fixed.
    fn forces<'py>(
        &self,
        py: Python<'py>,
        positions: PyReadonlyArray2<'py, f64>,
        rotations: PyReadonlyArray3<'py, f64>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        dispatch!(&self.model, m, D => {
            let x = self::positions::<D>(&positions, m.len(), "positions")?;
            let r = blocks::<D>(&rotations, m.len(), "rotations")?;
            let f = super::detach(py, || m.forces(x, &r))?;
            Ok(rows_out(py, f))
        })
    }

    /// Right-hand side (N, D) of the mode's system S x = f for rotations (N, D, D).
    fn rhs<'py>(
        &self,
        py: Python<'py>,
        rotations: PyReadonlyArray3<'py, f64>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        dispatch!(&self.model, m, D => {
            let r = blocks::<D>(&rotations, m.len(), "rotations")?;
            let f = super::detach(py, || m.rhs(&r))?;
            Ok(rows_out(py, f))
        })
    }

    /// S u (N, D), matrix-free, for rotations (N, D, D) and a field u (N, D).
    fn apply<'py>(
        &self,
        py: Python<'py>,
        rotations: PyReadonlyArray3<'py, f64>,
        u: PyReadonlyArray2<'py, f64>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        dispatch!(&self.model, m, D => {
            let r = blocks::<D>(&rotations, m.len(), "rotations")?;
            let u = self::positions::<D>(&u, m.len(), "u")?;
            let y = super::detach(py, || m.apply(&r, u))?;
            Ok(rows_out(py, y))
        })
    }

    /// The system matrix S (K, or K_R when warped) for rotations (N, D, D), as scalar CSR
    /// `(indptr, indices, data)` of shape (N D, N D), dof `node * D + axis`.
    fn system<'py>(
        &self,
        py: Python<'py>,
        rotations: PyReadonlyArray3<'py, f64>,
    ) -> PyResult<Csr<'py>> {
        dispatch!(&self.model, m, D => {
            let r = blocks::<D>(&rotations, m.len(), "rotations")?;
            let (indptr, indices, data) = super::detach(py, || m.system_csr(&r))?;
            let as_i64 = |v: Vec<usize>| v.into_iter().map(|x| x as i64).collect::<Vec<_>>();
            Ok((
                as_i64(indptr).into_pyarray(py),
                as_i64(indices).into_pyarray(py),
                data.into_pyarray(py),
            ))
        })
    }
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<ElasticCore>()
}
