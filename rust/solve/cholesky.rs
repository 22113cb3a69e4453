//! Sparse Cholesky $A = L L^\top$ by faer (AMD fill-reducing ordering; supernodal or
//! simplicial as faer's flop-ratio rule picks), with the symbolic analysis done once per
//! pattern and reused by every numeric factorisation of a matrix with that pattern.

use std::sync::Arc;

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::LltError;
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, LltRef, SymbolicCholesky,
    SymmetricOrdering,
};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};

use super::block::{BlockCsr, Pattern};
use super::pcg::Preconditioner;
use crate::error::{check_finite, Error, Result};

/// A sparse Cholesky factorisation bound to one block pattern.
pub struct SparseCholesky<const B: usize> {
    pattern: Arc<Pattern>,
    /// Lower triangle of $A$ in compressed sparse columns (scalar): since $A$ is symmetric,
    /// column $j$ is row $j$ of the block CSR from the diagonal on.
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    values: Vec<f64>,
    symbolic: SymbolicCholesky<usize>,
    factor: Vec<f64>,
    factorized: bool,
    factorize_scratch: MemBuffer,
    solve_scratch: MemBuffer,
    par: Par,
}

fn generic(error: faer::sparse::FaerError) -> Error {
    Error::Factorization {
        reason: format!("{error:?}"),
    }
}

impl<const B: usize> SparseCholesky<B> {
    /// The symbolic analysis of `matrix`'s pattern (its values are not read): AMD
    /// ordering, elimination tree, column counts and supernodes.
    ///
    /// # Errors
    /// [`Error::Factorization`] if faer cannot allocate or index the factor.
    pub fn analyse(matrix: &BlockCsr<B>) -> Result<Self> {
        let n = matrix.len();
        let (indptr, indices) = (matrix.indptr(), matrix.indices());
        let mut col_ptr = Vec::with_capacity(n * B + 1);
        col_ptr.push(0);
        let mut row_idx = Vec::new();
        for i in 0..n {
            let upper = &indices[indptr[i]..indptr[i + 1]];
            let upper = &upper[upper.partition_point(|&j| (j as usize) < i)..];
            for a in 0..B {
                for &j in upper {
                    let first = if j as usize == i { a } else { 0 };
                    row_idx.extend((first..B).map(|b| j as usize * B + b));
                }
                col_ptr.push(row_idx.len());
            }
        }
        let size = n * B;
        let symbolic = factorize_symbolic_cholesky(
            SymbolicSparseColMatRef::new_checked(size, size, &col_ptr, None, &row_idx),
            Side::Lower,
            SymmetricOrdering::Amd,
            CholeskySymbolicParams::default(),
        )
        .map_err(generic)?;
        let par = Par::rayon(0);
        let factorize_scratch = MemBuffer::try_new(
            symbolic.factorize_numeric_llt_scratch::<f64>(par, Default::default()),
        )
        .map_err(|_| generic(faer::sparse::FaerError::OutOfMemory))?;
        let solve_scratch = MemBuffer::try_new(symbolic.solve_in_place_scratch::<f64>(1, par))
            .map_err(|_| generic(faer::sparse::FaerError::OutOfMemory))?;
        Ok(Self {
            pattern: Arc::clone(matrix.pattern()),
            values: vec![0.0; row_idx.len()],
            factor: vec![0.0; symbolic.len_val()],
            col_ptr,
            row_idx,
            symbolic,
            factorized: false,
            factorize_scratch,
            solve_scratch,
            par,
        })
    }

    /// Number of scalar rows.
    pub fn size(&self) -> usize {
        self.col_ptr.len() - 1
    }

    /// Stored entries of the factor $L$.
    pub fn factor_len(&self) -> usize {
        self.factor.len()
    }

    /// True when the analysis chose faer's supernodal factorisation.
    pub fn is_supernodal(&self) -> bool {
        matches!(
            self.symbolic.raw(),
            faer::sparse::linalg::cholesky::SymbolicCholeskyRaw::Supernodal(_)
        )
    }

    /// The numeric factorisation of `matrix`, which must have the analysed pattern; only
    /// its lower triangle is read.
    ///
    /// # Errors
    /// [`Error::PatternMismatch`]; [`Error::NotPositiveDefinite`] naming the row of the
    /// first non-positive pivot (the factor is then unusable until the next success);
    /// [`Error::Factorization`].
    pub fn factorize(&mut self, matrix: &BlockCsr<B>) -> Result<()> {
        if !(Arc::ptr_eq(&self.pattern, matrix.pattern()) || *self.pattern == **matrix.pattern()) {
            return Err(Error::PatternMismatch {
                argument: "matrix",
                expected: "the Cholesky factorisation was analysed for",
            });
        }
        self.factorized = false;
        let (indptr, indices, blocks) = (matrix.indptr(), matrix.indices(), matrix.blocks());
        let mut out = 0;
        for i in 0..matrix.len() {
            let row = indptr[i]..indptr[i + 1];
            let first = row.start + indices[row.clone()].partition_point(|&j| (j as usize) < i);
            for a in 0..B {
                for (at, block) in blocks.iter().enumerate().take(row.end).skip(first) {
                    let start = if indices[at] as usize == i { a } else { 0 };
                    let values = &block[a][start..];
                    self.values[out..out + values.len()].copy_from_slice(values);
                    out += values.len();
                }
            }
        }
        let size = self.size();
        let a = SparseColMatRef::new(
            SymbolicSparseColMatRef::new_checked(size, size, &self.col_ptr, None, &self.row_idx),
            &self.values,
        );
        let result = self.symbolic.factorize_numeric_llt::<f64>(
            &mut self.factor,
            a,
            Side::Lower,
            LltRegularization::default(),
            self.par,
            MemStack::new(&mut self.factorize_scratch),
            Default::default(),
        );
        match result {
            Ok(_) => {
                self.factorized = true;
                Ok(())
            }
            Err(LltError::NonPositivePivot { index }) => {
                // faer's simplicial path reports the pivot one-based, the supernodal
                // (dense kernels) zero-based; both in the permuted order.
                let pivot = if self.is_supernodal() {
                    index
                } else {
                    index.saturating_sub(1)
                };
                let pivot = pivot.min(size - 1);
                Err(Error::NotPositiveDefinite {
                    argument: "matrix",
                    row: self.symbolic.perm().map_or(pivot, |p| p.arrays().0[pivot]),
                    reason: "the Cholesky factorisation met a non-positive pivot",
                })
            }
        }
    }

    /// Overwrites `x` (the right-hand side on entry) with $A^{-1} x$.
    fn solve_unchecked(&mut self, x: &mut [f64]) {
        let size = x.len();
        LltRef::new(&self.symbolic, &self.factor).solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(x, size, 1),
            self.par,
            MemStack::new(&mut self.solve_scratch),
        );
    }

    /// $x = A^{-1} b$ with the last factorisation.
    ///
    /// # Errors
    /// [`Error::VectorLength`], [`Error::NonFinite`]; [`Error::NotFactorized`] when no
    /// factorisation has succeeded since the analysis or the last failure.
    pub fn solve_into(&mut self, rhs: &[f64], x: &mut [f64]) -> Result<()> {
        for (argument, len) in [("rhs", rhs.len()), ("x", x.len())] {
            if len != self.size() {
                return Err(Error::VectorLength {
                    argument,
                    expected: self.size(),
                    got: len,
                });
            }
        }
        if !self.factorized {
            return Err(Error::NotFactorized);
        }
        check_finite("rhs", rhs.as_chunks::<B>().0)?;
        x.copy_from_slice(rhs);
        self.solve_unchecked(x);
        Ok(())
    }
}

/// The factor of a nearby matrix as the preconditioner of CG: factor once per frame,
/// iterate while the values drift. Applying it before any successful factorisation
/// is the identity.
impl<const B: usize> Preconditioner<B> for SparseCholesky<B> {
    fn apply(&mut self, r: &[[f64; B]], z: &mut [[f64; B]]) {
        z.copy_from_slice(r);
        if self.factorized {
            self.solve_unchecked(z.as_flattened_mut());
        }
    }
}
