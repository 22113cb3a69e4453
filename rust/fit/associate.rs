//! SPEC 5 steps 1-2 at the current positions: the model's surface, its vertex normals, the
//! associations of its nodes with the target (colliding ones invalidated) and the distance
//! term $D$ they give.

use super::surface::{associate, invalidate_collisions, vertex_normals, Association};
use super::workspace::FitWorkspace;
use crate::grid_sample::Field;
use crate::linalg::{quadratic_form, sub};

/// The surface at one iterate and where its nodes are pulled.
pub(super) struct SurfaceTerms<const D: usize> {
    /// Surface node positions.
    pub(super) positions: Vec<[f64; D]>,
    /// Their unit vertex normals, outward.
    pub(super) normals: Vec<[f64; D]>,
    /// One association per surface node.
    pub(super) found: Vec<Association<D>>,
    /// Associations dropped by the invalidation.
    pub(super) invalidated: usize,
}

/// The surface of positions `x` associated with `target`; colliding associations of
/// distant parts are dropped when `invalidate` is set.
pub(super) fn associate_surface<const D: usize, F: Field<D>>(
    workspace: &FitWorkspace<D>,
    target: &F,
    x: &[[f64; D]],
    invalidate: bool,
) -> SurfaceTerms<D> {
    let positions = workspace.surface_positions(x);
    let normals = vertex_normals(&positions, &workspace.faces);
    let mut found = associate(target, &positions, &normals, &workspace.support);
    let invalidated = if invalidate {
        invalidate_collisions(&mut found, &workspace.rest_surface, &workspace.support)
    } else {
        0
    };
    SurfaceTerms {
        positions,
        normals,
        found,
        invalidated,
    }
}

impl<const D: usize> SurfaceTerms<D> {
    /// $D = \sum_p w_p (x_p - t_p)^\top M_p (x_p - t_p)$.
    pub(super) fn distance_term(&self) -> f64 {
        self.positions
            .iter()
            .zip(&self.found)
            .map(|(x, a)| quadratic_form(&a.weight, &sub(x, &a.target)))
            .sum()
    }
}
