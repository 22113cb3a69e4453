//! The system matrix $S$ of the mode ($K$, or the warped $K_R$): its matrix-free product,
//! its diagonal blocks (for block Jacobi) and its blocks on the stiffness pattern.

use rayon::prelude::*;

use super::ElasticModel;
use crate::efg::Block;
use crate::error::{Error, Result};
use crate::linalg::{dot, mat_mul, mat_vec, transpose};

impl<const D: usize> ElasticModel<D> {
    /// The stress of the product's field `u` at node `p`: $\sigma(F_p(u))$, or
    /// $\sigma(R_p^\top F_p(u))$ with warped rotations.
    #[inline]
    fn product_stress(&self, p: usize, u: &[[f64; D]], warped: Option<&[Block<D>]>) -> Block<D> {
        let f = self.deformation_gradient(p, u);
        let h = match warped {
            Some(r) => mat_mul(&transpose(&r[p]), &f),
            None => f,
        };
        self.stress(&h)
    }

    /// $S u$, matrix-free: `Linear` and `Rhs` multiply by $K$, `Warped` by $K_R$.
    ///
    /// # Errors
    /// As [`Self::energy`] (for `u` in place of positions).
    pub fn apply(&self, rotations: &[Block<D>], u: &[[f64; D]]) -> Result<Vec<[f64; D]>> {
        self.check_positions(u)?;
        self.check_rotations(rotations)?;
        let warped = self.warped_rotations(rotations);
        let stresses: Vec<Block<D>> = (0..self.len())
            .into_par_iter()
            .map(|p| self.product_stress(p, u, warped))
            .collect();
        let slots = self.penalty_slots(u);
        Ok(self.gather(&stresses, warped, slots.as_deref()))
    }

    /// $S u$ into `out` with caller-kept scratch, for the inner loop of an iterative
    /// solver: no checks (the caller checked the rotations once; `u` comes from the solver).
    pub fn apply_into(
        &self,
        rotations: &[Block<D>],
        u: &[[f64; D]],
        stresses: &mut Vec<Block<D>>,
        slots: &mut Vec<[f64; D]>,
        out: &mut [[f64; D]],
    ) {
        let warped = self.warped_rotations(rotations);
        stresses.resize(self.len(), [[0.0; D]; D]);
        stresses
            .par_iter_mut()
            .enumerate()
            .for_each(|(p, sigma)| *sigma = self.product_stress(p, u, warped));
        let penalty = self.penalty_slots_into(u, slots);
        self.gather_into(stresses, warped, penalty.then_some(slots.as_slice()), out);
    }

    /// The diagonal blocks of $S$ (one per node), for a block-Jacobi preconditioner of the
    /// matrix-free product.
    ///
    /// # Errors
    /// Wrong-length or non-finite rotations.
    pub fn diagonal_blocks(&self, rotations: &[Block<D>]) -> Result<Vec<Block<D>>> {
        self.check_rotations(rotations)?;
        let (lambda, mu) = self.lame;
        let warped = self.warped_rotations(rotations);
        let k = self.k;
        Ok((0..self.len())
            .into_par_iter()
            .map(|i| {
                let mut block = [[0.0; D]; D];
                for &(p, a) in self.occurrences.of(i) {
                    let (p, a) = (p as usize, a as usize);
                    let g = match warped {
                        Some(r) => mat_vec(&r[p], &self.grad[p * k + a]),
                        None => self.grad[p * k + a],
                    };
                    let v = self.volumes[p];
                    let dot = dot(&g, &g);
                    let penalty = self
                        .consistency
                        .as_ref()
                        .map_or(0.0, |c| c.coefficient(p, a, a, self.hood(p).1));
                    for r in 0..D {
                        for c in 0..D {
                            block[r][c] += v * (lambda + mu) * g[r] * g[c];
                        }
                        block[r][r] += v * mu * dot + penalty;
                    }
                }
                block
            })
            .collect())
    }

    /// The blocks of the system matrix $S$ on [`Self::pattern`]: $K$, or $K_R$ in the warped
    /// mode.
    ///
    /// # Errors
    /// Wrong-length or non-finite rotations; [`Error::OutputSize`] for a wrong `blocks`.
    pub fn system_blocks(&self, rotations: &[Block<D>], blocks: &mut [Block<D>]) -> Result<()> {
        self.check_rotations(rotations)?;
        let pattern = self.pattern();
        if blocks.len() != pattern.nnz() {
            return Err(Error::OutputSize {
                expected: pattern.nnz(),
                got: blocks.len(),
            });
        }
        pattern.assemble(
            &self.grad,
            &self.volumes,
            self.lame,
            self.warped_rotations(rotations),
            self.penalty_blocks(),
            blocks,
        );
        Ok(())
    }

    /// The system matrix $S$ as scalar CSR `(indptr, indices, data)` of shape `(n D, n D)`,
    /// dof `node * D + axis`, columns sorted.
    ///
    /// # Errors
    /// Wrong-length or non-finite rotations.
    pub fn system_csr(&self, rotations: &[Block<D>]) -> Result<(Vec<usize>, Vec<usize>, Vec<f64>)> {
        let pattern = self.pattern();
        let mut blocks = vec![[[0.0; D]; D]; pattern.nnz()];
        self.system_blocks(rotations, &mut blocks)?;
        Ok(pattern.to_scalar_csr(&blocks))
    }
}
