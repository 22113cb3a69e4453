//! The volume term of the fitting (SPEC 5.1; issue 17, item 4): the measure enclosed by the
//! model's surface (volume in 3-D, area in 2-D) is held near its rest value.
//!
//! A body does not change its volume, but the targets do: a carved hull keeps phantom volume
//! where the cameras cannot see between limbs, and loses it again when the limbs part, and
//! a fit that follows the hull's surface follows its volume. The term is
//! $P = c\,(V(x) - V_0)^2$ with $c = w\,N_s / A_0^2$ ($N_s$ surface nodes, $A_0$ the rest
//! surface's measure): a volume error $\delta A_0$ costs as much as moving every surface
//! node by $\delta$ under a data term of weight $w$. Gauss-Newton linearises $V$ at the
//! iterate, $V(x) \approx V_k + g^\top (x - x_k)$ with $g = \partial V / \partial x$, so the
//! system gains the rank-one $c\,g g^\top$ over all surface nodes and its right-hand side
//! $c\,g\,s$, $s = g^\top x_k - (V_k - V_0)$. That does not fit the sparse pattern: the
//! solve adds it to the product and to the preconditioner by Sherman-Morrison
//! ([`crate::solve::RankOne`]), one solve where the solution's Sherman-Morrison took two
//! ($A^{-1} b$ and $A^{-1} g$; the second was 40% of a frame's iterations, benches/README.md).

use super::surface::{enclosed_measure, face_normal};
use super::workspace::FitWorkspace;
use crate::linalg::dot;
use crate::solve::RankOne;

/// The volume term at one iterate.
#[derive(Debug, Clone, Default)]
pub(super) struct VolumeTerm {
    /// $\partial V / \partial x$ over all model nodes, flat `(n D,)` (zero off the surface).
    pub(super) gradient: Vec<f64>,
    /// $V_k - V_0$.
    pub(super) residual: f64,
    /// $c$.
    pub(super) weight: f64,
}

impl VolumeTerm {
    /// $P$ at the iterate.
    pub(super) fn energy(&self) -> f64 {
        self.weight * self.residual * self.residual
    }

    /// The system's rank-one part $c\,g g^\top$.
    pub(super) fn rank_one(&self) -> RankOne<'_> {
        RankOne {
            vector: &self.gradient,
            weight: self.weight,
        }
    }

    /// Adds the term's right-hand side $c\,g\,(g^\top x_k - (V_k - V_0))$ at the iterate
    /// `x` to `rhs` (flat).
    pub(super) fn add_to_rhs<const D: usize>(&self, x: &[[f64; D]], rhs: &mut [f64]) {
        let flat = x.as_flattened();
        let s = flat_dot(&self.gradient, flat) - self.residual;
        let scale = self.weight * s;
        rhs.iter_mut()
            .zip(&self.gradient)
            .for_each(|(b, g)| *b += scale * g);
    }
}

fn flat_dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(a, b)| a * b).sum()
}

/// $\partial V / \partial x_i$ of the measure enclosed by `faces` over `vertices` (see
/// [`enclosed_measure`]): a triangle $a \cdot (b \times c) / 6$ gives $b \times c / 6$ to
/// $a$ (cyclically); an edge $(a_x b_y - a_y b_x) / 2$ gives $(b_y, -b_x) / 2$ to $a$ and
/// $(-a_y, a_x) / 2$ to $b$.
pub fn measure_gradient<const D: usize>(
    vertices: &[[f64; D]],
    faces: &[[u32; D]],
) -> Vec<[f64; D]> {
    let mut out = vec![[0.0; D]; vertices.len()];
    for face in faces {
        let x = face.map(|i| vertices[i as usize]);
        if D == 2 {
            let (a, b) = (face[0] as usize, face[1] as usize);
            out[a][0] += 0.5 * x[1][1];
            out[a][1] -= 0.5 * x[1][0];
            out[b][0] -= 0.5 * x[0][1];
            out[b][1] += 0.5 * x[0][0];
        } else {
            for corner in 0..3 {
                let (u, w) = (x[(corner + 1) % 3], x[(corner + 2) % 3]);
                let cross = [
                    u[1] * w[2] - u[2] * w[1],
                    u[2] * w[0] - u[0] * w[2],
                    u[0] * w[1] - u[1] * w[0],
                ];
                let at = face[corner] as usize;
                for axis in 0..3 {
                    out[at][axis] += cross[axis] / 6.0;
                }
            }
        }
    }
    out
}

/// The rest surface's measure (area in 3-D, length in 2-D).
pub(super) fn boundary_measure<const D: usize>(workspace: &FitWorkspace<D>) -> f64 {
    workspace
        .faces
        .iter()
        .map(|face| {
            let n = face_normal(&face.map(|i| workspace.rest_surface[i as usize]));
            dot(&n, &n).sqrt() / if D == 3 { 2.0 } else { 1.0 }
        })
        .sum()
}

/// The volume term of the surface nodes at `positions` (of `n` model nodes), weight `weight`
/// ($w$; none at 0).
pub(super) fn volume_term<const D: usize>(
    workspace: &FitWorkspace<D>,
    positions: &[[f64; D]],
    n: usize,
    weight: f64,
) -> Option<VolumeTerm> {
    if !(weight > 0.0) {
        return None;
    }
    let rest = enclosed_measure(&workspace.rest_surface, &workspace.faces);
    let boundary = boundary_measure(workspace);
    if !(rest > 0.0 && boundary > 0.0) {
        return None;
    }
    let now = enclosed_measure(positions, &workspace.faces);
    let mut gradient = vec![0.0; n * D];
    for (&node, g) in workspace
        .surface
        .iter()
        .zip(measure_gradient(positions, &workspace.faces))
    {
        gradient[node as usize * D..(node as usize + 1) * D].copy_from_slice(&g);
    }
    Some(VolumeTerm {
        gradient,
        residual: now - rest,
        weight: weight * workspace.surface.len() as f64 / (boundary * boundary),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The gradient against central differences of the enclosed measure, on a tetrahedron
    /// and a triangle's contour.
    #[test]
    fn the_measure_gradient_matches_finite_differences() {
        let tet = vec![
            [0.1, 0.0, 0.2],
            [1.0, 0.1, 0.0],
            [0.0, 1.2, 0.1],
            [0.2, 0.1, 0.9],
        ];
        let faces: Vec<[u32; 3]> = vec![[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]];
        check(&tet, &faces);
        let triangle = vec![[0.0, 0.1], [1.0, 0.2], [0.3, 0.8]];
        let edges: Vec<[u32; 2]> = vec![[0, 1], [1, 2], [2, 0]];
        check(&triangle, &edges);
    }

    fn check<const D: usize>(vertices: &[[f64; D]], faces: &[[u32; D]]) {
        let gradient = measure_gradient(vertices, faces);
        let h = 1e-6;
        for i in 0..vertices.len() {
            for axis in 0..D {
                let mut plus = vertices.to_vec();
                let mut minus = vertices.to_vec();
                plus[i][axis] += h;
                minus[i][axis] -= h;
                let numeric =
                    (enclosed_measure(&plus, faces) - enclosed_measure(&minus, faces)) / (2.0 * h);
                assert!((numeric - gradient[i][axis]).abs() < 1e-8, "{i} {axis}");
            }
        }
    }
}
