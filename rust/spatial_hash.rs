//! Neighbour search by spatial hashing: k nearest neighbours and fixed-radius neighbours of
//! 2-D and 3-D point clouds.
//!
//! A uniform grid hash in the style of Teschner et al. 2003 ("Optimized spatial hashing for
//! collision detection of deformable objects"), made robust to non-uniform clouds:
//!
//! * points are sorted by the Morton code of their cell on a fine grid ($2^{21}$ cells per
//!   axis in 3-D), so each cell of every coarser level (cell edge doubled per level) is a
//!   contiguous run of the sorted array;
//! * the level a query searches is picked from the data: the one whose cells hold, for a
//!   typical point, a number of points proportional to $k$ (or whose cells are just larger
//!   than the search radius); its cells are found through a hash table, in rings around
//!   the query's cell;
//! * a query the rings do not settle (an outlier far from the bulk, say) falls back to a
//!   best-first walk down the implicit octree from its root, so no cloud shape makes the
//!   search quadratic.
//!
//! Points are stored once, in Morton order, for cache locality.

mod cell_table;
pub mod knn;
mod morton;
mod radius;

use std::sync::OnceLock;

use rayon::prelude::*;

use crate::error::{check_finite, Error, Result};
use cell_table::CellTable;

pub use knn::Knn;
pub use radius::RadiusNeighbors;

/// A walk down the octree stops subdividing cells holding this many points or fewer.
const LEAF_SIZE: usize = 32;

/// A spatial hash over a fixed set of `D`-dimensional points (`D` is 2 or 3), answering
/// k-nearest and fixed-radius queries in parallel.
pub struct SpatialHash<const D: usize> {
    /// Lower corner of the bounding box: finest cell `c` spans `origin + fine * [c, c + 1)`.
    origin: [f64; D],
    /// Edge of a finest-level cell.
    fine: f64,
    /// The points, in Morton order.
    points: Vec<[f64; D]>,
    /// `order[i]` is the caller's index of sorted point `i`.
    order: Vec<u32>,
    /// Finest cells per axis spanned by the points.
    cells: [u64; D],
    /// Morton code of the finest cell of each sorted point (ascending).
    codes: Vec<u64>,
    /// Per level: mean number of points sharing a cell with a point (point-weighted).
    occupancy: Vec<f64>,
    /// Per level: the hash table of its cells, built when a query first needs it.
    tables: Vec<OnceLock<CellTable>>,
}

/// Number of levels: level 0 is the finest grid, the last one a single cell (the root).
const fn levels(d: usize) -> usize {
    morton::bits_per_axis(d) as usize + 1
}

impl<const D: usize> SpatialHash<D> {
    /// Indexes `points`.
    ///
    /// # Errors
    /// [`Error::Empty`] for no points, [`Error::NonFinite`] for NaN or infinity,
    /// [`Error::TooManyPoints`] beyond $2^{32} - 1$ points.
    pub fn new(points: &[[f64; D]]) -> Result<Self> {
        const {
            assert!(
                D == 2 || D == 3,
                "spatial hashing is implemented in 2-D and 3-D"
            )
        };
        if points.is_empty() {
            return Err(Error::Empty {
                argument: "points",
                needed: 1,
            });
        }
        if points.len() >= u32::MAX as usize {
            return Err(Error::TooManyPoints {
                argument: "points",
                got: points.len(),
                max: u32::MAX as usize - 1,
            });
        }
        check_finite("points", points)?;

        let (lo, hi) = bounding_box(points);
        let extent = (0..D).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
        let cells = (1u64 << morton::bits_per_axis(D)) as f64;
        let fine = if extent > 0.0 { extent / cells } else { 1.0 };

        let mut keyed: Vec<(u64, u32)> = points
            .par_iter()
            .enumerate()
            .map(|(i, p)| (morton::encode(finest_cell(p, &lo, fine)), i as u32))
            .collect();
        keyed.par_sort_unstable();
        let codes: Vec<u64> = keyed.par_iter().map(|&(c, _)| c).collect();
        let order: Vec<u32> = keyed.par_iter().map(|&(_, i)| i).collect();
        let sorted = order.par_iter().map(|&i| points[i as usize]).collect();

        let cells = std::array::from_fn(|a| finest_cell(&hi, &lo, fine)[a] + 1);
        Ok(SpatialHash {
            origin: lo,
            cells,
            fine,
            points: sorted,
            occupancy: occupancy_by_level::<D>(&codes),
            order,
            codes,
            tables: (0..levels(D)).map(|_| OnceLock::new()).collect(),
        })
    }

    /// Number of indexed points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Always false: an index holds at least one point.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Cell edge at `level`.
    fn cell_size(&self, level: usize) -> f64 {
        self.fine * (1u64 << level) as f64
    }

    /// Edge of the cells that a k-nearest query for this `k` searches first.
    pub fn knn_cell_size(&self, k: usize) -> f64 {
        self.cell_size(self.knn_level(k))
    }

    fn table(&self, level: usize) -> &CellTable {
        self.tables[level]
            .get_or_init(|| CellTable::build::<D>(&self.codes, level as u32, self.cells))
    }

    /// Cell coordinates of `q` at `level` (may lie outside the grid for outside queries).
    fn cell_of(&self, q: &[f64; D], level: usize) -> [i64; D] {
        // Same arithmetic as the binning of the points (`finest_cell`), so a point and a
        // query at the same place agree on their cell, also on the upper faces of the box.
        const LIMIT: f64 = (1u64 << 62) as f64;
        let last = (1i64 << morton::bits_per_axis(D)) - 1;
        std::array::from_fn(|a| {
            let c = ((q[a] - self.origin[a]) / self.fine)
                .floor()
                .clamp(-LIMIT, LIMIT) as i64;
            (if c == last + 1 { last } else { c }) >> level
        })
    }

    /// Absolute slack on every geometric test that decides what may be skipped: a point
    /// on a cell face must not be lost to the rounding of the face's position (which is
    /// about an ulp of the coordinates, far below a finest cell).
    fn face_slack(&self) -> f64 {
        0.5 * self.fine
    }

    /// Cells per axis of the grid at `level`.
    fn cells_per_axis(&self, level: usize) -> i64 {
        1i64 << (morton::bits_per_axis(D) as usize - level)
    }

    /// The cell at integer coordinates `c` of `level`, if it lies inside the grid.
    fn grid_cell(&self, c: [i64; D], level: usize) -> Option<[u64; D]> {
        let limit = self.cells_per_axis(level);
        c.iter()
            .all(|&v| (0..limit).contains(&v))
            .then(|| c.map(|v| v as u64))
    }

    /// Squared distance from `q` to the box of the cell `coords` at `level`.
    fn box_distance2(&self, q: &[f64; D], coords: [u64; D], level: usize) -> f64 {
        let h = self.cell_size(level);
        (0..D)
            .map(|a| {
                let lo = self.origin[a] + coords[a] as f64 * h;
                let d = ((lo - q[a]).max(q[a] - (lo + h)) - self.face_slack()).max(0.0);
                d * d
            })
            .sum()
    }

    /// Splits the run `[start, end)` of a cell with Morton prefix `prefix` at `level` into
    /// its non-empty children at `level - 1`: calls `visit(child_prefix, start, end)`.
    fn for_children(
        &self,
        prefix: u64,
        level: usize,
        start: usize,
        end: usize,
        mut visit: impl FnMut(u64, usize, usize),
    ) {
        let shift = D * (level - 1);
        let mut s = start;
        for child in 0..(1u64 << D) {
            if s == end {
                break;
            }
            let child_prefix = prefix << D | child;
            let e = s + self.codes[s..end].partition_point(|&c| c >> shift <= child_prefix);
            if e > s {
                visit(child_prefix, s, e);
            }
            s = e;
        }
    }

    /// `position[caller_index]`: where each of the caller's points sits in Morton order.
    fn inverse_order(&self) -> Vec<u32> {
        let mut position = vec![0u32; self.len()];
        for (pos, &i) in self.order.iter().enumerate() {
            position[i as usize] = pos as u32;
        }
        position
    }

    #[inline]
    fn distance2(&self, i: usize, q: &[f64; D]) -> f64 {
        let p = &self.points[i];
        (0..D).map(|a| (p[a] - q[a]) * (p[a] - q[a])).sum()
    }
}

/// Queries must be a non-empty set of finite points.
fn check_queries<const D: usize>(queries: &[[f64; D]]) -> Result<()> {
    if queries.is_empty() {
        return Err(Error::Empty {
            argument: "queries",
            needed: 1,
        });
    }
    check_finite("queries", queries)
}

fn bounding_box<const D: usize>(points: &[[f64; D]]) -> ([f64; D], [f64; D]) {
    points
        .par_iter()
        .fold(
            || ([f64::INFINITY; D], [f64::NEG_INFINITY; D]),
            |(mut lo, mut hi), p| {
                for a in 0..D {
                    lo[a] = lo[a].min(p[a]);
                    hi[a] = hi[a].max(p[a]);
                }
                (lo, hi)
            },
        )
        .reduce(
            || ([f64::INFINITY; D], [f64::NEG_INFINITY; D]),
            |(l1, h1), (l2, h2)| {
                (
                    std::array::from_fn(|a| l1[a].min(l2[a])),
                    std::array::from_fn(|a| h1[a].max(h2[a])),
                )
            },
        )
}

fn finest_cell<const D: usize>(p: &[f64; D], origin: &[f64; D], fine: f64) -> [u64; D] {
    let max = (1u64 << morton::bits_per_axis(D)) - 1;
    std::array::from_fn(|a| (((p[a] - origin[a]) / fine).floor() as u64).min(max))
}

/// Point-weighted mean cell occupancy of every level, in one pass over the sorted codes:
/// consecutive codes first differing in bit `b` start a new cell at levels `0..=b / D`.
fn occupancy_by_level<const D: usize>(codes: &[u64]) -> Vec<f64> {
    let n = codes.len();
    let mut sum_squares = vec![0f64; levels(D)];
    let mut run_start = vec![0usize; levels(D)];
    for i in 1..=n {
        let top = if i == n {
            levels(D) - 1
        } else {
            let diff = codes[i - 1] ^ codes[i];
            if diff == 0 {
                continue;
            }
            (63 - diff.leading_zeros() as usize) / D
        };
        for level in 0..=top {
            let len = (i - run_start[level]) as f64;
            sum_squares[level] += len * len;
            run_start[level] = i;
        }
    }
    sum_squares.into_iter().map(|s| s / n as f64).collect()
}

/// A row-major output whose rows parallel tasks fill in an order only known at run time
/// (self-queries run in Morton order but write to their caller's row).
struct DisjointRows<'a, T> {
    data: *mut T,
    rows: usize,
    row_len: usize,
    _borrow: std::marker::PhantomData<&'a mut [T]>,
}

// SAFETY: the pointer comes from a `&mut [T]` held for 'a; `row` hands out each row to one
// writer only (its caller's contract), so sharing the writer across threads is sound.
unsafe impl<T: Send> Sync for DisjointRows<'_, T> {}

impl<'a, T> DisjointRows<'a, T> {
    fn new(data: &'a mut [T], row_len: usize) -> Self {
        DisjointRows {
            data: data.as_mut_ptr(),
            rows: data.len() / row_len,
            row_len,
            _borrow: std::marker::PhantomData,
        }
    }

    /// Row `r`.
    ///
    /// # Safety
    /// No two live borrows may be of the same row.
    #[allow(clippy::mut_from_ref)]
    unsafe fn row(&self, r: usize) -> &mut [T] {
        assert!(r < self.rows, "row {r} out of {}", self.rows);
        // SAFETY: in bounds by the assertion; exclusive by the caller's contract.
        unsafe { std::slice::from_raw_parts_mut(self.data.add(r * self.row_len), self.row_len) }
    }
}

/// Offsets of the cells on the shell of Chebyshev radius `r` (at most 2) around a cell,
/// nearest first. Stored 3-D; in 2-D the third offset is zero and unused.
fn ring_offsets<const D: usize>(r: usize) -> &'static [[i64; 3]] {
    const R: i64 = 2;
    static SHELLS: [OnceLock<Vec<Vec<[i64; 3]>>>; 2] = [OnceLock::new(), OnceLock::new()];
    let shells = SHELLS[D - 2].get_or_init(|| {
        let mut shells = vec![Vec::new(); R as usize + 1];
        let side = (2 * R + 1) as usize;
        for n in 0..side.pow(D as u32) {
            let mut offset = [0i64; 3];
            for (a, o) in offset.iter_mut().enumerate().take(D) {
                *o = (n / side.pow(a as u32) % side) as i64 - R;
            }
            let ring = offset.iter().map(|v| v.abs()).max().unwrap_or(0);
            shells[ring as usize].push(offset);
        }
        for shell in &mut shells {
            shell.sort_by_key(|o| o.iter().map(|v| v * v).sum::<i64>());
        }
        shells
    });
    &shells[r]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn occupancy_counts_points_per_cell() {
        // Two points in one finest cell, one alone: point-weighted mean = (2*2 + 1) / 3.
        let codes = [5u64, 5, 1 << 40];
        let occ = occupancy_by_level::<3>(&codes);
        assert!((occ[0] - 5.0 / 3.0).abs() < 1e-15);
        assert!((occ[levels(3) - 1] - 3.0).abs() < 1e-15);
    }

    #[test]
    fn rejects_bad_points() {
        assert!(matches!(
            SpatialHash::<3>::new(&[]),
            Err(Error::Empty { .. })
        ));
        assert!(matches!(
            SpatialHash::<2>::new(&[[0.0, 1.0], [f64::NAN, 0.0]]),
            Err(Error::NonFinite { row: 1, .. })
        ));
    }
}
