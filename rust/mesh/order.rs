//! Query order: points sorted along a Z-order (Morton) curve, so that consecutive queries are
//! near each other and each can start its search from the previous one's answer.

use rayon::prelude::*;

/// Bits of cell coordinate per axis: 1024 cells a side orders 100,000s of points well enough.
const BITS: u32 = 10;

/// Spreads the low 10 bits of `x` to every third bit.
fn spread(x: u64) -> u64 {
    let mut x = x & 0x3ff;
    x = (x | x << 16) & 0x0300_00ff;
    x = (x | x << 8) & 0x0300_f00f;
    x = (x | x << 4) & 0x030c_30c3;
    (x | x << 2) & 0x0924_9249
}

/// Indices of `points` in Morton order of their cells in the points' bounding box.
pub(super) fn morton_order(points: &[[f64; 3]]) -> Vec<u32> {
    let (lo, hi) = points.iter().fold(
        ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]),
        |(lo, hi), p| {
            (
                std::array::from_fn(|a| lo[a].min(p[a])),
                std::array::from_fn(|a| hi[a].max(p[a])),
            )
        },
    );
    let cells = (1u64 << BITS) as f64;
    let scale: [f64; 3] = std::array::from_fn(|a| {
        let extent = hi[a] - lo[a];
        if extent > 0.0 {
            (cells - 1.0) / extent
        } else {
            0.0
        }
    });
    let mut keyed: Vec<(u32, u32)> = points
        .par_iter()
        .enumerate()
        .map(|(i, p)| {
            let code = (0..3).fold(0, |code, a| {
                code | spread(((p[a] - lo[a]) * scale[a]) as u64) << a
            });
            (code as u32, i as u32)
        })
        .collect();
    keyed.par_sort_unstable();
    keyed.into_iter().map(|(_, i)| i).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spread_interleaves_every_third_bit() {
        assert_eq!(spread(0b1011), 0b1_000_001_001);
        assert_eq!(spread(0x3ff), 0x0924_9249);
    }

    #[test]
    fn the_order_is_a_permutation_along_the_curve() {
        let points: Vec<[f64; 3]> = (0..8)
            .map(|i| [(i & 1) as f64, ((i >> 1) & 1) as f64, (i >> 2) as f64])
            .rev()
            .collect();
        assert_eq!(morton_order(&points), vec![7, 6, 5, 4, 3, 2, 1, 0]);
        assert!(morton_order(&[]).is_empty());
    }
}
