//! Exact queries against a triangle mesh: closest points, (signed) distances, ray casts and
//! containment, in parallel over batches of points, through parry's bounding-volume
//! hierarchy (BVH) built once per mesh.
//!
//! The sign of a distance comes from the angle-weighted pseudo-normal of the closest feature
//! (face, edge or vertex): a point is inside when $(p - c) \cdot n \le 0$ with $c$ its closest
//! point and $n$ that feature's pseudo-normal (Bærentzen & Aanæs 2005). It is exact for a
//! closed, consistently oriented (outward) manifold mesh; on any other mesh only the unsigned
//! distance has a meaning.

mod closest;
mod normals;
mod order;
mod rays;

use parry3d_f64::math::Vector;
use parry3d_f64::shape::TriMesh;

use crate::error::{check_finite, Error, Result};

pub use closest::Projections;
pub use rays::RayHits;

/// A triangle mesh with its BVH and pseudo-normals, for repeated exact queries.
///
/// Degenerate (zero-area) triangles are allowed: they are the segments or points they
/// collapse to for distances and ray casts, and carry no normal, so they never decide a sign.
pub struct TriangleMesh {
    mesh: TriMesh,
    normals: normals::PseudoNormals,
}

impl TriangleMesh {
    /// The mesh of `vertices` (world units) and `triangles` (vertex indices, counter-clockwise
    /// seen from outside for signed queries).
    ///
    /// # Errors
    /// [`Error::Empty`] without vertices or triangles, [`Error::NonFinite`] for a vertex with
    /// NaN or infinity, [`Error::IndexOutOfRange`] for a triangle naming no vertex,
    /// [`Error::TooManyPoints`] past 2^32 - 1 vertices or triangles.
    pub fn new(vertices: &[[f64; 3]], triangles: &[[i64; 3]]) -> Result<Self> {
        if vertices.is_empty() {
            return Err(Error::Empty {
                argument: "vertices",
                needed: 3,
            });
        }
        if triangles.is_empty() {
            return Err(Error::Empty {
                argument: "triangles",
                needed: 1,
            });
        }
        for (argument, got) in [("vertices", vertices.len()), ("triangles", triangles.len())] {
            if got >= u32::MAX as usize {
                return Err(Error::TooManyPoints {
                    argument,
                    got,
                    max: u32::MAX as usize - 1,
                });
            }
        }
        check_finite("vertices", vertices)?;
        let bound = vertices.len();
        let mut indices = Vec::with_capacity(triangles.len());
        for (row, triangle) in triangles.iter().enumerate() {
            let mut corners = [0u32; 3];
            for (corner, &value) in corners.iter_mut().zip(triangle) {
                if value < 0 || value as usize >= bound {
                    return Err(Error::IndexOutOfRange {
                        argument: "triangles",
                        row,
                        value,
                        bound,
                    });
                }
                *corner = value as u32;
            }
            indices.push(corners);
        }
        let points: Vec<Vector> = vertices.iter().map(vector).collect();
        // The pseudo-normals that sign the distances are computed here, not by parry (see
        // `normals`); the mesh keeps the caller's vertex and triangle numbering.
        let normals = normals::PseudoNormals::new(&points, &indices);
        let mesh = TriMesh::new(points, indices).map_err(|_| Error::Empty {
            argument: "triangles",
            needed: 1,
        })?;
        Ok(TriangleMesh { mesh, normals })
    }

    /// Number of vertices.
    pub fn n_vertices(&self) -> usize {
        self.mesh.vertices().len()
    }

    /// Number of triangles.
    pub fn n_triangles(&self) -> usize {
        self.mesh.num_triangles()
    }

    /// Signed volume enclosed, $\frac{1}{6} \sum_t a_t \cdot (b_t \times c_t)$: positive for
    /// a closed mesh whose triangles wind counter-clockwise seen from outside.
    pub fn volume(&self) -> f64 {
        let v = self.mesh.vertices();
        self.mesh
            .indices()
            .iter()
            .map(|t| v[t[0] as usize].dot(v[t[1] as usize].cross(v[t[2] as usize])))
            .sum::<f64>()
            / 6.0
    }

    /// Surface area, $\frac{1}{2} \sum_t |(b_t - a_t) \times (c_t - a_t)|$.
    pub fn area(&self) -> f64 {
        let v = self.mesh.vertices();
        self.mesh
            .indices()
            .iter()
            .map(|t| {
                let a = v[t[0] as usize];
                (v[t[1] as usize] - a).cross(v[t[2] as usize] - a).length()
            })
            .sum::<f64>()
            / 2.0
    }

    /// Whether every edge is shared by exactly two triangles running along it in opposite
    /// directions: a closed (watertight), consistently oriented surface, on which signed
    /// distances and containment hold.
    pub fn is_closed(&self) -> bool {
        self.normals.closed
    }

    /// Length of the diagonal of the axis-aligned bounding box: the mesh's size, the scale
    /// of every tolerance.
    pub fn diagonal(&self) -> f64 {
        let aabb = self.mesh.local_aabb();
        (aabb.maxs - aabb.mins).length()
    }
}

fn vector(p: &[f64; 3]) -> Vector {
    Vector::new(p[0], p[1], p[2])
}

#[cfg(test)]
mod tests;
