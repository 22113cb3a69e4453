//! The upper triangle read straight from scalar CSR arrays (scipy's), for block-Jacobi
//! conjugate gradients from Python: no full [`super::BlockCsr`] in between. The full
//! matrix (15 MB at the paper's size) and then its upper copy were two fresh allocations
//! written once each; this writes the upper blocks only, in one pass that also checks the
//! values (benches/README.md, session 4).

use std::mem::MaybeUninit;

use rayon::prelude::*;

use super::{wide, Upper};
use crate::error::{Error, Result};
use crate::solve::block::scan::{scan, Scan};
use crate::solve::block::{asymmetric_row, Block, CsrIndex};

/// Writes block row `i`'s upper blocks (columns `upper`) into `out`, zeros first, and
/// their float32 copy into `narrow` when given; `Err(row)` for the first scalar row of the
/// block row holding a non-finite value (in either triangle), else whether every value
/// fits in float32.
fn fill_row<I: CsrIndex, const B: usize>(
    scan: &Scan<'_, I>,
    data: &[f64],
    i: usize,
    upper: &[u32],
    out: &mut [MaybeUninit<Block<B>>],
    narrow: Option<&mut [MaybeUninit<f32>]>,
) -> std::result::Result<bool, usize> {
    // Zeroed here, in cache, rather than by a pass over the whole array beforehand.
    for block in out.iter_mut() {
        block.write([[0.0; B]; B]);
    }
    // SAFETY: every element was just initialised; MaybeUninit<T> has T's layout.
    let out = unsafe { &mut *(out as *mut [MaybeUninit<Block<B>>] as *mut [Block<B>]) };
    for r in i * B..(i + 1) * B {
        let span = scan.indptr[r]..scan.indptr[r + 1];
        // A fold, not `all`: no early exit, so it vectorises.
        if !data[span.clone()]
            .iter()
            .fold(true, |ok, v| ok & v.is_finite())
        {
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
            out[pos][r % B][c % B] = value;
        }
    }
    let mut fits = true;
    if let Some(narrow) = narrow {
        for (n, &v) in narrow.iter_mut().zip(out.as_flattened().as_flattened()) {
            let v = v as f32;
            fits &= v.is_finite();
            n.write(v);
        }
    }
    Ok(fits)
}

/// Splits `all` into one slice per block row of `indptr` (`per_block` elements per block).
fn per_row<'a, T>(mut all: &'a mut [T], indptr: &[usize], per_block: usize) -> Vec<&'a mut [T]> {
    let mut rows = Vec::with_capacity(indptr.len() - 1);
    for w in indptr.windows(2) {
        let (row, tail) = std::mem::take(&mut all).split_at_mut((w[1] - w[0]) * per_block);
        rows.push(row);
        all = tail;
    }
    rows
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
        let count = up_idx.len();
        // The AVX2 kernel's copies end with one zero block past the last.
        let fast = B == 3 && wide::available();
        let mut blocks: Vec<Block<B>> = Vec::with_capacity(count + 1);
        let mut narrow: Vec<f32> = Vec::with_capacity(if fast { (count + 1) * B * B } else { 0 });
        let block_rows = per_row(&mut blocks.spare_capacity_mut()[..count], up_ptr, 1);
        let narrow_rows: Vec<Option<&mut [MaybeUninit<f32>]>> = if fast {
            let spare = &mut narrow.spare_capacity_mut()[..count * B * B];
            per_row(spare, up_ptr, B * B)
                .into_iter()
                .map(Some)
                .collect()
        } else {
            (0..n).map(|_| None).collect()
        };
        let filled = block_rows
            .into_par_iter()
            .zip(narrow_rows)
            .with_min_len(16)
            .enumerate()
            .map(|(i, (out, narrow))| {
                let upper = &up_idx[up_ptr[i]..up_ptr[i + 1]];
                fill_row::<I, B>(&scan, data, i, upper, out, narrow)
            })
            .try_fold(|| true, |all, r| r.map(|fits| all && fits))
            .try_reduce(|| true, |a, b| Ok(a && b));
        let fits = match filled {
            Ok(fits) => fits,
            // The first non-finite row, as `BlockCsr::from_csr_parts` reports it.
            Err(_) => {
                let row = super::super::block::scan::non_finite_row(&scan.indptr, data);
                return Err(Error::NonFinite {
                    argument,
                    row: row.unwrap_or(0),
                });
            }
        };
        // SAFETY: `fill_row` initialised every block (and every float32 value when fast).
        unsafe {
            blocks.set_len(count);
            if fast {
                narrow.set_len(count * B * B);
            }
        }
        this.blocks = blocks;
        if let Some(row) = asymmetric_row(n, |i| &scan.rows[i]) {
            return Err(Error::SparsePattern {
                argument,
                row,
                reason: "the pattern is not symmetric (an entry (i, j) has no (j, i))",
            });
        }
        this.split(n);
        this.fast = fast;
        if fast {
            this.blocks.push([[0.0; B]; B]);
            narrow.resize((count + 1) * B * B, 0.0);
            if fits {
                this.narrow = narrow;
            }
        }
        Ok(this)
    }
}
