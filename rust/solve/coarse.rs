//! A two-level preconditioner: block Jacobi plus a coarse correction on the rigid motions
//! of node aggregates (unsmoothed aggregation, Vaněk, Mandel & Brezina 1996, with the
//! rigid body modes as the near null space), applied additively:
//! $$ M^{-1} = D^{-1} + Z E^{-1} Z^\top, \qquad E = Z^\top A Z. $$
//!
//! Why: once the stabilised stiffness has no soft oscillating modes left, the slowest
//! modes of the fitting system are smooth, near-rigid motions of body parts that only the
//! surface term anchors (weakly, when the fit is stiff). Block Jacobi sees each node alone
//! and needs many iterations to move a limb as a whole; the coarse space moves it in one.
//! Measured in benches/README.md against block Jacobi alone.
//!
//! * Aggregates: greedy on the matrix graph (a node with no aggregated strong neighbour
//!   starts one with its strong neighbours; the rest join the aggregate they connect to
//!   most strongly), strength $\|A_{ij}\|_F > \theta \sqrt{\|A_{ii}\|_F \|A_{jj}\|_F}$.
//! * $Z$: per aggregate, the $B(B+1)/2$ rigid motions about its centroid (translations and
//!   rotations, the offsets scaled to unit size). Rank-deficient aggregates (one node, or
//!   collinear ones) give zero pivots in $E$; those coarse unknowns are dropped.
//! * $E$ is dense (a few hundred unknowns at the paper's size), factored by Cholesky.

use rayon::prelude::*;

use super::block::{Block, BlockCsr, ROWS_PER_TASK};
use super::pcg::{BlockJacobi, Preconditioner};
use crate::error::{check_finite, Error, Result};

/// Rigid modes per aggregate: $B (B + 1) / 2$ (3 in 2-D, 6 in 3-D); arrays hold 6.
const MAX_MODES: usize = 6;

/// Rows of $Z$ for one node: $B \times$ modes (columns past the mode count are zero).
type Basis<const B: usize> = [[f64; MAX_MODES]; B];

/// Default strength threshold $\theta$ (benches/README.md: iterations barely depend on it
/// between 0.02 and 0.1, the coarse size does).
pub const STRENGTH: f64 = 0.02;

/// Block Jacobi plus the rigid-mode coarse correction.
#[derive(Debug, Clone)]
pub struct TwoLevel<const B: usize> {
    jacobi: BlockJacobi<B>,
    aggregate: Vec<u32>,
    aggregates: usize,
    basis: Vec<Basis<B>>,
    /// The pattern of $A Z$: per block row, its aggregates (`az_indptr`, `az_aggregate`),
    /// and for every block of $A$ the entry of $A Z$ it adds to.
    az_indptr: Vec<usize>,
    az_aggregate: Vec<u32>,
    az_slot: Vec<u32>,
    az: Vec<Basis<B>>,
    /// Lower Cholesky factor of $E$, row-major `(nc, nc)`; dropped unknowns have a zero
    /// column and a unit diagonal.
    factor: Vec<f64>,
    dropped: Vec<bool>,
    coarse: Vec<f64>,
}

const fn modes(b: usize) -> usize {
    b * (b + 1) / 2
}

impl<const B: usize> TwoLevel<B> {
    /// Aggregates the nodes of `matrix` (strength threshold `strength`, e.g. [`STRENGTH`]),
    /// builds the rigid modes at `positions` (one row per node) and factors the coarse
    /// matrix.
    ///
    /// # Errors
    /// [`Error::VectorLength`] / [`Error::NonFinite`] for `positions`,
    /// [`Error::InvalidOption`] for a strength outside `[0, 1)`, and as
    /// [`BlockJacobi::new`] for a matrix whose diagonal blocks are not positive definite.
    pub fn new(matrix: &BlockCsr<B>, positions: &[[f64; B]], strength: f64) -> Result<Self> {
        if !(strength.is_finite() && (0.0..1.0).contains(&strength)) {
            return Err(Error::InvalidOption {
                argument: "strength",
                value: strength,
                expected: "a number in [0, 1)",
            });
        }
        let (aggregate, aggregates) = aggregate(matrix, strength);
        let (az_indptr, az_aggregate, az_slot) = az_pattern(matrix, &aggregate);
        let mut this = Self {
            jacobi: BlockJacobi::new(matrix)?,
            aggregate,
            aggregates,
            basis: Vec::new(),
            az: vec![[[0.0; MAX_MODES]; B]; az_aggregate.len()],
            az_indptr,
            az_aggregate,
            az_slot,
            factor: Vec::new(),
            dropped: Vec::new(),
            coarse: Vec::new(),
        };
        this.set_positions(positions)?;
        this.factor(matrix)?;
        Ok(this)
    }

    /// Number of aggregates.
    pub fn aggregates(&self) -> usize {
        self.aggregates
    }

    /// Coarse unknowns kept (rigid modes of the aggregates less the dropped ones).
    pub fn coarse_size(&self) -> usize {
        self.dropped.iter().filter(|d| !**d).count()
    }

    /// Rebuilds the rigid modes about new node positions (the aggregates stay); call
    /// [`Self::update`] afterwards.
    ///
    /// # Errors
    /// [`Error::VectorLength`] / [`Error::NonFinite`] for `positions`.
    pub fn set_positions(&mut self, positions: &[[f64; B]]) -> Result<()> {
        let n = self.aggregate.len();
        if positions.len() != n {
            return Err(Error::VectorLength {
                argument: "nodes",
                expected: n * B,
                got: positions.len() * B,
            });
        }
        check_finite("nodes", positions)?;
        let mut centre = vec![[0.0; B]; self.aggregates];
        let mut count = vec![0usize; self.aggregates];
        for (x, &a) in positions.iter().zip(&self.aggregate) {
            count[a as usize] += 1;
            for c in 0..B {
                centre[a as usize][c] += x[c];
            }
        }
        for (m, &k) in centre.iter_mut().zip(&count) {
            m.iter_mut().for_each(|v| *v /= k as f64);
        }
        let mut size = vec![0.0f64; self.aggregates];
        for (x, &a) in positions.iter().zip(&self.aggregate) {
            let d: f64 = (0..B).map(|c| (x[c] - centre[a as usize][c]).powi(2)).sum();
            size[a as usize] = size[a as usize].max(d.sqrt());
        }
        self.basis = positions
            .iter()
            .zip(&self.aggregate)
            .map(|(x, &a)| {
                let a = a as usize;
                let scale = if size[a] > 0.0 { 1.0 / size[a] } else { 0.0 };
                let d: [f64; B] = std::array::from_fn(|c| (x[c] - centre[a][c]) * scale);
                rigid_rows(&d)
            })
            .collect();
        Ok(())
    }

    /// Refactors for new values of `matrix` (same pattern and size).
    ///
    /// # Errors
    /// As [`BlockJacobi::update`]; [`Error::VectorLength`] for a matrix of another size or
    /// number of blocks.
    pub fn update(&mut self, matrix: &BlockCsr<B>) -> Result<()> {
        if matrix.blocks().len() != self.az_slot.len() {
            return Err(Error::VectorLength {
                argument: "matrix",
                expected: self.az_slot.len(),
                got: matrix.blocks().len(),
            });
        }
        self.jacobi.update(matrix)?;
        self.factor(matrix)
    }

    /// Refreshes only the block-Jacobi part for new values of `matrix`, keeping the coarse
    /// factor of an earlier matrix: still a symmetric positive definite preconditioner, and
    /// the coarse modes change little between the iterations of one frame.
    ///
    /// # Errors
    /// As [`BlockJacobi::update`].
    pub fn update_smoother(&mut self, matrix: &BlockCsr<B>) -> Result<()> {
        self.jacobi.update(matrix)
    }

    /// $E = Z^\top A Z$ and its Cholesky factor.
    fn factor(&mut self, matrix: &BlockCsr<B>) -> Result<()> {
        let m = modes(B);
        let nc = self.aggregates * m;
        let (indptr, indices, blocks) = (matrix.indptr(), matrix.indices(), matrix.blocks());
        // A Z by block rows into the fixed pattern: row i of A Z at aggregate a is
        // sum over the blocks (i, j), j in a, of A_ij Z_j.
        let mut rows = Vec::with_capacity(n_rows(&self.az_indptr));
        let mut rest = self.az.as_mut_slice();
        for w in self.az_indptr.windows(2) {
            let (row, tail) = rest.split_at_mut(w[1] - w[0]);
            rows.push(row);
            rest = tail;
        }
        let (basis, slot, az_indptr) = (&self.basis, &self.az_slot, &self.az_indptr);
        rows.into_par_iter()
            .with_min_len(ROWS_PER_TASK)
            .enumerate()
            .for_each(|(i, row)| {
                row.fill([[0.0; MAX_MODES]; B]);
                for at in indptr[i]..indptr[i + 1] {
                    let (block, z) = (&blocks[at], &basis[indices[at] as usize]);
                    let out = &mut row[slot[at] as usize - az_indptr[i]];
                    for r in 0..B {
                        for t in 0..B {
                            let v = block[r][t];
                            for c in 0..m {
                                out[r][c] += v * z[t][c];
                            }
                        }
                    }
                }
            });
        let mut e = vec![0.0; nc * nc];
        for i in 0..matrix.len() {
            let (zi, ai) = (&self.basis[i], self.aggregate[i] as usize);
            for at in self.az_indptr[i]..self.az_indptr[i + 1] {
                let (aj, block) = (self.az_aggregate[at] as usize, &self.az[at]);
                for r in 0..m {
                    let row = &mut e[(ai * m + r) * nc + aj * m..(ai * m + r) * nc + aj * m + m];
                    for (c, value) in row.iter_mut().enumerate() {
                        *value += (0..B).map(|t| zi[t][r] * block[t][c]).sum::<f64>();
                    }
                }
            }
        }
        self.dropped = cholesky_dropping(&mut e, nc);
        self.factor = e;
        self.coarse = vec![0.0; nc];
        Ok(())
    }
}

fn n_rows(indptr: &[usize]) -> usize {
    indptr.len() - 1
}

/// The pattern of $A Z$: `(indptr, aggregate of each entry, entry of each block of A)`.
fn az_pattern<const B: usize>(
    matrix: &BlockCsr<B>,
    aggregate: &[u32],
) -> (Vec<usize>, Vec<u32>, Vec<u32>) {
    let (indptr, indices) = (matrix.indptr(), matrix.indices());
    let mut az_indptr = Vec::with_capacity(matrix.len() + 1);
    az_indptr.push(0);
    let mut az_aggregate: Vec<u32> = Vec::new();
    let mut slot = vec![0u32; indices.len()];
    for i in 0..matrix.len() {
        let start = az_aggregate.len();
        for at in indptr[i]..indptr[i + 1] {
            let a = aggregate[indices[at] as usize];
            // A row touches a handful of aggregates: a scan beats a map.
            slot[at] = match az_aggregate[start..].iter().position(|&b| b == a) {
                Some(s) => (start + s) as u32,
                None => {
                    az_aggregate.push(a);
                    (az_aggregate.len() - 1) as u32
                }
            };
        }
        az_indptr.push(az_aggregate.len());
    }
    (az_indptr, az_aggregate, slot)
}

/// The rigid-motion rows at offset `d` from the aggregate's centre: translations, then
/// rotations ($\omega \times d$ in 3-D, $\omega (-d_y, d_x)$ in 2-D).
fn rigid_rows<const B: usize>(d: &[f64; B]) -> Basis<B> {
    let mut z = [[0.0; MAX_MODES]; B];
    for (a, row) in z.iter_mut().enumerate() {
        row[a] = 1.0;
    }
    if B == 2 {
        z[0][2] = -d[1];
        z[1][2] = d[0];
    } else {
        let (x, y, w) = (d[0], d[1], d[2]);
        // e_x × d, e_y × d, e_z × d as columns 3, 4, 5.
        z[1][3] = -w;
        z[2][3] = y;
        z[0][4] = w;
        z[2][4] = -x;
        z[0][5] = -y;
        z[1][5] = x;
    }
    z
}

/// In-place lower Cholesky of the row-major symmetric `(n, n)` matrix `e`; an unknown
/// whose pivot falls below 1e-10 of its diagonal (a rigid mode its aggregate cannot
/// express) is dropped: zero column, unit pivot. Returns the dropped flags.
fn cholesky_dropping(e: &mut [f64], n: usize) -> Vec<bool> {
    let diagonal: Vec<f64> = (0..n).map(|i| e[i * n + i]).collect();
    let mut dropped = vec![false; n];
    for j in 0..n {
        let mut d = e[j * n + j];
        for t in 0..j {
            d -= e[j * n + t] * e[j * n + t];
        }
        let keep = d.is_finite() && d > 1e-10 * diagonal[j].abs();
        if !keep {
            dropped[j] = true;
            e[j * n + j] = 1.0;
            for i in j + 1..n {
                e[i * n + j] = 0.0;
            }
            continue;
        }
        let pivot = d.sqrt();
        e[j * n + j] = pivot;
        for i in j + 1..n {
            let mut v = e[i * n + j];
            for t in 0..j {
                v -= e[i * n + t] * e[j * n + t];
            }
            e[i * n + j] = v / pivot;
        }
    }
    // Clear the strict upper triangle (it held E) so solves read only L.
    for i in 0..n {
        for j in i + 1..n {
            e[i * n + j] = 0.0;
        }
    }
    dropped
}

/// Greedy aggregation on the strong connections of the block graph: `(aggregate of each
/// node, number of aggregates)`.
fn aggregate<const B: usize>(matrix: &BlockCsr<B>, theta: f64) -> (Vec<u32>, usize) {
    let (indptr, indices, blocks) = (matrix.indptr(), matrix.indices(), matrix.blocks());
    let n = matrix.len();
    let norm = |b: &Block<B>| b.iter().flatten().map(|v| v * v).sum::<f64>().sqrt();
    let diagonal: Vec<f64> = (0..n).map(|i| norm(matrix.diagonal_block(i))).collect();
    // Strong neighbours of each row with their strength, strongest first.
    let strong: Vec<Vec<(u32, f64)>> = (0..n)
        .into_par_iter()
        .with_min_len(ROWS_PER_TASK)
        .map(|i| {
            let mut row: Vec<(u32, f64)> = (indptr[i]..indptr[i + 1])
                .filter_map(|at| {
                    let j = indices[at] as usize;
                    let s = norm(&blocks[at]) / (diagonal[i] * diagonal[j]).sqrt();
                    (j != i && s > theta).then_some((j as u32, s))
                })
                .collect();
            row.sort_by(|a, b| b.1.total_cmp(&a.1));
            row
        })
        .collect();
    const NONE: u32 = u32::MAX;
    let mut of = vec![NONE; n];
    let mut count = 0u32;
    for i in 0..n {
        if of[i] == NONE && strong[i].iter().all(|&(j, _)| of[j as usize] == NONE) {
            of[i] = count;
            for &(j, _) in &strong[i] {
                of[j as usize] = count;
            }
            count += 1;
        }
    }
    for i in 0..n {
        if of[i] == NONE {
            of[i] = match strong[i].iter().find(|&&(j, _)| of[j as usize] != NONE) {
                Some(&(j, _)) => of[j as usize],
                None => {
                    count += 1;
                    count - 1
                }
            };
        }
    }
    (of, count as usize)
}

impl<const B: usize> Preconditioner<B> for TwoLevel<B> {
    fn apply(&mut self, r: &[[f64; B]], z: &mut [[f64; B]]) {
        self.jacobi.apply(r, z);
        let m = modes(B);
        let nc = self.coarse.len();
        // Restrict: c = Z^T r.
        self.coarse.iter_mut().for_each(|v| *v = 0.0);
        for ((zi, ri), &a) in self.basis.iter().zip(r).zip(&self.aggregate) {
            let base = a as usize * m;
            for (c, value) in self.coarse[base..base + m].iter_mut().enumerate() {
                *value += (0..B).map(|t| zi[t][c] * ri[t]).sum::<f64>();
            }
        }
        // Solve E y = c: L w = c, then L^T y = w (dropped unknowns stay zero).
        let (l, y) = (&self.factor, &mut self.coarse);
        for i in 0..nc {
            if self.dropped[i] {
                y[i] = 0.0;
                continue;
            }
            let s: f64 = (0..i).map(|t| l[i * nc + t] * y[t]).sum();
            y[i] = (y[i] - s) / l[i * nc + i];
        }
        for i in (0..nc).rev() {
            if self.dropped[i] {
                continue;
            }
            let v = y[i] / l[i * nc + i];
            y[i] = v;
            for t in 0..i {
                y[t] -= l[i * nc + t] * v;
            }
        }
        // Prolong: z += Z y.
        for ((zi, out), &a) in self.basis.iter().zip(z.iter_mut()).zip(&self.aggregate) {
            let base = a as usize * m;
            for t in 0..B {
                out[t] += (0..m).map(|c| zi[t][c] * y[base + c]).sum::<f64>();
            }
        }
    }
}
