//! Preconditioned conjugate gradients (Hestenes & Stiefel 1952; Saad, *Iterative Methods
//! for Sparse Linear Systems*, Alg. 9.1) on a [`BlockCsr`], warm-started from the given $x$.
//!
//! The iteration stops when the relative residual $\|b - A x\| / \|b\|$ falls to the
//! tolerance. The recursively updated residual drifts from the true one over many
//! iterations, so convergence is confirmed on the true residual (one extra product); when
//! they disagree the iteration restarts from the true residual.

use rayon::prelude::*;

use super::block::{BlockCsr, CsrIndex};
use super::upper::Upper;

mod jacobi;
mod rank_one;
use crate::error::{check_finite, Error, Result};
use crate::ordered::sum_chunks;
pub use jacobi::BlockJacobi;
pub use rank_one::{PlusRankOne, RankOne, ShermanMorrison};

/// Below this many scalar entries, vector updates and dot products run on one thread:
/// at the paper's size (7,395 unknowns) one pass takes ~5 us, less than waking the pool
/// (see benches/README.md). The matrix product is always split by block rows.
const PARALLEL_VECTOR_LEN: usize = 1 << 16;

/// Blocks per chunk of the parallel dot products. The chunks' partial sums are added in
/// order ([`crate::ordered`]), so a long vector's dot product, and with it the iteration,
/// is the same on any thread count.
const DOT_CHUNK: usize = 4096;

/// $z = M^{-1} r$ for a symmetric positive definite $M \approx A$.
pub trait Preconditioner<const B: usize> {
    /// Writes $M^{-1} r$ into `z` (both of the matrix size).
    fn apply(&mut self, r: &[[f64; B]], z: &mut [[f64; B]]);

    /// [`Self::apply`], returning $r^\top z$; a preconditioner may do both in one pass.
    fn apply_dot(&mut self, r: &[[f64; B]], z: &mut [[f64; B]]) -> f64 {
        self.apply(r, z);
        dot(r, z)
    }
}

/// $y = A x$ for a symmetric positive definite $A$ that need not be stored: the matrix-free
/// products of the elastic model are ~3x cheaper than an assembled one (benches/README.md).
pub trait LinearOperator<const B: usize> {
    /// Number of block rows.
    fn len(&self) -> usize;
    /// True without rows.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Writes $A x$ into `y` (both `len()` blocks).
    fn apply(&mut self, x: &[[f64; B]], y: &mut [[f64; B]]);

    /// Writes an approximation of $A x$ into `y` for the inner iterations, e.g. from a
    /// float32 copy of the matrix; the residuals that decide convergence always come from
    /// [`Self::apply`]. Default: [`Self::apply`].
    fn apply_inner(&mut self, x: &[[f64; B]], y: &mut [[f64; B]]) {
        self.apply(x, y);
    }

    /// True when [`Self::apply_inner`] is not [`Self::apply`] (default: false).
    fn inexact_inner(&self) -> bool {
        false
    }
}

/// An assembled matrix as an operator, through its upper triangle; exact products from
/// the matrix itself when the upper triangle is held in float32 alone.
struct Assembled<'a, const B: usize>(&'a mut Upper<B>, Option<&'a BlockCsr<B>>, usize);

impl<const B: usize> LinearOperator<B> for Assembled<'_, B> {
    fn len(&self) -> usize {
        self.2
    }
    fn apply(&mut self, x: &[[f64; B]], y: &mut [[f64; B]]) {
        match self.1 {
            Some(matrix) if !self.0.has_exact() => matrix.mul_unchecked(x, y),
            _ => self.0.mul(x, y),
        }
    }
    fn apply_inner(&mut self, x: &[[f64; B]], y: &mut [[f64; B]]) {
        self.0.mul_inner(x, y);
    }
    fn inexact_inner(&self) -> bool {
        self.0.inexact_inner()
    }
}

/// Outcome of a conjugate-gradient solve; not converging is reported here, not as an error.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PcgStatus {
    /// The true relative residual reached the tolerance.
    pub converged: bool,
    /// Iterations run (matrix products, not counting the residual checks).
    pub iterations: usize,
    /// $\|b - A x\| / \|b\|$ of the returned $x$, from the true residual (0 for $b = 0$).
    pub relative_residual: f64,
}

fn dot<const B: usize>(a: &[[f64; B]], b: &[[f64; B]]) -> f64 {
    let one = |(x, y): (&[f64; B], &[f64; B])| (0..B).map(|t| x[t] * y[t]).sum::<f64>();
    if a.len() * B >= PARALLEL_VECTOR_LEN {
        sum_chunks(a.len(), DOT_CHUNK, |range| {
            a[range.clone()].iter().zip(&b[range]).map(one).sum()
        })
    } else {
        a.iter().zip(b).map(one).sum()
    }
}

/// `y[i] = f(y[i], x[i])` over blocks, in parallel for long vectors.
fn update<const B: usize, F>(y: &mut [[f64; B]], x: &[[f64; B]], f: F)
where
    F: Fn(&mut [f64; B], &[f64; B]) + Sync + Send,
{
    if y.len() * B >= PARALLEL_VECTOR_LEN {
        y.par_iter_mut().zip(x).for_each(|(a, b)| f(a, b));
    } else {
        y.iter_mut().zip(x).for_each(|(a, b)| f(a, b));
    }
}

/// $x \mathrel{+}= \alpha p$, $r \mathrel{-}= \alpha q$, returning $r^\top r$: one pass
/// over the vectors instead of three.
fn step<const B: usize>(
    x: &mut [[f64; B]],
    r: &mut [[f64; B]],
    p: &[[f64; B]],
    q: &[[f64; B]],
    alpha: f64,
) -> f64 {
    let one = |x: &mut [f64; B], r: &mut [f64; B], p: &[f64; B], q: &[f64; B]| {
        let mut rr = 0.0;
        for a in 0..B {
            x[a] += alpha * p[a];
            r[a] -= alpha * q[a];
            rr += r[a] * r[a];
        }
        rr
    };
    if x.len() * B >= PARALLEL_VECTOR_LEN {
        // As `dot`: fixed chunks, their sums added in order.
        let partial: Vec<f64> = x
            .par_chunks_mut(DOT_CHUNK)
            .zip(r.par_chunks_mut(DOT_CHUNK))
            .zip(p.par_chunks(DOT_CHUNK).zip(q.par_chunks(DOT_CHUNK)))
            .map(|((x, r), (p, q))| {
                x.iter_mut()
                    .zip(r.iter_mut())
                    .zip(p.iter().zip(q))
                    .map(|((x, r), (p, q))| one(x, r, p, q))
                    .sum::<f64>()
            })
            .collect();
        partial.iter().sum()
    } else {
        x.iter_mut()
            .zip(r.iter_mut())
            .zip(p.iter().zip(q))
            .map(|((x, r), (p, q))| one(x, r, p, q))
            .sum()
    }
}

/// Inexact (float32) inner products: each cycle of iterations reduces the residual by this
/// factor before the true residual is recomputed with exact products (iterative
/// refinement). On the paper's system (cold, 1e-8) 1e-2 / 1e-3 / 1e-4 / 1e-5 / 1e-6 / 1e-9
/// took 73 / 70 / 70 / 68 / 66 / 72 iterations against 65 with exact products: the float32
/// error stays below 1e-6 of the residual, and fewer restarts keep more of the Krylov space.
const INNER_REDUCTION: f64 = 1e-6;

/// Conjugate gradients with its work vectors, kept across solves of one size so that the
/// per-iteration solve of a fitting loop allocates nothing.
#[derive(Debug, Clone, Default)]
pub struct Pcg<const B: usize> {
    r: Vec<[f64; B]>,
    z: Vec<[f64; B]>,
    p: Vec<[f64; B]>,
    q: Vec<[f64; B]>,
    upper: Upper<B>,
}

impl<const B: usize> Pcg<B> {
    /// Empty work vectors, sized on first use.
    pub fn new() -> Self {
        Self {
            r: Vec::new(),
            z: Vec::new(),
            p: Vec::new(),
            q: Vec::new(),
            upper: Upper::default(),
        }
    }

    /// Solves $A x = b$ from the initial guess in `x`, overwriting it, until
    /// $\|b - Ax\| \le \text{tolerance}\,\|b\|$ or `max_iterations` iterations.
    ///
    /// # Errors
    /// [`Error::VectorLength`] / [`Error::NonFinite`] for `rhs` and `x`;
    /// [`Error::InvalidOption`] for a negative or non-finite tolerance;
    /// [`Error::NotPositiveDefinite`] when a search direction has non-positive curvature
    /// $p^\top A p \le 0$ (the matrix is not positive definite). Not converging is not an
    /// error: see [`PcgStatus::converged`].
    pub fn solve<P: Preconditioner<B> + ?Sized>(
        &mut self,
        matrix: &BlockCsr<B>,
        preconditioner: &mut P,
        rhs: &[f64],
        x: &mut [f64],
        tolerance: f64,
        max_iterations: usize,
    ) -> Result<PcgStatus> {
        let mut upper = std::mem::take(&mut self.upper);
        upper.load(matrix);
        let result = self.solve_operator(
            &mut Assembled(&mut upper, Some(matrix), matrix.len()),
            preconditioner,
            rhs,
            x,
            tolerance,
            max_iterations,
        );
        self.upper = upper;
        result
    }

    /// Block-Jacobi conjugate gradients on a scalar CSR matrix (scipy's arrays, columns
    /// sorted within rows): [`BlockCsr::from_csr_parts`], [`BlockJacobi::new`] and
    /// [`Self::solve`] in one, reading the arrays straight into the upper triangle the
    /// products use (no full block matrix: from Python this halved the conversion).
    ///
    /// # Errors
    /// As [`BlockCsr::from_csr_parts`], [`BlockJacobi::new`] and [`Self::solve`].
    #[allow(clippy::too_many_arguments)] // the CSR arrays, then `solve`'s arguments
    pub fn solve_csr_parts<I: CsrIndex>(
        &mut self,
        size: usize,
        indptr: &[I],
        indices: &[I],
        data: &[f64],
        rhs: &[f64],
        x: &mut [f64],
        tolerance: f64,
        max_iterations: usize,
    ) -> Result<PcgStatus> {
        let mut upper = Upper::<B>::from_csr_parts(size, indptr, indices, data)?;
        let mut jacobi = BlockJacobi::from_diagonal(&upper.diagonal())?;
        let result = self.solve_operator(
            &mut Assembled(&mut upper, None, size / B),
            &mut jacobi,
            rhs,
            x,
            tolerance,
            max_iterations,
        );
        self.upper = upper;
        result
    }

    /// [`Self::solve`] for any operator.
    ///
    /// # Errors
    /// As [`Self::solve`].
    pub fn solve_operator<O: LinearOperator<B> + ?Sized, P: Preconditioner<B> + ?Sized>(
        &mut self,
        operator: &mut O,
        preconditioner: &mut P,
        rhs: &[f64],
        x: &mut [f64],
        tolerance: f64,
        max_iterations: usize,
    ) -> Result<PcgStatus> {
        let size = operator.len() * B;
        for (argument, len) in [("rhs", rhs.len()), ("x", x.len())] {
            if len != size {
                return Err(Error::VectorLength {
                    argument,
                    expected: size,
                    got: len,
                });
            }
        }
        if !(tolerance.is_finite() && tolerance >= 0.0) {
            return Err(Error::InvalidOption {
                argument: "tolerance",
                value: tolerance,
                expected: "a finite number >= 0",
            });
        }
        let b = rhs.as_chunks::<B>().0;
        let x = x.as_chunks_mut::<B>().0;
        check_finite("rhs", b)?;
        check_finite("x", x)?;
        let n = operator.len();
        for v in [&mut self.r, &mut self.z, &mut self.p, &mut self.q] {
            v.resize(n, [0.0; B]);
        }
        let b_norm = dot(b, b).sqrt();
        if b_norm == 0.0 {
            x.iter_mut().for_each(|v| *v = [0.0; B]);
            return Ok(PcgStatus {
                converged: true,
                iterations: 0,
                relative_residual: 0.0,
            });
        }
        let target = tolerance * b_norm;
        let mut iterations = 0;
        // A cold start needs no product for its residual.
        let mut zero_start = x.iter().all(|v| *v == [0.0; B]);
        let mut inexact = operator.inexact_inner();
        let mut last_norm = f64::INFINITY;
        loop {
            // True residual r = b - A x: at the start and to confirm convergence.
            self.r.copy_from_slice(b);
            if !zero_start {
                operator.apply(x, &mut self.q);
                update(&mut self.r, &self.q, |r, q| {
                    for a in 0..B {
                        r[a] -= q[a];
                    }
                });
            }
            zero_start = false;
            let r_norm = dot(&self.r, &self.r).sqrt();
            if r_norm <= target || iterations >= max_iterations || !r_norm.is_finite() {
                return Ok(PcgStatus {
                    converged: r_norm <= target,
                    iterations,
                    relative_residual: r_norm / b_norm,
                });
            }
            // A cycle of inexact products that did not gain a factor 10: the approximation
            // is too coarse for this matrix; finish with exact products.
            if r_norm > 0.1 * last_norm {
                inexact = false;
            }
            last_norm = r_norm;
            let cycle_target = if inexact {
                target.max(INNER_REDUCTION * r_norm)
            } else {
                target
            };
            preconditioner.apply(&self.r, &mut self.z);
            self.p.copy_from_slice(&self.z);
            let mut rz = dot(&self.r, &self.z);
            while iterations < max_iterations {
                iterations += 1;
                if inexact {
                    operator.apply_inner(&self.p, &mut self.q);
                } else {
                    operator.apply(&self.p, &mut self.q);
                }
                let curvature = dot(&self.p, &self.q);
                if inexact && (curvature.is_nan() || curvature <= 0.0) {
                    // Perhaps only the approximation is not positive definite.
                    inexact = false;
                    break;
                }
                if curvature.is_nan() || curvature <= 0.0 {
                    return Err(Error::NotPositiveDefinite {
                        argument: "matrix",
                        row: 0,
                        reason: "conjugate gradients met a direction p with p^T A p <= 0",
                    });
                }
                let alpha = rz / curvature;
                if step(x, &mut self.r, &self.p, &self.q, alpha).sqrt() <= cycle_target {
                    break;
                }
                let rz_next = preconditioner.apply_dot(&self.r, &mut self.z);
                let beta = rz_next / rz;
                rz = rz_next;
                update(&mut self.p, &self.z, |p, z| {
                    for a in 0..B {
                        p[a] = z[a] + beta * p[a];
                    }
                });
            }
        }
    }
}
