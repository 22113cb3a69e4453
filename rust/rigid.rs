//! Batched weighted least-squares rigid fits (Kabsch) of small point sets: the tracker's
//! rigid fusion fits one per tracked point to its neighbours, and the held-out check one
//! per neighbour left out (tens of thousands of 8-point fits a frame).
//!
//! For sets `a`, `b` of K points with weights `w` (normalised to sum 1): centroids
//! `ca = sum w_k a_k`, `cb`; cross-covariance `H = sum w_k (a_k - ca)(b_k - cb)^T`; the
//! rotation maximising `tr(R H)` over proper rotations is the one nearest to `H^T` in the
//! Frobenius norm ([`crate::polar::nearest_rotation3`]: Kabsch's `V diag(1, 1, det) U^T`
//! without an SVD), and `t = cb - R ca`.

use rayon::prelude::*;

use crate::polar::nearest_rotation3;

/// `(R, t)` of `b ~ R a + t` for each of the sets `a`, `b` (`M` sets of `k` points, set `m`
/// at rows `m k .. (m + 1) k`) with `weights` (`M k`; non-negative, a positive sum per set).
/// `R` row-major. Non-finite input gives NaN (or garbage), never a panic.
pub fn rigid_motions(
    a: &[[f64; 3]],
    b: &[[f64; 3]],
    weights: &[f64],
    k: usize,
) -> Vec<([f64; 9], [f64; 3])> {
    a.par_chunks(k)
        .zip(b.par_chunks(k))
        .zip(weights.par_chunks(k))
        .map(|((a, b), w)| rigid_motion(a, b, w))
        .collect()
}

/// One set's fit (`rigid_motions` of a single set; `crate::track::rigid_held_out` refits
/// each set with one point left out through it, so that its fits are the same to the bit).
pub(crate) fn rigid_motion(a: &[[f64; 3]], b: &[[f64; 3]], w: &[f64]) -> ([f64; 9], [f64; 3]) {
    let total: f64 = w.iter().sum();
    let mut ca = [0.0; 3];
    let mut cb = [0.0; 3];
    for ((p, q), &wk) in a.iter().zip(b).zip(w) {
        let wk = wk / total;
        for i in 0..3 {
            ca[i] += wk * p[i];
            cb[i] += wk * q[i];
        }
    }
    // H^T = sum w_k (b_k - cb)(a_k - ca)^T, row-major.
    let mut ht = [0.0; 9];
    for ((p, q), &wk) in a.iter().zip(b).zip(w) {
        let wk = wk / total;
        for i in 0..3 {
            let bi = wk * (q[i] - cb[i]);
            for j in 0..3 {
                ht[3 * i + j] += bi * (p[j] - ca[j]);
            }
        }
    }
    let r = if ht.iter().all(|v| v.is_finite()) {
        nearest_rotation3(&ht)
    } else {
        [f64::NAN; 9]
    };
    let t = std::array::from_fn(|i| {
        cb[i] - (r[3 * i] * ca[0] + r[3 * i + 1] * ca[1] + r[3 * i + 2] * ca[2])
    });
    (r, t)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A rotation about a unit axis by an angle (Rodrigues).
    fn rotation(axis: [f64; 3], angle: f64) -> [f64; 9] {
        let (s, c) = angle.sin_cos();
        let [x, y, z] = axis;
        [
            c + x * x * (1.0 - c),
            x * y * (1.0 - c) - z * s,
            x * z * (1.0 - c) + y * s,
            y * x * (1.0 - c) + z * s,
            c + y * y * (1.0 - c),
            y * z * (1.0 - c) - x * s,
            z * x * (1.0 - c) - y * s,
            z * y * (1.0 - c) + x * s,
            c + z * z * (1.0 - c),
        ]
    }

    #[test]
    fn recovers_a_rigid_motion_and_ignores_zero_weights() {
        let r = rotation([0.6, 0.0, 0.8], 2.5);
        let t = [0.3, -1.0, 2.0];
        let a = [
            [0.0, 0.0, 0.0],
            [1.0, 0.2, 0.0],
            [0.1, 1.0, 0.3],
            [0.4, 0.5, 1.0],
            [2.0, 2.0, 2.0],
        ];
        let mut b: Vec<[f64; 3]> = a
            .iter()
            .map(|p| {
                std::array::from_fn(|i| {
                    r[3 * i] * p[0] + r[3 * i + 1] * p[1] + r[3 * i + 2] * p[2] + t[i]
                })
            })
            .collect();
        // The last point is an outlier with no weight.
        b[4] = [9.0, -9.0, 9.0];
        let fits = rigid_motions(&a, &b, &[1.0, 2.0, 1.0, 0.5, 0.0], 5);
        let (rf, tf) = fits[0];
        for i in 0..9 {
            assert!((rf[i] - r[i]).abs() < 1e-12);
        }
        for i in 0..3 {
            assert!((tf[i] - t[i]).abs() < 1e-12);
        }
    }

    #[test]
    fn planar_sets_give_a_proper_rotation() {
        // Coplanar points mirrored through their plane: the best proper rotation, not the
        // reflection.
        let a = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [1.0, 1.0, 0.0],
        ];
        let fits = rigid_motions(&a, &a, &[1.0; 4], 4);
        let (r, _) = fits[0];
        let det = r[0] * (r[4] * r[8] - r[5] * r[7]) - r[1] * (r[3] * r[8] - r[5] * r[6])
            + r[2] * (r[3] * r[7] - r[4] * r[6]);
        assert!((det - 1.0).abs() < 1e-12);
        assert!(
            (r[0] - 1.0).abs() < 1e-12 && (r[4] - 1.0).abs() < 1e-12 && (r[8] - 1.0).abs() < 1e-12
        );
    }
}
