//! The per-node rotations $R_p$ (SPEC 4.4): the polar rotation of the weighted covariance
//! $A_p$ or of the deformation gradient $F_p$, batched through [`crate::polar`].

use rayon::prelude::*;

use super::{ElasticModel, Rotation, RotationFit};
use crate::efg::Block;
use crate::error::Result;
use crate::linalg::identity;
use crate::polar::{polar2, polar3};

impl<const D: usize> ElasticModel<D> {
    /// $R_p$ for every node at positions `x` (SPEC 4.4, from the matrix [`RotationFit`]
    /// names); identities in the `Linear` mode.
    ///
    /// # Errors
    /// As [`Self::check_positions`].
    pub fn rotations(&self, x: &[[f64; D]]) -> Result<Vec<Block<D>>> {
        self.check_positions(x)?;
        if self.rotation == Rotation::Linear {
            return Ok(vec![identity(); self.len()]);
        }
        let covariances: Vec<f64> = (0..self.len())
            .into_par_iter()
            .flat_map_iter(|p| {
                let a = match self.fit {
                    RotationFit::Gradient => self.deformation_gradient(p, x),
                    RotationFit::Weighted => self.weighted_covariance(p, x),
                };
                a.into_iter().flatten()
            })
            .collect();
        let mut flat = vec![0.0; covariances.len()];
        match D {
            2 => polar2(
                covariances.as_chunks::<4>().0,
                flat.as_chunks_mut::<4>().0,
                None,
            )?,
            _ => polar3(
                covariances.as_chunks::<9>().0,
                flat.as_chunks_mut::<9>().0,
                None,
            )?,
        }
        Ok(flat
            .as_chunks::<D>()
            .0
            .chunks_exact(D)
            .map(|rows| std::array::from_fn(|a| rows[a]))
            .collect())
    }

    /// $A_p = \sum_i m_i (x_i - x_p)(X_i - X_p)^\top$ (the paper's rotation fit).
    fn weighted_covariance(&self, p: usize, x: &[[f64; D]]) -> Block<D> {
        let k = self.k;
        let hood = &self.neighbors[p * k..(p + 1) * k];
        let mut a = [[0.0; D]; D];
        for (&i, &m) in hood.iter().zip(&self.weights[p * k..(p + 1) * k]) {
            let i = i as usize;
            for (r, row) in a.iter_mut().enumerate() {
                let b = m * (x[i][r] - x[p][r]);
                for (c, value) in row.iter_mut().enumerate() {
                    *value += b * (self.rest[i][c] - self.rest[p][c]);
                }
            }
        }
        a
    }
}
