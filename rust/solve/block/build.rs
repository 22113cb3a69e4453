//! Constructors of [`BlockCsr`]: from a scalar CSR matrix (grouping $B \times B$ blocks),
//! from node adjacency lists, and from EFG neighbourhoods (the stiffness pattern).

use std::sync::Arc;

use rayon::prelude::*;

use super::scan::{non_finite_row, scan};
use super::{BlockCsr, Pattern};
use crate::efg::Csr;
use crate::error::{Error, Result};

/// An integer type CSR arrays may use for their indices.
pub trait CsrIndex: Copy + Send + Sync {
    /// The index as `usize`, `None` if it is negative or does not fit.
    fn get(self) -> Option<usize>;
}

impl CsrIndex for usize {
    fn get(self) -> Option<usize> {
        Some(self)
    }
}

impl CsrIndex for u32 {
    fn get(self) -> Option<usize> {
        usize::try_from(self).ok()
    }
}

impl CsrIndex for i32 {
    fn get(self) -> Option<usize> {
        usize::try_from(self).ok()
    }
}

impl CsrIndex for i64 {
    fn get(self) -> Option<usize> {
        usize::try_from(self).ok()
    }
}

/// Sorts and deduplicates each row, adding its own index.
fn finish_rows(rows: &mut [Vec<u32>]) {
    rows.par_iter_mut().enumerate().for_each(|(i, row)| {
        row.push(i as u32);
        row.sort_unstable();
        row.dedup();
    });
}

impl<const B: usize> BlockCsr<B> {
    /// Groups a scalar CSR matrix (columns sorted within rows) into $B \times B$ blocks. A
    /// block is stored when any of its scalar entries is; entries missing inside a stored
    /// block are zero, and a missing diagonal block is stored as zeros.
    ///
    /// # Errors
    /// [`Error::Empty`]; [`Error::BlockSize`] unless the size is a multiple of $B$;
    /// [`Error::SparsePattern`] for a malformed CSR (indptr, unsorted or out-of-range
    /// columns) or a block pattern that is not symmetric; [`Error::NonFinite`].
    pub fn from_csr(csr: &Csr) -> Result<Self> {
        Self::from_csr_parts(csr.size, &csr.indptr, &csr.indices, &csr.data)
    }

    /// [`Self::from_csr`] from borrowed CSR arrays with any integer index type (scipy's
    /// `int32` / `int64` arrays are read in place).
    ///
    /// # Errors
    /// As [`Self::from_csr`]; negative indices are out of range.
    pub fn from_csr_parts<I: CsrIndex>(
        size: usize,
        indptr: &[I],
        indices: &[I],
        data: &[f64],
    ) -> Result<Self> {
        let () = Self::CHECK;
        let argument = "matrix";
        let scan = scan::<I, B>(argument, size, indptr, indices, data.len())?;
        if let Some(row) = non_finite_row(&scan.indptr, data) {
            return Err(Error::NonFinite { argument, row });
        }
        let n = size / B;
        let (indptr, rows) = (&scan.indptr, scan.rows);
        let mut this = Self::zeros(Pattern::from_rows(argument, rows)?);
        // Each block row's blocks are a disjoint slice of the output: fill them in place.
        let p = Arc::clone(&this.pattern);
        let mut rest = this.blocks.as_mut_slice();
        let mut row_blocks = Vec::with_capacity(n);
        for i in 0..n {
            let (row, tail) = rest.split_at_mut(p.indptr[i + 1] - p.indptr[i]);
            row_blocks.push(row);
            rest = tail;
        }
        row_blocks
            .into_par_iter()
            .enumerate()
            .for_each(|(i, blocks)| {
                let columns = &p.indices[p.indptr[i]..p.indptr[i + 1]];
                for r in i * B..(i + 1) * B {
                    let mut pos = 0;
                    let span = indptr[r]..indptr[r + 1];
                    for (c, &value) in scan.indices[span.clone()].iter().zip(&data[span]) {
                        let c = c.get().unwrap_or(0);
                        while (columns[pos] as usize) < c / B {
                            pos += 1;
                        }
                        blocks[pos][r % B][c % B] = value;
                    }
                }
            });
        Ok(this)
    }

    /// A zero matrix whose pattern is the symmetric closure of `adjacency` (node `i` is
    /// coupled to every node of `adjacency[i]` and they to it) plus the diagonal.
    ///
    /// # Errors
    /// [`Error::Empty`]; [`Error::NodeIndex`] for an index `>= adjacency.len()`.
    pub fn from_pattern<R: AsRef<[u32]>>(adjacency: &[R]) -> Result<Self> {
        let () = Self::CHECK;
        let n = adjacency.len();
        if n == 0 {
            return Err(Error::Empty {
                argument: "adjacency",
                needed: 1,
            });
        }
        let mut rows: Vec<Vec<u32>> = adjacency.iter().map(|r| r.as_ref().to_vec()).collect();
        for (i, row) in adjacency.iter().enumerate() {
            for &j in row.as_ref() {
                if j as usize >= n {
                    return Err(Error::NodeIndex {
                        argument: "adjacency",
                        position: i,
                        index: j as usize,
                        n,
                    });
                }
                rows[j as usize].push(i as u32);
            }
        }
        finish_rows(&mut rows);
        Ok(Self::zeros(Pattern::from_rows("adjacency", rows)?))
    }

    /// A zero matrix with the pattern of the EFG stiffness: nodes `i` and `j` are coupled
    /// when one neighbourhood holds both. `neighbors` is row-major `(n, k)`.
    ///
    /// # Errors
    /// [`Error::Empty`]; [`Error::LengthMismatch`] unless `neighbors` holds `n * k`
    /// entries; [`Error::NodeIndex`] for an index `>= n`.
    pub fn from_neighborhoods(n: usize, neighbors: &[u32], k: usize) -> Result<Self> {
        let () = Self::CHECK;
        if n == 0 || k == 0 {
            return Err(Error::Empty {
                argument: "neighbors",
                needed: 1,
            });
        }
        if neighbors.len() != n * k {
            return Err(Error::LengthMismatch {
                argument: "neighbors",
                expected: n,
                got: neighbors.len() / k,
            });
        }
        if let Some(position) = neighbors.par_iter().position_first(|&i| i as usize >= n) {
            return Err(Error::NodeIndex {
                argument: "neighbors",
                position,
                index: neighbors[position] as usize,
                n,
            });
        }
        // Neighbourhoods holding each node, then per node the union of those.
        let mut start = vec![0usize; n + 1];
        for &i in neighbors {
            start[i as usize + 1] += 1;
        }
        for i in 0..n {
            start[i + 1] += start[i];
        }
        let mut fill = start.clone();
        let mut holders = vec![0u32; neighbors.len()];
        for (at, &i) in neighbors.iter().enumerate() {
            holders[fill[i as usize]] = (at / k) as u32;
            fill[i as usize] += 1;
        }
        let mut rows: Vec<Vec<u32>> = (0..n)
            .into_par_iter()
            .map(|i| {
                holders[start[i]..start[i + 1]]
                    .iter()
                    .flat_map(|&q| &neighbors[q as usize * k..(q as usize + 1) * k])
                    .copied()
                    .collect()
            })
            .collect();
        finish_rows(&mut rows);
        Ok(Self::zeros(Pattern::from_rows("neighbors", rows)?))
    }
}
