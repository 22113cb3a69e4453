//! Closest points on the mesh and (signed) distances to it.

use parry3d_f64::math::Vector;
use parry3d_f64::query::{PointQueryWithLocation, Ray, RayCast};
use parry3d_f64::shape::TrianglePointLocation;
use rayon::prelude::*;

use super::order::morton_order;
use super::{vector, TriangleMesh};
use crate::error::{check_finite, Error, Result};

/// Queries per rayon task: each task's first search is unbounded, the others start from
/// their predecessor's answer.
const CHUNK: usize = 256;

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

/// The closest feature of the mesh to a point.
struct Nearest {
    point: Vector,
    triangle: u32,
    location: TrianglePointLocation,
}

impl TriangleMesh {
    /// The closest point among the triangles closer than `sqrt(bound)`, by parry's BVH
    /// descent on squared distances (no square root per box or triangle).
    fn nearest(&self, p: Vector, bound: f64) -> Option<Nearest> {
        let mesh = &self.mesh;
        let (triangle, (_, (point, location))) = mesh.bvh().find_best(
            bound,
            |node, _| {
                let aabb = node.aabb();
                let d = (aabb.mins - p).max(p - aabb.maxs).max(Vector::ZERO);
                d.length_squared()
            },
            |leaf, _| {
                let (projection, location) = mesh
                    .triangle(leaf)
                    .project_local_point_and_get_location(p, false);
                Some((
                    (projection.point - p).length_squared(),
                    (projection.point, location),
                ))
            },
        )?;
        Some(Nearest {
            point,
            triangle,
            location,
        })
    }

    /// [`nearest`](Self::nearest) by parry's own descent on distances, for queries so far
    /// away (beyond 1e154) that their squared distances overflow.
    fn nearest_unsquared(&self, p: Vector) -> Nearest {
        let (projection, (triangle, location)) =
            self.mesh.project_local_point_and_get_location(p, false);
        Nearest {
            point: projection.point,
            triangle,
            location,
        }
    }

    /// Squared distance from `p` to one triangle.
    fn squared_distance_to(&self, p: Vector, triangle: u32) -> f64 {
        let (projection, _) = self
            .mesh
            .triangle(triangle)
            .project_local_point_and_get_location(p, false);
        (projection.point - p).length_squared()
    }

    /// Whether `p` is behind the pseudo-normal of its closest feature (Bærentzen & Aanæs).
    fn is_inside(&self, p: Vector, nearest: &Nearest) -> bool {
        let t = nearest.triangle as usize;
        let normal = match nearest.location {
            TrianglePointLocation::OnVertex(i) => {
                self.normals.vertices[self.mesh.indices()[t][i as usize] as usize]
            }
            TrianglePointLocation::OnEdge(i, _) => self.normals.edges[t][i as usize],
            TrianglePointLocation::OnFace(..) | TrianglePointLocation::OnSolid => {
                self.mesh.triangle(nearest.triangle).scaled_normal()
            }
        };
        (p - nearest.point).dot(normal) < 0.0
    }

    /// Whether `p` is inside, by the first hit of a ray from it: leaving through a face
    /// means inside. For points farther from the surface than a search went.
    fn is_inside_by_ray(&self, p: Vector) -> bool {
        // Off every axis and diagonal, so that rays along grid lines of a regular mesh do not
        // run through its edges.
        let direction = Vector::new(0.5773, 0.5779, 0.5767);
        let ray = Ray::new(p, direction);
        self.mesh
            .cast_local_ray_and_get_normal(&ray, f64::MAX, false)
            .is_some_and(|hit| {
                self.mesh
                    .triangle(hit.subshape)
                    .scaled_normal()
                    .dot(direction)
                    > 0.0
            })
    }

    /// Closest point, distance (signed when `signed`) and triangle of each query, in `order`
    /// (indices into `queries`, nearby queries next to each other). Each search is bounded by
    /// the distance to the previous query's triangle, which prunes most of the BVH when
    /// queries are close, and by `max_distance`: a query with no triangle that near gets
    /// `(NaN, +-max_distance, -1)`, its sign from a ray cast.
    fn project_in_order(
        &self,
        queries: &[[f64; 3]],
        order: &[u32],
        signed: bool,
        max_distance: f64,
    ) -> Vec<([f64; 3], f64, i64)> {
        let band = if max_distance.is_finite() {
            max_distance * max_distance * (1.0 + 1e-9) + f64::MIN_POSITIVE
        } else {
            f64::MAX
        };
        order
            .par_chunks(CHUNK)
            .flat_map_iter(|chunk| {
                let mut previous: Option<u32> = None;
                chunk.iter().map(move |&i| {
                    let p = vector(&queries[i as usize]);
                    // Slightly above the previous triangle's distance, so that it is found again
                    // when nothing is closer (the box test rounds differently from the triangle's).
                    let bound = previous.map_or(band, |t| {
                        band.min(self.squared_distance_to(p, t) * (1.0 + 1e-9) + f64::MIN_POSITIVE)
                    });
                    let found = self.nearest(p, bound).or_else(|| {
                        if band < f64::MAX {
                            self.nearest(p, band)
                        } else {
                            Some(
                                self.nearest(p, f64::MAX)
                                    .unwrap_or_else(|| self.nearest_unsquared(p)),
                            )
                        }
                    });
                    let Some(nearest) = found.filter(|n| (p - n.point).length() <= max_distance)
                    else {
                        let inside = signed && self.is_inside_by_ray(p);
                        return (
                            [f64::NAN; 3],
                            if inside { -max_distance } else { max_distance },
                            -1,
                        );
                    };
                    previous = Some(nearest.triangle);
                    let distance = (p - nearest.point).length();
                    let inside = signed && self.is_inside(p, &nearest);
                    let c = nearest.point;
                    (
                        [c.x, c.y, c.z],
                        if inside { -distance } else { distance },
                        nearest.triangle as i64,
                    )
                })
            })
            .collect()
    }
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
        let order = morton_order(queries);
        let found = self.project_in_order(queries, &order, signed, f64::INFINITY);
        for (&i, (closest, distance, triangle)) in order.iter().zip(found) {
            let i = i as usize;
            points[i] = closest;
            distances[i] = distance;
            triangles[i] = triangle;
        }
        Ok(())
    }

    /// Distances of every query, signed (negative inside) when `signed`, into `distances`.
    /// Past `max_distance` a distance is reported as `max_distance` (signed: the sign is still
    /// exact), which spares the search of the far points' closest triangles; pass infinity
    /// for every distance exact.
    ///
    /// # Errors
    /// [`Error::NonFinite`] for a query with NaN or infinity; [`Error::InvalidOption`] for a
    /// negative or NaN `max_distance`; [`Error::OutputSize`] when `distances` has not one
    /// entry per query.
    pub fn distances_into(
        &self,
        queries: &[[f64; 3]],
        signed: bool,
        max_distance: f64,
        distances: &mut [f64],
    ) -> Result<()> {
        check_finite("queries", queries)?;
        if !(max_distance >= 0.0) {
            return Err(Error::InvalidOption {
                argument: "max_distance",
                value: max_distance,
                expected: "non-negative (infinity for every distance exact)",
            });
        }
        check_output(queries.len(), distances.len())?;
        let order = morton_order(queries);
        let found = self.project_in_order(queries, &order, signed, max_distance);
        for (&i, (_, distance, _)) in order.iter().zip(found) {
            distances[i as usize] = distance;
        }
        Ok(())
    }

    /// Signed distances (negative inside) of every query.
    ///
    /// # Errors
    /// [`Error::NonFinite`] for a query with NaN or infinity.
    pub fn signed_distances(&self, queries: &[[f64; 3]]) -> Result<Vec<f64>> {
        let mut out = vec![0.0; queries.len()];
        self.distances_into(queries, true, f64::INFINITY, &mut out)?;
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
