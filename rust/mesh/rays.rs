//! Ray casts: the first hit of each ray on the mesh.

use parry3d_f64::query::{Ray, RayCast};
use rayon::prelude::*;

use super::{vector, TriangleMesh};
use crate::error::{check_finite, Error, Result};

/// Rays per rayon task (see `closest::CHUNK`).
const CHUNK: usize = 64;

/// Results of [`TriangleMesh::cast_rays`], one row per ray.
#[derive(Debug, Clone, PartialEq)]
pub struct RayHits {
    /// Distance along the ray, in units of its direction's length (world units for unit
    /// directions); infinity where the ray misses.
    pub distances: Vec<f64>,
    /// The triangle hit; -1 where the ray misses.
    pub triangles: Vec<i64>,
}

impl TriangleMesh {
    /// The first hit of each ray `origins[i] + t directions[i]`, `0 <= t <= max_distance`,
    /// front or back face alike (a ray starting inside hits the surface from within).
    ///
    /// # Errors
    /// [`Error::NonFinite`] for non-finite origins or directions, [`Error::LengthMismatch`]
    /// when they differ in length, [`Error::BadRay`] for a zero direction,
    /// [`Error::InvalidOption`] for a negative or NaN `max_distance`.
    pub fn cast_rays(
        &self,
        origins: &[[f64; 3]],
        directions: &[[f64; 3]],
        max_distance: f64,
    ) -> Result<RayHits> {
        check_finite("origins", origins)?;
        check_finite("directions", directions)?;
        if directions.len() != origins.len() {
            return Err(Error::LengthMismatch {
                argument: "directions",
                expected: origins.len(),
                got: directions.len(),
            });
        }
        if let Some(row) = directions.iter().position(|d| d.iter().all(|&v| v == 0.0)) {
            return Err(Error::BadRay { row });
        }
        if !(max_distance >= 0.0) {
            return Err(Error::InvalidOption {
                argument: "max_distance",
                value: max_distance,
                expected: "non-negative (infinity for unbounded rays)",
            });
        }
        let hits: Vec<(f64, i64)> = origins
            .par_iter()
            .zip(directions)
            .with_min_len(CHUNK)
            .map(|(o, d)| {
                let ray = Ray::new(vector(o), vector(d));
                match self
                    .mesh
                    .cast_local_ray_and_get_normal(&ray, max_distance, false)
                {
                    Some(hit) => (hit.time_of_impact, hit.subshape as i64),
                    None => (f64::INFINITY, -1),
                }
            })
            .collect();
        let (distances, triangles) = hits.into_iter().unzip();
        Ok(RayHits {
            distances,
            triangles,
        })
    }
}
