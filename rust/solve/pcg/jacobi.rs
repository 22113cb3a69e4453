//! The block-Jacobi preconditioner of [`super::Pcg`]: the inverses of the diagonal blocks.

use rayon::prelude::*;

use super::{dot, Preconditioner, PARALLEL_VECTOR_LEN};
use crate::error::{Error, Result};
use crate::linalg::{mat_vec, spd_inverse};
use crate::solve::block::{Block, BlockCsr, ROWS_PER_TASK};

/// The block-Jacobi preconditioner: the inverses of the $B \times B$ diagonal blocks.
#[derive(Debug, Clone)]
pub struct BlockJacobi<const B: usize> {
    inverse: Vec<[[f64; B]; B]>,
}

impl<const B: usize> BlockJacobi<B> {
    /// Inverts the diagonal blocks of `matrix`.
    ///
    /// # Errors
    /// [`Error::NotPositiveDefinite`] naming the first row whose diagonal block is not
    /// symmetric positive definite.
    pub fn new(matrix: &BlockCsr<B>) -> Result<Self> {
        let mut this = Self {
            inverse: vec![[[0.0; B]; B]; matrix.len()],
        };
        this.update(matrix)?;
        Ok(this)
    }

    /// Inverts the given diagonal blocks (of an operator that is not assembled).
    ///
    /// # Errors
    /// As [`Self::new`].
    pub fn from_diagonal(blocks: &[Block<B>]) -> Result<Self> {
        let mut inverse = vec![[[0.0; B]; B]; blocks.len()];
        for (i, (inv, block)) in inverse.iter_mut().zip(blocks).enumerate() {
            *inv = spd_inverse(block).map_err(|pivot| Error::NotPositiveDefinite {
                argument: "matrix",
                row: i * B + pivot,
                reason: "its diagonal block (inverted by the block-Jacobi preconditioner) has a non-positive pivot",
            })?;
        }
        Ok(Self { inverse })
    }

    /// Recomputes the inverses for new values of `matrix` (same number of nodes).
    ///
    /// # Errors
    /// As [`Self::new`]; [`Error::VectorLength`] for a matrix of another size.
    pub fn update(&mut self, matrix: &BlockCsr<B>) -> Result<()> {
        if matrix.len() != self.inverse.len() {
            return Err(Error::VectorLength {
                argument: "matrix",
                expected: self.inverse.len() * B,
                got: matrix.size(),
            });
        }
        let failed = self
            .inverse
            .par_iter_mut()
            .with_min_len(ROWS_PER_TASK)
            .enumerate()
            .map(|(i, inv)| {
                spd_inverse(matrix.diagonal_block(i))
                    .map(|m| *inv = m)
                    .map_err(|pivot| i * B + pivot)
            })
            .find_first(|r| r.is_err());
        match failed {
            Some(Err(row)) => Err(Error::NotPositiveDefinite {
                argument: "matrix",
                row,
                reason: "its diagonal block (inverted by the block-Jacobi preconditioner) has a non-positive pivot",
            }),
            _ => Ok(()),
        }
    }
}

impl<const B: usize> Preconditioner<B> for BlockJacobi<B> {
    fn apply_dot(&mut self, r: &[[f64; B]], z: &mut [[f64; B]]) -> f64 {
        if r.len() * B >= PARALLEL_VECTOR_LEN {
            self.apply(r, z);
            return dot(r, z);
        }
        let mut rz = 0.0;
        for (zi, (m, ri)) in z.iter_mut().zip(self.inverse.iter().zip(r)) {
            *zi = mat_vec(m, ri);
            for a in 0..B {
                rz += zi[a] * ri[a];
            }
        }
        rz
    }

    fn apply(&mut self, r: &[[f64; B]], z: &mut [[f64; B]]) {
        let one = |(zi, (m, ri)): (&mut [f64; B], (&Block<B>, &[f64; B]))| {
            *zi = mat_vec(m, ri);
        };
        if r.len() * B >= PARALLEL_VECTOR_LEN {
            z.par_iter_mut()
                .zip(self.inverse.par_iter().zip(r))
                .for_each(one);
        } else {
            z.iter_mut().zip(self.inverse.iter().zip(r)).for_each(one);
        }
    }
}
