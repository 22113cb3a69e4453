//! The upper triangle of a symmetric [`BlockCsr`] (diagonal blocks included), for the
//! products of conjugate gradients: each stored block is read once and used twice,
//! $y_i \mathrel{+}= A_{ij} x_j$ and $y_j \mathrel{+}= A_{ij}^\top x_i$. The product is
//! bound by memory traffic (the matrix does not fit in cache at the paper's size), so
//! reading half the blocks is about twice as fast (see benches/README.md).

use std::sync::Arc;

use rayon::prelude::*;

use super::block::{Block, BlockCsr, Pattern};

mod csr;
mod wide;
use wide::{Lane, Wide};

/// Blocks per task below which the product runs on one thread.
const BLOCKS_PER_TASK: usize = 8192;

/// Upper-triangle copy of a matrix, with per-task accumulators for the product.
#[derive(Debug, Clone, Default)]
pub(super) struct Upper<const B: usize> {
    source: Option<Arc<Pattern>>,
    indptr: Vec<usize>,
    indices: Vec<u32>,
    /// Position of each upper block in the full matrix.
    positions: Vec<usize>,
    blocks: Vec<Block<B>>,
    /// The upper blocks padded for the AVX2 kernel (3x3 blocks on a CPU that has it);
    /// `blocks` is then left empty.
    wide: Vec<Wide>,
    /// `x` padded, and the per-task accumulators, of the AVX2 kernel.
    x_wide: Vec<Lane>,
    partial_wide: Vec<Vec<Lane>>,
    /// Row ranges of the tasks, balanced by blocks.
    ranges: Vec<(usize, usize)>,
    partial: Vec<Vec<[f64; B]>>,
}

impl<const B: usize> Upper<B> {
    /// Splits the rows into one task per thread, balanced by blocks (one task when small),
    /// and sizes the accumulators.
    fn split(&mut self, n: usize) {
        let total = self.indices.len();
        let tasks = rayon::current_num_threads()
            .min(total / BLOCKS_PER_TASK)
            .max(1);
        self.ranges.clear();
        let mut start = 0;
        for t in 1..=tasks {
            let end = if t == tasks {
                n
            } else {
                self.indptr
                    .partition_point(|&p| p < total * t / tasks)
                    .min(n)
            };
            self.ranges.push((start, end.max(start)));
            start = end.max(start);
        }
        if B == 3 && wide::available() {
            self.partial = Vec::new();
            self.x_wide = vec![[0.0; 4]; n];
            self.partial_wide = vec![vec![[0.0; 4]; n]; tasks];
        } else {
            self.partial = vec![vec![[0.0; B]; n]; tasks];
        }
    }

    /// The diagonal blocks, one per row (the first block of each upper row).
    pub(super) fn diagonal(&self) -> Vec<Block<B>> {
        let first = self.indptr[..self.indptr.len() - 1].iter();
        if self.wide.is_empty() {
            first.map(|&at| self.blocks[at]).collect()
        } else {
            first
                .map(|&at| std::array::from_fn(|a| std::array::from_fn(|b| self.wide[at][a][b])))
                .collect()
        }
    }

    /// Row pointers, columns and blocks (unpadded) of the upper triangle, and whether every
    /// pad lane is zero: for the tests.
    #[cfg(test)]
    pub(super) fn parts(&self) -> (&[usize], &[u32], Vec<Block<B>>, bool) {
        if self.wide.is_empty() {
            return (&self.indptr, &self.indices, self.blocks.clone(), true);
        }
        let blocks = self
            .wide
            .iter()
            .map(|w| std::array::from_fn(|a| std::array::from_fn(|b| w[a][b])))
            .collect();
        let pads = self
            .wide
            .iter()
            .all(|w| w.iter().all(|row| row[B..].iter().all(|&v| v == 0.0)));
        (&self.indptr, &self.indices, blocks, pads)
    }

    /// Copies the upper triangle of `matrix`; the pattern work is redone only when the
    /// pattern changed.
    pub(super) fn load(&mut self, matrix: &BlockCsr<B>) {
        let same = self
            .source
            .as_ref()
            .is_some_and(|p| Arc::ptr_eq(p, matrix.pattern()));
        if !same {
            let (n, indptr, indices) = (matrix.len(), matrix.indptr(), matrix.indices());
            self.indptr.clear();
            self.indices.clear();
            self.positions.clear();
            self.indptr.push(0);
            for i in 0..n {
                let row = indptr[i]..indptr[i + 1];
                let first = row.start + indices[row.clone()].partition_point(|&j| (j as usize) < i);
                self.positions.extend(first..row.end);
                self.indices.extend_from_slice(&indices[first..row.end]);
                self.indptr.push(self.indices.len());
            }
            self.split(n);
            self.source = Some(Arc::clone(matrix.pattern()));
        }
        let all = matrix.blocks();
        if B == 3 && wide::available() {
            self.blocks.clear();
            self.wide.resize(self.positions.len(), [[0.0; 4]; 3]);
            self.wide
                .par_iter_mut()
                .with_min_len(BLOCKS_PER_TASK)
                .zip(self.positions.par_iter())
                .for_each(|(w, &at)| {
                    for a in 0..B {
                        w[a][..B].copy_from_slice(&all[at][a]);
                    }
                });
            return;
        }
        self.wide.clear();
        self.blocks.resize(self.positions.len(), [[0.0; B]; B]);
        self.blocks
            .par_iter_mut()
            .with_min_len(BLOCKS_PER_TASK)
            .zip(self.positions.par_iter())
            .for_each(|(b, &at)| *b = all[at]);
    }

    /// $y = A x$ from the upper triangle.
    pub(super) fn mul(&mut self, x: &[[f64; B]], y: &mut [[f64; B]]) {
        if !self.wide.is_empty() {
            self.mul_wide(x, y);
            return;
        }
        let (indptr, indices, blocks) = (&self.indptr, &self.indices, &self.blocks);
        let rows = |(start, end): (usize, usize), y: &mut [[f64; B]]| {
            for i in start..end {
                let xi = x[i];
                let mut yi = [0.0; B];
                for at in indptr[i]..indptr[i + 1] {
                    let (m, j) = (&blocks[at], indices[at] as usize);
                    let xj = x[j];
                    for a in 0..B {
                        for b in 0..B {
                            yi[a] += m[a][b] * xj[b];
                        }
                    }
                    if j != i {
                        let yj = &mut y[j];
                        for b in 0..B {
                            for a in 0..B {
                                yj[b] += m[a][b] * xi[a];
                            }
                        }
                    }
                }
                for a in 0..B {
                    y[i][a] += yi[a];
                }
            }
        };
        if self.ranges.len() == 1 {
            y.iter_mut().for_each(|v| *v = [0.0; B]);
            rows(self.ranges[0], y);
            return;
        }
        self.partial
            .par_iter_mut()
            .zip(self.ranges.par_iter())
            .for_each(|(part, &range)| {
                part.iter_mut().for_each(|v| *v = [0.0; B]);
                rows(range, part);
            });
        let partial = &self.partial;
        y.iter_mut().enumerate().for_each(|(i, yi)| {
            *yi = [0.0; B];
            for part in partial {
                for a in 0..B {
                    yi[a] += part[i][a];
                }
            }
        });
    }

    /// [`Self::mul`] by the AVX2 kernel on the padded blocks.
    fn mul_wide(&mut self, x: &[[f64; B]], y: &mut [[f64; B]]) {
        for (w, v) in self.x_wide.iter_mut().zip(x) {
            w[..B].copy_from_slice(v);
        }
        let (indptr, indices, blocks) = (&self.indptr, &self.indices, &self.wide);
        let x = &self.x_wide;
        // SAFETY: `wide` is filled only when `available()`; rows of the upper triangle start
        // with the diagonal block (every diagonal block is stored); columns are < n.
        let rows = |range, part: &mut [Lane]| unsafe {
            wide::rows(indptr, indices, blocks, x, range, part)
        };
        if self.ranges.len() == 1 {
            let part = &mut self.partial_wide[0];
            part.iter_mut().for_each(|v| *v = [0.0; 4]);
            rows(self.ranges[0], part);
        } else {
            self.partial_wide
                .par_iter_mut()
                .zip(self.ranges.par_iter())
                .for_each(|(part, &range)| {
                    part.iter_mut().for_each(|v| *v = [0.0; 4]);
                    rows(range, part);
                });
        }
        let partial = &self.partial_wide;
        y.iter_mut().enumerate().for_each(|(i, yi)| {
            for a in 0..B {
                yi[a] = partial.iter().map(|part| part[i][a]).sum();
            }
        });
    }
}
