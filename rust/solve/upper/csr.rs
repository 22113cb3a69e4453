//! The upper triangle read straight from scalar CSR arrays (scipy's), for block-Jacobi
//! conjugate gradients from Python: no full [`super::BlockCsr`] in between. The full
//! matrix (15 MB at the paper's size) and then its upper copy were two fresh allocations
//! written once each; this writes the upper blocks only, in one pass that also checks the
//! values (benches/README.md, session 4).

use rayon::prelude::*;

use super::Upper;
use crate::error::{Error, Result};
use crate::solve::block::scan::{scan, Scan};
use crate::solve::block::{asymmetric_row, Block, CsrIndex};

/// Writes the entries of block row `i`'s upper blocks into `out` (its slice of the upper
/// blocks, columns `upper`) with `set(block, a, b, value)`; `Err(row)` for the first scalar
/// row of the block row holding a non-finite value (in either triangle).
fn fill_row<I: CsrIndex, T, const B: usize>(
    scan: &Scan<'_, I>,
    data: &[f64],
    i: usize,
    upper: &[u32],
    out: &mut [T],
    set: impl Fn(&mut T, usize, usize, f64),
) -> std::result::Result<(), usize> {
    for r in i * B..(i + 1) * B {
        let span = scan.indptr[r]..scan.indptr[r + 1];
        if !data[span.clone()].iter().all(|v| v.is_finite()) {
            return Err(r);
        }
        let columns = &scan.indices[span.clone()];
        let first = columns.partition_point(|c| c.get().unwrap_or(0) < i * B);
        let mut pos = 0;
        for (c, &value) in columns[first..]
            .iter()
            .zip(&data[span.start + first..span.end])
        {
            let c = c.get().unwrap_or(0);
            while (upper[pos] as usize) < c / B {
                pos += 1;
            }
            set(&mut out[pos], r % B, c % B, value);
        }
    }
    Ok(())
}

/// Fills `blocks` (one per upper block) block row by block row in parallel; the first
/// scalar row with a non-finite value, if any.
fn fill<I: CsrIndex, T: Send, const B: usize>(
    scan: &Scan<'_, I>,
    data: &[f64],
    indptr: &[usize],
    indices: &[u32],
    blocks: &mut [T],
    set: impl Fn(&mut T, usize, usize, f64) + Sync,
) -> Option<usize> {
    let mut rest = blocks;
    let mut rows = Vec::with_capacity(indptr.len() - 1);
    for w in indptr.windows(2) {
        let (row, tail) = rest.split_at_mut(w[1] - w[0]);
        rows.push(row);
        rest = tail;
    }
    rows.into_par_iter()
        .with_min_len(16)
        .enumerate()
        .map(|(i, out)| {
            fill_row::<I, T, B>(scan, data, i, &indices[indptr[i]..indptr[i + 1]], out, &set)
        })
        .find_first(|r| r.is_err())
        .and_then(|r| r.err())
}

impl<const B: usize> Upper<B> {
    /// The upper triangle of the scalar CSR matrix (columns sorted within rows) grouped
    /// into $B \times B$ blocks, exactly as [`super::BlockCsr::from_csr_parts`] followed by
    /// [`Self::load`] would give it.
    ///
    /// # Errors
    /// As [`super::BlockCsr::from_csr_parts`], in the same order.
    pub(in crate::solve) fn from_csr_parts<I: CsrIndex>(
        size: usize,
        indptr: &[I],
        indices: &[I],
        data: &[f64],
    ) -> Result<Self> {
        let argument = "matrix";
        let scan = scan::<I, B>(argument, size, indptr, indices, data.len())?;
        let n = size / B;
        let mut this = Self::default();
        this.indptr.reserve(n + 1);
        this.indptr.push(0);
        for (i, row) in scan.rows.iter().enumerate() {
            let first = row.partition_point(|&j| (j as usize) < i);
            this.indices.extend_from_slice(&row[first..]);
            this.indptr.push(this.indices.len());
        }
        let (up_ptr, up_idx) = (&this.indptr, &this.indices);
        this.blocks = vec![[[0.0; B]; B]; up_idx.len()];
        let set = |m: &mut Block<B>, a: usize, b: usize, v| m[a][b] = v;
        let non_finite = fill::<I, Block<B>, B>(&scan, data, up_ptr, up_idx, &mut this.blocks, set);
        if let Some(row) = non_finite {
            return Err(Error::NonFinite { argument, row });
        }
        if let Some(row) = asymmetric_row(n, |i| &scan.rows[i]) {
            return Err(Error::SparsePattern {
                argument,
                row,
                reason: "the pattern is not symmetric (an entry (i, j) has no (j, i))",
            });
        }
        this.split(n);
        this.finish();
        Ok(this)
    }
}
