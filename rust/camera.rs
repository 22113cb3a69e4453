//! Pinhole cameras with OpenCV distortion and skew: the projection the Rust kernels need.
//!
//! World -> camera: $x = R X + t$; $(a, b) = (x / z, y / z)$; with $r^2 = a^2 + b^2$,
//! OpenCV's rational radial factor
//! $q = (1 + k_1 r^2 + k_2 r^4 + k_3 r^6) / (1 + k_4 r^2 + k_5 r^4 + k_6 r^6)$,
//! $a' = a q + 2 p_1 a b + p_2 (r^2 + 2 a^2) + s_1 r^2 + s_2 r^4$,
//! $b' = b q + p_1 (r^2 + 2 b^2) + 2 p_2 a b + s_3 r^2 + s_4 r^4$;
//! pixel $= K [a', b', 1]^\top$ with the full $K$, skew included (SPEC 1). Pixel $(u, v)$ =
//! (column, row), origin at the centre of the top-left pixel. The Python `Camera`
//! (`elastocap.cameras.distortion`) implements the same model in numpy.
//!
//! Points beyond the radius where the radial factor folds over ($r q(r^2)$ stops
//! increasing, or the denominator vanishes) are outside the lens model's range: they
//! would map to spurious pixels, often inside the image, so [`Camera::project`] treats
//! them like points behind the camera (the Python `Camera.visible` does the same).

use nalgebra::DMatrix;

use crate::error::{check_finite, Error, Result};

mod lens;

/// OpenCV's distortion coefficients elastocap models: k1 k2 p1 p2 k3 k4 k5 k6 s1 s2 s3 s4.
pub const DIST_LEN: usize = 12;

/// A root of the fold polynomial counts as real when its imaginary part is below this
/// (relative to its size), as in the Python `fold_radius`.
const REAL_ROOT_RTOL: f64 = 1e-12;

/// A calibrated camera.
#[derive(Debug, Clone)]
pub struct Camera {
    k: [[f64; 3]; 3],
    dist: [f64; DIST_LEN],
    r: [[f64; 3]; 3],
    t: [f64; 3],
    /// Squared normalised radius where the distortion folds over (infinite if never).
    fold2: f64,
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
}

impl Camera {
    /// A camera from its intrinsics `k` (row-major 3x3), OpenCV distortion `dist` (4, 5, 8,
    /// 12 or 14 coefficients in OpenCV's order; the 14-coefficient tilt terms must be zero),
    /// rotation `r` (row-major 3x3), translation `t` and image size.
    ///
    /// # Errors
    /// [`Error::NonFinite`] for a non-finite parameter, [`Error::BadCamera`] for an empty
    /// image, a distortion vector of another length or a non-zero sensor tilt.
    pub fn new(
        k: [f64; 9],
        dist: impl AsRef<[f64]>,
        r: [f64; 9],
        t: [f64; 3],
        width: usize,
        height: usize,
    ) -> Result<Self> {
        let dist = dist.as_ref();
        check_finite("camera parameters", &[k, r])?;
        if let Some(row) = dist.iter().position(|v| !v.is_finite()) {
            return Err(Error::NonFinite {
                argument: "camera distortion",
                row,
            });
        }
        check_finite("camera parameters", &[t])?;
        if width == 0 || height == 0 {
            return Err(Error::BadCamera {
                reason: "image size must be positive",
            });
        }
        if ![4, 5, 8, 12, 14].contains(&dist.len()) {
            return Err(Error::BadCamera {
                reason: "distortion must have 4, 5, 8, 12 or 14 coefficients (OpenCV's order)",
            });
        }
        if dist.len() == 14 && (dist[12] != 0.0 || dist[13] != 0.0) {
            return Err(Error::BadCamera {
                reason: "tilted-sensor distortion (tauX, tauY) is not supported",
            });
        }
        let mut full = [0.0; DIST_LEN];
        let used = dist.len().min(DIST_LEN);
        full[..used].copy_from_slice(&dist[..used]);
        let rows = |m: [f64; 9]| [[m[0], m[1], m[2]], [m[3], m[4], m[5]], [m[6], m[7], m[8]]];
        Ok(Camera {
            k: rows(k),
            dist: full,
            r: rows(r),
            t,
            fold2: fold_radius_squared(&full),
            width,
            height,
        })
    }

    /// The normalised radius beyond which the lens model folds over (`inf` if never).
    pub fn fold_radius(&self) -> f64 {
        self.fold2.sqrt()
    }

    /// Pixel of world point `p`, or `None` when it is not in front of the camera or lies
    /// beyond the fold radius.
    #[inline]
    pub fn project(&self, p: &[f64; 3]) -> Option<[f64; 2]> {
        let x: [f64; 3] = std::array::from_fn(|i| {
            self.r[i][0] * p[0] + self.r[i][1] * p[1] + self.r[i][2] * p[2] + self.t[i]
        });
        if x[2] <= 0.0 {
            return None;
        }
        let (a, b) = (x[0] / x[2], x[1] / x[2]);
        if !(a * a + b * b < self.fold2) {
            return None;
        }
        let [ad, bd] = lens::distort(&self.dist, a, b);
        let k = &self.k;
        Some([
            k[0][0] * ad + k[0][1] * bd + k[0][2],
            k[1][1] * bd + k[1][2],
        ])
    }
}

/// Product of two polynomials with ascending coefficients.
fn poly_mul(a: &[f64], b: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0; a.len() + b.len() - 1];
    for (i, x) in a.iter().enumerate() {
        for (j, y) in b.iter().enumerate() {
            out[i + j] += x * y;
        }
    }
    out
}

/// Smallest positive real root of a polynomial (ascending coefficients), from the
/// eigenvalues of its companion matrix (what numpy's `polyroots` does); `inf` if none.
fn smallest_positive_root(ascending: &[f64]) -> f64 {
    // Leading terms below a rounding error of the largest only place roots where
    // |s| > eps^(-1/degree) (r > 400 for a cubic), far beyond any lens, and scale the
    // companion matrix by 1 / lead until its eigenvalues are noise: leave them out.
    let largest = ascending.iter().fold(0.0_f64, |m, c| m.max(c.abs()));
    let negligible = f64::EPSILON * largest;
    let degree = match ascending.iter().rposition(|&c| c.abs() > negligible) {
        Some(d) if d >= 1 => d,
        _ => return f64::INFINITY,
    };
    let lead = ascending[degree];
    let companion = DMatrix::from_fn(degree, degree, |i, j| {
        if j == degree - 1 {
            -ascending[i] / lead
        } else if i == j + 1 {
            1.0
        } else {
            0.0
        }
    });
    companion
        .complex_eigenvalues()
        .iter()
        .filter(|z| z.im.abs() <= REAL_ROOT_RTOL * z.norm().max(1.0) && z.re > 0.0)
        .map(|z| z.re)
        .fold(f64::INFINITY, f64::min)
}

/// Squared fold radius: with $s = r^2$, $N = 1 + k_1 s + k_2 s^2 + k_3 s^3$ and
/// $D = 1 + k_4 s + k_5 s^2 + k_6 s^3$, $d/dr [r N/D] = ((N + 2 s N') D - 2 s N D') / D^2$;
/// the smallest positive root of its numerator or of $D$.
fn fold_radius_squared(dist: &[f64; DIST_LEN]) -> f64 {
    let [k1, k2, _, _, k3, k4, k5, k6, ..] = *dist;
    let d = [1.0, k4, k5, k6];
    let n_plus = [1.0, 3.0 * k1, 5.0 * k2, 7.0 * k3]; // N + 2 s N'
    let s_n = [0.0, 1.0, k1, k2, k3]; // s N
    let d_prime = [k4, 2.0 * k5, 3.0 * k6];
    let first = poly_mul(&n_plus, &d);
    let second = poly_mul(&s_n, &d_prime);
    let slope: Vec<f64> = (0..first.len().max(second.len()))
        .map(|i| first.get(i).copied().unwrap_or(0.0) - 2.0 * second.get(i).copied().unwrap_or(0.0))
        .collect();
    smallest_positive_root(&slope).min(smallest_positive_root(&d))
}

#[cfg(test)]
mod tests {
    use super::*;

    const IDENTITY: [f64; 9] = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    const K: [f64; 9] = [500.0, 2.0, 320.0, 0.0, 510.0, 240.0, 0.0, 0.0, 1.0];

    #[test]
    fn projects_with_skew_and_distortion() {
        let cam = Camera::new(
            K,
            [0.1, -0.05, 0.001, 0.002, 0.01],
            IDENTITY,
            [0.0, 0.0, 2.0],
            640,
            480,
        )
        .unwrap();
        let [u, v] = cam.project(&[0.2, -0.1, 0.0]).unwrap();
        let (a, b) = (0.1f64, -0.05f64);
        let r2 = a * a + b * b;
        let radial = 1.0 + 0.1 * r2 - 0.05 * r2 * r2 + 0.01 * r2 * r2 * r2;
        let ad = a * radial + 2.0 * 0.001 * a * b + 0.002 * (r2 + 2.0 * a * a);
        let bd = b * radial + 0.001 * (r2 + 2.0 * b * b) + 2.0 * 0.002 * a * b;
        assert!((u - (500.0 * ad + 2.0 * bd + 320.0)).abs() < 1e-12);
        assert!((v - (510.0 * bd + 240.0)).abs() < 1e-12);
        assert!(cam.project(&[0.0, 0.0, -3.0]).is_none());
    }

    #[test]
    fn rational_and_thin_prism_terms() {
        let dist = [
            0.1, -0.05, 0.001, 0.002, 0.01, 0.05, 0.01, -0.002, 0.003, -0.001, 0.002, 0.0005,
        ];
        let cam = Camera::new(K, dist, IDENTITY, [0.0, 0.0, 2.0], 640, 480).unwrap();
        let [u, v] = cam.project(&[0.2, -0.1, 0.0]).unwrap();
        let (a, b) = (0.1f64, -0.05f64);
        let r2 = a * a + b * b;
        let num = 1.0 + 0.1 * r2 - 0.05 * r2 * r2 + 0.01 * r2.powi(3);
        let den = 1.0 + 0.05 * r2 + 0.01 * r2 * r2 - 0.002 * r2.powi(3);
        let q = num / den;
        let ad =
            a * q + 2.0 * 0.001 * a * b + 0.002 * (r2 + 2.0 * a * a) + 0.003 * r2 - 0.001 * r2 * r2;
        let bd = b * q
            + 0.001 * (r2 + 2.0 * b * b)
            + 2.0 * 0.002 * a * b
            + 0.002 * r2
            + 0.0005 * r2 * r2;
        assert!((u - (500.0 * ad + 2.0 * bd + 320.0)).abs() < 1e-10);
        assert!((v - (510.0 * bd + 240.0)).abs() < 1e-10);
    }

    #[test]
    fn fold_radius_of_barrel_distortion() {
        // r (1 + k1 r^2) folds where 1 + 3 k1 r^2 = 0.
        let cam = Camera::new(K, [-0.5, 0.0, 0.0, 0.0], IDENTITY, [0.0; 3], 640, 480).unwrap();
        assert!((cam.fold_radius() - (1.0f64 / 1.5).sqrt()).abs() < 1e-12);
        // Beyond it a point is not projected, even though its pixel would be finite.
        assert!(cam.project(&[1.0, 0.0, 1.0]).is_none());
        assert!(cam.project(&[0.5, 0.0, 1.0]).is_some());
        let none = Camera::new(K, [0.1, 0.0, 0.0, 0.0, 0.0], IDENTITY, [0.0; 3], 640, 480).unwrap();
        assert!(none.fold_radius().is_infinite());
        // A vanishing denominator 1 + k4 r^2 limits the range too.
        let pole = Camera::new(
            K,
            [0.0, 0.0, 0.0, 0.0, 0.0, -0.25, 0.0, 0.0],
            IDENTITY,
            [0.0; 3],
            640,
            480,
        )
        .unwrap();
        assert!(pole.fold_radius() <= 2.0 + 1e-12);
    }

    #[test]
    fn refuses_other_lengths_and_tilt() {
        assert!(Camera::new(K, [0.0; 6], IDENTITY, [0.0; 3], 640, 480).is_err());
        let mut tilted = [0.0; 14];
        tilted[12] = 0.01;
        assert!(Camera::new(K, tilted, IDENTITY, [0.0; 3], 640, 480).is_err());
        assert!(Camera::new(K, [0.0; 14], IDENTITY, [0.0; 3], 640, 480).is_ok());
    }
}
