//! Moving Least Squares shape functions with a linear basis and their gradients, evaluated at
//! the nodes of a 2-D or 3-D point cloud (SPEC 4.2; Belytschko, Lu & Gu 1994, element-free
//! Galerkin).
//!
//! At node $p$ with neighbours $N_p$ (the node included) and support radius $d_p$:
//!
//! * basis $\mathbf p(x) = [1, (x - x_p) / d_p]$, centred on the node and scaled by its
//!   support so that the moment matrix has entries of order one;
//! * weight $w_i(x) = \prod_a w(|x_a - x_{i,a}| / d_p)$, the tensor product of the cubic
//!   spline $w(r) = 2/3 - 4r^2 + 4r^3$ ($r \le 1/2$), $\tfrac43 (1 - r)^3$ ($1/2 < r \le 1$),
//!   0 beyond;
//! * $A = \sum_i w_i \mathbf p_i \mathbf p_i^\top$, $B = [w_i \mathbf p_i]$,
//!   $\Phi^\top = \mathbf p^\top A^{-1} B$, and
//!   $\partial_j \Phi^\top = \partial_j\mathbf p^\top A^{-1} B
//!   + \mathbf p^\top A^{-1} (\partial_j B - \partial_j A\, A^{-1} B)$.
//!
//! Both are computed through $\gamma = A^{-1}\mathbf p$ and
//! $\partial_j\gamma = A^{-1}(\partial_j \mathbf p - \partial_j A\,\gamma)$ with one Cholesky
//! factorisation of $A$ per node: $\Phi_i = w_i \gamma^\top \mathbf p_i$ and
//! $\partial_j \Phi_i = w_i\, \partial_j\gamma^\top \mathbf p_i
//! + \partial_j w_i\, \gamma^\top \mathbf p_i$.
//!
//! Why every neighbour has non-zero weight when $d_p = c\, r_k$ with $c > 1$ and $r_k$ the
//! distance to the farthest (k-th) neighbour: per axis $|x_{p,a} - x_{i,a}| \le |x_p - x_i|
//! \le r_k$, so $r_a \le 1/c < 1$, and the spline is positive on $[0, 1)$; the tensor
//! product of positive factors is positive. (With $c = 1$ the k-th neighbour would get zero
//! weight whenever it lies on a coordinate axis through $x_p$.)
//!
//! A neighbourhood that does not span the space (collinear in 2-D, coplanar in 3-D, or with
//! too few neighbours inside the support) makes $A$ singular. It is detected from the
//! reciprocal condition number of the Jacobi-equilibrated $A$ (below [`RCOND_MIN`]) and
//! repaired by enlarging that node's support by [`ENLARGEMENT`], up to
//! [`MAX_ENLARGEMENTS`] times; this helps when the neighbour list holds points that span
//! the space but lie outside, or at the very edge of, the support.

use nalgebra::{Cholesky, Const, SMatrix, SVector};
use rayon::prelude::*;

use crate::error::{check_finite, Error, Result};

/// Smallest admissible reciprocal condition number of the moment matrix after symmetric
/// Jacobi scaling to unit diagonal, the scaling-invariant condition number that governs the
/// accuracy of a Cholesky solve (van der Sluis 1969; Demmel 1989). It is estimated in the
/// Frobenius norm, $1 / (\lVert H \rVert_F \lVert H^{-1} \rVert_F)$, at most $M$ times
/// below the 2-norm value.
///
/// Chosen from the accuracy SPEC 4.2 asks for (1e-10). Measured over random clouds with
/// minimal neighbourhoods (k = D + 1), the partition of unity and linear reproduction stay
/// at ~1e-14 at any rcond, but the gradient identities degrade as ~$10^{-13} /
/// \text{rcond}$ (2e-8 at rcond = 1e-6), so $10^{-3}$ keeps accepted nodes near 1e-10.
/// Well-sampled neighbourhoods sit above it with room: with c = 1.1 on random, regular and
/// anisotropic clouds (boundary nodes included) the smallest value is 3e-2 for k = 20 and
/// 4e-3 for k = 2D + 2; only k <= D + 3 gives nodes below it (up to 10% of random 3-D
/// nodes at k = D + 1). Exactly coplanar or collinear neighbourhoods give $\lesssim
/// 10^{-16}$ or fail to factor.
pub const RCOND_MIN: f64 = 1e-3;

/// Factor by which an ill-conditioned node's support is enlarged per repair step.
pub const ENLARGEMENT: f64 = 1.25;

/// Repair steps tried before giving up: $1.25^4 \approx 2.4$ times the original support.
pub const MAX_ENLARGEMENTS: usize = 4;

/// Shape functions and gradients at every node, for nodes with `k` neighbours each.
#[derive(Debug, Clone)]
pub struct ShapeFunctions<const D: usize> {
    /// Neighbours per node (the node included).
    pub k: usize,
    /// Row-major `(n, k)`: $\Phi_i(x_p)$ for neighbour `i` of node `p`, in the order of the
    /// neighbour lists.
    pub phi: Vec<f64>,
    /// Row-major `(n, k)`: $\nabla \Phi_i(x_p)$, in inverse units of the points.
    pub grad: Vec<[f64; D]>,
    /// `(n,)`: the support radius used at each node (the given one, or enlarged).
    pub support: Vec<f64>,
    /// Number of nodes whose support was enlarged.
    pub repaired: usize,
}

/// The cubic spline $w(r)$ of SPEC 4.2 and its derivative $w'(r)$, for $r \ge 0$.
#[inline]
fn cubic_spline(r: f64) -> (f64, f64) {
    if r <= 0.5 {
        (
            2.0 / 3.0 - 4.0 * r * r + 4.0 * r * r * r,
            -8.0 * r + 12.0 * r * r,
        )
    } else if r <= 1.0 {
        let s = 1.0 - r;
        (4.0 / 3.0 * s * s * s, -4.0 * s * s)
    } else {
        (0.0, 0.0)
    }
}

/// Basis $\mathbf p_i$, weight $w_i$ and weight gradient $\nabla w_i$ at $x_p$, for a
/// neighbour at offset `offset` $= x_i - x_p$ and support `ddm`.
#[inline]
fn basis_and_weight<const D: usize, const M: usize>(
    offset: [f64; D],
    ddm: f64,
) -> (SVector<f64, M>, f64, [f64; D]) {
    let mut basis = SVector::<f64, M>::zeros();
    basis[0] = 1.0;
    let mut factors = [(0.0, 0.0); D];
    for a in 0..D {
        let scaled = offset[a] / ddm;
        basis[a + 1] = scaled;
        factors[a] = cubic_spline(scaled.abs());
    }
    let weight = factors.iter().map(|f| f.0).product::<f64>();
    // d r_a / d x_a = sign(x_p,a - x_i,a) / ddm = -sign(offset_a) / ddm; at r = 0, w' = 0.
    let gradient = std::array::from_fn(|j| {
        let others: f64 = (0..D).filter(|&a| a != j).map(|a| factors[a].0).product();
        -factors[j].1 * offset[j].signum() / ddm * others
    });
    (basis, weight, gradient)
}

/// The moment matrix $A$ factored after symmetric Jacobi scaling: $H = S A S$ with
/// $S = \mathrm{diag}(A_{ii}^{-1/2})$ (unit diagonal), $H = L L^\top$.
struct Moments<const M: usize> {
    scale: SVector<f64, M>,
    cholesky: Cholesky<f64, Const<M>>,
}

impl<const M: usize> Moments<M> {
    /// Factors `a` and estimates the reciprocal condition number of $H$ as
    /// $1 / (\lVert H \rVert_F \lVert H^{-1} \rVert_F)$, which lies between $1/M$ times
    /// and once the 2-norm value $\lambda_{min} / \lambda_{max}$. Returns `(None, 0)`
    /// when $H$ is not numerically positive definite.
    fn factor(a: &SMatrix<f64, M, M>) -> (Option<Self>, f64) {
        let mut scale = SVector::<f64, M>::zeros();
        for i in 0..M {
            let d = a[(i, i)];
            if !(d > 0.0 && d.is_finite()) {
                return (None, 0.0);
            }
            scale[i] = d.sqrt().recip();
        }
        let h = SMatrix::<f64, M, M>::from_fn(|i, j| a[(i, j)] * scale[i] * scale[j]);
        let Some(cholesky) = h.cholesky() else {
            return (None, 0.0);
        };
        let mut inverse_norm2 = 0.0f64;
        for i in 0..M {
            let mut unit = SVector::<f64, M>::zeros();
            unit[i] = 1.0;
            inverse_norm2 += cholesky.solve(&unit).norm_squared();
        }
        let rcond = (h.norm() * inverse_norm2.sqrt()).recip();
        let rcond = if rcond.is_finite() { rcond } else { 0.0 };
        (Some(Moments { scale, cholesky }), rcond)
    }

    /// $A^{-1} b = S H^{-1} S b$.
    fn solve(&self, b: &SVector<f64, M>) -> SVector<f64, M> {
        self.cholesky
            .solve(&b.component_mul(&self.scale))
            .component_mul(&self.scale)
    }
}

/// One node: writes `phi` and `grad` for its neighbours, returns the support used.
/// `M` is `D + 1`.
fn node<const D: usize, const M: usize>(
    p: usize,
    points: &[[f64; D]],
    neighbors: &[u32],
    support: f64,
    phi: &mut [f64],
    grad: &mut [[f64; D]],
) -> Result<f64> {
    let xp = points[p];
    let offset = |i: u32| -> [f64; D] {
        let xi = points[i as usize];
        std::array::from_fn(|a| xi[a] - xp[a])
    };
    let mut ddm = support;
    let mut rcond = 0.0;
    for attempt in 0..=MAX_ENLARGEMENTS {
        if attempt > 0 {
            ddm *= ENLARGEMENT;
        }
        let mut a = SMatrix::<f64, M, M>::zeros();
        let mut da = [SMatrix::<f64, M, M>::zeros(); D];
        for &i in neighbors {
            let (basis, w, dw) = basis_and_weight::<D, M>(offset(i), ddm);
            let outer = basis * basis.transpose();
            a += outer * w;
            for j in 0..D {
                da[j] += outer * dw[j];
            }
        }
        let moments;
        (moments, rcond) = Moments::factor(&a);
        let Some(moments) = moments.filter(|_| rcond >= RCOND_MIN) else {
            continue;
        };
        let mut at_node = SVector::<f64, M>::zeros();
        at_node[0] = 1.0;
        let gamma = moments.solve(&at_node);
        let dgamma: [SVector<f64, M>; D] = std::array::from_fn(|j| {
            let mut rhs = -(da[j] * gamma);
            rhs[j + 1] += 1.0 / ddm;
            moments.solve(&rhs)
        });
        for ((&i, phi), grad) in neighbors.iter().zip(phi.iter_mut()).zip(grad.iter_mut()) {
            let (basis, w, dw) = basis_and_weight::<D, M>(offset(i), ddm);
            let g = gamma.dot(&basis);
            *phi = w * g;
            *grad = std::array::from_fn(|j| w * dgamma[j].dot(&basis) + dw[j] * g);
        }
        return Ok(ddm);
    }
    Err(Error::IllConditioned {
        node: p,
        rcond,
        support: ddm,
    })
}

/// Checks the inputs of [`shape_functions_into`] and returns the number of nodes.
fn check_inputs<const D: usize>(
    points: &[[f64; D]],
    neighbors: &[u32],
    k: usize,
    support: &[f64],
) -> Result<usize> {
    let n = points.len();
    if n == 0 {
        return Err(Error::Empty {
            argument: "points",
            needed: 1,
        });
    }
    if n > u32::MAX as usize {
        return Err(Error::TooManyPoints {
            argument: "points",
            got: n,
            max: u32::MAX as usize,
        });
    }
    if k < D + 1 {
        return Err(Error::NotEnoughNeighbours {
            found: k,
            needed: D + 1,
        });
    }
    if neighbors.len() != n * k {
        return Err(Error::LengthMismatch {
            argument: "neighbors",
            expected: n,
            got: neighbors.len() / k,
        });
    }
    if support.len() != n {
        return Err(Error::LengthMismatch {
            argument: "support",
            expected: n,
            got: support.len(),
        });
    }
    check_finite("points", points)?;
    if let Some(node) = support
        .par_iter()
        .position_first(|s| !(s.is_finite() && *s > 0.0))
    {
        return Err(Error::InvalidSupport {
            node,
            value: support[node],
        });
    }
    let bad_row = neighbors
        .par_chunks(k)
        .enumerate()
        .find_first(|(p, row)| row.iter().any(|&i| i as usize >= n) || !row.contains(&(*p as u32)));
    if let Some((row, indices)) = bad_row {
        return Err(match indices.iter().position(|&i| i as usize >= n) {
            Some(column) => Error::NeighborIndex {
                row,
                column,
                index: i64::from(indices[column]),
                n,
            },
            None => Error::SelfNotNeighbour { node: row },
        });
    }
    Ok(n)
}

/// MLS shape functions and gradients at every node, written into caller-provided buffers;
/// returns the number of nodes whose support was enlarged. `M` must be `D + 1` (the size of
/// the linear basis): call it as `shape_functions_into::<3, 4>` or `::<2, 3>`.
///
/// `neighbors` is row-major `(n, k)`, each row holding node `p` itself among its `k`
/// neighbours; `support` holds the radii $d_p$ (SPEC 4.1: $c\,r_k$). Outputs: `phi` and
/// `grad` row-major `(n, k)` in the order of `neighbors`, `support_used` `(n,)`.
///
/// # Errors
/// [`Error::Empty`], [`Error::TooManyPoints`], [`Error::NonFinite`] for bad points;
/// [`Error::NotEnoughNeighbours`] for `k < D + 1`; [`Error::LengthMismatch`] when
/// `neighbors` or `support` do not have `n` rows; [`Error::NeighborIndex`] /
/// [`Error::SelfNotNeighbour`] for bad neighbour lists; [`Error::InvalidSupport`] for a
/// radius that is not positive and finite; [`Error::OutputSize`] for wrong buffers;
/// [`Error::IllConditioned`] naming the first node whose neighbourhood stays degenerate
/// after [`MAX_ENLARGEMENTS`] enlargements.
pub fn shape_functions_into<const D: usize, const M: usize>(
    points: &[[f64; D]],
    neighbors: &[u32],
    k: usize,
    support: &[f64],
    phi: &mut [f64],
    grad: &mut [[f64; D]],
    support_used: &mut [f64],
) -> Result<usize> {
    const {
        assert!(
            (D == 2 || D == 3) && M == D + 1,
            "MLS is implemented in 2-D and 3-D with M = D + 1"
        )
    };
    let n = check_inputs(points, neighbors, k, support)?;
    for (expected, got) in [
        (n * k, phi.len()),
        (n * k, grad.len()),
        (n, support_used.len()),
    ] {
        if expected != got {
            return Err(Error::OutputSize { expected, got });
        }
    }
    let outcomes: Vec<Result<bool>> = phi
        .par_chunks_mut(k)
        .zip(grad.par_chunks_mut(k))
        .zip(support_used.par_iter_mut())
        .enumerate()
        .map(|(p, ((phi, grad), used))| {
            let row = &neighbors[p * k..(p + 1) * k];
            let ddm = node::<D, M>(p, points, row, support[p], phi, grad)?;
            *used = ddm;
            Ok(ddm != support[p])
        })
        .collect();
    let mut repaired = 0;
    for outcome in outcomes {
        repaired += usize::from(outcome?);
    }
    Ok(repaired)
}

/// [`shape_functions_into`] allocating its outputs.
///
/// # Errors
/// As [`shape_functions_into`].
pub fn shape_functions<const D: usize, const M: usize>(
    points: &[[f64; D]],
    neighbors: &[u32],
    k: usize,
    support: &[f64],
) -> Result<ShapeFunctions<D>> {
    let n = points.len();
    let mut phi = vec![0.0; n * k];
    let mut grad = vec![[0.0; D]; n * k];
    let mut used = vec![0.0; n];
    let repaired = shape_functions_into::<D, M>(
        points, neighbors, k, support, &mut phi, &mut grad, &mut used,
    )?;
    Ok(ShapeFunctions {
        k,
        phi,
        grad,
        support: used,
        repaired,
    })
}

#[cfg(test)]
mod tests;
