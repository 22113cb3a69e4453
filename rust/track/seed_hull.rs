//! The seeding's visual-hull test of ray samples: each sample into every other camera, the
//! pixel, whether it is seen and the mask there, one sample at a time.
//!
//! A seeding frame tests ~2 M ray samples against the other cameras' masks
//! (benches/README.md "seedframe1", "seedfast1"); in numpy each of the ~25 element-wise
//! operations of the pinhole and lens model was a pass over all of them, with a gather of
//! the samples still inside before each camera. Here each sample's operations are the same
//! IEEE operations in the same order as `elastocap.tracking.seeding._seen_pixels` (itself
//! `Camera.project`'s, without the lens terms whose coefficient is zero: the same skips
//! here), so the pixel, the footprint test and the mask read agree bit for bit.
//!
//! The rotation into the camera is numpy's `points @ R.T + t`, a BLAS product whose
//! summation order is the library's: OpenBLAS's kernels (Haswell and later) accumulate
//! `fma(x2, r2, fma(x1, r1, fma(x0, r0, 0)))`, then numpy adds `t`. [`HullView`] computes
//! exactly that, with fused multiply-adds, so the hull is numpy's to the bit on such a
//! machine (checked on every sample of a seeding frame, "seedfast1"); elsewhere it differs
//! from numpy's at rounding level only.

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

/// One camera that bounds the visual hull: its pose, intrinsics and mask.
#[derive(Debug, Clone, Copy)]
pub struct HullView<'a> {
    /// World-to-camera rotation (rows: the camera's axes).
    pub r: [[f64; 3]; 3],
    /// World-to-camera translation.
    pub t: [f64; 3],
    /// Intrinsics, lens and image size.
    pub camera: HullCamera,
    /// The silhouette, row-major `height x width`.
    pub mask: &'a [bool],
}

impl HullView<'_> {
    /// Camera coordinates `R p + t` of world point `p`, rounded as OpenBLAS's product
    /// (module docs): the dot product a chain of fused multiply-adds from zero.
    #[inline(always)]
    fn camera_frame(&self, p: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|j| {
            let r = self.r[j];
            p[2].mul_add(r[2], p[1].mul_add(r[1], p[0].mul_add(r[0], 0.0))) + self.t[j]
        })
    }
}

/// Whether world point `p` lies in the visual hull of `views`: finite, inside every
/// view's mask where that view sees it, and seen by at least `min_seen` of them (space few
/// cameras see is not bounded by the hull). The views are tried in order and the first
/// mask that does not hold the point ends the test (most ray samples leave the hull in the
/// first view tried).
#[inline(always)]
fn in_hull(p: [f64; 3], views: &[HullView<'_>], min_seen: usize) -> bool {
    if !p.iter().all(|c| c.is_finite()) {
        return false;
    }
    let mut seen_by = 0;
    for view in views {
        let (held, seen) = view.camera.held(view.camera_frame(p), view.mask);
        if !held {
            return false;
        }
        seen_by += usize::from(seen);
    }
    seen_by >= min_seen
}

/// Samples tested together: one AVX register of f64 (two SSE2 registers without AVX).
const LANES: usize = 4;
type Lanes = [f64; LANES];

/// `f` of each lane: every lane the same IEEE operations as the scalar code, which the
/// compiler turns into one vector instruction per operation (divisions and fused
/// multiply-adds are correctly rounded lane by lane, so the lanes equal the scalar path).
#[inline(always)]
fn lanes(f: impl Fn(usize) -> f64) -> Lanes {
    std::array::from_fn(f)
}

impl HullCamera {
    /// [`HullCamera::pixel`] of four camera-coordinate points (`x[axis][lane]`), lane by
    /// lane the same operations in the same order.
    #[inline(always)]
    fn pixels(&self, x: &[Lanes; 3]) -> [Lanes; 2] {
        let [k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4] = self.dist;
        let a = lanes(|i| x[0][i] / x[2][i]);
        let b = lanes(|i| x[1][i] / x[2][i]);
        let (mut a2, mut b2) = (a, b);
        if self.dist.iter().any(|&c| c != 0.0) {
            let r2 = lanes(|i| a[i] * a[i] + b[i] * b[i]);
            let mut radial = lanes(|i| 1.0 + r2[i] * (k1 + r2[i] * (k2 + r2[i] * k3)));
            if k4 != 0.0 || k5 != 0.0 || k6 != 0.0 {
                radial = lanes(|i| radial[i] / (1.0 + r2[i] * (k4 + r2[i] * (k5 + r2[i] * k6))));
            }
            a2 = lanes(|i| a[i] * radial[i]);
            b2 = lanes(|i| b[i] * radial[i]);
            if p1 != 0.0 {
                a2 = lanes(|i| a2[i] + 2.0 * p1 * a[i] * b[i]);
                b2 = lanes(|i| b2[i] + p1 * (r2[i] + 2.0 * b[i] * b[i]));
            }
            if p2 != 0.0 {
                a2 = lanes(|i| a2[i] + p2 * (r2[i] + 2.0 * a[i] * a[i]));
                b2 = lanes(|i| b2[i] + 2.0 * p2 * a[i] * b[i]);
            }
            if s1 != 0.0 || s2 != 0.0 {
                a2 = lanes(|i| a2[i] + r2[i] * (s1 + r2[i] * s2));
            }
            if s3 != 0.0 || s4 != 0.0 {
                b2 = lanes(|i| b2[i] + r2[i] * (s3 + r2[i] * s4));
            }
        }
        let k = &self.k;
        [
            lanes(|i| k[0][0] * a2[i] + k[0][1] * b2[i] + k[0][2]),
            lanes(|i| k[1][1] * b2[i] + k[1][2]),
        ]
    }
}

impl HullView<'_> {
    /// [`HullView::camera_frame`] of four world points (`p[axis][lane]`).
    #[inline(always)]
    fn camera_frames(&self, p: &[Lanes; 3]) -> [Lanes; 3] {
        std::array::from_fn(|j| {
            let r = self.r[j];
            lanes(|i| {
                p[2][i].mul_add(r[2], p[1][i].mul_add(r[1], p[0][i].mul_add(r[0], 0.0))) + self.t[j]
            })
        })
    }
}

/// [`in_hull`] of four points at once: the arithmetic of each view for all four (as long as
/// one is still in), the footprint test and mask read lane by lane. The views are tried
/// starting with the one that last put a whole group out (consecutive samples lie along
/// one ray: the view that refuses one mostly refuses the next); the answer is an AND over
/// the views and a count, whatever the order.
#[inline(always)]
fn in_hull4(
    p: &[[f64; 3]; LANES],
    views: &[HullView<'_>],
    min_seen: usize,
    first: &mut usize,
    out: &mut [bool],
) {
    let mut alive: [bool; LANES] = std::array::from_fn(|i| p[i].iter().all(|c| c.is_finite()));
    // Non-finite lanes are out; they still ride along in the arithmetic as zeros.
    let q: [Lanes; 3] = std::array::from_fn(|a| lanes(|i| if alive[i] { p[i][a] } else { 0.0 }));
    let mut seen_by = [0usize; LANES];
    let start = *first;
    let order = std::iter::once(start).chain((0..views.len()).filter(|&v| v != start));
    for v in order {
        if !alive.iter().any(|&a| a) {
            break;
        }
        let view = &views[v];
        let x = view.camera_frames(&q);
        let [u, w] = view.camera.pixels(&x);
        let cam = &view.camera;
        // The footprint's far edges, as `held`'s test.
        let (u_end, v_end) = (cam.width as f64 - 0.5, cam.height as f64 - 0.5);
        for i in 0..LANES {
            if !alive[i] {
                continue;
            }
            let seen =
                x[2][i] > 0.0 && u[i] >= -0.5 && u[i] < u_end && w[i] >= -0.5 && w[i] < v_end;
            if seen {
                let (iu, iv) = (
                    u[i].round_ties_even() as usize,
                    w[i].round_ties_even() as usize,
                );
                if !view.mask[iv * cam.width + iu] {
                    alive[i] = false;
                }
                seen_by[i] += 1;
            }
        }
        if !alive.iter().any(|&a| a) {
            *first = v;
        }
    }
    for i in 0..LANES {
        out[i] = alive[i] && seen_by[i] >= min_seen;
    }
}

/// [`in_hull`] of each of `points` into `out` (the same length), four at a time; `first`
/// the view to try first (updated to the last one that put a whole group out).
#[inline(always)]
pub(crate) fn hull_fill(
    points: &[[f64; 3]],
    views: &[HullView<'_>],
    min_seen: usize,
    first: &mut usize,
    out: &mut [bool],
) {
    if views.is_empty() {
        for (o, &p) in out.iter_mut().zip(points) {
            *o = in_hull(p, views, min_seen);
        }
        return;
    }
    let (groups, tail) = points.as_chunks::<LANES>();
    let (out_groups, out_tail) = out.split_at_mut(groups.len() * LANES);
    for (p, o) in groups.iter().zip(out_groups.chunks_exact_mut(LANES)) {
        in_hull4(p, views, min_seen, first, o);
    }
    for (o, &p) in out_tail.iter_mut().zip(tail) {
        *o = in_hull(p, views, min_seen);
    }
}

/// Pixels of `points` in `view`'s camera (its mask unused) into `uv`, and whether each is
/// seen (in front, inside the image's pixel footprints) into `seen`: four at a time.
#[inline(always)]
fn fill_pixels(points: &[[f64; 3]], view: &HullView<'_>, uv: &mut [[f64; 2]], seen: &mut [bool]) {
    let cam = &view.camera;
    let (u_end, v_end) = (cam.width as f64 - 0.5, cam.height as f64 - 0.5);
    let (groups, tail) = points.as_chunks::<LANES>();
    let n = groups.len() * LANES;
    for ((p, o), s) in groups
        .iter()
        .zip(uv[..n].chunks_exact_mut(LANES))
        .zip(seen[..n].chunks_exact_mut(LANES))
    {
        let q: [Lanes; 3] = std::array::from_fn(|a| lanes(|i| p[i][a]));
        let x = view.camera_frames(&q);
        let [u, w] = cam.pixels(&x);
        for i in 0..LANES {
            o[i] = [u[i], w[i]];
            s[i] = x[2][i] > 0.0 && u[i] >= -0.5 && u[i] < u_end && w[i] >= -0.5 && w[i] < v_end;
        }
    }
    for ((&p, o), s) in tail.iter().zip(&mut uv[n..]).zip(&mut seen[n..]) {
        let x = view.camera_frame(p);
        let [u, w] = cam.pixel(x);
        *o = [u, w];
        *s = x[2] > 0.0 && u >= -0.5 && u < u_end && w >= -0.5 && w < v_end;
    }
}

/// The pixels of world points `points` in `view`'s camera (`Camera.project`'s numbers where
/// finite, [`HullCamera::pixel`]) into `uv`, and whether each is seen into `seen`.
pub fn hull_pixels(
    points: &[[f64; 3]],
    view: &HullView<'_>,
    uv: &mut [[f64; 2]],
    seen: &mut [bool],
) {
    assert!(
        uv.len() == points.len() && seen.len() == points.len(),
        "one pixel per point"
    );
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU has AVX2 and FMA.
        unsafe { hull_pixels_wide(points, view, uv, seen) };
        return;
    }
    fill_pixels(points, view, uv, seen);
}

/// [`hull_pixels`] compiled for AVX2 and FMA (as [`hull_inside_wide`]).
///
/// # Safety
/// The CPU must have AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn hull_pixels_wide(
    points: &[[f64; 3]],
    view: &HullView<'_>,
    uv: &mut [[f64; 2]],
    seen: &mut [bool],
) {
    fill_pixels(points, view, uv, seen);
}

/// Where a seed's line scores nothing: both coordinates of a sample outside the hull, far
/// outside any image (`seed_points`' `-1e6`).
pub const OUTSIDE: f64 = -1e6;

/// One seed ray's samples `points` (D) as its partner scores them along the line: the
/// pixels in `view`'s camera of numpy's `nan_to_num` of each sample ([`hull_pixels`]), and
/// [`OUTSIDE`] where the sample is not `inside` the hull (D), into `uv` (D). `scratch`
/// (D points, D flags) is overwritten. `seed_points`' gather, `nan_to_num`, projection
/// and masking of the rows it scores, to the bit (benches/README.md, "seedpar1").
pub fn line_pixels(
    points: &[[f64; 3]],
    inside: &[bool],
    view: &HullView<'_>,
    uv: &mut [[f64; 2]],
    scratch: (&mut Vec<[f64; 3]>, &mut Vec<bool>),
) {
    assert!(
        inside.len() == points.len() && uv.len() == points.len(),
        "one flag and one pixel per sample"
    );
    let (finite, seen) = scratch;
    finite.clear();
    finite.extend(points.iter().map(|p| p.map(nan_to_num)));
    seen.clear();
    seen.resize(points.len(), false);
    hull_pixels(finite, view, uv, seen);
    for (o, &held) in uv.iter_mut().zip(inside) {
        if !held {
            *o = [OUTSIDE, OUTSIDE];
        }
    }
}

/// numpy's `nan_to_num` of one float64: NaN to 0, the infinities to the largest finite
/// values of their sign.
#[inline]
fn nan_to_num(x: f64) -> f64 {
    if x.is_nan() {
        0.0
    } else if x == f64::INFINITY {
        f64::MAX
    } else if x == f64::NEG_INFINITY {
        f64::MIN
    } else {
        x
    }
}

/// [`in_hull`] of each of `points` into `out` (the same length).
pub fn hull_inside(points: &[[f64; 3]], views: &[HullView<'_>], min_seen: usize, out: &mut [bool]) {
    assert_eq!(points.len(), out.len(), "one answer per point");
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU has AVX2 and FMA.
        unsafe { hull_inside_wide(points, views, min_seen, out) };
        return;
    }
    // Without FMA `mul_add` is the C library's `fma`: the same numbers, slower.
    hull_fill(points, views, min_seen, &mut 0, out);
}

/// [`hull_inside`] compiled for AVX2 and FMA: four lanes of f64 a register and `mul_add`
/// one instruction (the portable build's is a call into the C library, several times the
/// rest of a view's arithmetic). Only the explicit `mul_add`s fuse: Rust never contracts
/// `a * b + c`, so the pixel's operations stay those of `_seen_pixels`.
///
/// # Safety
/// The CPU must have AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn hull_inside_wide(
    points: &[[f64; 3]],
    views: &[HullView<'_>],
    min_seen: usize,
    out: &mut [bool],
) {
    hull_fill(points, views, min_seen, &mut 0, out);
}

#[cfg(test)]
#[path = "seed_hull_tests.rs"]
mod tests;
