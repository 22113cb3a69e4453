//! Morton (Z-order) codes of integer cell coordinates, 2-D and 3-D.
//!
//! Sorting points by the Morton code of their finest cell makes every cell of every
//! coarser level a contiguous run of the sorted array: a linear octree (quadtree in 2-D)
//! for free, which is what the hierarchical fallback of the hash walks.

/// Bits of cell coordinate per axis, so that `D * bits` fits in 63 bits.
pub const fn bits_per_axis(d: usize) -> u32 {
    (63 / d) as u32
}

fn spread3(x: u64) -> u64 {
    let mut x = x & 0x1f_ffff;
    x = (x | x << 32) & 0x001f_0000_0000_ffff;
    x = (x | x << 16) & 0x001f_0000_ff00_00ff;
    x = (x | x << 8) & 0x100f_00f0_0f00_f00f;
    x = (x | x << 4) & 0x10c3_0c30_c30c_30c3;
    (x | x << 2) & 0x1249_2492_4924_9249
}

fn compact3(x: u64) -> u64 {
    let mut x = x & 0x1249_2492_4924_9249;
    x = (x ^ (x >> 2)) & 0x10c3_0c30_c30c_30c3;
    x = (x ^ (x >> 4)) & 0x100f_00f0_0f00_f00f;
    x = (x ^ (x >> 8)) & 0x001f_0000_ff00_00ff;
    x = (x ^ (x >> 16)) & 0x001f_0000_0000_ffff;
    (x ^ (x >> 32)) & 0x1f_ffff
}

fn spread2(x: u64) -> u64 {
    let mut x = x & 0xffff_ffff;
    x = (x | x << 16) & 0x0000_ffff_0000_ffff;
    x = (x | x << 8) & 0x00ff_00ff_00ff_00ff;
    x = (x | x << 4) & 0x0f0f_0f0f_0f0f_0f0f;
    x = (x | x << 2) & 0x3333_3333_3333_3333;
    (x | x << 1) & 0x5555_5555_5555_5555
}

fn compact2(x: u64) -> u64 {
    let mut x = x & 0x5555_5555_5555_5555;
    x = (x ^ (x >> 1)) & 0x3333_3333_3333_3333;
    x = (x ^ (x >> 2)) & 0x0f0f_0f0f_0f0f_0f0f;
    x = (x ^ (x >> 4)) & 0x00ff_00ff_00ff_00ff;
    x = (x ^ (x >> 8)) & 0x0000_ffff_0000_ffff;
    (x ^ (x >> 16)) & 0xffff_ffff
}

/// Interleaves the bits of `coords` (axis 0 in the lowest bit).
pub fn encode<const D: usize>(coords: [u64; D]) -> u64 {
    let spread = if D == 3 { spread3 } else { spread2 };
    coords
        .iter()
        .enumerate()
        .fold(0, |code, (axis, &c)| code | spread(c) << axis)
}

/// Inverse of [`encode`].
pub fn decode<const D: usize>(code: u64) -> [u64; D] {
    let compact = if D == 3 { compact3 } else { compact2 };
    std::array::from_fn(|axis| compact(code >> axis))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_and_orders_by_octant() {
        for c in [
            [0u64, 0, 0],
            [1, 2, 3],
            [0x1f_ffff, 0, 0x1f_ffff],
            [12345, 678, 91011],
        ] {
            assert_eq!(decode::<3>(encode::<3>(c)), c);
        }
        for c in [[0u64, 0], [0x7fff_ffff, 3], [123_456_789, 987_654_321]] {
            assert_eq!(decode::<2>(encode::<2>(c)), c);
        }
        // The top bits of the code are the coarse cell: (1,0,0) at level 1 = octant 1.
        assert_eq!(encode::<3>([2, 0, 0]) >> 3, 1);
        assert_eq!(encode::<3>([0, 0, 2]) >> 3, 4);
    }
}
