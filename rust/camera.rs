//! Pinhole cameras with OpenCV distortion and skew: the projection the Rust kernels need.
//!
//! World -> camera: $x = R X + t$; $(a, b) = (x / z, y / z)$; OpenCV's radial (k1, k2, k3)
//! and tangential (p1, p2) distortion; pixel $= K [a', b', 1]^\top$ with the full $K$,
//! skew included (SPEC 1). Pixel $(u, v)$ = (column, row), origin at the centre of the
//! top-left pixel. The Python `Camera` implements the same model in numpy.

use crate::error::{check_finite, Error, Result};

/// A calibrated camera.
#[derive(Debug, Clone)]
pub struct Camera {
    k: [[f64; 3]; 3],
    dist: [f64; 5],
    r: [[f64; 3]; 3],
    t: [f64; 3],
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
}

impl Camera {
    /// A camera from its intrinsics `k` (row-major 3x3), distortion `(k1, k2, p1, p2, k3)`,
    /// rotation `r` (row-major 3x3), translation `t` and image size.
    ///
    /// # Errors
    /// [`Error::NonFinite`] for a non-finite parameter, [`Error::BadCamera`] for an empty
    /// image.
    pub fn new(
        k: [f64; 9],
        dist: [f64; 5],
        r: [f64; 9],
        t: [f64; 3],
        width: usize,
        height: usize,
    ) -> Result<Self> {
        check_finite("camera parameters", &[k, r])?;
        check_finite("camera parameters", &[dist])?;
        check_finite("camera parameters", &[t])?;
        if width == 0 || height == 0 {
            return Err(Error::BadCamera {
                reason: "image size must be positive",
            });
        }
        let rows = |m: [f64; 9]| [[m[0], m[1], m[2]], [m[3], m[4], m[5]], [m[6], m[7], m[8]]];
        Ok(Camera {
            k: rows(k),
            dist,
            r: rows(r),
            t,
            width,
            height,
        })
    }

    /// Pixel of world point `p`, or `None` when it is not in front of the camera.
    #[inline]
    pub fn project(&self, p: &[f64; 3]) -> Option<[f64; 2]> {
        let x: [f64; 3] = std::array::from_fn(|i| {
            self.r[i][0] * p[0] + self.r[i][1] * p[1] + self.r[i][2] * p[2] + self.t[i]
        });
        if x[2] <= 0.0 {
            return None;
        }
        let (a, b) = (x[0] / x[2], x[1] / x[2]);
        let [k1, k2, p1, p2, k3] = self.dist;
        let r2 = a * a + b * b;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        let ad = a * radial + 2.0 * p1 * a * b + p2 * (r2 + 2.0 * a * a);
        let bd = b * radial + p1 * (r2 + 2.0 * b * b) + 2.0 * p2 * a * b;
        let k = &self.k;
        Some([
            k[0][0] * ad + k[0][1] * bd + k[0][2],
            k[1][1] * bd + k[1][2],
        ])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn projects_with_skew_and_distortion() {
        let cam = Camera::new(
            [500.0, 2.0, 320.0, 0.0, 510.0, 240.0, 0.0, 0.0, 1.0],
            [0.1, -0.05, 0.001, 0.002, 0.01],
            [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
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
}
