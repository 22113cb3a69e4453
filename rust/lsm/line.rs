//! The epipolar line a match may be held on, and the test of a runaway affine map.

use super::dense::MAX;
use super::gauss_newton::State;

const U: usize = MAX;

/// A line `normal . y + distance = 0` in search pixels, `|normal| = 1`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Line {
    pub normal: [f64; 2],
    pub distance: f64,
}

impl Line {
    /// From `a u + b v + c = 0`; `None` when not finite or `(a, b) = 0` (no constraint).
    pub fn new(coefficients: [f64; 3]) -> Option<Self> {
        let [a, b, c] = coefficients;
        let norm = a.hypot(b);
        (norm > 0.0 && norm.is_finite() && c.is_finite()).then(|| Self {
            normal: [a / norm, b / norm],
            distance: c / norm,
        })
    }

    pub(crate) fn signed_distance(&self, y: [f64; 2]) -> f64 {
        self.normal[0] * y[0] + self.normal[1] * y[1] + self.distance
    }

    /// The constraint on a step, `c . step = h`, that puts the new centre on the line.
    pub(crate) fn on_step(&self, state: &State) -> ([f64; U], f64) {
        let [a11, a12, a21, a22] = state.a;
        let [la, lb] = self.normal;
        let mut c = [0.0; U];
        c[0] = a11 * la + a21 * lb;
        c[1] = a12 * la + a22 * lb;
        (c, -self.signed_distance(state.b))
    }
}

/// Whether the map `a` has run away from `start`: a reflection, or a singular value of
/// `a start^-1` outside `[1 / max_scale, max_scale]`.
pub(crate) fn degenerate(a: [f64; 4], start: [f64; 4], max_scale: f64) -> bool {
    let det0 = start[0] * start[3] - start[1] * start[2];
    let inv = [
        start[3] / det0,
        -start[1] / det0,
        -start[2] / det0,
        start[0] / det0,
    ];
    let m = [
        a[0] * inv[0] + a[1] * inv[2],
        a[0] * inv[1] + a[1] * inv[3],
        a[2] * inv[0] + a[3] * inv[2],
        a[2] * inv[1] + a[3] * inv[3],
    ];
    let e = 0.5 * (m[0] + m[3]);
    let f = 0.5 * (m[0] - m[3]);
    let g = 0.5 * (m[2] + m[1]);
    let h = 0.5 * (m[2] - m[1]);
    let q = e.hypot(h);
    let r = f.hypot(g);
    let (largest, smallest) = (q + r, q - r);
    // Written so that NaN counts as degenerate.
    !(smallest > 1.0 / max_scale && largest < max_scale)
}
