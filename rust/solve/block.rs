//! A symmetric block-sparse matrix: $B \times B$ blocks in compressed sparse rows, the full
//! pattern stored (both triangles, every diagonal block present), columns sorted.
//!
//! The pattern is shared (`Arc`) by every matrix of a sequence, so checking that two
//! matrices have the same pattern is a pointer comparison in the common case, and the
//! per-iteration assembly $\alpha K + \sum_j s M_j$ rewrites values in place.

use std::sync::Arc;

use rayon::prelude::*;

use crate::efg::Csr;
use crate::error::{check_finite, Error, Result};

mod build;
pub(super) mod scan;
pub use build::CsrIndex;

/// Block rows per rayon task: a row of the EFG pattern holds ~50-100 blocks, so 64 rows
/// are tens of microseconds of work, well above the cost of a task.
pub(super) const ROWS_PER_TASK: usize = 64;

/// A dense $B \times B$ block, row-major (a [`crate::linalg::Matrix`]).
pub type Block<const B: usize> = crate::linalg::Matrix<B>;

/// Block columns of each block row, sorted, symmetric, with the diagonal present.
#[derive(Debug, PartialEq, Eq)]
pub(super) struct Pattern {
    /// `(n + 1,)`: block row `i` holds blocks `indptr[i]..indptr[i + 1]`.
    pub(super) indptr: Vec<usize>,
    /// Block column of each block.
    pub(super) indices: Vec<u32>,
    /// Position of the diagonal block of each row.
    pub(super) diagonal: Vec<usize>,
}

impl Pattern {
    /// The pattern of sorted, deduplicated `rows` (each holding its own index); fails
    /// unless it is symmetric.
    fn from_rows(argument: &'static str, rows: Vec<Vec<u32>>) -> Result<Self> {
        let n = rows.len();
        let mut indptr = Vec::with_capacity(n + 1);
        indptr.push(0);
        for row in &rows {
            indptr.push(indptr[indptr.len() - 1] + row.len());
        }
        let mut indices = Vec::with_capacity(indptr[n]);
        for row in rows {
            indices.extend(row);
        }
        let diagonal: Vec<usize> = (0..n)
            .into_par_iter()
            .map(|i| {
                let row = &indices[indptr[i]..indptr[i + 1]];
                indptr[i] + row.binary_search(&(i as u32)).unwrap_or(0)
            })
            .collect();
        if let Some(row) = asymmetric_row(n, |i| &indices[indptr[i]..indptr[i + 1]]) {
            return Err(Error::SparsePattern {
                argument,
                row,
                reason: "the pattern is not symmetric (an entry (i, j) has no (j, i))",
            });
        }
        Ok(Self {
            indptr,
            indices,
            diagonal,
        })
    }

    fn len(&self) -> usize {
        self.diagonal.len()
    }
}

/// The first block row `i` holding a column `j` whose row does not hold `i`; `row(i)` gives
/// the sorted block columns of row `i`.
pub(in crate::solve) fn asymmetric_row<'a, R>(n: usize, row: R) -> Option<usize>
where
    R: Fn(usize) -> &'a [u32] + Sync,
{
    if is_symmetric(n, &row) {
        return None;
    }
    // Only for the error message: the binary searches name the first offending row.
    (0..n).into_par_iter().with_min_len(16).find_first(|&i| {
        row(i)
            .iter()
            .any(|&j| row(j as usize).binary_search(&(i as u32)).is_err())
    })
}

/// True when every `(i, j)` of the pattern has its `(j, i)`, by one merge-like pass: rows
/// taken in order consume the lower entries of the rows they point to, which must come in
/// the same order. One pass without searches (the binary searches took ~2 ms at the
/// paper's size, this ~0.3 ms).
fn is_symmetric<'a>(n: usize, row: &impl Fn(usize) -> &'a [u32]) -> bool {
    // next[j]: how many lower entries of row j were matched so far.
    let mut next = vec![0usize; n];
    for i in 0..n {
        let columns = row(i);
        // Every lower entry (i, k < i) was matched by row k, which came before.
        if columns.get(next[i]).is_none_or(|&k| k as usize != i) {
            return false;
        }
        for &j in &columns[next[i] + 1..] {
            let j = j as usize;
            if row(j).get(next[j]) != Some(&(i as u32)) {
                return false;
            }
            next[j] += 1;
        }
    }
    true
}

/// A symmetric matrix of $n \times n$ blocks of size $B \times B$ ($B$ = 2 or 3), scalar
/// degree of freedom `node * B + axis`.
#[derive(Debug, Clone)]
pub struct BlockCsr<const B: usize> {
    pattern: Arc<Pattern>,
    blocks: Vec<[[f64; B]; B]>,
}

impl<const B: usize> BlockCsr<B> {
    const CHECK: () = assert!(B == 2 || B == 3, "blocks are 2x2 or 3x3");

    pub(super) fn zeros(pattern: Pattern) -> Self {
        let blocks = vec![[[0.0; B]; B]; pattern.indices.len()];
        Self {
            pattern: Arc::new(pattern),
            blocks,
        }
    }

    /// A zero matrix sharing this one's pattern: the preallocated output of
    /// [`Self::scale_into`].
    pub fn zeros_like(&self) -> Self {
        Self {
            pattern: Arc::clone(&self.pattern),
            blocks: vec![[[0.0; B]; B]; self.blocks.len()],
        }
    }

    /// The scalar CSR matrix ($nB \times nB$), every stored block written out in full.
    pub fn to_csr(&self) -> Csr {
        let (n, p) = (self.len(), &*self.pattern);
        let size = n * B;
        let mut indptr = Vec::with_capacity(size + 1);
        indptr.push(0);
        let mut indices = Vec::with_capacity(self.blocks.len() * B * B);
        let mut data = Vec::with_capacity(self.blocks.len() * B * B);
        for i in 0..n {
            for a in 0..B {
                for at in p.indptr[i]..p.indptr[i + 1] {
                    let j = p.indices[at] as usize;
                    indices.extend((0..B).map(|b| j * B + b));
                    data.extend_from_slice(&self.blocks[at][a]);
                }
                indptr.push(data.len());
            }
        }
        Csr {
            size,
            indptr,
            indices,
            data,
        }
    }

    /// Number of block rows (nodes).
    pub fn len(&self) -> usize {
        self.pattern.len()
    }

    /// Always false: a matrix has at least one block row.
    pub fn is_empty(&self) -> bool {
        self.pattern.len() == 0
    }

    /// Number of scalar rows, $nB$.
    pub fn size(&self) -> usize {
        self.len() * B
    }

    /// `(n + 1,)` block-row pointers.
    pub fn indptr(&self) -> &[usize] {
        &self.pattern.indptr
    }

    /// Block column of each stored block, sorted within each row.
    pub fn indices(&self) -> &[u32] {
        &self.pattern.indices
    }

    /// The stored blocks, row-major.
    pub fn blocks(&self) -> &[[[f64; B]; B]] {
        &self.blocks
    }

    /// The stored blocks, to rewrite in place (the pattern stays).
    pub fn blocks_mut(&mut self) -> &mut [[[f64; B]; B]] {
        &mut self.blocks
    }

    /// The diagonal block of node `i`.
    ///
    /// # Panics
    /// If `i >= self.len()`.
    pub fn diagonal_block(&self, i: usize) -> &[[f64; B]; B] {
        &self.blocks[self.pattern.diagonal[i]]
    }

    /// The diagonal block of node `i`, to change in place.
    ///
    /// # Panics
    /// If `i >= self.len()`.
    pub fn diagonal_block_mut(&mut self, i: usize) -> &mut [[f64; B]; B] {
        &mut self.blocks[self.pattern.diagonal[i]]
    }

    /// True when `other` has the same pattern (a pointer comparison when it was made from
    /// this one by [`Self::zeros_like`] or `clone`).
    pub fn same_pattern(&self, other: &Self) -> bool {
        Arc::ptr_eq(&self.pattern, &other.pattern) || self.pattern == other.pattern
    }

    pub(super) fn pattern(&self) -> &Arc<Pattern> {
        &self.pattern
    }

    /// Adds `scale * blocks[j]` to the diagonal block of node `nodes[j]` (a node may repeat).
    ///
    /// # Errors
    /// [`Error::VectorLength`] unless `blocks` has one block per node; [`Error::NodeIndex`];
    /// [`Error::NonFinite`] for `blocks`; [`Error::InvalidOption`] for a non-finite scale.
    pub fn add_diagonal_blocks(
        &mut self,
        scale: f64,
        nodes: &[u32],
        blocks: &[[[f64; B]; B]],
    ) -> Result<()> {
        if !scale.is_finite() {
            return Err(Error::InvalidOption {
                argument: "scale",
                value: scale,
                expected: "a finite number",
            });
        }
        if blocks.len() != nodes.len() {
            return Err(Error::VectorLength {
                argument: "blocks",
                expected: nodes.len(),
                got: blocks.len(),
            });
        }
        let n = self.len();
        if let Some(position) = nodes.iter().position(|&i| i as usize >= n) {
            return Err(Error::NodeIndex {
                argument: "nodes",
                position,
                index: nodes[position] as usize,
                n,
            });
        }
        let flat: Vec<[f64; B]> = blocks.iter().flatten().copied().collect();
        check_finite("blocks", &flat).map_err(|e| match e {
            Error::NonFinite { argument, row } => Error::NonFinite {
                argument,
                row: row / B,
            },
            other => other,
        })?;
        for (&i, m) in nodes.iter().zip(blocks) {
            let d = &mut self.blocks[self.pattern.diagonal[i as usize]];
            for a in 0..B {
                for b in 0..B {
                    d[a][b] += scale * m[a][b];
                }
            }
        }
        Ok(())
    }

    /// Writes `alpha * self` into `out`, a matrix of the same pattern (e.g. from
    /// [`Self::zeros_like`]); with [`Self::add_diagonal_blocks`] on `out` this assembles
    /// $\alpha K + \beta D + \gamma I$ without allocating.
    ///
    /// # Errors
    /// [`Error::PatternMismatch`]; [`Error::InvalidOption`] for a non-finite `alpha`.
    pub fn scale_into(&self, alpha: f64, out: &mut Self) -> Result<()> {
        if !alpha.is_finite() {
            return Err(Error::InvalidOption {
                argument: "alpha",
                value: alpha,
                expected: "a finite number",
            });
        }
        if !self.same_pattern(out) {
            return Err(Error::PatternMismatch {
                argument: "out",
                expected: "of the matrix being scaled",
            });
        }
        out.blocks
            .par_iter_mut()
            .with_min_len(4096)
            .zip(&self.blocks)
            .for_each(|(o, s)| {
                for a in 0..B {
                    for b in 0..B {
                        o[a][b] = alpha * s[a][b];
                    }
                }
            });
        Ok(())
    }

    /// $(A x)_i$ for block row `i`.
    #[inline]
    pub(super) fn row_product(&self, i: usize, x: &[[f64; B]]) -> [f64; B] {
        let p = &*self.pattern;
        let mut y = [0.0; B];
        for at in p.indptr[i]..p.indptr[i + 1] {
            let (m, xj) = (&self.blocks[at], &x[p.indices[at] as usize]);
            for a in 0..B {
                for b in 0..B {
                    y[a] += m[a][b] * xj[b];
                }
            }
        }
        y
    }

    /// $y = A x$, block rows in parallel.
    ///
    /// # Errors
    /// [`Error::VectorLength`] unless `x` and `y` have $nB$ entries.
    pub fn mul_into(&self, x: &[f64], y: &mut [f64]) -> Result<()> {
        for (argument, len) in [("x", x.len()), ("y", y.len())] {
            if len != self.size() {
                return Err(Error::VectorLength {
                    argument,
                    expected: self.size(),
                    got: len,
                });
            }
        }
        self.mul_unchecked(x.as_chunks::<B>().0, y.as_chunks_mut::<B>().0);
        Ok(())
    }

    pub(super) fn mul_unchecked(&self, x: &[[f64; B]], y: &mut [[f64; B]]) {
        y.par_iter_mut()
            .with_min_len(ROWS_PER_TASK)
            .enumerate()
            .for_each(|(i, yi)| *yi = self.row_product(i, x));
    }
}
