//! The self-intersection term of the fitting (SPEC 5, step 3; the paper's Eq. 16-17).
//!
//! A surface node `p` penetrates when it lies behind the surface of a part of the model that
//! is far from `p` at rest (more than $3 d_p$): among the current surface nodes near `p`,
//! a node `q` far from `p` at rest with $(x_p - x_q) \cdot n_q < 0$ and
//! $|x_p - x_q| < d_q$. Its push-back target is `p'`, the projection of $x_p$ onto `q`'s
//! tangent plane (the closest point of that part's surface, to first order), pulled along
//! $e = \operatorname{normalise}(n_p - n_q)$ with the metric
//! $M_I = s_I^2 I + (1 - s_I^2) e e^\top$, $s_I = 0.1$.

use rayon::prelude::*;

use super::associate::SurfaceTerms;
use super::surface::FAR_APART;
use super::workspace::FitWorkspace;
use crate::efg::Block;
use crate::linalg::{distance, dot, sub, unit};
use crate::SpatialHash;

/// Anisotropy of the contact metric (SPEC 5: $s_I = 0.1$).
pub const CONTACT_ANISOTROPY: f64 = 0.1;
/// Surface nodes examined around each node.
const CANDIDATES: usize = 8;

/// A penetrating surface node and where it is pushed.
#[derive(Debug, Clone, Copy)]
pub struct Contact<const D: usize> {
    /// Index of the node among the surface nodes.
    pub node: usize,
    /// The surface node `q` whose tangent plane `node` is pushed to.
    pub partner: usize,
    /// $x_{p'}$, held fixed during a solve.
    pub target: [f64; D],
    /// $M_I$.
    pub weight: Block<D>,
    /// Penetration depth $-(x_p - x_q) \cdot n_q \ge 0$.
    pub depth: f64,
}

/// The penetrating surface nodes at `positions` (surface nodes only) with `normals`, their
/// `rest` positions and supports.
pub fn find_contacts<const D: usize>(
    positions: &[[f64; D]],
    normals: &[[f64; D]],
    rest: &[[f64; D]],
    support: &[f64],
) -> Vec<Contact<D>> {
    let n = positions.len();
    if n < 2 {
        return Vec::new();
    }
    let Ok(hash) = SpatialHash::new(positions) else {
        return Vec::new();
    };
    let Ok(near) = hash.knn(None, CANDIDATES.min(n - 1)) else {
        return Vec::new();
    };
    let k = near.k;
    (0..n)
        .into_par_iter()
        .filter_map(|p| {
            let x = positions[p];
            near.indices[p * k..(p + 1) * k]
                .iter()
                .map(|&q| q as usize)
                .filter(|&q| distance(&rest[p], &rest[q]) > FAR_APART * support[p].max(support[q]))
                .filter_map(|q| {
                    let offset = sub(&x, &positions[q]);
                    let depth = -dot(&offset, &normals[q]);
                    (depth > 0.0 && distance(&x, &positions[q]) < support[q]).then_some((q, depth))
                })
                .max_by(|a, b| a.1.total_cmp(&b.1))
                .map(|(q, depth)| contact(p, q, &x, depth, normals))
        })
        .collect()
}

/// Keeps the contacts of the previous iteration that [`find_contacts`] no longer reports
/// (their node was pushed out) while the node is still within its partner's support: each
/// is held where it is across its partner's tangent plane, or pushed back onto it. Without
/// this the set of contacts alternates between iterations (nodes pushed out, released,
/// pulled back in by the surface term: 37, 62, 34, 73, 28 penetrating nodes in successive
/// iterations on two blocks squeezed together, whatever the contact weight), and a frame
/// ends with whichever half it stopped on.
pub fn hold_contacts<const D: usize>(
    found: &mut Vec<Contact<D>>,
    previous: &[Contact<D>],
    positions: &[[f64; D]],
    normals: &[[f64; D]],
    support: &[f64],
) {
    let mut active = vec![false; positions.len()];
    for c in found.iter() {
        active[c.node] = true;
    }
    for old in previous {
        let (p, q) = (old.node, old.partner);
        if active[p] {
            continue;
        }
        let x = positions[p];
        if distance(&x, &positions[q]) < support[q] {
            let depth = -dot(&sub(&x, &positions[q]), &normals[q]);
            found.push(contact(p, q, &x, depth.max(0.0), normals));
            active[p] = true;
        }
    }
}

/// Node `p` at `x`, `depth` behind the tangent plane of `q`: pushed onto that plane along
/// $e$ with the metric $M_I$.
fn contact<const D: usize>(
    p: usize,
    q: usize,
    x: &[f64; D],
    depth: f64,
    normals: &[[f64; D]],
) -> Contact<D> {
    let target = std::array::from_fn(|a| x[a] + depth * normals[q][a]);
    let e = unit(&sub(&normals[p], &normals[q]));
    let s2 = CONTACT_ANISOTROPY * CONTACT_ANISOTROPY;
    let weight = std::array::from_fn(|r| {
        std::array::from_fn(|c| (if r == c { s2 } else { 0.0 }) + (1.0 - s2) * e[r] * e[c])
    });
    Contact {
        node: p,
        partner: q,
        target,
        weight,
        depth,
    }
}

/// SPEC 5 step 3 at one iterate: the penetrating surface nodes of `surface` (none when
/// the term is off) with the `held` contacts of earlier iterations added
/// ([`hold_contacts`]), and how many penetrate before holding.
pub(super) fn contact_terms<const D: usize>(
    workspace: &FitWorkspace<D>,
    surface: &SurfaceTerms<D>,
    enabled: bool,
    held: &[Contact<D>],
) -> (Vec<Contact<D>>, usize) {
    let (positions, normals) = (&surface.positions, &surface.normals);
    let mut contacts = if enabled {
        find_contacts(
            positions,
            normals,
            &workspace.rest_surface,
            &workspace.support,
        )
    } else {
        Vec::new()
    };
    let penetrating = contacts.len();
    hold_contacts(&mut contacts, held, positions, normals, &workspace.support);
    (contacts, penetrating)
}
