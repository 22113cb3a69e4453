//! Strain, stress and what follows from them (SPEC 4.4): the energy, the forces and the
//! right-hand side $f$ of the mode's linear system, all through the gather of nodal
//! stresses onto the nodes.

use rayon::prelude::*;

use super::{ElasticModel, Rotation};
use crate::efg::Block;
use crate::error::Result;
use crate::linalg::{mat_mul, mat_sub, mat_vec, transpose};
use crate::ordered::{sum_chunks, CHUNK};

impl<const D: usize> ElasticModel<D> {
    /// $H_p$ of the mode at positions `x`.
    fn displacement_gradient(&self, p: usize, x: &[[f64; D]], r: &Block<D>) -> Block<D> {
        let f = self.deformation_gradient(p, x);
        let g = &self.rest_gradient[p];
        match self.rotation {
            Rotation::Linear => mat_sub(&f, g),
            Rotation::Rhs => mat_sub(&f, &mat_mul(r, g)),
            Rotation::Warped => mat_sub(&mat_mul(&transpose(r), &f), g),
        }
    }

    /// $\sigma(\operatorname{sym} H)$.
    #[inline]
    pub(super) fn stress(&self, h: &Block<D>) -> Block<D> {
        let (lambda, mu) = self.lame;
        let trace: f64 = (0..D).map(|a| h[a][a]).sum();
        std::array::from_fn(|a| {
            std::array::from_fn(|b| {
                mu * (h[a][b] + h[b][a]) + if a == b { lambda * trace } else { 0.0 }
            })
        })
    }

    /// Per node $i$: $\sum_p V_p\, Q_p\, \sigma_p \nabla\Phi_i(x_p)$, with $Q_p = R_p$ when
    /// `rotations` are given, else $I$: the gather of the nodal stresses onto the nodes.
    /// Plus, with `slots` (row-major `(n, k)`, from [`Self::penalty_slots_into`]), each
    /// occurrence's slot vector: the consistency penalty's gradient.
    pub(super) fn gather(
        &self,
        stresses: &[Block<D>],
        rotations: Option<&[Block<D>]>,
        slots: Option<&[[f64; D]]>,
    ) -> Vec<[f64; D]> {
        let mut out = vec![[0.0; D]; self.len()];
        self.gather_into(stresses, rotations, slots, &mut out);
        out
    }

    pub(super) fn gather_into(
        &self,
        stresses: &[Block<D>],
        rotations: Option<&[Block<D>]>,
        slots: Option<&[[f64; D]]>,
        out: &mut [[f64; D]],
    ) {
        let k = self.k;
        out.par_iter_mut().enumerate().for_each(|(i, f)| {
            *f = [0.0; D];
            for &(p, a) in self.occurrences.of(i) {
                let (p, a) = (p as usize, a as usize);
                let mut t = mat_vec(&stresses[p], &self.grad[p * k + a]);
                if let Some(r) = rotations {
                    t = mat_vec(&r[p], &t);
                }
                for c in 0..D {
                    f[c] += self.volumes[p] * t[c];
                }
                if let Some(s) = slots {
                    for c in 0..D {
                        f[c] += s[p * k + a][c];
                    }
                }
            }
        });
    }

    /// The consistency penalty's per-slot gradients at `x` into `slots` (resized to
    /// `(n, k)`); false (and `slots` untouched) without a penalty.
    pub(super) fn penalty_slots_into(&self, x: &[[f64; D]], slots: &mut Vec<[f64; D]>) -> bool {
        let Some(penalty) = &self.consistency else {
            return false;
        };
        let k = self.k;
        slots.resize(self.len() * k, [0.0; D]);
        slots.par_chunks_mut(k).enumerate().for_each(|(p, out)| {
            let (hood, grad) = self.hood(p);
            let f = self.deformation_gradient(p, x);
            penalty.slot_gradients(p, hood, &f, x, grad, out);
        });
        true
    }

    pub(super) fn penalty_slots(&self, x: &[[f64; D]]) -> Option<Vec<[f64; D]>> {
        let mut slots = Vec::new();
        self.penalty_slots_into(x, &mut slots).then_some(slots)
    }

    /// The rotations the system matrix depends on: those of the warped mode, else none.
    pub(super) fn warped_rotations<'r>(&self, rotations: &'r [Block<D>]) -> Option<&'r [Block<D>]> {
        (self.rotation == Rotation::Warped).then_some(rotations)
    }

    /// Elastic energy at positions `x` with the given rotations (SPEC 4.4).
    ///
    /// # Errors
    /// As [`Self::check_positions`]; wrong-length or non-finite rotations.
    pub fn energy(&self, x: &[[f64; D]], rotations: &[Block<D>]) -> Result<f64> {
        self.check_positions(x)?;
        self.check_rotations(rotations)?;
        // Summed in fixed chunks (crate::ordered): the fit's stopping test reads this energy,
        // so its rounding must not depend on the thread count.
        Ok(sum_chunks(self.len(), CHUNK, |range| {
            range
                .map(|p| {
                    let h = self.displacement_gradient(p, x, &rotations[p]);
                    let sigma = self.stress(&h);
                    let work: f64 = (0..D)
                        .flat_map(|a| (0..D).map(move |b| (a, b)))
                        .map(|(a, b)| sigma[a][b] * 0.5 * (h[a][b] + h[b][a]))
                        .sum();
                    let penalty = self.consistency.as_ref().map_or(0.0, |c| {
                        c.energy(p, self.hood(p).0, &self.deformation_gradient(p, x), x)
                    });
                    0.5 * self.volumes[p] * work + penalty
                })
                .sum()
        }))
    }

    /// Elastic forces $-\partial E / \partial x$ at positions `x`, rotations held fixed.
    ///
    /// # Errors
    /// As [`Self::energy`].
    pub fn forces(&self, x: &[[f64; D]], rotations: &[Block<D>]) -> Result<Vec<[f64; D]>> {
        self.check_positions(x)?;
        self.check_rotations(rotations)?;
        let stresses: Vec<Block<D>> = (0..self.len())
            .into_par_iter()
            .map(|p| self.stress(&self.displacement_gradient(p, x, &rotations[p])))
            .collect();
        let slots = self.penalty_slots(x);
        let mut f = self.gather(
            &stresses,
            self.warped_rotations(rotations),
            slots.as_deref(),
        );
        f.par_iter_mut().flatten().for_each(|v| *v = -*v);
        Ok(f)
    }

    /// The right-hand side $f$ of the mode's linear system $S x = f$ with these rotations
    /// ($S = K$, or the warped $K_R$): the positions minimising the elastic energy for fixed
    /// rotations solve it. Forces are $f - S x$.
    ///
    /// # Errors
    /// Wrong-length or non-finite rotations.
    pub fn rhs(&self, rotations: &[Block<D>]) -> Result<Vec<[f64; D]>> {
        self.check_rotations(rotations)?;
        let stresses: Vec<Block<D>> = (0..self.len())
            .into_par_iter()
            .map(|p| {
                let g = &self.rest_gradient[p];
                match self.rotation {
                    Rotation::Rhs => self.stress(&mat_mul(&rotations[p], g)),
                    Rotation::Linear | Rotation::Warped => self.stress(g),
                }
            })
            .collect();
        // The penalty vanishes on affine fields, the rest state among them: no term here.
        Ok(self.gather(&stresses, self.warped_rotations(rotations), None))
    }
}
