//! Linear elasticity of an element-free Galerkin model by direct nodal integration
//! (SPEC 4.3; Belytschko, Lu & Gu 1994; Beissel & Belytschko 1996).
//!
//! At node $p$ with neighbours $N_p$ (the node included), MLS gradients $\nabla\Phi_i(x_p)$
//! and nodal volume $V_p$:
//!
//! * strain (Voigt, engineering shear) $\varepsilon_p = B_p u_{N_p}$, with the block of
//!   neighbour $i$ built from $\nabla\Phi_i$: 3-D rows $[xx, yy, zz, xy, yz, zx]$ =
//!   $(\partial_x,0,0), (0,\partial_y,0), (0,0,\partial_z), (\partial_y,\partial_x,0),
//!   (0,\partial_z,\partial_y), (\partial_z,0,\partial_x)$; 2-D rows $[xx, yy, xy]$;
//! * local stiffness $k_p = V_p B_p^\top C B_p$ and $K = \sum_p k_p$ scattered;
//! * energy $\tfrac12 \sum_p V_p \varepsilon_p^\top C \varepsilon_p = \tfrac12 u^\top K u$
//!   and forces $-K u = -\sum_p B_p^\top V_p C \varepsilon_p$, both matrix-free.
//!
//! Nodal integration evaluates the strain only at the nodes, so $K$ may have zero-energy
//! modes beyond the rigid motions; `tests/test_efg.py` measures them. This module is the
//! plain nodal integration; the elastic model adds the stabilising penalty of
//! [`consistency`].

use rayon::prelude::*;

use crate::error::{check_finite, Error, Result};
use crate::ordered::{sum_chunks, CHUNK};

pub mod assembly;
pub mod consistency;
pub use assembly::{Block, BlockPattern, Occurrences};

/// 2-D idealisation of a 3-D body.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Plane {
    /// Plane strain: $\varepsilon_{zz} = 0$ (a thick body).
    Strain,
    /// Plane stress: $\sigma_{zz} = 0$ (a thin plate).
    Stress,
}

/// An isotropic linear-elastic material.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Material {
    /// Young's modulus $E > 0$.
    pub youngs: f64,
    /// Poisson's ratio $0 \le \nu < 1/2$.
    pub poisson: f64,
    /// 2-D idealisation (ignored in 3-D).
    pub plane: Plane,
}

/// A square sparse matrix in compressed sparse row form, columns sorted within each row.
#[derive(Debug, Clone, PartialEq)]
pub struct Csr {
    /// Number of rows and columns.
    pub size: usize,
    /// `(size + 1,)`: row `r` holds entries `indptr[r]..indptr[r + 1]`.
    pub indptr: Vec<usize>,
    /// Column of each entry.
    pub indices: Vec<usize>,
    /// Value of each entry.
    pub data: Vec<f64>,
}

/// Number of Voigt strain components in `D` dimensions: 3 in 2-D, 6 in 3-D.
pub const fn voigt_size(d: usize) -> usize {
    d * (d + 1) / 2
}

/// Per Voigt row, the `(displacement axis, derivative axis)` pairs whose products sum to it.
fn voigt_pairs(d: usize) -> &'static [&'static [(usize, usize)]] {
    if d == 2 {
        &[&[(0, 0)], &[(1, 1)], &[(0, 1), (1, 0)]]
    } else {
        &[
            &[(0, 0)],
            &[(1, 1)],
            &[(2, 2)],
            &[(0, 1), (1, 0)],
            &[(1, 2), (2, 1)],
            &[(0, 2), (2, 0)],
        ]
    }
}

/// The elasticity matrix $C$ (row-major, $S \times S$ with $S$ = [`voigt_size`]) for
/// engineering shear strains: 3-D and plane strain
/// $\frac{E}{(1+\nu)(1-2\nu)}$ times $1-\nu$ on the normal diagonal, $\nu$ off it and
/// $1/2-\nu$ on the shear diagonal; plane stress $\frac{E}{1-\nu^2}$ times $1$, $\nu$ and
/// $(1-\nu)/2$.
///
/// # Errors
/// [`Error::InvalidMaterial`] unless $E$ is positive and finite and $0 \le \nu < 1/2$.
pub fn elasticity_matrix<const D: usize>(material: &Material) -> Result<Vec<f64>> {
    let Material {
        youngs,
        poisson,
        plane,
    } = *material;
    if !(youngs.is_finite() && youngs > 0.0) {
        return Err(Error::InvalidMaterial {
            argument: "youngs",
            value: youngs,
            expected: "a positive finite number",
        });
    }
    if !(0.0..0.5).contains(&poisson) {
        return Err(Error::InvalidMaterial {
            argument: "poisson",
            value: poisson,
            expected: "in [0, 0.5)",
        });
    }
    let s = voigt_size(D);
    let (scale, diagonal, off, shear) = if D == 2 && plane == Plane::Stress {
        (
            youngs / (1.0 - poisson * poisson),
            1.0,
            poisson,
            0.5 * (1.0 - poisson),
        )
    } else {
        (
            youngs / ((1.0 + poisson) * (1.0 - 2.0 * poisson)),
            1.0 - poisson,
            poisson,
            0.5 - poisson,
        )
    };
    let mut c = vec![0.0; s * s];
    for i in 0..D {
        for j in 0..D {
            c[i * s + j] = scale * if i == j { diagonal } else { off };
        }
    }
    for i in D..s {
        c[i * s + i] = scale * shear;
    }
    Ok(c)
}

/// A validated nodal-integration model: neighbour lists, MLS gradients, volumes and $C$.
#[derive(Debug, Clone)]
pub struct NodalElasticity<'a, const D: usize> {
    neighbors: &'a [u32],
    k: usize,
    grad: &'a [[f64; D]],
    volumes: &'a [f64],
    c: Vec<f64>,
}

impl<'a, const D: usize> NodalElasticity<'a, D> {
    /// Checks the inputs: `neighbors` and `grad` row-major `(n, k)` (each row holding its
    /// node; `grad` from [`crate::mls`]), `volumes` `(n,)`.
    ///
    /// # Errors
    /// [`Error::Empty`], [`Error::TooManyPoints`]; [`Error::NotEnoughNeighbours`] for
    /// `k < D + 1`; [`Error::LengthMismatch`] when `neighbors` or `grad` do not have `n` rows;
    /// [`Error::NonFinite`] for `grad`; [`Error::InvalidVolume`]; [`Error::NeighborIndex`] /
    /// [`Error::SelfNotNeighbour`]; [`Error::InvalidMaterial`].
    pub fn new(
        neighbors: &'a [u32],
        k: usize,
        grad: &'a [[f64; D]],
        volumes: &'a [f64],
        material: &Material,
    ) -> Result<Self> {
        const {
            assert!(
                D == 2 || D == 3,
                "nodal elasticity is implemented in 2-D and 3-D"
            )
        };
        let c = elasticity_matrix::<D>(material)?;
        let n = volumes.len();
        if n == 0 {
            return Err(Error::Empty {
                argument: "volumes",
                needed: 1,
            });
        }
        if n > u32::MAX as usize {
            return Err(Error::TooManyPoints {
                argument: "volumes",
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
        for (argument, len) in [("neighbors", neighbors.len()), ("grad", grad.len())] {
            if len != n * k {
                return Err(Error::LengthMismatch {
                    argument,
                    expected: n,
                    got: len / k,
                });
            }
        }
        check_finite("grad", grad)?;
        if let Some(node) = volumes
            .par_iter()
            .position_first(|v| !(v.is_finite() && *v > 0.0))
        {
            return Err(Error::InvalidVolume {
                node,
                value: volumes[node],
            });
        }
        let bad_row = neighbors.par_chunks(k).enumerate().find_first(|(p, row)| {
            row.iter().any(|&i| i as usize >= n) || !row.contains(&(*p as u32))
        });
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
        Ok(Self {
            neighbors,
            k,
            grad,
            volumes,
            c,
        })
    }

    /// Number of nodes.
    pub fn len(&self) -> usize {
        self.volumes.len()
    }

    /// Always false: a model has at least one node.
    pub fn is_empty(&self) -> bool {
        self.volumes.is_empty()
    }

    /// The elasticity matrix $C$, row-major $S \times S$.
    pub fn elasticity(&self) -> &[f64] {
        &self.c
    }

    /// $B_p$, row-major $S \times Dk$, columns ordered neighbour-major then axis.
    pub fn strain_displacement(&self, p: usize) -> Vec<f64> {
        let (s, cols) = (voigt_size(D), D * self.k);
        let mut b = vec![0.0; s * cols];
        for (i, g) in self.grad[p * self.k..(p + 1) * self.k].iter().enumerate() {
            for (row, pairs) in voigt_pairs(D).iter().enumerate() {
                for &(axis, derivative) in *pairs {
                    b[row * cols + i * D + axis] += g[derivative];
                }
            }
        }
        b
    }

    /// $k_p = V_p B_p^\top C B_p$, row-major $Dk \times Dk$.
    pub fn local_stiffness(&self, p: usize) -> Vec<f64> {
        let (s, cols) = (voigt_size(D), D * self.k);
        let b = self.strain_displacement(p);
        let mut cb = vec![0.0; s * cols];
        for r in 0..s {
            for t in 0..s {
                let c = self.c[r * s + t] * self.volumes[p];
                if c != 0.0 {
                    for j in 0..cols {
                        cb[r * cols + j] += c * b[t * cols + j];
                    }
                }
            }
        }
        let mut local = vec![0.0; cols * cols];
        for r in 0..s {
            for i in 0..cols {
                let bi = b[r * cols + i];
                if bi != 0.0 {
                    for j in 0..cols {
                        local[i * cols + j] += bi * cb[r * cols + j];
                    }
                }
            }
        }
        local
    }

    /// Lamé parameters $(\lambda, \mu)$ of $C$ (plane stress: the reduced $\lambda$).
    pub fn lame(&self) -> (f64, f64) {
        let s = voigt_size(D);
        (self.c[1], self.c[D * s + D])
    }

    /// The global stiffness $K$ ($nD \times nD$, dof `node * D + axis`) as CSR, columns
    /// sorted: the block pattern and closed-form blocks of [`assembly`], expanded.
    pub fn stiffness(&self) -> Csr {
        let pattern = BlockPattern::new(self.neighbors, self.k, self.len());
        let mut blocks = vec![[[0.0; D]; D]; pattern.nnz()];
        pattern.assemble(
            self.grad,
            self.volumes,
            self.lame(),
            None,
            None,
            &mut blocks,
        );
        let (indptr, indices, data) = pattern.to_scalar_csr(&blocks);
        Csr {
            size: D * self.len(),
            indptr,
            indices,
            data,
        }
    }

    fn check_displacements(&self, u: &[[f64; D]]) -> Result<()> {
        if u.len() != self.len() {
            return Err(Error::LengthMismatch {
                argument: "displacements",
                expected: self.len(),
                got: u.len(),
            });
        }
        check_finite("displacements", u)
    }

    fn strain_at(&self, p: usize, u: &[[f64; D]]) -> [f64; 6] {
        let mut eps = [0.0; 6];
        let row = &self.neighbors[p * self.k..(p + 1) * self.k];
        for (&i, g) in row.iter().zip(&self.grad[p * self.k..(p + 1) * self.k]) {
            let ui = u[i as usize];
            for (r, pairs) in voigt_pairs(D).iter().enumerate() {
                for &(axis, derivative) in *pairs {
                    eps[r] += g[derivative] * ui[axis];
                }
            }
        }
        eps
    }

    fn stress(&self, eps: &[f64; 6]) -> [f64; 6] {
        let s = voigt_size(D);
        let mut sigma = [0.0; 6];
        for (r, value) in sigma.iter_mut().enumerate().take(s) {
            *value = (0..s).map(|t| self.c[r * s + t] * eps[t]).sum();
        }
        sigma
    }

    /// Strains $\varepsilon_p = B_p u_{N_p}$ at every node, row-major `(n, S)`.
    ///
    /// # Errors
    /// [`Error::LengthMismatch`] / [`Error::NonFinite`] for bad displacements.
    pub fn strains(&self, u: &[[f64; D]]) -> Result<Vec<f64>> {
        self.check_displacements(u)?;
        let s = voigt_size(D);
        Ok((0..self.len())
            .into_par_iter()
            .flat_map_iter(|p| self.strain_at(p, u).into_iter().take(s))
            .collect())
    }

    /// Elastic energy $\tfrac12 \sum_p V_p \varepsilon_p^\top C \varepsilon_p$, matrix-free.
    ///
    /// # Errors
    /// As [`Self::strains`].
    pub fn energy(&self, u: &[[f64; D]]) -> Result<f64> {
        self.check_displacements(u)?;
        let s = voigt_size(D);
        // Summed in fixed chunks (crate::ordered): the same bits on any thread count.
        Ok(sum_chunks(self.len(), CHUNK, |range| {
            range
                .map(|p| {
                    let eps = self.strain_at(p, u);
                    let sigma = self.stress(&eps);
                    0.5 * self.volumes[p] * (0..s).map(|r| eps[r] * sigma[r]).sum::<f64>()
                })
                .sum()
        }))
    }

    /// Nodal forces $-K u = -\sum_p B_p^\top V_p C \varepsilon_p$, matrix-free.
    ///
    /// # Errors
    /// As [`Self::strains`].
    pub fn forces(&self, u: &[[f64; D]]) -> Result<Vec<[f64; D]>> {
        self.check_displacements(u)?;
        let local: Vec<[f64; D]> = (0..self.len())
            .into_par_iter()
            .flat_map_iter(|p| {
                let sigma = self.stress(&self.strain_at(p, u));
                let volume = self.volumes[p];
                self.grad[p * self.k..(p + 1) * self.k]
                    .iter()
                    .map(move |g| {
                        let mut f = [0.0; D];
                        for (r, pairs) in voigt_pairs(D).iter().enumerate() {
                            for &(axis, derivative) in *pairs {
                                f[axis] -= volume * g[derivative] * sigma[r];
                            }
                        }
                        f
                    })
            })
            .collect();
        let mut forces = vec![[0.0; D]; self.len()];
        for (&i, f) in self.neighbors.iter().zip(&local) {
            for a in 0..D {
                forces[i as usize][a] += f[a];
            }
        }
        Ok(forces)
    }
}

#[cfg(test)]
mod tests;
