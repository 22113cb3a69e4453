//! The camera model's derivatives and its inverse, for the forward intersection: the
//! projection with its analytic Jacobian (no fold or depth check: Gauss-Newton needs the
//! model's value wherever it steps), and the ray through a pixel, the distortion inverted by
//! Newton's method exactly as the Python `elastocap.cameras.distortion.undistort` does (same
//! start, step shortening, stopping rules and failure test), so that both start the
//! intersection from the same midpoint to rounding.

use super::{Camera, DIST_LEN};

/// Newton's step below which the inversion stops (normalised coordinates; Python's
/// `UNDISTORT_STEP_TOL`).
const UNDISTORT_STEP_TOL: f64 = 1e-15;
/// Newton iterations at most (Python's `UNDISTORT_MAX_ITERATIONS`).
const UNDISTORT_MAX_ITERATIONS: usize = 50;
/// Largest distortion residual of an accepted inversion (Python's `UNDISTORT_RESIDUAL_TOL`).
const UNDISTORT_RESIDUAL_TOL: f64 = 1e-10;

/// `max` that propagates NaN, as numpy's `maximum` does (`f64::max` ignores it).
#[inline]
fn nan_max(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else {
        a.max(b)
    }
}

/// The distortion map of normalised coordinates `(a, b)` (without k4..k6 the denominator
/// is exactly 1: the division changes nothing).
#[inline]
pub(crate) fn distort(dist: &[f64; DIST_LEN], a: f64, b: f64) -> [f64; 2] {
    let [k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4] = *dist;
    let r2 = a * a + b * b;
    let radial = (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1.0 + r2 * (k4 + r2 * (k5 + r2 * k6)));
    [
        a * radial + 2.0 * p1 * a * b + p2 * (r2 + 2.0 * a * a) + r2 * (s1 + r2 * s2),
        b * radial + p1 * (r2 + 2.0 * b * b) + 2.0 * p2 * a * b + r2 * (s3 + r2 * s4),
    ]
}

/// The distortion map at `(a, b)` and its Jacobian `[[da'/da, da'/db], [db'/da, db'/db]]`.
#[inline]
pub(crate) fn distort_jacobian(
    dist: &[f64; DIST_LEN],
    a: f64,
    b: f64,
) -> ([f64; 2], [[f64; 2]; 2]) {
    let [k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4] = *dist;
    let r2 = a * a + b * b;
    let numerator = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
    let denominator = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6));
    let radial = numerator / denominator;
    // d radial / d r2, by the quotient rule.
    let dradial = ((k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)) * denominator
        - numerator * (k4 + r2 * (2.0 * k5 + 3.0 * k6 * r2)))
        / (denominator * denominator);
    let dprism_a = s1 + 2.0 * s2 * r2;
    let dprism_b = s3 + 2.0 * s4 * r2;
    let value = [
        a * radial + 2.0 * p1 * a * b + p2 * (r2 + 2.0 * a * a) + r2 * (s1 + r2 * s2),
        b * radial + p1 * (r2 + 2.0 * b * b) + 2.0 * p2 * a * b + r2 * (s3 + r2 * s4),
    ];
    // With d r2/da = 2a, d r2/db = 2b.
    let cross = 2.0 * a * b * dradial + 2.0 * p1 * a + 2.0 * p2 * b;
    let jacobian = [
        [
            radial + 2.0 * a * a * dradial + 2.0 * p1 * b + 6.0 * p2 * a + 2.0 * a * dprism_a,
            cross + 2.0 * b * dprism_a,
        ],
        [
            cross + 2.0 * a * dprism_b,
            radial + 2.0 * b * b * dradial + 6.0 * p1 * b + 2.0 * p2 * a + 2.0 * b * dprism_b,
        ],
    ];
    (value, jacobian)
}

impl Camera {
    /// Pixel of world point `p` and its Jacobian `(2, 3)` with respect to `p`, whatever its
    /// depth or radius (NaN or infinite values where the model is undefined, as numpy's).
    #[inline]
    pub fn project_jacobian(&self, p: &[f64; 3]) -> ([f64; 2], [[f64; 3]; 2]) {
        let r = &self.r;
        let x: [f64; 3] =
            std::array::from_fn(|i| r[i][0] * p[0] + r[i][1] * p[1] + r[i][2] * p[2] + self.t[i]);
        let z = x[2];
        let (a, b) = (x[0] / z, x[1] / z);
        let (d, lens) = distort_jacobian(&self.dist, a, b);
        let k = &self.k;
        let uv = [
            k[0][0] * d[0] + k[0][1] * d[1] + k[0][2],
            k[1][0] * d[0] + k[1][1] * d[1] + k[1][2],
        ];
        // d(a, b)/d(x_cam) = [[1/z, 0, -a/z], [0, 1/z, -b/z]]; chain K2 . lens . dab . R.
        let kl: [[f64; 2]; 2] = std::array::from_fn(|i| {
            std::array::from_fn(|j| k[i][0] * lens[0][j] + k[i][1] * lens[1][j])
        });
        let dab = [[1.0 / z, 0.0, -a / z], [0.0, 1.0 / z, -b / z]];
        let kld: [[f64; 3]; 2] = std::array::from_fn(|i| {
            std::array::from_fn(|j| kl[i][0] * dab[0][j] + kl[i][1] * dab[1][j])
        });
        let jacobian = std::array::from_fn(|i| {
            std::array::from_fn(|j| kld[i][0] * r[0][j] + kld[i][1] * r[1][j] + kld[i][2] * r[2][j])
        });
        (uv, jacobian)
    }

    /// The camera centre `-R^T t` (world).
    pub fn center(&self) -> [f64; 3] {
        let (r, t) = (&self.r, &self.t);
        std::array::from_fn(|j| -(r[0][j] * t[0] + r[1][j] * t[1] + r[2][j] * t[2]))
    }

    /// Unit direction (world) of the ray through pixel `uv`; NaN where no ray within the
    /// fold radius reaches it (Python's `Camera.rays`).
    pub fn ray_direction(&self, uv: [f64; 2]) -> [f64; 3] {
        let k = &self.k;
        let (fx, s, cx, fy, cy) = (k[0][0], k[0][1], k[0][2], k[1][1], k[1][2]);
        // K^-1 as the Python camera writes it (upper triangular K).
        let target = [
            uv[0] * (1.0 / fx) + uv[1] * (-s / (fx * fy)) + (s * cy - cx * fy) / (fx * fy),
            uv[0] * 0.0 + uv[1] * (1.0 / fy) + (-cy / fy),
        ];
        let [a, b] = self.undistort(target);
        let r = &self.r;
        let d: [f64; 3] = std::array::from_fn(|j| a * r[0][j] + b * r[1][j] + r[2][j]);
        let norm = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        d.map(|v| v / norm)
    }

    /// Normalised coordinates `(a, b)` whose distortion is `target`, inside the fold radius,
    /// by Newton's method with steps halved to stay inside; NaN where there is none.
    pub fn undistort(&self, target: [f64; 2]) -> [f64; 2] {
        let dist = &self.dist;
        if dist.iter().all(|&v| v == 0.0) {
            return target;
        }
        let limit = 0.999 * self.fold2.sqrt();
        let mut ab = target;
        let radius = ab[0].hypot(ab[1]);
        if radius >= limit {
            let shrink = 0.5 * limit / radius;
            ab = [ab[0] * shrink, ab[1] * shrink];
        }
        let mut active = ab[0].is_finite() && ab[1].is_finite();
        for _ in 0..UNDISTORT_MAX_ITERATIONS {
            if !active {
                break;
            }
            let [a, b] = ab;
            let (value, j) = distort_jacobian(dist, a, b);
            let (fa, fb) = (value[0] - target[0], value[1] - target[1]);
            let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
            let da = (j[1][1] * fa - j[0][1] * fb) / det;
            let db = (j[0][0] * fb - j[1][0] * fa) / det;
            let mut scale = 1.0;
            for _ in 0..60 {
                if (a - scale * da).hypot(b - scale * db) >= limit {
                    scale *= 0.5;
                } else {
                    break;
                }
            }
            ab = [a - scale * da, b - scale * db];
            let step = scale * nan_max(da.abs(), db.abs());
            let done = step <= UNDISTORT_STEP_TOL * nan_max(1.0, nan_max(ab[0].abs(), ab[1].abs()));
            if done || !step.is_finite() {
                active = false;
            }
        }
        let back = distort(dist, ab[0], ab[1]);
        let residual = nan_max((back[0] - target[0]).abs(), (back[1] - target[1]).abs());
        let bound =
            UNDISTORT_RESIDUAL_TOL * nan_max(1.0, nan_max(target[0].abs(), target[1].abs()));
        if residual <= bound {
            ab
        } else {
            [f64::NAN; 2]
        }
    }
}
