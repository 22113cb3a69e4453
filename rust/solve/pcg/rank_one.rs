//! A symmetric positive rank-one term on top of a system: $(A + c\,g g^\top)\,x = b$ in one
//! conjugate-gradient solve.
//!
//! A dense rank-one term does not fit the sparse pattern. Sherman-Morrison on the solution
//! needs two solves with $A$ ($A^{-1} b$ and $A^{-1} g$); here the product adds the term
//! ($O(n)$ per iteration) and the preconditioner takes it by Sherman-Morrison on $M$:
//! $(M + c\,g g^\top)^{-1} r = M^{-1} r - c\,M^{-1} g\,(g^\top M^{-1} r) / (1 + c\,g^\top M^{-1} g)$,
//! one more application of $M$ per solve. The preconditioned operator then differs from
//! $M^{-1} A$'s by a low-rank part, which costs conjugate gradients a few iterations, not a
//! second solve (the fit's volume term, measured in benches/README.md).

use super::{dot, BlockCsr, LinearOperator, Pcg, PcgStatus, Preconditioner, Upper};
use crate::error::{Error, Result};

/// The term $c\,g g^\top$: `vector` $g$ (flat, the system's size), `weight` $c \ge 0$.
#[derive(Debug, Clone, Copy)]
pub struct RankOne<'a> {
    /// $g$, flat `(n B,)`.
    pub vector: &'a [f64],
    /// $c$.
    pub weight: f64,
}

impl RankOne<'_> {
    fn check(&self, size: usize) -> Result<()> {
        if self.vector.len() != size {
            return Err(Error::VectorLength {
                argument: "rank-one vector",
                expected: size,
                got: self.vector.len(),
            });
        }
        if !(self.weight.is_finite() && self.weight >= 0.0) {
            return Err(Error::InvalidOption {
                argument: "rank-one weight",
                value: self.weight,
                expected: "a finite number >= 0",
            });
        }
        crate::error::check_finite("rank-one vector", self.vector.as_chunks::<1>().0)
    }

    /// `y += c g (g^T x)`.
    fn add_product<const B: usize>(&self, x: &[[f64; B]], y: &mut [[f64; B]]) {
        let g = self.vector.as_chunks::<B>().0;
        let scale = self.weight * dot(g, x);
        y.iter_mut().zip(g).for_each(|(y, g)| {
            for a in 0..B {
                y[a] += scale * g[a];
            }
        });
    }
}

/// $A + c\,g g^\top$ as an operator over `inner` ($A$).
pub struct PlusRankOne<'a, O: ?Sized> {
    inner: &'a mut O,
    term: RankOne<'a>,
}

impl<'a, O: ?Sized> PlusRankOne<'a, O> {
    /// `inner` plus `term` (whose vector has `inner`'s size).
    pub fn new(inner: &'a mut O, term: RankOne<'a>) -> Self {
        Self { inner, term }
    }
}

impl<const B: usize, O: LinearOperator<B> + ?Sized> LinearOperator<B> for PlusRankOne<'_, O> {
    fn len(&self) -> usize {
        self.inner.len()
    }
    fn apply(&mut self, x: &[[f64; B]], y: &mut [[f64; B]]) {
        self.inner.apply(x, y);
        self.term.add_product(x, y);
    }
    fn apply_inner(&mut self, x: &[[f64; B]], y: &mut [[f64; B]]) {
        self.inner.apply_inner(x, y);
        self.term.add_product(x, y);
    }
    fn inexact_inner(&self) -> bool {
        self.inner.inexact_inner()
    }
}

/// $(M + c\,g g^\top)^{-1}$ by Sherman-Morrison over `inner` ($M^{-1}$).
pub struct ShermanMorrison<'a, P: ?Sized, const B: usize> {
    inner: &'a mut P,
    /// $M^{-1} g$.
    preconditioned: Vec<[f64; B]>,
    /// $c / (1 + c\,g^\top M^{-1} g)$.
    scale: f64,
    vector: &'a [f64],
}

impl<'a, const B: usize, P: Preconditioner<B> + ?Sized> ShermanMorrison<'a, P, B> {
    /// `inner` with `term` folded in (one application of `inner`).
    pub fn new(inner: &'a mut P, term: RankOne<'a>) -> Self {
        let g = term.vector.as_chunks::<B>().0;
        let mut preconditioned = vec![[0.0; B]; g.len()];
        let gmg = inner.apply_dot(g, &mut preconditioned);
        let denominator = 1.0 + term.weight * gmg;
        // M is positive definite, so g^T M^{-1} g >= 0 and the denominator >= 1; a
        // preconditioner that broke shows here as a non-positive or NaN denominator, and
        // then the term is left to the product alone (conjugate gradients still converge).
        let scale = if denominator.is_finite() && denominator >= 1.0 {
            term.weight / denominator
        } else {
            0.0
        };
        Self {
            inner,
            preconditioned,
            scale,
            vector: term.vector,
        }
    }
}

impl<const B: usize, P: Preconditioner<B> + ?Sized> Preconditioner<B>
    for ShermanMorrison<'_, P, B>
{
    fn apply(&mut self, r: &[[f64; B]], z: &mut [[f64; B]]) {
        self.inner.apply(r, z);
        let g = self.vector.as_chunks::<B>().0;
        let scale = self.scale * dot(g, z);
        z.iter_mut().zip(&self.preconditioned).for_each(|(z, v)| {
            for a in 0..B {
                z[a] -= scale * v[a];
            }
        });
    }
}

impl<const B: usize> Pcg<B> {
    /// [`Self::solve`] of $(A + c\,g g^\top)\,x = b$ for `matrix` $A$ and `term`
    /// $c\,g g^\top$, with `preconditioner` ($\approx A$) extended to the term by
    /// Sherman-Morrison.
    ///
    /// # Errors
    /// As [`Self::solve`]; [`Error::VectorLength`] / [`Error::InvalidOption`] /
    /// [`Error::NonFinite`] for a bad term.
    #[allow(clippy::too_many_arguments)] // `solve`'s arguments and the term
    pub fn solve_plus_rank_one<P: Preconditioner<B> + ?Sized>(
        &mut self,
        matrix: &BlockCsr<B>,
        preconditioner: &mut P,
        term: RankOne<'_>,
        rhs: &[f64],
        x: &mut [f64],
        tolerance: f64,
        max_iterations: usize,
    ) -> Result<PcgStatus> {
        term.check(matrix.size())?;
        let mut upper: Upper<B> = std::mem::take(&mut self.upper);
        upper.load(matrix);
        let len = matrix.len();
        let mut assembled = super::Assembled(&mut upper, Some(matrix), len);
        let result = self.solve_operator(
            &mut PlusRankOne::new(&mut assembled, term),
            &mut ShermanMorrison::new(preconditioner, term),
            rhs,
            x,
            tolerance,
            max_iterations,
        );
        self.upper = upper;
        result
    }

    /// [`Self::solve_operator`] of $(A + c\,g g^\top)\,x = b$ for `operator` $A$; see
    /// [`Self::solve_plus_rank_one`].
    ///
    /// # Errors
    /// As [`Self::solve_plus_rank_one`].
    #[allow(clippy::too_many_arguments)] // `solve_operator`'s arguments and the term
    pub fn solve_operator_plus_rank_one<
        O: LinearOperator<B> + ?Sized,
        P: Preconditioner<B> + ?Sized,
    >(
        &mut self,
        operator: &mut O,
        preconditioner: &mut P,
        term: RankOne<'_>,
        rhs: &[f64],
        x: &mut [f64],
        tolerance: f64,
        max_iterations: usize,
    ) -> Result<PcgStatus> {
        term.check(operator.len() * B)?;
        self.solve_operator(
            &mut PlusRankOne::new(operator, term),
            &mut ShermanMorrison::new(preconditioner, term),
            rhs,
            x,
            tolerance,
            max_iterations,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solve::BlockJacobi;

    /// `dense` (symmetric) as a matrix of 2x2 blocks.
    fn blocks(dense: &[Vec<f64>]) -> BlockCsr<2> {
        let (mut indptr, mut indices, mut data) = (vec![0usize], Vec::new(), Vec::new());
        for row in dense {
            for (j, &v) in row.iter().enumerate() {
                if v != 0.0 {
                    indices.push(j);
                    data.push(v);
                }
            }
            indptr.push(indices.len());
        }
        BlockCsr::<2>::from_csr_parts(dense.len(), &indptr, &indices, &data).unwrap()
    }

    fn solve(
        dense: &[Vec<f64>],
        g: &[f64],
        c: f64,
        b: &[f64],
        cap: usize,
    ) -> (Vec<f64>, PcgStatus) {
        let matrix = blocks(dense);
        let mut jacobi = BlockJacobi::new(&matrix).unwrap();
        let mut x = vec![0.0; b.len()];
        let term = RankOne {
            vector: g,
            weight: c,
        };
        let status = Pcg::new()
            .solve_plus_rank_one(&matrix, &mut jacobi, term, b, &mut x, 1e-12, cap)
            .unwrap();
        (x, status)
    }

    /// An SPD tridiagonal plus a dense rank-one term, against the dense product.
    #[test]
    fn a_rank_one_term_solves_as_the_dense_matrix() {
        let n = 40;
        let mut dense = vec![vec![0.0; n]; n];
        for i in 0..n {
            dense[i][i] = 2.5 + 0.01 * i as f64;
            if i + 1 < n {
                dense[i][i + 1] = -1.0;
                dense[i + 1][i] = -1.0;
            }
        }
        let g: Vec<f64> = (0..n).map(|i| ((i as f64) * 0.37).sin() + 0.2).collect();
        let c = 50.0;
        let b: Vec<f64> = (0..n).map(|i| 1.0 + (i % 3) as f64).collect();
        let (x, status) = solve(&dense, &g, c, &b, 500);
        assert!(status.converged, "{status:?}");
        let gx: f64 = g.iter().zip(&x).map(|(a, b)| a * b).sum();
        for i in 0..n {
            let ax: f64 = (0..n).map(|j| dense[i][j] * x[j]).sum::<f64>() + c * g[i] * gx;
            assert!((ax - b[i]).abs() < 1e-9, "row {i}: {ax} against {}", b[i]);
        }
    }

    /// The Sherman-Morrison preconditioner is the exact inverse of $M + c\,g g^\top$ for an
    /// exact $M$ (a block-diagonal matrix, which block Jacobi inverts): one iteration
    /// solves, where block Jacobi alone (the term in the product only) takes two.
    #[test]
    fn an_exact_preconditioner_with_the_term_solves_in_one_iteration() {
        let n = 12;
        let mut dense = vec![vec![0.0; n]; n];
        for i in 0..n {
            dense[i][i] = 1.0 + i as f64;
        }
        let g: Vec<f64> = (0..n).map(|i| 1.0 / (1.0 + i as f64)).collect();
        let (_, status) = solve(&dense, &g, 1e3, &vec![1.0; n], 10);
        assert!(status.converged, "{status:?}");
        assert_eq!(status.iterations, 1, "{status:?}");
    }

    #[test]
    fn a_bad_term_is_refused() {
        let matrix = blocks(&[vec![1.0, 0.0], vec![0.0, 1.0]]);
        let mut jacobi = BlockJacobi::new(&matrix).unwrap();
        let (b, mut x) = (vec![1.0; 2], vec![0.0; 2]);
        for (g, c) in [
            (vec![1.0], 1.0),
            (vec![1.0, f64::NAN], 1.0),
            (vec![1.0; 2], -1.0),
        ] {
            let term = RankOne {
                vector: &g,
                weight: c,
            };
            assert!(Pcg::new()
                .solve_plus_rank_one(&matrix, &mut jacobi, term, &b, &mut x, 1e-10, 10)
                .is_err());
        }
    }
}
