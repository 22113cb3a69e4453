//! The seeding's visual-hull test of ray samples in one camera: from camera coordinates to
//! the pixel, whether it is seen, and the mask there, in one pass.
//!
//! A seeding frame tests ~10^7 ray samples against the other cameras' masks
//! (benches/README.md "seedframe1"); in numpy each of the ~25 element-wise operations of
//! the pinhole and lens model is a pass over all of them, and the mask read a gather. Here
//! each sample's operations are the same IEEE operations in the same order as
//! `elastocap.tracking.seeding._seen_pixels` (itself `Camera.project`'s, without the lens
//! terms whose coefficient is zero: the same skips here), so the pixel, the footprint test
//! and the mask read agree bit for bit. The rotation into the camera (a BLAS product in
//! numpy, whose summation order is the library's) stays with the caller.

use crate::camera::DIST_LEN;

/// A camera's intrinsics as the hull test uses them.
#[derive(Debug, Clone, Copy)]
pub struct HullCamera {
    /// The 3x3 intrinsic matrix (upper triangular; `k[0][1]` the skew).
    pub k: [[f64; 3]; 3],
    /// OpenCV's coefficients k1 k2 p1 p2 k3 k4 k5 k6 s1 s2 s3 s4 (zeros padded).
    pub dist: [f64; DIST_LEN],
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
}

impl HullCamera {
    /// Pixel `(u, v)` of camera coordinates `x` (no check: NaN or infinite where the
    /// depth is zero), the operations of `_seen_pixels` in its order.
    #[inline]
    pub fn pixel(&self, x: [f64; 3]) -> [f64; 2] {
        let [k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4] = self.dist;
        let (a, b) = (x[0] / x[2], x[1] / x[2]);
        let (mut a2, mut b2) = (a, b);
        if self.dist.iter().any(|&c| c != 0.0) {
            let r2 = a * a + b * b;
            let mut radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
            if k4 != 0.0 || k5 != 0.0 || k6 != 0.0 {
                radial /= 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6));
            }
            a2 = a * radial;
            b2 = b * radial;
            if p1 != 0.0 {
                a2 += 2.0 * p1 * a * b;
                b2 += p1 * (r2 + 2.0 * b * b);
            }
            if p2 != 0.0 {
                a2 += p2 * (r2 + 2.0 * a * a);
                b2 += 2.0 * p2 * a * b;
            }
            if s1 != 0.0 || s2 != 0.0 {
                a2 += r2 * (s1 + r2 * s2);
            }
            if s3 != 0.0 || s4 != 0.0 {
                b2 += r2 * (s3 + r2 * s4);
            }
        }
        let k = &self.k;
        [
            k[0][0] * a2 + k[0][1] * b2 + k[0][2],
            k[1][1] * b2 + k[1][2],
        ]
    }

    /// Whether camera coordinates `x` are seen (in front, inside the image's pixel
    /// footprints), and if so the mask (row-major, `width x height`) at the nearest pixel
    /// (ties to even, as numpy's `rint`): `(held, seen)`, held true where not seen.
    #[inline]
    pub fn held(&self, x: [f64; 3], mask: &[bool]) -> (bool, bool) {
        let [u, v] = self.pixel(x);
        let seen = x[2] > 0.0
            && u >= -0.5
            && u < self.width as f64 - 0.5
            && v >= -0.5
            && v < self.height as f64 - 0.5;
        if !seen {
            return (true, false);
        }
        // In the footprint: both round to a pixel of the image.
        let (iu, iv) = (u.round_ties_even() as usize, v.round_ties_even() as usize);
        (mask[iv * self.width + iu], true)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera(dist: [f64; DIST_LEN]) -> HullCamera {
        HullCamera {
            k: [[800.0, 0.3, 320.0], [0.0, 790.0, 240.0], [0.0, 0.0, 1.0]],
            dist,
            width: 640,
            height: 480,
        }
    }

    #[test]
    fn pinhole_without_distortion() {
        let cam = camera([0.0; DIST_LEN]);
        let [u, v] = cam.pixel([0.1, -0.2, 2.0]);
        assert_eq!(u, 800.0 * 0.05 + 0.3 * -0.1 + 320.0);
        assert_eq!(v, 790.0 * -0.1 + 240.0);
    }

    #[test]
    fn seen_and_mask_read_at_the_rounded_pixel() {
        let cam = camera([
            -0.1, 0.02, 0.001, -0.002, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
        ]);
        let mut mask = vec![false; 640 * 480];
        let x = [0.05, 0.03, 1.5];
        let [u, v] = cam.pixel(x);
        mask[v.round() as usize * 640 + u.round() as usize] = true;
        assert_eq!(cam.held(x, &mask), (true, true));
        mask[v.round() as usize * 640 + u.round() as usize] = false;
        assert_eq!(cam.held(x, &mask), (false, true));
        // Behind the camera, and outside the image: not seen, held.
        assert_eq!(cam.held([0.05, 0.03, -1.5], &mask), (true, false));
        assert_eq!(cam.held([5.0, 0.03, 1.0], &mask), (true, false));
    }

    #[test]
    fn a_zero_coefficient_changes_nothing() {
        // The skipped terms add exact zeros: with a rational term whose coefficients are
        // tiny but nonzero the pixel moves, with zeros it equals the plain polynomial.
        let plain = camera([
            -0.1, 0.02, 0.0, 0.0, 0.003, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
        ]);
        let mut rational = plain;
        rational.dist[5] = 1e-3;
        let x = [0.2, -0.1, 1.0];
        assert_ne!(plain.pixel(x), rational.pixel(x));
        let (a, b) = (0.2, -0.1);
        let r2: f64 = a * a + b * b;
        let radial = 1.0 + r2 * (-0.1 + r2 * (0.02 + r2 * 0.003));
        assert_eq!(
            plain.pixel(x),
            [
                800.0 * (a * radial) + 0.3 * (b * radial) + 320.0,
                790.0 * (b * radial) + 240.0
            ]
        );
    }
}
