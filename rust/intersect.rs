//! Forward intersection with one 2x2 covariance per view (SPEC 7; the tracker's case): the
//! world point that 2..C pixel observations of it determine, with its covariance, by
//! weighted least squares through the full camera model, and blunders rejected by
//! normalised residuals (Baarda's data snooping). The Python `elastocap.stereo.intersect`
//! calls it given covariances of shape `(N, C, 2, 2)`; its joint-covariance path (dense
//! `2C x 2C` weights) stays in numpy.
//!
//! Per point, independently (rayon over points): the start is the point nearest to the
//! used views' rays; Gauss-Newton minimises `sum_c r_c^T W_c r_c` (`W_c` the inverse of
//! view c's covariance, `r_c` observation minus projection) with the analytic Jacobian of
//! the projection (distortion and skew included) until a step is no longer than
//! `step_tolerance`; the covariance is the inverse of `sum_c J_c^T W_c J_c`, its eigenvalues
//! clamped at `1e-12` of the largest (as the Python `_inverse`); while the point keeps three
//! or more views and the largest normalised residual exceeds `critical`, the view holding
//! it is dropped and the point solved again.

use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use rayon::prelude::*;

use crate::camera::Camera;

/// Smallest eigenvalue of a normal matrix kept, relative to its largest, when it is
/// inverted into a covariance (the Python `intersection._CONDITION`: near-parallel rays
/// leave one direction almost free; clamped, it gets a covariance but no weight).
const CONDITION: f64 = 1e-12;

/// A view's normalised residual counts only where its residual's variance is above this
/// times the observation's variance (zero to rounding where the geometry fixes it).
const DETERMINED: f64 = 1e-9;

/// Options of [`intersect_views`].
#[derive(Debug, Clone, Copy)]
pub struct IntersectOptions {
    /// Reject blunders by normalised residuals.
    pub reject: bool,
    /// Critical value of the normalised residual.
    pub critical: f64,
    /// Gauss-Newton iterations per solve at most.
    pub iterations: usize,
    /// A step this short (world units) ends Gauss-Newton.
    pub step_tolerance: f64,
}

/// One point's intersection.
#[derive(Debug, Clone)]
pub struct PointIntersection {
    /// The point (world units); NaN where it could not be solved.
    pub point: [f64; 3],
    /// Its covariance (world units squared), NaN where the normal matrix is singular.
    pub covariance: [[f64; 3]; 3],
    /// Observation minus projection per view (pixels), zero for views not used.
    pub residuals: Vec<[f64; 2]>,
    /// Per view the larger normalised residual at the last solve the view took part in with
    /// three or more views; NaN otherwise.
    pub normalised: Vec<f64>,
    /// Views in the final solution.
    pub used: Vec<bool>,
    /// `sum_c r_c^T W_c r_c` over the used views.
    pub quad: f64,
    /// The last Gauss-Newton step was within the tolerance.
    pub converged: bool,
}

/// Intersect N points seen by C = `cameras.len()` cameras: `obs` holds N x C pixels (row
/// `n * C + c`; NaN where not observed), `cov` their 2x2 covariances as `[s_uu, s_uv, s_vu,
/// s_vv]` (pixels squared; a view with a non-finite one is not used). A used view whose
/// covariance is singular gets NaN weights (its point NaN).
pub fn intersect_views(
    cameras: &[Camera],
    obs: &[[f64; 2]],
    cov: &[[f64; 4]],
    options: IntersectOptions,
) -> Vec<PointIntersection> {
    let c = cameras.len();
    let centers: Vec<[f64; 3]> = cameras.iter().map(Camera::center).collect();
    // A few points (the tracker's re-intersections of the views it changed) on the calling
    // thread: each point is independent, so the answers are the same either way, and the
    // pool's hand-over cost more wall time than such a batch.
    if c > 0 && obs.len() / c < SERIAL_POINTS {
        return obs
            .chunks(c)
            .zip(cov.chunks(c))
            .map(|(o, s)| intersect_point(cameras, &centers, o, s, options))
            .collect();
    }
    obs.par_chunks(c)
        .zip(cov.par_chunks(c))
        .map(|(o, s)| intersect_point(cameras, &centers, o, s, options))
        .collect()
}

/// Batches of fewer points than this are intersected on the calling thread (a few us a
/// point).
const SERIAL_POINTS: usize = 64;

/// The Gauss-Newton solution over the views `used` of one point.
struct Solved {
    x: Vector3<f64>,
    jac: Vec<[[f64; 3]; 2]>,
    resid: Vec<[f64; 2]>,
    converged: bool,
}

fn intersect_point(
    cameras: &[Camera],
    centers: &[[f64; 3]],
    obs: &[[f64; 2]],
    cov: &[[f64; 4]],
    options: IntersectOptions,
) -> PointIntersection {
    let c = cameras.len();
    let mut used: Vec<bool> = (0..c)
        .map(|k| obs[k].iter().all(|v| v.is_finite()) && cov[k].iter().all(|v| v.is_finite()))
        .collect();
    let weight: Vec<[[f64; 2]; 2]> = cov
        .iter()
        .zip(&used)
        .map(|(s, &u)| if u { inverse2(s) } else { [[0.0; 2]; 2] })
        .collect();
    let mut normalised = vec![f64::NAN; c];
    loop {
        let solved = solve(cameras, centers, obs, &weight, &used, options);
        let point_cov = inverse_normal(&normal(&solved.jac, &weight, &used));
        let count = used.iter().filter(|&&u| u).count();
        let mut worst: Option<(usize, f64)> = None;
        if count >= 3 {
            for k in (0..c).filter(|&k| used[k]) {
                let w = normalised_residual(&cov[k], &solved.jac[k], &point_cov, &solved.resid[k]);
                if w.is_finite() {
                    normalised[k] = w;
                    // np.argmax: the first of equal maxima.
                    if worst.is_none_or(|(_, best)| w > best) {
                        worst = Some((k, w));
                    }
                }
            }
        }
        match worst {
            Some((k, w)) if options.reject && w > options.critical => used[k] = false,
            _ => {
                let quad = (0..c)
                    .filter(|&k| used[k])
                    .map(|k| quadratic2(&weight[k], &solved.resid[k]))
                    .sum();
                return PointIntersection {
                    point: [solved.x[0], solved.x[1], solved.x[2]],
                    covariance: std::array::from_fn(|i| std::array::from_fn(|j| point_cov[(i, j)])),
                    residuals: solved.resid,
                    normalised,
                    used,
                    quad,
                    converged: solved.converged,
                };
            }
        }
    }
}

/// Inverse of the 2x2 matrix `[a, b, c, d]` (row-major); NaN where singular.
fn inverse2(m: &[f64; 4]) -> [[f64; 2]; 2] {
    let det = m[0] * m[3] - m[1] * m[2];
    if det == 0.0 {
        return [[f64::NAN; 2]; 2];
    }
    [[m[3] / det, -m[1] / det], [-m[2] / det, m[0] / det]]
}

fn quadratic2(w: &[[f64; 2]; 2], r: &[f64; 2]) -> f64 {
    r[0] * (w[0][0] * r[0] + w[0][1] * r[1]) + r[1] * (w[1][0] * r[0] + w[1][1] * r[1])
}

/// Gauss-Newton from the rays' midpoint; the Jacobian and residual at the solution (zero
/// for views not used).
fn solve(
    cameras: &[Camera],
    centers: &[[f64; 3]],
    obs: &[[f64; 2]],
    weight: &[[[f64; 2]; 2]],
    used: &[bool],
    options: IntersectOptions,
) -> Solved {
    let mut x = midpoint(cameras, centers, obs, used);
    let mut converged = false;
    let (mut jac, mut resid) = linearised(cameras, obs, used, &x);
    for _ in 0..options.iterations {
        let mut info = Matrix3::zeros();
        let mut gradient = Vector3::zeros();
        for k in (0..cameras.len()).filter(|&k| used[k]) {
            let (j, w, r) = (&jac[k], &weight[k], &resid[k]);
            // J^T W (3x2).
            let jtw: [[f64; 2]; 3] = std::array::from_fn(|i| {
                std::array::from_fn(|b| j[0][i] * w[0][b] + j[1][i] * w[1][b])
            });
            for i in 0..3 {
                for l in 0..3 {
                    info[(i, l)] += jtw[i][0] * j[0][l] + jtw[i][1] * j[1][l];
                }
                gradient[i] += jtw[i][0] * r[0] + jtw[i][1] * r[1];
            }
        }
        let step = solve3(&info, &gradient);
        x += step;
        converged = step.norm() <= options.step_tolerance;
        (jac, resid) = linearised(cameras, obs, used, &x);
        if converged {
            break;
        }
    }
    Solved {
        x,
        jac,
        resid,
        converged,
    }
}

/// The point nearest to the used views' rays: `sum (I - d d^T) X = sum (I - d d^T) C`.
fn midpoint(
    cameras: &[Camera],
    centers: &[[f64; 3]],
    obs: &[[f64; 2]],
    used: &[bool],
) -> Vector3<f64> {
    let mut lhs = Matrix3::zeros();
    let mut rhs = Vector3::zeros();
    for k in (0..cameras.len()).filter(|&k| used[k]) {
        let d = cameras[k].ray_direction(obs[k]);
        if !d.iter().all(|v| v.is_finite()) {
            continue;
        }
        let d = Vector3::from(d);
        let proj = Matrix3::identity() - d * d.transpose();
        lhs += proj;
        rhs += proj * Vector3::from(centers[k]);
    }
    solve3(&lhs, &rhs)
}

/// Jacobian and residual of every used view at `x` (zero for the others).
fn linearised(
    cameras: &[Camera],
    obs: &[[f64; 2]],
    used: &[bool],
    x: &Vector3<f64>,
) -> (Vec<[[f64; 3]; 2]>, Vec<[f64; 2]>) {
    let p = [x[0], x[1], x[2]];
    let mut jac = vec![[[0.0; 3]; 2]; cameras.len()];
    let mut resid = vec![[0.0; 2]; cameras.len()];
    for k in (0..cameras.len()).filter(|&k| used[k]) {
        let (uv, j) = cameras[k].project_jacobian(&p);
        resid[k] = [obs[k][0] - uv[0], obs[k][1] - uv[1]];
        jac[k] = j;
    }
    (jac, resid)
}

/// `a^-1 b`; NaN where `a` is not finite or singular (fewer than two rays).
fn solve3(a: &Matrix3<f64>, b: &Vector3<f64>) -> Vector3<f64> {
    if !a.iter().all(|v| v.is_finite()) || a.determinant() == 0.0 {
        return Vector3::repeat(f64::NAN);
    }
    a.lu().solve(b).unwrap_or_else(|| Vector3::repeat(f64::NAN))
}

/// `sum_c J_c^T W_c J_c` over the used views.
fn normal(jac: &[[[f64; 3]; 2]], weight: &[[[f64; 2]; 2]], used: &[bool]) -> Matrix3<f64> {
    let mut info = Matrix3::zeros();
    for k in (0..jac.len()).filter(|&k| used[k]) {
        let (j, w) = (&jac[k], &weight[k]);
        for i in 0..3 {
            for l in 0..3 {
                let mut sum = 0.0;
                for a in 0..2 {
                    for b in 0..2 {
                        sum += j[a][i] * w[a][b] * j[b][l];
                    }
                }
                info[(i, l)] += sum;
            }
        }
    }
    info
}

/// The inverse of a symmetric positive semi-definite normal matrix, symmetric positive
/// definite by construction: `V diag(1 / max(w, CONDITION w_max)) V^T` of its symmetric
/// part; NaN where it is not finite, singular or has no positive eigenvalue.
fn inverse_normal(a: &Matrix3<f64>) -> Matrix3<f64> {
    let nan = Matrix3::repeat(f64::NAN);
    if !a.iter().all(|v| v.is_finite()) || a.determinant() == 0.0 {
        return nan;
    }
    let sym = 0.5 * (a + a.transpose());
    let eigen = SymmetricEigen::new(sym);
    let top = eigen.eigenvalues.max();
    if !(top > 0.0) {
        return nan;
    }
    let inv_w = eigen.eigenvalues.map(|w| 1.0 / w.max(CONDITION * top));
    let v = &eigen.eigenvectors;
    let inv = v * Matrix3::from_diagonal(&inv_w) * v.transpose();
    0.5 * (inv + inv.transpose())
}

/// The larger of a view's two normalised residuals `|r_i| / sqrt(Q_rr,ii)`, `Q_rr = Sigma -
/// J Sigma_X J^T`; NaN where neither coordinate is determined (the Python
/// `_normalised_residuals`).
fn normalised_residual(
    cov: &[f64; 4],
    jac: &[[f64; 3]; 2],
    point_cov: &Matrix3<f64>,
    resid: &[f64; 2],
) -> f64 {
    let mut best = f64::NAN;
    for a in 0..2 {
        let diag = cov[3 * a];
        let j = Vector3::new(jac[a][0], jac[a][1], jac[a][2]);
        let q = diag - (j.transpose() * point_cov * j)[0];
        let scale = diag.abs().sqrt();
        if q > DETERMINED * (scale * scale) {
            let w = resid[a].abs() / q.sqrt();
            // numpy's nanmax over the two coordinates: NaN only when both are.
            if !w.is_nan() && (best.is_nan() || w > best) {
                best = w;
            }
        }
    }
    best
}

#[cfg(test)]
mod tests;
