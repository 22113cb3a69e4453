//! The block-arrowhead normal matrix and its damped sparse Cholesky solve.

use faer::linalg::solvers::Solve;
use faer::sparse::linalg::solvers::{Llt, SymbolicLlt};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{MatMut, Side};

use crate::{Error, Result};

/// `J^T P J` and `J^T P r` in blocks: per frame `A_f` (m x m) and `B_f` (m x s, frame rows
/// by shared columns), shared `C` (s x s), all row-major and full (both triangles).
#[derive(Debug, Clone)]
pub struct ArrowNormal {
    /// Frames.
    pub frames: usize,
    /// Per-frame parameters.
    pub m: usize,
    /// Shared parameters.
    pub s: usize,
    /// Frame blocks, `frames * m * m`.
    pub a: Vec<f64>,
    /// Couplings, `frames * m * s`.
    pub b: Vec<f64>,
    /// Shared block, `s * s`.
    pub c: Vec<f64>,
    /// Gradient `J^T P r`, `frames * m + s`.
    pub g: Vec<f64>,
}

impl ArrowNormal {
    /// Zeros of the given dimensions.
    pub fn new(frames: usize, m: usize, s: usize) -> Self {
        Self {
            frames,
            m,
            s,
            a: vec![0.0; frames * m * m],
            b: vec![0.0; frames * m * s],
            c: vec![0.0; s * s],
            g: vec![0.0; frames * m + s],
        }
    }

    /// Sets everything to zero.
    pub fn clear(&mut self) {
        for v in [&mut self.a, &mut self.b, &mut self.c, &mut self.g] {
            v.iter_mut().for_each(|x| *x = 0.0);
        }
    }

    /// Diagonal entry `i` (global index).
    fn diagonal(&self, i: usize) -> f64 {
        let fm = self.frames * self.m;
        if i < fm {
            let (f, j) = (i / self.m, i % self.m);
            self.a[f * self.m * self.m + j * self.m + j]
        } else {
            let j = i - fm;
            self.c[j * self.s + j]
        }
    }
}

/// The lower-triangular CSC pattern of the arrowhead, its symbolic Cholesky (computed
/// once), and the value slots of the diagonal.
pub struct ArrowSolver {
    n: usize,
    col_ptr: Vec<u32>,
    row_idx: Vec<u32>,
    values: Vec<f64>,
    symbolic: SymbolicLlt<u32>,
    scaling: Vec<f64>,
}

impl ArrowSolver {
    /// Builds the pattern and its symbolic factorisation.
    ///
    /// # Errors
    /// [`Error::TooManyPoints`] when the system is too large for 32-bit indices.
    pub fn new(frames: usize, m: usize, s: usize) -> Result<Self> {
        let n = frames * m + s;
        let fm = frames * m;
        let nnz = frames * (m * (m + 1) / 2 + m * s) + s * (s + 1) / 2;
        if nnz >= u32::MAX as usize {
            return Err(Error::TooManyPoints {
                argument: "normal matrix",
                got: nnz,
                max: u32::MAX as usize,
            });
        }
        let mut col_ptr = Vec::with_capacity(n + 1);
        let mut row_idx = Vec::with_capacity(nnz);
        col_ptr.push(0u32);
        for col in 0..n {
            if col < fm {
                let end = (col / m + 1) * m;
                row_idx.extend((col..end).map(|r| r as u32));
                row_idx.extend((fm..n).map(|r| r as u32));
            } else {
                row_idx.extend((col..n).map(|r| r as u32));
            }
            col_ptr.push(row_idx.len() as u32);
        }
        let pattern = SymbolicSparseColMatRef::new_checked(n, n, &col_ptr, None, &row_idx);
        let symbolic =
            SymbolicLlt::try_new(pattern, Side::Lower).map_err(|_| Error::TooManyPoints {
                argument: "normal matrix",
                got: nnz,
                max: u32::MAX as usize,
            })?;
        Ok(Self {
            n,
            values: vec![0.0; row_idx.len()],
            col_ptr,
            row_idx,
            symbolic,
            scaling: vec![0.0; n],
        })
    }

    /// The Marquardt scaling `D` of the last solve (the floored diagonal of `A`).
    pub fn scaling(&self) -> &[f64] {
        &self.scaling
    }

    /// Solves `(A + λ D) δ = -g`; `None` when the damped matrix is not positive definite.
    pub fn solve(&mut self, normal: &ArrowNormal, lambda: f64) -> Option<Vec<f64>> {
        let (frames, m, s) = (normal.frames, normal.m, normal.s);
        let fm = frames * m;
        let largest = (0..self.n)
            .map(|i| normal.diagonal(i))
            .fold(0.0f64, f64::max);
        // A parameter no residual depends on has a zero column; the floor keeps the system
        // definite and its step zero (its gradient is zero too).
        let floor = 1e-9 * largest.max(f64::MIN_POSITIVE);
        for i in 0..self.n {
            self.scaling[i] = normal.diagonal(i).max(floor);
        }
        let mut at = 0;
        for col in 0..self.n {
            if col < fm {
                let (f, j) = (col / m, col % m);
                let a = &normal.a[f * m * m..(f + 1) * m * m];
                for r in j..m {
                    self.values[at] = a[r * m + j];
                    at += 1;
                }
                let b = &normal.b[f * m * s..(f + 1) * m * s];
                for r in 0..s {
                    self.values[at] = b[j * s + r];
                    at += 1;
                }
            } else {
                let j = col - fm;
                for r in j..s {
                    self.values[at] = normal.c[r * s + j];
                    at += 1;
                }
            }
            // The first entry of each column is its diagonal.
            let diagonal = self.col_ptr[col] as usize;
            self.values[diagonal] += lambda * self.scaling[col];
        }
        let pattern = SymbolicSparseColMatRef::new_checked(
            self.n,
            self.n,
            &self.col_ptr,
            None,
            &self.row_idx,
        );
        let matrix = SparseColMatRef::new(pattern, &self.values);
        let llt = Llt::try_new_with_symbolic(self.symbolic.clone(), matrix, Side::Lower).ok()?;
        let mut step: Vec<f64> = normal.g.iter().map(|g| -g).collect();
        llt.solve_in_place(MatMut::from_column_major_slice_mut(&mut step, self.n, 1));
        step.iter().all(|v| v.is_finite()).then_some(step)
    }
}
