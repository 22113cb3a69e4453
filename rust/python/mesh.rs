//! Bindings of the triangle mesh queries: `TriangleMesh`.

use numpy::{PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;

use super::{c_slice, invalid_input, rows};
use crate::mesh;

/// A triangle mesh with its BVH, for exact closest points, distances and ray casts.
#[pyclass(module = "elastocap._core", frozen, name = "TriangleMesh")]
pub struct TriangleMesh {
    mesh: mesh::TriangleMesh,
}

type Projections<'py> = (
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<i64>>,
);

#[pymethods]
impl TriangleMesh {
    #[new]
    fn new(
        py: Python<'_>,
        vertices: PyReadonlyArray2<'_, f64>,
        triangles: PyReadonlyArray2<'_, i64>,
    ) -> PyResult<Self> {
        let v = rows::<3>(&vertices, "vertices")?;
        if triangles.shape()[1] != 3 {
            return Err(invalid_input(format!(
                "triangles must have shape (M, 3), got {:?}",
                triangles.shape()
            )));
        }
        let t = c_slice(&triangles, "triangles")?.as_chunks::<3>().0;
        let mesh = super::detach(py, || mesh::TriangleMesh::new(v, t))?;
        Ok(TriangleMesh { mesh })
    }

    /// Number of vertices.
    #[getter]
    fn n_vertices(&self) -> usize {
        self.mesh.n_vertices()
    }

    /// Number of triangles.
    #[getter]
    fn n_triangles(&self) -> usize {
        self.mesh.n_triangles()
    }

    /// Signed enclosed volume (positive for outward triangles).
    fn volume(&self) -> f64 {
        self.mesh.volume()
    }

    /// Surface area.
    fn area(&self) -> f64 {
        self.mesh.area()
    }

    /// Closed and consistently oriented.
    fn is_closed(&self) -> bool {
        self.mesh.is_closed()
    }

    /// Diagonal of the bounding box.
    fn diagonal(&self) -> f64 {
        self.mesh.diagonal()
    }

    /// `(points (M, 3), distances (M,), triangles (M,))` of the closest points.
    fn closest_points<'py>(
        &self,
        py: Python<'py>,
        queries: PyReadonlyArray2<'py, f64>,
        signed: bool,
    ) -> PyResult<Projections<'py>> {
        let q = rows::<3>(&queries, "queries")?;
        let points = PyArray2::<f64>::zeros(py, [q.len(), 3], false);
        let distances = PyArray1::<f64>::zeros(py, q.len(), false);
        let triangles = PyArray1::<i64>::zeros(py, q.len(), false);
        {
            let (mut p, mut d, mut t) = (
                points.readwrite(),
                distances.readwrite(),
                triangles.readwrite(),
            );
            let (p, d, t) = (p.as_slice_mut()?, d.as_slice_mut()?, t.as_slice_mut()?);
            let p = p.as_chunks_mut::<3>().0;
            super::detach(py, || self.mesh.closest_points_into(q, signed, p, d, t))?;
        }
        Ok((points, distances, triangles))
    }

    /// `(M,)` distances, signed (negative inside) when `signed`, at most `max_distance`.
    fn distances<'py>(
        &self,
        py: Python<'py>,
        queries: PyReadonlyArray2<'py, f64>,
        signed: bool,
        max_distance: f64,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let q = rows::<3>(&queries, "queries")?;
        let distances = PyArray1::<f64>::zeros(py, q.len(), false);
        {
            let mut d = distances.readwrite();
            let d = d.as_slice_mut()?;
            super::detach(py, || self.mesh.distances_into(q, signed, max_distance, d))?;
        }
        Ok(distances)
    }

    /// `(M,)` bool: inside the closed mesh.
    fn contains<'py>(
        &self,
        py: Python<'py>,
        queries: PyReadonlyArray2<'py, f64>,
    ) -> PyResult<Bound<'py, PyArray1<bool>>> {
        let q = rows::<3>(&queries, "queries")?;
        let inside = super::detach(py, || self.mesh.contains(q))?;
        Ok(PyArray1::from_vec(py, inside))
    }

    /// `(distances (M,), triangles (M,))` of the first hit of each ray (inf, -1 on a miss).
    fn cast_rays<'py>(
        &self,
        py: Python<'py>,
        origins: PyReadonlyArray2<'py, f64>,
        directions: PyReadonlyArray2<'py, f64>,
        max_distance: f64,
    ) -> PyResult<(Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<i64>>)> {
        let o = rows::<3>(&origins, "origins")?;
        let d = rows::<3>(&directions, "directions")?;
        let hits = super::detach(py, || self.mesh.cast_rays(o, d, max_distance))?;
        Ok((
            PyArray1::from_vec(py, hits.distances),
            PyArray1::from_vec(py, hits.triangles),
        ))
    }
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<TriangleMesh>()
}
