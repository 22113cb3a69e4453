//! The element-free elastic body (SPEC 4): nodes, fixed neighbourhoods, MLS gradients,
//! nodal volumes and an isotropic material, with per-node rotation compensation (SPEC 4.4).
//!
//! Everything is written through the MLS deformation gradient of a neighbourhood,
//! $F_p(x) = \sum_{i \in N_p} x_i\, \nabla\Phi_i(x_p)^\top$ (and $G_p = F_p(X)$, the identity
//! up to rounding by linear reproduction). With $H_p$ the displacement gradient the mode
//! measures strain from,
//!
//! * `Linear`: $H_p = F_p - G_p$ (no compensation; rotations read as strain);
//! * `Rhs` (the paper's Eq. 12): $H_p = F_p - R_p G_p$, i.e. the neighbourhood's rest shape
//!   rotated by $R_p$ is the target, so $K$ stays fixed and only the right-hand side
//!   $f = \sum_p k_p R_p X_{N_p}$ changes;
//! * `Warped` (corotational): $H_p = R_p^\top F_p - G_p$, i.e. $k_p \to R_p k_p R_p^\top$;
//!
//! the energy is $\sum_p \tfrac12 V_p\, \sigma(\varepsilon_p) : \varepsilon_p$ with
//! $\varepsilon_p = \operatorname{sym} H_p$ and
//! $\sigma = \lambda \operatorname{tr}\varepsilon\, I + 2\mu\varepsilon$, and the force
//! on node $i$ is $-\sum_p V_p\, (R_p)\, \sigma_p\, \nabla\Phi_i(x_p)$ (with $R_p$ in the
//! warped mode), $R_p$ held fixed as in the paper.
//! A rigid motion $x = R X + t$ gives $R_p = R$ and zero strain in both compensated modes.
//!
//! $R_p$ is the rotation of the polar decomposition of
//! $A_p = \sum_i m_i (x_i - x_p)(X_i - X_p)^\top$, $m_i = \exp(-|X_i - X_p|^2 / (d_p/2)^2)$,
//! by the batched kernel of [`crate::polar`].

use std::sync::OnceLock;

use rayon::prelude::*;

use crate::efg::assembly::mul_vec;
use crate::efg::consistency::Consistency;
use crate::efg::{elasticity_matrix, Block, BlockPattern, Material, Occurrences};
use crate::error::{check_finite, Error, Result};
use crate::mls::shape_functions;
use crate::polar::{polar2, polar3};
use crate::SpatialHash;

/// How rotations are taken out of the strain (SPEC 4.4).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rotation {
    /// None: plain linear elasticity about the rest state.
    Linear,
    /// The paper's: rotated rest shapes on the right-hand side, $K$ fixed.
    Rhs,
    /// Corotational: $R_p k_p R_p^\top$, the system matrix changes with the rotations.
    Warped,
}

/// Which matrix's polar rotation is $R_p$ (SPEC 4.4 names the first).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RotationFit {
    /// $A_p = \sum_i m_i (x_i - x_p)(X_i - X_p)^\top$ with Gaussian weights (the paper's).
    Weighted,
    /// The MLS deformation gradient $F_p$: the rotation the strain measure itself sees.
    /// Measured: on a bar bent by 90 degrees the `Rhs` fixed-point iteration diverges with
    /// `Weighted` rotations and converges with these (benches/README.md).
    Gradient,
}

/// Support radius factor $c$ of SPEC 4.1: $d_p = c\, r_k$.
pub const SUPPORT_FACTOR: f64 = 1.1;

/// An element-free elastic model in `D` = 2 or 3 dimensions.
#[derive(Debug)]
pub struct ElasticModel<const D: usize> {
    rest: Vec<[f64; D]>,
    neighbors: Vec<u32>,
    k: usize,
    grad: Vec<[f64; D]>,
    support: Vec<f64>,
    volumes: Vec<f64>,
    lame: (f64, f64),
    rotation: Rotation,
    fit: RotationFit,
    /// $G_p$ per node.
    rest_gradient: Vec<Block<D>>,
    /// Rotation-fit weights $m_i$, row-major `(n, k)`.
    weights: Vec<f64>,
    occurrences: Occurrences,
    pattern: OnceLock<BlockPattern>,
    /// The penalty's $s_p L_p$ summed per block of the pattern (built on first use).
    penalty_blocks: OnceLock<Vec<f64>>,
    /// The stabilising consistency penalty and its strength $\epsilon$ (none at 0).
    consistency: Option<Consistency<D>>,
    stabilization: f64,
}

impl<const D: usize> ElasticModel<D> {
    /// Builds the model of nodes `rest` (their rest positions) with `k` neighbours each (the
    /// node itself and its `k - 1` nearest), MLS shape functions with supports
    /// [`SUPPORT_FACTOR`] times the farthest neighbour's distance, and the given nodal
    /// volumes.
    ///
    /// # Errors
    /// [`Error::Empty`] / [`Error::NonFinite`] / [`Error::TooManyPoints`] for bad nodes,
    /// [`Error::InvalidK`] unless `D + 1 <= k <= n`, [`Error::LengthMismatch`] /
    /// [`Error::InvalidVolume`] for bad volumes, [`Error::InvalidMaterial`], and
    /// [`Error::IllConditioned`] for neighbourhoods that do not span the space.
    pub fn new(
        rest: Vec<[f64; D]>,
        k: usize,
        volumes: Vec<f64>,
        material: &Material,
        rotation: Rotation,
        fit: RotationFit,
    ) -> Result<Self> {
        const { assert!(D == 2 || D == 3, "elastic models are 2-D or 3-D") };
        let c = elasticity_matrix::<D>(material)?;
        let s = D * (D + 1) / 2;
        let lame = (c[1], c[D * s + D]);
        let n = rest.len();
        if k < D + 1 || k > n {
            return Err(Error::InvalidK {
                k,
                max: n,
                note: "; k counts the node itself and needs at least D + 1 for a linear basis",
            });
        }
        if volumes.len() != n {
            return Err(Error::LengthMismatch {
                argument: "volumes",
                expected: n,
                got: volumes.len(),
            });
        }
        if let Some(node) = volumes.iter().position(|v| !(v.is_finite() && *v > 0.0)) {
            return Err(Error::InvalidVolume {
                node,
                value: volumes[node],
            });
        }
        let hash = SpatialHash::new(&rest)?;
        let knn = hash.knn(None, k - 1)?;
        let mut neighbors = Vec::with_capacity(n * k);
        let mut reach = Vec::with_capacity(n);
        for p in 0..n {
            neighbors.push(p as u32);
            let row = &knn.indices[p * (k - 1)..(p + 1) * (k - 1)];
            neighbors.extend(row.iter().map(|&i| i as u32));
            reach.push(SUPPORT_FACTOR * knn.distances[(p + 1) * (k - 1) - 1]);
        }
        let shapes = match D {
            2 => cast_shapes(shape_functions::<2, 3>(
                cast_rows(&rest),
                &neighbors,
                k,
                &reach,
            )?),
            _ => cast_shapes(shape_functions::<3, 4>(
                cast_rows(&rest),
                &neighbors,
                k,
                &reach,
            )?),
        };
        let (grad, support) = shapes;
        let rest_gradient = (0..n)
            .into_par_iter()
            .map(|p| {
                let hood = &neighbors[p * k..(p + 1) * k];
                outer_sum(hood, &grad[p * k..(p + 1) * k], |i| rest[i])
            })
            .collect();
        let weights = (0..n)
            .into_par_iter()
            .flat_map_iter(|p| {
                let scale = 4.0 / (support[p] * support[p]);
                let (rest, centre) = (&rest, rest[p]);
                neighbors[p * k..(p + 1) * k]
                    .iter()
                    .map(move |&i| (-scale * distance2(&rest[i as usize], &centre)).exp())
            })
            .collect();
        let occurrences = Occurrences::new(&neighbors, k, n);
        Ok(Self {
            rest,
            neighbors,
            k,
            grad,
            support,
            volumes,
            lame,
            rotation,
            fit,
            rest_gradient,
            weights,
            occurrences,
            pattern: OnceLock::new(),
            penalty_blocks: OnceLock::new(),
            consistency: None,
            stabilization: 0.0,
        })
    }

    /// Adds the consistency penalty of [`crate::efg::consistency`] with strength `epsilon`
    /// (relative to the shear modulus; 0 removes it). It is part of the energy, forces and
    /// system matrix of every rotation mode and zero for every affine motion.
    ///
    /// # Errors
    /// [`Error::InvalidOption`] for a negative or non-finite `epsilon`.
    pub fn with_stabilization(mut self, epsilon: f64) -> Result<Self> {
        if !(epsilon.is_finite() && epsilon >= 0.0) {
            return Err(Error::InvalidOption {
                argument: "stabilization",
                value: epsilon,
                expected: "a finite number >= 0",
            });
        }
        self.stabilization = epsilon;
        self.penalty_blocks = OnceLock::new();
        self.consistency = (epsilon > 0.0).then(|| {
            Consistency::new(
                &self.rest,
                &self.neighbors,
                self.k,
                &self.volumes,
                self.lame.1,
                epsilon,
            )
        });
        Ok(self)
    }

    /// The consistency penalty's strength $\epsilon$ (0: none).
    pub fn stabilization(&self) -> f64 {
        self.stabilization
    }

    /// Number of nodes.
    pub fn len(&self) -> usize {
        self.rest.len()
    }

    /// Always false: a model has nodes.
    pub fn is_empty(&self) -> bool {
        self.rest.is_empty()
    }

    /// Neighbours per node.
    pub fn k(&self) -> usize {
        self.k
    }

    /// Rest positions, `(n,)` rows.
    pub fn rest(&self) -> &[[f64; D]] {
        &self.rest
    }

    /// Neighbour lists, row-major `(n, k)`, each row starting with its node.
    pub fn neighbors(&self) -> &[u32] {
        &self.neighbors
    }

    /// MLS gradients at the nodes, row-major `(n, k)` in the order of [`Self::neighbors`].
    pub fn grad(&self) -> &[[f64; D]] {
        &self.grad
    }

    /// Support radii $d_p$.
    pub fn support(&self) -> &[f64] {
        &self.support
    }

    /// Nodal volumes $V_p$.
    pub fn volumes(&self) -> &[f64] {
        &self.volumes
    }

    /// The rotation mode.
    pub fn rotation(&self) -> Rotation {
        self.rotation
    }

    /// Lamé parameters $(\lambda, \mu)$ (plane stress: the reduced $\lambda$).
    pub fn lame(&self) -> (f64, f64) {
        self.lame
    }

    /// The block pattern of the stiffness (built on first use, then kept).
    pub fn pattern(&self) -> &BlockPattern {
        self.pattern
            .get_or_init(|| BlockPattern::new(&self.neighbors, self.k, self.len()))
    }

    /// The penalty's scalar per block of [`Self::pattern`] (constant: it is quadratic in
    /// the positions and needs no rotation), computed once.
    fn penalty_blocks(&self) -> Option<&[f64]> {
        let penalty = self.consistency.as_ref()?;
        let k = self.k;
        Some(self.penalty_blocks.get_or_init(|| {
            self.pattern().gather_scalars(|p, a, b| {
                penalty.coefficient(p, a, b, &self.grad[p * k..(p + 1) * k])
            })
        }))
    }

    /// Fails unless `x` holds one finite position per node.
    pub fn check_positions(&self, x: &[[f64; D]]) -> Result<()> {
        if x.len() != self.len() {
            return Err(Error::LengthMismatch {
                argument: "positions",
                expected: self.len(),
                got: x.len(),
            });
        }
        check_finite("positions", x)
    }

    /// $R_p$ for every node at positions `x` (SPEC 4.4, from the matrix [`RotationFit`]
    /// names); identities in the `Linear` mode.
    ///
    /// # Errors
    /// As [`Self::check_positions`].
    pub fn rotations(&self, x: &[[f64; D]]) -> Result<Vec<Block<D>>> {
        self.check_positions(x)?;
        let identity = std::array::from_fn(|a| std::array::from_fn(|b| f64::from(a == b)));
        if self.rotation == Rotation::Linear {
            return Ok(vec![identity; self.len()]);
        }
        let k = self.k;
        let covariances: Vec<f64> = (0..self.len())
            .into_par_iter()
            .flat_map_iter(|p| {
                if self.fit == RotationFit::Gradient {
                    return self.deformation_gradient(p, x).into_iter().flatten();
                }
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

    fn check_rotations(&self, rotations: &[Block<D>]) -> Result<()> {
        if rotations.len() != self.len() {
            return Err(Error::LengthMismatch {
                argument: "rotations",
                expected: self.len(),
                got: rotations.len(),
            });
        }
        match rotations
            .par_iter()
            .position_first(|r| !r.iter().flatten().all(|v| v.is_finite()))
        {
            Some(row) => Err(Error::NonFinite {
                argument: "rotations",
                row,
            }),
            None => Ok(()),
        }
    }

    /// $F_p$ of the field `x` over node `p`'s neighbourhood.
    fn deformation_gradient(&self, p: usize, x: &[[f64; D]]) -> Block<D> {
        let k = self.k;
        outer_sum(
            &self.neighbors[p * k..(p + 1) * k],
            &self.grad[p * k..(p + 1) * k],
            |i| x[i],
        )
    }

    /// $H_p$ of the mode at positions `x`.
    fn displacement_gradient(&self, p: usize, x: &[[f64; D]], r: &Block<D>) -> Block<D> {
        let f = self.deformation_gradient(p, x);
        let g = &self.rest_gradient[p];
        match self.rotation {
            Rotation::Linear => sub(&f, g),
            Rotation::Rhs => sub(&f, &matmul(r, g)),
            Rotation::Warped => sub(&matmul(&transpose(r), &f), g),
        }
    }

    /// $\sigma(\operatorname{sym} H)$.
    fn stress(&self, h: &Block<D>) -> Block<D> {
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
    fn gather(
        &self,
        stresses: &[Block<D>],
        rotations: Option<&[Block<D>]>,
        slots: Option<&[[f64; D]]>,
    ) -> Vec<[f64; D]> {
        let mut out = vec![[0.0; D]; self.len()];
        self.gather_into(stresses, rotations, slots, &mut out);
        out
    }

    fn gather_into(
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
                let mut t = mul_vec(&stresses[p], &self.grad[p * k + a]);
                if let Some(r) = rotations {
                    t = mul_vec(&r[p], &t);
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
    fn penalty_slots_into(&self, x: &[[f64; D]], slots: &mut Vec<[f64; D]>) -> bool {
        let Some(penalty) = &self.consistency else {
            return false;
        };
        let k = self.k;
        slots.resize(self.len() * k, [0.0; D]);
        slots.par_chunks_mut(k).enumerate().for_each(|(p, out)| {
            let hood = &self.neighbors[p * k..(p + 1) * k];
            let f = self.deformation_gradient(p, x);
            penalty.slot_gradients(p, hood, &f, x, &self.grad[p * k..(p + 1) * k], out);
        });
        true
    }

    fn penalty_slots(&self, x: &[[f64; D]]) -> Option<Vec<[f64; D]>> {
        let mut slots = Vec::new();
        self.penalty_slots_into(x, &mut slots).then_some(slots)
    }

    fn warped_rotations<'r>(&self, rotations: &'r [Block<D>]) -> Option<&'r [Block<D>]> {
        (self.rotation == Rotation::Warped).then_some(rotations)
    }

    /// Elastic energy at positions `x` with the given rotations (SPEC 4.4).
    ///
    /// # Errors
    /// As [`Self::check_positions`]; wrong-length or non-finite rotations.
    pub fn energy(&self, x: &[[f64; D]], rotations: &[Block<D>]) -> Result<f64> {
        self.check_positions(x)?;
        self.check_rotations(rotations)?;
        Ok((0..self.len())
            .into_par_iter()
            .map(|p| {
                let h = self.displacement_gradient(p, x, &rotations[p]);
                let sigma = self.stress(&h);
                let work: f64 = (0..D)
                    .flat_map(|a| (0..D).map(move |b| (a, b)))
                    .map(|(a, b)| sigma[a][b] * 0.5 * (h[a][b] + h[b][a]))
                    .sum();
                let penalty = self.consistency.as_ref().map_or(0.0, |c| {
                    let hood = &self.neighbors[p * self.k..(p + 1) * self.k];
                    c.energy(p, hood, &self.deformation_gradient(p, x), x)
                });
                0.5 * self.volumes[p] * work + penalty
            })
            .sum())
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
                    Rotation::Rhs => self.stress(&matmul(&rotations[p], g)),
                    Rotation::Linear | Rotation::Warped => self.stress(g),
                }
            })
            .collect();
        // The penalty vanishes on affine fields, the rest state among them: no term here.
        Ok(self.gather(&stresses, self.warped_rotations(rotations), None))
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
            .map(|p| {
                let f = self.deformation_gradient(p, u);
                let h = match warped {
                    Some(r) => matmul(&transpose(&r[p]), &f),
                    None => f,
                };
                self.stress(&h)
            })
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
        stresses.par_iter_mut().enumerate().for_each(|(p, sigma)| {
            let f = self.deformation_gradient(p, u);
            let h = match warped {
                Some(r) => matmul(&transpose(&r[p]), &f),
                None => f,
            };
            *sigma = self.stress(&h);
        });
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
                        Some(r) => mul_vec(&r[p], &self.grad[p * k + a]),
                        None => self.grad[p * k + a],
                    };
                    let v = self.volumes[p];
                    let dot: f64 = g.iter().map(|x| x * x).sum();
                    let penalty = self.consistency.as_ref().map_or(0.0, |c| {
                        c.coefficient(p, a, a, &self.grad[p * k..(p + 1) * k])
                    });
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
}

/// $\sum_i v(i)\, g_i^\top$ over a neighbourhood.
fn outer_sum<const D: usize>(
    hood: &[u32],
    grad: &[[f64; D]],
    value: impl Fn(usize) -> [f64; D],
) -> Block<D> {
    let mut m = [[0.0; D]; D];
    for (&i, g) in hood.iter().zip(grad) {
        let v = value(i as usize);
        for a in 0..D {
            for b in 0..D {
                m[a][b] += v[a] * g[b];
            }
        }
    }
    m
}

fn matmul<const D: usize>(a: &Block<D>, b: &Block<D>) -> Block<D> {
    std::array::from_fn(|r| std::array::from_fn(|c| (0..D).map(|t| a[r][t] * b[t][c]).sum()))
}

fn transpose<const D: usize>(a: &Block<D>) -> Block<D> {
    std::array::from_fn(|r| std::array::from_fn(|c| a[c][r]))
}

fn sub<const D: usize>(a: &Block<D>, b: &Block<D>) -> Block<D> {
    std::array::from_fn(|r| std::array::from_fn(|c| a[r][c] - b[r][c]))
}

fn distance2<const D: usize>(a: &[f64; D], b: &[f64; D]) -> f64 {
    (0..D).map(|c| (a[c] - b[c]).powi(2)).sum()
}

/// `&[[f64; D]]` as `&[[f64; E]]` when `D == E` (a no-op the const dispatch needs).
fn cast_rows<const D: usize, const E: usize>(rows: &[[f64; D]]) -> &[[f64; E]] {
    assert_eq!(D, E, "dimension dispatch");
    rows.as_flattened().as_chunks::<E>().0
}

fn cast_shapes<const E: usize, const D: usize>(
    shapes: crate::mls::ShapeFunctions<E>,
) -> (Vec<[f64; D]>, Vec<f64>) {
    assert_eq!(D, E, "dimension dispatch");
    let grad = shapes.grad.as_flattened().as_chunks::<D>().0.to_vec();
    (grad, shapes.support)
}

#[cfg(test)]
mod tests;
