//! Closest points on the mesh and (signed) distances to it.

use parry3d_f64::query::PointQueryWithLocation;
use rayon::prelude::*;

use super::{vector, TriangleMesh};
use crate::error::{check_finite, Error, Result};

/// Queries per rayon task: a BVH descent takes microseconds, so smaller tasks would spend
/// more on scheduling than on work.
const CHUNK: usize = 64;

/// Results of [`TriangleMesh::closest_points`], one row per query point.
#[derive(Debug, Clone, PartialEq)]
pub struct Projections {
    /// The closest point on the mesh.
    pub points: Vec<[f64; 3]>,
    /// Distance to it: signed (negative inside) or not, as asked.
    pub distances: Vec<f64>,
    /// The triangle it lies on (the lowest index among ties is not guaranteed).
    pub triangles: Vec<i64>,
}

/// One projection: closest point, distance signed by the pseudo-normal, triangle.
#[inline]
fn project(mesh: &TriangleMesh, p: &[f64; 3]) -> ([f64; 3], f64, i64) {
    let (projection, (triangle, _)) = mesh
        .mesh
        .project_local_point_and_get_location(vector(p), false);
    let c = projection.point;
    let distance = (vector(p) - c).length();
    let signed = if projection.is_inside {
        -distance
    } else {
        distance
    };
    ([c.x, c.y, c.z], signed, triangle as i64)
}

fn check_output(expected: usize, got: usize) -> Result<()> {
    if expected == got {
        Ok(())
    } else {
        Err(Error::OutputSize { expected, got })
    }
}

impl TriangleMesh {
    /// Closest points, distances (signed when `signed`) and triangles of every query.
    ///
    /// # Errors
    /// [`Error::NonFinite`] for a query with NaN or infinity.
    pub fn closest_points(&self, queries: &[[f64; 3]], signed: bool) -> Result<Projections> {
        let n = queries.len();
        let mut out = Projections {
            points: vec![[0.0; 3]; n],
            distances: vec![0.0; n],
            triangles: vec![0; n],
        };
        self.closest_points_into(
            queries,
            signed,
            &mut out.points,
            &mut out.distances,
            &mut out.triangles,
        )?;
        Ok(out)
    }

    /// [`closest_points`](Self::closest_points) into buffers of one row per query.
    ///
    /// # Errors
    /// As `closest_points`; [`Error::OutputSize`] for a buffer of the wrong length.
    pub fn closest_points_into(
        &self,
        queries: &[[f64; 3]],
        signed: bool,
        points: &mut [[f64; 3]],
        distances: &mut [f64],
        triangles: &mut [i64],
    ) -> Result<()> {
        check_finite("queries", queries)?;
        let n = queries.len();
        check_output(n, points.len())?;
        check_output(n, distances.len())?;
        check_output(n, triangles.len())?;
        queries
            .par_chunks(CHUNK)
            .zip(points.par_chunks_mut(CHUNK))
            .zip(distances.par_chunks_mut(CHUNK))
            .zip(triangles.par_chunks_mut(CHUNK))
            .for_each(|(((q, c), d), t)| {
                for i in 0..q.len() {
                    let (closest, distance, triangle) = project(self, &q[i]);
                    c[i] = closest;
                    d[i] = if signed { distance } else { distance.abs() };
                    t[i] = triangle;
                }
            });
        Ok(())
    }

    /// Distances of every query, signed (negative inside) when `signed`, into `distances`.
    ///
    /// # Errors
    /// [`Error::NonFinite`] for a query with NaN or infinity; [`Error::OutputSize`] when
    /// `distances` has not one entry per query.
    pub fn distances_into(
        &self,
        queries: &[[f64; 3]],
        signed: bool,
        distances: &mut [f64],
    ) -> Result<()> {
        check_finite("queries", queries)?;
        check_output(queries.len(), distances.len())?;
        queries
            .par_chunks(CHUNK)
            .zip(distances.par_chunks_mut(CHUNK))
            .for_each(|(q, d)| {
                for (p, out) in q.iter().zip(d) {
                    let distance = project(self, p).1;
                    *out = if signed { distance } else { distance.abs() };
                }
            });
        Ok(())
    }

    /// Signed distances (negative inside) of every query.
    ///
    /// # Errors
    /// [`Error::NonFinite`] for a query with NaN or infinity.
    pub fn signed_distances(&self, queries: &[[f64; 3]]) -> Result<Vec<f64>> {
        let mut out = vec![0.0; queries.len()];
        self.distances_into(queries, true, &mut out)?;
        Ok(out)
    }

    /// Whether each query lies inside the closed mesh (signed distance below zero; a point
    /// on the surface is outside).
    ///
    /// # Errors
    /// [`Error::NonFinite`] for a query with NaN or infinity.
    pub fn contains(&self, queries: &[[f64; 3]]) -> Result<Vec<bool>> {
        Ok(self
            .signed_distances(queries)?
            .into_iter()
            .map(|d| d < 0.0)
            .collect())
    }
}
