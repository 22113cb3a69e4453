//! The model's data and its build (SPEC 4.1-4.3): nodes, fixed neighbourhoods of the `k`
//! nearest, MLS gradients and supports, rest gradients $G_p$ and rotation-fit weights.

use std::sync::OnceLock;

use rayon::prelude::*;

use super::{Rotation, RotationFit, SUPPORT_FACTOR};
use crate::efg::consistency::Consistency;
use crate::efg::{elasticity_matrix, Block, BlockPattern, Material, Occurrences};
use crate::error::{check_finite, Error, Result};
use crate::linalg::distance2;
use crate::mls::shape_functions;
use crate::SpatialHash;

/// An element-free elastic model in `D` = 2 or 3 dimensions.
#[derive(Debug)]
pub struct ElasticModel<const D: usize> {
    pub(super) rest: Vec<[f64; D]>,
    pub(super) neighbors: Vec<u32>,
    pub(super) k: usize,
    pub(super) grad: Vec<[f64; D]>,
    pub(super) support: Vec<f64>,
    pub(super) volumes: Vec<f64>,
    pub(super) lame: (f64, f64),
    pub(super) rotation: Rotation,
    pub(super) fit: RotationFit,
    /// $G_p$ per node.
    pub(super) rest_gradient: Vec<Block<D>>,
    /// Rotation-fit weights $m_i$, row-major `(n, k)`.
    pub(super) weights: Vec<f64>,
    pub(super) occurrences: Occurrences,
    pattern: OnceLock<BlockPattern>,
    /// The penalty's $s_p L_p$ summed per block of the pattern (built on first use).
    penalty_blocks: OnceLock<Vec<f64>>,
    /// The stabilising consistency penalty and its strength $\epsilon$ (none at 0).
    pub(super) consistency: Option<Consistency<D>>,
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
    pub(super) fn penalty_blocks(&self) -> Option<&[f64]> {
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

    /// Fails unless `rotations` holds one finite matrix per node.
    pub(super) fn check_rotations(&self, rotations: &[Block<D>]) -> Result<()> {
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

    /// The node's neighbourhood and its MLS gradients (`k` rows each).
    #[inline]
    pub(super) fn hood(&self, p: usize) -> (&[u32], &[[f64; D]]) {
        let range = p * self.k..(p + 1) * self.k;
        (&self.neighbors[range.clone()], &self.grad[range])
    }

    /// $F_p$ of the field `x` over node `p`'s neighbourhood.
    #[inline]
    pub(super) fn deformation_gradient(&self, p: usize, x: &[[f64; D]]) -> Block<D> {
        let (hood, grad) = self.hood(p);
        outer_sum(hood, grad, |i| x[i])
    }
}

/// $\sum_i v(i)\, g_i^\top$ over a neighbourhood: the MLS gradient of the field `v`.
#[inline]
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
