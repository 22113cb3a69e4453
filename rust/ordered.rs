//! Parallel sums whose result does not depend on the thread count.
//!
//! Floating-point addition is not associative, so a sum's last bits depend on the order in
//! which its terms meet. Rayon's `sum`, `fold` and `reduce` split the work adaptively: the
//! split follows the pool's size and, with more than one thread, which worker steals what.
//! A fit whose stopping test or line search reads such a sum then takes another path on
//! another machine (and could on the same machine run to run): session 28 found the elastic
//! fit reproducible only at a fixed `RAYON_NUM_THREADS`.
//!
//! Here the terms are cut into chunks of a fixed size, each chunk is summed in order (in
//! parallel with the others), and the chunks' partial sums are added in order: the same
//! operations in the same order on one thread or many.

use std::ops::Range;

use rayon::prelude::*;

/// Terms per chunk of [`sum_chunks`]: large enough that a chunk outweighs rayon's per-task
/// cost (a few microseconds) for a term of tens of flops, small enough that a few thousand
/// terms still split over the cores.
pub const CHUNK: usize = 512;

/// `Σ_{i < len} f(i)` over chunks of `chunk` indices given to `sum_range` (which sums its
/// range in order), the chunks' sums added in order.
///
/// The result depends on `len` and `chunk` only, not on the thread count.
///
/// # Panics
/// If `chunk` is 0.
pub fn sum_chunks<F>(len: usize, chunk: usize, sum_range: F) -> f64
where
    F: Fn(Range<usize>) -> f64 + Sync + Send,
{
    assert!(chunk > 0, "sum_chunks: a chunk of 0 terms");
    let chunks = len.div_ceil(chunk);
    let partial: Vec<f64> = (0..chunks)
        .into_par_iter()
        .map(|c| sum_range(c * chunk..((c + 1) * chunk).min(len)))
        .collect();
    partial.iter().sum()
}

/// Runs `f` in a pool of `threads` threads: for the tests that compare thread counts.
#[cfg(test)]
pub(crate) fn in_pool<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("a thread pool")
        .install(f)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Terms whose sum's rounding depends strongly on the order they are added in.
    fn ill_conditioned(i: usize) -> f64 {
        let big = if i % 7 == 0 { 1e16 } else { 1.0 };
        let sign = if i % 2 == 0 { 1.0 } else { -1.0 };
        sign * big * (1.0 + (i as f64).sqrt() * 1e-9)
    }

    #[test]
    fn the_sum_is_the_same_bits_on_any_number_of_threads() {
        for len in [0, 1, 511, 512, 513, 10_007, 100_000] {
            let one = in_pool(1, || {
                sum_chunks(len, CHUNK, |r| r.map(ill_conditioned).sum())
            });
            for threads in [2, 3, 5, 8] {
                for _ in 0..3 {
                    let many = in_pool(threads, || {
                        sum_chunks(len, CHUNK, |r| r.map(ill_conditioned).sum())
                    });
                    assert_eq!(
                        one.to_bits(),
                        many.to_bits(),
                        "len {len}, {threads} threads"
                    );
                }
            }
        }
    }

    #[test]
    fn the_sum_is_the_chunked_sequential_sum() {
        let len: usize = 5_000;
        let expected: f64 = (0..len.div_ceil(CHUNK))
            .map(|c| {
                (c * CHUNK..((c + 1) * CHUNK).min(len))
                    .map(ill_conditioned)
                    .sum::<f64>()
            })
            .sum();
        let got = sum_chunks(len, CHUNK, |r| r.map(ill_conditioned).sum());
        assert_eq!(expected.to_bits(), got.to_bits());
        // And it is a sum: close to the exact one (the terms pair up to small values).
        let plain: f64 = (0..len).map(ill_conditioned).sum();
        assert!(
            (got - plain).abs() <= 1e-6 * (0..len).map(|i| ill_conditioned(i).abs()).sum::<f64>()
        );
    }
}
