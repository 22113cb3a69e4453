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
use wide::Lane;

/// True when 3x3 products run the AVX2 kernel (with a float32 copy): for the tests.
#[cfg(test)]
pub(super) fn avx2() -> bool {
    wide::available()
}

/// Blocks per task below which the product runs on one thread.
const BLOCKS_PER_TASK: usize = 8192;

/// Most tasks a product is split into. The tasks' accumulators are summed in task order,
/// so the split must not follow the pool's size: the product, and every fit that uses it,
/// would then round differently on another thread count ([`crate::ordered`]). The
/// split depends on the matrix alone; more tasks than threads cost one more accumulator
/// pass each (measured in benches/README.md, detsum1).
const MAX_TASKS: usize = 8;

/// Upper-triangle copy of a matrix, with per-task accumulators for the product.
#[derive(Debug, Clone, Default)]
pub(super) struct Upper<const B: usize> {
    source: Option<Arc<Pattern>>,
    indptr: Vec<usize>,
    indices: Vec<u32>,
    /// Position of each upper block in the full matrix.
    positions: Vec<usize>,
    blocks: Vec<Block<B>>,
    /// The AVX2 kernel runs (3x3 blocks on a CPU that has it): `blocks` then ends with one
    /// zero block past the last, read by the kernel's 4-lane loads.
    fast: bool,
    /// float32 copy of `blocks` (9 values per block, and the pad) for the inner products of
    /// [`Self::mul_inner`]; empty when not fast or a value exceeds float32's range.
    narrow: Vec<f32>,
    /// `x` padded, and the per-task accumulators, of the AVX2 kernel.
    x_wide: Vec<Lane>,
    partial_wide: Vec<Vec<Lane>>,
    /// Row ranges of the tasks, balanced by blocks.
    ranges: Vec<(usize, usize)>,
    /// Per task, the rows its accumulator touches: its first row up to one past its largest
    /// column (the upper triangle writes no row before its own). Only this span is zeroed
    /// and added, so on a banded ordering the extra tasks cost little ([`Self::sum_tasks`]).
    spans: Vec<(usize, usize)>,
    partial: Vec<Vec<[f64; B]>>,
}

impl<const B: usize> Upper<B> {
    /// Splits the rows into tasks of at least [`BLOCKS_PER_TASK`] blocks, at most
    /// [`MAX_TASKS`], balanced by blocks (one task when small), and sizes the accumulators.
    fn split(&mut self, n: usize) {
        let total = self.indices.len();
        let tasks = (total / BLOCKS_PER_TASK).clamp(1, MAX_TASKS);
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
        let indptr = &self.indptr;
        let indices = &self.indices;
        self.spans = self
            .ranges
            .iter()
            .map(|&(start, end)| {
                let reach = (start..end)
                    .filter(|&i| indptr[i + 1] > indptr[i])
                    .map(|i| indices[indptr[i + 1] - 1] as usize + 1)
                    .fold(end, usize::max);
                (start, reach)
            })
            .collect();
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
        self.indptr[..self.indptr.len() - 1]
            .iter()
            .map(|&at| self.blocks[at])
            .collect()
    }

    /// Row pointers, columns and blocks (unpadded) of the upper triangle, and whether every
    /// pad lane is zero: for the tests.
    /// Row pointers, columns, float64 blocks (empty when held in float32 alone; the pad
    /// block dropped) and the float32 copy (empty without one): for the tests.
    #[cfg(test)]
    pub(super) fn parts(&self) -> (&[usize], &[u32], &[Block<B>], &[f32]) {
        let n = self.indices.len().min(self.blocks.len());
        (&self.indptr, &self.indices, &self.blocks[..n], &self.narrow)
    }

    /// Row ranges of the tasks and the rows each one's accumulator touches: for the tests.
    #[cfg(test)]
    pub(super) fn tasks(&self) -> (&[(usize, usize)], &[(usize, usize)]) {
        (&self.ranges, &self.spans)
    }

    /// Marks the AVX2 kernel and makes its float32 copy, once `blocks` holds the upper
    /// triangle.
    fn finish(&mut self) {
        self.fast = B == 3 && wide::available();
        self.narrow.clear();
        if !self.fast {
            return;
        }
        self.blocks.push([[0.0; B]; B]);
        let flat = self.blocks.as_flattened().as_flattened();
        self.narrow.resize(flat.len(), 0.0);
        let fits = self
            .narrow
            .par_chunks_mut(1 << 16)
            .zip(flat.par_chunks(1 << 16))
            .all(|(n, f)| {
                n.iter_mut().zip(f).for_each(|(n, &f)| *n = f as f32);
                n.iter().all(|v| v.is_finite())
            });
        if !fits {
            self.narrow.clear();
        }
    }

    /// The float32 copy of the upper blocks of `matrix` alone (no float64 copy: the exact
    /// products then come from `matrix`); false, with nothing made, when a value does not
    /// fit in float32.
    fn gather_narrow(&mut self, matrix: &BlockCsr<B>) -> bool {
        let all = matrix.blocks();
        self.blocks.clear();
        // One zero block past the last, as `finish` makes: the kernel's 4-lane loads.
        let len = (self.positions.len() + 1) * B * B;
        self.narrow.resize(len, 0.0);
        self.narrow[len - B * B..].fill(0.0);
        let per_task = BLOCKS_PER_TASK / 2;
        let fits = self
            .narrow
            .par_chunks_mut(per_task * B * B)
            .zip(self.positions.par_chunks(per_task))
            .all(|(n, positions)| {
                for (k, &at) in positions.iter().enumerate() {
                    let values = all[at].as_flattened();
                    for (t, &v) in values.iter().enumerate() {
                        n[k * B * B + t] = v as f32;
                    }
                }
                n.iter().all(|v| v.is_finite())
            });
        if !fits {
            self.narrow.clear();
        }
        fits
    }

    /// True when the upper blocks are also held in float64 ([`Self::mul`] works); false
    /// after [`Self::load`] made the float32 copy alone.
    pub(super) fn has_exact(&self) -> bool {
        !self.blocks.is_empty()
    }

    /// True when [`Self::mul_inner`] is the float32 product (not exact).
    pub(super) fn inexact_inner(&self) -> bool {
        !self.narrow.is_empty()
    }

    /// Copies the upper triangle of `matrix`, in float32 alone when the AVX2 kernel runs
    /// (exact products then come from `matrix`: see [`Self::has_exact`]); the pattern work
    /// is redone only when the pattern changed.
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
        self.fast = B == 3 && wide::available();
        if self.fast && self.gather_narrow(matrix) {
            return;
        }
        let all = matrix.blocks();
        self.blocks.resize(self.positions.len(), [[0.0; B]; B]);
        self.blocks
            .par_iter_mut()
            .with_min_len(BLOCKS_PER_TASK)
            .zip(self.positions.par_iter())
            .for_each(|(b, &at)| *b = all[at]);
        self.finish();
    }

    /// $y = A x$ from the upper triangle.
    ///
    /// # Panics
    /// Unless [`Self::has_exact`].
    pub(super) fn mul(&mut self, x: &[[f64; B]], y: &mut [[f64; B]]) {
        if self.fast {
            let flat = self.blocks.as_flattened().as_flattened();
            // SAFETY: `fast` only when `available()`; `blocks` ends with the pad block.
            let kernel = |r, x: &[Lane], part: &mut [Lane]| unsafe {
                wide::rows_f64(&self.indptr, &self.indices, flat, x, r, part)
            };
            Self::mul_wide(
                &mut self.x_wide,
                &mut self.partial_wide,
                (&self.ranges, &self.spans),
                kernel,
                x,
                y,
            );
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
            .zip(self.ranges.par_iter().zip(self.spans.par_iter()))
            .for_each(|(part, (&range, &(from, to)))| {
                part[from..to].iter_mut().for_each(|v| *v = [0.0; B]);
                rows(range, part);
            });
        y.iter_mut().for_each(|v| *v = [0.0; B]);
        sum_tasks(&self.partial, &self.spans, y);
    }

    /// $y \approx A x$ from the float32 copy when there is one (relative error ~1e-7 of
    /// $|A|\,|x|$), else [`Self::mul`]: the inner iterations of conjugate gradients.
    pub(super) fn mul_inner(&mut self, x: &[[f64; B]], y: &mut [[f64; B]]) {
        if self.narrow.is_empty() {
            self.mul(x, y);
            return;
        }
        let narrow = &self.narrow;
        // SAFETY: `narrow` is made only when `fast`; it holds the pad values too.
        let kernel = |r, x: &[Lane], part: &mut [Lane]| unsafe {
            wide::rows_f32(&self.indptr, &self.indices, narrow, x, r, part)
        };
        Self::mul_wide(
            &mut self.x_wide,
            &mut self.partial_wide,
            (&self.ranges, &self.spans),
            kernel,
            x,
            y,
        );
    }

    /// The product by an AVX2 `kernel(rows, x, y)`: `x` padded, one task per range, the
    /// tasks' accumulators summed.
    fn mul_wide<K>(
        x_wide: &mut [Lane],
        partial: &mut [Vec<Lane>],
        (ranges, spans): (&[(usize, usize)], &[(usize, usize)]),
        kernel: K,
        x: &[[f64; B]],
        y: &mut [[f64; B]],
    ) where
        K: Fn((usize, usize), &[Lane], &mut [Lane]) + Sync,
    {
        for (w, v) in x_wide.iter_mut().zip(x) {
            w[..B].copy_from_slice(v);
        }
        let x_wide = &*x_wide;
        if ranges.len() == 1 {
            partial[0].iter_mut().for_each(|v| *v = [0.0; 4]);
            kernel(ranges[0], x_wide, &mut partial[0]);
            for (yi, p) in y.iter_mut().zip(&partial[0]) {
                // `-0.0 + v`, as a sum of one term starting from -0.0 gives.
                yi.iter_mut().zip(p).for_each(|(y, &v)| *y = -0.0 + v);
            }
            return;
        }
        partial
            .par_iter_mut()
            .zip(ranges.par_iter().zip(spans.par_iter()))
            .for_each(|(part, (&range, &(from, to)))| {
                part[from..to].iter_mut().for_each(|v| *v = [0.0; 4]);
                kernel(range, x_wide, part);
            });
        // The tasks' sum as `Iterator::sum` over all of them gave it (it starts from -0.0):
        // the skipped accumulators hold +0.0, which changes a sum only by turning a -0.0
        // into +0.0, so that is added where some task does not reach the row.
        y.iter_mut().for_each(|v| *v = [-0.0; B]);
        sum_tasks(partial, spans, y);
        let full = spans.last().map_or(0, |s| s.0)..spans.iter().map(|s| s.1).min().unwrap_or(0);
        for (i, yi) in y.iter_mut().enumerate() {
            if !full.contains(&i) {
                yi.iter_mut().for_each(|v| *v += 0.0);
            }
        }
    }
}

/// Adds each task's accumulator over its span to `y`, task by task (the order fixes the
/// rounding): the sum over all tasks, less the zeros of the rows a task does not touch.
fn sum_tasks<const B: usize, const L: usize>(
    partial: &[Vec<[f64; L]>],
    spans: &[(usize, usize)],
    y: &mut [[f64; B]],
) {
    for (part, &(from, to)) in partial.iter().zip(spans) {
        for (yi, p) in y[from..to].iter_mut().zip(&part[from..to]) {
            for a in 0..B {
                yi[a] += p[a];
            }
        }
    }
}
