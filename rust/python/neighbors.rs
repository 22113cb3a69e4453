//! Bindings of the spatial hash: `SpatialIndex`, `knn`, `radius_neighbors`.

use numpy::{PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;

use super::{invalid_input, rows};
use crate::spatial_hash::{RadiusNeighbors, SpatialHash};

enum Index {
    Planar(SpatialHash<2>),
    Spatial(SpatialHash<3>),
}

/// Spatial hash over fixed 2-D or 3-D points, for repeated neighbour queries.
#[pyclass(module = "elastocap._core", frozen)]
pub struct SpatialIndex {
    index: Index,
}

type KnnArrays<'py> = (Bound<'py, PyArray2<i64>>, Bound<'py, PyArray2<f64>>);
type CsrArrays<'py> = (
    Bound<'py, PyArray1<i64>>,
    Bound<'py, PyArray1<i64>>,
    Bound<'py, PyArray1<f64>>,
);

/// Runs `knn_into` on output arrays that numpy allocates: numpy puts large arrays on huge
/// pages, which saves most of the page faults of writing a fresh 16 MB result.
fn knn_arrays<'py, const D: usize>(
    py: Python<'py>,
    index: &SpatialHash<D>,
    queries: Option<&[[f64; D]]>,
    k: usize,
) -> PyResult<KnnArrays<'py>> {
    let m = super::detach(py, || index.check_knn(queries, k))?;
    let indices = PyArray2::<i64>::zeros(py, [m, k], false);
    let distances = PyArray2::<f64>::zeros(py, [m, k], false);
    {
        let mut i = indices.readwrite();
        let mut d = distances.readwrite();
        let (i, d) = (i.as_slice_mut()?, d.as_slice_mut()?);
        super::detach(py, || index.knn_into(queries, k, i, d))?;
    }
    Ok((indices, distances))
}

fn csr_arrays<'py>(py: Python<'py>, r: RadiusNeighbors) -> CsrArrays<'py> {
    (
        PyArray1::from_vec(py, r.indptr),
        PyArray1::from_vec(py, r.indices),
        PyArray1::from_vec(py, r.distances),
    )
}

#[pymethods]
impl SpatialIndex {
    #[new]
    fn new(py: Python<'_>, points: PyReadonlyArray2<'_, f64>) -> PyResult<Self> {
        let index = match points.shape()[1] {
            2 => {
                let p = rows::<2>(&points, "points")?;
                Index::Planar(super::detach(py, || SpatialHash::new(p))?)
            }
            3 => {
                let p = rows::<3>(&points, "points")?;
                Index::Spatial(super::detach(py, || SpatialHash::new(p))?)
            }
            d => {
                return Err(invalid_input(format!(
                    "points must have shape (N, 2) or (N, 3), got (N, {d})"
                )))
            }
        };
        Ok(SpatialIndex { index })
    }

    /// Number of indexed points.
    #[getter]
    fn n_points(&self) -> usize {
        match &self.index {
            Index::Planar(i) => i.len(),
            Index::Spatial(i) => i.len(),
        }
    }

    /// Dimension of the indexed points (2 or 3).
    #[getter]
    fn dim(&self) -> usize {
        match &self.index {
            Index::Planar(_) => 2,
            Index::Spatial(_) => 3,
        }
    }

    /// Edge of the hashed cells that a k-nearest query for this k searches first.
    fn cell_size(&self, k: usize) -> f64 {
        match &self.index {
            Index::Planar(i) => i.knn_cell_size(k),
            Index::Spatial(i) => i.knn_cell_size(k),
        }
    }

    /// `(indices (M, k) int64, distances (M, k) float64)` of the k nearest points.
    #[pyo3(signature = (k, queries=None))]
    fn knn<'py>(
        &self,
        py: Python<'py>,
        k: usize,
        queries: Option<PyReadonlyArray2<'py, f64>>,
    ) -> PyResult<KnnArrays<'py>> {
        match &self.index {
            Index::Planar(i) => {
                let q = queries
                    .as_ref()
                    .map(|q| rows::<2>(q, "queries"))
                    .transpose()?;
                knn_arrays(py, i, q, k)
            }
            Index::Spatial(i) => {
                let q = queries
                    .as_ref()
                    .map(|q| rows::<3>(q, "queries"))
                    .transpose()?;
                knn_arrays(py, i, q, k)
            }
        }
    }

    /// `(indptr, indices, distances)`: neighbours within `radius`, CSR, rows sorted.
    #[pyo3(signature = (radius, queries=None))]
    fn radius_neighbors<'py>(
        &self,
        py: Python<'py>,
        radius: f64,
        queries: Option<PyReadonlyArray2<'py, f64>>,
    ) -> PyResult<CsrArrays<'py>> {
        let result = match &self.index {
            Index::Planar(i) => {
                let q = queries
                    .as_ref()
                    .map(|q| rows::<2>(q, "queries"))
                    .transpose()?;
                super::detach(py, || i.radius_neighbors(q, radius))
            }
            Index::Spatial(i) => {
                let q = queries
                    .as_ref()
                    .map(|q| rows::<3>(q, "queries"))
                    .transpose()?;
                super::detach(py, || i.radius_neighbors(q, radius))
            }
        };
        Ok(csr_arrays(py, result?))
    }
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<SpatialIndex>()
}
