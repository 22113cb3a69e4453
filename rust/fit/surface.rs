//! The surface-distance term of the fitting (SPEC 5, step 2; the paper's Eq. 13-15) and the
//! surface geometry it needs (vertex normals of the model's surface at current positions).

use rayon::prelude::*;

use crate::efg::Block;
use crate::grid_sample::Field;
use crate::linalg::{cross, distance, dot, unit};
use crate::SpatialHash;

/// Lower clamp of the anisotropy $s$: moving across the surface costs at least 100 times
/// more than sliding along it (SPEC 5).
pub const MIN_ANISOTROPY: f64 = 0.1;
/// Associations closer than this fraction of $d_p$ collide (SPEC 5: $d/3$).
pub const COLLISION_FRACTION: f64 = 1.0 / 3.0;
/// Nodes farther apart at rest than this many $d_p$ belong to different parts (SPEC 5).
pub const FAR_APART: f64 = 3.0;

/// A face's normal scaled by its measure: a triangle's $(b - a) \times (c - a)$ (twice
/// its area) in 3-D, an edge's $(b - a)$ turned by $-90°$ (its length) in 2-D; outward for
/// counter-clockwise faces seen from outside.
pub fn face_normal<const D: usize>(corners: &[[f64; D]; D]) -> [f64; D] {
    let mut n = [0.0; D];
    if D == 2 {
        n[0] = corners[1][1] - corners[0][1];
        n[1] = corners[0][0] - corners[1][0];
    } else {
        let u: [f64; 3] = std::array::from_fn(|a| corners[1][a] - corners[0][a]);
        let v: [f64; 3] = std::array::from_fn(|a| corners[2][a] - corners[0][a]);
        let c = cross(&u, &v);
        n.iter_mut().zip(c).for_each(|(n, c)| *n = c);
    }
    n
}

/// The signed measure enclosed by a closed surface (volume in 3-D, area in 2-D, by the
/// divergence theorem): positive when its faces are oriented outward.
pub fn enclosed_measure<const D: usize>(vertices: &[[f64; D]], faces: &[[u32; D]]) -> f64 {
    faces
        .iter()
        .map(|face| {
            let corners = face.map(|i| vertices[i as usize]);
            dot(&corners[0], &face_normal(&corners)) / (D as f64 * if D == 3 { 2.0 } else { 1.0 })
        })
        .sum()
}

/// Unit vertex normals of a closed surface (measure-weighted face normals), one per
/// surface vertex; `faces` (triangles in 3-D, edges in 2-D) index into `vertices`.
pub fn vertex_normals<const D: usize>(vertices: &[[f64; D]], faces: &[[u32; D]]) -> Vec<[f64; D]> {
    let mut normals = vec![[0.0; D]; vertices.len()];
    for face in faces {
        let n = face_normal(&face.map(|i| vertices[i as usize]));
        for &i in face {
            for axis in 0..D {
                normals[i as usize][axis] += n[axis];
            }
        }
    }
    normals.iter_mut().for_each(|n| *n = unit(n));
    normals
}

/// One surface node's association with the target: where it is pulled, how confidently,
/// and the metric of the pull.
#[derive(Debug, Clone, Copy)]
pub struct Association<const D: usize> {
    /// Closest point $t_p$ on the target surface.
    pub target: [f64; D],
    /// Signed distance $d(x_p)$ to the target (positive outside).
    pub distance: f64,
    /// $w_p M_p$, with $w_p = \max(0, n_p \cdot g)$ and
    /// $M_p = s^2 I + (1 - s^2) g g^\top$, $s = \operatorname{clamp}(|d| / d_p, 0.1, 1)$.
    pub weight: Block<D>,
    /// $w_p$ (zero when invalidated).
    pub confidence: f64,
}

/// The associations of surface nodes at `positions` with `normals`, to the signed distance
/// field `target`; `support` are the nodes' $d_p$.
pub fn associate<const D: usize, F: Field<D>>(
    target: &F,
    positions: &[[f64; D]],
    normals: &[[f64; D]],
    support: &[f64],
) -> Vec<Association<D>> {
    positions
        .par_iter()
        .zip(normals)
        .zip(support)
        .map(|((x, n), &ddm)| {
            let (d, gradient) = target.value_and_gradient(x);
            let g = unit(&gradient);
            // One Newton step onto the zero level along the unit gradient (an exact
            // distance field has |grad| = 1; trilinear interpolation nearly so).
            let t = std::array::from_fn(|a| x[a] - d * g[a]);
            let confidence = dot(n, &g).max(0.0);
            let s = (d.abs() / ddm).clamp(MIN_ANISOTROPY, 1.0);
            let s2 = s * s;
            let weight = std::array::from_fn(|r| {
                std::array::from_fn(|c| {
                    confidence * (if r == c { s2 } else { 0.0 } + (1.0 - s2) * g[r] * g[c])
                })
            });
            Association {
                target: t,
                distance: d,
                weight,
                confidence,
            }
        })
        .collect()
}

/// SPEC 5 invalidation: surface nodes `p`, `q` whose targets are closer than $d_p / 3$
/// while they are more than $3 d_p$ apart at rest are both dropped (a limb tip must not be
/// pulled onto another limb). Returns how many were dropped.
pub fn invalidate_collisions<const D: usize>(
    associations: &mut [Association<D>],
    rest: &[[f64; D]],
    support: &[f64],
) -> usize {
    let targets: Vec<[f64; D]> = associations.iter().map(|a| a.target).collect();
    let Ok(hash) = SpatialHash::new(&targets) else {
        return 0;
    };
    let radius = COLLISION_FRACTION * support.iter().copied().fold(0.0, f64::max);
    let Ok(found) = hash.radius_neighbors(None, radius) else {
        return 0;
    };
    let dropped: Vec<bool> = (0..associations.len())
        .into_par_iter()
        .map(|p| {
            let row = found.indptr[p] as usize..found.indptr[p + 1] as usize;
            found.indices[row.clone()]
                .iter()
                .zip(&found.distances[row])
                .any(|(&q, &gap)| {
                    let q = q as usize;
                    let reach = support[p].min(support[q]);
                    q != p
                        && gap < COLLISION_FRACTION * reach
                        && distance(&rest[p], &rest[q]) > FAR_APART * support[p].max(support[q])
                })
        })
        .collect();
    let mut count = 0;
    for (association, drop) in associations.iter_mut().zip(dropped) {
        if drop {
            association.confidence = 0.0;
            association.weight = [[0.0; D]; D];
            count += 1;
        }
    }
    count
}
