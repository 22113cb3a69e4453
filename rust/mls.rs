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
mod tests {
    use super::*;
    use crate::SpatialHash;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The SPEC 4.2 identities hold to this, with gradients made dimensionless by the support.
    const IDENTITY_ATOL: f64 = 1e-10;

    /// Neighbours as `elastocap.mls_shape_functions` builds them: the node, then its k - 1
    /// nearest; support 1.1 times the farthest.
    fn neighbourhoods<const D: usize>(points: &[[f64; D]], k: usize) -> (Vec<u32>, Vec<f64>) {
        let knn = SpatialHash::new(points).unwrap().knn(None, k - 1).unwrap();
        let mut neighbors = Vec::with_capacity(points.len() * k);
        let mut support = Vec::with_capacity(points.len());
        for p in 0..points.len() {
            neighbors.push(p as u32);
            neighbors.extend(
                knn.indices[p * (k - 1)..(p + 1) * (k - 1)]
                    .iter()
                    .map(|&i| i as u32),
            );
            support.push(1.1 * knn.distances[(p + 1) * (k - 1) - 1]);
        }
        (neighbors, support)
    }

    fn random_cloud<const D: usize>(seed: u64, n: usize, stretch: [f64; D]) -> Vec<[f64; D]> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .map(|_| std::array::from_fn(|a| stretch[a] * rng.random_range(0.0..1.0)))
            .collect()
    }

    fn grid_cloud<const D: usize>(side: usize) -> Vec<[f64; D]> {
        (0..side.pow(D as u32))
            .map(|mut c| {
                std::array::from_fn(|_| {
                    let v = (c % side) as f64 / side as f64;
                    c /= side;
                    v
                })
            })
            .collect()
    }

    /// Largest violation of the four identities over all nodes.
    fn identity_error<const D: usize>(
        points: &[[f64; D]],
        neighbors: &[u32],
        s: &ShapeFunctions<D>,
    ) -> f64 {
        let k = s.k;
        let mut worst = 0.0f64;
        for p in 0..points.len() {
            let mut sum_phi = 0.0;
            let mut sum_phi_x = [0.0; D];
            let mut sum_grad = [0.0; D];
            let mut sum_grad_x = [[0.0; D]; D];
            for c in 0..k {
                let i = neighbors[p * k + c] as usize;
                let (phi, grad) = (s.phi[p * k + c], s.grad[p * k + c]);
                sum_phi += phi;
                for a in 0..D {
                    sum_phi_x[a] += phi * points[i][a];
                    sum_grad[a] += grad[a] * s.support[p];
                    for b in 0..D {
                        sum_grad_x[a][b] += grad[a] * points[i][b];
                    }
                }
            }
            worst = worst.max((sum_phi - 1.0).abs());
            for a in 0..D {
                worst = worst.max((sum_phi_x[a] - points[p][a]).abs());
                worst = worst.max(sum_grad[a].abs());
                for (b, &value) in sum_grad_x[a].iter().enumerate() {
                    let identity = if a == b { 1.0 } else { 0.0 };
                    worst = worst.max((value - identity).abs());
                }
            }
        }
        worst
    }

    /// Estimated reciprocal condition number of node `p`'s moment matrix at support `ddm`.
    fn rcond_at<const D: usize, const M: usize>(
        points: &[[f64; D]],
        row: &[u32],
        p: usize,
        ddm: f64,
    ) -> f64 {
        let mut a = SMatrix::<f64, M, M>::zeros();
        for &i in row {
            let offset = std::array::from_fn(|c| points[i as usize][c] - points[p][c]);
            let (basis, w, _) = basis_and_weight::<D, M>(offset, ddm);
            a += basis * basis.transpose() * w;
        }
        Moments::factor(&a).1
    }

    /// Smallest [`rcond_at`] over all nodes.
    fn smallest_rcond<const D: usize, const M: usize>(
        points: &[[f64; D]],
        neighbors: &[u32],
        k: usize,
        support: &[f64],
    ) -> f64 {
        (0..points.len())
            .map(|p| rcond_at::<D, M>(points, &neighbors[p * k..(p + 1) * k], p, support[p]))
            .fold(f64::INFINITY, f64::min)
    }

    fn check_cloud<const D: usize, const M: usize>(points: &[[f64; D]], k: usize) {
        let (neighbors, support) = neighbourhoods(points, k);
        let s = shape_functions::<D, M>(points, &neighbors, k, &support).unwrap();
        assert_eq!(s.repaired, 0, "a well-sampled cloud needs no repair");
        assert_eq!(s.support, support);
        let error = identity_error(points, &neighbors, &s);
        assert!(error < IDENTITY_ATOL, "identities violated by {error:e}");
        // Every neighbour inside c * r_k carries weight.
        for p in 0..points.len() {
            for &i in &neighbors[p * k..(p + 1) * k] {
                let offset = std::array::from_fn(|c| points[i as usize][c] - points[p][c]);
                let (_, w, _) = basis_and_weight::<D, M>(offset, support[p]);
                assert!(w > 0.0, "neighbour {i} of node {p} has zero weight");
            }
        }
        // Well-sampled neighbourhoods, boundary nodes included, sit far above the threshold.
        let rcond = smallest_rcond::<D, M>(points, &neighbors, k, &support);
        assert!(rcond > 10.0 * RCOND_MIN, "smallest rcond {rcond:e}");
    }

    #[test]
    fn spline_is_continuous_with_its_derivative() {
        for r in [0.5, 1.0] {
            let (below, above) = (cubic_spline(r - 1e-12), cubic_spline(r + 1e-12));
            assert!((below.0 - above.0).abs() < 1e-10 && (below.1 - above.1).abs() < 1e-10);
        }
        for r in [0.1, 0.3, 0.6, 0.9] {
            let h = 1e-6;
            let fd = (cubic_spline(r + h).0 - cubic_spline(r - h).0) / (2.0 * h);
            assert!((fd - cubic_spline(r).1).abs() < 1e-8);
        }
        assert_eq!(cubic_spline(1.5), (0.0, 0.0));
    }

    #[test]
    fn identities_on_random_clouds() {
        for seed in 0..3 {
            check_cloud::<2, 3>(&random_cloud(seed, 400, [1.0, 1.0]), 12);
            check_cloud::<3, 4>(&random_cloud(seed, 800, [1.0, 1.0, 1.0]), 20);
        }
    }

    #[test]
    fn identities_on_regular_grids() {
        check_cloud::<2, 3>(&grid_cloud(15), 9);
        check_cloud::<2, 3>(&grid_cloud(15), 12);
        check_cloud::<3, 4>(&grid_cloud(8), 20);
        check_cloud::<3, 4>(&grid_cloud(8), 27);
    }

    #[test]
    fn identities_on_anisotropic_clouds() {
        for seed in 10..13 {
            check_cloud::<2, 3>(&random_cloud(seed, 400, [10.0, 1.0]), 12);
            check_cloud::<3, 4>(&random_cloud(seed, 800, [1.0, 10.0, 1.0]), 20);
        }
    }

    /// A 3x3 patch in the plane z = 0 and two points above and below it at height `h`; every
    /// node lists all 11 points, with support 1.1 times the in-plane half-diagonal.
    fn patch_with_poles(h: f64) -> (Vec<[f64; 3]>, Vec<u32>, Vec<f64>) {
        let mut points: Vec<[f64; 3]> = (0..9)
            .map(|c| [(c % 3) as f64 - 1.0, (c / 3) as f64 - 1.0, 0.0])
            .collect();
        points.swap(0, 4); // node 0 at the centre
        points.extend([[0.0, 0.0, h], [0.0, 0.0, -h]]);
        let n = points.len();
        let neighbors = (0..n).flat_map(|_| 0..n as u32).collect();
        (points, neighbors, vec![1.1 * 2f64.sqrt(); n])
    }

    #[test]
    fn coplanar_neighbourhood_is_repaired_when_enlarging_reaches_off_plane_points() {
        // The poles at z = +-2 lie beyond the centre's support (r_z = 1.29), so its weighted
        // neighbours are coplanar; two enlargements (r_z = 0.82) bring them in.
        let (points, neighbors, support) = patch_with_poles(2.0);
        let rcond = rcond_at::<3, 4>(&points, &neighbors[..11], 0, support[0]);
        assert!(
            rcond < 1e-12,
            "the centre's weighted neighbourhood is coplanar: {rcond:e}"
        );
        let s = shape_functions::<3, 4>(&points, &neighbors, 11, &support).unwrap();
        assert!(s.repaired >= 1);
        assert!((s.support[0] - support[0] * ENLARGEMENT * ENLARGEMENT).abs() < 1e-12);
        assert!(
            s.phi[9] > 0.0 && s.phi[10] > 0.0,
            "the poles now carry weight"
        );
        let error = identity_error(&points, &neighbors, &s);
        assert!(error < IDENTITY_ATOL, "identities violated by {error:e}");
    }

    #[test]
    fn coplanar_cloud_is_an_error_naming_the_node() {
        let (points, neighbors, support) = patch_with_poles(0.0);
        let err = shape_functions::<3, 4>(&points, &neighbors, 11, &support).unwrap_err();
        match err {
            Error::IllConditioned {
                node,
                rcond,
                support: last,
            } => {
                assert_eq!(node, 0);
                assert!(rcond < RCOND_MIN);
                assert!(
                    (last - support[0] * ENLARGEMENT.powi(MAX_ENLARGEMENTS as i32)).abs() < 1e-12
                );
            }
            other => panic!("expected IllConditioned, got {other:?}"),
        }
        assert!(err.is_invalid_input());
        // Collinear in 2-D likewise.
        let line: Vec<[f64; 2]> = (0..6).map(|i| [i as f64, 2.0 * i as f64]).collect();
        let neighbors: Vec<u32> = (0..6).flat_map(|_| 0..6u32).collect();
        let err = shape_functions::<2, 3>(&line, &neighbors, 6, &[10.0; 6]).unwrap_err();
        assert!(matches!(err, Error::IllConditioned { node: 0, .. }));
    }

    #[test]
    fn bad_input_is_an_error_not_a_panic() {
        let points = grid_cloud::<2>(4);
        let (neighbors, support) = neighbourhoods(&points, 5);
        let run = |pts: &[[f64; 2]], nb: &[u32], k: usize, s: &[f64]| {
            shape_functions::<2, 3>(pts, nb, k, s).unwrap_err()
        };
        assert!(matches!(
            run(&points, &neighbors[..32], 2, &support),
            Error::NotEnoughNeighbours {
                found: 2,
                needed: 3
            }
        ));
        assert!(matches!(
            run(&points, &neighbors[..75], 5, &support),
            Error::LengthMismatch {
                argument: "neighbors",
                ..
            }
        ));
        assert!(matches!(
            run(&points, &neighbors, 5, &support[1..]),
            Error::LengthMismatch {
                argument: "support",
                ..
            }
        ));
        let mut bad = neighbors.clone();
        bad[7] = 16;
        assert!(matches!(
            run(&points, &bad, 5, &support),
            Error::NeighborIndex {
                row: 1,
                column: 2,
                index: 16,
                n: 16
            }
        ));
        let mut bad = neighbors.clone();
        bad[5] = 0; // row 1 without node 1
        assert!(matches!(
            run(&points, &bad, 5, &support),
            Error::SelfNotNeighbour { node: 1 }
        ));
        let mut bad = support.clone();
        bad[3] = 0.0;
        assert!(matches!(
            run(&points, &neighbors, 5, &bad),
            Error::InvalidSupport { node: 3, .. }
        ));
        bad[3] = f64::NAN;
        assert!(matches!(
            run(&points, &neighbors, 5, &bad),
            Error::InvalidSupport { node: 3, .. }
        ));
        let mut bad = points.clone();
        bad[2][1] = f64::INFINITY;
        assert!(matches!(
            run(&bad, &neighbors, 5, &support),
            Error::NonFinite {
                argument: "points",
                row: 2
            }
        ));
        assert!(matches!(run(&[], &[], 5, &[]), Error::Empty { .. }));
        let mut phi = vec![0.0; 3];
        let err = shape_functions_into::<2, 3>(
            &points,
            &neighbors,
            5,
            &support,
            &mut phi,
            &mut [],
            &mut [],
        )
        .unwrap_err();
        assert!(matches!(err, Error::OutputSize { .. }));
    }
}
