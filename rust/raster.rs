//! Triangle rasterisation at pixel centres: every pixel centre inside every projected
//! triangle, with its screen-space barycentric coordinates (`render/raster.py` draws
//! silhouettes, shaded images and z-buffers from these fragments).
//!
//! The arithmetic is the one the numpy version did, operation by operation and in the same
//! order (no fused multiply-adds), so the fragments are the same to the bit: the synthetic
//! captures' masks and images, on which every measured figure stands, do not move.

use rayon::prelude::*;

/// A pixel centre on a triangle's edge counts as inside when its barycentric coordinates
/// are above `-EDGE_TOLERANCE`: a shared edge evaluated from each triangle's own corner may
/// differ by rounding (~1e-13 at pixel coordinates of ~1e3); counting such centres in both
/// triangles leaves no crack between them.
pub const EDGE_TOLERANCE: f64 = 1e-9;

/// Fragments: pixel centres inside projected triangles, one entry per (pixel, triangle)
/// pair, triangle by triangle in the order given and row-major within each triangle.
#[derive(Debug, Default, Clone, PartialEq)]
pub struct Fragments {
    /// Flat pixel index `v * width + u`.
    pub pixel: Vec<i64>,
    /// Index of the triangle.
    pub face: Vec<i64>,
    /// Barycentric coordinates of the pixel centre, three per fragment.
    pub barycentric: Vec<f64>,
}

impl Fragments {
    fn append(&mut self, mut other: Fragments) {
        self.pixel.append(&mut other.pixel);
        self.face.append(&mut other.face);
        self.barycentric.append(&mut other.barycentric);
    }
}

/// Triangles per parallel task: enough to amortise a task, few enough to balance 2 threads
/// over a mesh of a few thousand faces.
const CHUNK: usize = 512;

/// Every pixel centre inside every projected triangle of `faces` (`F` triangles of vertex
/// indices into `uv`, either orientation), within a `width` x `height` image. Triangles
/// with a non-finite corner or of zero projected area cover nothing.
///
/// # Panics
/// If a face refers to a vertex beyond `uv` (the binding checks).
pub fn fragments(uv: &[[f64; 2]], faces: &[[usize; 3]], width: usize, height: usize) -> Fragments {
    let parts: Vec<Fragments> = faces
        .par_chunks(CHUNK)
        .enumerate()
        .map(|(chunk, faces)| {
            let mut out = Fragments::default();
            for (k, face) in faces.iter().enumerate() {
                triangle(
                    uv,
                    face,
                    (chunk * CHUNK + k) as i64,
                    width,
                    height,
                    &mut out,
                );
            }
            out
        })
        .collect();
    let mut all = Fragments::default();
    for part in parts {
        all.append(part);
    }
    all
}

/// The fragments of one triangle, appended to `out`.
fn triangle(
    uv: &[[f64; 2]],
    face: &[usize; 3],
    index: i64,
    width: usize,
    height: usize,
    out: &mut Fragments,
) {
    let [p0, p1, p2] = face.map(|i| uv[i]);
    let (u0, u1, u2, v0, v1, v2) = (p0[0], p1[0], p2[0], p0[1], p1[1], p2[1]);
    if ![u0, u1, u2, v0, v1, v2].iter().all(|x| x.is_finite()) {
        return;
    }
    let u_lo = (u0.min(u1).min(u2) - EDGE_TOLERANCE).ceil().max(0.0);
    let v_lo = (v0.min(v1).min(v2) - EDGE_TOLERANCE).ceil().max(0.0);
    let u_hi = (u0.max(u1).max(u2) + EDGE_TOLERANCE)
        .floor()
        .min(width as f64 - 1.0);
    let v_hi = (v0.max(v1).max(v2) + EDGE_TOLERANCE)
        .floor()
        .min(height as f64 - 1.0);
    let twice_area = (u1 - u0) * (v2 - v0) - (v1 - v0) * (u2 - u0);
    if !(u_hi >= u_lo && v_hi >= v_lo && twice_area != 0.0 && twice_area.is_finite()) {
        return;
    }
    let inverse_area = 1.0 / twice_area;
    // Barycentric coordinate i is the edge function of the opposite edge over twice the
    // area: an affine function of the offset (du, dv) from the bounding box's corner.
    let edge = |(ua, va): (f64, f64), (ub, vb): (f64, f64)| {
        let (eu, ev) = (ub - ua, vb - va);
        (
            -ev * inverse_area,
            eu * inverse_area,
            (eu * (v_lo - va) - ev * (u_lo - ua)) * inverse_area,
        )
    };
    let (a0, b0, c0) = edge((u1, v1), (u2, v2));
    let (a1, b1, c1) = edge((u2, v2), (u0, v0));
    let nu = (u_hi - u_lo) as i64 + 1;
    let nv = (v_hi - v_lo) as i64 + 1;
    let (u_first, v_first) = (u_lo as i64, v_lo as i64);
    for dv in 0..nv {
        let dv_f = dv as f64;
        for du in 0..nu {
            let du_f = du as f64;
            let l0 = a0 * du_f + b0 * dv_f + c0;
            let l1 = a1 * du_f + b1 * dv_f + c1;
            let l2 = 1.0 - l0 - l1;
            if l0 >= -EDGE_TOLERANCE && l1 >= -EDGE_TOLERANCE && l2 >= -EDGE_TOLERANCE {
                out.pixel.push((v_first + dv) * width as i64 + u_first + du);
                out.face.push(index);
                out.barycentric.extend_from_slice(&[l0, l1, l2]);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_square_of_two_triangles_covers_each_centre_inside_once_or_on_the_diagonal_twice() {
        let uv = [[0.5, 0.5], [4.5, 0.5], [4.5, 3.5], [0.5, 3.5]];
        let found = fragments(&uv, &[[0, 1, 2], [0, 2, 3]], 10, 10);
        let mut pixels = found.pixel.clone();
        pixels.sort();
        pixels.dedup();
        // Centres (1..=4, 1..=3): 12 pixels, none outside the square.
        assert_eq!(pixels.len(), 12);
        assert!(pixels
            .iter()
            .all(|p| (1..=4).contains(&(p % 10)) && (1..=3).contains(&(p / 10))));
        for (k, b) in found.barycentric.chunks(3).enumerate() {
            assert!((b[0] + b[1] + b[2] - 1.0).abs() < 1e-12, "fragment {k}");
        }
    }

    #[test]
    fn degenerate_non_finite_and_outside_triangles_cover_nothing() {
        let uv = [
            [1.0, 1.0],
            [5.0, 5.0],
            [3.0, 3.0],
            [f64::NAN, 2.0],
            [-9.0, -9.0],
            [-5.0, -9.0],
            [-5.0, -5.0],
        ];
        let found = fragments(&uv, &[[0, 1, 2], [0, 1, 3], [4, 5, 6]], 8, 8);
        assert!(found.pixel.is_empty());
    }

    #[test]
    fn chunks_keep_the_order_of_the_triangles() {
        let uv: Vec<[f64; 2]> = (0..3000)
            .map(|i| [(i % 50) as f64 * 1.3, (i / 50) as f64 * 1.1])
            .collect();
        let faces: Vec<[usize; 3]> = (0..2900).map(|i| [i, i + 1, i + 50]).collect();
        let found = fragments(&uv, &faces, 64, 64);
        assert!(!found.face.is_empty());
        assert!(found.face.windows(2).all(|w| w[0] <= w[1]));
    }
}
