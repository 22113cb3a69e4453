//! k nearest neighbours: rings of hashed cells first, a best-first octree walk when the
//! rings do not settle the query.

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use rayon::prelude::*;

use super::{check_queries, levels, morton, ring_offsets, DisjointRows, SpatialHash, LEAF_SIZE};
use crate::error::{Error, Result};

/// Rings of cells searched around a query before falling back to the octree walk.
const MAX_RINGS: i64 = 2;

/// The `k` nearest indexed points of every query.
#[derive(Debug, Clone)]
pub struct Knn {
    /// Neighbours per query.
    pub k: usize,
    /// Row-major `(queries, k)`: the caller's indices of the neighbours, nearest first.
    pub indices: Vec<i64>,
    /// Row-major `(queries, k)`: Euclidean distances, ascending.
    pub distances: Vec<f64>,
}

/// The best `k` candidates so far, sorted by (squared distance, caller index). A winner moves
/// in from the back like a step of insertion sort: for neighbourhood sizes this measured
/// about 3x faster than a binary heap followed by a sort (see benches/README.md), and the
/// result comes out sorted.
struct Nearest {
    k: usize,
    len: usize,
    items: Vec<(f64, u32)>,
    /// A known upper bound of the squared k-th distance: farther candidates are dropped.
    bound2: f64,
}

impl Nearest {
    fn new(k: usize) -> Self {
        Nearest {
            k,
            len: 0,
            items: vec![(0.0, 0); k],
            bound2: f64::INFINITY,
        }
    }

    /// Starts a query whose squared k-th distance is known to be at most `bound2`.
    fn reset(&mut self, bound2: f64) {
        self.len = 0;
        self.bound2 = bound2;
    }

    fn is_full(&self) -> bool {
        self.len == self.k
    }

    /// Squared distance of the k-th best, or the bound until k candidates are known.
    #[inline]
    fn worst2(&self) -> f64 {
        if self.is_full() {
            self.items[self.k - 1].0
        } else {
            self.bound2
        }
    }

    #[inline]
    fn offer(&mut self, d2: f64, i: u32) {
        let after = |e: &(f64, u32)| e.0 > d2 || (e.0 == d2 && e.1 > i);
        let mut at = if self.is_full() {
            if !after(&self.items[self.k - 1]) {
                return;
            }
            self.k - 1
        } else {
            if d2 > self.bound2 {
                return;
            }
            self.len += 1;
            self.len - 1
        };
        while at > 0 && after(&self.items[at - 1]) {
            self.items[at] = self.items[at - 1];
            at -= 1;
        }
        self.items[at] = (d2, i);
    }

    /// The candidates, nearest first.
    fn sorted(&self) -> &[(f64, u32)] {
        &self.items[..self.len]
    }
}

fn distance<const D: usize>(a: &[f64; D], b: &[f64; D]) -> f64 {
    (0..D)
        .map(|i| (a[i] - b[i]) * (a[i] - b[i]))
        .sum::<f64>()
        .sqrt()
}

/// A cell waiting in the best-first walk, ordered nearest first.
struct Pending {
    d2: f64,
    level: usize,
    prefix: u64,
    start: usize,
    end: usize,
}

impl PartialEq for Pending {
    fn eq(&self, other: &Self) -> bool {
        self.d2 == other.d2
    }
}
impl Eq for Pending {}
impl PartialOrd for Pending {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Pending {
    fn cmp(&self, other: &Self) -> Ordering {
        other.d2.total_cmp(&self.d2)
    }
}

impl<const D: usize> SpatialHash<D> {
    /// The `k` nearest indexed points of each query, or, when `queries` is `None`, of each
    /// indexed point excluding itself. Rows sorted by distance, ties by index order.
    ///
    /// # Errors
    /// [`Error::InvalidK`] unless `1 <= k <= n` (`n - 1` without queries),
    /// [`Error::Empty`] / [`Error::NonFinite`] for bad queries.
    pub fn knn(&self, queries: Option<&[[f64; D]]>, k: usize) -> Result<Knn> {
        let m = queries.map_or(self.len(), <[_]>::len);
        let mut indices = vec![0i64; m * k];
        let mut distances = vec![0.0; m * k];
        self.knn_into(queries, k, &mut indices, &mut distances)?;
        Ok(Knn {
            k,
            indices,
            distances,
        })
    }

    /// [`Self::knn`] writing into caller-provided row-major `(queries, k)` outputs (e.g.
    /// numpy's, which come on huge pages).
    ///
    /// # Errors
    /// As [`Self::knn`], and [`Error::OutputSize`] when an output has the wrong length.
    pub fn knn_into(
        &self,
        queries: Option<&[[f64; D]]>,
        k: usize,
        indices: &mut [i64],
        distances: &mut [f64],
    ) -> Result<()> {
        let m = self.check_knn(queries, k)?;
        let level = self.knn_level(k);
        self.table(level);
        for got in [indices.len(), distances.len()] {
            if got != m * k {
                return Err(Error::OutputSize {
                    expected: m * k,
                    got,
                });
            }
        }
        let index_rows = DisjointRows::new(indices, k);
        let distance_rows = DisjointRows::new(distances, k);

        // Self-queries run in Morton order (neighbouring queries touch the same cells), each
        // writing its result straight into its caller's row.
        const CHUNK: usize = 256;
        (0..m.div_ceil(CHUNK)).into_par_iter().for_each(|chunk| {
            let mut best = Nearest::new(k);
            let mut heap = BinaryHeap::new();
            let mut previous: Option<([f64; D], f64)> = None;
            for pos in chunk * CHUNK..((chunk + 1) * CHUNK).min(m) {
                let (q, skip, row) = match queries {
                    Some(q) => (&q[pos], None, pos),
                    None => (&self.points[pos], Some(pos), self.order[pos] as usize),
                };
                // The previous query's k neighbours (and itself) lie within its k-th
                // distance plus the step between the queries: a bound that lets the search
                // skip cells and candidates from the start. Consecutive self-queries are
                // Morton neighbours, so the bound is tight.
                let bound2 = match previous {
                    Some((p, dk)) => {
                        let b = (dk + distance(&p, q)) * (1.0 + 1e-9) + f64::MIN_POSITIVE;
                        b * b
                    }
                    None => f64::INFINITY,
                };
                self.nearest(q, level, skip, bound2, &mut best, &mut heap);
                previous = Some((*q, best.worst2().sqrt()));
                // SAFETY: `row` is `pos` or `order[pos]`, a permutation of `0..m`: every row
                // is written by exactly one iteration.
                let (out_i, out_d) = unsafe { (index_rows.row(row), distance_rows.row(row)) };
                for (j, &(d2, i)) in best.sorted().iter().enumerate() {
                    out_i[j] = i as i64;
                    out_d[j] = d2.sqrt();
                }
            }
        });
        Ok(())
    }

    /// Checks a k-nearest query before any work (or output allocation); returns the number
    /// of queries.
    ///
    /// # Errors
    /// [`Error::InvalidK`] unless `1 <= k <= n` (`n - 1` without queries),
    /// [`Error::Empty`] / [`Error::NonFinite`] for bad queries.
    pub fn check_knn(&self, queries: Option<&[[f64; D]]>, k: usize) -> Result<usize> {
        let n = self.len();
        let (max, note) = match queries {
            Some(_) => (n, ""),
            None => (n - 1, "; a point is not its own neighbour"),
        };
        if k == 0 || k > max {
            return Err(Error::InvalidK { k, max, note });
        }
        if let Some(q) = queries {
            check_queries(q)?;
        }
        Ok(queries.map_or(n, <[_]>::len))
    }

    /// The level whose cells are about as wide as the typical k-th neighbour distance.
    ///
    /// A cell of edge $h$ around a point holds $\lambda$ other points; on a cloud of
    /// effective dimension $m$ (3 for volumes, 2 for surfaces, 1 for curves, read off how
    /// $\lambda$ grows from level to level) the k-th neighbour distance is about $h$ when
    /// $\lambda \approx c_m k$, with $c_3 = 3 / (4 \pi)$ (cube vs. ball) and $c_2 \approx 0.5$,
    /// $c_1 \approx 0.6$ (a cell cuts about $1.5 h^2$ of a surface, $1.2 h$ of a curve).
    pub(super) fn knn_level(&self, k: usize) -> usize {
        let others = |level: usize| (self.occupancy[level] - 1.0).max(1e-9);
        let misfit = |level: usize| {
            let next = others((level + 1).min(levels(D) - 1));
            let dim = (next / others(level)).log2().clamp(1.0, D as f64);
            let per_neighbour = match dim {
                d if d > 2.5 => 3.0 / (4.0 * std::f64::consts::PI),
                d if d > 1.5 => 0.5,
                _ => 0.6,
            };
            (others(level) / (per_neighbour * k as f64)).ln().abs() / dim
        };
        (0..levels(D) - 1)
            .min_by(|&a, &b| misfit(a).total_cmp(&misfit(b)))
            .unwrap_or(0)
    }

    fn nearest(
        &self,
        q: &[f64; D],
        level: usize,
        skip: Option<usize>,
        bound2: f64,
        best: &mut Nearest,
        heap: &mut BinaryHeap<Pending>,
    ) {
        best.reset(bound2);
        if self.rings(q, level, skip, best) {
            return;
        }
        // Whatever the rings found bounds the k-th distance for the walk.
        best.reset(best.worst2());
        self.best_first(q, skip, best, heap);
    }

    /// Offers the points at sorted positions `start..end` (but `skip`) to `best`.
    #[inline]
    fn scan(
        &self,
        q: &[f64; D],
        start: usize,
        end: usize,
        skip: Option<usize>,
        best: &mut Nearest,
    ) {
        // Most candidates lose to the current k-th distance: test them against a local copy
        // in a tight loop and only touch the heap for the few that win.
        let mut worst2 = best.worst2();
        for (i, p) in (start..end).zip(&self.points[start..end]) {
            let d2: f64 = (0..D).map(|a| (p[a] - q[a]) * (p[a] - q[a])).sum();
            if d2 <= worst2 && Some(i) != skip {
                best.offer(d2, self.order[i]);
                worst2 = best.worst2();
            }
        }
    }

    /// Searches rings of cells around `q` at `level`; true once the k nearest are certain:
    /// the k-th distance is within the distance from `q` to the outside of the searched block.
    fn rings(&self, q: &[f64; D], level: usize, skip: Option<usize>, best: &mut Nearest) -> bool {
        const R: usize = MAX_RINGS as usize;
        let table = self.table(level);
        let home = self.cell_of(q, level);
        let h = self.cell_size(level);
        let limit = self.cells_per_axis(level);
        // Per axis and offset o in -R..=R: the squared gap from q to that slab of cells,
        // and whether the slab lies inside the grid. A cell's box distance is then a sum.
        let mut gap2 = [[0.0; 2 * R + 1]; D];
        let mut inside = [[false; 2 * R + 1]; D];
        let mut near_face = f64::INFINITY;
        for a in 0..D {
            let lo = self.origin[a] + home[a] as f64 * h;
            let (below, above) = (q[a] - lo, lo + h - q[a]);
            near_face = near_face.min(below).min(above);
            for o in -(R as i64)..=R as i64 {
                let gap = match o {
                    0 => 0.0,
                    o if o > 0 => (o - 1) as f64 * h + above,
                    o => (-o - 1) as f64 * h + below,
                };
                let slot = (o + R as i64) as usize;
                let gap = (gap - self.face_slack()).max(0.0);
                gap2[a][slot] = gap * gap;
                inside[a][slot] = (0..limit).contains(&(home[a] + o));
            }
        }
        for r in 0..=R {
            let visit = |offset: &[i64; 3], best: &mut Nearest| {
                let slot: [usize; D] = std::array::from_fn(|a| (offset[a] + R as i64) as usize);
                if !(0..D).all(|a| inside[a][slot[a]]) {
                    return;
                }
                // Cells beyond the current k-th distance cannot improve it.
                if r > 0 && (0..D).map(|a| gap2[a][slot[a]]).sum::<f64>() > best.worst2() {
                    return;
                }
                let cell: [u64; D] = std::array::from_fn(|a| (home[a] + offset[a]) as u64);
                if let Some((s, e)) = table.get(cell) {
                    self.scan(q, s as usize, e as usize, skip, best);
                }
            };
            if r <= 1 || !best.worst2().is_finite() {
                ring_offsets::<D>(r).iter().for_each(|o| visit(o, best));
            } else {
                // Only offsets whose slab along every axis is within the k-th distance can
                // hold a better point: enumerate that sub-box of the shell, not all of it.
                let worst2 = best.worst2();
                let r = r as i64;
                let mut lo = [0i64; 3];
                let mut hi = [0i64; 3];
                for a in 0..D {
                    let ok = |o: i64| gap2[a][(o + R as i64) as usize] <= worst2;
                    lo[a] = (-r..=0).find(|&o| ok(o)).unwrap_or(0);
                    hi[a] = (0..=r).rev().find(|&o| ok(o)).unwrap_or(0);
                }
                for x in lo[0]..=hi[0] {
                    for y in lo[1]..=hi[1] {
                        for z in lo[2]..=hi[2] {
                            if x.abs().max(y.abs()).max(z.abs()) == r {
                                visit(&[x, y, z], best);
                            }
                        }
                    }
                }
            }
            let margin = r as f64 * h + near_face - self.face_slack();
            if best.is_full() && margin > 0.0 && best.worst2() <= margin * margin {
                return true;
            }
        }
        false
    }

    /// Best-first walk down the implicit octree from the root, pruning cells farther than
    /// the current k-th distance (or than the bound `best` starts with).
    fn best_first(
        &self,
        q: &[f64; D],
        skip: Option<usize>,
        best: &mut Nearest,
        heap: &mut BinaryHeap<Pending>,
    ) {
        heap.clear();
        let root = levels(D) - 1;
        heap.push(Pending {
            d2: self.box_distance2(q, [0; D], root),
            level: root,
            prefix: 0,
            start: 0,
            end: self.len(),
        });
        while let Some(cell) = heap.pop() {
            let limit = best.worst2();
            if cell.d2 > limit {
                break;
            }
            if cell.end - cell.start <= LEAF_SIZE || cell.level == 0 {
                self.scan(q, cell.start, cell.end, skip, best);
                continue;
            }
            let level = cell.level - 1;
            self.for_children(
                cell.prefix,
                cell.level,
                cell.start,
                cell.end,
                |prefix, start, end| {
                    let d2 = self.box_distance2(q, morton::decode(prefix), level);
                    if d2 <= limit {
                        heap.push(Pending {
                            d2,
                            level,
                            prefix,
                            start,
                            end,
                        });
                    }
                },
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn brute<const D: usize>(
        points: &[[f64; D]],
        q: &[f64; D],
        k: usize,
        skip: Option<usize>,
    ) -> Vec<f64> {
        let mut d: Vec<f64> = points
            .iter()
            .enumerate()
            .filter(|(i, _)| Some(*i) != skip)
            .map(|(_, p)| (0..D).map(|a| (p[a] - q[a]).powi(2)).sum::<f64>().sqrt())
            .collect();
        d.sort_by(f64::total_cmp);
        d.truncate(k);
        d
    }

    fn check<const D: usize>(points: &[[f64; D]], k: usize) {
        let index = SpatialHash::new(points).unwrap();
        let knn = index.knn(None, k).unwrap();
        for (i, p) in points.iter().enumerate() {
            let want = brute(points, p, k, Some(i));
            let got = &knn.distances[i * k..(i + 1) * k];
            for (g, w) in got.iter().zip(&want) {
                assert!(
                    (g - w).abs() <= 1e-12 * (1.0 + w),
                    "point {i}: {got:?} vs {want:?}"
                );
            }
            assert!(knn.indices[i * k..(i + 1) * k]
                .iter()
                .all(|&j| j as usize != i));
        }
    }

    #[test]
    fn uniform_clustered_and_gridded_clouds_match_brute_force() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let uniform: Vec<[f64; 3]> = (0..2000)
            .map(|_| [rng.random(), rng.random(), rng.random()])
            .collect();
        check(&uniform, 10);
        // A tight cluster plus far outliers: the rings fail for the outliers.
        let mut clustered: Vec<[f64; 3]> = (0..1500)
            .map(|_| [rng.random::<f64>() * 1e-3, rng.random::<f64>() * 1e-3, 0.0])
            .collect();
        clustered.extend((0..20).map(|_| {
            [
                rng.random::<f64>() * 1e3,
                rng.random::<f64>() * -1e2,
                rng.random::<f64>(),
            ]
        }));
        check(&clustered, 8);
        let grid: Vec<[f64; 2]> = (0..900)
            .map(|i| [(i % 30) as f64, (i / 30) as f64])
            .collect();
        check(&grid, 12);
    }

    #[test]
    fn identical_points_are_all_at_distance_zero() {
        let points = vec![[1.0, 2.0, 3.0]; 50];
        let knn = SpatialHash::new(&points).unwrap().knn(None, 49).unwrap();
        assert!(knn.distances.iter().all(|&d| d == 0.0));
    }

    #[test]
    fn k_out_of_range_is_an_error() {
        let index = SpatialHash::new(&[[0.0, 0.0], [1.0, 0.0]]).unwrap();
        assert!(matches!(
            index.knn(None, 2),
            Err(Error::InvalidK { k: 2, max: 1, .. })
        ));
        assert!(matches!(index.knn(None, 0), Err(Error::InvalidK { .. })));
        assert!(index.knn(Some(&[[0.5, 0.5]]), 2).is_ok());
    }
}
