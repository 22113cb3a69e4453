//! Fixed-radius neighbours: the hashed cells of the level just larger than the radius,
//! each walked down the implicit octree with pruning.

use rayon::prelude::*;

use super::{check_queries, levels, morton, ring_offsets, SpatialHash, LEAF_SIZE};
use crate::error::{Error, Result};

/// Neighbours within a radius, in compressed sparse row form.
#[derive(Debug, Clone)]
pub struct RadiusNeighbors {
    /// `(queries + 1,)`: row `i` is `indices[indptr[i]..indptr[i + 1]]`.
    pub indptr: Vec<i64>,
    /// The caller's indices of the neighbours, nearest first within each row.
    pub indices: Vec<i64>,
    /// Euclidean distances, matching `indices`.
    pub distances: Vec<f64>,
}

impl<const D: usize> SpatialHash<D> {
    /// Indexed points within `radius` (inclusive) of each query, or, when `queries` is
    /// `None`, of each indexed point excluding itself.
    ///
    /// # Errors
    /// [`Error::InvalidRadius`] unless `radius` is positive and finite,
    /// [`Error::Empty`] / [`Error::NonFinite`] for bad queries.
    pub fn radius_neighbors(
        &self,
        queries: Option<&[[f64; D]]>,
        radius: f64,
    ) -> Result<RadiusNeighbors> {
        if !(radius > 0.0 && radius.is_finite()) {
            return Err(Error::InvalidRadius { radius });
        }
        if let Some(q) = queries {
            check_queries(q)?;
        }
        let level = (0..levels(D))
            .find(|&l| self.cell_size(l) >= radius)
            .unwrap_or(levels(D) - 1);
        self.table(level);
        let m = queries.map_or(self.len(), <[_]>::len);

        // Self-queries run in Morton order and are gathered back to the caller's order.
        const CHUNK: usize = 256;
        // Per chunk of queries: neighbour counts, then (squared distance, caller index) pairs.
        type Found = (Vec<usize>, Vec<(f64, u32)>);
        let chunks: Vec<Found> = (0..m.div_ceil(CHUNK))
            .into_par_iter()
            .map_init(Vec::new, |stack, chunk| {
                let mut counts = Vec::with_capacity(CHUNK);
                let mut found = Vec::new();
                for pos in chunk * CHUNK..((chunk + 1) * CHUNK).min(m) {
                    let (q, skip) = match queries {
                        Some(q) => (&q[pos], None),
                        None => (&self.points[pos], Some(pos)),
                    };
                    let start = found.len();
                    self.within(q, level, radius, skip, &mut found, stack);
                    found[start..].sort_unstable_by(|a: &(f64, u32), b| {
                        a.0.total_cmp(&b.0).then(a.1.cmp(&b.1))
                    });
                    counts.push(found.len() - start);
                }
                (counts, found)
            })
            .collect();
        let counts: Vec<usize> = chunks.iter().flat_map(|(c, _)| c.iter().copied()).collect();
        let found: Vec<(f64, u32)> = chunks.into_iter().flat_map(|(_, f)| f).collect();
        let mut offsets = Vec::with_capacity(m + 1);
        offsets.push(0usize);
        for c in &counts {
            offsets.push(offsets.last().unwrap() + c);
        }

        let position_of_row: Option<Vec<u32>> = queries.is_none().then(|| self.inverse_order());
        let pos = |row: usize| position_of_row.as_ref().map_or(row, |p| p[row] as usize);
        let mut indptr = Vec::with_capacity(m + 1);
        indptr.push(0i64);
        for row in 0..m {
            indptr.push(indptr[row] + counts[pos(row)] as i64);
        }
        let (indices, distances) = (0..m)
            .into_par_iter()
            .flat_map_iter(|row| {
                let p = pos(row);
                found[offsets[p]..offsets[p + 1]]
                    .iter()
                    .map(|&(d2, i)| (i as i64, d2.sqrt()))
            })
            .unzip();
        Ok(RadiusNeighbors {
            indptr,
            indices,
            distances,
        })
    }

    /// Appends (squared distance, caller index) of every point within `radius` of `q`.
    fn within(
        &self,
        q: &[f64; D],
        level: usize,
        radius: f64,
        skip: Option<usize>,
        out: &mut Vec<(f64, u32)>,
        stack: &mut Vec<(u64, usize, usize, usize)>,
    ) {
        let r2 = radius * radius;
        let table = self.table(level);
        let home = self.cell_of(q, level);
        let root = levels(D) - 1;
        if level == root {
            // The radius spans the whole cloud: walk from the root, wherever `q` is.
            stack.push((0, root, 0, self.len()));
        } else {
            // The cells are at least `radius` wide: the ball lies in the 3^D block around `q`.
            for offset in (0..=1).flat_map(ring_offsets::<D>) {
                let c: [i64; D] = std::array::from_fn(|a| home[a] + offset[a]);
                if let Some(cell) = self.grid_cell(c, level) {
                    if let Some((s, e)) = table.get(cell) {
                        stack.push((morton::encode(cell), level, s as usize, e as usize));
                    }
                }
            }
        }
        while let Some((prefix, level, start, end)) = stack.pop() {
            if self.box_distance2(q, morton::decode(prefix), level) > r2 {
                continue;
            }
            if end - start <= LEAF_SIZE || level == 0 {
                for i in start..end {
                    let d2 = self.distance2(i, q);
                    if d2 <= r2 && Some(i) != skip {
                        out.push((d2, self.order[i]));
                    }
                }
                continue;
            }
            self.for_children(prefix, level, start, end, |child, s, e| {
                stack.push((child, level - 1, s, e))
            });
        }
    }
}
