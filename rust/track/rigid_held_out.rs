//! The rigid residuals' leave-one-out fits (`elastocap.tracking.rigidity.rigid_residuals`):
//! how well a point's neighbourhood predicts a point it was not fitted to. For each set of
//! `K` neighbours (positions `a` on the seeding frame, `b` now, 0/1 `weights` for the chosen
//! ones) and each chosen neighbour `j` whose set keeps at least `min_others` weight without
//! it, the set is fitted again with `j`'s weight zeroed ([`crate::rigid::rigid_motion`], the
//! same fit as `rigid_fits`, to the bit).
//!
//! Python gathered the `K` points of every one of the ~9,000 refits a frame (`(M K, K, 3)`
//! arrays twice, ~5 ms a frame at 1,150 points) to hand them to `rigid_fits`; here each set
//! is read in place. The misses themselves stay in numpy: its `einsum` sums the three
//! products in an order of its own SIMD loop, which a plain sum here would not match.

use rayon::prelude::*;

use crate::rigid::rigid_motion;

/// One fit per set and neighbour, row-major by set then neighbour (`M k` of them): `(R, t)`
/// of the set without that neighbour for the chosen neighbours (`weights[j] > 0`) whose
/// set's other weights sum to `min_others` or more, NaN for the others. `a`, `b` hold `M`
/// sets of `k` points (set `m` at rows `m k .. (m + 1) k`), `weights` `M k`.
pub fn rigid_held_out(
    a: &[[f64; 3]],
    b: &[[f64; 3]],
    weights: &[f64],
    k: usize,
    min_others: f64,
) -> Vec<([f64; 9], [f64; 3])> {
    let none = ([f64::NAN; 9], [f64::NAN; 3]);
    let mut out = vec![none; weights.len()];
    if k == 0 {
        return out;
    }
    out.par_chunks_mut(k)
        .zip(a.par_chunks(k))
        .zip(b.par_chunks(k))
        .zip(weights.par_chunks(k))
        .for_each(|(((fits, a), b), w)| set_held_out(a, b, w, min_others, fits));
    out
}

fn set_held_out(
    a: &[[f64; 3]],
    b: &[[f64; 3]],
    w: &[f64],
    min_others: f64,
    fits: &mut [([f64; 9], [f64; 3])],
) {
    let mut without = w.to_vec();
    for j in 0..w.len() {
        if !(w[j] > 0.0) {
            continue;
        }
        // numpy's `weight * (1 - eye)`: this neighbour's weight times 0, the others' times 1.
        without.copy_from_slice(w);
        without[j] *= 0.0;
        // 0/1 weights sum exactly in any order (numpy's reduction has its own).
        if !(without.iter().sum::<f64>() >= min_others) {
            continue;
        }
        fits[j] = rigid_motion(a, b, &without);
    }
}
