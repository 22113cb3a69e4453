//! Solves straight from scalar CSR arrays (scipy's, columns sorted within rows, any index
//! type read in place): the factorisation, and conjugate gradients with the preconditioner
//! chosen by what the caller holds.

use super::block::{BlockCsr, CsrIndex};
use super::cholesky::SparseCholesky;
use super::coarse::{TwoLevel, STRENGTH};
use super::pcg::{Pcg, PcgStatus};
use crate::error::Result;

/// A scalar CSR matrix of `size` rows as borrowed arrays.
#[derive(Debug, Clone, Copy)]
pub struct CsrParts<'a, I> {
    /// Rows (and columns).
    pub size: usize,
    /// Row starts, `size + 1` entries.
    pub indptr: &'a [I],
    /// Column of each entry, sorted within rows.
    pub indices: &'a [I],
    /// Value of each entry.
    pub data: &'a [f64],
}

impl<I: CsrIndex> CsrParts<'_, I> {
    /// The matrix in `B x B` blocks.
    ///
    /// # Errors
    /// As [`BlockCsr::from_csr_parts`].
    pub fn blocks<const B: usize>(&self) -> Result<BlockCsr<B>> {
        BlockCsr::from_csr_parts(self.size, self.indptr, self.indices, self.data)
    }
}

/// The preconditioner of [`conjugate_gradient_csr`].
pub enum CsrPreconditioner<'a, const B: usize> {
    /// Block Jacobi, with the matrix read straight into the upper triangle the products use.
    BlockJacobi,
    /// The factorisation of a nearby matrix (same size and block).
    Factor(&'a mut SparseCholesky<B>),
    /// Block Jacobi plus the rigid modes of aggregates of these node positions
    /// ([`TwoLevel`] with [`STRENGTH`]), one row per block row.
    TwoLevel(&'a [[f64; B]]),
}

/// Conjugate gradients on `matrix` from `x` (overwritten with the solution) to the relative
/// residual `tolerance` or `max_iterations`, whichever comes first: the status says which.
///
/// # Errors
/// As [`BlockCsr::from_csr_parts`] for the matrix, [`Pcg::solve`] for the vectors and
/// [`crate::Error::NotPositiveDefinite`] when a diagonal block or a search direction
/// shows the matrix is not positive definite.
pub fn conjugate_gradient_csr<I: CsrIndex, const B: usize>(
    matrix: &CsrParts<'_, I>,
    rhs: &[f64],
    x: &mut [f64],
    tolerance: f64,
    max_iterations: usize,
    preconditioner: CsrPreconditioner<'_, B>,
) -> Result<PcgStatus> {
    let mut pcg = Pcg::<B>::new();
    match preconditioner {
        CsrPreconditioner::Factor(factor) => {
            let blocks = matrix.blocks::<B>()?;
            pcg.solve(&blocks, factor, rhs, x, tolerance, max_iterations)
        }
        CsrPreconditioner::TwoLevel(nodes) => {
            let blocks = matrix.blocks::<B>()?;
            let mut two_level = TwoLevel::new(&blocks, nodes, STRENGTH)?;
            pcg.solve(&blocks, &mut two_level, rhs, x, tolerance, max_iterations)
        }
        // Block Jacobi needs only the upper triangle: read it straight from the arrays.
        CsrPreconditioner::BlockJacobi => pcg.solve_csr_parts(
            matrix.size,
            matrix.indptr,
            matrix.indices,
            matrix.data,
            rhs,
            x,
            tolerance,
            max_iterations,
        ),
    }
}

impl<const B: usize> SparseCholesky<B> {
    /// Analyses and factorises `matrix`.
    ///
    /// # Errors
    /// As [`CsrParts::blocks`], [`Self::analyse`] and [`Self::factorize`].
    pub fn from_csr_parts<I: CsrIndex>(matrix: &CsrParts<'_, I>) -> Result<Self> {
        let blocks = matrix.blocks::<B>()?;
        let mut factor = Self::analyse(&blocks)?;
        factor.factorize(&blocks)?;
        Ok(factor)
    }

    /// Factorises new values with the analysed pattern.
    ///
    /// # Errors
    /// As [`CsrParts::blocks`] and [`Self::factorize`].
    pub fn factorize_csr_parts<I: CsrIndex>(&mut self, matrix: &CsrParts<'_, I>) -> Result<()> {
        self.factorize(&matrix.blocks::<B>()?)
    }

    /// $A^{-1} b$ with the last factorisation, in a new vector.
    ///
    /// # Errors
    /// As [`Self::solve_into`].
    pub fn solve(&mut self, rhs: &[f64]) -> Result<Vec<f64>> {
        let mut x = vec![0.0; rhs.len()];
        self.solve_into(rhs, &mut x)?;
        Ok(x)
    }
}
