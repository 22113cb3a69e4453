//! Several single-precision dot products over one pass of the patch, each summed exactly
//! as [`super::sample::dot`] sums it (and `sum(a)` as `dot(a, ones)`).
//!
//! `dot` keeps one run of eight `f32` lanes: every chunk of eight waits on the previous
//! chunk's add, so a dot product of a 15x15 patch (28 chunks) is bound by the adder's
//! latency, not its throughput. The normal equations' sums over a search patch (nine dot
//! products per Gauss-Newton iteration), the template's (33 per point) and the sandwich's
//! sensitivity (48 per match) were computed one dot product after the other: profiled at
//! 8-10% of the tracker's step and of the spatial matches (`Sums::new`), 5-6%
//! (`geo_sums`), and a share of `finish`. Here `K` products run side by side, `K`
//! independent chains the adders interleave; each chain adds the same terms in the same
//! order as `dot` (lane by lane over the chunks, then the lanes and the remainder in
//! `f64`), so every product is the same to the bit.

use super::sample::dot;

/// `[a_k . b_k for k in 0..K]`, each equal to the bit to `dot(a_k, b_k)`. All slices must
/// have one length (panics otherwise). `K` should stay at or below twelve: the chains
/// live in vector registers (sixteen under AVX2, with the loads and the product), beyond
/// that they spill.
#[inline]
pub(crate) fn dots<const K: usize>(pairs: [(&[f32], &[f32]); K]) -> [f64; K] {
    let n = pairs.first().map_or(0, |p| p.0.len());
    for (a, b) in &pairs {
        assert!(
            a.len() == n && b.len() == n,
            "dots: slices of one length expected"
        );
    }
    #[cfg(target_arch = "x86_64")]
    if super::resample::wide() {
        // SAFETY: `wide` checked that the CPU has AVX2 and FMA; every slice holds `n` values.
        return unsafe { dots_wide(&pairs, n) };
    }
    // The portable build: one product after the other (the definition itself).
    pairs.map(|(a, b)| dot(a, b))
}

/// The `K` chains in AVX registers of eight lanes, one register per chain: lane `l` of
/// chain `k` adds `a_k[8 c + l] * b_k[8 c + l]` over the chunks `c` in order, as `dot`'s
/// lane `l` does (a multiply, then an add: no fused multiply-add), then the lanes and the
/// remainder are reduced by `dot`'s own expressions. (Written with the loop over the
/// lanes left to the compiler, the chains' lanes stayed in memory, one scalar add at a
/// time: slower than the separate products.)
///
/// # Safety
/// The CPU must have AVX2 and FMA; every slice of `pairs` must hold `n` values.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn dots_wide<const K: usize>(pairs: &[(&[f32], &[f32]); K], n: usize) -> [f64; K] {
    use std::arch::x86_64::{
        _mm256_add_ps, _mm256_loadu_ps, _mm256_mul_ps, _mm256_setzero_ps, _mm256_storeu_ps,
    };
    let chunks = n / 8;
    let starts: [(*const f32, *const f32); K] = pairs.map(|(a, b)| (a.as_ptr(), b.as_ptr()));
    let mut acc = [_mm256_setzero_ps(); K];
    for c in 0..chunks {
        for (chain, &(a, b)) in acc.iter_mut().zip(&starts) {
            // SAFETY: `8 c + 8 <= 8 chunks <= n`, the length of both slices (the caller's).
            let (x, y) = unsafe { (_mm256_loadu_ps(a.add(8 * c)), _mm256_loadu_ps(b.add(8 * c))) };
            *chain = _mm256_add_ps(*chain, _mm256_mul_ps(x, y));
        }
    }
    std::array::from_fn(|k| {
        let mut lanes = [0.0f32; 8];
        // SAFETY: `lanes` holds eight floats.
        unsafe { _mm256_storeu_ps(lanes.as_mut_ptr(), acc[k]) };
        let (a, b) = pairs[k];
        let tail: f64 = a[chunks * 8..]
            .iter()
            .zip(&b[chunks * 8..])
            .map(|(&x, &y)| x as f64 * y as f64)
            .sum();
        lanes.iter().map(|&l| l as f64).sum::<f64>() + tail
    })
}

/// The products of any number of `pairs` into `out` (one per pair), eleven chains at a
/// time (the template's 33 sums are three groups; a last short group is padded with its
/// first pair, whose product is dropped);
/// each equal to the bit to `dot`.
pub(crate) fn dots_into(pairs: &[(&[f32], &[f32])], out: &mut [f64]) {
    assert_eq!(pairs.len(), out.len(), "dots_into: one output per pair");
    const GROUP: usize = 11;
    for (group, out) in pairs.chunks(GROUP).zip(out.chunks_mut(GROUP)) {
        let padded: [(&[f32], &[f32]); GROUP] =
            std::array::from_fn(|k| group.get(k).copied().unwrap_or(group[0]));
        let products = dots(padded);
        out.copy_from_slice(&products[..out.len()]);
    }
}

#[cfg(test)]
mod tests {
    use super::dot as one;
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Random patches of every length from 0 to 300 (whole chunks and remainders), values
    /// over several magnitudes and signs (so the lanes' rounding matters), zeros and
    /// negative zeros: every fused product equals `dot` to the bit.
    #[test]
    fn fused_products_equal_dot_to_the_bit() {
        let mut rng = ChaCha8Rng::seed_from_u64(31);
        for n in 0..300 {
            let column = |rng: &mut ChaCha8Rng| -> Vec<f32> {
                (0..n)
                    .map(|_| match rng.random_range(0..10) {
                        0 => 0.0,
                        1 => -0.0,
                        2 => rng.random_range(-1e4..1e4f32),
                        _ => rng.random_range(-300.0..300.0f32) * rng.random_range(0.0..1.0f32),
                    })
                    .collect()
            };
            let columns: Vec<Vec<f32>> = (0..10).map(|_| column(&mut rng)).collect();
            let c = |k: usize| columns[k].as_slice();
            let nine = dots([
                (c(0), c(9)),
                (c(1), c(9)),
                (c(2), c(9)),
                (c(3), c(9)),
                (c(4), c(9)),
                (c(5), c(9)),
                (c(6), c(9)),
                (c(9), c(9)),
                (c(9), c(8)),
            ]);
            let expected = [
                (0, 9),
                (1, 9),
                (2, 9),
                (3, 9),
                (4, 9),
                (5, 9),
                (6, 9),
                (9, 9),
                (9, 8),
            ];
            for (got, (i, j)) in nine.iter().zip(expected) {
                assert_eq!(got.to_bits(), one(c(i), c(j)).to_bits(), "n {n} ({i}, {j})");
            }
            let single = dots([(c(3), c(4))]);
            assert_eq!(single[0].to_bits(), one(c(3), c(4)).to_bits(), "n {n}");
        }
    }

    /// `sum` is `dot` with ones (the template's unit weights stand in for it), and the
    /// products of any number of pairs (`dots_into`, groups of eleven and a padded rest)
    /// are `dot`'s.
    #[test]
    fn sums_and_many_products_equal_the_single_ones_to_the_bit() {
        let mut rng = ChaCha8Rng::seed_from_u64(32);
        for n in [0, 1, 7, 8, 9, 49, 121, 225, 226, 289] {
            let columns: Vec<Vec<f32>> = (0..7)
                .map(|_| (0..n).map(|_| rng.random_range(-50.0..50.0f32)).collect())
                .collect();
            let ones = vec![1.0f32; n];
            for c in &columns {
                let [s] = dots([(ones.as_slice(), c.as_slice())]);
                assert_eq!(s.to_bits(), super::super::sample::sum(c).to_bits(), "n {n}");
            }
            for count in [1, 5, 8, 9, 16, 21, 33] {
                let pairs: Vec<(&[f32], &[f32])> = (0..count)
                    .map(|i| {
                        (
                            columns[i % 7].as_slice(),
                            columns[(i * 3 + 1) % 7].as_slice(),
                        )
                    })
                    .collect();
                let mut out = vec![0.0; count];
                dots_into(&pairs, &mut out);
                for ((a, b), got) in pairs.iter().zip(&out) {
                    assert_eq!(got.to_bits(), one(a, b).to_bits(), "n {n} count {count}");
                }
            }
        }
    }

    #[test]
    #[should_panic(expected = "one length")]
    fn slices_of_different_lengths_are_refused() {
        let (a, b) = (vec![1.0f32; 9], vec![1.0f32; 8]);
        dots([(a.as_slice(), b.as_slice())]);
    }
}
