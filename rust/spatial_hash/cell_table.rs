//! The cells of one level: cell coordinates -> run of the Morton-sorted points.
//!
//! When the level's grid over the bounding box has few cells (not many more than points, as
//! for uniform clouds and surfaces) they are a dense array, one lookup per cell. Otherwise
//! (clusters far apart) a hash table: open addressing with linear probing, keyed by the
//! packed cell coordinates and hashed with the prime-xor function of Teschner et al. 2003
//! (followed by a multiplicative mix so that a power-of-two table can use the top bits).

use super::morton;

/// Marks an empty slot: packed coordinates never reach it (`D * bits <= 63`).
const EMPTY: u64 = u64::MAX;

/// Cells of one level of the hierarchy, each a half-open range of sorted positions.
pub enum CellTable {
    /// Every cell of the level's grid, x fastest.
    Dense {
        /// Cells per axis.
        dims: [u64; 3],
        /// Run of each cell; empty cells hold an empty run.
        ranges: Vec<(u32, u32)>,
    },
    /// Occupied cells only.
    Hashed(HashedCells),
}

/// Open-addressing hash table of the occupied cells.
pub struct HashedCells {
    shift: u32,
    keys: Vec<u64>,
    ranges: Vec<(u32, u32)>,
}

/// A dense grid may hold this many cells per point (and at least `DENSE_MIN` cells).
const DENSE_CELLS_PER_POINT: u64 = 8;
const DENSE_MIN: u64 = 1 << 12;

fn pack<const D: usize>(coords: [u64; D]) -> u64 {
    let bits = morton::bits_per_axis(D);
    coords
        .iter()
        .enumerate()
        .fold(0, |key, (axis, &c)| key | c << (bits * axis as u32))
}

fn hash<const D: usize>(coords: [u64; D]) -> u64 {
    const PRIMES: [u64; 3] = [73_856_093, 19_349_663, 83_492_791];
    let h = coords
        .iter()
        .zip(PRIMES)
        .fold(0u64, |h, (&c, p)| h ^ c.wrapping_mul(p));
    h.wrapping_mul(0x9e37_79b9_7f4a_7c15)
}

impl CellTable {
    /// Collects the cells of `level` from Morton codes sorted ascending; `cells` is the
    /// number of finest cells per axis that the points span.
    pub fn build<const D: usize>(codes: &[u64], level: u32, cells: [u64; D]) -> Self {
        let runs = runs(codes, D as u32 * level);
        let mut dims = [1u64; 3];
        for a in 0..D {
            dims[a] = ((cells[a] - 1) >> level) + 1;
        }
        let total = dims.iter().try_fold(1u64, |t, &d| t.checked_mul(d));
        match total {
            Some(total) if total <= (DENSE_CELLS_PER_POINT * codes.len() as u64).max(DENSE_MIN) => {
                let mut ranges = vec![(0, 0); total as usize];
                for (prefix, start, end) in runs {
                    let c = morton::decode::<D>(prefix);
                    ranges[dense_index(&c, &dims)] = (start, end);
                }
                CellTable::Dense { dims, ranges }
            }
            _ => CellTable::Hashed(HashedCells::build::<D>(runs)),
        }
    }

    /// The run of sorted positions in the cell at `coords`, if it holds any point.
    #[inline]
    pub fn get<const D: usize>(&self, coords: [u64; D]) -> Option<(u32, u32)> {
        match self {
            CellTable::Dense { dims, ranges } => {
                if (0..D).any(|a| coords[a] >= dims[a]) {
                    return None;
                }
                let r = ranges[dense_index(&coords, dims)];
                (r.1 > r.0).then_some(r)
            }
            CellTable::Hashed(h) => h.get(coords),
        }
    }

    /// Number of occupied cells.
    #[cfg(test)]
    pub fn len(&self) -> usize {
        match self {
            CellTable::Dense { ranges, .. } => ranges.iter().filter(|r| r.1 > r.0).count(),
            CellTable::Hashed(h) => h.keys.iter().filter(|&&k| k != EMPTY).count(),
        }
    }
}

fn dense_index<const D: usize>(c: &[u64; D], dims: &[u64; 3]) -> usize {
    let mut index = 0;
    for a in (0..D).rev() {
        index = index * dims[a] + c[a];
    }
    index as usize
}

impl HashedCells {
    fn build<const D: usize>(runs: Vec<(u64, u32, u32)>) -> Self {
        let capacity = (2 * runs.len()).next_power_of_two().max(16);
        let mut table = HashedCells {
            shift: 64 - capacity.trailing_zeros(),
            keys: vec![EMPTY; capacity],
            ranges: vec![(0, 0); capacity],
        };
        for (prefix, start, end) in runs {
            let coords = morton::decode::<D>(prefix);
            let key = pack(coords);
            let mut slot = table.slot(hash(coords));
            while table.keys[slot] != EMPTY {
                slot = (slot + 1) & (capacity - 1);
            }
            table.keys[slot] = key;
            table.ranges[slot] = (start, end);
        }
        table
    }

    fn slot(&self, h: u64) -> usize {
        (h >> self.shift) as usize
    }

    #[inline]
    fn get<const D: usize>(&self, coords: [u64; D]) -> Option<(u32, u32)> {
        let key = pack(coords);
        let mask = self.keys.len() - 1;
        let mut slot = self.slot(hash(coords));
        loop {
            let k = self.keys[slot];
            if k == key {
                return Some(self.ranges[slot]);
            }
            if k == EMPTY {
                return None;
            }
            slot = (slot + 1) & mask;
        }
    }
}

/// Runs of equal `code >> shift`: (prefix, start, end).
fn runs(codes: &[u64], shift: u32) -> Vec<(u64, u32, u32)> {
    let mut out = Vec::new();
    let mut start = 0usize;
    for i in 1..=codes.len() {
        if i == codes.len() || codes[i] >> shift != codes[start] >> shift {
            out.push((codes[start] >> shift, start as u32, i as u32));
            start = i;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_every_cell_and_nothing_else() {
        let mut codes: Vec<u64> = (0..500u64)
            .map(|i| morton::encode::<3>([i % 7, (i / 7) % 5, i % 11]))
            .collect();
        codes.sort_unstable();
        for table in [
            CellTable::build::<3>(&codes, 0, [7, 5, 11]),
            CellTable::build::<3>(&codes, 0, [1 << 20; 3]),
        ] {
            let mut seen = 0;
            for x in 0..8 {
                for y in 0..6 {
                    for z in 0..12 {
                        let want = codes
                            .iter()
                            .filter(|&&c| c == morton::encode::<3>([x, y, z]))
                            .count();
                        match table.get::<3>([x, y, z]) {
                            Some((s, e)) => {
                                assert_eq!((e - s) as usize, want);
                                seen += 1;
                            }
                            None => assert_eq!(want, 0),
                        }
                    }
                }
            }
            assert_eq!(seen, table.len());
        }
    }
}
