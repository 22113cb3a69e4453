//! Checks of scalar CSR arrays and their grouping into block rows, shared by
//! [`super::BlockCsr::from_csr_parts`] and the upper triangle read straight from CSR
//! (`Pcg::solve_csr_parts`).
//!
//! One pass over the column indices checks them (sorted, unique, in range) and collects the
//! block columns of each block row; the values are checked for finiteness where they are
//! copied. Three separate passes (checks, finiteness, grouping) cost ~3x the memory
//! traffic (benches/README.md, session 4).

use rayon::prelude::*;

use super::CsrIndex;
use crate::error::{Error, Result};

/// Scalar CSR arrays that passed the structural checks, grouped into block rows.
pub(in crate::solve) struct Scan<'a, I> {
    /// `(size + 1,)` scalar row pointers.
    pub indptr: Vec<usize>,
    /// The column index of each entry (checked: sorted, unique, `< size` within each row).
    pub indices: &'a [I],
    /// Sorted block columns of each block row (the union over its `B` scalar rows), the
    /// diagonal included.
    pub rows: Vec<Vec<u32>>,
}

/// The first scalar row holding a non-finite entry, if any.
pub(in crate::solve) fn non_finite_row(indptr: &[usize], data: &[f64]) -> Option<usize> {
    // Chunks, not entries, as rayon's unit: position_first costs an atomic check per
    // item (~40 ms for the 1.9 M entries of the paper's system, measured).
    let chunk = 1 << 14;
    data.par_chunks(chunk)
        .position_first(|c| !c.iter().all(|v| v.is_finite()))
        .map(|c| {
            let at = c * chunk
                + data[c * chunk..]
                    .iter()
                    .position(|v| !v.is_finite())
                    .unwrap_or(0);
            indptr.partition_point(|&p| p <= at) - 1
        })
}

/// Checks the CSR arrays of a `size x size` matrix of `B x B` blocks and groups them.
///
/// # Errors
/// [`Error::Empty`]; [`Error::BlockSize`]; [`Error::TooManyPoints`];
/// [`Error::SparsePattern`] for a malformed CSR (indptr, unsorted or out-of-range columns).
pub(in crate::solve) fn scan<'a, I: CsrIndex, const B: usize>(
    argument: &'static str,
    size: usize,
    indptr: &[I],
    indices: &'a [I],
    data_len: usize,
) -> Result<Scan<'a, I>> {
    if size == 0 {
        return Err(Error::Empty {
            argument,
            needed: 1,
        });
    }
    if !size.is_multiple_of(B) {
        return Err(Error::BlockSize {
            argument,
            size,
            block: B,
        });
    }
    if size / B > u32::MAX as usize {
        return Err(Error::TooManyPoints {
            argument,
            got: size / B,
            max: u32::MAX as usize,
        });
    }
    let bad = |row, reason| Error::SparsePattern {
        argument,
        row,
        reason,
    };
    if indptr.len() != size + 1 {
        return Err(bad(0, "indptr must have size + 1 entries"));
    }
    let indptr: Vec<usize> = indptr
        .iter()
        .map(|p| p.get())
        .collect::<Option<_>>()
        .ok_or_else(|| bad(0, "indptr holds a negative entry"))?;
    if indptr[0] != 0 || indices.len() != data_len || indptr[size] != indices.len() {
        return Err(bad(
            size,
            "indptr must start at 0 and end at the length of indices and data",
        ));
    }
    if let Some(row) = (0..size).find(|&r| indptr[r] > indptr[r + 1]) {
        return Err(bad(row, "indptr decreases"));
    }
    // Block columns of scalar row r, or Err(r) if its columns are not sorted, unique and
    // in range.
    let block_columns = |r: usize| -> std::result::Result<Vec<u32>, usize> {
        let mut columns: Vec<u32> = Vec::with_capacity((indptr[r + 1] - indptr[r]) / B + 1);
        let mut last = None;
        for c in &indices[indptr[r]..indptr[r + 1]] {
            match c.get() {
                Some(c) if c < size && last.is_none_or(|l| l < c) => {
                    last = Some(c);
                    let j = (c / B) as u32;
                    if columns.last() != Some(&j) {
                        columns.push(j);
                    }
                }
                _ => return Err(r),
            }
        }
        Ok(columns)
    };
    let n = size / B;
    let rows: Vec<std::result::Result<Vec<u32>, usize>> = (0..n)
        .into_par_iter()
        .with_min_len(16)
        .map(|i| {
            // The rows of a block row usually share their column indices: then one of them
            // is checked and grouped, the others only compared with it (3x less work).
            let mut columns = block_columns(i * B)?;
            let first = &indices[indptr[i * B]..indptr[i * B + 1]];
            for r in i * B + 1..(i + 1) * B {
                let same = indices[indptr[r]..indptr[r + 1]]
                    .iter()
                    .map(|c| c.get())
                    .eq(first.iter().map(|c| c.get()));
                if same {
                    continue;
                }
                let other = block_columns(r)?;
                if other != columns {
                    columns.extend(other);
                    columns.sort_unstable();
                    columns.dedup();
                }
            }
            if let Err(at) = columns.binary_search(&(i as u32)) {
                columns.insert(at, i as u32);
            }
            Ok(columns)
        })
        .collect();
    let rows = rows
        .into_iter()
        .collect::<std::result::Result<Vec<_>, usize>>()
        .map_err(|row| bad(row, "columns must be sorted, unique and in 0..size"))?;
    Ok(Scan {
        indptr,
        indices,
        rows,
    })
}
