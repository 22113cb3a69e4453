//! Nearest proper rotations (the rotation factor of the polar decomposition), batched.
//!
//! For a 3x3 matrix $A$ the nearest rotation in the Frobenius norm maximises
//! $\operatorname{tr}(R^\top A)$ over $SO(3)$. Writing $R = R(q)$ for a unit quaternion $q$
//! turns this into $\max_q q^\top N q$ with Horn's symmetric traceless 4x4 matrix $N(A)$,
//! whose largest eigenvalue is $\sigma_1 + \sigma_2 + \operatorname{sign}(\det A)\,\sigma_3$.
//! We find that eigenvalue by Halley's method on the characteristic quartic (monotone from
//! an upper bound, as all roots are real) and its eigenvector by two steps of inverse
//! iteration with a 4x4 $L D L^\top$ factor: a few hundred flops, no SVD, four matrices in
//! lock step. When the top eigenvalue is nearly double (the rotation is then nearly
//! non-unique) the Jacobi method takes over. Reflections (det < 0) come out with the smallest singular direction
//! flipped, rank-deficient inputs give one of the (then non-unique) nearest rotations, and
//! the zero matrix gives the identity. The 2x2 case is closed-form.

mod horn;
mod jacobi;

use rayon::prelude::*;

use crate::error::{check_finite, Result};
use horn::{
    det3, det4, horn_matrix, largest_horn_eigenvalue, quaternion_to_matrix,
    rotation_by_inverse_iteration, unit_frobenius, NEARLY_DOUBLE,
};
use jacobi::top_eigenvector_jacobi;

/// A 3x3 matrix stored row-major.
pub type Mat3 = [f64; 9];
/// A 2x2 matrix stored row-major.
pub type Mat2 = [f64; 4];

const IDENTITY3: Mat3 = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];

/// The proper rotation nearest to `a` in the Frobenius norm (`a` finite).
///
/// Unique when $\sigma_2 + \operatorname{sign}(\det A)\,\sigma_3 > 0$; otherwise one of the
/// nearest rotations. The zero matrix gives the identity.
pub fn nearest_rotation3(a: &Mat3) -> Mat3 {
    // Unit norm keeps the quartic's coefficients O(1): no overflow, fixed tolerances.
    let Some(a) = unit_frobenius(a) else {
        return IDENTITY3;
    };
    let n = horn_matrix(&a);
    let (lambda, slope) = largest_horn_eigenvalue(&a, &n);
    if slope < NEARLY_DOUBLE {
        return quaternion_to_matrix(&top_eigenvector_jacobi(&n));
    }

    rotation_by_inverse_iteration(&n, lambda, slope)
}

/// Matrices handled together by [`nearest_rotations3_lanes`].
const LANES: usize = 4;

/// [`nearest_rotation3`] of `LANES` matrices at once, in lock step: a fixed number of Halley
/// steps and selects instead of branches, so the independent dependency chains of the
/// lanes overlap (and vectorise). A lane that did not settle in those steps (about 1 in 150
/// random matrices), has a nearly double top eigenvalue, or is the zero matrix, is redone by
/// the scalar [`nearest_rotation3`].
fn nearest_rotations3_lanes(a: &[Mat3; LANES]) -> [Mat3; LANES] {
    const HALLEY_STEPS: usize = 6;
    let mut nonzero = [false; LANES];
    let mut na = [[0.0; 9]; LANES];
    let mut n = [[[0.0; 4]; 4]; LANES];
    let mut lambda = [3f64.sqrt(); LANES];
    let mut c1 = [0.0; LANES];
    let mut c0 = [0.0; LANES];
    let mut last_step = [0.0; LANES];
    for l in 0..LANES {
        if let Some(unit) = unit_frobenius(&a[l]) {
            na[l] = unit;
            nonzero[l] = true;
        }
        n[l] = horn_matrix(&na[l]);
        c1[l] = -8.0 * det3(&na[l]);
        c0[l] = det4(&n[l]);
    }
    for _ in 0..HALLEY_STEPS {
        for l in 0..LANES {
            let x = lambda[l];
            let x2 = x * x;
            let p = (x2 - 2.0) * x2 + c1[l] * x + c0[l];
            let dp = (4.0 * x2 - 4.0) * x + c1[l];
            let ddp = 12.0 * x2 - 4.0;
            let step = 2.0 * p * dp / (2.0 * dp * dp - p * ddp);
            // Past the root (p <= 0), or rounding noise: stay.
            let step = if p > 0.0 && dp > 0.0 && step > 0.0 {
                step
            } else {
                0.0
            };
            lambda[l] = x - step;
            last_step[l] = step;
        }
    }
    let mut out = [[0.0; 9]; LANES];
    for l in 0..LANES {
        let x = lambda[l];
        let slope = (4.0 * x * x - 4.0) * x + c1[l];
        let settled = nonzero[l] && last_step[l] <= 1e-12 && slope >= NEARLY_DOUBLE;
        out[l] = if settled {
            rotation_by_inverse_iteration(&n[l], x, slope)
        } else {
            nearest_rotation3(&a[l])
        };
    }
    out
}

/// The proper 2-D rotation nearest to `a`: the angle of $(a_{00} + a_{11}, a_{10} - a_{01})$.
pub fn nearest_rotation2(a: &Mat2) -> Mat2 {
    // Halved so that the sums cannot overflow; the angle is unchanged.
    let c = 0.5 * a[0] + 0.5 * a[3];
    let s = 0.5 * a[2] - 0.5 * a[1];
    let h = c.hypot(s);
    if h == 0.0 {
        return [1.0, 0.0, 0.0, 1.0];
    }
    let (c, s) = (c / h, s / h);
    [c, -s, s, c]
}

/// Symmetric stretch $S = \operatorname{sym}(R^\top A)$ of a D x D row-major matrix pair.
fn stretch<const D: usize, const DD: usize>(r: &[f64; DD], a: &[f64; DD]) -> [f64; DD] {
    let mut s = [0.0; DD];
    for i in 0..D {
        for j in 0..D {
            let mut v = 0.0;
            for k in 0..D {
                v += r[k * D + i] * a[k * D + j];
            }
            s[i * D + j] = v;
        }
    }
    for i in 0..D {
        for j in i + 1..D {
            let m = 0.5 * (s[i * D + j] + s[j * D + i]);
            s[i * D + j] = m;
            s[j * D + i] = m;
        }
    }
    s
}

/// Rotations (and, when `stretches` is given, symmetric stretches $S$ with $A \approx R S$)
/// of a batch of row-major matrices, in parallel.
fn polar_batch<const D: usize, const DD: usize>(
    matrices: &[[f64; DD]],
    rotations: &mut [[f64; DD]],
    stretches: Option<&mut [[f64; DD]]>,
    nearest: impl Fn(&[f64; DD]) -> [f64; DD] + Sync,
) -> Result<()> {
    check_finite("matrices", matrices)?;
    const CHUNK: usize = 4096;
    match stretches {
        None => rotations
            .par_chunks_mut(CHUNK)
            .zip(matrices.par_chunks(CHUNK))
            .for_each(|(rs, ms)| {
                for (r, m) in rs.iter_mut().zip(ms) {
                    *r = nearest(m);
                }
            }),
        Some(stretches) => rotations
            .par_chunks_mut(CHUNK)
            .zip(stretches.par_chunks_mut(CHUNK))
            .zip(matrices.par_chunks(CHUNK))
            .for_each(|((rs, ss), ms)| {
                for ((r, s), m) in rs.iter_mut().zip(ss.iter_mut()).zip(ms) {
                    *r = nearest(m);
                    *s = stretch::<D, DD>(r, m);
                }
            }),
    }
    Ok(())
}

/// Batched [`nearest_rotation3`] (and stretches), writing into the given outputs.
///
/// # Errors
/// [`crate::Error::NonFinite`] when a matrix holds NaN or infinity.
pub fn polar3(
    matrices: &[Mat3],
    rotations: &mut [Mat3],
    stretches: Option<&mut [Mat3]>,
) -> Result<()> {
    const CHUNK: usize = 4096;
    // The finiteness check rides along with the work (a separate pass over the input
    // measured 10% of the time); non-finite matrices give garbage, never a panic, and the
    // first of them is reported.
    let non_finite = rotations
        .par_chunks_mut(CHUNK)
        .zip(matrices.par_chunks(CHUNK))
        .enumerate()
        .filter_map(|(chunk, (rs, ms))| {
            let (groups, rest) = ms.as_chunks::<LANES>();
            let (out_groups, out_rest) = rs.as_chunks_mut::<LANES>();
            for (r, m) in out_groups.iter_mut().zip(groups) {
                *r = nearest_rotations3_lanes(m);
            }
            for (r, m) in out_rest.iter_mut().zip(rest) {
                *r = nearest_rotation3(m);
            }
            let all_finite = |m: &Mat3| m.iter().all(|v| v.is_finite());
            ms.iter()
                .position(|m| !all_finite(m))
                .map(|i| chunk * CHUNK + i)
        })
        .min();
    if let Some(row) = non_finite {
        return Err(crate::Error::NonFinite {
            argument: "matrices",
            row,
        });
    }
    if let Some(stretches) = stretches {
        stretches
            .par_iter_mut()
            .zip(rotations.par_iter())
            .zip(matrices.par_iter())
            .for_each(|((s, r), m)| {
                *s = stretch::<3, 9>(r, m);
            });
    }
    Ok(())
}

/// Batched [`nearest_rotation2`] (and stretches), writing into the given outputs.
///
/// # Errors
/// [`crate::Error::NonFinite`] when a matrix holds NaN or infinity.
pub fn polar2(
    matrices: &[Mat2],
    rotations: &mut [Mat2],
    stretches: Option<&mut [Mat2]>,
) -> Result<()> {
    polar_batch::<2, 4>(matrices, rotations, stretches, nearest_rotation2)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix3;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn to_na(a: &Mat3) -> Matrix3<f64> {
        Matrix3::from_row_slice(a)
    }

    /// Reference: U diag(1, 1, det(U V^T)) V^T from nalgebra's SVD (of `a` scaled to unit
    /// largest entry, which leaves the rotation unchanged and keeps the SVD finite).
    fn svd_rotation(a: &Mat3) -> Matrix3<f64> {
        let largest = a
            .iter()
            .fold(0.0f64, |m, v| m.max(v.abs()))
            .max(f64::MIN_POSITIVE);
        let svd = (to_na(a) / largest).svd(true, true);
        let (u, vt) = (svd.u.unwrap(), svd.v_t.unwrap());
        let d = (u * vt).determinant().signum();
        u * Matrix3::from_diagonal(&nalgebra::Vector3::new(1.0, 1.0, d)) * vt
    }

    fn random_matrix(rng: &mut ChaCha8Rng) -> Mat3 {
        std::array::from_fn(|_| rng.random_range(-1.0..1.0))
    }

    #[test]
    fn characteristic_quartic_matches_horn_matrix() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for _ in 0..100 {
            let a = random_matrix(&mut rng);
            let s = a.iter().map(|v| v * v).sum::<f64>().sqrt();
            let a = a.map(|v| v / s);
            let n = horn_matrix(&a);
            let (lambda, _) = largest_horn_eigenvalue(&a, &n);
            let eig = nalgebra::Matrix4::from_fn(|i, j| n[i][j]).symmetric_eigenvalues();
            let top = eig.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
            assert!((lambda - top).abs() < 1e-12, "{lambda} vs {top}");
        }
    }

    #[test]
    fn matches_svd_on_random_and_reflected_matrices() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        for _ in 0..2000 {
            let a = random_matrix(&mut rng);
            let r = to_na(&nearest_rotation3(&a));
            let want = svd_rotation(&a);
            assert!((r - want).norm() < 1e-10, "{a:?}");
            assert!((r.transpose() * r - Matrix3::identity()).norm() < 1e-13);
            assert!((r.determinant() - 1.0).abs() < 1e-13);
        }
    }

    #[test]
    fn lanes_agree_with_the_scalar_path() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for _ in 0..2000 {
            let mut group: [Mat3; LANES] = std::array::from_fn(|_| random_matrix(&mut rng));
            group[1] = [0.0; 9];
            group[2] = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0];
            let lanes = nearest_rotations3_lanes(&group);
            for (got, a) in lanes.iter().zip(&group) {
                let want = nearest_rotation3(a);
                let r = to_na(got);
                assert!((r.transpose() * r - Matrix3::identity()).norm() < 1e-13);
                let (g, w) = (
                    (r.transpose() * to_na(a)).trace(),
                    (to_na(&want).transpose() * to_na(a)).trace(),
                );
                assert!(g >= w - 1e-12, "{a:?}");
            }
            assert!((to_na(&lanes[0]) - to_na(&nearest_rotation3(&group[0]))).norm() < 1e-10);
        }
    }

    #[test]
    fn degenerate_inputs_give_a_nearest_rotation() {
        let cases: [Mat3; 7] = [
            [0.0; 9],
            [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0],
            [1.0, 2.0, 3.0, 2.0, 4.0, 6.0, 3.0, 6.0, 9.0],
            [1e-300, 0.0, 0.0, 0.0, 1e-300, 0.0, 0.0, 0.0, 1e-300],
            [1e300, 2e300, 0.0, -1e300, 1e300, 0.0, 0.0, 0.0, 1e-300],
            [5e-320, 0.0, 0.0, 0.0, 5e-320, 0.0, 0.0, 0.0, 5e-320],
            [0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        ];
        for a in cases {
            let r = to_na(&nearest_rotation3(&a));
            assert!((r.transpose() * r - Matrix3::identity()).norm() < 1e-12);
            assert!((r.determinant() - 1.0).abs() < 1e-12);
            // Optimal: tr(R^T A) reaches the SVD rotation's value (A scaled to unit size).
            let largest = a
                .iter()
                .fold(0.0f64, |m, v| m.max(v.abs()))
                .max(f64::MIN_POSITIVE);
            let unit = to_na(&a) / largest;
            let got = (r.transpose() * unit).trace();
            let best = (svd_rotation(&a).transpose() * unit).trace();
            assert!(
                got >= best - 1e-12 * (1.0 + best.abs()),
                "{a:?}: {got} < {best}"
            );
        }
    }

    #[test]
    fn jacobi_recovers_the_top_eigenvector_of_nearly_double_eigenvalues() {
        // Nearly rank one: A = u v^T + 1e-9 E. The polar factor must still give R S = A.
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        for _ in 0..200 {
            let u: [f64; 3] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
            let v: [f64; 3] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
            let a: Mat3 =
                std::array::from_fn(|i| u[i / 3] * v[i % 3] + 1e-9 * rng.random_range(-1.0..1.0));
            let r = to_na(&nearest_rotation3(&a));
            let s = r.transpose() * to_na(&a);
            let skew = (s - s.transpose()).norm() / to_na(&a).norm();
            assert!(skew < 1e-12, "R^T A not symmetric: {skew:e}");
            assert!((r.transpose() * r - Matrix3::identity()).norm() < 1e-13);
        }
    }

    #[test]
    fn two_d_rotation_is_the_angle_of_the_rotational_part() {
        let r = nearest_rotation2(&[2.0, -1.0, 1.0, 2.0]);
        let t = (1.0f64).atan2(2.0);
        assert!((r[0] - t.cos()).abs() < 1e-15 && (r[2] - t.sin()).abs() < 1e-15);
        assert_eq!(nearest_rotation2(&[0.0; 4]), [1.0, 0.0, 0.0, 1.0]);
    }

    #[test]
    fn batch_rejects_non_finite() {
        let m = [[0.0; 9], [f64::NAN; 9]];
        let mut r = [[0.0; 9]; 2];
        assert_eq!(
            polar3(&m, &mut r, None),
            Err(crate::Error::NonFinite {
                argument: "matrices",
                row: 1
            })
        );
    }
}
